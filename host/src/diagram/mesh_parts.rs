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
//!   ([`HeldCells::certifies`]), and a grid walk that must look at a cell
//!   outside gives up (`Counters::out_of_halo`). A rank with a cell not
//!   certified asks again with a halo half as wide again (at most the
//!   whole grid, which certifies every cell);
//! - sends each row, with its faces (the other side's halves from the rank
//!   that built that side, as one process adds them), to the rank that
//!   read its site.
//!
//! Power cells and densities are not laid out so yet (their local weight
//! bounds and pieces read all sites): refused by name.

use super::periodic_parts::{
    at_row, counter_words, counters_of, faces_of, halves, rows_of, send, BuiltCells, FaceRow, Held, PartsReport, Row,
};
use crate::backends::distributed::{Parcels, Reduce};
use crate::diagram::voronoi::{Cells, ClippedVoronoi};
use crate::error::{Error, Result};
use crate::exec::CpuBackend;
use crate::geom::exact_sum::ExactSum;
use crate::geom::points::MortonKeys;
use crate::geom::timing::{timed, Timings};
use crate::job::clip::{Frame, JobShape, Strategy};
use crate::job::held::HeldCells;
use crate::job::sites::{Layout, Window};
use crate::passes::faces::Adjacency;
use crate::passes::polyhedra::merge_pieces;
use rayon::prelude::*;

/// The Morton key's bits that number a bucket (5 per axis).
const BUCKET_BITS: u32 = 15;

/// What a rank gives back.
struct MeshPartsOut {
    cells: Cells,
    built: Option<BuiltCells>,
    report: PartsReport,
}

/// A rank's part job and what it computed.
struct Part {
    held: Vec<Held>,
    answer: std::ops::Range<usize>,
    cells: Cells,
    pieces: Option<crate::passes::pieces::Pieces>,
    width: f64,
}

impl ClippedVoronoi<'_> {
    /// This rank's part of the diagram of the sites of all ranks of `comm`
    /// in the mesh (see the module's documentation): `self`'s sites are
    /// this rank's rows of the input, the rows of rank 0 first, then rank
    /// 1's, and so on; every rank holds the same mesh. Returns the cells of
    /// this rank's rows — the same bits as the diagram of all the sites in
    /// one process with whole cells, neighbours by input index (with
    /// [`Self::faces`]) — with the run's totals, and what the part did.
    /// Whole cells on the CPU; no weights or density yet.
    pub fn compute_in_parts(&self, comm: &dyn Reduce) -> Result<(Cells, PartsReport)> {
        let out = self.mesh_in_parts(comm, None)?;
        Ok((out.cells, out.report))
    }

    /// [`Self::compute_in_parts`] with the polyhedra of the cells this rank
    /// built (its sites' along the curve, not its rows), on `cpu`, each by
    /// its site's input index with its cell's volume, centroid and energy.
    pub fn compute_in_parts_with_polyhedra(
        &self,
        comm: &dyn Reduce,
        cpu: &CpuBackend,
    ) -> Result<(Cells, BuiltCells, PartsReport)> {
        let out = self.mesh_in_parts(comm, Some(cpu))?;
        let built = out.built.ok_or_else(|| Error::Internal("no polyhedra came back".into()))?;
        Ok((out.cells, built, out.report))
    }

    fn mesh_in_parts(&self, comm: &dyn Reduce, geometry: Option<&CpuBackend>) -> Result<MeshPartsOut> {
        let mesh = self.mesh;
        if mesh.tets.is_empty() {
            return Err(Error::InvalidInput("the mesh has no tets".into()));
        }
        if self.weights.is_some() || self.density.is_some() {
            return Err(Error::InvalidInput(
                "a mesh with its sites in parts takes no weights or density yet; give every rank the whole input"
                    .into(),
            ));
        }
        let own_cpu;
        let cpu: &dyn crate::backend::Backend = match (geometry, self.backend) {
            (Some(cpu), _) => cpu,
            (None, Some(b)) if b.kind() == crate::job::BackendKind::Cpu => b,
            (None, Some(_)) => {
                return Err(Error::InvalidInput("a mesh with its sites in parts runs on the CPU backend".into()))
            }
            (None, None) => {
                own_cpu = CpuBackend::new(None)?;
                &own_cpu
            }
        };
        let (rank, ranks) = (comm.rank(), comm.size());
        let mut timings = Timings::default();
        let clock = std::time::Instant::now();
        let counts = comm.gather_u64(self.sites.len() as u64)?;
        let first: u64 = counts[..rank].iter().sum();
        let total: u64 = counts.iter().sum();
        if total == 0 {
            return Err(Error::InvalidInput("there are no sites".into()));
        }
        if !self.sites.is_empty() {
            crate::job::sites::check_sites(self.sites, None).map_err(|e| at_row(e, first))?;
        }
        let shape = JobShape { density: false, sites: total as usize, tets: mesh.tets.len() };
        if Self::strategy_for(self.strategy, Some(cpu), shape) != Strategy::Whole {
            return Err(Error::InvalidInput("a mesh with its sites in parts is computed with whole cells".into()));
        }
        let reader = |site: u64| {
            let mut at = 0;
            counts.iter().position(|&c| {
                at += c;
                site < at
            })
        };

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
        let owner = owners(&per_bucket, ranks);
        drop(per_bucket);
        let mut report = PartsReport {
            rank,
            ranks,
            first,
            read: self.sites.len() as u64,
            total,
            blocks: [owner.len() as u64, owner.iter().filter(|&&r| r as usize == rank).count() as u64],
            ..Default::default()
        };
        let mut to = vec![Vec::new(); ranks];
        for (i, &p) in self.sites.iter().enumerate() {
            let r = owner[bucket(p)] as usize;
            to[r].push(Held::site(p, first + i as u64, 0.0, r));
        }
        let own: Vec<Held> = send(comm, to, &mut report.sent)?;
        report.owned = own.len() as u64;
        // Duplicates share a key, so a rank holds all of a position's.
        let mut distinct = [distinct_positions(&own) as i64];
        comm.sum(&mut distinct)?;

        // The whole job's frame, quantization and grid.
        let frame = Frame::of(mesh);
        let (l, h) = (frame.to_local(lo), frame.to_local(hi));
        let mut frame_points: Vec<[f64; 3]> = mesh.vertices.iter().map(|&p| frame.to_local(p)).collect();
        frame_points.extend((0..8).map(|c| [0, 1, 2].map(|a| if c >> a & 1 == 0 { l[a] } else { h[a] })));
        let (quantizer, grid) = crate::job::knn::frame_grid(&frame_points, distinct[0] as usize)?;
        drop(frame_points);
        let dims = [grid.dim_x, grid.dim_y, grid.dim_z];
        let quantized = |p: [f64; 3]| quantizer.quantize(frame.to_local(p), 0);
        let cell_of = |p: [f64; 3]| {
            let q = quantized(p);
            cvd_kernels::grid::cell_coords(&grid, [q[0], q[1], q[2]])
        };
        let own_cells: Vec<[u32; 3]> = own.par_iter().map(|s| cell_of(s.at)).collect();
        let (mut clo, mut chi) = ([u32::MAX; 3], [0u32; 3]);
        for c in &own_cells {
            for a in 0..3 {
                clo[a] = clo[a].min(c[a]);
                chi[a] = chi[a].max(c[a]);
            }
        }
        // One world unit in quantized units, and a cell's side in the world.
        let per_world = quantizer.scale() / frame.scale;
        let cell_side = grid.cell_size as f64 / per_world;
        let k_site = self.resolved_k_site();
        // A first halo a little wider than the ball of a cell's list (at
        // the grid's mean density), then half as wide again each round.
        let ball = (3.0 * k_site as f64 / (4.0 * std::f64::consts::PI * crate::job::knn::SITES_PER_CELL)).cbrt();
        let mut halo = ((1.3 * ball).ceil() as u32).max(1);
        timings.push("blocks", clock.elapsed().as_secs_f64());

        let mut done: Option<Part> = None;
        loop {
            let want =
                (done.is_none() && !own.is_empty()).then(|| HeldCells::around(clo, chi, halo, dims, grid.cell_size));
            let boxes = wanted_boxes(comm, want)?;
            if boxes.iter().all(Option::is_none) {
                break;
            }
            let (held, t) = timed(|| spread(comm, &own, &own_cells, &boxes, &mut report.sent));
            timings.add("exchange", t);
            let Some(window) = want else { continue };
            let mut held = held?;
            let clock = std::time::Instant::now();
            let mut keyed: Vec<(u32, u64, Held)> = held.par_iter().map(|h| (keys.key(h.at), h.site, *h)).collect();
            keyed.par_sort_unstable_by_key(|k| (k.0, k.1));
            held = keyed.into_iter().map(|k| k.2).collect();
            let start = held.iter().position(|h| h.rank as usize == rank).unwrap_or(0);
            let answer = start..start + held[start..].iter().take_while(|h| h.rank as usize == rank).count();
            if answer.len() != own.len() {
                return Err(Error::Internal(format!(
                    "{} of this rank's {} sites are a run of its part's order",
                    answer.len(),
                    own.len()
                )));
            }
            timings.add("order", clock.elapsed().as_secs_f64());
            let at: Vec<[f64; 3]> = held.iter().map(|h| h.at).collect();
            let order: Vec<u32> = (0..held.len() as u32).collect();
            let layout = Layout {
                order: &order,
                lo,
                hi,
                grid_sites: distinct[0] as usize,
                answer: (answer.start, answer.end),
                weights: None,
                window: Window::Held(window),
                periodic: false,
            };
            let part = ClippedVoronoi { sites: &at, ..*self }
                .strategy(Strategy::Whole)
                .backend(cpu)
                .layout(layout)
                .keep_lists(Some(k_site));
            let (mut cells, pieces) = match geometry {
                Some(cpu) => part.compute_with_pieces(cpu).map(|(c, p)| (c, Some(p)))?,
                None => (part.compute()?, None),
            };
            // Each list certified by the box; none of the walks left it.
            let kept = cells.kept.take().ok_or_else(|| Error::Internal("a part kept no lists".into()))?;
            let listed: Vec<u32> = kept.inputs.iter().copied().filter(|&i| answer.contains(&(i as usize))).collect();
            if listed.len() != kept.kth.len() {
                return Err(Error::Internal(format!("{} lists kept for {} cells", kept.kth.len(), listed.len())));
            }
            let shift = window.shift();
            let uncertified = (0..listed.len())
                .into_par_iter()
                .filter(|&u| {
                    let need = kept.kth[u] + 2.0 * (kept.kth[u] - kept.reach[u]).max(0.0);
                    let d2 = if need.is_finite() { ((need * per_world).ceil() + 2.0).powi(2) as u64 } else { u64::MAX };
                    let q = quantized(held[listed[u] as usize].at);
                    !window.certifies([0, 1, 2].map(|a| q[a] - shift[a]), d2)
                })
                .count();
            drop(kept);
            let c = &cells.counters;
            if window.is_whole() || (uncertified == 0 && c.out_of_halo == 0 && c.unresolved == 0) {
                report.grid_cells = cells.grid_cells;
                let width = halo as f64 * cell_side;
                done = Some(Part { held, answer, cells, pieces, width });
            } else {
                halo = halo.saturating_add(halo.div_ceil(2));
                report.widened += 1;
            }
        }
        let Part { held, answer, cells: whole, pieces, width } = match done {
            Some(part) => part,
            // No sites of its own: an empty part.
            None => Part {
                held: Vec::new(),
                answer: 0..0,
                cells: Cells { k_site, strategy: Strategy::Whole, ..Default::default() },
                pieces: None,
                width: 0.0,
            },
        };
        report.held = held.len() as u64;
        report.halo = width;

        // The polyhedra of this rank's cells, by input index.
        let clock = std::time::Instant::now();
        let built = geometry.map(|_| {
            let mut polyhedra = pieces.as_ref().map(merge_pieces).unwrap_or_default();
            let numbers = polyhedra
                .iter()
                .map(|p| {
                    let u = p.site as usize;
                    (whole.volume[u], whole.centroid[u], whole.energy[u])
                })
                .collect();
            polyhedra.par_iter_mut().for_each(|p| {
                p.site = held[p.site as usize].site as u32;
                for m in &mut p.face_neighbors {
                    if let Some(h) = usize::try_from(*m).ok().and_then(|u| held.get(u)) {
                        *m = h.site as i64;
                    }
                }
            });
            BuiltCells { polyhedra, numbers }
        });
        drop(pieces);
        if geometry.is_some() {
            timings.push("polyhedra", clock.elapsed().as_secs_f64());
        }

        // Each row, with its faces, to its reader.
        let clock = std::time::Instant::now();
        let mut seen = std::collections::HashSet::new();
        let duplicates = held[answer.clone()].iter().filter(|h| !seen.insert(h.at.map(f64::to_bits))).count() as u64;
        drop(seen);
        let none = Adjacency { offsets: vec![0], ..Default::default() };
        let a = whole.adjacency().filter(|_| self.faces).unwrap_or(&none);
        let halves = match self.faces {
            true => halves(comm, a, &held, answer.clone(), &mut report.sent)?,
            false => Default::default(),
        };
        let row_bytes = |u: usize, out: &mut [Vec<u8>]| -> Result<()> {
            let (faces, boundary, boundary_vector) = match self.faces {
                true => {
                    let (faces, _, _) = faces_of(a, &held, u, halves.get(&held[u].site));
                    (faces, a.boundary[u], a.boundary_vector[u])
                }
                false => (Vec::new(), 0.0, [0.0; 3]),
            };
            let h = held[u];
            let row = Row {
                site: h.site,
                volume: whole.volume[u],
                centroid: whole.centroid[u],
                energy: whole.energy[u],
                offset: [0.0; 3],
                wall: boundary,
                wall_vector: boundary_vector,
                faces: faces.len() as u64,
                area: 0.0,
                counts: Default::default(),
            };
            let r = reader(h.site).ok_or_else(|| Error::Internal(format!("site {} beyond the input", h.site)))?;
            out[r].extend_from_slice(bytemuck::bytes_of(&row));
            for (neighbor, shift, area, normal) in faces {
                let f = FaceRow { neighbor: neighbor as u64, shift, _pad: 0, area, normal };
                out[r].extend_from_slice(bytemuck::bytes_of(&f));
            }
            Ok(())
        };
        let chunks: Vec<Vec<Vec<u8>>> = answer
            .clone()
            .into_par_iter()
            .chunks(1 << 12)
            .map(|us| {
                let mut out = vec![Vec::new(); ranks];
                us.into_iter().try_for_each(|u| row_bytes(u, &mut out)).map(|()| out)
            })
            .collect::<Result<_>>()?;
        let mut to: Vec<Vec<u8>> =
            (0..ranks).map(|r| Vec::with_capacity(chunks.iter().map(|c| c[r].len()).sum())).collect();
        for chunk in chunks {
            for (r, bytes) in chunk.into_iter().enumerate() {
                to[r].extend_from_slice(&bytes);
            }
        }
        let (counted, pairing, k, phases) = (whole.counters, whole.pairing, whole.k, whole.timings.phases.clone());
        drop((whole, held));
        let to = Parcels::of(to);
        report.sent += (0..ranks).filter(|&r| r != rank).map(|r| to.get(r).len() as u64).sum::<u64>();
        let got = comm.exchange(to)?;
        let ((mut cells, _), _) = rows_of(&got, first, self.sites.len(), self.faces)?;
        // No images: a mesh's faces have no shifts.
        if let Some(a) = &mut cells.adjacency {
            a.shifts = Vec::new();
        }
        drop(got);
        timings.push("rows", clock.elapsed().as_secs_f64());

        // The run's totals.
        let mut counters = counter_words(&counted);
        counters.push(duplicates as i64);
        counters.push(cells.volume.iter().filter(|&&v| v <= 0.0).count() as i64);
        comm.sum(&mut counters)?;
        let mut c = counters_of(&counters);
        c.duplicate_sites = counters[counters.len() - 2] as u64;
        c.empty_cells = counters[counters.len() - 1] as u64 - c.duplicate_sites;
        let total_volume = comm.exact_total(&ExactSum::of(&cells.volume))?.value();
        let mesh_volume = mesh.volume();
        let mut cells = Cells {
            total_volume,
            mesh_volume,
            e_vol: (total_volume - mesh_volume).abs() / mesh_volume,
            strategy: Strategy::Whole,
            pairing,
            k,
            k_site,
            counters: c,
            chunks: ranks as u64,
            timings: timings.clone(),
            ..cells
        };
        for (name, t) in &phases {
            cells.timings.add(name, *t);
        }
        report.timings = cells.timings.clone();
        Ok(MeshPartsOut { cells, built, report })
    }
}

/// Each bucket's rank: runs of buckets along the curve, each holding about
/// a rank's share of the sites (a bucket goes to the rank whose share its
/// middle site falls in).
fn owners(counts: &[i64], ranks: usize) -> Vec<u32> {
    let total = counts.iter().sum::<i64>().max(1) as f64;
    let mut before = 0i64;
    counts
        .iter()
        .map(|&n| {
            let middle = before as f64 + n as f64 / 2.0;
            before += n;
            ((middle * ranks as f64 / total) as usize).min(ranks - 1) as u32
        })
        .collect()
}

/// The distinct positions among `sites` (`-0.0` and `0.0` alike).
fn distinct_positions(sites: &[Held]) -> usize {
    let mut keys: Vec<[u64; 3]> = sites.iter().map(|h| h.at.map(|c| (c + 0.0).to_bits())).collect();
    keys.par_sort_unstable();
    keys.dedup();
    keys.len()
}

/// Every rank's box of wanted cells (`None`: it wants none this round).
fn wanted_boxes(comm: &dyn Reduce, want: Option<HeldCells>) -> Result<Vec<Option<HeldCells>>> {
    let mine: Vec<u8> = match want {
        Some(b) => [b.lo, b.dim, b.grid, [b.cell_size, 0, 0]].concat().iter().flat_map(|w| w.to_le_bytes()).collect(),
        None => Vec::new(),
    };
    comm.all_gather(&mine)?
        .iter()
        .map(|b| {
            if b.is_empty() {
                return Ok(None);
            }
            let w: Vec<u32> = b.as_chunks::<4>().0.iter().map(|c| u32::from_le_bytes(*c)).collect();
            if w.len() != 12 {
                return Err(Error::Internal(format!("a rank's box came as {} bytes", b.len())));
            }
            let three = |k: usize| [w[k], w[k + 1], w[k + 2]];
            Ok(Some(HeldCells { lo: three(0), dim: three(3), grid: three(6), cell_size: w[9] }))
        })
        .collect()
}

/// Sends each of this rank's own sites (in grid cells `cells`) to every
/// rank whose box holds its cell, and returns what this rank received:
/// every site of its box.
fn spread(
    comm: &dyn Reduce,
    own: &[Held],
    cells: &[[u32; 3]],
    boxes: &[Option<HeldCells>],
    sent: &mut u64,
) -> Result<Vec<Held>> {
    let chunks: Vec<Vec<Vec<Held>>> = own
        .par_chunks(1 << 14)
        .zip(cells.par_chunks(1 << 14))
        .map(|(sites, cells)| {
            let mut to = vec![Vec::new(); boxes.len()];
            for (s, c) in sites.iter().zip(cells) {
                for (r, b) in boxes.iter().enumerate() {
                    if b.is_some_and(|b| b.holds(*c)) {
                        to[r].push(*s);
                    }
                }
            }
            to
        })
        .collect();
    let mut to: Vec<Vec<Held>> = vec![Vec::new(); boxes.len()];
    for chunk in chunks {
        for (r, part) in chunk.into_iter().enumerate() {
            to[r].extend(part);
        }
    }
    send(comm, to, sent)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::backends::distributed::InProcess;
    use crate::geom::mesh::TetMesh;
    use crate::geom::points;

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
        for ranks in 1..=4 {
            let what = format!("{ranks} ranks");
            let rows = |r: usize| sites.len() * r / ranks..sites.len() * (r + 1) / ranks;
            let runs: Vec<_> = std::thread::scope(|scope| {
                let handles: Vec<_> = InProcess::ranks(ranks)
                    .into_iter()
                    .enumerate()
                    .map(|(r, comm)| {
                        let (mesh, mine) = (&mesh, &sites[rows(r)]);
                        scope.spawn(move || {
                            let cpu = CpuBackend::new(Some(1)).unwrap();
                            let cv = ClippedVoronoi::new(mesh, mine).faces(true).backend(&cpu);
                            let (cells, report) = cv.compute_in_parts(&comm).unwrap();
                            let (with, built, _) = cv.compute_in_parts_with_polyhedra(&comm, &cpu).unwrap();
                            (cells, report, with, built)
                        })
                    })
                    .collect();
                handles.into_iter().map(|h| h.join().unwrap()).collect()
            });
            let mut polyhedra: Vec<_> = runs.iter().flat_map(|r| r.3.polyhedra.iter().cloned()).collect();
            polyhedra.sort_by_key(|p| p.site);
            assert!(polyhedra == *one_polyhedra, "{what}: the ranks' polyhedra are one process's, each once");
            let owned: u64 = runs.iter().map(|r| r.1.owned).sum();
            assert_eq!(owned, sites.len() as u64, "{what}: every site owned once");
            for (r, (cells, _, with, built)) in runs.iter().enumerate() {
                same_rows(&one, cells, rows(r), &what);
                same_rows(&one, with, rows(r), &format!("{what}, with polyhedra"));
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
    }

    /// A crowd in a cube: each rank holds its share of the sites and a
    /// halo, not every site, and its rows are one process's.
    #[test]
    fn the_ranks_hold_their_share_and_a_halo() {
        let mesh = TetMesh::voxels(6, |_, _, _| true);
        let sites = points::in_mesh(&mesh, 40_000, 5);
        let cpu = CpuBackend::new(Some(2)).unwrap();
        let one = ClippedVoronoi::new(&mesh, &sites).strategy(Strategy::Whole).faces(true).backend(&cpu).compute();
        let one = one.unwrap();
        for (ranks, most) in [(2, 0.7), (4, 0.55)] {
            let rows = |r: usize| sites.len() * r / ranks..sites.len() * (r + 1) / ranks;
            let runs: Vec<_> = std::thread::scope(|scope| {
                let handles: Vec<_> = InProcess::ranks(ranks)
                    .into_iter()
                    .enumerate()
                    .map(|(r, comm)| {
                        let (mesh, mine) = (&mesh, &sites[rows(r)]);
                        scope.spawn(move || {
                            let cpu = CpuBackend::new(Some(1)).unwrap();
                            ClippedVoronoi::new(mesh, mine).faces(true).backend(&cpu).compute_in_parts(&comm).unwrap()
                        })
                    })
                    .collect();
                handles.into_iter().map(|h| h.join().unwrap()).collect()
            });
            for (r, (cells, report)) in runs.iter().enumerate() {
                same_rows(&one, cells, rows(r), &format!("{ranks} ranks"));
                let share = report.held as f64 / sites.len() as f64;
                assert!(share < most, "{ranks} ranks: rank {r} holds {share:.2} of the sites ({report:?})");
            }
        }
    }
}
