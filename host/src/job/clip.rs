//! The clipping job: a validated, normalised clipped Voronoi computation
//! as every backend takes it ([`ClipJob`]), what a backend returns for it
//! ([`ClipOutput`]), the strategy and pairing it runs with, and the frame
//! it is normalised in ([`Frame`]).

use crate::geom::domain::DomainIndex;
use crate::geom::mesh::TetMesh;
use crate::geom::timing::Timings;
use crate::job::held::HeldCells;
use crate::job::knn::{KnnJob, PackedLists};
use crate::job::BackendKind;
use cvd_kernels::abi::{ClipParams, KnnParams, QuantPoint, RefineParams, SplitPoint};

/// How tets and cells are intersected: the paper's two strategies
/// (section 6), and whole cells.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub enum Strategy {
    /// Each site's cell built once; a cell whose ball lies inside the
    /// domain is integrated whole, and only the cells the boundary may cut
    /// are clipped by the tets they meet (`cvd_kernels::whole`).
    #[default]
    Whole,
    /// Start from the tet, clip by bisectors (Algorithm 4).
    TetCell,
    /// Build each Voronoi cell, clip it by the tet's faces (Algorithms 1-2).
    CellTet,
}

impl Strategy {
    /// Its name on the command line and in files: `whole`, `tet-cell`,
    /// `cell-tet`.
    pub fn name(self) -> &'static str {
        match self {
            Strategy::Whole => "whole",
            Strategy::TetCell => "tet-cell",
            Strategy::CellTet => "cell-tet",
        }
    }

    /// Every strategy, in the order of [`Self::name`]'s list.
    pub const ALL: [Strategy; 3] = [Strategy::Whole, Strategy::TetCell, Strategy::CellTet];

    /// The strategy named `name`, if any.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|s| s.name() == name)
    }

    /// The strategy a computation of that shape runs when none is asked
    /// for: whole cells (power cells too), but tet-cell where the tets
    /// outnumber the sites more than [`TETS_PER_SITE_FOR_WHOLE`] times
    /// (most cells are then cut, each by many tets, and tet-cell's flood
    /// builds those pieces faster: the paper's Joint with its 3 000 sites
    /// and 31 000 tets, 120 Lloyd iterations, 9.0 s against 15.4 s;
    /// docs/BENCHMARKS.md, "Which strategy by default"), under a density (linear in each tet, it needs every
    /// cell's pieces) and on Vulkan (where a thread per cell holds a whole
    /// cell, and a cut cell's thread loops over its tets while the others
    /// of its warp wait: not measured on a GPU here, so the paper's flood
    /// stays its default).
    pub fn auto(kind: BackendKind, shape: JobShape) -> Self {
        if shape.density || kind != BackendKind::Cpu || shape.tets > TETS_PER_SITE_FOR_WHOLE * shape.sites {
            Strategy::TetCell
        } else {
            Strategy::Whole
        }
    }
}

/// The most tets per site at which whole cells are the default on the CPU
/// ([`Strategy::auto`]): measured, whole cells win up to about 2 (fandisk,
/// 1.7 tets a site: 194 against 250 ms) and lose from about 4 (the joint
/// with 8 000 sites, 4.1: 176 against 163 ms; with 3 000, 10.9: 120
/// against 85 ms).
pub const TETS_PER_SITE_FOR_WHOLE: usize = 3;

/// What the strategy a computation runs by default depends on
/// ([`Strategy::auto`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct JobShape {
    /// Under a density (linear in each tet): every cell needs its pieces.
    pub density: bool,
    /// The sites (a periodic box's images included).
    pub sites: usize,
    /// The domain's tets (a periodic box: 6).
    pub tets: usize,
}

/// How tets are paired with the sites whose cells may meet them. Default:
/// flood for the tet-cell strategy, knn for cell-tet.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub enum Pairing {
    /// The k nearest sites of each tet's centroid (paper Eq. 6), the
    /// paper's heuristic. A site owning part of a tet but not among its k
    /// nearest would be missed: a tet with a piece bordering a site not
    /// paired with it (or whose pieces do not add up to it) gets its missing
    /// pieces from the host (counted in `missed_tets`).
    Knn,
    #[default]
    #[cfg_attr(feature = "clap", value(alias = "exact"))]
    /// From the site nearest the centroid, visit the sites whose bisectors
    /// are faces of the pieces found so far: exactly the sites that own
    /// part of the tet (tet-cell only).
    Flood,
}

impl Pairing {
    /// Its name on the command line and in files: `knn`, `flood`.
    pub fn name(self) -> &'static str {
        match self {
            Pairing::Knn => "knn",
            Pairing::Flood => "flood",
        }
    }
}

/// Neighbours per site used to build its cell (paper: 90): the default on
/// Vulkan, and for knn pairing and cell-tet.
pub const DEFAULT_K_SITE: usize = 90;

/// The default `k_site` of flood pairing on the CPU: a piece its list does
/// not settle walks the site grid, which on a CPU core costs only that
/// piece's time, so a shorter list (less k-NN work) pays (docs/BENCHMARKS.md:
/// 48 against 90 on joint_31k with 35k sites). On a GPU a walking thread
/// holds up its whole warp, and knn pairing sends such pieces to a second
/// pass: those keep [`DEFAULT_K_SITE`].
pub const DEFAULT_K_SITE_CPU_FLOOD: usize = 48;

/// The default `k_site` for a backend of `kind` (`Backend::kind`) and a
/// pairing.
pub fn default_k_site(kind: BackendKind, pairing: Pairing) -> usize {
    if kind == BackendKind::Cpu && pairing == Pairing::Flood {
        DEFAULT_K_SITE_CPU_FLOOD
    } else {
        DEFAULT_K_SITE
    }
}

/// The paper's Eq. (6): sites paired with each tet, from the ratio of
/// sites to tets (lambda 20, alpha 10, beta 8, gamma 7).
pub fn paper_k(n_sites: usize, n_tets: usize) -> usize {
    const LAMBDA: usize = 20;
    if n_sites < LAMBDA {
        return n_sites;
    }
    let ratio = n_sites as f64 / n_tets.max(1) as f64;
    let k = 10 * (8.0 * (7.0 * ratio + 1.0).log10()).ceil() as usize;
    k.max(LAMBDA)
}

/// A validated clipping job, normalised and ready for any backend.
#[derive(Clone, Debug)]
pub struct ClipJob {
    /// k nearest sites of each (unique) site.
    pub site_knn: KnnJob,
    /// k nearest sites of each tet centroid: the pairs. Its queries are
    /// left out (they would take 16 bytes a tet through the whole job):
    /// [`Self::tet_knn_job`] is the job with them.
    pub tet_knn: KnnJob,
    /// Unique sites, normalised, each as `hi + lo` (w: its power weight,
    /// shifted and scaled into the frame); with weights, each site's local
    /// weight bound after them (see [`ClipParams::weight_range`]).
    pub sites: Vec<SplitPoint>,
    /// Mesh vertices, normalised, each as `hi + lo`, the density (1
    /// without one) in `hi[3]`.
    pub verts: Vec<SplitPoint>,
    /// Tets.
    pub tets: Vec<[u32; 4]>,
    /// The mesh's index of each tet (they are in Morton order).
    pub tet_order: Vec<u32>,
    /// Kernel parameters.
    pub params: ClipParams,
    /// Parameters of the second pass (the site grid in the clipping frame;
    /// `capacity` is set by the backend).
    pub refine: RefineParams,
    /// Which strategy.
    pub strategy: Strategy,
    /// How tets and sites are paired.
    pub pairing: Pairing,
    /// Which faces of each tet lie on the mesh's boundary, as the kernels
    /// read them (`passes::faces::boundary_bits`; one word of zeros when
    /// no faces are summed).
    pub tet_faces: Vec<u32>,
    /// The whole-cell strategy's voxel grid over the tets and hierarchy
    /// over the boundary (`None` for the other strategies).
    pub domain: Option<std::sync::Arc<DomainIndex>>,
    /// For a part of a job (`backends::distributed`): the grid cells whose
    /// sites it holds (its quantized points are shifted by their corner);
    /// `None`: every site.
    pub held: Option<HeldCells>,
    /// Whole cells in a trajectory: the sites' lists to keep for the next
    /// frame, and the last frame's as candidates ([`crate::job::kept`]);
    /// `None`: nothing kept.
    pub keep: Option<crate::job::kept::Keep>,
    /// With faces: how many sites have face sums, from
    /// [`ClipParams::faces_first`] (a part's whole cells: the run it
    /// answers, not every site it holds).
    pub face_sites: u32,
    /// Whole cells on the CPU backend: of the answered sites, the only ones
    /// whose cells are built (job places, increasing; a part's cells built
    /// again with more sites held). Their lists, walks, pieces and sums are
    /// the bits of the job building every answered cell; the others' sums
    /// and faces stay zero. `None`: every answered site.
    pub only: Option<std::sync::Arc<[u32]>>,
}

impl ClipJob {
    /// Tet `t`'s centroid, quantized as the tets' k-NN queries it.
    pub fn tet_query(&self, t: usize) -> QuantPoint {
        let v = self.tets[t].map(|i| self.verts[i as usize].to_f64());
        let c = [0, 1, 2].map(|a| (v[0][a] + v[1][a] + v[2][a] + v[3][a]) / 4.0);
        let q = self.site_knn.quantizer.quantize(c, t as u32);
        // In the held cells' coordinates (a part's, or a window's: see
        // `RefineParams::held_lo_x`); outside their corner, at it (a part's
        // lists are not certified there).
        let s = HeldCells::of(&self.refine).shift();
        [q[0].saturating_sub(s[0]), q[1].saturating_sub(s[1]), q[2].saturating_sub(s[2]), q[3]]
    }

    /// The same whole-cell job building the cells of the answered sites
    /// `range` only (a share of its sites, `backends::distributed`): each
    /// of them gets the same list, walk, pieces and sums, to the bit, and
    /// the other sites' sums and faces stay zero. No lists are kept.
    pub fn answering(&self, range: std::ops::Range<usize>) -> crate::error::Result<Self> {
        let (lo, hi) = (self.params.own_lo as usize, self.params.own_hi as usize);
        let listed = (self.params.nbr_base as usize, self.params.nbr_end as usize);
        if self.strategy != Strategy::Whole || listed != (lo, hi) || range.start < lo || range.end > hi {
            return Err(crate::error::Error::Internal(format!(
                "sites {range:?} of a {:?} job answering {lo}..{hi}",
                self.strategy
            )));
        }
        let mut job = self.clone();
        job.params.own_lo = range.start as u32;
        job.params.own_hi = range.end as u32;
        job.params.nbr_base = range.start as u32;
        job.params.nbr_end = range.end as u32;
        job.refine.clip = job.params;
        job.site_knn = job.site_knn.answering(range);
        job.keep = None;
        Ok(job)
    }

    /// Whether the job holds a window of its grid's cells only (a part's:
    /// [`Self::held`], or [`crate::job::knn::KnnJob::windowed`]), or not
    /// every cell of its window (`KnnJob::unheld`).
    pub fn is_windowed(&self) -> bool {
        !HeldCells::of(&self.refine).is_whole() || self.site_knn.unheld.is_some()
    }

    /// The tets' k-NN job with its queries, every tet's centroid.
    pub fn tet_knn_job(&self) -> KnnJob {
        let queries: Vec<QuantPoint> = (0..self.tets.len()).map(|t| self.tet_query(t)).collect();
        KnnJob {
            params: KnnParams { n_queries: queries.len() as u32, ..self.tet_knn.params },
            queries: queries.into(),
            ..self.tet_knn.clone()
        }
    }

    /// How many face sums follow the tets' volumes (0: none).
    pub fn face_sums_len(&self) -> usize {
        if self.params.faces_base == 0 {
            0
        } else {
            self.face_sites as usize * (self.params.k_site as usize + cvd_kernels::clip::FACE_SUMS_EXTRA)
        }
    }
}

/// What a backend returns for a [`ClipJob`].
#[derive(Clone, Debug, Default)]
pub struct ClipOutput {
    /// Fixed-point sums, [`cvd_kernels::abi::ACCUM_PER_SITE`] per unique site.
    pub sums: Vec<i64>,
    /// Fixed-point volume of the pieces found in each tet (knn pairing;
    /// zero with flood pairing, whose certificate is in the kernel).
    pub tet_volumes: Vec<i64>,
    /// The face sums ([`ClipJob::face_sums_len`]; empty without faces).
    pub faces: Vec<i64>,
    /// With faces: every site's neighbour list as the kernels read it
    /// (`k_site` per site; empty if the backend did not keep them whole,
    /// and the host computes them again).
    pub site_lists: PackedLists,
    /// The kernels' counters (see `cvd_kernels::abi::counter`).
    pub counters: Vec<i64>,
    /// `(tet, site)` entries the kernels could not finish even in their
    /// second pass, sorted (`site == NO_SITE`: the whole tet).
    pub unfinished: Vec<[u32; 2]>,
    /// Entries of the first pass's unfinished list the kernels' second
    /// pass finished (and the host pass, when the backend ran it).
    pub refined: u64,
    /// Entries the backend's own host pass could not finish (see
    /// [`Counters::unresolved`]).
    pub unresolved: u64,
    /// A part of a job ([`ClipJob::held`]): the neighbour lists certified.
    pub certified: u64,
    /// The lists kept ([`ClipJob::keep`]; `None` where the backend keeps
    /// none).
    pub kept: Option<crate::job::kept::LocalKept>,
    /// Parts the backend split the job into to stay under its memory
    /// budget (1: none).
    pub chunks: u64,
    /// Time per phase.
    pub timings: Timings,
    /// Whole cells on the CPU backend, where the lists are kept
    /// ([`ClipJob::keep`]: a part's): each site's cell as the kernels'
    /// first pass counted it ([`cell_kind`]; what `Counters::whole_cells`
    /// and `cut_cells` add up), one per site; empty where the backend does
    /// not say.
    pub kinds: Vec<u8>,
}

/// A whole cell as the kernels' first pass counted it
/// ([`ClipOutput::kinds`]).
pub mod cell_kind {
    /// Not built, or not finished (counted neither way).
    pub const NONE: u8 = 0;
    /// Whole (`counter::WHOLE`).
    pub const WHOLE: u8 = 1;
    /// Cut by the domain's boundary (`counter::CUT`).
    pub const CUT: u8 = 2;
}

/// The kernels' one sums buffer cut into its parts: the sites' sums
/// (`n_site_sums`), the tets' volumes (`n_tets`) and the face sums (the
/// rest), without slack: the face sums keep the buffer itself (its head
/// moved out), the small parts are copied, so no part holds the whole
/// buffer's capacity.
pub fn split_sums(mut all: Vec<i64>, n_site_sums: usize, n_tets: usize) -> (Vec<i64>, Vec<i64>, Vec<i64>) {
    let (sums, tet_volumes) = (all[..n_site_sums].to_vec(), all[n_site_sums..n_site_sums + n_tets].to_vec());
    all.drain(..n_site_sums + n_tets);
    all.shrink_to_fit();
    (sums, tet_volumes, all)
}

/// The normalising map: `local = (world - origin) / scale`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frame {
    /// World position of the local origin.
    pub origin: [f64; 3],
    /// World length of one local unit (the mesh's longest side).
    pub scale: f64,
}

/// The box a whole cell is clipped from (Algorithm 1's box): `lo..hi`, the
/// mesh's and the sites' box in the local frame, a hundredth of its
/// diagonal (at least 10⁻⁵) wider on every side.
pub(crate) fn start_box(lo: [f64; 3], hi: [f64; 3]) -> ([f64; 3], [f64; 3]) {
    let diag = (0..3).map(|a| (hi[a] - lo[a]).powi(2)).sum::<f64>().sqrt();
    let margin = 0.01 * diag.max(1e-3);
    (lo.map(|x| x - margin), hi.map(|x| x + margin))
}

impl Frame {
    pub(crate) fn of(mesh: &TetMesh) -> Self {
        let (lo, hi) = mesh.bounding_box();
        let scale = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max);
        Self { origin: lo, scale: if scale > 0.0 { scale } else { 1.0 } }
    }

    pub(crate) fn to_local(self, p: [f64; 3]) -> [f64; 3] {
        [0, 1, 2].map(|a| (p[a] - self.origin[a]) / self.scale)
    }

    pub(crate) fn to_world(self, p: [f64; 3]) -> [f64; 3] {
        [0, 1, 2].map(|a| p[a] * self.scale + self.origin[a])
    }
}

/// The `(tet, site)` pairs of a device list (count, then pairs), sorted.
pub(crate) fn pair_list(raw: &[u32]) -> Vec<[u32; 2]> {
    let count = raw.first().copied().unwrap_or(0) as usize;
    let stored = count.min(raw.len().saturating_sub(1) / 2);
    let mut pairs: Vec<[u32; 2]> = (0..stored).map(|i| [raw[1 + 2 * i], raw[2 + 2 * i]]).collect();
    pairs.sort_unstable();
    pairs
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diagram::voronoi::ClippedVoronoi;
    use crate::job::sites::SiteMap;

    #[test]
    fn paper_k_follows_eq_6() {
        // k = max(20, 10 ceil(8 log10(7 n / tets + 1))).
        for (n, tets, k) in [
            (20, 1000, 20),     // 8 log10(1.14) = 0.46
            (1500, 10000, 30),  // 2.49
            (1000, 5000, 40),   // 3.04
            (1000, 1000, 80),   // 7.22
            (35000, 31000, 80), // 7.60
            (5000, 1000, 130),  // 12.45
            (20, 0, 180),       // no tets: counted as one
        ] {
            assert_eq!(paper_k(n, tets), k, "{n} sites, {tets} tets");
        }
    }

    #[test]
    fn paper_k_takes_every_site_below_twenty() {
        for n in 0..20 {
            assert_eq!(paper_k(n, 1), n);
            assert_eq!(paper_k(n, 1_000_000), n);
        }
        assert_eq!(paper_k(20, 1_000_000), 20, "at lambda: at least lambda");
        // More sites per tet never asks for fewer.
        let ks: Vec<usize> = (20..5000).step_by(7).map(|n| paper_k(n, 1000)).collect();
        assert!(ks.windows(2).all(|w| w[0] <= w[1]), "{ks:?}");
        assert!(ks.iter().all(|k| k % 10 == 0));
    }

    #[test]
    fn default_k_site_is_short_only_for_cpu_flood() {
        assert_eq!(default_k_site(BackendKind::Cpu, Pairing::Flood), DEFAULT_K_SITE_CPU_FLOOD);
        assert_eq!(default_k_site(BackendKind::Cpu, Pairing::Knn), DEFAULT_K_SITE);
        assert_eq!(default_k_site(BackendKind::Vulkan, Pairing::Flood), DEFAULT_K_SITE);
        assert_eq!(default_k_site(BackendKind::Vulkan, Pairing::Knn), DEFAULT_K_SITE);
        assert_eq!((DEFAULT_K_SITE, DEFAULT_K_SITE_CPU_FLOOD), (90, 48));
    }

    #[test]
    fn names_and_defaults() {
        assert_eq!((Strategy::TetCell.name(), Strategy::CellTet.name()), ("tet-cell", "cell-tet"));
        assert_eq!(Strategy::Whole.name(), "whole");
        for s in Strategy::ALL {
            assert_eq!(Strategy::from_name(s.name()), Some(s));
        }
        assert_eq!(Strategy::from_name("pieces"), None);
        assert_eq!((Pairing::Knn.name(), Pairing::Flood.name()), ("knn", "flood"));
        assert_eq!((Strategy::default(), Pairing::default()), (Strategy::Whole, Pairing::Flood));
        let shape = |density, sites, tets| JobShape { density, sites, tets };
        assert_eq!(Strategy::auto(BackendKind::Cpu, shape(false, 35_000, 30_000)), Strategy::Whole);
        assert_eq!(Strategy::auto(BackendKind::Cpu, shape(false, 6, 6)), Strategy::Whole);
        assert_eq!(
            Strategy::auto(BackendKind::Cpu, shape(false, 3_000, 31_000)),
            Strategy::TetCell,
            "many tets a site: most cells cut"
        );
        assert_eq!(Strategy::auto(BackendKind::Cpu, shape(false, 15_000, 26_000)), Strategy::Whole);
        assert_eq!(Strategy::auto(BackendKind::Cpu, shape(false, 10_000, 30_001)), Strategy::TetCell);
        assert_eq!(
            Strategy::auto(BackendKind::Cpu, shape(true, 35_000, 30_000)),
            Strategy::TetCell,
            "a density keeps the pieces"
        );
        assert_eq!(Strategy::auto(BackendKind::Vulkan, shape(false, 35_000, 30_000)), Strategy::TetCell);
    }

    #[test]
    fn the_frame_maps_the_box_onto_the_unit_box_and_back() {
        let mesh = TetMesh::grid([-2.0, 1.0, 3.0], [2.0, 2.0, 3.5], [2, 1, 1]);
        let f = Frame::of(&mesh);
        assert_eq!(f, Frame { origin: [-2.0, 1.0, 3.0], scale: 4.0 }, "origin lo, scale the longest side");
        assert_eq!(f.to_local([-2.0, 1.0, 3.0]), [0.0; 3]);
        assert_eq!(f.to_local([2.0, 2.0, 3.5]), [1.0, 0.25, 0.125]);
        assert_eq!(f.to_world([1.0, 0.25, 0.125]), [2.0, 2.0, 3.5]);
        // Any point, to within rounding of the scale.
        let f = Frame { origin: [-1.7, 0.3, 12.9], scale: 0.37 };
        for p in crate::geom::points::uniform(200, 3) {
            let w = p.map(|c| c * 10.0 - 5.0);
            let back = f.to_world(f.to_local(w));
            for a in 0..3 {
                assert!((back[a] - w[a]).abs() <= 4.0 * f64::EPSILON * (w[a].abs() + 13.0), "{w:?} -> {back:?}");
            }
            let local = f.to_local(w);
            let again = f.to_local(f.to_world(local));
            assert!((0..3).all(|a| (again[a] - local[a]).abs() <= 1e-13 * (1.0 + local[a].abs())));
        }
    }

    #[test]
    fn a_flat_mesh_has_scale_one() {
        let point = TetMesh { vertices: vec![[3.0, 4.0, 5.0]; 4], tets: vec![[0, 1, 2, 3]] };
        assert_eq!(Frame::of(&point), Frame { origin: [3.0, 4.0, 5.0], scale: 1.0 });
        // Flat along some axes: the longest side still scales.
        let flat =
            TetMesh { vertices: vec![[0.0; 3], [0.5, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]], tets: vec![] };
        assert_eq!(Frame::of(&flat).scale, 0.5);
    }

    #[test]
    fn pair_lists_are_read_sorted_and_never_past_the_buffer() {
        assert!(pair_list(&[]).is_empty());
        assert!(pair_list(&[0, 7, 7]).is_empty(), "a count of 0 ignores what follows");
        assert_eq!(pair_list(&[3, 5, 1, 2, 9, 2, 4]), vec![[2, 4], [2, 9], [5, 1]]);
        // The count says more than the buffer holds (the device list
        // overflowed): only the stored pairs, not a half pair.
        assert_eq!(pair_list(&[10, 4, 0, 1, 1, 8]), vec![[1, 1], [4, 0]]);
        assert!(pair_list(&[u32::MAX]).is_empty());
        // Fewer than stored: only the first `count`.
        assert_eq!(pair_list(&[1, 6, 6, 0, 0]), vec![[6, 6]]);
    }

    fn job(faces: bool, n: usize) -> (ClipJob, SiteMap) {
        let mesh = TetMesh::cube(2);
        let sites = crate::geom::points::uniform(n, 11);
        let (job, map, _) = ClippedVoronoi::new(&mesh, &sites).faces(faces).job().unwrap();
        (job, map)
    }

    #[test]
    fn face_sums_follow_the_sites_lists_only_with_faces() {
        let (plain, _) = job(false, 30);
        assert_eq!(plain.face_sums_len(), 0);
        let (with, _) = job(true, 30);
        let k = with.params.k_site as usize;
        assert_eq!(k, 29, "k_site clamped to the other sites");
        assert_eq!(with.face_sums_len(), 30 * (29 + cvd_kernels::clip::FACE_SUMS_EXTRA));
        assert_ne!(with.params.faces_base, 0);
    }

    #[test]
    fn tet_queries_are_the_centroids_quantized_shifted_for_a_part() {
        let (mut job, _) = job(false, 30);
        let all = job.tet_knn_job();
        assert_eq!(all.params.n_queries as usize, job.tets.len());
        assert_eq!(all.queries.len(), job.tets.len());
        assert_eq!(all.params.k, job.tet_knn.params.k);
        for t in 0..job.tets.len() {
            let v = job.tets[t].map(|i| job.verts[i as usize].to_f64());
            let c = [0, 1, 2].map(|a| (v[0][a] + v[1][a] + v[2][a] + v[3][a]) / 4.0);
            assert_eq!(all.queries[t], job.site_knn.quantizer.quantize(c, t as u32));
        }
        // A part whose box starts one cell in: shifted by a cell, at 0
        // below it.
        let g = job.site_knn.params.grid;
        let held = HeldCells::around([1, 1, 1], [1, 1, 1], 0, [g.dim_x, g.dim_y, g.dim_z], g.cell_size);
        job.held = Some(held);
        job.refine = held.in_refine(job.refine);
        let cs = g.cell_size;
        let (mut below, mut beyond) = (false, false);
        for t in 0..job.tets.len() {
            let q = all.queries[t];
            let s = [0, 1, 2].map(|a| q[a].saturating_sub(cs));
            assert_eq!(job.tet_query(t), [s[0], s[1], s[2], q[3]], "tet {t}");
            below |= q[0] < cs;
            beyond |= q[0] > cs;
        }
        assert!(below && beyond, "tets on both sides of the part's corner");
    }
}
