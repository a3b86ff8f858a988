//! A polyhedron clipped by the bisectors of its site and the sites near
//! it, toward the site's cell: the step the pairing bodies (`clip`) and the
//! grid walk (`walk`) share.
//!
//! Relative to site `i`, each site `j` at `n = x_j - x_i` cuts by its
//! bisector `n·x <= (|n|² + w_i - w_j)/2`, nearest first when the sites
//! come from a neighbour list, until the sites left all lie beyond the
//! security radius ([`reach2`]: twice the polyhedron's farthest vertex
//! without weights, widened by the weights' [`Slack`] for power cells),
//! where none can cut any more. A [`BisectorRun`] keeps that state for
//! sites from any source; [`clip_by_bisectors`] feeds it the site's
//! neighbour list, and [`Clipped`] tells how the clips ended. A piece
//! starts as its tet, relative to its site ([`tet_vertices`]).

use crate::abi::{SplitPoint, NO_SITE};
use crate::lists::{Lists, NO_LIST};
use crate::polyhedron::{between, bisector_offset, weight_gap, Clip, Point, Polyhedron};
use spirv_std::glam::Vec3;
#[cfg(target_arch = "spirv")]
use spirv_std::num_traits::Float;

/// How a run of clips ended.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Clipped {
    /// Clips that cut.
    pub clips: i64,
    /// The neighbour list ended before the security radius was reached.
    pub security_missed: bool,
    /// The polyhedron ran out of capacity.
    pub overflow: bool,
    /// The polyhedron's structure broke down numerically.
    pub broken: bool,
    /// Pieces finished by a grid walk after their list.
    pub walks: i64,
    /// The piece needed a site the job may not hold (a part of a
    /// distributed job): not finished ([`crate::abi::OUT_OF_HALO`]).
    pub out_of_halo: bool,
}

impl Clipped {
    /// Whether the piece is exact.
    #[inline]
    pub fn finished(&self) -> bool {
        !self.security_missed && !self.overflow && !self.broken
    }
}

/// The squared distance from a site beyond which no other site can cut a
/// polyhedron whose vertices lie within `sqrt(r2)` of it. A site `x_j` at
/// `n` from `x_i` owns a point `x` (relative to `x_i`) rather than `x_i`
/// only if `2 n·x > |n|² + w_i - w_j`; with `|x| <= r` and `w_j - w_i <=
/// slack` that needs `|n|² - 2 |n| r - slack < 0`, that is `|n| < r +
/// sqrt(r² + slack)`: twice the farthest vertex without weights (`slack =
/// weight_range - w_i`, 0 for Voronoi cells), widened by a rounding margin
/// with them.
#[inline]
pub fn reach2(r2: f32, slack: f32) -> f32 {
    if slack > 0.0 {
        let reach = r2.sqrt() + (r2 + slack).sqrt();
        reach * reach * (1.0 + 1e-6)
    } else {
        4.0 * r2
    }
}

/// How much more weight than site `i` a site that cuts its cell may have:
/// `weight_range - w_i` in general, and local bounds for polyhedra near
/// the site. The local bounds are the host's (see
/// [`ClipParams::weight_range`](crate::abi::ClipParams::weight_range)):
/// `W - w_i` with `W` the largest weight among the sites near `i`, found so
/// that every site that cuts a polyhedron within a given radius of the site
/// is among them, for three radii. Weights that drift across the domain (as optimal transport's do)
/// span much more than they vary within a few cells: the local bounds keep
/// the security radius near the Voronoi cells' `2r`. All 0 for Voronoi
/// cells.
#[derive(Clone, Copy, Default)]
pub struct Slack {
    /// `weight_range - w_i`.
    pub global: f32,
    /// `W - w_i` for polyhedra within `sqrt(caps[k])` of the site, the
    /// caps increasing.
    pub local: [f32; 3],
    /// The squared radii within which `local` holds.
    pub caps: [f32; 3],
}

impl Slack {
    /// Site `i`'s slack: without weights (`weight_range == 0`) none; its
    /// local bounds from record `n_sites + i` of `sites` when the host gave
    /// them (`hi = [W_0, R_0², W_1, R_1²]`, `lo = [W_2, R_2², 0, 0]`; see
    /// [`ClipParams::weight_range`](crate::abi::ClipParams::weight_range)).
    #[inline]
    pub fn of(weight_range: f32, sites: &[SplitPoint], i: usize, n_sites: u32) -> Self {
        if weight_range == 0.0 {
            return Self::default();
        }
        let site = &sites[i];
        let below = |w: f32| (w - site.hi[3]) - site.lo[3];
        let global = below(weight_range);
        let bound = n_sites as usize + i;
        if bound < sites.len() {
            let b = sites[bound];
            Self { global, local: [below(b.hi[0]), below(b.hi[2]), below(b.lo[0])], caps: [b.hi[1], b.hi[3], b.lo[1]] }
        } else {
            Self { global, local: [global; 3], caps: [0.0; 3] }
        }
    }

    /// The bound that holds for a polyhedron within `sqrt(r2)` of the site.
    #[inline]
    pub fn at(&self, r2: f32) -> f32 {
        if r2 <= self.caps[0] {
            self.local[0]
        } else if r2 <= self.caps[1] {
            self.local[1]
        } else if r2 <= self.caps[2] {
            self.local[2]
        } else {
            self.global
        }
    }

    /// The squared security radius of a polyhedron within `sqrt(r2)` of
    /// the site ([`reach2`]).
    #[inline]
    pub fn reach2(&self, r2: f32) -> f32 {
        reach2(r2, self.at(r2))
    }
}

/// A run of bisector clips on one polyhedron: how it went, and the
/// polyhedron's farthest vertex and bounding box, which decide cheaply
/// which bisectors can still cut it.
pub struct BisectorRun {
    /// How the run went so far.
    pub out: Clipped,
    /// The squared security radius: no site farther can cut ([`reach2`]).
    pub reach2: f32,
    slack: Slack,
    mid: Point,
    half: Point,
}

impl BisectorRun {
    /// A run on `poly`, with the security radius not yet reached, for a
    /// site with that [`Slack`].
    #[inline]
    pub fn new<const P: usize, const V: usize>(poly: &Polyhedron<P, V>, slack: Slack) -> Self {
        let (r2, mid, half) = poly.bounds();
        let out = Clipped { security_missed: true, ..Clipped::default() };
        Self { out, reach2: slack.reach2(r2), slack, mid, half }
    }

    /// Whether the bisector `n·x <= h` clears the bounding box — then it
    /// cannot cut. The margin keeps this test from deciding what rounding
    /// could flip.
    #[inline]
    pub fn clears(&self, n: Point, h: f32) -> bool {
        let inward = n.dot(self.mid);
        let spread = n.abs().dot(self.half);
        inward + spread + 1e-5 * (inward.abs() + spread) < h
    }

    /// Clips `poly` by the bisector `n·x <= h` (made by site `id`);
    /// returns whether the run must stop (nothing left, or a failure,
    /// recorded in `out`).
    #[inline]
    pub fn clip<const P: usize, const V: usize>(
        &mut self,
        poly: &mut Polyhedron<P, V>,
        n: Point,
        h: f32,
        id: u32,
    ) -> bool {
        match poly.clip_as(n.extend(h), id) {
            Clip::Cut => {
                self.out.clips += 1;
                let r2;
                (r2, self.mid, self.half) = poly.bounds();
                self.reach2 = self.slack.reach2(r2);
                false
            }
            Clip::Unchanged => false,
            Clip::Empty => {
                self.out.clips += 1;
                self.out.security_missed = false;
                true
            }
            Clip::Overflow => {
                self.out.overflow = true;
                true
            }
            Clip::Broken => {
                self.out.broken = true;
                true
            }
        }
    }
}

/// Clips `poly` (relative to site `i`) by the bisectors of `i` and its
/// neighbours in `lists` (the list at `slot`, from [`Lists::slot`]), nearest
/// first, until the next neighbour is beyond the security radius (twice the
/// farthest vertex without weights; [`reach2`]) or nothing is left.
/// Without a list (`slot == NO_LIST`) the piece is left unfinished, as if
/// the radius were missed; with a list marked unknown ([`Lists::unknown`]),
/// too, and out of the halo.
#[inline]
pub fn clip_by_bisectors<const P: usize, const V: usize>(
    poly: &mut Polyhedron<P, V>,
    i: usize,
    n_sites: u32,
    weight_range: f32,
    sites: &[SplitPoint],
    lists: &Lists,
    slot: usize,
) -> Clipped {
    if slot == NO_LIST {
        return Clipped { security_missed: true, ..Clipped::default() };
    }
    if lists.unknown(slot, i as u32) {
        return Clipped { security_missed: true, out_of_halo: true, ..Clipped::default() };
    }
    let xi = sites[i];
    let mut run = BisectorRun::new(poly, Slack::of(weight_range, sites, i, n_sites));
    let k = lists.k();
    let mut s = 0;
    while s < k {
        let nb = lists.get(slot, s);
        if nb == NO_SITE {
            // Every other site has been used: the cell is exact.
            run.out.security_missed = false;
            break;
        }
        let xj = sites[nb as usize];
        let n = between(&xj, &xi);
        let d2 = n.length_squared();
        if d2 > run.reach2 {
            run.out.security_missed = false;
            break;
        }
        let h = bisector_offset(d2, weight_gap(&xi, &xj));
        if !run.clears(n, h) && run.clip(poly, n, h, nb) {
            break;
        }
        s += 1;
    }
    if s == k && k as u32 + 1 >= n_sites {
        // The list held every other site.
        run.out.security_missed = false;
    }
    run.out
}

/// The vertices of tet `t`, relative to `origin` (a site).
#[inline]
pub fn tet_vertices(t: usize, verts: &[SplitPoint], tets: &[[u32; 4]], origin: &SplitPoint) -> [Vec3; 4] {
    let tet = tets[t];
    [
        Vec3::from(between(&verts[tet[0] as usize], origin)),
        Vec3::from(between(&verts[tet[1] as usize], origin)),
        Vec3::from(between(&verts[tet[2] as usize], origin)),
        Vec3::from(between(&verts[tet[3] as usize], origin)),
    ]
}
