//! Clipped Voronoi diagrams: the library API and the job shared by the
//! backends.

use crate::backend::Backend;
use crate::backends::distributed::Distributed;
use crate::error::{Error, Result};
use crate::exec::TaskSink;
use crate::geom::domain::DomainIndex;
use crate::geom::mesh::TetMesh;
use crate::geom::points;
use crate::geom::timing::Timings;
use crate::job::clip::{default_k_site, paper_k, ClipJob, ClipOutput, Frame, JobShape, Pairing, Strategy};
use crate::job::kept::{Candidates, Keep, KeptLists, LocalKept, SiteCandidates};
use crate::job::knn::{KnnJob, KnnMethod};
use crate::job::sites::{Layout, SiteMap, Window};
use crate::job::BackendKind;
use crate::passes::pieces::{PieceCollector, Pieces};
use crate::passes::polyhedra::{merge_pieces, CellPolyhedron};
use cvd_kernels::abi::{counter, domain_whole, ClipParams, RefineParams, SplitPoint, ACCUM_PER_SITE, NO_SITE};
use cvd_kernels::clip::NoPieces;
use cvd_kernels::lists::NO_LIST;
use std::sync::Mutex;

/// Counters of a computation: nothing is lost without being counted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub struct Counters {
    /// Tet-site pairs tried.
    pub pairs: u64,
    /// Pairs with a non-empty piece.
    pub nonempty: u64,
    /// Pairs dropped by the half-space test before any clipping.
    pub filtered: u64,
    /// Clips that cut.
    pub clips: u64,
    /// Cells or pieces whose security radius was not reached within k_site.
    pub security_missed: u64,
    /// Polyhedra that ran out of capacity.
    pub overflows: u64,
    /// Polyhedra that broke down numerically.
    pub broken: u64,
    /// Pieces their k_site list did not settle, finished in place by a grid
    /// walk (flood pairing; not unfinished, not in the second pass).
    pub walks: u64,
    /// Pieces the kernels could not finish (any of the three above), all
    /// redone on the CPU with every neighbour needed and more capacity.
    pub second_pass: u64,
    /// Pieces not even the second pass could finish (0 unless a cell has
    /// more faces than a polyhedron holds); their volume is missing.
    pub unresolved: u64,
    /// Sites equal to a lower-indexed site (their cell is empty).
    pub duplicate_sites: u64,
    /// Other sites whose clipped cell is empty (outside the mesh, or
    /// crowded out of it).
    pub empty_cells: u64,
    /// Knn pairing: tets a site owning part of them was not paired with
    /// (a piece bordered it), whose missing pieces the host added.
    pub missed_tets: u64,
    /// With faces: sites whose faces made by sites beyond their list
    /// outnumbered their spill slots, redone by the host on the CPU.
    pub faces_redone: u64,
    /// A distributed run: tet floods that needed a site outside their
    /// part's halo, done again with a wider one (their first tries are in
    /// the other counters too).
    pub out_of_halo: u64,
    /// The whole-cell strategy: cells inside the domain, integrated whole
    /// (no tet).
    pub whole_cells: u64,
    /// The whole-cell strategy: cells the boundary may cut, clipped by the
    /// tets they meet.
    pub cut_cells: u64,
}

/// Per-site results and totals.
#[derive(Clone, Debug, Default)]
pub struct Cells {
    /// Volume of each clipped cell.
    pub volume: Vec<f64>,
    /// Centroid of each clipped cell (the site itself when empty).
    pub centroid: Vec<[f64; 3]>,
    /// `∫ |x - x_i|²` over each clipped cell.
    pub energy: Vec<f64>,
    /// Sum of the cells' volumes.
    pub total_volume: f64,
    /// The mesh's volume.
    pub mesh_volume: f64,
    /// `|total - mesh| / mesh`.
    pub e_vol: f64,
    /// How tets and cells were intersected.
    pub strategy: Strategy,
    /// How tets were paired with sites.
    pub pairing: Pairing,
    /// Sites paired with each tet (1 for flood: its starting site).
    pub k: usize,
    /// Neighbours per site.
    pub k_site: usize,
    /// Counters.
    pub counters: Counters,
    /// Parts the backend split the job into (see [`ClipOutput::chunks`]).
    pub chunks: u64,
    /// The site grid's cells the job's table held, and the whole grid's
    /// (fewer in a part that searched a window of the grid).
    pub grid_cells: [u64; 2],
    /// The tets the job held (a part of a mesh in parts: those its cells
    /// may meet), and the mesh's.
    pub tets: [u64; 2],
    /// Time per phase.
    pub timings: Timings,
    /// The cells' faces and neighbours, when asked for
    /// ([`ClippedVoronoi::faces`]).
    pub adjacency: Option<crate::passes::faces::Adjacency>,
    /// Each cell as one closed polyhedron, when asked for
    /// ([`ClippedVoronoi::compute_with_polyhedra`]).
    pub polyhedra: Option<Vec<CellPolyhedron>>,
    /// The neighbour lists kept for a trajectory's next frame (periodic
    /// boxes' whole cells on the CPU backend, when asked for).
    pub kept: Option<KeptLists>,
}

impl Cells {
    /// The clipped Voronoi adjacency (shared faces, their areas and
    /// normals; each cell's boundary area), when asked for
    /// ([`ClippedVoronoi::faces`]).
    pub fn adjacency(&self) -> Option<&crate::passes::faces::Adjacency> {
        self.adjacency.as_ref()
    }

    /// Each cell that has a volume as one closed polyhedron, in site
    /// order (see [`crate::passes::polyhedra`]), when asked for
    /// ([`ClippedVoronoi::compute_with_polyhedra`]).
    pub fn polyhedra(&self) -> Option<&[CellPolyhedron]> {
        self.polyhedra.as_deref()
    }

    /// The CVT energy `Σ_i ∫ |x - x_i|²`.
    pub fn energy_total(&self) -> f64 {
        crate::geom::exact_sum::ExactSum::of(&self.energy).value()
    }
}

/// Builder for a clipped Voronoi computation.
#[derive(Clone, Copy)]
pub struct ClippedVoronoi<'a> {
    pub(crate) mesh: &'a TetMesh,
    pub(crate) sites: &'a [[f64; 3]],
    pub(crate) strategy: Option<Strategy>,
    pub(crate) pairing: Option<Pairing>,
    pub(crate) k: Option<usize>,
    pub(crate) k_site: Option<usize>,
    pub(crate) backend: Option<&'a dyn Backend>,
    pub(crate) density: Option<&'a [f64]>,
    pub(crate) weights: Option<&'a [f64]>,
    pub(crate) faces: bool,
    /// With a density, the faces' masses `∫ρ dA` instead of their areas
    /// (optimal transport's Hessian; see `ClipParams::face_masses`).
    pub(crate) face_masses: bool,
    /// A periodic box's job ([`Self::images_after`]): the sites from this
    /// index on are images of the first ones.
    pub(crate) images_from: Option<usize>,
    /// Whole cells: each answered site's list of this many nearest sites
    /// kept ([`Cells::kept`]) for a trajectory's next frame.
    pub(crate) keep: Option<usize>,
    /// Whether the kept lists hold their entries, or only their distances
    /// ([`Self::keep_reach`]).
    pub(crate) keep_entries: bool,
    /// The last frame's kept lists, as candidates ([`crate::job::kept`]).
    pub(crate) candidates: Option<&'a Candidates<'a>>,
    /// Most bytes the job may hold ([`Self::memory_budget`]).
    pub(crate) memory_budget: Option<u64>,
    /// The sites' order, frame and answered ones, laid out by the caller
    /// ([`Layout`]).
    pub(crate) layout: Option<Layout<'a>>,
    /// With the sites in parts ([`Self::compute_in_parts`]): the parts each
    /// rank computes in turn ([`Self::parts_per_rank`]; none: chosen by the
    /// sites a rank owns).
    pub(crate) sub_parts: Option<usize>,
    /// In parts, the halos the sub-parts last took
    /// ([`crate::diagram::mesh_parts::Halos`]).
    pub(crate) halos: Option<&'a crate::diagram::mesh_parts::Halos>,
    /// The mesh prepared once for the jobs that share it ([`PreparedMesh`]).
    pub(crate) prepared: Option<&'a PreparedMesh>,
    /// In parts, where a rank keeps its rows' faces until they are read
    /// ([`Self::spill_rows_to`]; none: in memory).
    pub(crate) spill: Option<&'a std::path::Path>,
}

/// A mesh prepared once for the jobs that share it — the parts of a
/// diagram in parts, each a job of its own, and the diagrams that follow
/// one another in the optimisers: the Morton order of its tets, its
/// boundary and the whole-cell index over it, each built the first time
/// a job asks (the same as a job builds alone). What is cheap to make
/// again (the mesh in its frame, its tets in that order) each job makes,
/// so that the prepared mesh holds no second copy of it.
#[derive(Debug, Default)]
pub struct PreparedMesh {
    slot: std::sync::Mutex<Option<std::sync::Arc<Prepared>>>,
}

#[derive(Debug)]
struct Prepared {
    /// The mesh it was prepared from: its address and sizes.
    of: (usize, usize, usize),
    tet_order: Vec<u32>,
    unshared: std::sync::OnceLock<Vec<(u32, u8)>>,
    surface: std::sync::OnceLock<crate::geom::surface::TriSurface>,
    /// The whole-cell index, with what it was built for.
    domain: std::sync::Mutex<Option<(IndexFor, std::sync::Arc<DomainIndex>)>>,
}

/// What a whole-cell index was built for: the flag of
/// `DomainParams::whole`, and the density's address and length.
type IndexFor = (u32, usize, usize);

impl PreparedMesh {
    /// `mesh` prepared in `frame` (its own frame), kept for the next job.
    fn of(&self, mesh: &TetMesh, frame: Frame) -> std::sync::Arc<Prepared> {
        let of = (mesh as *const TetMesh as usize, mesh.tets.len(), mesh.vertices.len());
        let mut slot = self.slot.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(p) = slot.as_ref().filter(|p| p.of == of) {
            return p.clone();
        }
        *slot = None;
        let (tet_order, _) = in_frame(mesh, frame, None);
        let p = std::sync::Arc::new(Prepared {
            of,
            tet_order,
            unshared: Default::default(),
            surface: Default::default(),
            domain: Default::default(),
        });
        *slot = Some(p.clone());
        p
    }
}

/// The box (in the job's frame) of the held cells `held` of the grid of
/// `quantizer`, a cell wider on every side.
fn window_box(
    held: &crate::job::held::HeldCells,
    quantizer: &crate::geom::quantize::Quantizer,
) -> ([f64; 3], [f64; 3]) {
    let (origin, cell) = (quantizer.origin(), held.cell_size as f64 / quantizer.scale());
    let lo = [0, 1, 2].map(|a| origin[a] + (held.lo[a] as f64 - 1.0) * cell);
    let hi = [0, 1, 2].map(|a| origin[a] + ((held.lo[a] + held.dim[a]) as f64 + 1.0) * cell);
    (lo, hi)
}

/// The tets of `mesh` whose boxes meet the box `lo..hi`, in order; `None`
/// if that is every tet.
fn tets_meeting(mesh: &TetMesh, (lo, hi): ([f64; 3], [f64; 3])) -> Option<Vec<u32>> {
    let meets =
        |tet: &[u32; 4]| crate::geom::vec3::box_meets(tet.iter().map(|&v| &mesh.vertices[v as usize]), (lo, hi));
    use rayon::prelude::*;
    let kept: Vec<u32> =
        (0..mesh.tets.len() as u32).into_par_iter().filter(|&t| meets(&mesh.tets[t as usize])).collect();
    (kept.len() < mesh.tets.len()).then_some(kept)
}

/// `mesh` in `frame`, its tets in Morton order of their centroids (or in
/// `order`, that order found before), and the order.
fn in_frame(mesh: &TetMesh, frame: Frame, order: Option<&[u32]>) -> (Vec<u32>, TetMesh) {
    let verts: Vec<[f64; 3]> = mesh.vertices.iter().map(|&p| frame.to_local(p)).collect();
    let mut local_mesh = TetMesh { vertices: verts, tets: Vec::new() };
    let tet_order = match order {
        Some(order) => order.to_vec(),
        None => points::morton_order_by(mesh.tets.len(), |t| {
            crate::geom::mesh::centroid_of(&local_mesh.vertices, mesh.tets[t])
        }),
    };
    local_mesh.tets = tet_order.iter().map(|&t| mesh.tets[t as usize]).collect();
    (tet_order, local_mesh)
}

impl<'a> ClippedVoronoi<'a> {
    /// The clipped Voronoi diagram of `sites` in `mesh`.
    pub fn new(mesh: &'a TetMesh, sites: &'a [[f64; 3]]) -> Self {
        Self {
            mesh,
            sites,
            strategy: None,
            pairing: None,
            k: None,
            k_site: None,
            backend: None,
            density: None,
            weights: None,
            faces: false,
            face_masses: false,
            images_from: None,
            keep: None,
            keep_entries: false,
            candidates: None,
            memory_budget: None,
            layout: None,
            sub_parts: None,
            halos: None,
            prepared: None,
            spill: None,
        }
    }

    /// With the sites in parts ([`Self::compute_in_parts`]): each rank
    /// computes its sites in `n` parts, one after another: each part's job
    /// holds a share of them and its halo, so a rank's memory falls with
    /// `n`, and its time grows with the halos. By default
    /// [`crate::diagram::mesh_parts::auto_parts`]: 4, fewer where a part
    /// would own fewer than 16 384 sites.
    pub fn parts_per_rank(mut self, n: usize) -> Self {
        self.sub_parts = Some(n.max(1));
        self
    }

    /// With the sites in parts ([`Self::compute_in_parts_by_rows`]): each
    /// rank keeps the faces of the rows it receives in a file of its own in
    /// `dir` until they are read, not in memory (with faces, about 640
    /// bytes a row: the most a rank holds beside one part's job). The file
    /// is unlinked as soon as it is made, so nothing is left behind; its
    /// pages are the system's to write out and drop. The cells are the
    /// same bits either way.
    pub fn spill_rows_to(mut self, dir: &'a std::path::Path) -> Self {
        self.spill = Some(dir);
        self
    }

    /// Jobs that take their mesh's preparation from `prepared` (built by
    /// the first that asks: [`PreparedMesh`]).
    pub(crate) fn prepared(mut self, prepared: &'a PreparedMesh) -> Self {
        self.prepared = Some(prepared);
        self
    }

    /// Whole cells laid out by the caller ([`Layout`]): the sites in its
    /// order, the frame from its bounds, cells for its answered sites only.
    pub(crate) fn layout(mut self, layout: Layout<'a>) -> Self {
        self.layout = Some(layout);
        self
    }

    /// Most memory the job may hold, in bytes: a job whose estimate
    /// ([`crate::job::memory::JobSize`]) exceeds it is refused before
    /// anything is allocated ([`Error::TooLarge`]). Default: the memory
    /// the machine has available.
    pub fn memory_budget(mut self, bytes: impl Into<Option<u64>>) -> Self {
        self.memory_budget = bytes.into();
        self
    }

    /// Whole cells: keeps each answered site's `k` nearest sites (at least
    /// `k_site`) and the distance within which they are all the sites
    /// ([`Cells::kept`]), for the next frame of a trajectory
    /// ([`crate::job::kept`]); the CPU backend keeps them, others none.
    pub(crate) fn keep_lists(mut self, k: Option<usize>) -> Self {
        (self.keep, self.keep_entries) = (k, true);
        self
    }

    /// [`Self::keep_lists`] without the lists' entries: each answered
    /// site's `k`-th distance and reach only ([`KeptLists::kth`],
    /// [`KeptLists::reach`]), what a part certifies its lists by.
    pub(crate) fn keep_reach(mut self, k: usize) -> Self {
        (self.keep, self.keep_entries) = (Some(k), false);
        self
    }

    /// Each answered site's candidate neighbours, from the last frame's
    /// kept lists: where they certify its list, no grid is searched.
    pub(crate) fn candidates(mut self, candidates: Option<&'a Candidates<'a>>) -> Self {
        self.candidates = candidates;
        self
    }

    /// A periodic box's cells (see `crate::diagram::periodic`): the sites
    /// from index `n` on are images of the first `n`, moved across the
    /// box's sides. Under whole cells only the first `n` get cells, each
    /// whole among its neighbours and their images, and the mesh (the box)
    /// cuts none; the images' cells stay empty. The other strategies clip
    /// every site's cell, images included, to the box.
    pub(crate) fn images_after(mut self, n: usize) -> Self {
        self.images_from = Some(n);
        self
    }

    /// Also sums each cell's faces: the sites it shares a face with, each
    /// face's area and normal, and its area on the domain's boundary
    /// ([`Cells::adjacency`]).
    pub fn faces(mut self, on: bool) -> Self {
        self.faces = on;
        self
    }

    /// Whole cells, tet-cell or cell-tet (default: [`Strategy::auto`] for
    /// the backend and density).
    pub fn strategy(mut self, strategy: impl Into<Option<Strategy>>) -> Self {
        self.strategy = strategy.into();
        self
    }

    /// The sites that get cells: the first ones, of a periodic box's
    /// images under whole cells ([`Self::images_after`]); else all.
    fn answered(&self) -> usize {
        match self.images_from {
            Some(n) if self.resolved_strategy() == Strategy::Whole => n,
            _ => self.sites.len(),
        }
    }

    /// The strategy this computation runs.
    pub fn resolved_strategy(&self) -> Strategy {
        let shape = JobShape { density: self.density.is_some(), sites: self.sites.len(), tets: self.mesh.tets.len() };
        Self::strategy_for(self.strategy, self.backend, shape)
    }

    /// The strategy `asked` for, else the backend's default for a job of
    /// that shape ([`Strategy::auto`]).
    pub(crate) fn strategy_for(asked: Option<Strategy>, backend: Option<&dyn Backend>, shape: JobShape) -> Strategy {
        asked.unwrap_or_else(|| backend.map_or(Strategy::auto(BackendKind::Cpu, shape), |b| b.default_strategy(shape)))
    }

    /// k-nearest or flood pairing (default: flood for tet-cell, knn for
    /// cell-tet).
    pub fn pairing(mut self, pairing: Pairing) -> Self {
        self.pairing = Some(pairing);
        self
    }

    fn resolved_pairing(&self) -> Pairing {
        self.pairing.unwrap_or(match self.resolved_strategy() {
            // Whole cells pair no tets: flood's single list, unused.
            Strategy::TetCell | Strategy::Whole => Pairing::Flood,
            Strategy::CellTet => Pairing::Knn,
        })
    }

    /// Sites paired with each tet (default: the paper's Eq. 6).
    pub fn k(mut self, k: Option<usize>) -> Self {
        self.k = k;
        self
    }

    /// Neighbours per site for its cell (default: [`default_k_site`]).
    pub fn k_site(mut self, k_site: impl Into<Option<usize>>) -> Self {
        self.k_site = k_site.into();
        self
    }

    /// The `k_site` this computation uses.
    pub fn resolved_k_site(&self) -> usize {
        let kind = self.backend.map_or(BackendKind::Cpu, |b| b.kind());
        self.k_site.unwrap_or_else(|| default_k_site(kind, self.resolved_pairing()))
    }

    /// A density `ρ > 0` per mesh vertex, linear inside each tet (default:
    /// 1). Volumes, centroids and energies become ρ-weighted: `volume` is
    /// the cell's mass `∫ρ`, `centroid` its centre of mass, `energy`
    /// `∫ρ|x - x_i|²`, and `mesh_volume` the mesh's mass.
    pub fn density(mut self, density: Option<&'a [f64]>) -> Self {
        self.density = density;
        self
    }

    /// Power (Laguerre) cells: a weight `w_i` per site, in squared units of
    /// length; site `i`'s cell is `{x : |x - x_i|² - w_i <= |x - x_j|² -
    /// w_j for all j}`, clipped to the mesh as before. A cell may be empty
    /// (counted in `empty_cells`, its centroid the site) or not hold its
    /// site. Adding a constant to every weight changes nothing; equal sites
    /// go to the larger weight (the lower index on a tie). Without weights
    /// (or all equal): the Voronoi cells.
    pub fn weights(mut self, weights: &'a [f64]) -> Self {
        self.weights = Some(weights);
        self
    }

    /// Where to run (default: the CPU backend with all cores).
    pub fn backend(mut self, backend: &'a dyn Backend) -> Self {
        self.backend = Some(backend);
        self
    }

    /// Validates and normalises the input into a job, with the map from
    /// each input site to its unique site (`None` for a duplicate).
    pub fn job(&self) -> Result<(ClipJob, SiteMap, Frame)> {
        let mesh = self.mesh;
        if mesh.tets.is_empty() {
            return Err(Error::InvalidInput("the mesh has no tets".into()));
        }
        crate::job::sites::check_sites(self.sites, self.weights)?;
        let pairing = self.resolved_pairing();
        let strategy = self.resolved_strategy();
        if pairing == Pairing::Flood && strategy == Strategy::CellTet {
            return Err(Error::InvalidInput("flood pairing works with the tet-cell strategy only".into()));
        }
        if pairing == Pairing::Knn && strategy == Strategy::Whole {
            return Err(Error::InvalidInput(
                "the whole-cell strategy pairs no tets: knn pairing does not apply".into(),
            ));
        }
        if let Some(rho) = self.density {
            if rho.len() != mesh.vertices.len() {
                return Err(Error::InvalidInput(format!(
                    "{} density values for {} mesh vertices",
                    rho.len(),
                    mesh.vertices.len()
                )));
            }
            if let Some(v) = rho.iter().position(|r| !(r.is_finite() && *r > 0.0)) {
                return Err(Error::InvalidInput(format!(
                    "the density at vertex {v} is {}; it must be positive",
                    rho[v]
                )));
            }
        }
        if self.k_site == Some(0) || self.k == Some(0) {
            return Err(Error::InvalidInput("k and k_site must be at least 1".into()));
        }
        let size = crate::job::memory::JobSize {
            sites: self.sites.len() as u64,
            tets: mesh.tets.len() as u64,
            k_site: self.resolved_k_site() as u64,
            faces: self.faces,
        };
        let what = format!("the diagram of {} sites in {} tets", self.sites.len(), mesh.tets.len());
        crate::job::memory::check(&what, size.bytes(), self.memory_budget)?;
        // Duplicates: the largest weight owns the cell, the lowest index on
        // a tie (without weights: the lowest index). Sites and tets go to
        // the kernels in Morton order, for locality; the map sends each
        // input site to its place in that order.
        let weight = |i: usize| self.weights.map_or(0.0, |w| w[i]);
        // Periodic whole cells: the sites answered for come first.
        let (inputs, map, own) = match &self.layout {
            Some(layout) => {
                if strategy != Strategy::Whole {
                    return Err(Error::Internal("a job laid out by its caller runs whole cells".into()));
                }
                crate::job::sites::unique_in_order(self.sites, self.weights, layout)?
            }
            None => {
                let answered = self.answered();
                let (inputs, map) = crate::job::sites::unique_in_morton_order(self.sites, self.weights, answered);
                let own = inputs.iter().filter(|&&i| (i as usize) < answered).count();
                (inputs, map, 0..own)
            }
        };
        // The places whose cells are built, if not all: in the job's order.
        let only = match self.layout.and_then(|l| l.only.map(|o| (l.order, o))) {
            Some((order, places)) => {
                let mut built = Vec::with_capacity(places.len());
                for &p in places {
                    let input = order
                        .get(p as usize)
                        .ok_or_else(|| Error::Internal(format!("place {p} built beyond the layout")))?;
                    if let Some(u) = map.get(*input as usize) {
                        if !own.contains(&u) || built.last().is_some_and(|&l| l >= u as u32) {
                            return Err(Error::Internal(format!("place {p} built out of order or not answered")));
                        }
                        built.push(u as u32);
                    }
                }
                Some(std::sync::Arc::from(built))
            }
            None => None,
        };

        let frame = Frame::of(mesh);
        let sites: Vec<[f64; 3]> = inputs.iter().map(|&i| frame.to_local(self.sites[i as usize])).collect();
        // Weights in the frame's squared units, shifted so that the
        // smallest is 0 (a constant changes no cell): all in 0..=range.
        let span = self.layout.as_ref().and_then(|l| l.weights);
        let w_min = match span {
            Some([lo, _]) => lo,
            None => inputs.iter().map(|&i| weight(i as usize)).fold(f64::INFINITY, f64::min),
        };
        let local_weight = |u: usize| (weight(inputs[u] as usize) - w_min) / (frame.scale * frame.scale);
        // (x - w_min) / s² grows with x: the largest weight's is the largest.
        let weight_range = match span {
            Some([_, hi]) => ((hi - w_min) / (frame.scale * frame.scale)).max(0.0),
            None => (0..inputs.len()).map(local_weight).fold(0.0, f64::max),
        };
        if !weight_range.is_finite() || weight_range > 1e30 {
            return Err(Error::InvalidInput(format!(
                "the weights span {:e}, too wide for the domain's size {:e}",
                weight_range * frame.scale * frame.scale,
                frame.scale
            )));
        }
        let mut split: Vec<SplitPoint> =
            sites.iter().enumerate().map(|(u, &p)| SplitPoint::site(p, local_weight(u))).collect();
        crate::job::sites::check_separable(&split, self.sites, &inputs)?;
        if weight_range > 0.0 {
            // Each site's local weight bound, after the sites.
            let volume = mesh.volume() / frame.scale.powi(3);
            let bounds = match self.layout.and_then(|l| l.weight_grid) {
                Some(grid) => grid.bounds(&split, weight_range),
                None => crate::job::weight_bounds::local_bounds(&split, weight_range, volume),
            };
            split.extend(bounds);
        }
        // The mesh in its frame, its tets in Morton order (prepared once
        // for the jobs that share it, or here).
        let prepared = self.prepared.map(|p| p.of(mesh, frame));
        let (tet_order, local_mesh) = in_frame(mesh, frame, prepared.as_ref().map(|p| &p.tet_order[..]));
        // The frame's points: the mesh, and a layout's bounds (the sites lie
        // inside them).
        let mut frame_points = local_mesh.vertices.clone();
        if let Some(l) = &self.layout {
            let (lo, hi) = (frame.to_local(l.lo), frame.to_local(l.hi));
            frame_points.extend((0..8).map(|c| [0, 1, 2].map(|a| if c >> a & 1 == 0 { lo[a] } else { hi[a] })));
        }
        let n = sites.len();
        let k = match pairing {
            Pairing::Knn => self.k.unwrap_or_else(|| paper_k(n, mesh.tets.len())).min(n),
            Pairing::Flood => 1,
        };
        // One frame and grid for both k-NN jobs, covering the mesh: sites
        // that move (Lloyd) stay inside it.
        let mut site_knn = KnnJob::sites_in_frame(&sites, &frame_points, self.resolved_k_site(), KnnMethod::Grid)?;
        // Whole cells are built for the sites answered for alone (a
        // periodic box's images get none): only their lists are needed.
        let listed = if strategy == Strategy::Whole { own.clone() } else { 0..n };
        if let Some(l) = &self.layout {
            site_knn = site_knn.with_grid_for(&frame_points, l.grid_sites);
        }
        // A part searches the window of the whole grid around its sites
        // (a cell more on every side for the walks' margins).
        let grid = site_knn.params.grid;
        let window = match self.layout.map(|l| l.window) {
            Some(Window::Around) => {
                let (job, window) = site_knn.windowed(2);
                site_knn = job;
                window
            }
            Some(Window::Held(held)) => {
                site_knn = site_knn.windowed_to(held)?;
                site_knn.unheld = self.layout.and_then(|l| l.unheld).map(std::sync::Arc::from);
                Some(held)
            }
            _ => None,
        };
        site_knn = site_knn.answering(listed.clone());
        if self.candidates.is_some() && listed.start > 0 {
            return Err(Error::Internal("candidates are taken for the first sites only".into()));
        }
        let keep = self.keep.filter(|_| strategy == Strategy::Whole).map(|kk| Keep {
            entries: self.keep_entries,
            k: kk.max(site_knn.params.k as usize).min(n.saturating_sub(1)) as u32,
            candidates: self.candidates.map(|c| local_candidates(c, &inputs, listed.end, &map, &site_knn, frame.scale)),
        });
        drop(inputs);
        // Its queries come when it runs (ClipJob::tet_knn_job).
        let mut tet_knn = KnnJob::points_like(&site_knn, &[], k)?;
        tet_knn.unheld = site_knn.unheld.clone();
        if local_mesh.tets.len().checked_mul(k).is_none_or(|n| n > u32::MAX as usize) {
            return Err(Error::InvalidInput(format!(
                "{} tets x k = {k} sites do not fit one buffer",
                local_mesh.tets.len()
            )));
        }

        // Box for Algorithm 1 (mesh and sites, with a margin).
        let (lo, hi) = match &self.layout {
            Some(_) => crate::geom::vec3::bounding_box(frame_points.iter()),
            None => crate::geom::vec3::bounding_box(sites.iter().chain(&local_mesh.vertices)),
        };
        let diag = (0..3).map(|a| (hi[a] - lo[a]).powi(2)).sum::<f64>().sqrt();
        let (box_lo, box_hi) = crate::job::clip::start_box(lo, hi);
        // Per-site sums, and their total over all sites, are at most (mesh
        // volume <= 1) x 3 (1 + diag)² x the largest density: the largest
        // power-of-two scale that keeps them inside i64 with a bit to spare
        // (about 2^56: a cell of 1e-9 of the frame gets 7e7 units, and each
        // piece is rounded to one, so its volume keeps 1e-6 relative).
        let rho_max = self.density.map_or(1.0, |rho| rho.iter().fold(1.0, |a: f64, &b| a.max(b)));
        let bound = 3.0 * (1.0 + diag).powi(2) * rho_max;
        let bits = 61.0 - bound.log2().ceil();
        // Faces: after the sites' sums and the tets' volumes; a slot holds
        // at most a cell's surface (inside the unit box: 6) plus the
        // mesh's boundary area.
        // The mesh's boundary, found once for the faces' bits, its area and
        // the domain's index.
        let (unshared, surface) = (std::sync::OnceLock::new(), std::sync::OnceLock::new());
        let (unshared, surface) = match &prepared {
            Some(p) => (&p.unshared, &p.surface),
            None => (&unshared, &surface),
        };
        let unshared = || unshared.get_or_init(|| local_mesh.unshared_faces());
        let surface = || surface.get_or_init(|| local_mesh.boundary_of(unshared()));
        // A part of a mesh's diagram in parts (a window of held cells of the
        // whole grid) holds only the tets its cells may meet, and the
        // boundary's triangles there (`part_box`, see below).
        let part_box = match (strategy, window, self.layout) {
            (Strategy::Whole, Some(held), Some(l)) if !l.periodic && matches!(l.window, Window::Held(_)) => {
                Some(window_box(&held, &site_knn.quantizer))
            }
            _ => None,
        };
        let part_tets = part_box.and_then(|b| tets_meeting(&local_mesh, b));
        let (tet_faces, faces_base, area_bits) = if self.faces {
            let bits = crate::passes::faces::boundary_bits_of(local_mesh.tets.len(), unshared());
            let boundary: f64 = surface().area();
            // Masses: areas times at most the largest density.
            let rho = if self.face_masses { rho_max } else { 1.0 };
            let n_tets = part_tets.as_ref().map_or(local_mesh.tets.len(), Vec::len);
            (bits, (n * ACCUM_PER_SITE + n_tets) as u32, 61.0 - ((8.0 + boundary) * rho).log2().ceil())
        } else if strategy == Strategy::Whole {
            // Whole cells' pieces read the mesh's boundary here (a part's
            // tets have a boundary of their own; the kernels read it with
            // faces only).
            (crate::passes::faces::boundary_bits_of(local_mesh.tets.len(), unshared()), 0, 0.0)
        } else {
            (vec![0], 0, 0.0)
        };
        let params = ClipParams {
            n_sites: n as u32,
            n_tets: part_tets.as_ref().map_or(mesh.tets.len(), Vec::len) as u32,
            k_site: site_knn.params.k,
            k_tet: tet_knn.params.k,
            fixed_scale: bits.exp2() as f32,
            tet_base: 0,
            nbr_base: listed.start as u32,
            nbr_end: listed.end as u32,
            own_lo: own.start as u32,
            own_hi: own.end as u32,
            box_lo_x: box_lo[0] as f32,
            box_lo_y: box_lo[1] as f32,
            box_lo_z: box_lo[2] as f32,
            box_hi_x: box_hi[0] as f32,
            box_hi_y: box_hi[1] as f32,
            box_hi_z: box_hi[2] as f32,
            faces_base,
            area_scale: if self.faces { area_bits.exp2() as f32 } else { 0.0 },
            // A site lies within a few quantization steps of its cell, plus
            // f32 rounding of coordinates of order 1.
            walk_margin: (4.0 / site_knn.quantizer.scale() + 1e-6) as f32,
            capacity: 0,
            // Rounded up: the security radius must not shrink.
            weight_range: if weight_range > 0.0 { next_up(weight_range as f32) } else { 0.0 },
            face_masses: (self.face_masses && self.density.is_some()) as u32,
            // Plain lists; a backend that packs its lists says so.
            list_bits: 32,
            // The listed sites sum faces: a whole-cell job's answered run
            // (each cell its own; the sites a part holds around them build
            // no cell), else every site.
            faces_first: listed.start as u32,
        };
        let q = &site_knn.quantizer;
        let lo = q.origin();
        // The window's cells, or every cell.
        let held = window.unwrap_or_else(|| crate::job::held::HeldCells::whole(&grid));
        let refine = held.in_refine(RefineParams {
            clip: params,
            grid,
            grid_lo_x: lo[0] as f32,
            grid_lo_y: lo[1] as f32,
            grid_lo_z: lo[2] as f32,
            cell_len: (grid.cell_size as f64 / q.scale()) as f32,
            ..Default::default()
        });
        let verts: Vec<SplitPoint> = local_mesh
            .vertices
            .iter()
            .enumerate()
            .map(|(v, &p)| SplitPoint::new(p, self.density.map_or(1.0, |rho| rho[v] as f32)))
            .collect();
        let periodic = self.layout.filter(|l| l.periodic).map(|_| 0);
        let whole = match (self.density, self.images_from.or(periodic)) {
            (Some(_), _) => domain_whole::NONE,
            (None, Some(_)) => domain_whole::ALL,
            (None, None) => domain_whole::INSIDE,
        };
        // A part's tets, boundary bits and index: the whole mesh's, of
        // those tets (in the same order, on the whole mesh's voxel grid),
        // and of the boundary's triangles whose boxes meet the part's.
        let (tets, tet_order, tet_faces, domain) = match (&part_tets, part_box) {
            (Some(kept), Some(b)) => {
                let tets: Vec<[u32; 4]> = kept.iter().map(|&t| local_mesh.tets[t as usize]).collect();
                let order: Vec<u32> = kept.iter().map(|&t| tet_order[t as usize]).collect();
                let tet_faces = crate::passes::faces::boundary_bits_among(&tet_faces, kept);
                let grid = DomainIndex::grid_of(&local_mesh, whole);
                let boundary = (whole == domain_whole::INSIDE).then(|| surface().meeting(b.0, b.1));
                let part = TetMesh { vertices: local_mesh.vertices, tets };
                let domain = std::sync::Arc::new(DomainIndex::over(&part, &verts, grid, boundary.as_ref()));
                (part.tets, order, tet_faces, Some(domain))
            }
            _ => {
                let domain = (strategy == Strategy::Whole).then(|| {
                    let boundary = (whole == domain_whole::INSIDE).then(surface);
                    let build = || std::sync::Arc::new(DomainIndex::new(&local_mesh, &verts, whole, boundary));
                    let Some(p) = &prepared else { return build() };
                    let density = self.density.map_or((0, 0), |d| (d.as_ptr() as usize, d.len()));
                    let mut domain = p.domain.lock().unwrap_or_else(|e| e.into_inner());
                    match domain.as_ref().filter(|d| d.0 == (whole, density.0, density.1)) {
                        Some(d) => d.1.clone(),
                        None => domain.insert(((whole, density.0, density.1), build())).1.clone(),
                    }
                });
                (local_mesh.tets, tet_order, tet_faces, domain)
            }
        };
        let job = ClipJob {
            refine,
            site_knn,
            tet_knn,
            sites: split,
            // The density rides in each vertex record's w.
            verts,
            tets,
            tet_order,
            params,
            strategy,
            domain,
            pairing,
            tet_faces,
            held: None,
            keep,
            face_sites: listed.len() as u32,
            only,
        };
        Ok((job, map, frame))
    }

    /// Computes the clipped cells.
    pub fn compute(&self) -> Result<Cells> {
        let (job, map, frame, job_s) = self.timed_job()?;
        let cpu;
        let backend = match self.backend {
            Some(b) => b,
            None => {
                cpu = crate::exec::CpuBackend::new(None)?;
                &cpu
            }
        };
        let mut out = backend.clip(&job)?;
        out.timings.phases.insert(0, ("job".into(), job_s));
        self.finish_job(&job, &map, &frame, out, &Mutex::new(Vec::<NoPieces>::new()))
    }

    /// The job ([`Self::job`]) and the seconds it took to build.
    fn timed_job(&self) -> Result<(ClipJob, SiteMap, Frame, f64)> {
        let (job, t) = crate::geom::timing::timed(|| self.job());
        let (job, map, frame) = job?;
        Ok((job, map, frame, t))
    }

    /// Computes the clipped cells on the CPU backend `cpu` (whatever
    /// [`Self::backend`] says) and also returns every non-empty piece — a
    /// site's cell inside one tet — numbered by site and tet, each given in
    /// world coordinates on request ([`Pieces::get`]). The cells are those
    /// [`Self::compute`] returns on `cpu`.
    pub fn compute_with_pieces(&self, cpu: &crate::exec::CpuBackend) -> Result<(Cells, Pieces)> {
        self.with_pieces(|job, sinks| Ok((cpu.clip_into(job, sinks)?, None)))
    }

    /// The cells, and the pieces `clip` hands its sinks (of the sites at
    /// the places it says, or all), in world coordinates.
    fn with_pieces(
        &self,
        clip: impl FnOnce(&ClipJob, &Mutex<Vec<PieceCollector>>) -> Result<(ClipOutput, Option<std::ops::Range<usize>>)>,
    ) -> Result<(Cells, Pieces)> {
        let (job, map, frame, job_s) = self.timed_job()?;
        let sinks = Mutex::new(Vec::new());
        let (mut out, only) = clip(&job, &sinks)?;
        out.timings.phases.insert(0, ("job".into(), job_s));
        let cells = self.finish_job(&job, &map, &frame, out, &sinks)?;
        let collected = sinks.into_inner().unwrap_or_else(|e| e.into_inner());
        Ok((cells, crate::passes::pieces::to_world(collected, &job, &map, &frame, self.sites, only)))
    }

    /// `cells` with the polyhedra merged from `pieces`.
    fn with_polyhedra((mut cells, pieces): (Cells, Pieces)) -> (Cells, Pieces) {
        let (polyhedra, t) = crate::geom::timing::timed(|| merge_pieces(&pieces));
        cells.polyhedra = Some(polyhedra);
        cells.timings.push("polyhedra", t);
        (cells, pieces)
    }

    /// Whole cells over the ranks of `parts` ([`Distributed`]), as
    /// [`Self::compute`] on it gives them (every site's, on every rank),
    /// with the polyhedra ([`Cells::polyhedra`]) and pieces of the cells
    /// this rank built (by site): together, the ranks' are those of
    /// [`Self::compute_with_polyhedra`] in one process, each once.
    pub fn compute_with_geometry_in_parts(&self, parts: &Distributed) -> Result<(Cells, Pieces)> {
        let cv = ClippedVoronoi { backend: Some(parts), ..*self };
        if cv.resolved_strategy() != Strategy::Whole {
            return Err(Error::InvalidInput("the cells' polyhedra in parts come from whole cells".into()));
        }
        let built = cv.with_pieces(|job, sinks| Ok((parts.clip_whole_into(job, sinks)?, Some(parts.share(job)))))?;
        Ok(Self::with_polyhedra(built))
    }

    /// Computes the clipped cells on the CPU backend `cpu`, as
    /// [`Self::compute_with_pieces`], with each cell as one closed
    /// polyhedron ([`Cells::polyhedra`]): its pieces merged (a whole cell
    /// is one piece).
    pub fn compute_with_polyhedra(&self, cpu: &crate::exec::CpuBackend) -> Result<(Cells, Pieces)> {
        Ok(Self::with_polyhedra(self.compute_with_pieces(cpu)?))
    }

    /// The cells on the diagram's backend, each also as one closed
    /// polyhedron ([`Cells::polyhedra`]), and the pieces they were merged
    /// from. On the CPU backend (or none) they come from one run on `cpu`;
    /// another backend's pieces stay on its device, so its cells come with
    /// the polyhedra of a second run, without faces, on `cpu`.
    pub fn compute_with_geometry(&self, cpu: &crate::exec::CpuBackend) -> Result<(Cells, Pieces)> {
        if self.backend.is_none_or(|b| b.kind() == BackendKind::Cpu) {
            return self.compute_with_polyhedra(cpu);
        }
        let mut cells = self.compute()?;
        let (mut with, pieces) = self.faces(false).compute_with_polyhedra(cpu)?;
        cells.polyhedra = with.polyhedra.take();
        Ok((cells, pieces))
    }

    /// The second pass, then the per-site results.
    fn finish_job<S: TaskSink>(
        &self,
        job: &ClipJob,
        map: &SiteMap,
        frame: &Frame,
        mut out: ClipOutput,
        sinks: &Mutex<Vec<S>>,
    ) -> Result<Cells> {
        let (redone, t) = crate::geom::timing::timed(|| crate::passes::second_pass::run(job, &mut out, sinks));
        let redone = redone?;
        if redone.finished + redone.unresolved + redone.missed_tets > 0 {
            out.timings.push("host pass", t);
        }
        let (refined, out_unresolved) = (out.refined, out.unresolved);
        // A part's cells whose walks had to leave its window (job sites):
        // the part does them again with a wider halo.
        let mut left: Vec<u32> = if job.is_windowed() && out.counters.get(counter::HALO).is_some_and(|&h| h > 0) {
            // A whole cell's site, or a cut cell's (a piece of it in a
            // tet); not a tet's marks.
            let sites = job.params.n_sites;
            out.unfinished.iter().filter(|e| e[1] < sites).map(|e| e[1]).collect()
        } else {
            Vec::new()
        };
        let (adjacency, faces_redone, faces_left) = if job.face_sums_len() > 0 {
            // The face sums and lists go to the adjacency and are dropped
            // as soon as read.
            let (sums, lists) = (std::mem::take(&mut out.faces), std::mem::take(&mut out.site_lists));
            let (adjacency, t) = crate::geom::timing::timed(|| self.adjacency(job, map, frame, &out, sums, lists));
            out.timings.push("faces", t);
            let (adjacency, redone, faces_left) = adjacency?;
            left.extend(&faces_left);
            (Some(adjacency), redone, !faces_left.is_empty())
        } else {
            (None, 0, false)
        };
        let kept = out.kept.take().map(|kept| {
            let inputs = map.inputs(job.site_knn.sites.len());
            let mut left: Vec<u32> = left.iter().map(|&u| inputs[u as usize]).collect();
            left.sort_unstable();
            left.dedup();
            let listed = job.params.own_lo as usize..job.params.own_hi as usize;
            let kinds = out.kinds.get(listed).map(<[u8]>::to_vec).unwrap_or_default();
            KeptLists { left, kinds, ..kept_lists(kept, inputs, &job.site_knn, frame.scale, self.candidates) }
        });
        let mut cells = finish(self.mesh, self.density, self.sites, job, map, frame, out);
        cells.adjacency = adjacency;
        cells.kept = kept;
        cells.counters.second_pass = refined + redone.finished;
        cells.counters.unresolved = redone.unresolved + out_unresolved;
        cells.counters.missed_tets = redone.missed_tets;
        cells.counters.faces_redone = faces_redone as u64;
        cells.counters.out_of_halo += u64::from(faces_left);
        Ok(cells)
    }
}

impl ClippedVoronoi<'_> {
    /// The adjacency from the kernels' face sums: each site's neighbour
    /// list again (the same exact k-NN, on the CPU), the slots read
    /// through it; the sites with faces outside their list get theirs from
    /// the kernels' bodies on the CPU.
    fn adjacency(
        &self,
        job: &ClipJob,
        map: &SiteMap,
        frame: &Frame,
        out: &ClipOutput,
        sums: Vec<i64>,
        lists: crate::job::knn::PackedLists,
    ) -> Result<(crate::passes::faces::Adjacency, usize, Vec<u32>)> {
        let k = job.params.k_site as usize;
        let n = job.params.n_sites;
        let mut cpu = None;
        let (base, listed) = (job.site_knn.params.query_base, job.site_knn.params.n_queries as usize);
        let lists = if lists.k as usize == k && lists.view(base).slot(base as usize + listed - 1) != NO_LIST {
            lists
        } else {
            drop(lists);
            let c = cpu.insert(crate::exec::CpuBackend::new(None)?);
            c.packed_lists(&job.site_knn, cvd_kernels::lists::width(n))?
        };
        let summed = (job.params.faces_first as usize, n as usize);
        let halves = self.layout.is_some_and(|l| l.halves);
        let (mut faces, incomplete) =
            crate::passes::faces::from_sums(sums, &lists.view(base), k, job.params.area_scale as f64, summed);
        if !incomplete.is_empty() {
            // Those sites' own pieces, else every piece again.
            let redone = crate::passes::faces::redo_sites(job, out, &incomplete, &lists);
            drop(lists);
            let all = match redone {
                Some(all) => all,
                // A part's cell built again by a walk that had to leave its
                // held cells: the part is done again with a wider halo
                // (its faces here would come from another body than one
                // process's); said as a cell out of the halo.
                None if job.is_windowed() => {
                    let adjacency = crate::passes::faces::assemble(faces, map, self.sites, frame.scale, halves);
                    return Ok((adjacency, incomplete.len(), incomplete));
                }
                None => {
                    let cpu = match cpu {
                        Some(c) => c,
                        None => crate::exec::CpuBackend::new(None)?,
                    };
                    let sinks = Mutex::new(Vec::new());
                    let mut again = cpu.clip_into::<crate::passes::faces::FaceCollector>(job, &sinks)?;
                    crate::passes::second_pass::run(job, &mut again, &sinks)?;
                    sinks.into_inner().unwrap_or_else(|e| e.into_inner())
                }
            };
            // Masses: each piece's faces weighted by its tet's mean density
            // (the kernels take the piece's own).
            let tet_density =
                |t: usize| job.tets[t].iter().map(|&v| job.verts[v as usize].hi[3] as f64).sum::<f64>() / 4.0;
            let masses = job.params.face_masses != 0;
            crate::passes::faces::complete(&mut faces, &incomplete, &all, &job.tet_faces, |t| {
                if masses {
                    tet_density(t)
                } else {
                    1.0
                }
            });
        }
        let redone = incomplete.len();
        Ok((crate::passes::faces::assemble(faces, map, self.sites, frame.scale, halves), redone, Vec::new()))
    }
}

/// The smallest f32 above a positive finite `x`.
fn next_up(x: f32) -> f32 {
    f32::from_bits(x.to_bits() + 1)
}

fn finish(
    mesh: &TetMesh,
    density: Option<&[f64]>,
    input: &[[f64; 3]],
    job: &ClipJob,
    map: &SiteMap,
    frame: &Frame,
    out: ClipOutput,
) -> Cells {
    let inv = 1.0 / job.params.fixed_scale as f64;
    let l = frame.scale;
    let mut cells = Cells {
        strategy: job.strategy,
        pairing: job.pairing,
        chunks: out.chunks,
        grid_cells: [job.site_knn.params.grid.n_cells as u64, job.refine.grid.n_cells as u64],
        tets: [job.tets.len() as u64, mesh.tets.len() as u64],
        k: job.params.k_tet as usize,
        k_site: job.params.k_site as usize,
        ..Default::default()
    };
    for (i, m) in map.iter().enumerate() {
        let site = input[i];
        let (v, c, e) = match m {
            Some(u) => {
                let s = &out.sums[u * ACCUM_PER_SITE..(u + 1) * ACCUM_PER_SITE];
                let v = s[0] as f64 * inv * l.powi(3);
                let first = [1, 2, 3].map(|a| s[a] as f64 * inv * l.powi(4));
                let e = s[4] as f64 * inv * l.powi(5);
                let c = if v > 0.0 { [0, 1, 2].map(|a| site[a] + first[a] / v) } else { site };
                (v, c, e)
            }
            None => (0.0, site, 0.0),
        };
        cells.volume.push(v);
        cells.centroid.push(c);
        cells.energy.push(e);
    }
    cells.total_volume = crate::geom::exact_sum::ExactSum::of(&cells.volume).value();
    cells.mesh_volume = match density {
        // Linear in each tet: the mass is the volume times the mean.
        Some(rho) => (0..mesh.tets.len())
            .map(|t| mesh.tet_volume(t).abs() * mesh.tets[t].iter().map(|&v| rho[v as usize]).sum::<f64>() / 4.0)
            .sum(),
        None => mesh.volume(),
    };
    cells.e_vol = (cells.total_volume - cells.mesh_volume).abs() / cells.mesh_volume;
    let c = |i: usize| out.counters[i].max(0) as u64;
    cells.counters = Counters {
        pairs: c(counter::PAIRS),
        nonempty: c(counter::NONEMPTY),
        filtered: c(counter::FILTERED),
        clips: c(counter::CLIPS),
        security_missed: c(counter::SECURITY_MISSED),
        overflows: c(counter::OVERFLOWS),
        broken: c(counter::BROKEN),
        walks: c(counter::WALKS),
        out_of_halo: c(counter::HALO),
        whole_cells: c(counter::WHOLE),
        cut_cells: c(counter::CUT),
        duplicate_sites: map.iter().filter(|m| m.is_none()).count() as u64,
        empty_cells: map.iter().zip(&cells.volume).filter(|(m, &v)| m.is_some() && v <= 0.0).count() as u64,
        second_pass: 0,
        unresolved: 0,
        missed_tets: 0,
        faces_redone: 0,
    };
    cells.timings = out.timings;
    cells
}

/// The last frame's candidates ([`Candidates`]) for the `listed` sites of
/// a job (`inputs`: each job site's input index) in its site indices and
/// squared quantized distances: each last-job site taken to this job's
/// site (none for a point that is no site of it, or a duplicate's), and
/// each reach shrunk by the quantization's rounding (a distance between
/// quantized points is within `sqrt(3)` units of the exact one).
fn local_candidates(
    c: &Candidates<'_>,
    inputs: &[u32],
    listed: usize,
    map: &SiteMap,
    knn: &KnnJob,
    scale: f64,
) -> SiteCandidates {
    use rayon::prelude::*;
    let site =
        |p: u32| if (p as usize) < map.len() { map.get(p as usize).map_or(NO_SITE, |u| u as u32) } else { NO_SITE };
    let to_site: Vec<u32> = c.to_input.par_iter().map(|&p| site(p)).collect();
    let k = c.k;
    let mut out = SiteCandidates { k, sites: vec![NO_SITE; listed * k], below2: vec![0; listed] };
    out.sites.par_chunks_mut(k.max(1)).zip(&mut out.below2).zip(&inputs[..listed]).for_each(|((row, below2), &i)| {
        let Some(&r) = c.row_of.get(i as usize).filter(|&&r| r != u32::MAX) else { return };
        let r = r as usize;
        for (slot, &v) in row.iter_mut().zip(&c.lists[r * k..(r + 1) * k]) {
            if v != NO_SITE {
                *slot = to_site.get(v as usize).copied().unwrap_or(NO_SITE);
            }
        }
        let reach = c.reach[r];
        let below = reach / scale * knn.quantizer.scale() - 2.0;
        *below2 = if reach == f64::INFINITY {
            u64::MAX
        } else if below > 0.0 {
            (below * below).min(u64::MAX as f64 / 2.0) as u64
        } else {
            0
        };
    });
    out
}

/// The lists a job kept ([`LocalKept`]) with its sites' input indices
/// (`inputs`) and each list's reach in input units: a searched list's from
/// its last entry (less the quantization's rounding), a list taken from
/// the candidates keeping theirs (`c`, through each site's row).
fn kept_lists(kept: LocalKept, inputs: Vec<u32>, knn: &KnnJob, scale: f64, c: Option<&Candidates<'_>>) -> KeptLists {
    // Every point not listed lies at least this far: past its last entry.
    let past = |u: usize| {
        if kept.last2[u] == u64::MAX {
            f64::INFINITY
        } else {
            ((kept.last2[u] as f64).sqrt() - 2.0).max(0.0) / knn.quantizer.scale() * scale
        }
    };
    let reach: Vec<f64> = (0..kept.reused.len())
        .map(|u| {
            if kept.reused[u] {
                // Not a candidate, or a candidate past the list's end.
                let row = c.and_then(|c| c.row_of.get(inputs[u] as usize).map(|&r| c.reach[r as usize]));
                row.unwrap_or(0.0).min(past(u))
            } else {
                past(u)
            }
        })
        .collect();
    let kth: Vec<f64> = kept
        .kth2
        .iter()
        .map(|&d2| if d2 == u64::MAX { f64::INFINITY } else { (d2 as f64).sqrt() / knn.quantizer.scale() * scale })
        .collect();
    let reused = kept.reused.iter().filter(|&&r| r).count();
    let mut beyond: Vec<f64> = (0..kept.reused.len())
        .filter(|&u| !kept.reused[u])
        .map(|u| reach[u] - kth[u])
        .filter(|w: &f64| w.is_finite())
        .collect();
    // Rows searched afresh because their candidates failed are the odd
    // ones: the skin is measured where most rows were searched.
    let skin = if beyond.len() * 2 < kept.reused.len() {
        0.0
    } else {
        let mid = beyond.len() / 2;
        beyond.select_nth_unstable_by(mid, f64::total_cmp).1.max(0.0)
    };
    KeptLists {
        k: kept.k as usize,
        lists: kept.lists,
        reach,
        kth,
        inputs,
        reused,
        skin,
        left: Vec::new(),
        kinds: Vec::new(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::points;

    fn refused(d: ClippedVoronoi) -> String {
        match d.job() {
            Err(Error::InvalidInput(m)) => m,
            Err(e) => panic!("not an input error: {e}"),
            Ok(_) => panic!("accepted"),
        }
    }

    #[test]
    fn an_empty_mesh_or_no_sites_are_refused() {
        let sites = points::uniform(10, 1);
        assert!(refused(ClippedVoronoi::new(&TetMesh::default(), &sites)).contains("no tets"));
        let mesh = TetMesh::cube(1);
        assert!(refused(ClippedVoronoi::new(&mesh, &[])).contains("no sites"));
        let bad = [[0.5, 0.5, 0.5], [0.1, f64::NAN, 0.2]];
        assert!(refused(ClippedVoronoi::new(&mesh, &bad)).contains("site 1"));
    }

    /// A job answering a run of the sites it lays out sums the faces of
    /// that run only (`faces_first` on, one slot row per answered site),
    /// and those cells and faces are the bits of the job answering every
    /// site; the sites held around them get no faces.
    #[test]
    fn a_run_answered_sums_its_own_faces_only() {
        let mesh = TetMesh::cube(3);
        let sites = points::uniform(3000, 21);
        let order = crate::geom::points::morton_order(&sites);
        let laid = |answer: (usize, usize)| {
            let layout = Layout {
                order: &order,
                lo: [0.0; 3],
                hi: [1.0; 3],
                grid_sites: sites.len(),
                answer,
                weights: None,
                weight_grid: None,
                window: Window::Whole,
                unheld: None,
                periodic: false,
                only: None,
                halves: false,
            };
            ClippedVoronoi::new(&mesh, &sites).faces(true).strategy(Strategy::Whole).layout(layout)
        };
        let (job, _, _) = laid((1000, 1700)).job().unwrap();
        let per = job.params.k_site as usize + cvd_kernels::clip::FACE_SUMS_EXTRA;
        assert_eq!((job.params.faces_first, job.face_sums_len()), (1000, 700 * per));
        let (all, run) = (laid((0, sites.len())).compute().unwrap(), laid((1000, 1700)).compute().unwrap());
        let (a, b) = (all.adjacency().unwrap(), run.adjacency().unwrap());
        let mut place = vec![0; sites.len()];
        for (p, &i) in order.iter().enumerate() {
            place[i as usize] = p;
        }
        let answered = |i: usize| (1000..1700).contains(&place[i]);
        let mut faces = 0;
        for i in 0..sites.len() {
            let (mine, theirs): (Vec<_>, Vec<_>) = (b.of(i).collect(), a.of(i).collect());
            if answered(i) {
                assert_eq!(run.volume[i].to_bits(), all.volume[i].to_bits(), "site {i}");
                assert_eq!(b.boundary[i].to_bits(), a.boundary[i].to_bits(), "site {i}'s boundary");
                // A face with a cell not built holds this side's half.
                let ids = |f: &[(u32, f64, [f64; 3])]| f.iter().map(|e| e.0).collect::<Vec<_>>();
                assert_eq!(ids(&mine), ids(&theirs), "site {i}'s neighbours");
                for (m, t) in mine.iter().zip(&theirs).filter(|(m, _)| answered(m.0 as usize)) {
                    assert_eq!(m, t, "site {i}'s face with {}", m.0);
                    faces += 1;
                }
            } else {
                // Only the halves the answered cells gave it.
                assert_eq!(run.volume[i], 0.0, "site {i} held, not answered");
                assert!(mine.iter().all(|m| answered(m.0 as usize)), "site {i}: a face of its own");
            }
        }
        assert!(faces > 700 * 10, "{faces} faces");
    }

    /// A job building some of its answered cells only (`Layout::only`, the
    /// CPU's) gives those cells the bits of the job building every one —
    /// volumes, kinds, and each face's own half, the two halves adding up
    /// to the whole job's face — and the others nothing.
    #[test]
    fn some_cells_only_are_the_bits_of_the_job_building_all() {
        let mesh = TetMesh::cube(3);
        let sites = points::uniform(3000, 22);
        let order = crate::geom::points::morton_order(&sites);
        let only: Vec<u32> = (1000..1700).filter(|p| p % 7 == 0 || (1300..1340).contains(p)).collect();
        let laid = |only: Option<&[u32]>, halves: bool| {
            let layout = Layout {
                order: &order,
                lo: [0.0; 3],
                hi: [1.0; 3],
                grid_sites: sites.len(),
                answer: (1000, 1700),
                weights: None,
                weight_grid: None,
                window: Window::Whole,
                unheld: None,
                periodic: false,
                only,
                halves,
            };
            let cv = ClippedVoronoi::new(&mesh, &sites).faces(true).strategy(Strategy::Whole).layout(layout);
            cv.keep_reach(cv.resolved_k_site()).compute().unwrap()
        };
        let (all, some) = (laid(None, false), laid(Some(&only), true));
        let (a, b) = (all.adjacency().unwrap(), some.adjacency().unwrap());
        let built = |i: usize| order.iter().position(|&o| o as usize == i).is_some_and(|p| only.contains(&(p as u32)));
        let (ka, kb) = (all.kept.as_ref().unwrap(), some.kept.as_ref().unwrap());
        let listed = |k: &KeptLists, i: usize| k.inputs.iter().position(|&j| j as usize == i);
        let (mut pairs, mut cut) = (0, 0);
        for i in 0..sites.len() {
            if !built(i) {
                assert_eq!((some.volume[i], b.of(i).count()), (0.0, 0), "site {i} not built");
                continue;
            }
            assert_eq!(some.volume[i].to_bits(), all.volume[i].to_bits(), "site {i}");
            let kind = |k: &KeptLists| listed(k, i).and_then(|u| k.kinds.get(u - 1000).copied());
            assert_eq!(kind(kb), kind(ka), "site {i}'s kind");
            cut += (kind(kb) == Some(crate::job::clip::cell_kind::CUT)) as usize;
            for (j, half, normal) in b.of(i) {
                let whole = a.of(i).find(|e| e.0 == j).expect("the same neighbours");
                assert_eq!(normal, whole.2, "site {i}'s face with {j}");
                if built(j as usize) {
                    let theirs = b.of(j as usize).find(|e| e.0 == i as u32).map_or(0.0, |e| e.1);
                    assert_eq!((half + theirs).to_bits(), whole.1.to_bits(), "site {i}'s face with {j}");
                    pairs += 1;
                }
            }
        }
        println!("{pairs} faces between built cells, {cut} cut of {}", only.len());
        assert!(pairs > 50 && cut > 0 && cut < only.len(), "{pairs} faces between built cells, {cut} cut");
    }

    /// Jobs that share a prepared mesh take its tets' order, boundary and
    /// whole-cell index from the first (one index for all), and are the
    /// job built alone, to the bit; a density asks for an index of its own.
    #[test]
    fn jobs_sharing_a_prepared_mesh_are_the_job_built_alone() {
        let mesh = TetMesh::voxels(5, |x, y, z| x + y + z < 11);
        let sites = points::in_mesh(&mesh, 600, 3);
        let prepared = PreparedMesh::default();
        let alone = ClippedVoronoi::new(&mesh, &sites).strategy(Strategy::Whole).faces(true);
        let (one, _, _) = alone.job().unwrap();
        let with = alone.prepared(&prepared);
        let (first, _, _) = with.job().unwrap();
        let (second, _, _) = ClippedVoronoi::new(&mesh, &sites[..300]).faces(true).prepared(&prepared).job().unwrap();
        let index = |j: &ClipJob| j.domain.clone().expect("a whole-cell job has an index");
        assert!(std::sync::Arc::ptr_eq(&index(&first), &index(&second)), "the index was built twice");
        for job in [&first, &second] {
            assert_eq!((&job.tets, &job.tet_order, &job.tet_faces), (&one.tets, &one.tet_order, &one.tet_faces));
            assert_eq!(format!("{:?}", index(job)), format!("{:?}", index(&one)));
        }
        let cpu = crate::exec::CpuBackend::new(Some(2)).unwrap();
        let (a, b) = (alone.backend(&cpu).compute().unwrap(), with.backend(&cpu).compute().unwrap());
        assert_eq!(
            a.volume.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            b.volume.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
        );
        let rho = vec![2.0; mesh.vertices.len()];
        let (dense, _, _) = with.density(Some(&rho)).job().unwrap();
        assert!(!std::sync::Arc::ptr_eq(&index(&dense), &index(&first)), "a density took the index without one");
        // Another mesh, prepared in its place.
        let other = TetMesh::cube(2);
        let (third, _, _) =
            ClippedVoronoi::new(&other, &sites[..50]).strategy(Strategy::Whole).prepared(&prepared).job().unwrap();
        assert_eq!(third.tets.len(), other.tets.len());
    }

    #[test]
    fn a_density_needs_one_positive_value_per_vertex() {
        let mesh = TetMesh::cube(1);
        let sites = points::uniform(10, 2);
        let n = mesh.vertices.len();
        let short = vec![1.0; n - 1];
        let m = refused(ClippedVoronoi::new(&mesh, &sites).density(Some(&short)));
        assert!(m.contains(&format!("{} density values for {n} mesh vertices", n - 1)), "{m}");
        for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            let mut rho = vec![1.0; n];
            rho[3] = bad;
            let m = refused(ClippedVoronoi::new(&mesh, &sites).density(Some(&rho)));
            assert!(m.contains("the density at vertex 3"), "{bad}: {m}");
        }
        let rho: Vec<f64> = (0..n).map(|v| 1.0 + v as f64).collect();
        let (job, _, _) = ClippedVoronoi::new(&mesh, &sites).density(Some(&rho)).job().unwrap();
        let stored: Vec<f32> = job.verts.iter().map(|v| v.hi[3]).collect();
        assert_eq!(stored, rho.iter().map(|&r| r as f32).collect::<Vec<_>>(), "the density rides in w");
    }

    #[test]
    fn k_and_k_site_must_be_positive() {
        let mesh = TetMesh::cube(1);
        let sites = points::uniform(10, 3);
        let d = ClippedVoronoi::new(&mesh, &sites);
        assert!(refused(d.k_site(0)).contains("at least 1"));
        assert!(refused(d.strategy(Strategy::TetCell).pairing(Pairing::Knn).k(Some(0))).contains("at least 1"));
        assert!(refused(d.k(Some(0))).contains("at least 1"), "even where flood does not use k");
        assert!(refused(d.pairing(Pairing::Knn)).contains("pairs no tets"), "whole cells, the default");
    }

    #[test]
    fn a_job_over_its_memory_budget_is_refused_before_it_is_built() {
        let mesh = TetMesh::cube(4);
        let sites = points::uniform(20_000, 3);
        let d = ClippedVoronoi::new(&mesh, &sites);
        match d.memory_budget(1 << 20).job() {
            Err(e @ Error::TooLarge { .. }) => {
                let m = e.to_string();
                assert!(m.contains("20000 sites in 384 tets") && m.contains("1.0 MB"), "{m}");
                assert!(e.is_input_error());
            }
            Err(e) => panic!("not refused for its size: {e}"),
            Ok(_) => panic!("a job of 20 000 sites in 1 MiB"),
        }
        assert!(d.memory_budget(1 << 30).job().is_ok());
        let b = crate::PeriodicBox::unit();
        let periodic = crate::PeriodicVoronoi::new(b, &sites).memory_budget(1 << 20).compute();
        assert!(matches!(periodic, Err(Error::TooLarge { .. })), "{:?}", periodic.err());
    }

    #[test]
    fn flood_pairing_needs_tet_cell() {
        let mesh = TetMesh::cube(1);
        let sites = points::uniform(10, 4);
        let d = ClippedVoronoi::new(&mesh, &sites).strategy(Strategy::CellTet);
        assert!(refused(d.pairing(Pairing::Flood)).contains("tet-cell strategy only"));
        let (job, _, _) = d.job().unwrap();
        assert_eq!((job.strategy, job.pairing), (Strategy::CellTet, Pairing::Knn), "cell-tet's default: knn");
        let (job, _, _) = ClippedVoronoi::new(&mesh, &sites).strategy(Strategy::TetCell).job().unwrap();
        assert_eq!((job.strategy, job.pairing), (Strategy::TetCell, Pairing::Flood), "tet-cell's default: flood");
        let (job, _, _) = ClippedVoronoi::new(&mesh, &sites).job().unwrap();
        assert_eq!((job.strategy, job.pairing), (Strategy::Whole, Pairing::Flood), "the default: whole cells");
        assert!(job.domain.is_some() && job.tet_knn.params.k == 1, "the domain's index, no tet lists");
        let rho = vec![1.0; mesh.vertices.len()];
        let (job, _, _) = ClippedVoronoi::new(&mesh, &sites).density(Some(&rho)).job().unwrap();
        assert_eq!(job.strategy, Strategy::TetCell, "under a density: tet-cell");
    }

    #[test]
    fn weights_must_fit_the_sites_and_the_frame() {
        let mesh = TetMesh::cube(1);
        let sites = points::uniform(4, 5);
        let m = refused(ClippedVoronoi::new(&mesh, &sites).weights(&[0.0; 3]));
        assert!(m.contains("3 weights for 4 sites"), "{m}");
        let m = refused(ClippedVoronoi::new(&mesh, &sites).weights(&[0.0, f64::NAN, 0.0, 0.0]));
        assert!(m.contains("site 1"), "{m}");
        let m = refused(ClippedVoronoi::new(&mesh, &sites).weights(&[0.0, 1e31, 0.0, -1e31]));
        assert!(m.contains("the weights span"), "{m}");
        // A constant changes nothing: the job's weights start at 0.
        let (job, _, _) = ClippedVoronoi::new(&mesh, &sites).weights(&[5.0, 5.25, 5.5, 5.0]).job().unwrap();
        assert!(job.params.weight_range >= 0.5);
        assert_eq!(job.sites.len(), 2 * 4, "each site's weight bound after the sites");
    }

    #[test]
    fn k_defaults_to_eq_6_and_k_site_to_the_backends() {
        let mesh = TetMesh::cube(3); // 162 tets
        let sites = points::uniform(200, 6);
        let d = ClippedVoronoi::new(&mesh, &sites).strategy(Strategy::TetCell);
        assert_eq!(d.resolved_k_site(), 48, "CPU, flood");
        assert_eq!(ClippedVoronoi::new(&mesh, &sites).resolved_k_site(), 48, "CPU, whole cells");
        assert_eq!(d.pairing(Pairing::Knn).resolved_k_site(), 90);
        assert_eq!(d.strategy(Strategy::CellTet).resolved_k_site(), 90);
        assert_eq!(d.k_site(7).resolved_k_site(), 7);
        let (job, _, _) = d.pairing(Pairing::Knn).job().unwrap();
        assert_eq!(job.params.k_tet as usize, paper_k(200, 162));
        assert_eq!((job.params.k_site, job.site_knn.params.k), (90, 90));
        let (job, _, _) = d.pairing(Pairing::Knn).k(Some(500)).job().unwrap();
        assert_eq!(job.params.k_tet, 200, "k clamped to the sites");
        let (job, _, _) = d.k(Some(5)).job().unwrap();
        assert_eq!(job.params.k_tet, 1, "flood pairs a tet with its nearest site");
        // Few sites: k_site clamped to the others.
        let (job, _, _) = ClippedVoronoi::new(&mesh, &sites[..5]).job().unwrap();
        assert_eq!(job.params.k_site, 4);
    }

    #[test]
    fn the_job_is_normalised_in_morton_order_with_a_map_back() {
        let mesh = TetMesh::grid([-1.0, 2.0, 0.0], [3.0, 4.0, 1.0], [4, 2, 1]);
        let mut sites: Vec<[f64; 3]> =
            points::uniform(40, 7).iter().map(|p| [4.0 * p[0] - 1.0, 2.0 * p[1] + 2.0, p[2]]).collect();
        sites.push(sites[3]);
        sites.push(sites[10]);
        let (job, map, frame) = ClippedVoronoi::new(&mesh, &sites).job().unwrap();
        assert_eq!(frame, Frame { origin: [-1.0, 2.0, 0.0], scale: 4.0 });
        assert_eq!(job.params.n_sites, 40);
        assert_eq!(map.len(), 42);
        assert_eq!((map.get(40), map.get(41)), (None, None), "duplicates map to nothing");
        for (i, m) in map.iter().enumerate().take(40) {
            let u = m.expect("a distinct site has a place");
            let local = frame.to_local(sites[i]);
            let p = job.sites[u].to_f64();
            assert!((0..3).all(|a| (p[a] - local[a]).abs() < 1e-15), "site {i}: {p:?} vs {local:?}");
        }
        // The tets: every mesh tet once, as `tet_order` says.
        let mut order = job.tet_order.clone();
        order.sort_unstable();
        assert!(order.iter().copied().eq(0..mesh.tets.len() as u32));
        for (t, &o) in job.tet_order.iter().enumerate() {
            assert_eq!(job.tets[t], mesh.tets[o as usize]);
        }
        assert_eq!((job.params.n_tets as usize, job.held), (mesh.tets.len(), None));
        // The Algorithm 1 box holds the mesh and sites, in the frame.
        let p = job.params;
        assert!(p.box_lo_x < 0.0 && p.box_lo_y < 0.0 && p.box_lo_z < 0.0);
        assert!(p.box_hi_x > 1.0 && p.box_hi_y > 0.5 && p.box_hi_z > 0.25);
    }
}
