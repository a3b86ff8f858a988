//! The clipping job: a validated, normalised clipped Voronoi computation
//! as every backend takes it ([`ClipJob`]), what a backend returns for it
//! ([`ClipOutput`]), the strategy and pairing it runs with, and the frame
//! it is normalised in ([`Frame`]).

use crate::geom::mesh::TetMesh;
use crate::geom::timing::Timings;
use crate::job::held::Held;
use crate::job::knn::{KnnJob, PackedLists};
use crate::job::BackendKind;
use cvd_kernels::abi::{ClipParams, KnnParams, QuantPoint, RefineParams, SplitPoint};

/// How tets and cells are intersected (paper section 6).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "clap", derive(clap::ValueEnum))]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub enum Strategy {
    /// Start from the tet, clip by bisectors (Algorithm 4).
    #[default]
    TetCell,
    /// Build each Voronoi cell, clip it by the tet's faces (Algorithms 1-2).
    CellTet,
}

impl Strategy {
    /// Its name on the command line and in files: `tet-cell`, `cell-tet`.
    pub fn name(self) -> &'static str {
        match self {
            Strategy::TetCell => "tet-cell",
            Strategy::CellTet => "cell-tet",
        }
    }
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
    /// For a part of a job (`backends::distributed`): the grid cells whose
    /// sites it holds (its quantized points are shifted by their corner);
    /// `None`: every site.
    pub held: Option<Held>,
}

impl ClipJob {
    /// Tet `t`'s centroid, quantized as the tets' k-NN queries it.
    pub fn tet_query(&self, t: usize) -> QuantPoint {
        let v = self.tets[t].map(|i| self.verts[i as usize].to_f64());
        let c = [0, 1, 2].map(|a| (v[0][a] + v[1][a] + v[2][a] + v[3][a]) / 4.0);
        let q = self.site_knn.quantizer.quantize(c, t as u32);
        match self.held {
            // Outside the held cells' corner: at it (not certified).
            Some(h) => {
                let s = h.shift();
                [q[0].saturating_sub(s[0]), q[1].saturating_sub(s[1]), q[2].saturating_sub(s[2]), q[3]]
            }
            None => q,
        }
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
            self.params.n_sites as usize * (self.params.k_site as usize + cvd_kernels::clip::FACE_SUMS_EXTRA)
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
    /// Parts the backend split the job into to stay under its memory
    /// budget (1: none).
    pub chunks: u64,
    /// Time per phase.
    pub timings: Timings,
}

/// The normalising map: `local = (world - origin) / scale`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frame {
    /// World position of the local origin.
    pub origin: [f64; 3],
    /// World length of one local unit (the mesh's longest side).
    pub scale: f64,
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
