//! A trajectory's frames: what one frame of particles in a periodic cell
//! leaves for the next ([`FrameLists`]), and the next frame's candidate
//! neighbours from it (see [`crate::job::kept`] for why they certify).
//!
//! A frame keeps, per particle, its nearest sites and images in its job's
//! numbering, with what each job point is — a particle, a lattice shift
//! and a wall — which the next frame renumbers. Between frames each
//! particle moves by a displacement `d_j` taken modulo the lattice (the
//! fractional coordinates' difference rounded to whole turns `w_j` along
//! the periodic axes), so that a point `(j, s)` of the last job is
//! `(j, s - w_j)` now, as seen from a particle that did not wrap (one
//! that did is searched afresh). With `d` the largest displacement,
//! particle `i`'s list holds every point within `r - |d_i| - d` of it, `r`
//! its last reach. A frame's reach is at most its halo: a point outside
//! one frame's halo (no point of that job) is farther than the halo from
//! every particle in the cell — a mirror too, being farther from the cell
//! than the point it mirrors, which lies inside the walls.
//!
//! Keeping the spare neighbours costs a wider search; a frame keeps them
//! only while they pay ([`FrameLists::spare`]).

use super::periodic::{Image, NO_WALL};
use crate::geom::periodic_box::PeriodicBox;
use crate::job::kept::{Candidates, KeptLists};
use rayon::prelude::*;

/// Spare neighbours a frame keeps beyond a cell's list (`k_site`): the
/// skin that lets the next frames reuse it while particles move a little
/// (at density 1, 48 + 24 neighbours reach about 0.3 beyond the 48th).
pub const KEEP_SPARE: usize = 24;

/// The particles' moves since the last frame: each one's whole turns
/// across the cell's sides and its displacement modulo the lattice, and
/// the largest.
pub(super) struct Moves {
    each: Vec<([i32; 3], f64)>,
    most: f64,
}

/// What a frame of a periodic diagram leaves for the next frame of the
/// same particles: each particle's nearest sites and images in the
/// frame's job, what those points are (a particle, a shift, a wall), and
/// the distance within which they are all there are
/// ([`super::periodic::PeriodicVoronoi::keep_lists`]). 4 bytes per kept
/// neighbour.
#[derive(Clone, Debug)]
pub struct FrameLists {
    domain: PeriodicBox,
    sites: Vec<[f64; 3]>,
    weights: Option<Vec<f64>>,
    images: Vec<Image>,
    kept: KeptLists,
    /// Each particle's row in `kept` (`u32::MAX`: none).
    row_of: Vec<u32>,
    /// The skin's typical width: the median of the lists' reach beyond
    /// their cell's last entry (of the last frame that searched most
    /// lists with spare neighbours).
    skin: f64,
    /// Frames in a row that kept no spare neighbours.
    idle: u32,
}

/// Frames between tries of the skin while it does not pay: every this
/// many frames without spare neighbours, one keeps them again.
pub const PROBE_EVERY: u32 = 8;

impl FrameLists {
    /// A frame's lists ([`KeptLists`] of its job over its sites, then
    /// `images`), each reach at most the frame's `halo`; `last`: the frame
    /// before, `spare`: the spare neighbours this one kept.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn new(
        domain: PeriodicBox,
        sites: Vec<[f64; 3]>,
        weights: Option<&[f64]>,
        images: Vec<Image>,
        mut kept: KeptLists,
        halo: f64,
        last: Option<&Self>,
        spare: usize,
    ) -> Self {
        let mut row_of = vec![u32::MAX; sites.len()];
        for (u, r) in kept.reach.iter_mut().enumerate() {
            *r = r.min(halo);
            if let Some(slot) = row_of.get_mut(kept.inputs[u] as usize) {
                *slot = u as u32;
            }
        }
        let skin = if kept.skin > 0.0 && spare > 0 { kept.skin } else { last.map_or(0.0, |l| l.skin) };
        let idle = if spare > 0 { 0 } else { last.map_or(0, |l| l.idle) + 1 };
        Self { domain, sites, weights: weights.map(<[f64]>::to_vec), images, kept, row_of, skin, idle }
    }

    /// The spare neighbours a frame keeps: [`KEEP_SPARE`] where the last
    /// frame's lists gave it candidates, or its particles moved less than
    /// half the skin (the next frame, if it moves alike, can reuse most
    /// lists), or it is time to try again ([`PROBE_EVERY`]); else none
    /// (searching them would be wasted). The first frame keeps them, to
    /// learn the skin.
    pub(super) fn spare(last: Option<&Self>, moves: Option<&Moves>, candidates: bool) -> usize {
        match (last, moves) {
            (Some(l), Some(m)) => {
                let pays = candidates || (l.skin > 0.0 && m.most < 0.5 * l.skin) || (l.idle + 1) % PROBE_EVERY == 0;
                if pays {
                    KEEP_SPARE
                } else {
                    0
                }
            }
            _ => KEEP_SPARE,
        }
    }

    /// Each particle's moves from this frame to one of `sites` (wrapped;
    /// the same particles).
    pub(super) fn moves(&self, sites: &[[f64; 3]]) -> Moves {
        let d = &self.domain;
        let v = d.vectors();
        let each: Vec<([i32; 3], f64)> = sites
            .par_iter()
            .zip(&self.sites)
            .map(|(new, old)| {
                let delta = [0, 1, 2].map(|k| new[k] - old[k]);
                let f = d.fractional([0, 1, 2].map(|k| d.lo()[k] + delta[k]));
                let w = [0, 1, 2].map(|a| if d.periodic()[a] { f[a].round() as i32 } else { 0 });
                let r = [0, 1, 2].map(|k| delta[k] - (0..3).map(|a| w[a] as f64 * v[a][k]).sum::<f64>());
                (w, (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt())
            })
            .collect();
        let most = each.iter().fold(0.0, |m: f64, &(_, r)| m.max(r));
        Moves { each, most }
    }

    /// Particles.
    pub fn len(&self) -> usize {
        self.sites.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.sites.is_empty()
    }

    /// Whether a frame of `sites` (wrapped) with `weights` in `domain` can
    /// start from these lists: the same cell, particles and weights.
    pub(super) fn fits(&self, domain: &PeriodicBox, sites: &[[f64; 3]], weights: Option<&[f64]>) -> bool {
        self.domain == *domain && self.sites.len() == sites.len() && self.weights.as_deref() == weights
    }

    /// The candidates of a frame of `sites` (wrapped) and its `images`
    /// (the job's points: the sites, then the images): each kept point
    /// found again among them, each reach shrunk by the moves. A particle
    /// wrapped across a side since gets none (its list is searched).
    /// `None` where they would certify fewer than an eighth of the cells.
    pub(super) fn candidates(&self, moves: &Moves, images: &[Image]) -> Option<Candidates<'_>> {
        let n = self.sites.len();
        let (most, moves) = (moves.most, &moves.each);
        // Rounding of the distances compared: a relative margin. A row
        // whose reach falls short of its cell's last list entry as it
        // was is not tried (it would most likely fail): 0.
        let reach: Vec<f64> = (0..self.kept.reach.len())
            .into_par_iter()
            .map(|r| {
                let i = self.kept.inputs[r] as usize;
                let reach = self.kept.reach[r] * (1.0 - 1e-9) - moves[i].1 - most;
                if reach > self.kept.kth[r] && moves[i].0 == [0; 3] {
                    reach
                } else {
                    0.0
                }
            })
            .collect();
        if reach.iter().filter(|&&r| r > 0.0).count() < n.div_ceil(8) {
            return None;
        }
        // Each site's images (mirrors included), by site.
        let mut first = vec![0u32; n + 1];
        for m in images {
            first[m.site as usize + 1] += 1;
        }
        for i in 0..n {
            first[i + 1] += first[i];
        }
        let mut fill = first.clone();
        let mut by_site = vec![0u32; images.len()];
        for (u, m) in images.iter().enumerate() {
            by_site[fill[m.site as usize] as usize] = u as u32;
            fill[m.site as usize] += 1;
        }
        let find = |j: usize, shift: [i32; 3], wall: u8| -> u32 {
            if shift == [0; 3] && wall == NO_WALL {
                return j as u32;
            }
            by_site[first[j] as usize..first[j + 1] as usize]
                .iter()
                .find(|&&u| images[u as usize].shift == shift && images[u as usize].wall == wall)
                .map_or(u32::MAX, |&u| (n + u as usize) as u32)
        };
        // The last job's points now: `(j, s)` is `(j, s - w_j)` (seen from
        // a particle that did not wrap).
        let last_n = self.sites.len();
        let to_input: Vec<u32> = self
            .kept
            .inputs
            .par_iter()
            .map(|&u| {
                let u = u as usize;
                let m = if u < last_n {
                    Image { site: u as u32, shift: [0; 3], wall: NO_WALL }
                } else if let Some(&m) = self.images.get(u - last_n) {
                    m
                } else {
                    return u32::MAX;
                };
                let w = moves[m.site as usize].0;
                find(m.site as usize, [0, 1, 2].map(|a| m.shift[a] - w[a]), m.wall)
            })
            .collect();
        Some(Candidates { k: self.kept.k, lists: &self.kept.lists, reach, to_input, row_of: &self.row_of })
    }
}
