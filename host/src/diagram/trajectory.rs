//! A trajectory's frames: what one frame of particles in a periodic cell
//! leaves for the next ([`FrameLists`]), and the next frame's candidate
//! neighbours from it (see [`crate::job::kept`] for why they certify).
//!
//! A frame keeps, per particle, its nearest sites and images as
//! *identities* — a particle, a lattice shift and a wall — never as the
//! frame's own indices, which the next frame renumbers. Between frames
//! each particle moves by a displacement `d_j` taken modulo the lattice
//! (the fractional coordinates' difference rounded to whole turns along
//! the periodic axes: a particle wrapped across a side keeps its
//! neighbours), so that a neighbour `(j, s)` of particle `i` is
//! `(j, s - w_j + w_i)` now, `w` each particle's whole turns. With `d` the
//! largest displacement, the particle's list holds every point within
//! `r - |d_i| - d` of it, `r` its last reach. A frame's reach is at most
//! its halo: a point outside one frame's halo (no point of that job) is
//! farther than the halo from every particle in the cell.

use super::periodic::{Image, NO_WALL};
use crate::geom::periodic_box::PeriodicBox;
use crate::job::kept::{Candidates, KeptLists};
use rayon::prelude::*;

/// Spare neighbours a frame keeps beyond a cell's list (`k_site`): the
/// skin that lets the next frames reuse it while particles move a little
/// (at density 1, 48 + 24 neighbours reach about 0.3 beyond the 48th).
pub const KEEP_SPARE: usize = 24;

/// One kept neighbour: a particle's image by its identity.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Kept {
    site: u32,
    shift: [i8; 3],
    wall: u8,
}

const NONE: Kept = Kept { site: u32::MAX, shift: [0; 3], wall: NO_WALL };

/// What a frame of a periodic diagram leaves for the next frame of the
/// same particles: each particle's nearest sites and images, and the
/// distance within which they are all there are
/// ([`super::periodic::PeriodicVoronoi::keep_lists`]). 8 bytes per kept
/// neighbour.
#[derive(Clone, Debug)]
pub struct FrameLists {
    domain: PeriodicBox,
    sites: Vec<[f64; 3]>,
    weights: Option<Vec<f64>>,
    k: usize,
    entries: Vec<Kept>,
    reach: Vec<f64>,
}

impl FrameLists {
    /// A frame's lists ([`KeptLists`] over its sites then `images`, in
    /// input terms), each reach at most the frame's `halo`.
    pub(super) fn new(
        domain: PeriodicBox,
        sites: Vec<[f64; 3]>,
        weights: Option<&[f64]>,
        images: &[Image],
        kept: &KeptLists,
        halo: f64,
    ) -> Self {
        let n = sites.len();
        let k = kept.k;
        let mut entries = vec![NONE; n * k];
        let mut reach = vec![0.0; n];
        entries.par_chunks_mut(k.max(1)).zip(&mut reach).enumerate().for_each(|(i, (row, r))| {
            if i >= kept.reach.len() {
                return;
            }
            *r = kept.reach[i].min(halo);
            for (slot, &u) in row.iter_mut().zip(kept.of(i)) {
                let u = u as usize;
                *slot = if u == u32::MAX as usize {
                    NONE
                } else if u < n {
                    Kept { site: u as u32, shift: [0; 3], wall: NO_WALL }
                } else {
                    let m = images[u - n];
                    match m.shift.map(i8::try_from) {
                        [Ok(a), Ok(b), Ok(c)] => Kept { site: m.site, shift: [a, b, c], wall: m.wall },
                        // Too far to keep: the list holds only what lies
                        // before it.
                        _ => {
                            *r = 0.0;
                            NONE
                        }
                    }
                };
            }
        });
        Self { domain, sites, weights: weights.map(<[f64]>::to_vec), k, entries, reach }
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

    /// Each particle's candidates in a frame of `sites` (wrapped) and its
    /// `images` (the job's points: the sites, then the images), with the
    /// reach within which they are every point of the job.
    pub(super) fn candidates(&self, sites: &[[f64; 3]], images: &[Image]) -> Candidates {
        let n = sites.len();
        let d = &self.domain;
        let v = d.vectors();
        // Each particle's whole turns and displacement modulo the lattice.
        let moves: Vec<([i32; 3], f64)> = sites
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
        let most = moves.iter().fold(0.0, |m: f64, &(_, r)| m.max(r));
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
        let find = |j: usize, shift: [i32; 3], wall: u8| -> Option<u32> {
            if shift == [0; 3] && wall == NO_WALL {
                return Some(j as u32);
            }
            by_site[first[j] as usize..first[j + 1] as usize]
                .iter()
                .find(|&&u| images[u as usize].shift == shift && images[u as usize].wall == wall)
                .map(|&u| (n + u as usize) as u32)
        };
        let rows: Vec<(Vec<u32>, f64)> = (0..n)
            .into_par_iter()
            .map(|i| {
                // Rounding of the distances compared: a relative margin.
                let reach = self.reach[i] * (1.0 - 1e-9) - moves[i].1 - most;
                if reach <= 0.0 {
                    return (Vec::new(), 0.0);
                }
                let wi = moves[i].0;
                let row = self.entries[i * self.k..(i + 1) * self.k]
                    .iter()
                    .filter(|e| e.site != u32::MAX)
                    .filter_map(|e| {
                        let j = e.site as usize;
                        let wj = moves[j].0;
                        let s = [0, 1, 2].map(|a| e.shift[a] as i32 - wj[a] + wi[a]);
                        find(j, s, e.wall)
                    })
                    .collect();
                (row, reach)
            })
            .collect();
        let mut c = Candidates { offsets: vec![0], ..Default::default() };
        for (row, reach) in rows {
            c.points.extend(row);
            c.offsets.push(c.points.len());
            c.reach.push(reach);
        }
        c
    }
}
