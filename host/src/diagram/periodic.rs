//! Periodic boxes: each site's Voronoi (or power) cell in the space the
//! box tiles, cut into the box.
//!
//! The box is cut into tets like any mesh, and the sites' images — a site
//! moved by whole box lengths — that lie within a halo of the box join the
//! sites: the same kernels, on either backend, clip the box by sites and
//! images together. Inside the box, their diagram is the periodic one as
//! soon as the halo holds, for every point of the box, the site (image)
//! whose power distance to it is smallest: a site farther than `H` from
//! the box is farther than `H` from every point in it, so with `R` the
//! largest distance from a point of the box to its nearest site (or
//! image) and `w_max - w_min` the weights' range, a halo of
//! `H = sqrt(R² + w_max - w_min)` leaves out only sites that lose
//! everywhere in the box. `R` is bounded before the diagram is computed,
//! over a grid of query cells (the distance from a cell's nearest site to
//! its farthest corner bounds it over the cell), with a first halo's
//! images; if the `H` it gives is wider, the images are taken again out
//! to it.
//!
//! Under whole cells (the default on the CPU backend) nothing is cut: each
//! site's cell is built whole among the sites and images around it — the
//! periodic cell itself, reaching across the box's sides as it may — and
//! the images get no cell of their own; the box, as 6 tets, only frames
//! the job. The halo is then `2H`: a point `y` of site `i`'s cell has
//! `|y - x_i|² - w_i <= |y - x_s|² - w_s` for its nearest site `s`, so
//! `|y - x_i| <= H`: the cell lies within `H` of the box, and the sites
//! that may cut it within `H` of its points. The other strategies clip
//! every cell, images' included, to the box cut into about one tet per
//! site, and fold the images' pieces into their sites as follows.
//!
//! An image's pieces belong to its site: volumes and energies (which are
//! moments about the image) add up, first moments about the image add up
//! to the site's, and a face shared with an image of site `j` is a face
//! with `j` through the images' difference of shifts
//! ([`Adjacency::shifts`]). The box's own faces are no boundary here.
//! Sums are folded in a fixed order, so a run repeats bit for bit.
//!
//! Triclinic cells and walls. The box may be any parallelepiped (three
//! lattice vectors, [`PeriodicBox::triclinic`]): sites are wrapped in its
//! fractional coordinates, images are moved by lattice vectors, and the
//! halo's images are those whose distance to the cell's slabs is within
//! it (a bound from below of their distance to the cell, so a few more
//! than needed). Along an axis that does not repeat, the cell's two faces
//! are walls: no image is taken across them, and each site and image
//! near a wall is mirrored in it. Inside the walls a mirror is never
//! nearer than the point it mirrors (the wall bisects them), so it cuts
//! no cell there; a site's own mirror, with the site's weight, cuts the
//! site's cell exactly along the wall. A face with a mirror is the cell's
//! area on the wall (its boundary). Walls are taken under whole cells
//! only; a site on a wall is moved [`WALL_GAP`] of the cell's height
//! inside, so that its mirror stays apart from it (and counted).

use crate::backend::Backend;
use crate::diagram::trajectory::FrameLists;
use crate::diagram::voronoi::{Cells, ClippedVoronoi};
use crate::error::{Error, Result};
use crate::exec::CpuBackend;
use crate::geom::periodic_box::PeriodicBox;
use crate::geom::site_grid::SiteGrid;
use crate::job::clip::{JobShape, Strategy};
use crate::job::sites::{Layout, Window};
use crate::job::BackendKind;
use crate::passes::faces::Adjacency;
use crate::passes::pieces::ON_BOUNDARY;
use crate::passes::polyhedra::{merge_pieces, CellPolyhedron};
use cvd_kernels::abi::SplitPoint;
use rayon::prelude::*;
use std::time::Instant;

/// The tets of a periodic job under whole cells: the box, as 6 tets, only
/// frames the job (its [`JobShape`] for the default strategy too).
pub const WHOLE_FRAME_TETS: usize = 6;

/// The image of a site: site `site` moved by `shift` lattice vectors,
/// then, for a mirror, reflected in a wall.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Image {
    pub(super) site: u32,
    pub(super) shift: [i32; 3],
    /// The wall it is reflected in: `2 axis + upper`, or [`NO_WALL`].
    pub(super) wall: u8,
}

/// An image not reflected in any wall.
pub(super) const NO_WALL: u8 = u8::MAX;

impl Image {
    pub(super) fn at(&self, domain: &PeriodicBox, sites: &[[f64; 3]]) -> [f64; 3] {
        let p = domain.shifted(sites[self.site as usize], self.shift);
        if self.wall == NO_WALL {
            p
        } else {
            domain.mirrored(p, (self.wall / 2) as usize, self.wall % 2 == 1)
        }
    }
}

/// How close to a wall, in its cell's heights, a site may lie: nearer, it
/// is moved this far inside, so that its mirror stays apart from it.
pub const WALL_GAP: f64 = 1e-9;

/// Builder of a periodic diagram: the cells of sites in a periodic box.
#[derive(Clone, Copy)]
pub struct PeriodicVoronoi<'a> {
    pub(super) domain: PeriodicBox,
    pub(super) sites: &'a [[f64; 3]],
    pub(super) weights: Option<&'a [f64]>,
    pub(super) backend: Option<&'a dyn Backend>,
    pub(super) faces: bool,
    pub(super) strategy: Option<Strategy>,
    pub(super) k_site: Option<usize>,
    pub(super) tets: Option<usize>,
    pub(super) keep: bool,
    pub(super) last: Option<&'a FrameLists>,
    pub(super) memory_budget: Option<u64>,
}

/// A periodic diagram's cells, per input site.
#[derive(Clone, Debug, Default)]
pub struct PeriodicCells {
    /// Volume, centroid (wrapped into the box), energy `∫|x - x_i|²` about
    /// the site's wrapped position, counters, and with faces the adjacency
    /// with each neighbour's image shift and no boundary. `mesh_volume` is
    /// the box's volume.
    pub cells: Cells,
    /// The sites wrapped into the box.
    pub sites: Vec<[f64; 3]>,
    /// Each cell's centroid less its site, unwrapped: the centroid of the
    /// whole cell around the site (0 for an empty cell).
    pub offsets: Vec<[f64; 3]>,
    /// How many sites were given outside the box (and wrapped).
    pub wrapped: usize,
    /// How many images joined the sites (mirrors included).
    pub images: usize,
    /// How many of them are mirrors in the walls.
    pub mirrors: usize,
    /// How many sites lay on a wall (within [`WALL_GAP`] of its cell's
    /// height) and were moved that far inside it.
    pub on_walls: usize,
    /// The halo's width (see the module's documentation).
    pub halo: f64,
    /// What this frame leaves for the next ([`PeriodicVoronoi::keep_lists`];
    /// `None` where not asked for, or on another backend than the CPU).
    pub lists: Option<FrameLists>,
    /// How many cells were built from the last frame's lists
    /// ([`PeriodicVoronoi::after`]) without searching for neighbours.
    pub reused: usize,
}

impl<'a> PeriodicVoronoi<'a> {
    /// The cells of `sites` in the periodic box `domain` (sites outside it
    /// are wrapped into it).
    pub fn new(domain: PeriodicBox, sites: &'a [[f64; 3]]) -> Self {
        Self {
            domain,
            sites,
            weights: None,
            backend: None,
            faces: false,
            strategy: None,
            k_site: None,
            tets: None,
            keep: false,
            last: None,
            memory_budget: None,
        }
    }

    /// Most memory the job may hold, in bytes (see
    /// [`ClippedVoronoi::memory_budget`]; images count as sites).
    pub fn memory_budget(mut self, bytes: impl Into<Option<u64>>) -> Self {
        self.memory_budget = bytes.into();
        self
    }

    /// Keeps each particle's nearest sites and images for the next frame
    /// of a trajectory ([`PeriodicCells::lists`]; whole cells on the CPU
    /// backend; see [`crate::diagram::trajectory`]).
    pub fn keep_lists(mut self, on: bool) -> Self {
        self.keep = on;
        self
    }

    /// Starts from the last frame's lists ([`PeriodicCells::lists`] of the
    /// same particles in the same cell, with the same weights; otherwise
    /// they are not used): a cell whose list they certify is built without
    /// searching for neighbours ([`PeriodicCells::reused`]). The cells are
    /// those of a frame computed afresh, bit for bit.
    pub fn after(mut self, last: Option<&'a FrameLists>) -> Self {
        self.last = last;
        self
    }

    /// The box.
    pub fn domain(&self) -> PeriodicBox {
        self.domain
    }

    /// The sites as given (not wrapped).
    pub fn input_sites(&self) -> &'a [[f64; 3]] {
        self.sites
    }

    /// Power cells: a weight per site ([`ClippedVoronoi::weights`]); each
    /// image carries its site's.
    pub fn weights(mut self, weights: &'a [f64]) -> Self {
        self.weights = Some(weights);
        self
    }

    /// Where to run (default: the CPU backend with all cores).
    pub fn backend(mut self, backend: &'a dyn Backend) -> Self {
        self.backend = Some(backend);
        self
    }

    /// Also the cells' faces, with each neighbour's image shift.
    pub fn faces(mut self, on: bool) -> Self {
        self.faces = on;
        self
    }

    /// Whole cells, tet-cell or cell-tet (default: as
    /// [`ClippedVoronoi::strategy`]).
    pub fn strategy(mut self, strategy: impl Into<Option<Strategy>>) -> Self {
        self.strategy = strategy.into();
        self
    }

    /// Neighbours per site for its cell (see [`ClippedVoronoi::k_site`]).
    pub fn k_site(mut self, k_site: impl Into<Option<usize>>) -> Self {
        self.k_site = k_site.into();
        self
    }

    /// Tets the box is cut into (default: about one per site).
    pub fn tets(mut self, tets: usize) -> Self {
        self.tets = Some(tets);
        self
    }

    /// The same diagram for other sites (a CVT's next iteration).
    pub fn sites<'b>(&self, sites: &'b [[f64; 3]]) -> PeriodicVoronoi<'b>
    where
        'a: 'b,
    {
        PeriodicVoronoi { sites, ..*self }
    }

    /// Computes the cells.
    pub fn compute(&self) -> Result<PeriodicCells> {
        self.run(None)
    }

    /// Computes the cells, each also as one closed polyhedron (whole cells
    /// only: [`Cells::polyhedra`], one per site with a cell, in site
    /// order) — its faces with the neighbours' sites (an image's face:
    /// its site's) or [`ON_BOUNDARY`] on a wall. On another backend than
    /// the CPU, the polyhedra come from a second run on `cpu`.
    pub fn compute_with_polyhedra(&self, cpu: &CpuBackend) -> Result<PeriodicCells> {
        self.run(Some(cpu))
    }

    fn run(&self, cpu: Option<&CpuBackend>) -> Result<PeriodicCells> {
        crate::job::sites::check_sites(self.sites, self.weights)?;
        let n = self.sites.len();
        let domain = self.domain;
        let clock = Instant::now();
        let (sites, on_walls) = place_sites(&domain, self.sites)?;
        let wrapped = sites.iter().zip(self.sites).filter(|(a, b)| a != b).count() - on_walls;
        let range = self.weights.map_or(0.0, |w| {
            let (lo, hi) = w.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
            hi - lo
        });
        let spacing = (domain.volume() / n as f64).cbrt();
        let shape = JobShape { density: false, sites: sites.len(), tets: WHOLE_FRAME_TETS };
        let strategy = match self.strategy {
            // Walls are mirrors, which only whole cells take as such; the
            // polyhedra are whole cells'.
            None if domain.has_walls() || cpu.is_some() => Some(Strategy::Whole),
            Some(s) if s != Strategy::Whole && domain.has_walls() => {
                return Err(Error::InvalidInput(format!(
                    "a cell with walls (periodic along {} only) is computed with whole cells; the {} strategy \
                     applies to cells periodic along every axis",
                    periodic_axes(&domain),
                    s.name()
                )))
            }
            s => s,
        };
        let whole = ClippedVoronoi::strategy_for(strategy, self.backend, shape) == Strategy::Whole;
        // A first halo: about the largest gap of uniform sites; then the
        // one the sites need.
        let first = (2.0 * spacing * 2.0 * spacing + range).sqrt();
        let mut images = images_within(&domain, &sites, first);
        let points: Vec<[f64; 3]> = sites.iter().copied().chain(images.iter().map(|m| m.at(&domain, &sites))).collect();
        let (reach, _) = coverage(&domain, &points, spacing, |_| true);
        drop(points);
        let mut halo = (reach * reach + range).sqrt() * (1.0 + 1e-9);
        if whole {
            // A whole cell reaches up to `H` outside the box, and the sites
            // that may cut it lie within `H` of its points.
            halo *= 2.0;
        }
        if halo > first {
            images = images_within(&domain, &sites, halo);
        }
        let before = images.len();
        images.extend(mirrors_within(&domain, &sites, &images, halo));
        let mirrors = images.len() - before;
        let mut all = sites.clone();
        all.extend(images.iter().map(|m| m.at(&domain, &sites)));
        let weights: Option<Vec<f64>> =
            self.weights.map(|w| w.iter().copied().chain(images.iter().map(|m| w[m.site as usize])).collect());
        // Whole cells need the box only as the job's frame: its 6 tets.
        let mesh = domain.mesh(self.tets.unwrap_or(if whole { 6 } else { n }));
        let images_s = clock.elapsed().as_secs_f64();
        let mut diagram = ClippedVoronoi::new(&mesh, &all)
            .faces(self.faces)
            .strategy(strategy)
            .k_site(self.k_site)
            .images_after(n)
            .memory_budget(self.memory_budget);
        if let Some(b) = self.backend {
            diagram = diagram.backend(b);
        }
        let whole_cells = diagram.resolved_strategy() == Strategy::Whole;
        // Whole cells in the order and frame a part of the box would lay
        // them out in (`crate::diagram::periodic_parts`): the same bits.
        // The frame: the points' bounding box (a part's, combined with the
        // others' by their extremes, is the same).
        let frame = crate::geom::vec3::bounding_box(&all);
        let order: Vec<u32> = if whole_cells {
            let blocks = Blocks::of(&domain, n);
            let key = |u: usize| match u.checked_sub(n).map(|k| images[k]) {
                None => PointKey::of(&domain, &blocks, &frame, all[u], u as u64, None),
                Some(m) => PointKey::of(&domain, &blocks, &frame, all[u], m.site as u64, Some((m.shift, m.wall))),
            };
            let mut keyed: Vec<(PointKey, u32)> = (0..all.len()).into_par_iter().map(|u| (key(u), u as u32)).collect();
            keyed.par_sort_unstable();
            keyed.into_iter().map(|(_, u)| u).collect()
        } else {
            Vec::new()
        };
        if whole_cells {
            diagram = diagram.layout(Layout {
                order: &order,
                lo: frame.0,
                hi: frame.1,
                grid_sites: all.len(),
                answer: (0, n),
                weights: None,
                weight_grid: None,
                window: Window::Whole,
                unheld: None,
                periodic: true,
                only: None,
                halves: false,
            });
        }
        let last = self.last.filter(|l| whole_cells && l.fits(&domain, &sites, self.weights));
        let moves = last.map(|l| l.moves(&sites));
        let candidates = last.zip(moves.as_ref()).and_then(|(l, m)| l.candidates(m, &images));
        let spare = FrameLists::spare(last, moves.as_ref(), candidates.is_some());
        if self.keep && whole_cells {
            diagram = diagram.keep_lists(Some(diagram.resolved_k_site() + spare)).candidates(candidates.as_ref());
        }
        if let Some(w) = &weights {
            diagram = diagram.weights(w);
        }
        let (mut whole, polyhedra) = match cpu {
            None => (diagram.compute()?, None),
            Some(cpu) => {
                if diagram.resolved_strategy() != Strategy::Whole {
                    return Err(Error::InvalidInput(
                        "the polyhedra of a periodic box's cells come from whole cells (--strategy whole)".into(),
                    ));
                }
                // As `ClippedVoronoi::compute_with_geometry`: another
                // backend's pieces stay on its device.
                let (mut cells, mut pieces) = if self.backend.is_none_or(|b| b.kind() == BackendKind::Cpu) {
                    diagram.compute_with_pieces(cpu)?
                } else {
                    (diagram.compute()?, diagram.faces(false).compute_with_pieces(cpu)?.1)
                };
                // A wall is one face, whatever mirrors made its parts: in
                // exact arithmetic a neighbour's mirror only touches the
                // cell along the line where the wall meets their bisector,
                // and rounding can leave a sliver of it there.
                if domain.has_walls() {
                    let first = all.len() as i64;
                    pieces.map_makers(|m| match usize::try_from(m - n as i64).ok().and_then(|k| images.get(k)) {
                        Some(image) if image.wall != NO_WALL => first + image.wall as i64,
                        _ => m,
                    });
                }
                let (polyhedra, t) = crate::geom::timing::timed(|| merge_pieces(&pieces));
                cells.timings.push("polyhedra", t);
                (cells, Some(polyhedra))
            }
        };
        let clock = Instant::now();
        let kept = whole.kept.take();
        let reused = kept.as_ref().map_or(0, |k| k.reused);
        let (mut cells, offsets) = fold(&domain, &sites, &all, &images, &whole);
        cells.polyhedra = polyhedra.map(|p| own_polyhedra(p, &images, n));
        cells.timings = whole.timings.clone();
        cells.timings.phases.insert(0, ("images".into(), images_s));
        cells.timings.push("fold", clock.elapsed().as_secs_f64());
        let image_count = images.len();
        let lists = kept.map(|k| FrameLists::new(domain, sites.clone(), self.weights, images, k, halo, last, spare));
        Ok(PeriodicCells {
            cells,
            sites,
            offsets,
            wrapped,
            images: image_count,
            mirrors,
            on_walls,
            halo,
            lists,
            reused,
        })
    }
}

/// The polyhedra of the sites' own cells (the first `n`; under whole
/// cells the images have none), with each face's maker taken to its site,
/// or to [`ON_BOUNDARY`] for a wall's (made by mirrors, numbered after the
/// images).
fn own_polyhedra(mut polyhedra: Vec<CellPolyhedron>, images: &[Image], n: usize) -> Vec<CellPolyhedron> {
    polyhedra.retain(|p| (p.site as usize) < n);
    polyhedra.par_iter_mut().for_each(|p| {
        for m in &mut p.face_neighbors {
            if *m >= n as i64 {
                *m = match images.get(*m as usize - n) {
                    Some(image) if image.wall == NO_WALL => image.site as i64,
                    _ => ON_BOUNDARY,
                };
            }
        }
    });
    polyhedra
}

/// The periodic axes' names, for messages.
fn periodic_axes(domain: &PeriodicBox) -> String {
    let names: Vec<&str> = (0..3).filter(|&a| domain.periodic()[a]).map(PeriodicBox::axis_name).collect();
    if names.is_empty() {
        "no axis".into()
    } else {
        names.join(", ")
    }
}

/// The sites wrapped into the box along its periodic axes; along its
/// walls each must lie between them (a site on a wall, or outside it by
/// rounding, within [`WALL_GAP`] of the height, is moved that far inside:
/// its mirror must stay apart from it). Also how many were moved so.
pub(super) fn place_sites(domain: &PeriodicBox, sites: &[[f64; 3]]) -> Result<(Vec<[f64; 3]>, usize)> {
    let mut placed: Vec<[f64; 3]> = sites.par_iter().map(|&p| domain.wrap(p)).collect();
    if !domain.has_walls() {
        return Ok((placed, 0));
    }
    let h = domain.heights();
    let mut moved = 0;
    for (i, p) in placed.iter_mut().enumerate() {
        let (out, axis) = domain.outside_walls(*p);
        if out > WALL_GAP * h[axis] {
            return Err(Error::InvalidInput(format!(
                "site {i} {:?} lies {out:e} outside the walls across axis {} (the cell is not periodic along it)",
                sites[i],
                PeriodicBox::axis_name(axis)
            )));
        }
        let s = domain.fractional(*p);
        let inside = s.map(|x| x.clamp(WALL_GAP, 1.0 - WALL_GAP));
        let mut t = [0.0; 3];
        for a in (0..3).filter(|&a| !domain.periodic()[a]) {
            t[a] = inside[a] - s[a];
        }
        if t != [0.0; 3] {
            let v = domain.vectors();
            *p = [0, 1, 2].map(|k| p[k] + t[0] * v[0][k] + t[1] * v[1][k] + t[2] * v[2][k]);
            moved += 1;
        }
    }
    Ok((placed, moved))
}

/// Every image of `sites` (other than the sites themselves) within
/// `halo` of the box, by site, then shift: shifts along the periodic axes
/// only.
pub(super) fn images_within(domain: &PeriodicBox, sites: &[[f64; 3]], halo: f64) -> Vec<Image> {
    let h = domain.heights();
    let m = [0, 1, 2].map(|a| if domain.periodic()[a] { (halo / h[a]).ceil().min(64.0) as i32 } else { 0 });
    let shifts: Vec<[i32; 3]> = (-m[2]..=m[2])
        .flat_map(|z| (-m[1]..=m[1]).flat_map(move |y| (-m[0]..=m[0]).map(move |x| [x, y, z])))
        .filter(|s| *s != [0; 3])
        .collect();
    sites
        .par_iter()
        .enumerate()
        .flat_map_iter(|(i, &p)| {
            shifts.iter().filter(move |&&s| domain.distance(domain.shifted(p, s)) <= halo).map(move |&shift| Image {
                site: i as u32,
                shift,
                wall: NO_WALL,
            })
        })
        .collect()
}

/// The mirrors of the sites and their `images` in each wall that lie
/// within `halo` of the box. Inside the walls a mirror is never nearer
/// than the point it mirrors, so it cuts no cell there; a site's own
/// mirror cuts its cell along the wall (their bisector, with equal
/// weights, is the wall).
pub(super) fn mirrors_within(domain: &PeriodicBox, sites: &[[f64; 3]], images: &[Image], halo: f64) -> Vec<Image> {
    let walls: Vec<u8> =
        (0..3u8).filter(|&a| !domain.periodic()[a as usize]).flat_map(|a| [2 * a, 2 * a + 1]).collect();
    if walls.is_empty() {
        return Vec::new();
    }
    let own = (0..sites.len()).map(|i| Image { site: i as u32, shift: [0; 3], wall: NO_WALL });
    let points: Vec<Image> = own.chain(images.iter().copied()).collect();
    points
        .par_iter()
        .flat_map_iter(|m| {
            walls.iter().filter_map(move |&wall| {
                let mirror = Image { wall, ..*m };
                (domain.distance(mirror.at(domain, sites)) <= halo).then_some(mirror)
            })
        })
        .collect()
}

/// An upper bound of the distance from any point of the box to the
/// nearest of `points`: over query cells of about `spacing` (a grid of the
/// fractional coordinates; those `counted` says), each cell's centre's
/// distance to its nearest point plus the cell's half diagonal. The
/// nearest point's distance is the same whichever of equally near points
/// is found, so the bound is a function of the points alone: a part that
/// holds every point within the centre's nearest distance of its cells
/// gets the same bits. Also the largest such nearest distance.
pub(super) fn coverage(
    domain: &PeriodicBox,
    points: &[[f64; 3]],
    spacing: f64,
    counted: impl Fn([f64; 3]) -> bool + Sync,
) -> (f64, f64) {
    let dims = coverage_dims(domain, spacing);
    let points: Vec<SplitPoint> = points.iter().map(|&p| SplitPoint::site(p, 0.0)).collect();
    if points.is_empty() {
        return (0.0, 0.0);
    }
    let grid = SiteGrid::new(&points);
    let centre = |at: [usize; 3]| domain.cartesian([0, 1, 2].map(|a| (at[a] as f64 + 0.5) / dims[a] as f64));
    // Every cell is the same parallelepiped: its centre's farthest corner.
    let half = (0..8)
        .map(|k| {
            let d = [0, 1, 2].map(|a| if (k >> a) & 1 == 0 { -0.5 } else { 0.5 } / dims[a] as f64);
            let (c, o) = (domain.cartesian(d), domain.cartesian([0.0; 3]));
            (0..3).map(|a| (c[a] - o[a]).powi(2)).sum::<f64>().sqrt()
        })
        .fold(0.0, f64::max);
    let nearest = |c: [f64; 3]| {
        let (s, _) = grid.nearest(c);
        let q = points[s as usize].to_f64();
        (0..3).map(|a| (c[a] - q[a]).powi(2)).sum::<f64>().sqrt()
    };
    // The query cells in blocks of `COVERAGE_BLOCK`³, each block's centres
    // within `r` of its middle `m`: none nearer its nearest point than
    // `nearest(m) + r` (the distance to the nearest point moves no faster
    // than the point). The blocks in order of that bound, each's cells
    // asked until the bound is no more than the largest found: the same
    // largest, without asking every cell of a wide void.
    let b = COVERAGE_BLOCK;
    let blocks = dims.map(|d| d.div_ceil(b));
    let cells_of = |k: usize| {
        let at = [k % blocks[0], (k / blocks[0]) % blocks[1], k / (blocks[0] * blocks[1])];
        [0, 1, 2].map(|a| at[a] * b..((at[a] + 1) * b).min(dims[a]))
    };
    let mut bounds: Vec<(f64, usize)> = (0..blocks.iter().product::<usize>())
        .into_par_iter()
        .map(|k| {
            let r = cells_of(k);
            let frac = |a: usize, i: usize| (i as f64 + 0.5) / dims[a] as f64;
            let mid = domain.cartesian([0, 1, 2].map(|a| 0.5 * (frac(a, r[a].start) + frac(a, r[a].end - 1))));
            let reach = (0..8)
                .map(|c| {
                    let corner = [0, 1, 2].map(|a| frac(a, if (c >> a) & 1 == 0 { r[a].start } else { r[a].end - 1 }));
                    let p = domain.cartesian(corner);
                    (0..3).map(|a| (p[a] - mid[a]).powi(2)).sum::<f64>().sqrt()
                })
                .fold(0.0, f64::max);
            ((nearest(mid) + reach) * (1.0 + 1e-9) + 1e-300, k)
        })
        .collect();
    bounds.sort_unstable_by(|x, y| y.0.total_cmp(&x.0).then(x.1.cmp(&y.1)));
    let mut largest: Option<f64> = None;
    for (bound, k) in bounds {
        if largest.is_some_and(|l| bound <= l) {
            break;
        }
        let r = cells_of(k);
        let mut cells: Vec<[usize; 3]> = Vec::with_capacity(b * b * b);
        for z in r[2].clone() {
            for y in r[1].clone() {
                cells.extend(r[0].clone().map(|x| [x, y, z]));
            }
        }
        let found = cells.into_par_iter().map(centre).filter(|&c| counted(c)).map(nearest).reduce_with(f64::max);
        largest = match (largest, found) {
            (Some(l), Some(f)) => Some(l.max(f)),
            (l, f) => l.or(f),
        };
    }
    largest.map_or((0.0, 0.0), |d| (d + half, d))
}

/// Query cells a side of a block of [`coverage`].
const COVERAGE_BLOCK: usize = 8;

/// The query cells of [`coverage`] along each axis.
fn coverage_dims(domain: &PeriodicBox, spacing: f64) -> [usize; 3] {
    domain.heights().map(|l| ((l / spacing).ceil() as usize).clamp(1, 1 << 10))
}

/// The box cut into blocks along its fractional coordinates — a power of
/// two along each axis, each block about [`Blocks::SPACINGS`] sites'
/// spacings across — numbered along a Morton curve. A diagram in parts
/// gives each rank a run of blocks in that order; every diagram orders its
/// sites by block first, so the sites of a run are a run of the sites.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct Blocks {
    /// Blocks along each axis.
    pub dims: [u32; 3],
}

impl Blocks {
    /// About how many spacings across a block is.
    const SPACINGS: f64 = 8.0;
    /// Most blocks in all.
    const MOST: u64 = 1 << 21;

    /// The blocks of `domain` for `n` sites.
    pub fn of(domain: &PeriodicBox, n: usize) -> Self {
        let spacing = (domain.volume() / n.max(1) as f64).cbrt();
        let mut dims = domain.heights().map(|h| {
            let b = (h / (Self::SPACINGS * spacing)).max(1.0);
            (b.log2().floor().exp2() as u32).clamp(1, 1 << 10)
        });
        while dims.iter().map(|&d| d as u64).product::<u64>() > Self::MOST {
            let a = (0..3).max_by_key(|&a| dims[a]).unwrap_or(0);
            dims[a] /= 2;
        }
        Self { dims }
    }

    /// Blocks in all.
    pub fn count(&self) -> usize {
        self.dims.iter().map(|&d| d as usize).product()
    }

    /// The block of a point of the box (by its fractional coordinates,
    /// clamped into the box).
    pub fn of_point(&self, domain: &PeriodicBox, p: [f64; 3]) -> [u32; 3] {
        let s = domain.fractional(p);
        [0, 1, 2].map(|a| ((s[a] * self.dims[a] as f64).floor().max(0.0) as u32).min(self.dims[a] - 1))
    }

    /// A block's index (x fastest).
    pub fn index(&self, b: [u32; 3]) -> usize {
        let d = self.dims.map(|d| d as usize);
        b[0] as usize + d[0] * (b[1] as usize + d[1] * b[2] as usize)
    }

    /// A block's place along the Morton curve (bits interleaved).
    pub fn key(b: [u32; 3]) -> u64 {
        let spread = |v: u32| {
            let mut x = v as u64 & 0x1f_ffff;
            x = (x | (x << 32)) & 0x1f_0000_0000_ffff;
            x = (x | (x << 16)) & 0x1f_0000_ff00_00ff;
            x = (x | (x << 8)) & 0x100f_00f0_0f00_f00f;
            x = (x | (x << 4)) & 0x10c3_0c30_c30c_30c3;
            (x | (x << 2)) & 0x1249_2492_4924_9249
        };
        spread(b[0]) | (spread(b[1]) << 1) | (spread(b[2]) << 2)
    }

    /// Every block's index, in Morton order.
    pub fn in_order(&self) -> Vec<u32> {
        let d = self.dims;
        let mut all: Vec<(u64, u32)> = (0..d[2])
            .flat_map(|z| (0..d[1]).flat_map(move |y| (0..d[0]).map(move |x| [x, y, z])))
            .map(|b| (Self::key(b), self.index(b) as u32))
            .collect();
        all.sort_unstable();
        all.into_iter().map(|(_, i)| i).collect()
    }
}

/// What orders a periodic job's points ([`crate::job::sites::Layout`]):
/// the sites first, by block ([`Blocks`]), then by their place along a
/// Morton curve in the frame, then by input index; the images and mirrors
/// after, by their place along the curve, then by site, shift and wall.
/// The same for a point whoever holds it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub(super) struct PointKey {
    image: bool,
    block: u64,
    curve: u32,
    site: u64,
    shift: [i32; 3],
    wall: u8,
}

impl PointKey {
    /// The key of a site (`image` none) or of its image, at `p`.
    pub fn of(
        domain: &PeriodicBox,
        blocks: &Blocks,
        frame: &([f64; 3], [f64; 3]),
        p: [f64; 3],
        site: u64,
        image: Option<([i32; 3], u8)>,
    ) -> Self {
        let (lo, hi) = frame;
        let extent = (0..3).map(|a| hi[a] - lo[a]).fold(0.0f64, f64::max).max(f64::MIN_POSITIVE);
        let q = |a: usize| ((((p[a] - lo[a]) / extent) * 1023.0).clamp(0.0, 1023.0)) as u32;
        let curve = Blocks::key([q(0), q(1), q(2)]) as u32;
        match image {
            None => Self {
                image: false,
                block: Blocks::key(blocks.of_point(domain, p)),
                curve,
                site,
                shift: [0; 3],
                wall: NO_WALL,
            },
            Some((shift, wall)) => Self { image: true, block: 0, curve, site, shift, wall },
        }
    }
}

/// A face of a folded cell: neighbour, shift, area, normal.
pub(super) type Face = (u32, [i32; 3], f64, [f64; 3]);

/// A folded cell's faces, and its area and area vector on the walls.
pub(super) type FoldedFaces = (Vec<Face>, f64, [f64; 3]);

/// A site's volume, energy, centroid offset (unwrapped) and centroid
/// (wrapped), from the cells `us` of `whole` (its own and its images',
/// each about its point of `all`).
pub(super) fn fold_site(
    domain: &PeriodicBox,
    site: [f64; 3],
    all: &[[f64; 3]],
    whole: &Cells,
    us: impl Iterator<Item = usize>,
) -> (f64, f64, [f64; 3], [f64; 3]) {
    let (mut m, mut first, mut e) = (0.0, [0.0; 3], 0.0);
    for u in us {
        let v = whole.volume[u];
        if v > 0.0 {
            m += v;
            e += whole.energy[u];
            for a in 0..3 {
                first[a] += v * (whole.centroid[u][a] - all[u][a]);
            }
        }
    }
    if m > 0.0 {
        let offset = first.map(|f| f / m);
        (m, e, offset, domain.wrap([0, 1, 2].map(|a| site[a] + offset[a])))
    } else {
        (m, e, [0.0; 3], site)
    }
}

/// A site's faces from the faces of its cells `us` in `a`: by (neighbour's
/// site, shift between them), in the order met, sorted (stably) and each
/// run of one key summed in that order; a face with a mirror is on a wall
/// (its area and area vector summed apart).
pub(super) fn fold_faces(
    a: &Adjacency,
    us: impl Iterator<Item = usize>,
    shift: impl Fn(usize) -> [i32; 3],
    owner: impl Fn(usize) -> u32,
    mirror: impl Fn(usize) -> bool,
) -> FoldedFaces {
    let mut faces: Vec<Face> = Vec::new();
    let (mut wall, mut wall_vector) = (0.0, [0.0; 3]);
    for u in us {
        let su = shift(u);
        for (v, area, normal) in a.of(u) {
            if mirror(v as usize) {
                wall += area;
                for k in 0..3 {
                    wall_vector[k] += area * normal[k];
                }
                continue;
            }
            let sv = shift(v as usize);
            faces.push((owner(v as usize), [0, 1, 2].map(|k| sv[k] - su[k]), area, normal));
        }
    }
    (merge_faces(faces), wall, wall_vector)
}

/// Faces sorted (stably) by (neighbour, shift), each run of one key summed
/// in the order met.
pub(super) fn merge_faces(mut faces: Vec<Face>) -> Vec<Face> {
    faces.sort_by_key(|f| (f.0, f.1));
    let mut row: Vec<Face> = Vec::with_capacity(faces.len());
    for (j, s, area, normal) in faces {
        match row.last_mut() {
            Some(last) if (last.0, last.1) == (j, s) => last.2 += area,
            _ => row.push((j, s, area, normal)),
        }
    }
    row
}

/// The cells of `sites` from the diagram `whole` of `all` (the sites, then
/// their `images`): each image's sums added to its site's, a face with a
/// mirror taken as the cell's boundary on a wall; and each centroid's
/// offset from its site, unwrapped.
fn fold(
    domain: &PeriodicBox,
    sites: &[[f64; 3]],
    all: &[[f64; 3]],
    images: &[Image],
    whole: &Cells,
) -> (Cells, Vec<[f64; 3]>) {
    let n = sites.len();
    // The images of each site, in order (mirrors get no cells: they are
    // taken under whole cells only).
    let mut of = vec![Vec::new(); n];
    for (k, m) in images.iter().enumerate() {
        if m.wall == NO_WALL {
            of[m.site as usize].push(n + k);
        }
    }
    let mirror = |u: usize| u >= n && images[u - n].wall != NO_WALL;
    let shift = |u: usize| if u < n { [0; 3] } else { images[u - n].shift };
    let owner = |u: usize| if u < n { u } else { images[u - n].site as usize };
    let mut volume = vec![0.0; n];
    let mut centroid = vec![[0.0; 3]; n];
    let mut energy = vec![0.0; n];
    let mut offsets = vec![[0.0; 3]; n];
    for i in 0..n {
        let us = std::iter::once(i).chain(of[i].iter().copied());
        (volume[i], energy[i], offsets[i], centroid[i]) = fold_site(domain, sites[i], all, whole, us);
    }
    let mut counters = whole.counters;
    let mut seen = std::collections::HashSet::new();
    counters.duplicate_sites = sites.iter().filter(|p| !seen.insert(p.map(f64::to_bits))).count() as u64;
    counters.empty_cells = volume.iter().filter(|&&v| v <= 0.0).count() as u64 - counters.duplicate_sites;
    let adjacency = whole.adjacency.as_ref().map(|a| {
        let rows: Vec<(Vec<Face>, f64, [f64; 3])> = (0..n)
            .into_par_iter()
            .map(|i| {
                let us = std::iter::once(i).chain(of[i].iter().copied());
                fold_faces(a, us, shift, |v| owner(v) as u32, mirror)
            })
            .collect();
        // A face with a mirror is seen from the cell's side only: half its
        // area is on the mirror's row, as the face with the cell.
        let (mut half, mut half_vector) = (vec![0.0; n], vec![[0.0; 3]; n]);
        for u in (n..all.len()).filter(|&u| mirror(u)) {
            for (v, area, normal) in a.of(u) {
                let i = owner(v as usize);
                half[i] += area;
                for k in 0..3 {
                    half_vector[i][k] -= area * normal[k];
                }
            }
        }
        let mut adj = Adjacency { offsets: vec![0], ..Default::default() };
        for (i, (row, wall, wall_vector)) in rows.into_iter().enumerate() {
            let (wall, wall_vector) = (wall + half[i], [0, 1, 2].map(|k| wall_vector[k] + half_vector[i][k]));
            for (j, s, area, normal) in row {
                adj.neighbors.push(j);
                adj.shifts.push(s);
                adj.areas.push(area);
                adj.normals.push(normal);
            }
            adj.offsets.push(adj.neighbors.len());
            adj.boundary.push(wall);
            adj.boundary_vector.push(wall_vector);
        }
        adj
    });
    let total_volume: f64 = volume.iter().sum();
    let mesh_volume = domain.volume();
    let cells = Cells {
        volume,
        centroid,
        energy,
        total_volume,
        mesh_volume,
        e_vol: (total_volume - mesh_volume).abs() / mesh_volume,
        strategy: whole.strategy,
        pairing: whole.pairing,
        k: whole.k,
        k_site: whole.k_site,
        counters,
        chunks: whole.chunks,
        grid_cells: whole.grid_cells,
        tets: whole.tets,
        timings: Default::default(),
        adjacency,
        polyhedra: None,
        kept: None,
    };
    (cells, offsets)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::points;

    #[test]
    fn images_within_are_all_the_images_near_the_box() {
        let b = PeriodicBox::new([0.0; 3], [1.0, 2.0, 0.5]).unwrap();
        let sites = points::uniform(12, 33).iter().map(|p| [p[0], 2.0 * p[1], 0.5 * p[2]]).collect::<Vec<_>>();
        for halo in [0.1, 0.45, 1.3] {
            let got = images_within(&b, &sites, halo);
            let mut expected = Vec::new();
            for (i, &p) in sites.iter().enumerate() {
                for z in -4..=4 {
                    for y in -4..=4 {
                        for x in -4..=4 {
                            let s = [x, y, z];
                            if s != [0; 3] && b.distance(b.shifted(p, s)) <= halo {
                                expected.push(Image { site: i as u32, shift: s, wall: NO_WALL });
                            }
                        }
                    }
                }
            }
            assert_eq!(got, expected, "halo {halo}: by site, then shift");
        }
    }

    /// The coverage's largest nearest distance, and its bound, are those of
    /// every query cell asked (the blocks pruned by their bounds hide no
    /// larger one): clusters alone in a box and in a triclinic one, with
    /// every cell counted and with half of them.
    #[test]
    fn coverage_is_every_query_cells_largest() {
        let blob = points::clustered(2_000, 2, 0.04, 8);
        let tilted = PeriodicBox::lammps([0.0; 3], [1.0, 1.2, 0.9], [0.3, -0.2, 0.1]).unwrap();
        for domain in [PeriodicBox::unit(), tilted] {
            let at: Vec<[f64; 3]> = blob.iter().map(|&p| domain.cartesian(p)).collect();
            let spacing = 0.02;
            let all: Vec<SplitPoint> = at.iter().map(|&p| SplitPoint::site(p, 0.0)).collect();
            let grid = crate::geom::site_grid::SiteGrid::new(&all);
            let dims = coverage_dims(&domain, spacing);
            for half_of in [false, true] {
                let counted = |c: [f64; 3]| !half_of || domain.fractional(c)[0] < 0.5;
                let mut most = 0.0f64;
                for z in 0..dims[2] {
                    for y in 0..dims[1] {
                        for x in 0..dims[0] {
                            let f = [x, y, z].map(|i| i as f64 + 0.5);
                            let c = domain.cartesian([0, 1, 2].map(|a| f[a] / dims[a] as f64));
                            if counted(c) {
                                let (s, _) = grid.nearest(c);
                                let q = all[s as usize].to_f64();
                                most = most.max((0..3).map(|a| (c[a] - q[a]).powi(2)).sum::<f64>().sqrt());
                            }
                        }
                    }
                }
                let (bound, largest) = coverage(&domain, &at, spacing, counted);
                assert!(most > 0.2, "a void: {most}");
                assert_eq!(largest.to_bits(), most.to_bits(), "half: {half_of}");
                assert!(bound > largest);
            }
        }
    }

    #[test]
    fn sites_are_checked_before_anything_is_computed() {
        let b = PeriodicBox::unit();
        assert!(matches!(PeriodicVoronoi::new(b, &[]).compute(), Err(Error::InvalidInput(_))));
        let sites = points::uniform(3, 34);
        let r = PeriodicVoronoi::new(b, &sites).weights(&[0.0; 2]).compute();
        assert!(matches!(r, Err(Error::InvalidInput(m)) if m.contains("2 weights for 3 sites")));
        let bad = [[0.5, f64::NAN, 0.5]];
        assert!(matches!(PeriodicVoronoi::new(b, &bad).compute(), Err(Error::InvalidInput(_))));
    }
}
