//! The interface of every entry point in [`crate::entry`]: its storage
//! buffers (descriptor set 0, binding = position in the list), their
//! element types and access, and its push-constant type. The host builds its
//! pipelines from this table and the exported manifest is written from it;
//! a test checks it against a reflection of the SPIR-V.
//!
//! Host-only: not compiled for SPIR-V.

use crate::abi::{
    ClipParams, DomainParams, GridBuildParams, KnnParams, LloydParams, RefineParams, SplitPoint, WORKGROUP_SIZE,
};
use crate::layout::{Layout, TypeLayout};

/// The version of the kernels' binary interface: entry points, bindings,
/// element and push-constant layouts, and the constants that give buffers
/// their meaning (records per stored cell, the markers in lists, sums per
/// site). It changes with any of them;
/// [`fingerprint`] is pinned by a test to make sure it does.
pub const ABI_VERSION: u32 = 13;

/// The [`fingerprint`] of the interface of [`ABI_VERSION`].
pub const ABI_FINGERPRINT: u64 = 0x5b4a_4e13_8607_f36c;

/// How an entry point uses a storage buffer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Access {
    /// Only read (declared `NonWritable` in the SPIR-V).
    ReadOnly,
    /// Read and written (atomically where many threads share elements).
    ReadWrite,
}

/// One storage buffer of an entry point: a runtime array of `element`.
#[derive(Clone, Copy, Debug)]
pub struct Binding {
    /// The parameter's name in [`crate::entry`].
    pub name: &'static str,
    /// The element type's layout (the array stride is its size).
    pub element: fn() -> TypeLayout,
    /// Read-only or read-write.
    pub access: Access,
    /// What the buffer holds and how long it is.
    pub doc: &'static str,
}

/// One compute entry point.
#[derive(Clone, Copy, Debug)]
pub struct EntryPoint {
    /// Its name in [`crate::entry`].
    pub name: &'static str,
    /// Its SPIR-V name: rust-gpu names entry points by their path inside
    /// the kernels crate, `entry::` + name.
    pub spirv_name: &'static str,
    /// What it does and how many threads it is dispatched over.
    pub doc: &'static str,
    /// Threads per workgroup (`x`; `y` and `z` are 1).
    pub workgroup_size: u32,
    /// The push-constant block's type.
    pub push_constants: fn() -> TypeLayout,
    /// Storage buffers at set 0, bindings `0..bindings.len()`.
    pub bindings: &'static [Binding],
}

impl EntryPoint {
    /// The push-constant block's size in bytes.
    pub fn push_size(&self) -> usize {
        (self.push_constants)().size
    }
}

const fn b<T: Layout>(name: &'static str, access: Access, doc: &'static str) -> Binding {
    Binding { name, element: T::describe, access, doc }
}

macro_rules! ep {
    ($p:ty, $name:literal, $doc:literal, $bindings:expr $(,)?) => {
        EntryPoint {
            name: $name,
            spirv_name: concat!("entry::", $name),
            doc: $doc,
            workgroup_size: WORKGROUP_SIZE,
            push_constants: <$p as Layout>::describe,
            bindings: $bindings,
        }
    };
}

use Access::{ReadOnly as R, ReadWrite as W};

type Quant = [u32; 4];
type Vec4 = [f32; 4];
type Split = SplitPoint;

/// What the clipping kernels' `site_nbrs` binding holds.
const SITE_NBRS: &str = "(nbr_end - nbr_base) * ceil(k_site * list_bits / 32): the k_site nearest other sites of each site in nbr_base..nbr_end, list_bits bits each (32: plain u32), packed in whole words per list, all ones for none";
/// What the clipping kernels' `tet_faces` binding holds.
const TET_FACES: &str = "ceil(n_tets / 8): 4 bits per tet, bit f set when the face opposite vertex f is on the domain's boundary (for the face sums)";
/// What a site-grid walk's bindings hold.
const CELL_START: &str = "n_cells: first sorted slot of each cell of the site grid";
/// See [`CELL_START`].
const CELL_COUNT: &str = "n_cells: sites per cell";
/// See [`CELL_START`].
const SORTED: &str = "n_sites: the sites sorted by cell and index (grid_sort)";

/// Every entry point of [`crate::entry`], in the order a clipping job
/// first dispatches them.
pub const ENTRY_POINTS: &[EntryPoint] = &[
    ep!(
        GridBuildParams,
        "grid_count",
        "Bins each site into its grid cell and counts the sites per cell. One thread per site.",
        &[
            b::<Quant>("sites", R, "n_sites quantized sites [x, y, z, index]"),
            b::<u32>("site_cell", W, "n_sites: the cell of each site"),
            b::<u32>("cell_count", W, "n_cells: sites per cell (atomic; zero it first)"),
        ],
    ),
    ep!(
        GridBuildParams,
        "scan_blocks",
        "Prefix sum, step 1: an exclusive scan of each block of 256 cell counts. One thread per block.",
        &[
            b::<u32>("cell_count", R, "n_cells: sites per cell"),
            b::<u32>("cell_start", W, "n_cells: first sorted slot of each cell"),
            b::<u32>("block_sums", W, "n_blocks: each block's total"),
        ],
    ),
    ep!(
        GridBuildParams,
        "scan_totals",
        "Prefix sum, step 2: thread 0 scans the block totals. Dispatch one thread.",
        &[b::<u32>("block_sums", W, "n_blocks: block totals, scanned in place")],
    ),
    ep!(
        GridBuildParams,
        "scan_offsets",
        "Prefix sum, step 3: adds each block's offset to its cells. One thread per block.",
        &[
            b::<u32>("block_sums", R, "n_blocks: scanned block totals"),
            b::<u32>("cell_start", W, "n_cells: first sorted slot of each cell"),
        ],
    ),
    ep!(
        GridBuildParams,
        "grid_scatter",
        "Moves each site into its cell's range of the sorted array. One thread per site.",
        &[
            b::<Quant>("sites", R, "n_sites quantized sites"),
            b::<u32>("site_cell", R, "n_sites: the cell of each site"),
            b::<u32>("cell_start", R, "n_cells: first sorted slot of each cell"),
            b::<u32>("cursor", W, "n_cells: sites placed per cell so far (atomic; zero it first)"),
            b::<Quant>("sorted", W, "n_sites: the sites sorted by cell"),
        ],
    ),
    ep!(
        GridBuildParams,
        "grid_sort",
        "Orders each cell's sites by index, making later results independent of thread timing. One thread per cell.",
        &[
            b::<u32>("cell_start", R, "n_cells: first sorted slot of each cell"),
            b::<u32>("cell_count", R, "n_cells: sites per cell"),
            b::<Quant>("sorted", W, "n_sites: the sites sorted by cell, then by index"),
        ],
    ),
    ep!(
        KnnParams,
        "knn_grid",
        "The k nearest sites of each query by grid ring search. One thread per query.",
        &[
            b::<Quant>("queries", R, "n_queries quantized query points (the sites for a site job)"),
            b::<u32>("cell_start", R, "n_cells: first sorted slot of each cell"),
            b::<u32>("cell_count", R, "n_cells: sites per cell"),
            b::<Quant>("sorted", R, "n_sites: the sites sorted by cell"),
            b::<u32>(
                "neighbors",
                W,
                "n_sites * k (site job) or n_queries * k: neighbour indices, nearest first (NO_SITE: none)"
            ),
            b::<u64>("neighbor_d2", W, "like neighbors: squared quantized distances"),
        ],
    ),
    ep!(
        KnnParams,
        "knn_brute",
        "The k nearest sites of each query by brute force. One thread per query.",
        &[
            b::<Quant>("queries", R, "n_queries quantized query points"),
            b::<Quant>("sites", R, "n_sites quantized sites"),
            b::<u32>("neighbors", W, "n_queries * k: neighbour indices, nearest first"),
            b::<u64>("neighbor_d2", W, "like neighbors: squared quantized distances"),
        ],
    ),
    ep!(
        ClipParams,
        "clip_tet_cell",
        "Tet-cell strategy, knn pairing: one thread per (tet, paired site), n_tets * k_tet threads.",
        &[
            b::<Split>("sites", R, "n_sites normalised sites, each as hi + lo ([x, y, z, 0] twice; abi::SplitPoint)"),
            b::<Split>("verts", R, "mesh vertices, normalised, as hi + lo (abi::SplitPoint), the density (1 without one) in hi[3]"),
            b::<Quant>("tets", R, "n_tets: four vertex indices per tet"),
            b::<u32>("tet_sites", R, "(n_tets - tet_base) * k_tet: the sites paired with each tet of the part"),
            b::<u32>("site_nbrs", R, SITE_NBRS),
            b::<i64>("sums", W, "n_sites * 5 + n_tets: fixed-point sums per site, then per-tet volumes, then the face sums from faces_base (atomic)"),
            b::<i64>("counters", W, "8 counters (abi::counter; atomic)"),
            b::<u32>("unfinished", W, "1 + 2 * capacity: count, then (tet, site) entries left for the second pass"),
            b::<u32>("tet_faces", R, TET_FACES),
        ],
    ),
    ep!(
        ClipParams,
        "voronoi_cells",
        "Cell-tet strategy: the Voronoi cell of each site (Algorithm 1). One thread per site.",
        &[
            b::<Split>("sites", R, "n_sites normalised sites (hi + lo)"),
            b::<u32>("site_nbrs", R, SITE_NBRS),
            b::<Vec4>("cells", W, "n_sites * CELL_RECORDS records: each site's cell"),
            b::<i64>("counters", W, "8 counters (atomic)"),
        ],
    ),
    ep!(
        ClipParams,
        "clip_cell_tet",
        "Cell-tet strategy: clips each stored cell by a paired tet. One thread per (tet, paired site).",
        &[
            b::<Split>("sites", R, "n_sites normalised sites (hi + lo)"),
            b::<Split>("verts", R, "mesh vertices, normalised (hi + lo), the density in hi[3]"),
            b::<Quant>("tets", R, "n_tets: four vertex indices per tet"),
            b::<u32>("tet_sites", R, "(n_tets - tet_base) * k_tet: the sites paired with each tet of the part"),
            b::<Vec4>("cells", R, "n_sites * CELL_RECORDS: the cells from voronoi_cells"),
            b::<i64>("sums", W, "n_sites * 5 + n_tets: fixed-point sums, then the face sums (atomic)"),
            b::<i64>("counters", W, "8 counters (atomic)"),
            b::<u32>("unfinished", W, "1 + 2 * capacity: entries left for the second pass"),
            b::<u32>("site_nbrs", R, SITE_NBRS),
            b::<u32>("tet_faces", R, TET_FACES),
        ],
    ),
    ep!(
        RefineParams,
        "clip_flood",
        "Tet-cell strategy, flood pairing: one thread per tet, seeded with the site nearest its centroid; a piece its site's list does not settle walks the site grid.",
        &[
            b::<Split>("sites", R, "n_sites normalised sites (hi + lo)"),
            b::<Split>("verts", R, "mesh vertices, normalised (hi + lo), the density in hi[3]"),
            b::<Quant>("tets", R, "n_tets: four vertex indices per tet"),
            b::<u32>("tet_sites", R, "n_tets - tet_base: the site nearest each tet's centroid (knn_grid with k = 1)"),
            b::<u32>("site_nbrs", R, SITE_NBRS),
            b::<u32>("cell_start", R, CELL_START),
            b::<u32>("cell_count", R, CELL_COUNT),
            b::<Quant>("sorted", R, SORTED),
            b::<i64>("sums", W, "n_sites * 5 (+ n_tets, unused): fixed-point sums per site, then the face sums (atomic)"),
            b::<i64>("counters", W, "8 counters (atomic)"),
            b::<u32>("unfinished", W, "1 + 2 * n_tets: count, then (tet, site or NO_SITE) entries"),
            b::<u32>("tet_faces", R, TET_FACES),
        ],
    ),
    ep!(
        RefineParams,
        "clip_whole",
        "Whole cells: one thread per site; its cell, built by its list and a grid walk, integrated whole where no boundary triangle meets it, else clipped by every tet its box meets.",
        &[
            b::<Split>("sites", R, "n_sites normalised sites (hi + lo)"),
            b::<Split>("verts", R, "mesh vertices, normalised (hi + lo), the density in hi[3]"),
            b::<Quant>("tets", R, "n_tets: four vertex indices per tet"),
            b::<u32>("site_nbrs", R, SITE_NBRS),
            b::<u32>("cell_start", R, CELL_START),
            b::<u32>("cell_count", R, CELL_COUNT),
            b::<Quant>("sorted", R, SORTED),
            b::<i64>("sums", W, "n_sites * 5 (+ n_tets, unused): fixed-point sums per site, then the face sums (atomic)"),
            b::<i64>("counters", W, "counters (atomic)"),
            b::<u32>("unfinished", W, "1 + 2 * n_sites: count, then (WHOLE_CELL, site) entries for the host"),
            b::<u32>("tet_faces", R, TET_FACES),
            b::<DomainParams>("domain", R, "one record: the voxel grid over the tets and the boundary hierarchy's size"),
            b::<u32>("voxel_start", R, "voxels + 1: where each voxel's tets start in voxel_tets"),
            b::<u32>("voxel_tets", R, "the tets whose padded bounding box meets each voxel"),
            b::<u32>("tet_voxel", R, "n_tets: each tet's first voxel (linear index)"),
            b::<Vec4>("nodes", R, "2 per node of the boundary's hierarchy: [lo, a], [hi, b] (LEAF | first triangle and count, or children)"),
            b::<Quant>("tris", R, "the boundary's triangles, as vertex indices, in the hierarchy's order"),
        ],
    ),
    ep!(
        RefineParams,
        "refine",
        "Second pass: redoes each unfinished entry by its neighbour list, then a grid walk. One thread per list slot (capacity threads).",
        &[
            b::<Split>("sites", R, "n_sites normalised sites (hi + lo)"),
            b::<Split>("verts", R, "mesh vertices, normalised (hi + lo), the density in hi[3]"),
            b::<Quant>("tets", R, "n_tets: four vertex indices per tet"),
            b::<u32>("tet_sites", R, "the first pass's pairs"),
            b::<u32>("list", R, "the first pass's unfinished list"),
            b::<u32>("site_nbrs", R, SITE_NBRS),
            b::<u32>("cell_start", R, CELL_START),
            b::<u32>("cell_count", R, CELL_COUNT),
            b::<Quant>("sorted", R, SORTED),
            b::<i64>("sums", W, "the first pass's sums, added to (atomic)"),
            b::<i64>("counters", W, "8 counters (atomic; the host passes a scratch buffer)"),
            b::<u32>("still", W, "1 + 2 * capacity: entries even this pass could not finish"),
            b::<u32>("tet_faces", R, TET_FACES),
        ],
    ),
    ep!(
        LloydParams,
        "move_sites",
        "Lloyd: moves each site to its cell's centroid and records the iteration's statistics. One thread per site.",
        &[
            b::<i64>("sums", R, "n_sites * 5: the diagram's fixed-point sums"),
            b::<u32>("unfinished", R, "the first pass's unfinished list"),
            b::<u32>("still", R, "the second pass's unfinished list"),
            b::<Split>("sites", W, "n_sites normalised sites (hi + lo), moved in place"),
            b::<Quant>("quant", W, "n_sites quantized sites, moved in place"),
            b::<i64>("stats", W, "iterations * 4 statistics (abi::lloyd_stat; atomic)"),
        ],
    ),
];

/// The entry point named `name` (without the `entry::` prefix).
pub fn entry_point(name: &str) -> Option<&'static EntryPoint> {
    ENTRY_POINTS.iter().find(|e| e.name == name)
}

/// A 64-bit FNV-1a hash of the whole interface: every entry point's name,
/// workgroup size, bindings (name, access, element layout) and
/// push-constant layout, with every field's name, offset and size; and
/// the constants buffers are read by.
pub fn fingerprint() -> u64 {
    let mut h = Fnv(0xcbf2_9ce4_8422_2325);
    for c in [
        crate::clip::CELL_RECORDS as u64,
        crate::abi::NO_SITE as u64,
        crate::abi::INCOMPLETE_TET as u64,
        crate::abi::OUT_OF_HALO as u64,
        crate::abi::counter::COUNT as u64,
        crate::abi::ACCUM_PER_SITE as u64,
        crate::clip::FACE_SUMS_EXTRA as u64,
        crate::abi::WHOLE_CELL as u64,
        crate::abi::domain_whole::INSIDE as u64,
        crate::abi::domain_whole::ALL as u64,
    ] {
        h.num(c);
    }
    for e in ENTRY_POINTS {
        h.str(e.name);
        h.num(e.workgroup_size as u64);
        hash_layout(&mut h, &(e.push_constants)());
        for b in e.bindings {
            h.str(b.name);
            h.num(matches!(b.access, Access::ReadWrite) as u64);
            hash_layout(&mut h, &(b.element)());
        }
        h.str(";");
    }
    h.0
}

fn hash_layout(h: &mut Fnv, t: &TypeLayout) {
    h.str(t.name);
    h.num(t.size as u64);
    t.for_each_scalar(&mut |path, index, offset, s| {
        for p in path {
            h.str(p);
        }
        h.num(index.map_or(u64::MAX, |i| i as u64));
        h.num(offset as u64);
        h.str(s.name);
    });
}

struct Fnv(u64);

impl Fnv {
    fn byte(&mut self, b: u8) {
        self.0 = (self.0 ^ b as u64).wrapping_mul(0x0000_0100_0000_01b3);
    }
    fn str(&mut self, s: &str) {
        s.bytes().for_each(|b| self.byte(b));
        self.byte(0);
    }
    fn num(&mut self, n: u64) {
        n.to_le_bytes().into_iter().for_each(|b| self.byte(b));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn abi_version_matches_the_interface() {
        let now = fingerprint();
        assert_eq!(
            now, ABI_FINGERPRINT,
            "the kernels' interface changed (fingerprint {now:#018x}): increase ABI_VERSION and set ABI_FINGERPRINT"
        );
    }
}
