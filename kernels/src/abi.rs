//! Types shared by the host and the kernels (push constants and buffer
//! records), defined once.
//!
//! # Layout rule
//! Storage buffers use the std430 layout, where a 3-vector has a 16-byte
//! alignment but a glam `Vec3` has a 12-byte stride on the host. So no `Vec3`
//! ever crosses the boundary: points are stored as 4-component records
//! (`[u32; 4]`, `[f32; 4]`) and every struct here is `#[repr(C)]`, made of
//! 4-byte scalars (or 8-byte ones at 8-byte offsets), with no implicit padding.
//! Push-constant structs follow the same rule.

use bytemuck::{Pod, Zeroable};

/// Coordinates are quantized to integers in `[0, QUANT_MAX]` on the host, so
/// that squared distances are exact in 64 bits (3 * (2^30)^2 < 2^64) and every
/// backend orders neighbours identically.
pub const QUANT_BITS: u32 = 30;
/// The largest quantized coordinate.
pub const QUANT_MAX: u32 = (1 << QUANT_BITS) - 1;

/// Marks "no site" (no index to exclude, an empty neighbour slot).
pub const NO_SITE: u32 = u32::MAX;

/// In an unfinished list, `(tet, INCOMPLETE_TET)` says that a piece of the
/// tet (knn pairing) has a face made by a site not paired with the tet:
/// that site, or one beyond it, owns part of the tet, and the host adds
/// the tet's missing pieces.
pub const INCOMPLETE_TET: u32 = u32::MAX - 1;

/// A part of a distributed job holds the sites of some grid cells only
/// ([`RefineParams::held_lo_x`]). In an unfinished list, `(tet,
/// OUT_OF_HALO)` says that the tet's flood needed a site it may not hold (a
/// walk reaching a cell outside, or a neighbour list the host could not
/// certify): the tet added nothing, and is done again with a wider halo. As
/// a tet's nearest site (`tet_sites`), it says that the host could not
/// certify that site.
pub const OUT_OF_HALO: u32 = u32::MAX - 2;

/// The `cell_start` of a grid cell inside the held cells
/// ([`RefineParams::held_lo_x`]) whose sites a part does not hold, with a
/// `cell_count` of 0: a search finds no site there, and a walk that must
/// look at it gives up as outside the held cells (a part's held cells are
/// then the box less these, not the whole box). No cell's first slot is
/// ever this large.
pub const UNHELD: u32 = u32::MAX;

/// In the tet slot of an unfinished entry `(WHOLE_CELL, site)`: the
/// whole-cell strategy could not build that site's cell (a full polyhedron
/// or a breakdown); the host finishes the site from its tets' pieces. As
/// the tet of a piece handed to a sink: the site's whole cell, in no tet.
pub const WHOLE_CELL: u32 = u32::MAX - 3;

/// Threads per workgroup of every kernel.
pub const WORKGROUP_SIZE: u32 = 64;

/// A site or query point: quantized `x, y, z` and its original index.
pub type QuantPoint = [u32; 4];

/// A point of the clipping frame as the unevaluated sum `hi + lo` of two
/// f32 vectors, made on the host from the f64 input: `hi` is the point
/// rounded to f32 and `lo` what that rounding left, so the pair holds about
/// 48 bits per coordinate. The kernels take the vector between two nearby
/// points as `(hi_a - hi_b) + (lo_a - lo_b)` (see
/// `polyhedron::between`): the first difference is exact or
/// rounded relative to itself, so the vector is accurate to f32 relative to
/// its own length, however far the points are from the frame's origin.
/// `hi[3] + lo[3]` carries a value of the point, split the same way: a
/// site's power weight (0 for Voronoi cells; see [`ClipParams::weight_range`]),
/// or a mesh vertex's density (in `hi[3]` alone).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct SplitPoint {
    /// The coordinates rounded to f32, and the point's value.
    pub hi: [f32; 4],
    /// The rounding's remainders (and the value's).
    pub lo: [f32; 4],
}

#[cfg(not(target_arch = "spirv"))]
impl SplitPoint {
    /// `p` split into `hi + lo`, with `value` in `hi[3]`.
    #[inline]
    pub fn new(p: [f64; 3], value: f32) -> Self {
        let hi = [p[0] as f32, p[1] as f32, p[2] as f32];
        let lo = [(p[0] - hi[0] as f64) as f32, (p[1] - hi[1] as f64) as f32, (p[2] - hi[2] as f64) as f32];
        Self { hi: [hi[0], hi[1], hi[2], value], lo: [lo[0], lo[1], lo[2], 0.0] }
    }

    /// Site `p` with power weight `w`, both split into `hi + lo`.
    #[inline]
    pub fn site(p: [f64; 3], w: f64) -> Self {
        let mut s = Self::new(p, w as f32);
        s.lo[3] = (w - s.hi[3] as f64) as f32;
        s
    }

    /// The point's value in f64 (a site's weight, exactly `hi + lo`).
    #[inline]
    pub fn value(&self) -> f64 {
        self.hi[3] as f64 + self.lo[3] as f64
    }

    /// The point in f64 (exactly `hi + lo`).
    #[inline]
    pub fn to_f64(&self) -> [f64; 3] {
        [
            self.hi[0] as f64 + self.lo[0] as f64,
            self.hi[1] as f64 + self.lo[1] as f64,
            self.hi[2] as f64 + self.lo[2] as f64,
        ]
    }
}

/// A uniform grid over quantized space: cubic cells of side `cell_size`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct GridParams {
    /// Number of cells along x.
    pub dim_x: u32,
    /// Number of cells along y.
    pub dim_y: u32,
    /// Number of cells along z.
    pub dim_z: u32,
    /// Side of a cell in quantized units.
    pub cell_size: u32,
    /// Number of sites in the grid.
    pub n_sites: u32,
    /// `dim_x * dim_y * dim_z`.
    pub n_cells: u32,
    /// Padding to a 16-byte multiple.
    pub _pad: [u32; 2],
}

/// Push constants of the grid-building kernels.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct GridBuildParams {
    /// The grid being built.
    pub grid: GridParams,
    /// Number of blocks of the prefix sum (see [`crate::scan`]).
    pub n_blocks: u32,
    /// Padding to a 16-byte multiple.
    pub _pad: [u32; 3],
}

/// Push constants of the k-nearest-neighbour kernels.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct KnnParams {
    /// The grid over the sites (unused by brute force, but for `n_sites`).
    pub grid: GridParams,
    /// Number of query points.
    pub n_queries: u32,
    /// Neighbours per query (already clamped to what exists).
    pub k: u32,
    /// 1: query `i` is site `i` and excludes itself; 0: plain points.
    pub exclude_self: u32,
    /// First query of this dispatch (a job in parts; 0 otherwise): thread
    /// `i` of a point job answers query `query_base + i`, writing at slot
    /// `i` (the lists hold the dispatch's queries).
    pub query_base: u32,
    /// 1: a site job answers its sites in index order from `query_base`,
    /// like a point job (the lists hold the dispatch's sites); 0: in grid
    /// order, each at its own slot.
    pub in_order: u32,
    /// 1: each query sorts its candidates in slots `0..k` of the two
    /// buffers, its own scratch (a CPU thread's, reused query after query,
    /// which then stores the list where it wants it: the threads return
    /// the query's slot); 0: at the query's own slots, the output.
    pub local_lists: u32,
    /// Padding to a 16-byte multiple.
    pub _pad: [u32; 2],
}

/// The thread index of a 1D job dispatched as a 2D grid of workgroups
/// (`x` limited to 65535 groups): `id.y` rows of `groups_x * WORKGROUP_SIZE`.
#[inline]
pub fn thread_index(global_id_x: u32, global_id_y: u32, groups_x: u32) -> usize {
    global_id_y as usize * (groups_x * WORKGROUP_SIZE) as usize + global_id_x as usize
}

/// Integrals accumulated per site, each an `i64` in fixed point (see
/// [`ClipParams::fixed_scale`]), relative to the site: volume, first moment
/// x, y, z, second moment `∫|x - x_i|²`.
pub const ACCUM_PER_SITE: usize = 5;

/// Counters of a clipping job (`i64` each), by index.
pub mod counter {
    /// Tet-site pairs tried.
    pub const PAIRS: usize = 0;
    /// Pairs whose piece was not empty.
    pub const NONEMPTY: usize = 1;
    /// Plane clips that cut a polyhedron.
    pub const CLIPS: usize = 2;
    /// Cells or pieces whose security radius was not reached within the
    /// neighbour budget (their result may be too large).
    pub const SECURITY_MISSED: usize = 3;
    /// Polyhedra that ran out of capacity (their result is wrong).
    pub const OVERFLOWS: usize = 4;
    /// Polyhedra whose structure broke down numerically.
    pub const BROKEN: usize = 5;
    /// Pairs dropped by the half-space test before any clipping.
    pub const FILTERED: usize = 6;
    /// Pieces their neighbour list did not settle, finished in place by a
    /// grid walk (flood pairing).
    pub const WALKS: usize = 7;
    /// Tets whose flood needed a site outside the held cells (a part of a
    /// distributed job; see [`super::OUT_OF_HALO`]), left for a wider halo.
    pub const HALO: usize = 8;
    /// Whole-cell strategy: cells inside the domain, integrated whole.
    pub const WHOLE: usize = 9;
    /// Whole-cell strategy: cells the boundary may cut, clipped by the tets
    /// their ball meets.
    pub const CUT: usize = 10;
    /// Number of counters.
    pub const COUNT: usize = 11;
}

/// Push constants of the clipping kernels. Coordinates are normalised on
/// the host (the mesh's bounding box scaled to a unit longest side).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct ClipParams {
    /// Number of sites.
    pub n_sites: u32,
    /// End of the tets this dispatch covers: tets `tet_base..n_tets` (the
    /// number of tets when the job is not split into chunks).
    pub n_tets: u32,
    /// Neighbours per site used for its cell (Algorithm 1).
    pub k_site: u32,
    /// Sites paired with each tet.
    pub k_tet: u32,
    /// Fixed-point scale of the accumulated integrals (a power of two).
    pub fixed_scale: f32,
    /// Lower corner of a box holding the mesh and the sites (cell-tet).
    pub box_lo_x: f32,
    /// See `box_lo_x`.
    pub box_lo_y: f32,
    /// See `box_lo_x`.
    pub box_lo_z: f32,
    /// Upper corner of that box.
    pub box_hi_x: f32,
    /// See `box_hi_x`.
    pub box_hi_y: f32,
    /// See `box_hi_x`.
    pub box_hi_z: f32,
    /// First tet this dispatch covers: thread `i` works on tet pair
    /// `tet_base * k_tet + i`, whose paired sites are at `tet_sites[i]`
    /// (the lists hold the chunk's tets only). 0 when not chunked.
    pub tet_base: u32,
    /// The sites whose neighbour lists are bound, `nbr_base..nbr_end`:
    /// site `j`'s `k_site` neighbours are at `site_nbrs[(j - nbr_base) *
    /// k_site..]`. A piece of a site outside is left unfinished. `0..n_sites`
    /// when the lists are not split into windows.
    pub nbr_base: u32,
    /// See `nbr_base`.
    pub nbr_end: u32,
    /// The sites this dispatch answers for, `own_lo..own_hi`: a pair whose
    /// site is, or a cell of a site outside is left to the dispatch that
    /// owns it (floods go by tets, `tet_base..n_tets`). `0..n_sites` when
    /// not split.
    pub own_lo: u32,
    /// See `own_lo`.
    pub own_hi: u32,
    /// Where the faces' sums begin in `sums` (`clip::add_faces`),
    /// or 0: no faces are summed.
    pub faces_base: u32,
    /// Fixed-point scale of the face areas (a power of two).
    pub area_scale: f32,
    /// How far a site may sit outside its site-grid cell in the clipping
    /// frame (quantization and rounding), subtracted from every gap of a
    /// grid walk.
    pub walk_margin: f32,
    /// Capacity of the second pass's entry lists, in entries.
    pub capacity: u32,
    /// Power (Laguerre) cells: the sites' weights range over
    /// `0..=weight_range` (the host shifts them so that the smallest is 0,
    /// which changes no cell); 0 for Voronoi cells. A site's weight is in
    /// its [`SplitPoint`]'s `hi[3] + lo[3]`. Site `j` cuts a point within
    /// `r` of site `i` only if `|x_j - x_i| < r + sqrt(r² + w_j - w_i)`:
    /// the security radius (docs/ARCHITECTURE.md), with `w_j` at most
    /// `weight_range`, or at most a local bound `W_k` when `r <= R_k`: the
    /// sites buffer may then hold `n_sites` more records after the sites,
    /// record `n_sites + i` with `hi = [W_0, R_0², W_1, R_1²]` and `lo =
    /// [W_2, R_2², 0, 0]`, `R_0 < R_1 < R_2` (see `cell::Slack`;
    /// without them the global bound serves).
    pub weight_range: f32,
    /// With face sums and a density: 1 sums each face's mass `∫ρ dA`
    /// instead of its area, taken as the area times its piece's mean
    /// density (exact for a density constant over the piece; what optimal
    /// transport's Newton steps are made of); 0 sums areas.
    pub face_masses: u32,
    /// Bits per entry of the neighbour lists (`site_nbrs`): 32 for plain
    /// `u32` entries, fewer for lists packed into whole words per list
    /// (see `lists`).
    pub list_bits: u32,
    /// The first site with face sums: site `j`'s begin at `faces_base +
    /// (j - faces_first) * (k_site + FACE_SUMS_EXTRA)` (`clip::add_faces`).
    /// A whole-cell job answering a run of the sites it holds (a part's)
    /// sums the faces of that run only; 0 otherwise (every site's).
    pub faces_first: u32,
}

/// Push constants of the second pass (`refine`): the clipping
/// job's parameters and the site grid in the clipping frame.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct RefineParams {
    /// The clipping job.
    pub clip: ClipParams,
    /// The site grid (built on the quantized sites).
    pub grid: GridParams,
    /// Lower corner of grid cell (0, 0, 0) in the clipping frame.
    pub grid_lo_x: f32,
    /// See `grid_lo_x`.
    pub grid_lo_y: f32,
    /// See `grid_lo_x`.
    pub grid_lo_z: f32,
    /// Side of a grid cell in the clipping frame.
    pub cell_len: f32,
    /// The grid cells whose sites the job holds, `held_lo + 0..held_dim`
    /// on each axis (`grid` cell coordinates): the whole grid, or, for a
    /// part of a distributed job, a box around its tets. The site grid's
    /// arrays cover these cells only (x fastest); a walk that must search
    /// a cell outside gives up ([`crate::abi::OUT_OF_HALO`]).
    pub held_lo_x: u32,
    /// See `held_lo_x`.
    pub held_lo_y: u32,
    /// See `held_lo_x`.
    pub held_lo_z: u32,
    /// See `held_lo_x`.
    pub held_dim_x: u32,
    /// See `held_lo_x`.
    pub held_dim_y: u32,
    /// See `held_lo_x`.
    pub held_dim_z: u32,
    /// To a multiple of 16 bytes.
    pub _pad: [u32; 2],
}

/// The domain as the whole-cell strategy reads it (`whole.rs`): a
/// uniform grid of voxels over the mesh listing the tets whose bounding box
/// meets each voxel, and a bounding-volume hierarchy over the boundary's
/// triangles. Read from a one-record storage buffer.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct DomainParams {
    /// Lower corner of voxel (0, 0, 0) in the clipping frame.
    pub lo_x: f32,
    /// See `lo_x`.
    pub lo_y: f32,
    /// See `lo_x`.
    pub lo_z: f32,
    /// Side of a voxel.
    pub voxel_len: f32,
    /// Voxels along x.
    pub dim_x: u32,
    /// Voxels along y.
    pub dim_y: u32,
    /// Voxels along z.
    pub dim_z: u32,
    /// Nodes of the boundary's hierarchy (0: no boundary triangles).
    pub n_nodes: u32,
    /// A distance below which the boundary counts as touching a cell's
    /// ball whatever the rounding (absolute, in the frame).
    pub margin: f32,
    /// Which cells are integrated whole ([`domain_whole`]).
    pub whole: u32,
    /// To a multiple of 16 bytes.
    pub _pad: [u32; 2],
}

/// Which cells the whole-cell strategy integrates whole
/// ([`DomainParams::whole`]).
pub mod domain_whole {
    /// None: every cell goes through its tets (a density varies inside
    /// them).
    pub const NONE: u32 = 0;
    /// Those inside the domain (certified); the others go through the tets
    /// their box meets.
    pub const INSIDE: u32 = 1;
    /// Every cell: nothing bounds the cells but their neighbours (a
    /// periodic box, whose sites' images are the neighbours across its
    /// sides); the mesh only frames the job.
    pub const ALL: u32 = 2;
}

/// Per-iteration statistics of a Lloyd run (`i64` each), by index within
/// an iteration's block of [`lloyd_stat::COUNT`].
pub mod lloyd_stat {
    /// CVT energy `Σ ∫|x - x_i|²` of the diagram, in fixed point.
    pub const ENERGY: usize = 0;
    /// Sites whose clipped cell was empty (they stay where they are).
    pub const EMPTY: usize = 1;
    /// Entries the first pass left unfinished.
    pub const UNFINISHED: usize = 2;
    /// Entries still unfinished after the second pass (their volume is
    /// missing from that iteration).
    pub const STILL: usize = 3;
    /// Statistics per iteration.
    pub const COUNT: usize = 4;
}

/// Push constants of the site update of a Lloyd iteration.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct LloydParams {
    /// Number of sites.
    pub n_sites: u32,
    /// Fixed-point scale of the sums (see [`ClipParams::fixed_scale`]).
    pub fixed_scale: f32,
    /// Which iteration (its block of statistics).
    pub iteration: u32,
    /// Quantized units per unit of the clipping frame (a power of two).
    pub quant_scale: f32,
    /// The point of the clipping frame quantized to 0.
    pub quant_origin_x: f32,
    /// See `quant_origin_x`.
    pub quant_origin_y: f32,
    /// See `quant_origin_x`.
    pub quant_origin_z: f32,
    /// Padding to a 16-byte multiple.
    pub _pad: u32,
}
