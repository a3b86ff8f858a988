//! A mesh's diagram in parts with its input in parts too: each rank of a
//! run starts with its own rows of the sites (a run of the input, as it
//! read them), holds the mesh (every rank reads it: a mesh is small beside
//! the sites it is cut into) and only the sites near its own, and every
//! cell comes out to the bit as in one process.
//!
//! The one-process job is laid out by what every rank can learn from a few
//! numbers: its frame is the mesh's, its quantization and grid follow from
//! the bounding box of the mesh and all the sites and from the number of
//! distinct sites, and its sites are in Morton order over their bounding
//! box (ties by input index). So a rank, in turn:
//! - adds up with the others the sites' box, the sites per Morton bucket
//!   (the curve's first 15 bits: 32 768 buckets) and the distinct sites;
//!   takes a run of buckets along the curve holding its share of the
//!   sites, and receives the sites in them (its own: their cells are the
//!   ones it builds, a run of the one process's order);
//! - asks for every site of a box of the whole job's grid cells around its
//!   own (`halo` cells wider than their box on every side), so that every
//!   grid cell of the box is complete, and builds the whole cells of its
//!   own sites in a job holding that box ([`Window::Held`]): the same
//!   frame, grid, order and quantization as the one process;
//! - certifies each cell: its neighbour list is the one process's when the
//!   ball through its last entry lies inside the box
//!   ([`HeldCells::certifies`]), and a grid walk passes over a cell outside
//!   where no site there could cut its cell, else gives up
//!   (`Counters::out_of_halo`). The halo goes around groups of the part's
//!   cells along the curve, each its own: a group with a list not
//!   certified asks again with a halo as wide as the list's ball, a cell
//!   whose walk left with the grid cells around its vertices' balls among
//!   the sites held ([`flower_cover`]), the others keep theirs (at most
//!   the whole grid, which certifies every cell); the next round's job
//!   holds the wider set and builds those cells only (on the CPU:
//!   [`crate::job::clip::ClipJob::only`]; a device builds every cell of
//!   the run again, and the round takes those);
//! - sends each row, with its faces (the other side's halves from the
//!   round or the rank that finished that side, as one process adds them),
//!   to the rank that read its site.
//!
//! Power cells carry their weights with their sites: the job shifts them
//! by the smallest of all, and its local weight bounds read the grid of
//! largest weights of all the sites (each rank adds its own; the largest
//! over the ranks in each grid cell), so every part bounds its sites as the
//! one process does. Densities are not laid out so yet: refused by name.

use super::periodic::merge_faces;
use super::periodic_parts::{
    at_row, counter_words, distinct_positions, kept_span, send, to_owners, weight_grid_as_one, weight_span,
    with_totals, BuiltCells, Held, PartsReport, RowsAcross,
};
use super::spill::Spill;
use crate::backends::distributed::{records, Parcels, Reduce};
use crate::diagram::particles::{cell_quantities, IndexThresholds, ParticleCells, INDEX_ORDERS};
use crate::diagram::voronoi::{Cells, ClippedVoronoi, Counters};
use crate::error::{Error, Result};
use crate::exec::CpuBackend;
use crate::geom::points::MortonKeys;
use crate::geom::timing::{timed, Timings};
use crate::job::clip::{Frame, JobShape, Strategy};
use crate::job::held::{HeldCells, HeldMask, HeldSet};
use crate::job::sites::{Layout, Window};
use crate::job::weight_bounds::WeightGrid;
use crate::passes::faces::Adjacency;
use crate::passes::pieces::Pieces;
use crate::passes::polyhedra::merge_pieces;
use bytemuck::{Pod, Zeroable};
use rayon::prelude::*;

/// What is handed each sub-part's pieces
/// ([`ClippedVoronoi::compute_in_parts_visiting`]).
type Visit<'v> = &'v mut dyn FnMut(&Pieces) -> Result<()>;

/// Groups of a sub-part's cells along the curve, each held with the cells
/// around it (a held box each: [`HeldSet`]). Fine enough that a group in
/// the sparse space beside a cluster holds its own neighbourhood, not the
/// cluster's core (4 096 against 64: 23 % fewer sites held on a clustered
/// crowd, uniform sites the same; docs/BENCHMARKS.md "Halos widened group
/// by group"); the boxes go only to the ranks that send the part sites.
const HELD_GROUPS: usize = 4096;

/// The Morton key's bits that number a bucket (5 per axis).
const BUCKET_BITS: u32 = 15;

/// How far from an even share (of the sites counted) a rank's run of the
/// curve may end, to end where the curve's keys change in a higher bit
/// (a more compact box of cells, a smaller halo).
const COUNTED_SLACK: f64 = 0.05;

/// The same, when the ranks are balanced by the work they measured (the
/// measurement already holds what a less compact box costs).
const MEASURED_SLACK: f64 = 0.01;

/// The parts a rank computes its share of the sites in, one after another,
/// unless the caller says ([`ClippedVoronoi::parts_per_rank`]): 4, fewer
/// where a part would own fewer than [`AUTO_PART_SITES`] sites (its halo
/// would outweigh it). A rank holds one part's job (about 1 kB a held
/// site with faces) and the rows it receives (about 640 bytes a row with
/// faces, unless they wait in a file: [`ClippedVoronoi::spill_rows_to`]):
/// 4 parts cost 3-7 % more time than one (docs/BENCHMARKS.md, "Parts per
/// rank by default").
pub fn auto_parts(total: u64, ranks: usize) -> usize {
    (total / ranks.max(1) as u64 / AUTO_PART_SITES).clamp(1, AUTO_PARTS as u64) as usize
}

/// The most parts [`auto_parts`] takes.
const AUTO_PARTS: usize = 4;

/// The fewest sites a part of [`auto_parts`] owns.
pub const AUTO_PART_SITES: u64 = 16_384;

/// What a rank of a mesh in parts gives back
/// ([`ClippedVoronoi::compute_in_parts_by_rows`]).
pub struct MeshInParts {
    /// The run's totals and counters, and each of this rank's rows'
    /// volume, centroid and energy (their faces: [`Self::rows`]).
    pub cells: Cells,
    /// This rank's rows with their faces, read in batches.
    pub rows: MeshRows,
    /// The polyhedra of the cells this rank built, when asked for.
    pub built: Option<BuiltCells>,
    /// The pieces they were merged from.
    pub pieces: u64,
    /// What the part did.
    pub report: PartsReport,
}

/// A round of a rank's sub-part and what its job computed: the input
/// index and place of each site it held (in its job's order), the places
/// of the run it answered, its cells and pieces, and the cells of the run
/// it finished (places in the run, increasing; the others are finished in
/// another round).
struct Round<'a> {
    held: &'a [u64],
    answer: std::ops::Range<usize>,
    cells: &'a Cells,
    pieces: Option<crate::passes::pieces::Pieces>,
    finished: &'a [u32],
}

/// A run of a rank's sites along the curve (places in its order).
type Run = std::ops::Range<usize>;

/// A sub-part of a rank's sites, from round to round: its run, the groups
/// of its cells along the curve its halo goes around (their first places
/// in the run, `starts`, and boxes of grid cells), each group's halo, the
/// boxes its failing cells asked for, and its cells not finished yet.
struct SubPart {
    sub: usize,
    run: Run,
    first_halo: u32,
    /// The curve's key and input index of its first site.
    first_key: Option<(u32, u64)>,
    starts: Vec<usize>,
    groups: Vec<([u32; 3], [u32; 3])>,
    halos: Vec<u32>,
    /// Boxes around cells whose lists were not certified or whose walks
    /// left, holding where a site that cuts them can be
    /// ([`flower_cover`]).
    covers: Vec<HeldCells>,
    /// The run's cells not finished yet (places in the run, increasing;
    /// `None`: every one).
    pending: Option<Vec<u32>>,
    done: bool,
}

impl SubPart {
    /// The boxes of grid cells its next round holds: every group's with
    /// its halo, and the covers; `None` once every cell is finished.
    fn want(&self, whole: &Whole) -> Option<HeldSet> {
        if self.done {
            return None;
        }
        let grid = &whole.grid;
        let dims = [grid.dim_x, grid.dim_y, grid.dim_z];
        let around =
            |&(lo, hi): &([u32; 3], [u32; 3]), halo: u32| HeldCells::around(lo, hi, halo, dims, grid.cell_size);
        let boxes = self.groups.iter().zip(&self.halos).map(|(g, &h)| around(g, h));
        Some(HeldSet::of(boxes.chain(self.covers.iter().copied()).collect()))
    }
}

impl ClippedVoronoi<'_> {
    /// This rank's part of the diagram of the sites of all ranks of `comm`
    /// in the mesh (see the module's documentation): `self`'s sites are
    /// this rank's rows of the input, the rows of rank 0 first, then rank
    /// 1's, and so on; every rank holds the same mesh. Returns the cells of
    /// this rank's rows — the same bits as the diagram of all the sites in
    /// one process with whole cells, neighbours by input index (with
    /// [`Self::faces`]) — with the run's totals, and what the part did.
    /// Whole cells, on the CPU or a device ([`Self::backend`]: each part a
    /// whole-cell job in its window), with power weights ([`Self::weights`]: this
    /// rank's rows' own) and a density ([`Self::density`]: every rank the
    /// whole mesh's, as it holds the mesh).
    pub fn compute_in_parts(&self, comm: &dyn Reduce) -> Result<(Cells, PartsReport)> {
        let out = self.compute_in_parts_by_rows(comm, None)?;
        Ok((out.all_rows()?, out.report))
    }

    /// [`Self::compute_in_parts`] with the polyhedra of the cells this rank
    /// built (its sites' along the curve, not its rows), on `cpu`, each by
    /// its site's input index with its cell's volume, centroid and energy.
    pub fn compute_in_parts_with_polyhedra(
        &self,
        comm: &dyn Reduce,
        cpu: &CpuBackend,
    ) -> Result<(Cells, BuiltCells, PartsReport)> {
        let mut out = self.compute_in_parts_by_rows(comm, Some(cpu))?;
        let built = out.built.take().ok_or_else(|| Error::Internal("no polyhedra came back".into()))?;
        Ok((out.all_rows()?, built, out.report))
    }

    /// [`Self::compute_in_parts`] (with the polyhedra on `geometry`), the
    /// rows' faces kept as the ranks sent them, to be read in batches
    /// ([`MeshRows::cells`]): a rank then holds its rows' faces once, not
    /// twice.
    pub fn compute_in_parts_by_rows(&self, comm: &dyn Reduce, geometry: Option<&CpuBackend>) -> Result<MeshInParts> {
        self.mesh_in_parts(comm, geometry, &mut |_| Ok(()))
    }

    /// [`Self::compute_in_parts_by_rows`], handing `visit` the pieces of
    /// the cells this rank builds, a sub-part's at a time, as they are
    /// made (each site named by its input index; they are dropped after):
    /// to draw or write them without holding them all.
    pub fn compute_in_parts_visiting(
        &self,
        comm: &dyn Reduce,
        geometry: &CpuBackend,
        visit: &mut dyn FnMut(&Pieces) -> Result<()>,
    ) -> Result<MeshInParts> {
        self.mesh_in_parts(comm, Some(geometry), visit)
    }

    fn mesh_in_parts(&self, comm: &dyn Reduce, geometry: Option<&CpuBackend>, visit: Visit) -> Result<MeshInParts> {
        // The sub-parts' jobs share the mesh prepared once (and the
        // diagrams that follow, if the caller keeps it).
        let prepared = crate::diagram::voronoi::PreparedMesh::default();
        let prepared = self.prepared.or(self.halos.map(|h| &h.mesh)).unwrap_or(&prepared);
        let this = (*self).prepared(prepared);
        this.mesh_in_parts_prepared(comm, geometry, visit)
    }

    fn mesh_in_parts_prepared(
        &self,
        comm: &dyn Reduce,
        geometry: Option<&CpuBackend>,
        visit: Visit,
    ) -> Result<MeshInParts> {
        let mesh = self.mesh;
        if mesh.tets.is_empty() {
            return Err(Error::InvalidInput("the mesh has no tets".into()));
        }
        // The cells on the diagram's backend (the CPU's own, or a device's:
        // the whole-cell kernel in the held window either way); the
        // polyhedra on `geometry`, from the same run on the CPU.
        let own_cpu;
        let backend: &dyn crate::backend::Backend = match (geometry, self.backend) {
            (_, Some(b)) if b.kind() != crate::job::BackendKind::Cpu => b,
            (Some(cpu), _) => cpu,
            (None, Some(b)) => b,
            (None, None) => {
                own_cpu = CpuBackend::new(None)?;
                &own_cpu
            }
        };
        let ranks = comm.size();
        let mut timings = Timings::default();
        let clock = std::time::Instant::now();
        let across = RowsAcross::of(comm, self.sites.len())?;
        let (first, total) = (across.first, across.total);
        if !self.sites.is_empty() {
            crate::job::sites::check_sites(self.sites, self.weights).map_err(|e| at_row(e, first))?;
        }
        let span = weight_span(comm, self.weights)?;
        let shape = JobShape { density: self.density.is_some(), sites: total as usize, tets: mesh.tets.len() };
        if Self::strategy_for(self.strategy, Some(backend), shape) != Strategy::Whole {
            return Err(Error::InvalidInput(format!(
                "a mesh with its sites in parts is computed with whole cells{}",
                match (shape.density, backend.kind()) {
                    (true, _) => " (under a density one process takes tet-cell: ask for whole cells)",
                    (false, crate::job::BackendKind::Cpu) => "",
                    (false, _) => " (a device takes tet-cell by default: ask for whole cells)",
                }
            )));
        }
        let reader = |site: u64| across.reader(site);

        // The sites' box over all ranks, and the curve over it.
        let (lo, hi) = crate::geom::vec3::bounding_box(self.sites.iter());
        let mut extremes = [-lo[0], -lo[1], -lo[2], hi[0], hi[1], hi[2]];
        comm.max(&mut extremes)?;
        let (lo, hi) = ([0, 1, 2].map(|a| -extremes[a]), [0, 1, 2].map(|a| extremes[a + 3]));
        let keys = MortonKeys::new(lo, hi);
        let bucket = |p: [f64; 3]| (keys.key(p) >> (30 - BUCKET_BITS)) as usize;
        let mut per_bucket = vec![0i64; 1 << BUCKET_BITS];
        for &p in self.sites {
            per_bucket[bucket(p)] += 1;
        }
        comm.sum(&mut per_bucket)?;
        // By count, or by the work the last diagram measured.
        let owner = match self.halos.and_then(Halos::work).filter(|w| w.rate.len() == ranks) {
            Some(work) => owners(&weighed(&per_bucket, &work), ranks, MEASURED_SLACK),
            None => owners(&per_bucket, ranks, COUNTED_SLACK),
        };
        drop(per_bucket);
        let weight = |i: usize| self.weights.map_or(0.0, |w| w[i]);
        let (mut own, mut report) = to_owners(comm, self.sites, (first, total), &owner, bucket, weight)?;
        report.owned = own.len() as u64;
        // Duplicates share a key, so a rank holds all of a position's.
        let mut distinct = [distinct_positions(&own) as i64];
        comm.sum(&mut distinct)?;
        // Every rank takes the same number of sub-parts (each a round).
        let mut sub = [self.sub_parts.unwrap_or_else(|| auto_parts(total, ranks)) as f64];
        comm.max(&mut sub)?;
        let sub = sub[0] as usize;
        report.parts = sub as u64;

        // The whole job's frame, quantization and grid.
        let frame = Frame::of(mesh);
        let (l, h) = (frame.to_local(lo), frame.to_local(hi));
        let mut frame_points: Vec<[f64; 3]> = mesh.vertices.iter().map(|&p| frame.to_local(p)).collect();
        frame_points.extend((0..8).map(|c| [0, 1, 2].map(|a| if c >> a & 1 == 0 { l[a] } else { h[a] })));
        let (quantizer, grid) = crate::job::knn::frame_grid(&frame_points, distinct[0] as usize)?;
        let (box_lo, box_hi) = crate::geom::vec3::bounding_box(frame_points.iter());
        let (box_lo, box_hi) = crate::job::clip::start_box(box_lo, box_hi);
        let start_box = (frame.to_world(box_lo), frame.to_world(box_hi));
        drop(frame_points);
        let weights = match span {
            Some([_, largest]) => Some(self.weights_as_one(comm, &own, largest, frame, distinct[0] as usize)?),
            None => None,
        };
        let distinct = distinct[0] as usize;
        let whole_grid = Whole { frame, quantizer, grid, keys, lo, hi, start_box, distinct, weights };
        // This rank's sites in the one process's order, and their cells.
        let mut keyed: Vec<(u32, u64, Held)> = own.par_iter().map(|h| (keys.key(h.at), h.site, *h)).collect();
        keyed.par_sort_unstable_by_key(|k| (k.0, k.1));
        own = keyed.into_iter().map(|k| k.2).collect();
        let own_cells: Vec<[u32; 3]> = own.par_iter().map(|s| whole_grid.cell_of(s.at)).collect();
        timings.push("blocks", clock.elapsed().as_secs_f64());

        // The sub-parts in turn, each one's rows (and the halves of its
        // faces that others' cells share) sent to their readers.
        let kept = match self.spill.filter(|_| self.faces) {
            Some(dir) => Spill::to_file(dir, &format!("rows-{}", comm.rank()))?,
            None => Spill::default(),
        };
        let mut rows = Received::new(first, self.sites.len(), self.faces, kept);
        let mut built = geometry.map(|_| BuiltCells::default());
        let mut pieces_merged = 0;
        let mut counted = vec![0i64; counter_words(&Default::default()).len() + 1];
        let (mut pairing, mut k) = (crate::job::clip::Pairing::Flood, 1);
        let mut phases = Timings::default();
        let own_keys: Vec<u32> = own.iter().map(|h| keys.key(h.at)).collect();
        let runs = cuts_along(own.len(), sub, COUNTED_SLACK, |i| i as i64, |i| own_keys[i]);
        drop(own_keys);
        // Each round's finished cells: their polyhedra, counters and rows
        // (and the halves of their faces others' cells share).
        let mut emit = |round: Round<'_>, counters: Counters| -> Result<RowsAndHalves> {
            let Round { held, cells, pieces, finished, answer } = round;
            for (name, t) in &cells.timings.phases {
                phases.add(name, *t);
            }
            (pairing, k) = (cells.pairing, cells.k);
            for (c, w) in counted.iter_mut().zip(counter_words(&counters)) {
                *c += w;
            }
            let clock = std::time::Instant::now();
            let is_finished = |i: u32| {
                let q = i.wrapping_sub(answer.start as u32);
                finished.binary_search(&q).is_ok()
            };
            if let (Some(built), Some(mut pieces)) = (built.as_mut(), pieces) {
                pieces.retain_sites(is_finished);
                pieces_merged += pieces.len() as u64;
                add_polyhedra(built, pieces, held, cells, visit)?;
                timings.add("polyhedra", clock.elapsed().as_secs_f64());
            }
            let clock = std::time::Instant::now();
            let made = self.rows_of_part(cells, held, answer.start, finished, &reader, ranks)?;
            timings.add("rows", clock.elapsed().as_secs_f64());
            Ok(made)
        };
        // The sub-parts in turn, each in rounds; every rank takes part in
        // each round (the boxes wanted, the rows made, the sites held),
        // with a round of its own or none. (Rounds not kept in step by
        // sub-part pair one rank's costly first round with another's short
        // last one: on three blobs 0.5 s faster, among uniform sites 1 s
        // slower.)
        let own_box = (!own_cells.is_empty()).then(|| cells_box(&own_cells));
        let mut duplicates = 0;
        // The rows a round made, sent in the next.
        let mut made: RowsAndHalves = Default::default();
        for s in 0..sub {
            let run = runs[s]..runs[s + 1];
            // Duplicates: a run holds all of a position's.
            let mut seen = std::collections::HashSet::new();
            duplicates += own[run.clone()].iter().filter(|h| !seen.insert(h.at.map(f64::to_bits))).count() as i64;
            let mut part = self.sub_part(&whole_grid, &own, &own_cells, s, run);
            loop {
                let want = part.want(&whole_grid);
                // Every rank's boxes, once every rank has finished its
                // round: the time a rank waits for the others is said here.
                let (wanted, t) = timed(|| wanted_boxes(comm, want.as_ref(), own_box));
                report.timings.add("waiting", t);
                let (boxes, any) = wanted?;
                // The last round's rows to their readers, before the next
                // job.
                let (to_rows, to_halves) = std::mem::take(&mut made);
                let (sent, t) = timed(|| rows.add(comm, to_rows, to_halves, &mut report.sent));
                report.timings.add("rows", t);
                sent?;
                if !any {
                    break;
                }
                let (held, t) = timed(|| spread(comm, &own, &own_cells, own_box, &boxes, &mut report.sent));
                report.timings.add("exchange", t);
                let held = held?;
                if let Some(set) = want {
                    let on = (backend, geometry);
                    made =
                        self.sub_part_round(on, &whole_grid, &own, &mut part, (set, held), &mut report, &mut emit)?;
                }
            }
        }
        drop(emit);
        if let Some(c) = counted.last_mut() {
            *c += duplicates;
        }
        let clock = std::time::Instant::now();
        let mut rows = MeshRows::of(rows)?;
        let mut cells = rows.take_numbers();
        timings.add("rows", clock.elapsed().as_secs_f64());

        // The run's totals.
        let like = Cells {
            strategy: Strategy::Whole,
            pairing,
            k,
            k_site: self.resolved_k_site(),
            chunks: (ranks * sub) as u64,
            timings: timings.clone(),
            ..Default::default()
        };
        cells = with_totals(comm, counted, cells, mesh.volume(), like)?;
        // The sub-parts' exchanges (timed in the report), then their jobs'.
        for (name, t) in report.timings.phases.iter().chain(&phases.phases) {
            cells.timings.add(name, *t);
        }
        report.timings = cells.timings.clone();
        if let Some(halos) = self.halos {
            // Seconds a site on each rank: its jobs' time over its cells.
            let busy: f64 = phases.phases.iter().map(|p| p.1).sum();
            let rate = busy / report.owned.max(1) as f64;
            let rates = comm.all_gather(&rate.to_le_bytes())?;
            let rate = rates.iter().map(|b| b.as_chunks::<8>().0.first().map_or(0.0, |&w| f64::from_le_bytes(w)));
            halos.set_work(Work { owner, rate: rate.collect() });
        }
        Ok(MeshInParts { cells, rows, built, pieces: pieces_merged, report })
    }

    /// The one process's weights (see [`WholeWeights`]), from every
    /// rank's `own` sites; `largest` is the largest weight of all.
    fn weights_as_one(
        &self,
        comm: &dyn Reduce,
        own: &[Held],
        largest: f64,
        frame: Frame,
        distinct: usize,
    ) -> Result<WholeWeights> {
        let span = kept_span(comm, own, largest)?;
        let scale2 = frame.scale * frame.scale;
        if ((span[1] - span[0]) / scale2).max(0.0) == 0.0 {
            return Ok(WholeWeights { span, grid: None });
        }
        let volume = self.mesh.volume() / frame.scale.powi(3);
        let grid = weight_grid_as_one(comm, own, span, frame, distinct, volume)?;
        Ok(WholeWeights { span, grid })
    }

    /// Sub-part `run` of this rank's sites `own` (in the one process's
    /// order, in grid cells `own_cells`), before its first round: the
    /// groups of its cells its halo goes around, each's first halo.
    fn sub_part(&self, whole: &Whole, own: &[Held], own_cells: &[[u32; 3]], sub: usize, run: Run) -> SubPart {
        let k_site = self.resolved_k_site();
        // A first halo twice as wide as the ball of a cell's list (a cut
        // cell's walk may reach farther), then wider each round where a
        // group's cells need it. The ball at the density of the run's typical grid cell
        // (the median of its occupied cells' sites, at most the grid's
        // mean): where a crowd is packed in tight clusters, most cells are
        // the sparse ones between, whose lists reach farthest, and a halo
        // sized by the mean would be widened, a round more.
        let typical = median_occupancy(&own_cells[run.clone()]).min(crate::job::knn::SITES_PER_CELL);
        let ball = (3.0 * k_site as f64 / (4.0 * std::f64::consts::PI * typical)).cbrt();
        let first_halo = ((2.0 * ball).ceil() as u32).max(1);
        let first_key = own.get(run.start).map(|h| (whole.keys.key(h.at), h.site));
        // The halo goes around groups of the run's cells along the curve,
        // each a compact box, not around the box of them all: a run that
        // crosses sparse space and ends in a cluster would hold most sites
        // in that one box. Each group's halo is widened on its own, where
        // its cells need it (the tails of a cluster alone in a large
        // domain reach far; the rest of the run does not).
        let cells = &own_cells[run.clone()];
        let n_groups = HELD_GROUPS.min(cells.len());
        let starts: Vec<usize> = (0..=n_groups).map(|g| cells.len() * g / n_groups).collect();
        let groups: Vec<([u32; 3], [u32; 3])> = starts.windows(2).map(|w| cells_box(&cells[w[0]..w[1]])).collect();
        // The halos this sub-part's groups last took, if the diagram's
        // caller keeps them (the optimisers' diagrams follow one another,
        // their runs much the same).
        let last = self.halos.map(|h| h.get(sub)).unwrap_or_default();
        let halos: Vec<u32> = (0..n_groups).map(|g| first_halo.max(last.get(g).copied().unwrap_or(0))).collect();
        let done = run.is_empty() || first_key.is_none();
        SubPart { sub, run, first_halo, first_key, starts, groups, halos, covers: Vec::new(), pending: None, done }
    }

    /// A round of sub-part `part`: the cells of its sites still pending,
    /// built in a job holding the sites `held` (every site of the boxes
    /// `set` it asked for), each certified or not; those certified handed
    /// to `emit` (which returns their rows), the others left for the next
    /// round with the boxes they need (see the module's documentation).
    #[allow(clippy::too_many_arguments)]
    fn sub_part_round(
        &self,
        (backend, geometry): (&dyn crate::backend::Backend, Option<&CpuBackend>),
        whole: &Whole,
        own: &[Held],
        part: &mut SubPart,
        (set, held): (HeldSet, Vec<Held>),
        report: &mut PartsReport,
        emit: &mut dyn FnMut(Round<'_>, Counters) -> Result<RowsAndHalves>,
    ) -> Result<RowsAndHalves> {
        let grid = &whole.grid;
        let dims = [grid.dim_x, grid.dim_y, grid.dim_z];
        let k_site = self.resolved_k_site();
        let SubPart { sub, run, first_halo, first_key, starts, halos, covers, pending, done, .. } = part;
        let (sub, first_halo, run, first_key) = (*sub, *first_halo, run.clone(), first_key.unwrap_or_default());
        // The CPU builds only the cells pending again; a device builds every
        // answered cell each round, and only those are taken.
        let rebuild_only = backend.kind() == crate::job::BackendKind::Cpu;
        if let Some(p) = pending {
            report.rebuilt += if rebuild_only { p.len() } else { run.len() } as u64;
        }
        let window = set.bounds;
        let unheld = set.unheld_bits();
        let unheld_cells = unheld.as_ref().map_or(0, |b| b.iter().map(|w| w.count_ones() as u64).sum());
        report.unheld_cells = report.unheld_cells.max(unheld_cells);
        // In the one process's order; then each held site's input index
        // and place only (a part holds many sites around its own).
        let mut keyed: Vec<(u32, u64, Held)> =
            held.into_par_iter().map(|h| (whole.keys.key(h.at), h.site, h)).collect();
        keyed.par_sort_unstable_by_key(|k| (k.0, k.1));
        let start = keyed.partition_point(|k| (k.0, k.1) < first_key);
        let held: Vec<u64> = keyed.iter().map(|k| k.1).collect();
        let at: Vec<[f64; 3]> = keyed.iter().map(|k| k.2.at).collect();
        let weights: Option<Vec<f64>> = self.weights.map(|_| keyed.iter().map(|k| k.2.weight).collect());
        drop(keyed);
        let answer = start..start + run.len();
        if answer.end > held.len() || held[answer.clone()].iter().zip(&own[run.clone()]).any(|(&a, b)| a != b.site) {
            return Err(Error::Internal("a sub-part's sites are not a run of its part's order".into()));
        }
        let order: Vec<u32> = (0..held.len() as u32).collect();
        // The cells built again: the pending ones' places.
        let only: Option<Vec<u32>> = pending
            .as_ref()
            .filter(|_| rebuild_only)
            .map(|p| p.iter().map(|&q| (answer.start + q as usize) as u32).collect());
        let layout = Layout {
            order: &order,
            lo: whole.lo,
            hi: whole.hi,
            grid_sites: whole.distinct,
            answer: (answer.start, answer.end),
            weights: whole.weights.as_ref().map(|w| w.span),
            weight_grid: whole.weights.as_ref().and_then(|w| w.grid.as_ref()),
            window: Window::Held(window),
            unheld: unheld.as_deref(),
            periodic: false,
            only: only.as_deref(),
            halves: true,
        };
        let mut part = ClippedVoronoi { sites: &at, ..*self };
        if let Some(w) = &weights {
            part = part.weights(w);
        }
        let part = part.strategy(Strategy::Whole).backend(backend).layout(layout).keep_reach(k_site);
        // Walks of the pieces' run that left the box (or did not end).
        let mut pieces_left = 0;
        let (mut cells, pieces) = match geometry {
            Some(g) if backend.kind() == crate::job::BackendKind::Cpu => {
                part.compute_with_pieces(g).map(|(c, p)| (c, Some(p)))?
            }
            // A device's cells, the pieces of a run on the CPU (as one
            // process takes them: `ClippedVoronoi::compute_with_geometry`),
            // certified too.
            Some(g) => {
                let cells = part.compute()?;
                let (again, pieces) = part.faces(false).compute_with_pieces(g)?;
                pieces_left = again.counters.out_of_halo + again.counters.unresolved;
                (cells, Some(pieces))
            }
            None => (part.compute()?, None),
        };
        drop(only);
        let pending_place = |i: u32| {
            let q = i.wrapping_sub(answer.start as u32);
            pending.as_ref().map_or((q as usize) < run.len(), |p| p.binary_search(&q).is_ok())
        };
        // Each list certified by the box; none of the walks left it.
        let kept = cells.kept.take().ok_or_else(|| Error::Internal("a part kept no lists".into()))?;
        let listed: Vec<u32> = kept.inputs.iter().copied().filter(|&i| answer.contains(&(i as usize))).collect();
        if listed.len() != kept.kth.len() {
            return Err(Error::Internal(format!("{} lists kept for {} cells", kept.kth.len(), listed.len())));
        }
        let shift = window.shift();
        let clearance = set.clearance();
        let per_world = whole.quantizer.scale() / whole.frame.scale;
        // Each pending cell not certified, with the ball its list needs
        // held.
        let uncertified: Vec<(u32, f64)> = (0..listed.len())
            .into_par_iter()
            .filter(|&u| pending_place(listed[u]))
            .filter_map(|u| {
                let need = kept.kth[u] + 2.0 * (kept.kth[u] - kept.reach[u]).max(0.0);
                let d2 = if need.is_finite() { ((need * per_world).ceil() + 2.0).powi(2) as u64 } else { u64::MAX };
                let q = whole.quantized(at[listed[u] as usize]);
                let certified = set.certifies([0, 1, 2].map(|a| q[a] - shift[a]), d2, clearance.as_deref());
                (!certified).then_some((listed[u], need))
            })
            .collect();
        drop(clearance);
        report.uncertified += uncertified.len() as u64;
        let c = &cells.counters;
        let left = c.out_of_halo + c.unresolved + pieces_left;
        let ends = set.is_whole() || (uncertified.is_empty() && left == 0);
        // A walk that left that the job did not name (a device's
        // pieces, a cell not even the host could finish): no cell of
        // the round is taken.
        let unnamed = left > 0 && (pieces_left > 0 || kept.left.is_empty());
        let failed: Vec<(u32, Option<f64>)> = uncertified
            .into_iter()
            .map(|(i, need)| (i, Some(need)))
            .chain(kept.left.iter().map(|&i| (i, None)))
            .collect();
        if let Some(&(i, _)) = failed.iter().find(|f| !pending_place(f.0)) {
            return Err(Error::Internal(format!("cell {i} of a part left beyond the cells it built")));
        }
        let mut failing: Vec<u32> = failed.iter().map(|f| f.0 - answer.start as u32).collect();
        failing.sort_unstable();
        failing.dedup();
        // The round's finished cells: the pending ones, less those that
        // failed.
        let all_pending = || pending.clone().unwrap_or_else(|| (0..run.len() as u32).collect());
        let finished: Vec<u32> = match (ends, unnamed) {
            (true, _) => all_pending(),
            (false, true) => Vec::new(),
            (false, false) => all_pending().into_iter().filter(|q| failing.binary_search(q).is_err()).collect(),
        };
        // What the finished cells add to the run's counters: on the CPU
        // their kinds, each round's work, and what the last left; a
        // device's last round built every cell.
        let mut counters = cells.counters;
        if rebuild_only && !kept.kinds.is_empty() {
            let kind_of = |q: u32| {
                let i = answer.start as u32 + q;
                listed.binary_search(&i).ok().map_or(crate::job::clip::cell_kind::NONE, |u| kept.kinds[u])
            };
            let count = |kind: u8| finished.iter().filter(|&&q| kind_of(q) == kind).count() as u64;
            counters.whole_cells = count(crate::job::clip::cell_kind::WHOLE);
            counters.cut_cells = count(crate::job::clip::cell_kind::CUT);
            if !ends {
                (counters.out_of_halo, counters.unresolved) = (0, 0);
            }
        } else if !ends {
            counters = Default::default();
        }
        // The lists are read: not kept while the rows are made.
        drop((kept, listed));
        let width = halos.iter().copied().max().unwrap_or(first_halo) as f64 * grid.cell_size as f64 / per_world;
        report.held = report.held.max(held.len() as u64);
        report.halo = report.halo.max(width);
        report.grid_cells = [0, 1].map(|i| report.grid_cells[i].max(cells.grid_cells[i]));
        report.tets = [0, 1].map(|i| report.tets[i].max(cells.tets[i]));
        let round = Round { held: &held, answer: answer.clone(), cells: &cells, pieces, finished: &finished };
        let made = emit(round, counters)?;
        drop(cells);
        if ends {
            if let Some(h) = self.halos {
                h.set(sub, halos.clone());
            }
            *done = true;
            return Ok(made);
        }
        // The groups of the cells not certified and of those whose walks
        // left, and only those (overshooting costs a few groups, not the
        // part), each group a cell wider. A list not certified: the
        // cells of its ball around its site. A walk that left: boxes
        // holding the balls of its cell's vertices among the sites held
        // ([`flower_cover`]: every site that can cut it lies in one, and
        // a walk passes over the cells it does not hold that no site in
        // could cut); where the cell is not known (power cells, cells
        // past the first [`REACH_CELLS`]), its group twice as wide. Every group
        // twice as wide where a walk left that the job did not name (a
        // device's pieces, a cell not even the host could finish).
        let grid_map = GridMap::of(whole);
        // The held sites by cell, where a cell is clipped on the host.
        let near_held = failed.iter().any(|f| f.1.is_none()).then(|| NearHeld::new(&at, &grid_map));
        // Each failing cell's group, whether it is twice as wide, and the
        // boxes the cell adds.
        let wanted: Vec<(usize, bool, Vec<HeldCells>)> = failed
            .par_iter()
            .enumerate()
            .map(|(f, &(i, list))| {
                let place = i as usize - answer.start;
                let group = starts.partition_point(|&s| s <= place) - 1;
                if let Some(need) = list {
                    // The grid cells of the list's ball around its own
                    // site (a group's box about a sparse site is wide).
                    let cells = match need * (1.0 + 1e-3) * grid_map.per_cell {
                        c if c < (u32::MAX - 1) as f64 => c.ceil() as u32 + 1,
                        _ => u32::MAX,
                    };
                    let own = whole.cell_of(at[i as usize]);
                    return Ok((group, false, vec![HeldCells::around(own, own, cells, dims, grid.cell_size)]));
                }
                // Each cell clipped by every site held: for the first
                // `REACH_CELLS` cells only (a few hundred leave a round
                // where any do).
                let cell = match self.weights {
                    Some(_) => None,
                    None if f >= REACH_CELLS => None,
                    None => near_held.as_ref().and_then(|n| {
                        cell_clipped(&at, i as usize, whole.start_box, n.nearest(i as usize, REACH_CLIPPED))
                    }),
                };
                Ok(match cell {
                    Some(cell) => (group, false, flower_cover(&cell, at[i as usize], &grid_map)),
                    None => (group, true, Vec::new()),
                })
            })
            .collect::<Result<_>>()?;
        // Each failing group's new halo at least a cell wider than its
        // last.
        let mut next: Vec<u32> = halos.iter().map(|&h| if unnamed { h.saturating_mul(2) } else { h }).collect();
        let mut seen: std::collections::HashSet<HeldCells> = covers.iter().copied().collect();
        for (g, double, boxes) in wanted {
            let h = halos[g];
            next[g] = next[g].max(if double { h.saturating_mul(2) } else { h }.max(h.saturating_add(1)));
            covers.extend(boxes.into_iter().filter(|b| seen.insert(*b)));
        }
        drop(seen);
        *halos = next;
        report.widened += 1;
        // The cells left for the next round.
        let rest = if unnamed { all_pending() } else { failing };
        *pending = Some(rest);
        Ok(made)
    }

    /// The rows of a round's finished cells (`finished`: places in the
    /// run answered from `first`), each for its site's reader, with their
    /// faces and boundary: each face's two halves where both cells
    /// finished in the round, as one process adds them (the cell's own
    /// first), else the cell's own; and the halves of their faces with
    /// the cells not finished here, for the reader of the other side's
    /// site. The adjacency holds each cell's own halves
    /// ([`Layout::halves`]).
    fn rows_of_part(
        &self,
        whole: &Cells,
        held: &[u64],
        first: usize,
        finished: &[u32],
        reader: &(dyn Fn(u64) -> Option<usize> + Sync),
        ranks: usize,
    ) -> Result<RowsAndHalves> {
        let none = Adjacency { offsets: vec![0], ..Default::default() };
        let a = whole.adjacency().filter(|_| self.faces).unwrap_or(&none);
        let reader_of =
            |site: u64| reader(site).ok_or_else(|| Error::Internal(format!("site {site} beyond the input")));
        let is_finished = |v: usize| v.checked_sub(first).is_some_and(|q| finished.binary_search(&(q as u32)).is_ok());
        // Cell `v`'s own half of its face with `u`, if it has one.
        let half_of = |v: usize, u: u32| {
            let r = a.offsets[v]..a.offsets[v + 1];
            a.neighbors[r.clone()].binary_search(&u).ok().map(|e| a.areas[r.start + e])
        };
        let chunk = |qs: &[u32]| -> Result<RowsAndHalves> {
            let (mut rows, mut halves) = (vec![Vec::new(); ranks], vec![Vec::new(); ranks]);
            for &q in qs {
                let u = first + q as usize;
                let site = held[u];
                let mut faces: Vec<MeshFace> = Vec::new();
                let (mut boundary, mut boundary_vector) = (0.0, [0.0; 3]);
                if self.faces {
                    for (v, own, normal) in a.of(u) {
                        let other = held[v as usize];
                        match is_finished(v as usize).then(|| half_of(v as usize, u as u32)).flatten() {
                            Some(theirs) => faces.push(MeshFace { neighbor: other, area: own + theirs, normal }),
                            None => {
                                faces.push(MeshFace { neighbor: other, area: own, normal });
                                // The one process's, from the other side:
                                // exactly opposite (a zero stays +0).
                                let half = MeshFace { neighbor: site, area: own, normal: normal.map(|c| 0.0 - c) };
                                halves[reader_of(other)?].push(MeshHalf { site: other, face: half });
                            }
                        }
                    }
                    (boundary, boundary_vector) = (a.boundary[u], a.boundary_vector[u]);
                }
                let row = MeshRow {
                    site,
                    volume: whole.volume[u],
                    centroid: whole.centroid[u],
                    energy: whole.energy[u],
                    boundary,
                    boundary_vector,
                    faces: faces.len() as u64,
                };
                let out = &mut rows[reader_of(site)?];
                out.extend_from_slice(bytemuck::bytes_of(&row));
                out.extend_from_slice(bytemuck::cast_slice(&faces));
            }
            Ok((rows, halves))
        };
        let chunks: Vec<_> = finished.par_chunks(1 << 12).map(chunk).collect::<Result<_>>()?;
        let (mut rows, mut halves) = (vec![Vec::new(); ranks], vec![Vec::new(); ranks]);
        for (r, h) in chunks {
            for (to, part) in rows.iter_mut().zip(r) {
                to.extend_from_slice(&part);
            }
            for (to, part) in halves.iter_mut().zip(h) {
                to.extend(part);
            }
        }
        Ok((rows, halves))
    }
}

/// What a diagram in parts leaves the next ([`ClippedVoronoi::halos`]):
/// the optimisers' diagrams follow one another.
///
/// The halos (in grid cells) each group of each sub-part of a rank last
/// took: a group whose cells needed a wider halo than the first (power
/// cells whose weights reach far) starts there next time, not from the
/// first again.
/// And the work each rank measured: the next diagram balances the ranks
/// by it, each bucket of the curve weighed by the time a site took on the
/// rank that last built it (cut cells, tight clusters and sparse space do
/// not cost the same per site). And the mesh prepared for the jobs
/// ([`crate::diagram::voronoi::PreparedMesh`]: its tets' order, its
/// boundary, the whole-cell index), built once for all of them. None
/// changes a bit of the cells, only how many rounds a part takes, which
/// rank builds a cell and how often the mesh is prepared.
#[derive(Debug, Default)]
pub struct Halos {
    halos: std::sync::Mutex<Vec<Vec<u32>>>,
    work: std::sync::Mutex<Option<Work>>,
    mesh: crate::diagram::voronoi::PreparedMesh,
}

/// The work the ranks measured in a diagram: each bucket's rank, and each
/// rank's seconds per site it built (the same on every rank).
#[derive(Clone, Debug, PartialEq)]
struct Work {
    owner: Vec<u32>,
    rate: Vec<f64>,
}

impl Halos {
    fn get(&self, sub: usize) -> Vec<u32> {
        self.halos.lock().unwrap_or_else(|e| e.into_inner()).get(sub).cloned().unwrap_or_default()
    }

    fn set(&self, sub: usize, halos: Vec<u32>) {
        let mut all = self.halos.lock().unwrap_or_else(|e| e.into_inner());
        if all.len() <= sub {
            all.resize(sub + 1, Vec::new());
        }
        all[sub] = halos;
    }

    fn work(&self) -> Option<Work> {
        self.work.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }

    fn set_work(&self, work: Work) {
        *self.work.lock().unwrap_or_else(|e| e.into_inner()) = Some(work);
    }
}

/// Rows and halves, by the rank they go to.
type RowsAndHalves = (Vec<Vec<u8>>, Vec<Vec<MeshHalf>>);

/// What every rank knows of the one process's job: its frame, quantization
/// and grid, its curve over the sites' box, and its distinct sites.
struct Whole {
    frame: Frame,
    quantizer: crate::geom::quantize::Quantizer,
    grid: cvd_kernels::abi::GridParams,
    keys: MortonKeys,
    lo: [f64; 3],
    hi: [f64; 3],
    /// The box the kernels clip a whole cell from, in input units
    /// ([`crate::job::clip::start_box`]).
    start_box: ([f64; 3], [f64; 3]),
    distinct: usize,
    weights: Option<WholeWeights>,
}

/// The one process's power weights: the span it shifts them by, and the
/// grid its local bounds read (none when every weight is the same).
struct WholeWeights {
    span: [f64; 2],
    grid: Option<WeightGrid>,
}

impl Whole {
    fn quantized(&self, p: [f64; 3]) -> cvd_kernels::abi::QuantPoint {
        self.quantizer.quantize(self.frame.to_local(p), 0)
    }

    fn cell_of(&self, p: [f64; 3]) -> [u32; 3] {
        let q = self.quantized(p);
        cvd_kernels::grid::cell_coords(&self.grid, [q[0], q[1], q[2]])
    }
}

/// A cell's row as its reader receives it; its faces follow it.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct MeshRow {
    site: u64,
    volume: f64,
    centroid: [f64; 3],
    energy: f64,
    boundary: f64,
    boundary_vector: [f64; 3],
    faces: u64,
}

/// A face of a row: half its area seen from the cell (the other half
/// comes from the other side's cell, in the same row or as a [`MeshHalf`]).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct MeshFace {
    neighbor: u64,
    area: f64,
    normal: [f64; 3],
}

/// The half of a face a cell sends the reader of the site on its other
/// side.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct MeshHalf {
    site: u64,
    face: MeshFace,
}

/// What a reader received of its rows: each row's numbers, its faces kept
/// (with [`ClippedVoronoi::faces`]) until they are read, in memory or in a
/// file ([`ClippedVoronoi::spill_rows_to`]), and the halves of faces the
/// other sides' cells sent.
struct Received {
    first: u64,
    faces: bool,
    /// Each row's place in `kept` and its count of faces (`u32::MAX`: not
    /// come yet).
    at: Vec<(u64, u32)>,
    /// Each row's volume, centroid and energy.
    numbers: Cells,
    kept: Spill,
    halves: Vec<MeshHalf>,
}

impl Received {
    /// Room for the `len` rows from `first`, their faces (if `faces`) to be
    /// kept in `kept`.
    fn new(first: u64, len: usize, faces: bool, kept: Spill) -> Self {
        let numbers = Cells {
            volume: vec![0.0; len],
            centroid: vec![[0.0; 3]; len],
            energy: vec![0.0; len],
            ..Default::default()
        };
        Self { first, faces, at: vec![(0, u32::MAX); len], numbers, kept, halves: Vec::new() }
    }

    /// One round: `rows` and `halves` to their readers, and this rank's
    /// kept.
    fn add(&mut self, comm: &dyn Reduce, rows: Vec<Vec<u8>>, halves: Vec<Vec<MeshHalf>>, sent: &mut u64) -> Result<()> {
        let me = comm.rank();
        let rows = if rows.is_empty() { vec![Vec::new(); comm.size()] } else { rows };
        let halves = if halves.is_empty() { vec![Vec::new(); comm.size()] } else { halves };
        *sent += rows.iter().enumerate().filter(|&(r, _)| r != me).map(|(_, b)| b.len() as u64).sum::<u64>();
        *sent += halves
            .iter()
            .enumerate()
            .filter(|&(r, _)| r != me)
            .map(|(_, h)| (h.len() * size_of::<MeshHalf>()) as u64)
            .sum::<u64>();
        let got = comm.exchange(Parcels::of(rows))?;
        self.take_rows(got.bytes)?;
        let got =
            comm.exchange(Parcels::of(halves.into_iter().map(|h| bytemuck::cast_slice(&h).to_vec()).collect()))?;
        self.halves.extend(records::<MeshHalf>(&got.bytes));
        Ok(())
    }

    /// The rows in `bytes` (each a [`MeshRow`] and its faces): their
    /// numbers taken, their bytes kept when they have faces.
    fn take_rows(&mut self, bytes: Vec<u8>) -> Result<()> {
        let (first, len) = (self.first, self.at.len());
        let mut found = Vec::new();
        let mut k = 0;
        while k < bytes.len() {
            let head = bytes.get(k..k + size_of::<MeshRow>());
            let row: MeshRow = bytemuck::pod_read_unaligned(
                head.ok_or_else(|| Error::Internal(format!("a row cut short at byte {k} of its parcel")))?,
            );
            let i = row.site.checked_sub(first).map(|i| i as usize).filter(|&i| i < len);
            let i = i.ok_or_else(|| Error::Internal(format!("row {} sent to the reader of {first}..", row.site)))?;
            if self.at[i].1 != u32::MAX {
                return Err(Error::Internal(format!("row {} came back twice", row.site)));
            }
            self.at[i].1 = row.faces as u32;
            (self.numbers.volume[i], self.numbers.centroid[i]) = (row.volume, row.centroid);
            self.numbers.energy[i] = row.energy;
            found.push((i, k));
            k += size_of::<MeshRow>() + row.faces as usize * size_of::<MeshFace>();
        }
        if self.faces && !bytes.is_empty() {
            let at = self.kept.append(bytes)?;
            for (i, k) in found {
                self.at[i].0 = at + k as u64;
            }
        }
        Ok(())
    }
}

impl MeshInParts {
    /// The cells of all this rank's rows with their faces, and the run's
    /// totals.
    pub fn all_rows(&self) -> Result<Cells> {
        Ok(Cells { adjacency: self.rows.cells(&self.cells, 0..self.rows.len())?.adjacency, ..self.cells.clone() })
    }

    /// The particles' quantities (`--voronoi-index`: surface area,
    /// coordination, Voronoi index, largest face order) of this rank's
    /// rows: each cell's measured from its polyhedron on the rank that built
    /// it and sent to the rank that read its site, so the same bits as
    /// [`ParticleCells::of`] on one process's polyhedra (a cell without a
    /// polyhedron, zero). Needs the polyhedra
    /// ([`ClippedVoronoi::compute_in_parts_by_rows`] with `geometry`);
    /// every rank calls it together.
    pub fn particles(&self, comm: &dyn Reduce, thresholds: &IndexThresholds) -> Result<ParticleCells> {
        let built = self
            .built
            .as_ref()
            .ok_or_else(|| Error::InvalidInput("the Voronoi index needs the cells' polyhedra".into()))?;
        let (first, len) = (self.rows.first(), self.rows.len());
        let across = RowsAcross::of(comm, len)?;
        let measured: Vec<Measured> = built
            .polyhedra
            .par_iter()
            .map(|p| {
                let (area, coordination, index, max_face_order) = cell_quantities(p, thresholds);
                Measured { site: p.site as u64, area, coordination, max_face_order, index }
            })
            .collect();
        let mut to = vec![Vec::new(); comm.size()];
        for m in &measured {
            let r =
                across.reader(m.site).ok_or_else(|| Error::Internal(format!("site {} beyond the input", m.site)))?;
            to[r].extend_from_slice(bytemuck::bytes_of(m));
        }
        drop(measured);
        let got = comm.exchange(Parcels::of(to))?;
        let mut out = ParticleCells {
            area: vec![0.0; len],
            coordination: vec![0; len],
            index: vec![[0; INDEX_ORDERS]; len],
            max_face_order: vec![0; len],
        };
        for m in records::<Measured>(&got.bytes) {
            let i = m.site.checked_sub(first).map(|i| i as usize).filter(|&i| i < len);
            let i = i.ok_or_else(|| Error::Internal(format!("site {} sent to the reader of {first}..", m.site)))?;
            (out.area[i], out.coordination[i], out.index[i]) = (m.area, m.coordination, m.index);
            out.max_face_order[i] = m.max_face_order;
        }
        Ok(out)
    }
}

/// A cell's particle quantities, on the way to its site's reader.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct Measured {
    site: u64,
    area: f64,
    coordination: u32,
    max_face_order: u32,
    index: [u32; INDEX_ORDERS],
}

/// A rank's rows of a mesh in parts, as the ranks that built them sent
/// them: read in batches ([`Self::cells`]).
pub struct MeshRows {
    received: Received,
}

impl MeshRows {
    /// The rows `received`, each found.
    fn of(mut received: Received) -> Result<Self> {
        if let Some(i) = received.at.iter().position(|a| a.1 == u32::MAX) {
            return Err(Error::Internal(format!("no cell came back for site {}", received.first + i as u64)));
        }
        received.halves.par_sort_by_key(|h| h.site);
        Ok(Self { received })
    }

    /// This rank's rows.
    pub fn len(&self) -> usize {
        self.received.at.len()
    }

    /// Whether this rank has no rows.
    pub fn is_empty(&self) -> bool {
        self.received.at.is_empty()
    }

    /// The input index of this rank's first row.
    pub fn first(&self) -> u64 {
        self.received.first
    }

    /// Where the rows' faces are kept until read: a file's path, or
    /// "memory".
    pub fn kept_in(&self) -> String {
        self.received.kept.place()
    }

    /// Every row's volume, centroid and energy, taken out (the rank's
    /// [`MeshInParts::cells`] holds them, not these rows too).
    fn take_numbers(&mut self) -> Cells {
        std::mem::take(&mut self.received.numbers)
    }

    /// Rows `range` (of this rank's) as cells with their faces, each row's
    /// faces merged with the halves from the other sides as one process
    /// adds them: the cell's own first, then the other side's; their
    /// volumes, centroids and energies from `numbers` (the rank's
    /// [`MeshInParts::cells`]). Fails where the rows kept in a file cannot
    /// be read back, or `numbers` or these rows have no row of `range`.
    pub fn cells(&self, numbers: &Cells, range: std::ops::Range<usize>) -> Result<Cells> {
        let Received { first, faces, at, kept, halves, .. } = &self.received;
        let n = numbers.volume.len().min(numbers.centroid.len()).min(numbers.energy.len()).min(at.len());
        if range.start > range.end || range.end > n {
            return Err(Error::InvalidInput(format!("rows {range:?} asked of {n}")));
        }
        let mut cells = Cells {
            volume: numbers.volume[range.clone()].to_vec(),
            centroid: numbers.centroid[range.clone()].to_vec(),
            energy: numbers.energy[range.clone()].to_vec(),
            ..Default::default()
        };
        if !faces {
            return Ok(cells);
        }
        let mut adj = Adjacency { offsets: vec![0], ..Default::default() };
        let mut bytes = Vec::new();
        for i in range {
            let (place, count) = at[i];
            kept.read(place, size_of::<MeshRow>() + count as usize * size_of::<MeshFace>(), &mut bytes)?;
            let row: MeshRow = bytemuck::pod_read_unaligned(&bytes[..size_of::<MeshRow>()]);
            let site = first + i as u64;
            if row.site != site {
                return Err(Error::Internal(format!("row {} read back where row {site} was kept", row.site)));
            }
            let own = records::<MeshFace>(&bytes[size_of::<MeshRow>()..]);
            let lo = halves.partition_point(|h| h.site < site);
            let others = halves[lo..].iter().take_while(|h| h.site == site).map(|h| h.face);
            let merged =
                merge_faces(own.chain(others).map(|f| (f.neighbor as u32, [0; 3], f.area, f.normal)).collect());
            for (j, _, area, normal) in merged {
                adj.neighbors.push(j);
                adj.areas.push(area);
                adj.normals.push(normal);
            }
            adj.offsets.push(adj.neighbors.len());
            adj.boundary.push(row.boundary + 0.0);
            adj.boundary_vector.push(row.boundary_vector.map(|v| v + 0.0));
        }
        cells.adjacency = Some(adj);
        Ok(cells)
    }
}

/// The polyhedra of a part's cells (`pieces` of its job over `held`), by
/// input index, added to `built` with their cells' numbers; the pieces,
/// named by input index, handed to `visit`.
fn add_polyhedra(built: &mut BuiltCells, mut pieces: Pieces, held: &[u64], whole: &Cells, visit: Visit) -> Result<()> {
    let mut polyhedra = merge_pieces(&pieces);
    pieces.relabel(|i| held[i as usize] as u32);
    visit(&pieces)?;
    drop(pieces);
    built.numbers.extend(polyhedra.iter().map(|p| {
        let u = p.site as usize;
        (whole.volume[u], whole.centroid[u], whole.energy[u])
    }));
    polyhedra.par_iter_mut().for_each(|p| {
        p.site = held[p.site as usize] as u32;
        for m in &mut p.face_neighbors {
            if let Some(&site) = usize::try_from(*m).ok().and_then(|u| held.get(u)) {
                *m = site as i64;
            }
        }
    });
    built.polyhedra.extend(polyhedra);
    Ok(())
}

/// Each bucket's rank: runs of buckets along the curve, each holding about
/// a rank's share of `counts` (sites, or their measured work), cut where
/// the curve leaves the largest octant it can within `slack` of the share
/// (a run of a whole octant is a box; a run across a big octant's end
/// spans both).
fn owners(counts: &[i64], ranks: usize, slack: f64) -> Vec<u32> {
    let mut before = Vec::with_capacity(counts.len() + 1);
    before.push(0i64);
    for &n in counts {
        before.push(before[before.len() - 1] + n);
    }
    let cuts = cuts_along(counts.len(), ranks, slack, |b| before[b], |b| b as u32);
    let mut owner = vec![0u32; counts.len()];
    for (r, w) in cuts.windows(2).enumerate() {
        owner[w[0]..w[1]].fill(r as u32);
    }
    owner
}

/// Each bucket's sites weighed by the seconds a site took on the rank
/// that last built the bucket's cells (a rank that measured nothing, or
/// far less than the others, at a hundredth of their mean), in units of
/// a thousandth of the mean rate: integer weights for [`owners`].
fn weighed(counts: &[i64], work: &Work) -> Vec<i64> {
    let mean = work.rate.iter().sum::<f64>() / work.rate.len().max(1) as f64;
    if !(mean > 0.0 && mean.is_finite()) || work.owner.len() != counts.len() {
        return counts.to_vec();
    }
    let rate = |r: u32| work.rate.get(r as usize).map_or(mean, |&x| x.clamp(0.01 * mean, 100.0 * mean)) / mean;
    counts.iter().zip(&work.owner).map(|(&n, &r)| (n as f64 * rate(r) * 1000.0).round() as i64).collect()
}

/// `parts + 1` places cutting `0..n` into runs of about equal weight
/// (`before(i)`: the weight before place `i`, growing), each cut where
/// the curve's keys (`key(i)`, growing) change in their highest bit among
/// the places within `slack` of a part's weight of the even cut.
fn cuts_along(
    n: usize,
    parts: usize,
    slack: f64,
    before: impl Fn(usize) -> i64,
    key: impl Fn(usize) -> u32,
) -> Vec<usize> {
    let total = before(n);
    let share = total as f64 / parts as f64;
    let mut cuts = vec![0];
    for p in 1..parts {
        let ideal = share * p as f64;
        let (lo, hi) = (ideal - slack * share, ideal + slack * share);
        // The first place whose weight before it is not below `x` (or
        // above it, with `inclusive`).
        let place = |x: f64, inclusive: bool| {
            let (mut a, mut b) = (0, n + 1);
            while a < b {
                let m = (a + b) / 2;
                let w = before(m) as f64;
                if w < x || (inclusive && w == x) {
                    a = m + 1;
                } else {
                    b = m;
                }
            }
            a
        };
        let even = place(ideal, false);
        let last = *cuts.last().unwrap_or(&0);
        let first = place(lo, false).max(last + 1);
        let end = place(hi, true).min(n);
        let best = (first..end.max(first))
            .filter(|&i| i > 0 && i < n)
            .max_by_key(|&i| (key(i - 1) ^ key(i), std::cmp::Reverse(i.abs_diff(even))))
            .unwrap_or(even.clamp(last, n));
        cuts.push(best.max(last));
    }
    cuts.push(n);
    cuts
}

/// The held cells of the ranks this rank sends sites to, and whether any
/// rank wants any this round. Every rank tells all the bounds of the cells
/// it wants and the box of its own sites' cells (`own`), a few words each;
/// a rank's boxes (a part's groups: thousands) then go only to the ranks
/// whose own cells meet its bounds — the ranks that send it sites, its
/// neighbours — not to all. `None` for a rank that wants nothing or that
/// this rank sends nothing to.
fn wanted_boxes(
    comm: &dyn Reduce,
    want: Option<&HeldSet>,
    own: Option<([u32; 3], [u32; 3])>,
) -> Result<(Vec<Option<HeldSet>>, bool)> {
    let words = |b: &HeldCells| [b.lo, b.dim, b.grid, [b.cell_size, 0, 0]].concat();
    let mut mine = [0u32; 20];
    if let Some(set) = want {
        mine[0] = 1;
        mine[1..13].copy_from_slice(&words(&set.bounds));
    }
    if let Some((lo, hi)) = own {
        mine[13] = 1;
        mine[14..17].copy_from_slice(&lo);
        mine[17..20].copy_from_slice(&hi);
    }
    let bytes: Vec<u8> = mine.iter().flat_map(|w| w.to_le_bytes()).collect();
    let said: Vec<Vec<u32>> = comm
        .all_gather(&bytes)?
        .iter()
        .map(|b| b.as_chunks::<4>().0.iter().map(|c| u32::from_le_bytes(*c)).collect())
        .collect();
    if let Some(w) = said.iter().find(|w| w.len() != 20) {
        return Err(Error::Internal(format!("a rank's wanted bounds came as {} words", w.len())));
    }
    let any = said.iter().any(|w| w[0] == 1);
    // This rank's boxes to each rank whose own cells meet its bounds.
    let to: Vec<Vec<u8>> = said
        .iter()
        .map(|w| match want {
            Some(set) if w[13] == 1 && set.bounds.meets([w[14], w[15], w[16]], [w[17], w[18], w[19]]) => {
                set.boxes.iter().flat_map(words).flat_map(|w| w.to_le_bytes()).collect()
            }
            _ => Vec::new(),
        })
        .collect();
    let got = comm.exchange(Parcels::of(to))?;
    let sets = (0..got.len())
        .map(|r| {
            let b = got.get(r);
            if b.is_empty() {
                return Ok(None);
            }
            let w: Vec<u32> = b.as_chunks::<4>().0.iter().map(|c| u32::from_le_bytes(*c)).collect();
            if !w.len().is_multiple_of(12) {
                return Err(Error::Internal(format!("a rank's boxes came as {} bytes", b.len())));
            }
            let boxes = w
                .chunks(12)
                .map(|w| {
                    let three = |k: usize| [w[k], w[k + 1], w[k + 2]];
                    HeldCells { lo: three(0), dim: three(3), grid: three(6), cell_size: w[9] }
                })
                .collect();
            Ok(Some(HeldSet::of(boxes)))
        })
        .collect::<Result<_>>()?;
    Ok((sets, any))
}

/// Sends each of this rank's own sites (in grid cells `cells`) to every
/// rank whose held cells hold its cell, and returns what this rank
/// received: every site of its held cells. The sites go by runs along the
/// curve, each run looking only at the ranks whose held cells' bounds
/// meet its cells' box (a rank's neighbours, not every rank), and each
/// site's cell up in their masks of held cells (`own_box`: the box of all
/// of `cells`).
fn spread(
    comm: &dyn Reduce,
    own: &[Held],
    cells: &[[u32; 3]],
    own_box: Option<([u32; 3], [u32; 3])>,
    sets: &[Option<HeldSet>],
    sent: &mut u64,
) -> Result<Vec<Held>> {
    // The cells each rank holds, as a mask, for the ranks whose held
    // cells' bounds meet this rank's (a rank's neighbours, not every rank).
    let masks: Vec<Option<HeldMask>> = sets
        .par_iter()
        .map(|set| set.as_ref().filter(|s| own_box.is_some_and(|(lo, hi)| s.bounds.meets(lo, hi))))
        .map(|set| set.map(HeldSet::mask))
        .collect();
    let chunks: Vec<Vec<Vec<Held>>> = own
        .par_chunks(1 << 14)
        .zip(cells.par_chunks(1 << 14))
        .map(|(sites, cells)| {
            let mut to = vec![Vec::new(); sets.len()];
            let (lo, hi) = cells_box(cells);
            let near: Vec<(usize, &HeldMask)> = (masks.iter().enumerate())
                .filter_map(|(r, m)| m.as_ref().filter(|m| m.bounds().meets(lo, hi)).map(|m| (r, m)))
                .collect();
            for (s, c) in sites.iter().zip(cells) {
                for &(r, mask) in &near {
                    if mask.holds(*c) {
                        to[r].push(*s);
                    }
                }
            }
            to
        })
        .collect();
    let mut to: Vec<Vec<Held>> = vec![Vec::new(); sets.len()];
    for chunk in chunks {
        for (r, part) in chunk.into_iter().enumerate() {
            to[r].extend(part);
        }
    }
    send(comm, to, sent)
}

/// The most sites nearest a cell [`cell_among`] clips it by.
const REACH_CLIPPED: usize = 4096;

/// The most cells of a round whose cell is clipped on the host
/// ([`cell_among`]); the groups of the others are twice as wide.
const REACH_CELLS: usize = 1024;

/// Site `u`'s cell among the sites `held` (their places) in the box
/// `(lo, hi)` (the kernels' box of a whole cell), relative to the site:
/// clipped by the held sites nearest it, in order, until the next lies
/// beyond twice its farthest vertex (no site farther can cut it) or after
/// [`REACH_CLIPPED`] of them. More sites only shrink a cell, so this one
/// holds the cell among any sites that include these (a cell clipped by
/// fewer is larger): every site that cuts that one lies nearer one of
/// this one's vertices than its own site ([`flower_cover`]). `None` where
/// it cannot be told (its planes broke down, or nothing of it is left).
#[cfg(test)]
fn cell_among(held: &[[f64; 3]], u: usize, start: ([f64; 3], [f64; 3])) -> Option<Box<cvd_kernels::polyhedron::Cell>> {
    cell_clipped(held, u, start, scan_nearest(held, u))
}

/// Every held site apart from site `u` (squared distance, place).
#[cfg(test)]
fn scan_nearest(held: &[[f64; 3]], u: usize) -> Vec<(f64, u32)> {
    let s = held[u];
    held.iter().enumerate().filter_map(|(j, &h)| (h != s).then_some((distance2(h, s), j as u32))).collect()
}

/// [`cell_among`] from candidates `near` (squared distance, place) that
/// hold the [`REACH_CLIPPED`] sites nearest site `u` (or all of them).
fn cell_clipped(
    held: &[[f64; 3]],
    u: usize,
    (lo, hi): ([f64; 3], [f64; 3]),
    mut near: Vec<(f64, u32)>,
) -> Option<Box<cvd_kernels::polyhedron::Cell>> {
    use crate::geom::vec3::sub;
    use cvd_kernels::glam::{Vec3, Vec4};
    use cvd_kernels::polyhedron::{Cell, Clip};
    let s = *held.get(u)?;
    if near.len() > REACH_CLIPPED {
        near.select_nth_unstable_by(REACH_CLIPPED, |a, b| a.0.total_cmp(&b.0));
        near.truncate(REACH_CLIPPED);
    }
    near.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
    let v = |p: [f64; 3]| Vec3::from(sub(p, s).map(|x| x as f32));
    let mut cell = Box::new(Cell::cuboid(v(lo), v(hi)));
    for (d2, j) in near {
        let r2 = cell.bounds().0 as f64;
        if d2 > 4.0 * r2 * (1.0 + 1e-4) {
            break;
        }
        let p = v(held[j as usize]);
        match cell.clip(Vec4::new(p.x, p.y, p.z, 0.5 * p.length_squared())) {
            Clip::Broken | Clip::Empty => return None,
            // Left unclipped, the cell is only larger: it still bounds.
            Clip::Overflow | Clip::Cut | Clip::Unchanged => {}
        }
    }
    (!cell.is_empty()).then_some(cell)
}

/// The squared distance between two points.
fn distance2(a: [f64; 3], b: [f64; 3]) -> f64 {
    (0..3).map(|k| (a[k] - b[k]) * (a[k] - b[k])).sum()
}

/// A round's held sites by the whole job's grid cells, to find the sites
/// nearest one of them ([`cell_clipped`]'s candidates) without looking at
/// every one.
struct NearHeld<'a> {
    at: &'a [[f64; 3]],
    map: &'a GridMap,
    /// The corner and size of the box of cells the sites lie in.
    lo: [i64; 3],
    dims: [i64; 3],
    /// Each cell's first entry in `order` (and one more: the end).
    start: Vec<u32>,
    order: Vec<u32>,
}

impl<'a> NearHeld<'a> {
    fn new(at: &'a [[f64; 3]], map: &'a GridMap) -> Self {
        let cell = |p: [f64; 3]| map.at(p).map(|c| c.floor() as i64);
        let (mut lo, mut hi) = ([i64::MAX; 3], [i64::MIN; 3]);
        for &p in at {
            let c = cell(p);
            for a in 0..3 {
                (lo[a], hi[a]) = (lo[a].min(c[a]), hi[a].max(c[a]));
            }
        }
        let dims = [0, 1, 2].map(|a| (hi[a] - lo[a] + 1).max(0));
        let index = |c: [i64; 3]| ((c[2] - lo[2]) * dims[1] + (c[1] - lo[1])) * dims[0] + (c[0] - lo[0]);
        let n_cells = dims.iter().product::<i64>() as usize;
        let mut start = vec![0u32; n_cells + 1];
        let cells: Vec<usize> = at.iter().map(|&p| index(cell(p)) as usize).collect();
        for &c in &cells {
            start[c + 1] += 1;
        }
        for c in 0..n_cells {
            start[c + 1] += start[c];
        }
        let mut order = vec![0u32; at.len()];
        let mut next = start.clone();
        for (j, &c) in cells.iter().enumerate() {
            order[next[c] as usize] = j as u32;
            next[c] += 1;
        }
        Self { at, map, lo, dims, start, order }
    }

    /// The held sites apart from site `u` (squared distance, place), ring
    /// of cells after ring around it until they hold the `k` nearest.
    fn nearest(&self, u: usize, k: usize) -> Vec<(f64, u32)> {
        let s = self.at[u];
        let at = self.map.at(s);
        let c = at.map(|x| x.floor() as i64);
        let mut near: Vec<(f64, u32)> = Vec::new();
        let reach = (0..3).map(|a| (c[a] - self.lo[a]).max(self.lo[a] + self.dims[a] - 1 - c[a])).max().unwrap_or(0);
        for r in 0..=reach.max(0) {
            for z in c[2] - r..=c[2] + r {
                for y in c[1] - r..=c[1] + r {
                    let on_ring = (z - c[2]).abs() == r || (y - c[1]).abs() == r;
                    let step = if on_ring { 1 } else { (2 * r).max(1) };
                    let mut x = c[0] - r;
                    while x <= c[0] + r {
                        self.add([x, y, z], s, u, &mut near);
                        x += step;
                    }
                }
            }
            // No site beyond the ring lies nearer than the ring's faces.
            let clear =
                (0..3).map(|a| (at[a] - (c[a] - r) as f64).min((c[a] + r + 1) as f64 - at[a])).fold(f64::MAX, f64::min);
            let clear = clear / self.map.per_cell;
            if near.len() >= k {
                let kth = near.select_nth_unstable_by(k - 1, |a, b| a.0.total_cmp(&b.0)).1 .0;
                if kth <= clear * clear {
                    break;
                }
            }
        }
        near
    }

    /// The sites of cell `c` (if in the box), but site `u` and its place.
    fn add(&self, c: [i64; 3], s: [f64; 3], u: usize, near: &mut Vec<(f64, u32)>) {
        let rel = [0, 1, 2].map(|a| c[a] - self.lo[a]);
        if (0..3).any(|a| rel[a] < 0 || rel[a] >= self.dims[a]) {
            return;
        }
        let i = ((rel[2] * self.dims[1] + rel[1]) * self.dims[0] + rel[0]) as usize;
        for &j in &self.order[self.start[i] as usize..self.start[i + 1] as usize] {
            let p = self.at[j as usize];
            if j as usize != u && p != s {
                near.push((distance2(p, s), j));
            }
        }
    }
}

/// Input points in a grid's cells: continuous cell coordinates.
struct GridMap {
    /// The grid's cells per axis.
    dims: [u32; 3],
    /// A cell's side in quantized units.
    cell_size: u32,
    /// Cells per input unit.
    per_cell: f64,
    /// The input point at the grid's corner.
    origin: [f64; 3],
}

impl GridMap {
    /// The whole job's grid.
    fn of(whole: &Whole) -> Self {
        let g = &whole.grid;
        let per_cell = whole.quantizer.scale() / whole.frame.scale / g.cell_size as f64;
        let origin = whole.frame.to_world(whole.quantizer.origin());
        Self { dims: [g.dim_x, g.dim_y, g.dim_z], cell_size: g.cell_size, per_cell, origin }
    }

    /// Point `p` in cell coordinates (cell `c` spans `c..c + 1`).
    fn at(&self, p: [f64; 3]) -> [f64; 3] {
        [0, 1, 2].map(|a| (p[a] - self.origin[a]) * self.per_cell)
    }
}

/// The most boxes [`flower_cover`] gives a cell.
const COVER_BOXES: usize = 256;

/// Boxes of the whole job's grid cells holding every point nearer a vertex
/// of `cell` (relative to its site `s`, input units) than `s` is: where
/// every site lies that can cut the cell or any smaller one (a walk passes
/// over the other cells it does not hold: [`cvd_kernels::walk::walk_rings`]).
/// Each ball a little wider (a thousandth, and a twentieth of a cell) for
/// the kernels' rounding. Boxes are halved, the largest first, while they
/// meet the balls and lie in none whole, until [`COVER_BOXES`].
fn flower_cover(cell: &cvd_kernels::polyhedron::Cell, s: [f64; 3], grid: &GridMap) -> Vec<HeldCells> {
    let (dims, per_cell, to_grid) = (grid.dims, grid.per_cell, |p| grid.at(p));
    let balls: Vec<([f64; 3], f64)> = cell.verts[..(cell.n_verts as usize).min(cell.verts.len())]
        .iter()
        .map(|v| {
            let p = [v.x as f64, v.y as f64, v.z as f64];
            let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt() * per_cell * (1.0 + 1e-3) + 0.05;
            (to_grid([s[0] + p[0], s[1] + p[1], s[2] + p[2]]), r)
        })
        .collect();
    // A box of cells `lo..=hi` against the balls: (meets one, inside one).
    let test = |lo: [u32; 3], hi: [u32; 3]| {
        let mut meets = false;
        for &(c, r) in &balls {
            let (mut near, mut far) = (0.0, 0.0);
            for a in 0..3 {
                let (l, h) = (lo[a] as f64, hi[a] as f64 + 1.0);
                let gap = (l - c[a]).max(c[a] - h).max(0.0);
                let most = (c[a] - l).abs().max((h - c[a]).abs());
                near += gap * gap;
                far += most * most;
            }
            if far <= r * r {
                return (true, true);
            }
            meets |= near <= r * r;
        }
        (meets, false)
    };
    if balls.is_empty() {
        return Vec::new();
    }
    // The balls' box, in the grid.
    let mut lo = [u32::MAX; 3];
    let mut hi = [0u32; 3];
    for &(c, r) in &balls {
        for a in 0..3 {
            let cell = |x: f64| x.floor().clamp(0.0, (dims[a] - 1) as f64) as u32;
            lo[a] = lo[a].min(cell(c[a] - r));
            hi[a] = hi[a].max(cell(c[a] + r));
        }
    }
    let boxed = |lo: [u32; 3], hi: [u32; 3]| HeldCells::around(lo, hi, 0, dims, grid.cell_size);
    let volume = |lo: [u32; 3], hi: [u32; 3]| (0..3).map(|a| (hi[a] - lo[a] + 1) as u64).product::<u64>();
    let mut done = Vec::new();
    let mut todo = std::collections::BinaryHeap::new();
    match test(lo, hi) {
        (false, _) => return Vec::new(),
        (true, true) => return vec![boxed(lo, hi)],
        (true, false) => todo.push((volume(lo, hi), lo, hi)),
    }
    while let Some((v, lo, hi)) = todo.pop() {
        if v == 1 || done.len() + todo.len() + 2 > COVER_BOXES {
            done.push(boxed(lo, hi));
            continue;
        }
        let a = (0..3).max_by_key(|&a| hi[a] - lo[a]).unwrap_or(0);
        let mid = lo[a] + (hi[a] - lo[a]) / 2;
        let (mut h0, mut l1) = (hi, lo);
        h0[a] = mid;
        l1[a] = mid + 1;
        for (l, h) in [(lo, h0), (l1, hi)] {
            match test(l, h) {
                (false, _) => {}
                (true, true) => done.push(boxed(l, h)),
                (true, false) => todo.push((volume(l, h), l, h)),
            }
        }
    }
    done
}

/// The box of grid cells `cells` (inclusive; empty: `[u32::MAX; 3]` to
/// `[0; 3]`, meeting nothing).
fn cells_box(cells: &[[u32; 3]]) -> ([u32; 3], [u32; 3]) {
    let (mut lo, mut hi) = ([u32::MAX; 3], [0u32; 3]);
    for c in cells {
        for a in 0..3 {
            (lo[a], hi[a]) = (lo[a].min(c[a]), hi[a].max(c[a]));
        }
    }
    (lo, hi)
}

/// The median number of sites of the grid cells `cells` holds a site in
/// (1 if none).
fn median_occupancy(cells: &[[u32; 3]]) -> f64 {
    let mut keys: Vec<u64> =
        cells.par_iter().map(|c| (c[0] as u64) << 42 | (c[1] as u64) << 21 | c[2] as u64).collect();
    keys.par_sort_unstable();
    let mut counts: Vec<u32> = keys.chunk_by(|a, b| a == b).map(|run| run.len() as u32).collect();
    if counts.is_empty() {
        return 1.0;
    }
    let middle = counts.len() / 2;
    *counts.select_nth_unstable(middle).1 as f64
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::backends::distributed::InProcess;
    use crate::geom::mesh::TetMesh;
    use crate::geom::points;

    /// A cell clipped among any subset of the sites holding its own
    /// ([`cell_among`]) has boxes of grid cells ([`flower_cover`]) that hold
    /// every neighbour the one process finds among all the sites: on a
    /// lattice, around a site alone in the box, and on a blob beside sparse
    /// sites (so that the nearest sites it clips by run out before the cell
    /// is told); and a site farther than twice its farthest vertex in none.
    #[test]
    fn a_cells_cover_holds_every_site_that_cuts_it() {
        let unit = ([0.0; 3], [1.0; 3]);
        let map = GridMap { dims: [20; 3], cell_size: 1, per_cell: 20.0, origin: [0.0; 3] };
        let cell_of = |p: [f64; 3]| map.at(p).map(|x| (x.floor() as u32).min(19));
        let covered = |boxes: &[HeldCells], p: [f64; 3]| boxes.iter().any(|b| b.holds(cell_of(p)));
        let lattice: Vec<[f64; 3]> =
            (0..125).map(|i| [i % 5, i / 5 % 5, i / 25].map(|c| (c as f64 + 0.5) / 5.0)).collect();
        let cell = cell_among(&lattice, 62, unit).unwrap();
        let cover = flower_cover(&cell, lattice[62], &map);
        for (j, &p) in lattice.iter().enumerate() {
            let d = [0, 1, 2].map(|a| ((p[a] - 0.5) * 5.0).round().abs() as u32);
            // The cube's 6 face neighbours cut it; 3 cells along an axis do not.
            if d.iter().sum::<u32>() == 1 {
                assert!(covered(&cover, p), "lattice site {j} cuts the centre's cell");
            }
            if d.contains(&2) && d.iter().sum::<u32>() >= 4 {
                assert!(!covered(&cover, p), "lattice site {j} is far beyond the centre's cell");
            }
        }
        let alone = cell_among(&[[0.25, 0.5, 0.5]], 0, unit).unwrap();
        let cover = flower_cover(&alone, [0.25, 0.5, 0.5], &map);
        let all = [[0.0, 0.0, 0.0], [0.999, 0.999, 0.999], [0.999, 0.0, 0.5]];
        assert!(all.iter().all(|&p| covered(&cover, p)), "a site alone: its cell is the box, any site cuts it");

        let mut sites = points::clustered(6000, 1, 0.01, 3);
        sites.retain(|p| p.iter().all(|&x| x > 0.0 && x < 1.0));
        sites.extend(points::uniform(300, 4));
        let mesh = TetMesh::cube(2);
        let one = ClippedVoronoi::new(&mesh, &sites).faces(true).compute().unwrap();
        let a = one.adjacency().unwrap();
        let mut rng = points::Rng::new(5);
        let (mut boxes, mut told) = (0, 0);
        for u in (0..sites.len()).step_by(37) {
            // Every site, or a random third and the cell's own.
            let kept: Vec<usize> = (0..sites.len()).filter(|&j| j == u || rng.below(3) == 0).collect();
            let some: Vec<[f64; 3]> = kept.iter().map(|&j| sites[j]).collect();
            let at = kept.iter().position(|&j| j == u).unwrap();
            for (held, at) in [(&sites, u), (&some, at)] {
                let cell = cell_among(held, at, unit).unwrap();
                let cover = flower_cover(&cell, sites[u], &map);
                assert!(!cover.is_empty() && cover.len() <= COVER_BOXES, "site {u}: {} boxes", cover.len());
                (boxes, told) = (boxes + cover.len(), told + 1);
                for (v, _, _) in a.of(u) {
                    assert!(covered(&cover, sites[v as usize]), "site {u}: neighbour {v} in no box of its cover");
                }
            }
        }
        assert!(boxes > told, "the covers were cut finer than one box each");
    }

    /// `run(rank, comm)` on each of `ranks` ranks, as threads; their
    /// results by rank.
    fn on_ranks<T: Send>(ranks: usize, run: impl Fn(usize, &InProcess) -> T + Sync) -> Vec<T> {
        InProcess::each(ranks, |comm| run(comm.rank(), comm))
    }

    /// The cells of `sites` in `mesh` with their faces, each of `ranks` ranks
    /// reading an even share of the rows, in `per_rank` parts.
    fn in_parts(mesh: &TetMesh, sites: &[[f64; 3]], ranks: usize, per_rank: usize) -> Vec<(Cells, PartsReport)> {
        let rows = |r: usize| sites.len() * r / ranks..sites.len() * (r + 1) / ranks;
        on_ranks(ranks, |r, comm| {
            let cpu = CpuBackend::new(Some(1)).unwrap();
            let cv = ClippedVoronoi::new(mesh, &sites[rows(r)]).faces(true).backend(&cpu);
            cv.parts_per_rank(per_rank).compute_in_parts(comm).unwrap()
        })
    }

    /// Rows `rows` of the one-process cells `one` are `part`'s, bit for bit
    /// (volumes, centroids, energies, faces and boundary).
    fn same_rows(one: &Cells, part: &Cells, rows: std::ops::Range<usize>, what: &str) {
        assert_eq!(part.volume.len(), rows.len(), "{what}: rows");
        let (a, b) = (one.adjacency().unwrap(), part.adjacency().unwrap());
        for (k, i) in rows.enumerate() {
            assert_eq!(one.volume[i].to_bits(), part.volume[k].to_bits(), "{what}: volume of {i}");
            assert_eq!(one.energy[i].to_bits(), part.energy[k].to_bits(), "{what}: energy of {i}");
            assert_eq!(one.centroid[i].map(f64::to_bits), part.centroid[k].map(f64::to_bits), "{what}: centroid {i}");
            let (x, y): (Vec<_>, Vec<_>) = (a.of(i).collect(), b.of(k).collect());
            assert_eq!(x, y, "{what}: faces of {i}");
            assert_eq!(a.boundary[i].to_bits(), b.boundary[k].to_bits(), "{what}: boundary of {i}");
            assert_eq!(a.boundary_vector[i], b.boundary_vector[k], "{what}: boundary vector of {i}");
        }
    }

    /// Every rank's rows and polyhedra are one process's, in a non-convex
    /// domain with a tight cluster in a crowd (cells cut by the boundary,
    /// long walks), a duplicate, and sites on a lattice (distance ties); the
    /// ranks run as threads, each with a run of the input's rows.
    #[test]
    fn a_mesh_with_its_sites_in_parts_gives_the_bits_of_one_process() {
        let mesh = TetMesh::voxels(12, |i, j, _| i < 6 || j < 6);
        let mut sites = points::in_mesh(&mesh, 6000, 21);
        sites.extend(points::clustered(3000, 3, 0.02, 22).into_iter().map(|p| p.map(|x| 0.05 + 0.4 * x)));
        sites.push(sites[17]);
        // Outside the domain: in the L's notch, and beyond the mesh's box.
        sites.extend([[0.8, 0.8, 0.5], [1.2, 0.3, 0.4]]);
        // A lattice in a corner: many equal distances.
        for x in 0..8 {
            for y in 0..8 {
                for z in 0..8 {
                    sites.push([0.6 + 0.03125 * x as f64, 0.1 + 0.03125 * y as f64, 0.5 + 0.03125 * z as f64]);
                }
            }
        }
        let cpu = CpuBackend::new(Some(2)).unwrap();
        let whole = ClippedVoronoi::new(&mesh, &sites).strategy(Strategy::Whole).faces(true);
        let (one, _) = whole.compute_with_polyhedra(&cpu).unwrap();
        let one_polyhedra = one.polyhedra.as_ref().unwrap();
        assert!(one.counters.cut_cells > 0 && one.counters.whole_cells > 0);
        // The second run of each keeps its rows' faces in files there.
        let scratch = std::env::temp_dir().join(format!("cvd-mesh-parts-{}", std::process::id()));
        std::fs::create_dir_all(&scratch).unwrap();
        for (ranks, per_rank) in [(1, 1), (2, 1), (3, 2), (4, 1), (2, 3)] {
            let what = format!("{ranks} ranks x {per_rank} parts");
            let rows = |r: usize| sites.len() * r / ranks..sites.len() * (r + 1) / ranks;
            let runs = on_ranks(ranks, |r, comm| {
                let cpu = CpuBackend::new(Some(1)).unwrap();
                let cv = ClippedVoronoi::new(&mesh, &sites[rows(r)]).faces(true).backend(&cpu).parts_per_rank(per_rank);
                let (cells, report) = cv.compute_in_parts(comm).unwrap();
                let spilled = cv.spill_rows_to(&scratch).compute_in_parts_by_rows(comm, Some(&cpu)).unwrap();
                assert!(spilled.rows.kept_in().starts_with(scratch.to_str().unwrap()), "{}", spilled.rows.kept_in());
                let with = spilled.all_rows().unwrap();
                // Rows past this rank's, or numbers of no row: an error.
                let past = spilled.rows.len() + 1;
                assert!(spilled.rows.cells(&spilled.cells, 0..past).is_err());
                assert!(spilled.rows.cells(&Cells::default(), 0..1).is_err() || spilled.rows.is_empty());
                (cells, report, with, spilled.built.unwrap())
            });
            assert_eq!(std::fs::read_dir(&scratch).unwrap().count(), 0, "{what}: no spill file left behind");
            let mut polyhedra: Vec<_> = runs.iter().flat_map(|r| r.3.polyhedra.iter().cloned()).collect();
            polyhedra.sort_by_key(|p| p.site);
            assert!(polyhedra == *one_polyhedra, "{what}: the ranks' polyhedra are one process's, each once");
            let owned: u64 = runs.iter().map(|r| r.1.owned).sum();
            assert_eq!(owned, sites.len() as u64, "{what}: every site owned once");
            for (r, (cells, _, with, built)) in runs.iter().enumerate() {
                same_rows(&one, cells, rows(r), &what);
                same_rows(&one, with, rows(r), &format!("{what}, with polyhedra, the rows spilled"));
                assert_eq!(one.total_volume.to_bits(), cells.total_volume.to_bits(), "{what}: total volume");
                assert_eq!(
                    (one.counters.whole_cells, one.counters.cut_cells, one.counters.duplicate_sites),
                    (cells.counters.whole_cells, cells.counters.cut_cells, cells.counters.duplicate_sites),
                    "{what}"
                );
                for (p, n) in built.polyhedra.iter().zip(&built.numbers) {
                    let i = p.site as usize;
                    assert_eq!(n.0.to_bits(), one.volume[i].to_bits(), "{what}: a polyhedron's cell's volume");
                }
            }
        }
        std::fs::remove_dir(&scratch).unwrap();
    }

    /// Power cells in parts are one process's: weights that drift across
    /// the domain over a few spacings² with noise (the local weight bounds
    /// matter), a duplicate lighter than its twin, a cluster; then weights
    /// spread far wider than the spacing (walks beyond any first halo).
    #[test]
    fn power_cells_in_parts_give_the_bits_of_one_process() {
        let mesh = TetMesh::voxels(10, |i, j, _| i < 5 || j < 5);
        let mut sites = points::in_mesh(&mesh, 4000, 31);
        sites.extend(points::clustered(1500, 2, 0.02, 32).into_iter().map(|p| p.map(|x| 0.05 + 0.4 * x)));
        sites.push(sites[11]);
        let noise = points::uniform(sites.len(), 33);
        let cpu = CpuBackend::new(Some(2)).unwrap();
        for spread in [0.004, 0.3] {
            let mut weights: Vec<f64> =
                sites.iter().zip(&noise).map(|(p, n)| spread * (p[0] + 0.5 * p[2] + n[0])).collect();
            let last = weights.len() - 1;
            weights[last] = weights[11] - 0.5 * spread;
            let whole = ClippedVoronoi::new(&mesh, &sites).strategy(Strategy::Whole).faces(true).weights(&weights);
            let one = whole.backend(&cpu).compute().unwrap();
            assert!(one.counters.empty_cells > 0 || spread < 0.1, "spread {spread}: heavy weights empty some cells");
            for (ranks, per_rank) in [(1, 1), (2, 1), (3, 2), (4, 1)] {
                let what = format!("spread {spread}, {ranks} ranks x {per_rank} parts");
                let rows = |r: usize| sites.len() * r / ranks..sites.len() * (r + 1) / ranks;
                let runs = on_ranks(ranks, |r, comm| {
                    let cpu = CpuBackend::new(Some(1)).unwrap();
                    let cv = ClippedVoronoi::new(&mesh, &sites[rows(r)]).faces(true).weights(&weights[rows(r)]);
                    cv.backend(&cpu).parts_per_rank(per_rank).compute_in_parts(comm).unwrap()
                });
                for (r, (cells, _)) in runs.iter().enumerate() {
                    same_rows(&one, cells, rows(r), &what);
                    assert_eq!(one.total_volume.to_bits(), cells.total_volume.to_bits(), "{what}: total volume");
                    assert_eq!(one.counters.empty_cells, cells.counters.empty_cells, "{what}: empty cells");
                }
            }
        }
    }

    /// A density over the mesh: every cell cut into its tets' pieces, its
    /// mass, centroid and energy weighted, the same bits as one process
    /// with whole cells and the density.
    #[test]
    fn a_density_in_parts_gives_the_bits_of_one_process() {
        let mesh = TetMesh::voxels(8, |i, j, _| i < 4 || j < 4);
        let mut sites = points::in_mesh(&mesh, 2500, 41);
        sites.extend(points::clustered(600, 2, 0.02, 42).into_iter().map(|p| p.map(|x| 0.05 + 0.3 * x)));
        // Twenty times denser at one corner than at the other.
        let rho: Vec<f64> = mesh.vertices.iter().map(|v| 1.0 + 19.0 * v[0] * v[1]).collect();
        let cpu = CpuBackend::new(Some(2)).unwrap();
        let whole = ClippedVoronoi::new(&mesh, &sites).strategy(Strategy::Whole).faces(true).density(Some(&rho));
        let one = whole.backend(&cpu).compute().unwrap();
        let plain = ClippedVoronoi::new(&mesh, &sites).strategy(Strategy::Whole).backend(&cpu).compute().unwrap();
        assert!(one.total_volume > 2.0 * plain.total_volume, "the density weighs the masses");
        for (ranks, per_rank) in [(2, 1), (3, 2)] {
            let what = format!("{ranks} ranks x {per_rank} parts");
            let rows = |r: usize| sites.len() * r / ranks..sites.len() * (r + 1) / ranks;
            let runs = on_ranks(ranks, |r, comm| {
                let cpu = CpuBackend::new(Some(1)).unwrap();
                let cv = ClippedVoronoi::new(&mesh, &sites[rows(r)]).faces(true).density(Some(&rho));
                cv.strategy(Strategy::Whole).backend(&cpu).parts_per_rank(per_rank).compute_in_parts(comm).unwrap()
            });
            for (r, (cells, _)) in runs.iter().enumerate() {
                same_rows(&one, cells, rows(r), &what);
                assert_eq!(one.total_volume.to_bits(), cells.total_volume.to_bits(), "{what}: total mass");
            }
        }
    }

    /// The Voronoi index in parts: each cell measured where it was built
    /// and sent to its reader, the same numbers as one process's.
    #[test]
    fn the_voronoi_index_in_parts_is_one_process_index() {
        let mesh = TetMesh::voxels(8, |i, j, _| i < 4 || j < 4);
        let mut sites = points::in_mesh(&mesh, 2500, 51);
        sites.extend(points::clustered(500, 2, 0.02, 52).into_iter().map(|p| p.map(|x| 0.1 + 0.3 * x)));
        let thresholds = IndexThresholds { relative_face: 0.01, ..Default::default() };
        let cpu = CpuBackend::new(Some(2)).unwrap();
        let (one, _) =
            ClippedVoronoi::new(&mesh, &sites).strategy(Strategy::Whole).compute_with_polyhedra(&cpu).unwrap();
        let expected = ParticleCells::of(sites.len(), one.polyhedra().unwrap(), &thresholds);
        assert!(expected.coordination.iter().filter(|&&c| c > 0).count() > sites.len() * 9 / 10);
        for (ranks, per_rank) in [(2, 1), (3, 2)] {
            let rows = |r: usize| sites.len() * r / ranks..sites.len() * (r + 1) / ranks;
            let runs = on_ranks(ranks, |r, comm| {
                let cpu = CpuBackend::new(Some(1)).unwrap();
                let cv = ClippedVoronoi::new(&mesh, &sites[rows(r)]).backend(&cpu).parts_per_rank(per_rank);
                cv.compute_in_parts_by_rows(comm, Some(&cpu)).unwrap().particles(comm, &thresholds).unwrap()
            });
            for (r, got) in runs.iter().enumerate() {
                for (k, i) in rows(r).enumerate() {
                    let what = format!("{ranks} ranks x {per_rank} parts: site {i}");
                    assert_eq!(got.area[k].to_bits(), expected.area[i].to_bits(), "{what}: area");
                    assert_eq!(got.coordination[k], expected.coordination[i], "{what}: coordination");
                    assert_eq!(got.index[k], expected.index[i], "{what}: index");
                    assert_eq!(got.max_face_order[k], expected.max_face_order[i], "{what}");
                }
            }
        }
    }

    /// Tight clusters in a sparse crowd: the first halo is sized for the
    /// sparse cells between the clusters, so no part is computed twice.
    #[test]
    fn a_clustered_crowd_takes_its_first_halo() {
        let mesh = TetMesh::voxels(6, |_, _, _| true);
        let mut sites = points::clustered(24_000, 6, 0.03, 61);
        sites.retain(|p| p.iter().all(|&x| x > 1e-3 && x < 1.0 - 1e-3));
        sites.extend(points::in_mesh(&mesh, 5_000, 62));
        let cpu = CpuBackend::new(Some(2)).unwrap();
        let one = ClippedVoronoi::new(&mesh, &sites).strategy(Strategy::Whole).faces(true).backend(&cpu).compute();
        let one = one.unwrap();
        for (ranks, per_rank) in [(2, 1), (2, 2), (4, 1)] {
            let rows = |r: usize| sites.len() * r / ranks..sites.len() * (r + 1) / ranks;
            let runs = in_parts(&mesh, &sites, ranks, per_rank);
            for (r, (cells, report)) in runs.iter().enumerate() {
                same_rows(&one, cells, rows(r), &format!("{ranks} ranks x {per_rank}"));
                assert_eq!(report.widened, 0, "{ranks} ranks x {per_rank}: rank {r} widened its halo ({report:?})");
            }
        }
    }

    /// Clusters alone in a large domain: their tails' cells reach the
    /// domain's empty corners, walk out of any first halo and are not
    /// certified; the groups they are in are widened (each on its own,
    /// round after round) until they finish, and the rows are one
    /// process's to the bit.
    #[test]
    fn clusters_alone_in_a_large_domain_widen_where_their_tails_are() {
        let mesh = TetMesh::voxels(4, |_, _, _| true);
        let mut sites: Vec<[f64; 3]> =
            points::clustered(6_000, 3, 0.05, 81).into_iter().map(|p| p.map(|x| 0.3 + 0.4 * x)).collect();
        sites.retain(|p| p.iter().all(|&x| x > 1e-3 && x < 1.0 - 1e-3));
        let cpu = CpuBackend::new(Some(2)).unwrap();
        let one = ClippedVoronoi::new(&mesh, &sites).strategy(Strategy::Whole).faces(true).backend(&cpu).compute();
        let one = one.unwrap();
        for (ranks, per_rank) in [(2, 1), (2, 2), (3, 1)] {
            let what = format!("{ranks} ranks x {per_rank}");
            let rows = |r: usize| sites.len() * r / ranks..sites.len() * (r + 1) / ranks;
            let runs = in_parts(&mesh, &sites, ranks, per_rank);
            for (r, (cells, _)) in runs.iter().enumerate() {
                same_rows(&one, cells, rows(r), &what);
                assert_eq!(one.total_volume.to_bits(), cells.total_volume.to_bits(), "{what}: total volume");
                assert_eq!(
                    (one.counters.whole_cells, one.counters.cut_cells),
                    (cells.counters.whole_cells, cells.counters.cut_cells),
                    "{what}: each cell counted once"
                );
            }
            assert!(runs.iter().any(|r| r.1.widened > 0), "{what}: the tails widened their groups");
            // A later round builds again the cells that reached past what
            // their part held, not the part.
            let rebuilt: u64 = runs.iter().map(|r| r.1.rebuilt).sum();
            let n = sites.len() as u64;
            println!("{what}: {rebuilt} cells of {n} built again");
            assert!(rebuilt > 0 && rebuilt * 20 < n, "{what}: {rebuilt} cells of {n} built again");
        }
    }

    /// The held sites by cell find the sites nearest one as a scan of them
    /// all does: from inside a blob and from the sparse sites around it,
    /// and where there are fewer sites than asked for.
    #[test]
    fn held_sites_by_cell_find_the_nearest_as_a_scan() {
        let mesh = TetMesh::voxels(4, |_, _, _| true);
        let mut at = points::clustered(3_000, 1, 0.03, 5);
        at.extend(points::in_mesh(&mesh, 300, 9));
        let map = GridMap { dims: [10; 3], cell_size: 1, per_cell: 10.0, origin: [0.0; 3] };
        let near = NearHeld::new(&at, &map);
        for u in [0, 1_500, 2_999, 3_000, 3_150, 3_299] {
            for k in [1, 48, REACH_CLIPPED] {
                let firsts = |mut all: Vec<(f64, u32)>| {
                    all.sort_by(|a, b| a.0.total_cmp(&b.0));
                    all.truncate(k);
                    all.into_iter().map(|e| e.0).collect::<Vec<_>>()
                };
                assert_eq!(firsts(near.nearest(u, k)), firsts(scan_nearest(&at, u)), "site {u}, k = {k}");
            }
        }
    }

    /// A part holds the grid cells around groups of its own cells, not the
    /// box around them all: in a crowd of tight clusters its box holds
    /// cells it does not hold, marked so that a walk that must look at one
    /// gives up and a list whose ball reaches one is not certified; the
    /// rows are still one process's to the bit, and the parts hold fewer
    /// sites than their boxes do.
    #[test]
    fn a_part_holds_the_cells_around_its_own_not_their_box() {
        let mesh = TetMesh::voxels(4, |_, _, _| true);
        let mut sites = points::clustered(60_000, 8, 0.015, 71);
        sites.retain(|p| p.iter().all(|&x| x > 1e-3 && x < 1.0 - 1e-3));
        sites.extend(points::in_mesh(&mesh, 3_000, 72));
        let cpu = CpuBackend::new(Some(2)).unwrap();
        let mut unheld = 0;
        // Short lists (k_site 8): the first halo is thin, and cells walk
        // past their lists, up to the cells their parts do not hold.
        let one_process = |k_site| {
            let whole = ClippedVoronoi::new(&mesh, &sites).strategy(Strategy::Whole).faces(true).k_site(k_site);
            whole.backend(&cpu).compute().unwrap()
        };
        let (long, short) = (one_process(48), one_process(8));
        for (ranks, per_rank, k_site) in [(2, 1, 48), (3, 2, 48), (4, 1, 48), (3, 2, 8), (4, 1, 8)] {
            let what = format!("{ranks} ranks x {per_rank}, k_site {k_site}");
            let one = if k_site == 8 { &short } else { &long };
            let rows = |r: usize| sites.len() * r / ranks..sites.len() * (r + 1) / ranks;
            let runs = on_ranks(ranks, |r, comm| {
                let cpu = CpuBackend::new(Some(1)).unwrap();
                let cv = ClippedVoronoi::new(&mesh, &sites[rows(r)]).faces(true).k_site(k_site).backend(&cpu);
                cv.parts_per_rank(per_rank).compute_in_parts(comm).unwrap()
            });
            for (r, (cells, report)) in runs.iter().enumerate() {
                same_rows(one, cells, rows(r), &what);
                unheld += report.unheld_cells;
            }
        }
        assert!(unheld > 0, "no part's box held a cell it did not hold");
    }

    /// A rank whose sites took twice as long per site as the other's
    /// gets fewer of them in the next diagram.
    #[test]
    fn ranks_are_balanced_by_the_work_they_measured() {
        let counts = vec![10i64; 1 << 10];
        let share = |owner: &[u32]| owner.iter().filter(|&&r| r == 0).count() as f64 / owner.len() as f64;
        let by_count = owners(&counts, 2, COUNTED_SLACK);
        assert!((share(&by_count) - 0.5).abs() <= 0.05, "{}", share(&by_count));
        // Its buckets weigh twice: it takes 3/8 of the sites (then, the
        // rates measured again, 1/3).
        let work = Work { owner: by_count.clone(), rate: vec![2e-5, 1e-5] };
        let by_work = owners(&weighed(&counts, &work), 2, MEASURED_SLACK);
        assert!((share(&by_work) - 0.375).abs() <= 0.05, "{}", share(&by_work));
        // Nothing measured: by count. A rank that measured nothing: its
        // buckets at a hundredth of the mean, so it takes them all and
        // half the other's (3/4).
        let none = Work { owner: by_count.clone(), rate: vec![0.0, 0.0] };
        assert_eq!(owners(&weighed(&counts, &none), 2, COUNTED_SLACK), by_count);
        let idle = Work { owner: by_count.clone(), rate: vec![0.0, 1e-5] };
        let idle = share(&owners(&weighed(&counts, &idle), 2, MEASURED_SLACK));
        assert!((idle - 0.75).abs() <= 0.05, "{idle}");
    }

    /// A crowd in a cube: each rank holds its share of the sites and a
    /// halo, not every site, and the tets its cells may meet, not the
    /// mesh; its rows are one process's.
    #[test]
    fn the_ranks_hold_their_share_and_a_halo() {
        let mesh = TetMesh::voxels(6, |_, _, _| true);
        let sites = points::in_mesh(&mesh, 40_000, 5);
        let cpu = CpuBackend::new(Some(2)).unwrap();
        let one = ClippedVoronoi::new(&mesh, &sites).strategy(Strategy::Whole).faces(true).backend(&cpu).compute();
        let one = one.unwrap();
        for (ranks, most) in [(2, 0.75), (4, 0.6)] {
            let rows = |r: usize| sites.len() * r / ranks..sites.len() * (r + 1) / ranks;
            let runs = on_ranks(ranks, |r, comm| {
                let cpu = CpuBackend::new(Some(1)).unwrap();
                ClippedVoronoi::new(&mesh, &sites[rows(r)]).faces(true).backend(&cpu).compute_in_parts(comm).unwrap()
            });
            for (r, (cells, report)) in runs.iter().enumerate() {
                same_rows(&one, cells, rows(r), &format!("{ranks} ranks"));
                let share = report.held as f64 / sites.len() as f64;
                assert!(share < most, "{ranks} ranks: rank {r} holds {share:.2} of the sites ({report:?})");
                // Its jobs held the tets their cells may meet, not the mesh.
                let [part, all] = report.tets;
                assert_eq!(all, mesh.tets.len() as u64);
                let tets = part as f64 / all as f64;
                assert!(tets < most + 0.1, "{ranks} ranks: rank {r} held {tets:.2} of the tets ({report:?})");
            }
        }
    }
}
