//! The second pass: every piece or tet the first pass could not finish (a
//! full polyhedron or flood queue, or, for knn pairing, a security radius
//! not reached within `k_site` neighbours), redone with room to spare and
//! a complete neighbourhood ([`clip_to_cell`]), on the device or the CPU
//! alike. Only a polyhedron or a flood queue that is still too small leaves
//! an entry unfinished, for the host.

use crate::abi::{RefineParams, SplitPoint, INCOMPLETE_TET, NO_SITE, OUT_OF_HALO, WHOLE_CELL};
use crate::buffers::{AtomicSums, PairList};
use crate::cell::tet_vertices;
use crate::clip::{finish_pair, flood, FaceInputs, Paired, PieceSink};
use crate::polyhedron::{Cell, CELL_PLANES, CELL_VERTS};
use crate::walk::{clip_to_cell, power_nearest, GridWalk};

/// Most sites a tet's flood may visit in the second pass.
pub const REFINE_QUEUE: usize = 256;

/// Thread `e` of the second pass over the first pass's unfinished list
/// (`list[0]` entries `(tet, site)` from `list[1]`): a whole tet
/// (`site == NO_SITE`, a failed flood) is flooded again from the site
/// nearest its centroid (`tet_sites[(tet - tet_base) * k_tet]`; in power
/// distance with weights); a pair's piece is clipped on its own and
/// checked against the tet's paired sites; a tet already known to be
/// incomplete, or out of its part's halo, is passed on. What fails again,
/// and those tets, go to `still`.
#[inline]
pub fn refine_entry<A: AtomicSums, C: AtomicSums, L: PairList, S: PieceSink>(
    e: usize,
    p: &RefineParams,
    w: GridWalk,
    sites: &[SplitPoint],
    verts: &[SplitPoint],
    tets: &[[u32; 4]],
    tet_sites: &[u32],
    list: &[u32],
    faces: FaceInputs,
    sums: &mut A,
    counters: &mut C,
    still: &mut L,
    sink: &mut S,
) {
    if e >= list[0] as usize || e >= p.clip.capacity as usize {
        return;
    }
    let t = list[1 + 2 * e] as usize;
    let j = list[2 + 2 * e];
    if t == WHOLE_CELL as usize {
        // A whole cell that could not be built: the host finishes its site.
        still.push(WHOLE_CELL, j);
        return;
    }
    // The tet's slots in `tet_sites`: its paired sites, nearest first.
    let (k, slot) = (p.clip.k_tet as usize, (t - p.clip.tet_base as usize) * p.clip.k_tet as usize);
    if j == NO_SITE {
        refine_tet::<REFINE_QUEUE, _, _, _, _>(
            t,
            power_nearest(t, tet_sites[slot], sites, verts, tets, &w),
            p,
            w,
            sites,
            verts,
            tets,
            faces,
            sums,
            counters,
            still,
            sink,
        );
    } else if j == INCOMPLETE_TET || j == OUT_OF_HALO {
        // Known incomplete, or to be done again from the start with a
        // wider halo (this pass's clips differ from the first pass's).
        still.push(t as u32, j);
    } else {
        let paired = Paired::around(tet_sites, slot, k);
        refine_pair(t, j as usize, paired, p, w, sites, verts, tets, faces, sums, still, sink);
    }
}

/// Tet `t` flooded again from site `start`, each piece clipped by a grid
/// walk in a [`Cell`], with room for `Q` sites; listed whole in `still`
/// if even that fails.
#[inline]
pub fn refine_tet<const Q: usize, A: AtomicSums, C: AtomicSums, L: PairList, S: PieceSink>(
    t: usize,
    start: u32,
    p: &RefineParams,
    w: GridWalk,
    sites: &[SplitPoint],
    verts: &[SplitPoint],
    tets: &[[u32; 4]],
    faces: FaceInputs,
    sums: &mut A,
    counters: &mut C,
    still: &mut L,
    sink: &mut S,
) {
    flood::<CELL_PLANES, CELL_VERTS, Q, _, _, _, _, _>(
        t,
        start,
        &p.clip,
        sites,
        verts,
        tets,
        faces,
        move |j: usize, poly: &mut Cell| clip_to_cell(poly, j, sites, w),
        sums,
        counters,
        still,
        sink,
    );
}

/// Site `j`'s piece of tet `t`, clipped by a grid walk in a [`Cell`];
/// listed in `still` if even that fails (and its tet if it borders a site
/// not `paired` with the tet).
#[inline]
pub fn refine_pair<A: AtomicSums, L: PairList, S: PieceSink>(
    t: usize,
    j: usize,
    paired: Paired,
    p: &RefineParams,
    w: GridWalk,
    sites: &[SplitPoint],
    verts: &[SplitPoint],
    tets: &[[u32; 4]],
    faces: FaceInputs,
    sums: &mut A,
    still: &mut L,
    sink: &mut S,
) {
    let mut poly = Cell::empty();
    let tv = tet_vertices(t, verts, tets, &sites[j]);
    poly.set_tetrahedron(tv);
    let c = clip_to_cell(&mut poly, j, sites, w);
    finish_pair(t, j, &poly, &tv, &c, paired, &p.clip, sites, verts, tets, faces, sums, still, sink);
}
