//! A periodic box's diagram in parts, over the ranks of a run: no rank
//! holds the whole problem, and every cell comes out to the bit as in one
//! process.
//!
//! Each rank starts with its own rows of the sites (a run of the input, as
//! it read them: [`PeriodicVoronoi::compute_in_parts`]). The box is cut
//! into blocks ([`Blocks`]: a power of two along each axis, numbered along
//! a Morton curve); the ranks add up how many sites each block holds (one
//! sum of a few thousand numbers) and each takes a run of blocks along the
//! curve holding its share of the sites. The sites move to their blocks'
//! ranks, and each rank receives, from the others, the sites, images and
//! mirrors within a halo of its blocks — nothing else.
//!
//! The one-process diagram is laid out so that a part can repeat it
//! ([`crate::job::sites::Layout`]): its frame follows from the box and the
//! halo, its sites are ordered by block, then along a curve, then by index,
//! and the halo comes from the largest distance of a query cell's centre to
//! its nearest site. So a rank computes, in turn:
//! - that distance over the query cells whose centres lie in its blocks,
//!   from the sites and images within the first halo around them (wider if
//!   a centre's nearest site lies farther) — the largest over the ranks is
//!   the one process's, to the bit;
//! - from it the halo `2H` and the images and mirrors of its own sites, as
//!   the one process takes them; it receives every point within `2H` of its
//!   blocks (a cell lies within `H` of its site, and the points that cut it
//!   within `H` of the cell), and checks that each of its sites' `k_site`
//!   nearest points lies within the halo too (else all ranks widen it and
//!   exchange again), so that each list is the one process's, entry for
//!   entry;
//! - the whole cells of its own sites, in the one process's order and
//!   frame, folded as the one process folds them; each cell's row goes
//!   back to the rank that read its site.
//!
//! Power cells carry their weights with their points (the halo widens
//! with the whole job's range, the job shifts them by its smallest); with
//! the Voronoi index, each part merges and measures the polyhedra of the
//! cells it built ([`PeriodicVoronoi::compute_in_parts_with_index`]).

use crate::backend::Backend;
use crate::backends::distributed::{records, Parcels, Reduce};
use crate::diagram::particles::{IndexThresholds, ParticleCells, INDEX_ORDERS};
use crate::diagram::periodic::{
    coverage, fold_site, images_within, merge_faces, mirrors_within, place_sites, Blocks, FoldedFaces, Image,
    PeriodicCells, PeriodicVoronoi, PointKey, NO_WALL, WHOLE_FRAME_TETS,
};
use crate::diagram::voronoi::{Cells, ClippedVoronoi, Counters};
use crate::error::{Error, Result};
use crate::exec::CpuBackend;
use crate::geom::exact_sum::ExactSum;
use crate::geom::periodic_box::PeriodicBox;
use crate::geom::timing::{timed, Timings};
use crate::job::clip::{Frame, Strategy};
use crate::job::sites::{Layout, Window};
use crate::job::weight_bounds::WeightGrid;
use crate::passes::faces::Adjacency;
use crate::passes::pieces::ON_BOUNDARY;
use crate::passes::polyhedra::{merge_pieces, CellPolyhedron};
use bytemuck::{Pod, Zeroable};
use cvd_kernels::abi::SplitPoint;
use rayon::prelude::*;

/// A point a rank holds: a site (no shift, no wall) or an image of one.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub(super) struct Held {
    pub(super) at: [f64; 3],
    /// The site's input index.
    pub(super) site: u64,
    /// The site's power weight (0 without weights).
    pub(super) weight: f64,
    shift: [i32; 3],
    /// The wall it is mirrored in, or `NO_WALL`.
    wall: u32,
    /// The rank whose cell its site's is.
    pub(super) rank: u32,
    _pad: u32,
}

impl Held {
    pub(super) fn site(at: [f64; 3], site: u64, weight: f64, rank: usize) -> Self {
        Self { at, site, weight, shift: [0; 3], wall: NO_WALL as u32, rank: rank as u32, _pad: 0 }
    }

    fn image(m: &Image, domain: &PeriodicBox, sites: &[[f64; 3]], ids: &[Held]) -> Self {
        let of = ids[m.site as usize];
        Self { at: m.at(domain, sites), shift: m.shift, wall: m.wall as u32, ..of }
    }

    fn is_mirror(&self) -> bool {
        self.wall != NO_WALL as u32
    }

    /// Where the one process puts a mirror among its points: the sites'
    /// own mirrors first, by site, then the images', by site and shift
    /// (`images_within`'s order), each by wall.
    fn mirror_order(&self) -> (bool, u64, [i32; 3], u32) {
        let s = self.shift;
        (s != [0; 3], self.site, [s[2], s[1], s[0]], self.wall)
    }

    fn is_site(&self) -> bool {
        self.shift == [0; 3] && self.wall == NO_WALL as u32
    }
}

/// A cell's row, sent back to the rank that read its site (its faces
/// follow it).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub(super) struct Row {
    pub(super) site: u64,
    pub(super) volume: f64,
    pub(super) centroid: [f64; 3],
    pub(super) energy: f64,
    pub(super) offset: [f64; 3],
    pub(super) wall: f64,
    pub(super) wall_vector: [f64; 3],
    pub(super) faces: u64,
    /// The cell's particle quantities (zero unless asked for): surface
    /// area, then coordination, the Voronoi index and the largest order.
    pub(super) area: f64,
    pub(super) counts: [u32; INDEX_ORDERS + 2],
}

/// A face of a row.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub(super) struct FaceRow {
    pub(super) neighbor: u64,
    pub(super) shift: [i32; 3],
    pub(super) _pad: u32,
    pub(super) area: f64,
    pub(super) normal: [f64; 3],
}

/// What this rank's part of a diagram in parts did.
#[derive(Clone, Debug, Default)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub struct PartsReport {
    /// This rank.
    pub rank: usize,
    /// Ranks.
    pub ranks: usize,
    /// The first input row this rank read.
    pub first: u64,
    /// The rows it read.
    pub read: u64,
    /// Sites in all.
    pub total: u64,
    /// Blocks of the box in all, and this rank's.
    pub blocks: [u64; 2],
    /// The sites whose cells this rank built.
    pub owned: u64,
    /// The points it held for them: its sites, and the sites, images and
    /// mirrors of its halo.
    pub held: u64,
    /// The halo's width around its blocks.
    pub halo: f64,
    /// Times the ranks widened the halo.
    pub widened: u32,
    /// A mesh in parts: the cells built again in the rounds after the
    /// first, with more sites held (on the CPU only those whose list or
    /// walk reached past what their part held; a device builds every cell
    /// of the part again).
    pub rebuilt: u64,
    /// A mesh in parts: the neighbour lists this rank's boxes did not
    /// certify, over its rounds (each such round widened the halo).
    pub uncertified: u64,
    /// A mesh in parts: the grid cells inside a part's box that it did not
    /// hold (in none of its groups' boxes), the most over its parts.
    pub unheld_cells: u64,
    /// The cells of the grid's table this rank held (a window of the whole
    /// job's grid around its points), and the whole grid's.
    pub grid_cells: [u64; 2],
    /// A mesh in parts: the most tets a part's job held, and the mesh's
    /// (0 in a periodic box).
    pub tets: [u64; 2],
    /// A mesh in parts: the parts this rank computed its sites in, one
    /// after another (0 in a periodic box).
    pub parts: u64,
    /// Times the ranks searched the whole grid again because a walk would
    /// have left a window (0 expected).
    pub windows_dropped: u32,
    /// Bytes this rank sent to the others (itself excluded).
    pub sent: u64,
    /// Time per phase.
    pub timings: Timings,
}

impl PeriodicVoronoi<'_> {
    /// This rank's part of the diagram of the sites of all ranks of `comm`
    /// (see the module's documentation): `self`'s sites are this rank's
    /// rows of the input, the rows of rank 0 first, then rank 1's, and so
    /// on. Returns the cells of this rank's rows — the same bits as the
    /// diagram of all the sites in one process, neighbours by input index —
    /// with the run's totals (counters, total volume, images), and what
    /// the part did. Whole cells, on the diagram's backend (the CPU's, or a
    /// device's: each part one windowed job); with weights
    /// ([`PeriodicVoronoi::weights`]: this rank's rows' own, on every rank
    /// or on none), power cells (the `walks` counter may differ from one
    /// process's). The polyhedra: [`Self::compute_in_parts_with_index`]; no
    /// kept lists yet.
    pub fn compute_in_parts(&self, comm: &dyn Reduce) -> Result<(PeriodicCells, PartsReport)> {
        let out = self.in_parts(comm, None)?;
        Ok((out.cells, out.report))
    }

    /// [`Self::compute_in_parts`] with the particles' quantities of this
    /// rank's rows (their cells' polyhedra measured with `thresholds`, as
    /// [`ParticleCells::of`] measures them in one process: the same bits),
    /// on `cpu` (the cells on the diagram's device, if it has one: the
    /// polyhedra then from a second run on `cpu`); and the polyhedra of the cells this rank built (the sites
    /// of its blocks, not its rows) with their numbers.
    pub fn compute_in_parts_with_index(
        &self,
        comm: &dyn Reduce,
        cpu: &CpuBackend,
        thresholds: &IndexThresholds,
    ) -> Result<IndexInParts> {
        let out = self.in_parts(comm, Some((cpu, thresholds)))?;
        match (out.particles, out.built) {
            (Some(particles), Some(built)) => {
                Ok(IndexInParts { cells: out.cells, particles, built, report: out.report })
            }
            _ => Err(Error::Internal("no particle quantities came back".into())),
        }
    }

    fn in_parts(&self, comm: &dyn Reduce, index: Option<(&CpuBackend, &IndexThresholds)>) -> Result<PartsOut> {
        if self.strategy.is_some_and(|s| s != Strategy::Whole) {
            return Err(Error::InvalidInput("a periodic box in parts is computed with whole cells".into()));
        }
        let own_cpu;
        let backend: &dyn Backend = match (index, self.backend) {
            // A device's cells, the polyhedra from a run on the CPU (as one
            // process takes them).
            (_, Some(b)) if b.kind() != crate::job::BackendKind::Cpu => b,
            (Some((cpu, _)), _) => cpu,
            // A device's too: the whole-cell kernel in the part's window,
            // its lists' distances read back for the certificate.
            (None, Some(b)) => b,
            (None, None) => {
                own_cpu = CpuBackend::new(None)?;
                &own_cpu
            }
        };
        let domain = self.domain;
        let (rank, ranks) = (comm.rank(), comm.size());
        let mut timings = Timings::default();
        let clock = std::time::Instant::now();
        let rows = RowsAcross::of(comm, self.sites.len())?;
        let (first, total) = (rows.first, rows.total);
        let reader = |site: u64| rows.reader(site);
        // A rank may hold no rows (fewer rows than ranks, or none of a
        // frame's ids): the others' checks stand for it.
        if !self.sites.is_empty() {
            crate::job::sites::check_sites(self.sites, self.weights).map_err(|e| at_row(e, first))?;
        }
        // The weights' range over all rows (the halo widens with it), as
        // the one process takes it; whether the ranks agree on weights.
        let span = weight_span(comm, self.weights)?;
        let range = span.map_or(0.0, |[lo, hi]| hi - lo);
        let (placed, on_walls) = place_sites(&domain, self.sites).map_err(|e| at_row(e, first))?;
        let wrapped = placed.iter().zip(self.sites).filter(|(a, b)| a != b).count() - on_walls;
        let spacing = (domain.volume() / total as f64).cbrt();

        // Blocks: their sites counted by all, a run of them per rank.
        let blocks = Blocks::of(&domain, total as usize);
        let mut per_block = vec![0i64; blocks.count()];
        for &p in &placed {
            per_block[blocks.index(blocks.of_point(&domain, p))] += 1;
        }
        comm.sum(&mut per_block)?;
        let owner = owners(&blocks, &per_block, ranks);
        drop(per_block);
        let mine = |p: [f64; 3]| owner[blocks.index(blocks.of_point(&domain, p))] as usize == rank;
        // The sites to their blocks' ranks.
        let (mut own, mut report) = to_owners(
            comm,
            &placed,
            (first, total),
            &owner,
            |p| blocks.index(blocks.of_point(&domain, p)),
            |i| self.weights.map_or(0.0, |w| w[i]),
        )?;
        own.sort_unstable_by_key(|h| h.site);
        let own_sites: Vec<[f64; 3]> = own.iter().map(|h| h.at).collect();
        report.owned = own.len() as u64;
        timings.push("blocks", clock.elapsed().as_secs_f64());

        // The halo the one process takes: from the query cells in this
        // rank's blocks, each with every point within its nearest's
        // distance.
        let clock = std::time::Instant::now();
        let first_halo = (2.0 * spacing * 2.0 * spacing + range).sqrt();
        let images = images_within(&domain, &own_sites, first_halo);
        let points: Vec<Held> =
            own.iter().copied().chain(images.iter().map(|m| Held::image(m, &domain, &own_sites, &own))).collect();
        let mut width = first_halo;
        let reach = loop {
            let held = spread(comm, &domain, &blocks, &owner, &points, width, &mut report.sent)?;
            let at: Vec<[f64; 3]> = held.iter().map(|h| h.at).collect();
            let (reach, nearest) = coverage(&domain, &at, spacing, mine);
            let mut most = [reach, if nearest > width { nearest } else { 0.0 }];
            comm.max(&mut most)?;
            if most[1] == 0.0 {
                break most[0];
            }
            width = most[1] * (1.0 + 1e-6);
            report.widened += 1;
        };
        drop(points);
        let halo = 2.0 * ((reach * reach + range).sqrt() * (1.0 + 1e-9));
        let outermost = if halo > first_halo { halo } else { first_halo };
        let mut images = images_within(&domain, &own_sites, outermost);
        let before = images.len();
        images.extend(mirrors_within(&domain, &own_sites, &images, halo));
        let mut tally = [images.len() as i64, (images.len() - before) as i64, wrapped as i64, on_walls as i64];
        comm.sum(&mut tally)?;
        let points: Vec<Held> =
            own.iter().copied().chain(images.iter().map(|m| Held::image(m, &domain, &own_sites, &own))).collect();
        drop(images);
        timings.push("halo", clock.elapsed().as_secs_f64());

        // Every point within the halo of this rank's blocks, in the one
        // process's order; wider until each own site's list lies inside.
        // The weights as the one process shifts them: from the smallest of
        // a site that owns its cell (of duplicates, the largest weight's).
        let kept_span = match self.weights {
            Some(_) => kept_span(comm, &own, span.map_or(0.0, |s| s[1]))?,
            None => [0.0; 2],
        };
        let (lo, hi) = crate::geom::vec3::bounding_box(points.iter().map(|h| &h.at));
        let mut extremes = [0, 1, 2, 3, 4, 5].map(|k| if k < 3 { -lo[k] } else { hi[k - 3] });
        comm.max(&mut extremes)?;
        let frame = ([0, 1, 2].map(|a| -extremes[a]), [0, 1, 2].map(|a| extremes[a + 3]));
        let mesh = domain.mesh(WHOLE_FRAME_TETS);
        // The one process's grid of largest weights, from every rank's
        // sites and images (each rank holds every duplicate of its own).
        let weight_grid = match self.weights {
            Some(_) => {
                let mut distinct = [distinct_positions(&points) as i64];
                comm.sum(&mut distinct)?;
                let frame = Frame::of(&mesh);
                let volume = mesh.volume() / frame.scale.powi(3);
                weight_grid_as_one(comm, &points, kept_span, frame, distinct[0] as usize, volume)?
            }
            None => None,
        };
        let diagram = ClippedVoronoi::new(&mesh, &own_sites)
            .faces(self.faces)
            .strategy(Strategy::Whole)
            .k_site(self.k_site)
            .backend(backend)
            .memory_budget(self.memory_budget);
        let k_site = diagram.resolved_k_site();
        let mut width = halo * (1.0 + 1e-6);
        let grid_sites = (total + tally[0] as u64) as usize;
        // A window of the grid around each part's points; the whole grid
        // for all if a walk would leave a window (none should: the halo
        // holds every point that can cut a cell).
        let mut window = true;
        let (whole, pieces, held, at, answer) = loop {
            let (held, t) = timed(|| spread(comm, &domain, &blocks, &owner, &points, width, &mut report.sent));
            timings.add("exchange", t);
            let mut held = held?;
            let (answer, t) = timed(|| order(&domain, &blocks, &frame, &mut held, &mine));
            timings.add("order", t);
            // This rank's cells, each site's list kept to check its reach.
            let at: Vec<[f64; 3]> = held.iter().map(|h| h.at).collect();
            let order: Vec<u32> = (0..held.len() as u32).collect();
            let layout = Layout {
                order: &order,
                lo: frame.0,
                hi: frame.1,
                grid_sites,
                answer: (answer.start, answer.end),
                weights: self.weights.map(|_| kept_span),
                weight_grid: weight_grid.as_ref(),
                window: if window { Window::Around } else { Window::Whole },
                unheld: None,
                periodic: true,
                only: None,
                halves: false,
            };
            let weights: Option<Vec<f64>> = self.weights.map(|_| held.iter().map(|h| h.weight).collect());
            // Walks of the pieces' run on the CPU that left the window.
            let mut pieces_left = 0;
            let (mut whole, pieces) = if answer.is_empty() {
                (Cells { k_site, strategy: Strategy::Whole, ..Default::default() }, None)
            } else {
                let mut part = ClippedVoronoi { sites: &at, ..diagram }.layout(layout).keep_reach(k_site);
                if let Some(w) = &weights {
                    part = part.weights(w);
                }
                match index {
                    Some((cpu, _)) if backend.kind() == crate::job::BackendKind::Cpu => {
                        part.compute_with_pieces(cpu).map(|(c, p)| (c, Some(p)))?
                    }
                    Some((cpu, _)) => {
                        let cells = part.compute()?;
                        let (again, pieces) = part.faces(false).compute_with_pieces(cpu)?;
                        pieces_left = again.counters.out_of_halo;
                        (cells, Some(pieces))
                    }
                    None => (part.compute()?, None),
                }
            };
            // Each list is the one process's if its k-th entry lies within
            // the halo (its distance plus the quantization's rounding, the
            // gap between a list's last entry and its reach, twice).
            let need = whole.kept.take().map_or(0.0, |kept| {
                (0..kept.kth.len()).map(|u| kept.kth[u] + 2.0 * (kept.kth[u] - kept.reach[u])).fold(0.0, f64::max)
            });
            let left = whole.counters.out_of_halo + pieces_left;
            let mut most = [if need > width { need } else { 0.0 }, left as f64];
            comm.max(&mut most)?;
            if most == [0.0; 2] {
                break (whole, pieces, held, at, answer);
            }
            if most[1] > 0.0 {
                window = false;
                report.windows_dropped += 1;
            }
            if most[0] > 0.0 {
                width = most[0] * (1.0 + 1e-6);
                report.widened += 1;
            }
        };
        report.grid_cells = whole.grid_cells;
        drop(points);
        report.held = held.len() as u64;
        report.halo = width;

        // This rank's cells, folded, and each row to its reader.
        let clock = std::time::Instant::now();
        let mut seen = std::collections::HashSet::new();
        let duplicates = held[answer.clone()].iter().filter(|h| !seen.insert(h.at.map(f64::to_bits))).count() as u64;
        drop(seen);
        // The polyhedra of this rank's cells, and their particle quantities.
        let (built, quantities) = match (pieces, index) {
            (Some(pieces), Some((_, thresholds))) => {
                let (polyhedra, places, q, t) = polyhedra_of(pieces, &held, thresholds);
                timings.push("polyhedra", t);
                let numbers = places
                    .par_iter()
                    .map(|&u| {
                        let (volume, energy, _, centroid) =
                            fold_site(&domain, held[u].at, &at, &whole, std::iter::once(u));
                        (volume, centroid, energy)
                    })
                    .collect();
                (Some(BuiltCells { polyhedra, numbers }), Some(q))
            }
            _ => (index.map(|_| BuiltCells::default()), None),
        };
        // Every rank takes part in the exchange of halves, with cells or not.
        let none = Adjacency { offsets: vec![0], ..Default::default() };
        let a = whole.adjacency().filter(|_| self.faces).unwrap_or(&none);
        let halves = match self.faces {
            true => halves(comm, a, &held, answer.clone(), &mut report.sent)?,
            false => Default::default(),
        };
        // Rows made in chunks on every core, each chunk's for each reader,
        // then laid end to end by reader (the reader puts them in order).
        let row_bytes = |u: usize, out: &mut [Vec<u8>]| -> Result<()> {
            let (faces, wall, wall_vector) = match self.faces {
                true => faces_of(a, &held, u, halves.get(&held[u].site)),
                false => (Vec::new(), 0.0, [0.0; 3]),
            };
            let h = held[u];
            let (volume, energy, offset, centroid) = fold_site(&domain, h.at, &at, &whole, std::iter::once(u));
            let (area, counts) = quantities.as_ref().map_or((0.0, [0; INDEX_ORDERS + 2]), |q| {
                let mut counts = [0; INDEX_ORDERS + 2];
                counts[0] = q.coordination[u];
                counts[1..=INDEX_ORDERS].copy_from_slice(&q.index[u]);
                counts[INDEX_ORDERS + 1] = q.max_face_order[u];
                (q.area[u], counts)
            });
            let faces_n = faces.len() as u64;
            let row =
                Row { site: h.site, volume, centroid, energy, offset, wall, wall_vector, faces: faces_n, area, counts };
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
        drop((whole, held, at));
        let to = Parcels::of(to);
        report.sent += (0..ranks).filter(|&r| r != rank).map(|r| to.get(r).len() as u64).sum::<u64>();
        let got = comm.exchange(to)?;
        let (cells, particles) = rows_of(&got, first, self.sites.len(), self.faces)?;
        let particles = index.map(|_| particles);
        drop(got);
        timings.push("rows", clock.elapsed().as_secs_f64());

        // The run's totals.
        let mut counters = counter_words(&counted);
        counters.push(duplicates as i64);
        let whole = Cells { strategy: Strategy::Whole, pairing, k, k_site, chunks: ranks as u64, ..Default::default() };
        let (cells, offsets) = (with_totals(comm, counters, cells.0, domain.volume(), whole)?, cells.1);
        let mut cells = cells;
        cells.timings = timings.clone();
        for (name, t) in &phases {
            cells.timings.add(name, *t);
        }
        report.timings = cells.timings.clone();
        Ok(PartsOut {
            cells: PeriodicCells {
                cells,
                sites: placed,
                offsets,
                wrapped: tally[2] as usize,
                images: tally[0] as usize,
                mirrors: tally[1] as usize,
                on_walls: tally[3] as usize,
                halo,
                lists: None,
                reused: 0,
            },
            particles,
            built,
            report,
        })
    }
}

/// What [`PeriodicVoronoi::compute_in_parts_with_index`] gives a rank.
#[derive(Clone, Debug)]
pub struct IndexInParts {
    /// The cells of its rows, as [`PeriodicVoronoi::compute_in_parts`]'s.
    pub cells: PeriodicCells,
    /// Its rows' particle quantities (Voronoi index and all).
    pub particles: ParticleCells,
    /// The cells it built, with their polyhedra.
    pub built: BuiltCells,
    /// What the part did.
    pub report: PartsReport,
}

/// The cells one rank of a diagram in parts built (the sites of its
/// blocks), as polyhedra: sites and neighbours by input index, a wall's
/// face [`ON_BOUNDARY`].
#[derive(Clone, Debug, Default)]
pub struct BuiltCells {
    /// The polyhedra, one per cell with volume.
    pub polyhedra: Vec<CellPolyhedron>,
    /// Each polyhedron's cell's volume, centroid and energy.
    pub numbers: Vec<(f64, [f64; 3], f64)>,
}

/// What a part gives back, before it is taken apart.
struct PartsOut {
    cells: PeriodicCells,
    particles: Option<ParticleCells>,
    built: Option<BuiltCells>,
    report: PartsReport,
}

/// Where the ranks' rows of the input lie: each rank's count, this rank's
/// first row, and the total (none refused).
pub(super) struct RowsAcross {
    counts: Vec<u64>,
    pub(super) first: u64,
    pub(super) total: u64,
}

impl RowsAcross {
    /// The rows of every rank of `comm`, this rank's `len`.
    pub(super) fn of(comm: &dyn Reduce, len: usize) -> Result<Self> {
        let counts = comm.gather_u64(len as u64)?;
        let first: u64 = counts[..comm.rank()].iter().sum();
        let total: u64 = counts.iter().sum();
        if total == 0 {
            return Err(Error::InvalidInput("there are no sites".into()));
        }
        Ok(Self { counts, first, total })
    }

    /// The rank that read input row `site`.
    pub(super) fn reader(&self, site: u64) -> Option<usize> {
        let mut at = 0;
        self.counts.iter().position(|&c| {
            at += c;
            site < at
        })
    }
}

/// This rank's report as its part starts, and its `rows` (from input row
/// `first` of `total`) sent to the ranks that own them (`owner[part(p)]`,
/// each with `weight(row)`): returns the sites this rank owns.
pub(super) fn to_owners(
    comm: &dyn Reduce,
    rows: &[[f64; 3]],
    (first, total): (u64, u64),
    owner: &[u32],
    part: impl Fn([f64; 3]) -> usize,
    weight: impl Fn(usize) -> f64,
) -> Result<(Vec<Held>, PartsReport)> {
    let (rank, ranks) = (comm.rank(), comm.size());
    let mut report = PartsReport {
        rank,
        ranks,
        first,
        read: rows.len() as u64,
        total,
        blocks: [owner.len() as u64, owner.iter().filter(|&&r| r as usize == rank).count() as u64],
        ..Default::default()
    };
    let mut to = vec![Vec::new(); ranks];
    for (i, &p) in rows.iter().enumerate() {
        let r = owner[part(p)] as usize;
        to[r].push(Held::site(p, first + i as u64, weight(i), r));
    }
    let own = send(comm, to, &mut report.sent)?;
    Ok((own, report))
}

/// The smallest and largest of the weights of every rank's rows (`None`:
/// no weights); an error if some ranks have weights and some do not.
pub(super) fn weight_span(comm: &dyn Reduce, weights: Option<&[f64]>) -> Result<Option<[f64; 2]>> {
    let (lo, hi) =
        weights.unwrap_or_default().iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
    let weighted = weights.is_some() as u8 as f64;
    let mut span = [-lo, hi, weighted, -weighted];
    comm.max(&mut span)?;
    if span[2] != -span[3] {
        return Err(Error::InvalidInput("some ranks have weights and some do not".into()));
    }
    Ok((span[2] > 0.0).then_some([-span[0], span[1]]))
}

/// The smallest and largest weight over every rank's sites that own a
/// cell (of duplicates, the largest weight's), as the one process shifts
/// the weights by: each rank holds every duplicate of its `own` sites;
/// `largest` is the largest weight of all.
pub(super) fn kept_span(comm: &dyn Reduce, own: &[Held], largest: f64) -> Result<[f64; 2]> {
    let mut kept: std::collections::HashMap<[u64; 3], f64> = Default::default();
    for h in own {
        let w = kept.entry(h.at.map(f64::to_bits)).or_insert(h.weight);
        *w = w.max(h.weight);
    }
    let mut span = [-kept.values().copied().fold(f64::INFINITY, f64::min), largest];
    comm.max(&mut span)?;
    Ok([-span[0], span[1]])
}

/// The grid of largest weights whose local bounds the one process's
/// sites take (see `WeightGrid`), from every rank's `points` (its sites,
/// and in a periodic box their images, each with its weight): over the
/// box of all the points as the job holds them (in `frame`, the weights
/// shifted by `span[0]`), for `distinct` positions of all the ranks in a
/// domain of `volume` (the frame's units), each cell the largest over the
/// ranks. `None` when every weight is the same (no bounds are read).
pub(super) fn weight_grid_as_one(
    comm: &dyn Reduce,
    points: &[Held],
    span: [f64; 2],
    frame: Frame,
    distinct: usize,
    volume: f64,
) -> Result<Option<WeightGrid>> {
    let scale2 = frame.scale * frame.scale;
    if ((span[1] - span[0]) / scale2).max(0.0) == 0.0 {
        return Ok(None);
    }
    let split: Vec<SplitPoint> =
        points.par_iter().map(|h| SplitPoint::site(frame.to_local(h.at), (h.weight - span[0]) / scale2)).collect();
    let mut extremes = [f64::NEG_INFINITY; 6];
    for p in split.iter().map(SplitPoint::to_f64) {
        for a in 0..3 {
            (extremes[a], extremes[a + 3]) = (extremes[a].max(-p[a]), extremes[a + 3].max(p[a]));
        }
    }
    comm.max(&mut extremes)?;
    let (lo, hi) = ([0, 1, 2].map(|a| -extremes[a]), [0, 1, 2].map(|a| extremes[a + 3]));
    let mut grid = WeightGrid::new(lo, hi, distinct, volume);
    for s in &split {
        grid.add(s);
    }
    comm.max(grid.cells_mut())?;
    Ok(Some(grid))
}

/// The distinct positions among `points` (`-0.0` and `0.0` alike).
pub(super) fn distinct_positions(points: &[Held]) -> usize {
    let mut keys: Vec<[u64; 3]> = points.iter().map(|h| h.at.map(|c| (c + 0.0).to_bits())).collect();
    keys.par_sort_unstable();
    keys.dedup();
    keys.len()
}

/// An error about a site, its index moved from this rank's rows to the
/// input's.
pub(super) fn at_row(e: Error, first: u64) -> Error {
    if first == 0 {
        return e;
    }
    match e {
        Error::InvalidInput(m) => Error::InvalidInput(format!("{m} (counting from row {first} of the input)")),
        e => e,
    }
}

/// Each block's rank: runs of blocks along the curve, each holding about
/// a rank's share of the sites (a block goes to the rank whose share its
/// middle site falls in).
fn owners(blocks: &Blocks, counts: &[i64], ranks: usize) -> Vec<u32> {
    let total = counts.iter().sum::<i64>().max(1) as f64;
    let mut owner = vec![0u32; blocks.count()];
    let mut before = 0i64;
    for b in blocks.in_order() {
        let middle = before as f64 + counts[b as usize] as f64 / 2.0;
        owner[b as usize] = ((middle * ranks as f64 / total) as usize).min(ranks - 1) as u32;
        before += counts[b as usize];
    }
    owner
}

/// The half of a face a cell sends the rank of the cell on its other side.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub(super) struct Half {
    /// The other side's site, and the cell's own.
    site: u64,
    neighbor: u64,
    /// The cell's site's image, seen from the other side.
    shift: [i32; 3],
    _pad: u32,
    area: f64,
    normal: [f64; 3],
}

/// The faces of this rank's cells (`answer` of `held`) seen from their
/// other side where that side is not built here (a site of another rank, or
/// an image): each sent to the rank that built the cell on that side, and
/// those sent to this rank returned, by site.
pub(super) fn halves(
    comm: &dyn Reduce,
    a: &Adjacency,
    held: &[Held],
    answer: std::ops::Range<usize>,
    sent: &mut u64,
) -> Result<std::collections::HashMap<u64, Vec<Half>>> {
    let mut to = vec![Vec::new(); comm.size()];
    for u in answer.clone() {
        for (v, area, normal) in a.of(u) {
            let h = held[v as usize];
            if !h.is_mirror() && !answer.contains(&(v as usize)) {
                to[h.rank as usize].push(Half {
                    site: h.site,
                    neighbor: held[u].site,
                    shift: h.shift.map(|s| -s),
                    _pad: 0,
                    area,
                    // The one process's, from the other side: exactly
                    // opposite (a zero stays +0).
                    normal: normal.map(|c| 0.0 - c),
                });
            }
        }
    }
    let me = comm.rank();
    *sent +=
        to.iter().enumerate().filter(|&(r, _)| r != me).map(|(_, h)| (h.len() * size_of::<Half>()) as u64).sum::<u64>();
    let got = comm.exchange(Parcels::of(to.into_iter().map(|h| bytemuck::cast_slice(&h).to_vec()).collect()))?;
    let mut by_site: std::collections::HashMap<u64, Vec<Half>> = Default::default();
    for h in records::<Half>(&got.bytes) {
        by_site.entry(h.site).or_default().push(h);
    }
    Ok(by_site)
}

/// The faces of cell `u` of `held` as the one process folds them
/// (`fold_faces`): a face is half the area from each side, the cell's own
/// first, then the other side's (from this rank's cells, or `halves` from
/// another's); a wall sums the cell's faces with mirrors in the one
/// process's order, and again (the mirrors' rows there).
pub(super) fn faces_of(a: &Adjacency, held: &[Held], u: usize, halves: Option<&Vec<Half>>) -> FoldedFaces {
    let (mut faces, mut mirrors) = (Vec::new(), Vec::new());
    for (v, area, normal) in a.of(u) {
        let h = held[v as usize];
        if h.is_mirror() {
            mirrors.push((h.mirror_order(), area, normal));
        } else {
            faces.push((h.site as u32, h.shift, area, normal));
        }
    }
    faces.extend(halves.into_iter().flatten().map(|h| (h.neighbor as u32, h.shift, h.area, h.normal)));
    mirrors.sort_by_key(|m| m.0);
    let (mut wall, mut wall_vector, mut half, mut half_vector) = (0.0, [0.0; 3], 0.0, [0.0; 3]);
    for &(_, area, normal) in &mirrors {
        wall += area;
        half += area;
        for k in 0..3 {
            wall_vector[k] += area * normal[k];
            half_vector[k] -= area * (0.0 - normal[k]);
        }
    }
    (merge_faces(faces), wall + half, [0, 1, 2].map(|k| wall_vector[k] + half_vector[k]))
}

/// Sends each of `points` to every rank with a block within `width` of it
/// (by its distance to the blocks' slabs: a few more than needed), and
/// returns what this rank received.
fn spread(
    comm: &dyn Reduce,
    domain: &PeriodicBox,
    blocks: &Blocks,
    owner: &[u32],
    points: &[Held],
    width: f64,
    sent: &mut u64,
) -> Result<Vec<Held>> {
    let h = domain.heights();
    let dims = blocks.dims.map(|d| d as i64);
    let reach = [0, 1, 2].map(|a| width / h[a]);
    let chunks: Vec<Vec<Vec<Held>>> = points
        .par_chunks(1 << 14)
        .map(|chunk| {
            let mut to = vec![Vec::new(); comm.size()];
            let mut ranks: Vec<u32> = Vec::new();
            for p in chunk {
                let s = domain.fractional(p.at);
                let lo = [0, 1, 2].map(|a| (((s[a] - reach[a]) * dims[a] as f64).floor() as i64).max(0));
                let hi = [0, 1, 2].map(|a| (((s[a] + reach[a]) * dims[a] as f64).floor() as i64).min(dims[a] - 1));
                ranks.clear();
                for z in lo[2]..=hi[2] {
                    for y in lo[1]..=hi[1] {
                        for x in lo[0]..=hi[0] {
                            let r = owner[blocks.index([x as u32, y as u32, z as u32])];
                            if !ranks.contains(&r) {
                                ranks.push(r);
                            }
                        }
                    }
                }
                for &r in &ranks {
                    to[r as usize].push(*p);
                }
            }
            to
        })
        .collect();
    let mut to: Vec<Vec<Held>> = vec![Vec::new(); comm.size()];
    for chunk in chunks {
        for (r, part) in chunk.into_iter().enumerate() {
            to[r].extend(part);
        }
    }
    send(comm, to, sent)
}

/// Exchanges points between the ranks (see [`Reduce::exchange`]).
pub(super) fn send(comm: &dyn Reduce, to: Vec<Vec<Held>>, sent: &mut u64) -> Result<Vec<Held>> {
    let me = comm.rank();
    *sent +=
        to.iter().enumerate().filter(|&(r, _)| r != me).map(|(_, p)| (p.len() * size_of::<Held>()) as u64).sum::<u64>();
    let bytes = Parcels::of(to.into_iter().map(|p| bytemuck::cast_slice(&p).to_vec()).collect());
    Ok(records::<Held>(&comm.exchange(bytes)?.bytes).collect())
}

/// Sorts `held` in the one process's order ([`PointKey`]) and returns the
/// places of this rank's own sites (a run of them).
fn order(
    domain: &PeriodicBox,
    blocks: &Blocks,
    frame: &([f64; 3], [f64; 3]),
    held: &mut Vec<Held>,
    mine: &(impl Fn([f64; 3]) -> bool + Sync),
) -> std::ops::Range<usize> {
    let key = |h: &Held| {
        let image = (!h.is_site()).then_some((h.shift, h.wall as u8));
        PointKey::of(domain, blocks, frame, h.at, h.site, image)
    };
    let mut keyed: Vec<(PointKey, Held)> = held.par_iter().map(|h| (key(h), *h)).collect();
    keyed.par_sort_unstable_by(|a, b| a.0.cmp(&b.0));
    *held = keyed.into_iter().map(|(_, h)| h).collect();
    let start = held.iter().position(|h| h.is_site() && mine(h.at)).unwrap_or(0);
    let end = start + held[start..].iter().take_while(|h| h.is_site() && mine(h.at)).count();
    start..end
}

/// The cells of a rank's rows with their centroids' offsets, and their
/// particle quantities (zero unless asked for).
type RowsBack = ((Cells, Vec<[f64; 3]>), ParticleCells);

/// The cells of this rank's `len` rows from `first`, from the rows the
/// ranks sent it.
pub(super) fn rows_of(got: &Parcels, first: u64, len: usize, faces: bool) -> Result<RowsBack> {
    // Where each row's record starts in the parcels, then the rows in order.
    let bytes = &got.bytes;
    let mut starts = vec![usize::MAX; len];
    let mut at = 0;
    while at < bytes.len() {
        let row: Row = bytemuck::pod_read_unaligned(&bytes[at..at + size_of::<Row>()]);
        let i = row.site.checked_sub(first).filter(|&i| (i as usize) < len);
        let i = i.ok_or_else(|| Error::Internal(format!("row {} sent to the reader of {first}..", row.site)))?;
        starts[i as usize] = at;
        at += size_of::<Row>() + row.faces as usize * size_of::<FaceRow>();
    }
    let mut cells = Cells::default();
    let mut offsets = Vec::with_capacity(len);
    let mut particles = ParticleCells::default();
    let mut adj = Adjacency { offsets: vec![0], ..Default::default() };
    for (i, &at) in starts.iter().enumerate() {
        if at == usize::MAX {
            return Err(Error::Internal(format!("no cell came back for site {}", first + i as u64)));
        }
        let row: Row = bytemuck::pod_read_unaligned(&bytes[at..at + size_of::<Row>()]);
        let f = records::<FaceRow>(&bytes[at + size_of::<Row>()..][..row.faces as usize * size_of::<FaceRow>()]);
        particles.area.push(row.area);
        particles.coordination.push(row.counts[0]);
        particles.index.push(row.counts[1..=INDEX_ORDERS].try_into().unwrap_or([0; INDEX_ORDERS]));
        particles.max_face_order.push(row.counts[INDEX_ORDERS + 1]);
        cells.volume.push(row.volume);
        cells.centroid.push(row.centroid);
        cells.energy.push(row.energy);
        offsets.push(row.offset);
        for face in f {
            adj.neighbors.push(face.neighbor as u32);
            adj.shifts.push(face.shift);
            adj.areas.push(face.area);
            adj.normals.push(face.normal);
        }
        adj.offsets.push(adj.neighbors.len());
        adj.boundary.push(row.wall + 0.0);
        adj.boundary_vector.push(row.wall_vector.map(|v| v + 0.0));
    }
    cells.adjacency = faces.then_some(adj);
    Ok(((cells, offsets), particles))
}

/// The polyhedra of the cells in `pieces` (a part's job over `held`), as
/// one process's: each by its site's input index, a face across another
/// cell by that cell's site (an image's: its site's), a wall's made of its
/// mirrors' faces as one face ([`ON_BOUNDARY`]); with their particle
/// quantities by place in `held`, each polyhedron's place in `held`, and
/// the seconds taken.
fn polyhedra_of(
    mut pieces: crate::passes::pieces::Pieces,
    held: &[Held],
    thresholds: &IndexThresholds,
) -> (Vec<CellPolyhedron>, Vec<usize>, ParticleCells, f64) {
    let clock = std::time::Instant::now();
    let n = held.len() as i64;
    pieces.map_makers(|m| match usize::try_from(m).ok().and_then(|u| held.get(u)) {
        Some(h) if h.is_mirror() => n + h.wall as i64,
        _ => m,
    });
    let mut polyhedra = merge_pieces(&pieces);
    drop(pieces);
    let quantities = ParticleCells::of(held.len(), &polyhedra, thresholds);
    let places = polyhedra.iter().map(|p| p.site as usize).collect();
    polyhedra.par_iter_mut().for_each(|p| {
        p.site = held[p.site as usize].site as u32;
        for m in &mut p.face_neighbors {
            *m = match usize::try_from(*m).ok().and_then(|u| held.get(u)) {
                Some(h) if !h.is_mirror() => h.site as i64,
                Some(_) => ON_BOUNDARY,
                None if *m >= n => ON_BOUNDARY,
                None => *m,
            };
        }
    });
    (polyhedra, places, quantities, clock.elapsed().as_secs_f64())
}

/// This rank's rows' `cells` with the run's totals over the ranks of
/// `comm`, and what `like` says of the run (strategy, pairing, `k`,
/// `k_site`, parts): the counters (`counted`: [`counter_words`], then the
/// duplicates) added with the empty cells, the total volume summed exactly
/// and its error against `mesh_volume`.
pub(super) fn with_totals(
    comm: &dyn Reduce,
    mut counted: Vec<i64>,
    cells: Cells,
    mesh_volume: f64,
    like: Cells,
) -> Result<Cells> {
    counted.push(cells.volume.iter().filter(|&&v| v <= 0.0).count() as i64);
    comm.sum(&mut counted)?;
    let mut c = counters_of(&counted);
    c.duplicate_sites = counted[counted.len() - 2] as u64;
    c.empty_cells = counted[counted.len() - 1] as u64 - c.duplicate_sites;
    let total_volume = comm.exact_total(&ExactSum::of(&cells.volume))?.value();
    Ok(Cells {
        total_volume,
        mesh_volume,
        e_vol: (total_volume - mesh_volume).abs() / mesh_volume,
        counters: c,
        volume: cells.volume,
        centroid: cells.centroid,
        energy: cells.energy,
        adjacency: cells.adjacency,
        ..like
    })
}

/// The counters as numbers to add across ranks.
pub(super) fn counter_words(c: &Counters) -> Vec<i64> {
    [
        c.pairs,
        c.nonempty,
        c.filtered,
        c.clips,
        c.security_missed,
        c.overflows,
        c.broken,
        c.walks,
        c.second_pass,
        c.unresolved,
        c.missed_tets,
        c.faces_redone,
        c.out_of_halo,
        c.whole_cells,
        c.cut_cells,
    ]
    .map(|v| v as i64)
    .to_vec()
}

/// [`counter_words`] back.
fn counters_of(w: &[i64]) -> Counters {
    let v = |i: usize| w[i].max(0) as u64;
    Counters {
        pairs: v(0),
        nonempty: v(1),
        filtered: v(2),
        clips: v(3),
        security_missed: v(4),
        overflows: v(5),
        broken: v(6),
        walks: v(7),
        second_pass: v(8),
        unresolved: v(9),
        missed_tets: v(10),
        faces_redone: v(11),
        out_of_halo: v(12),
        whole_cells: v(13),
        cut_cells: v(14),
        duplicate_sites: 0,
        empty_cells: 0,
    }
}
