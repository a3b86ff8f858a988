//! The faces of the clipped cells: which sites' cells touch, over what
//! area, and how much of each cell lies on the domain's boundary — the
//! clipped Voronoi adjacency (the restricted Delaunay graph), from the
//! kernels' face sums ([`cvd_kernels::clip::add_faces`]).
//!
//! The kernels add each piece's bisector faces to the slot of the
//! neighbour that made them in the site's own neighbour list, and its
//! faces on the mesh's boundary to one slot per site; a face whose maker
//! is not in the list (a grid walk found it) goes to one of a few spill
//! slots that maker claims, and when those run out it is summed apart and
//! the host gives such a site its faces from the same kernel bodies on the
//! CPU ([`FaceCollector`]). Each
//! shared face is then measured from both sides; the adjacency holds their
//! mean, so `area(i, j) == area(j, i)` exactly.

use crate::exec::TaskSink;
use crate::geom::mesh::TetMesh;
use cvd_kernels::clip::PieceSink;
use cvd_kernels::lists::Lists;
use cvd_kernels::polyhedron::{made_by_site, Polyhedron, NO_ID, TET_FACE};
use rayon::prelude::*;
use std::collections::HashMap;
use std::sync::Mutex;

/// The clipped Voronoi adjacency, per input site (CSR): the sites whose
/// cells share a face with its cell, the face's area and unit normal
/// (from the site towards the neighbour), and the cell's area on the
/// domain's boundary. A duplicated site's row is empty (its cell is the
/// first copy's).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Adjacency {
    /// Row `i` is `offsets[i]..offsets[i + 1]` of the arrays below.
    pub offsets: Vec<usize>,
    /// Neighbour sites (input indices), increasing within a row.
    pub neighbors: Vec<u32>,
    /// Area of each shared face, the same from either side.
    pub areas: Vec<f64>,
    /// Unit normal of each shared face, from the site towards the
    /// neighbour (the bisector's).
    pub normals: Vec<[f64; 3]>,
    /// Each cell's area on the domain's boundary.
    pub boundary: Vec<f64>,
    /// Each cell's boundary area vector `∫ n dA` over its part of the
    /// domain's boundary (`n` the outward unit normal): its length is at
    /// most the boundary area, equal where that part is flat.
    pub boundary_vector: Vec<[f64; 3]>,
    /// In a periodic box, the image of each neighbour the face is shared
    /// with: the neighbour's site plus `shift` box lengths along each axis
    /// (one per entry of `neighbors`; empty when not periodic). A site may
    /// then share several faces with one neighbour, or with itself.
    pub shifts: Vec<[i32; 3]>,
}

impl Adjacency {
    /// The faces site `i` shares: `(neighbour, area, normal)`.
    pub fn of(&self, i: usize) -> impl Iterator<Item = (u32, f64, [f64; 3])> + '_ {
        let r = self.offsets[i]..self.offsets[i + 1];
        r.map(move |e| (self.neighbors[e], self.areas[e], self.normals[e]))
    }

    /// The image shift of entry `e` ([`Self::shifts`]; none when not
    /// periodic).
    pub fn shift(&self, e: usize) -> [i32; 3] {
        self.shifts.get(e).copied().unwrap_or([0; 3])
    }

    /// The surface area of cell `i`: its shared faces and its boundary.
    pub fn surface_area(&self, i: usize) -> f64 {
        self.areas[self.offsets[i]..self.offsets[i + 1]].iter().sum::<f64>() + self.boundary[i]
    }

    /// Number of sites (rows).
    pub fn len(&self) -> usize {
        self.boundary.len()
    }

    /// Whether there are no rows.
    pub fn is_empty(&self) -> bool {
        self.boundary.is_empty()
    }
}

/// Which faces of each tet lie on the mesh's boundary: 4 bits per tet
/// (bit `f` for the face opposite vertex `f`), 8 tets per word, as the
/// kernels read them.
pub(crate) fn boundary_bits(mesh: &TetMesh) -> Vec<u32> {
    boundary_bits_of(mesh.tets.len(), &mesh.unshared_faces())
}

/// [`boundary_bits`] of `n_tets` tets from their unshared faces
/// ([`TetMesh::unshared_faces`]).
pub(crate) fn boundary_bits_of(n_tets: usize, unshared: &[(u32, u8)]) -> Vec<u32> {
    let mut bits = vec![0u32; n_tets.div_ceil(8).max(1)];
    for &(t, f) in unshared {
        let t = t as usize;
        bits[t / 8] |= 1 << (4 * (t % 8) + f as usize);
    }
    bits
}

/// Of the boundary bits `bits` ([`boundary_bits`]) of a mesh, those of
/// its tets `kept` (in their order: a part of the mesh).
pub(crate) fn boundary_bits_among(bits: &[u32], kept: &[u32]) -> Vec<u32> {
    let mut among = vec![0u32; kept.len().div_ceil(8).max(1)];
    for (u, &t) in kept.iter().enumerate() {
        let t = t as usize;
        among[u / 8] |= (bits[t / 8] >> (4 * (t % 8)) & 0xf) << (4 * (u % 8));
    }
    among
}

/// One face of a piece: its site, its maker (a site, or [`TET_FACE`] +
/// f), its area, its tet and its outward unit normal, in the job's frame
/// and indices.
pub(crate) struct PieceFace {
    site: u32,
    maker: u32,
    area: f32,
    tet: u32,
    normal: [f32; 3],
}

/// Every face of every piece the kernels finish.
#[derive(Default)]
pub(crate) struct FaceCollector(pub(crate) Vec<PieceFace>);

impl PieceSink for FaceCollector {
    fn piece<const P: usize, const V: usize>(&mut self, tet: u32, site: u32, poly: &Polyhedron<P, V>, _volume: f32) {
        let areas = poly.face_areas();
        for (q, &area) in areas.iter().enumerate().take(poly.n_planes as usize) {
            let maker = poly.ids[q];
            if area != 0.0 && maker != NO_ID {
                let n = poly.planes[q].truncate().normalize();
                self.0.push(PieceFace { site, maker, area, tet, normal: n.to_array() });
            }
        }
    }

    fn discard_tet(&mut self, tet: u32) {
        while self.0.last().is_some_and(|f| f.tet == tet) {
            self.0.pop();
        }
    }

    fn discard_site(&mut self, site: u32) {
        while self.0.last().is_some_and(|f| f.site == site) {
            self.0.pop();
        }
    }
}

impl TaskSink for FaceCollector {
    fn hand_over(self, all: &Mutex<Vec<Self>>) {
        if !self.0.is_empty() {
            all.lock().unwrap_or_else(|e| e.into_inner()).push(self);
        }
    }
}

/// Each unique site's faces in the job's frame, as rows (CSR): the
/// neighbours it shares a face with (job indices, increasing) and the
/// faces' areas, its boundary area and the boundary's area vector. The few
/// rows [`complete`] redoes are held apart.
#[derive(Default)]
pub(crate) struct FaceRows {
    offsets: Vec<usize>,
    neighbors: Vec<u32>,
    areas: Vec<f64>,
    boundary: Vec<f64>,
    vector: Vec<[f64; 3]>,
    redone: HashMap<u32, (Vec<u32>, Vec<f64>)>,
}

impl FaceRows {
    /// Site `u`'s neighbours and areas.
    fn row(&self, u: usize) -> (&[u32], &[f64]) {
        if !self.redone.is_empty() {
            if let Some((n, a)) = self.redone.get(&(u as u32)) {
                return (n, a);
            }
        }
        let r = self.offsets[u]..self.offsets[u + 1];
        (&self.neighbors[r.clone()], &self.areas[r])
    }

    /// The area site `u` gives its face with `v`, if it has one.
    fn area(&self, u: usize, v: u32) -> Option<f64> {
        let (n, a) = self.row(u);
        n.binary_search(&v).ok().map(|at| a[at])
    }

    fn len(&self) -> usize {
        self.boundary.len()
    }
}

/// Each unique site's faces from the kernels' sums (`sums`, `k +`
/// [`FACE_SUMS_EXTRA`](cvd_kernels::clip::FACE_SUMS_EXTRA) per site from
/// site `first` of the job's `n`, in units of `1 / area_scale`; the other
/// sites have none) and its list `lists[u * k..]`, the sums dropped as soon
/// as read; the sites with faces outside their list are returned apart, to
/// be completed.
pub(crate) fn from_sums(
    sums: Vec<i64>,
    lists: &Lists,
    k: usize,
    area_scale: f64,
    (first, n): (usize, usize),
) -> (FaceRows, Vec<u32>) {
    use cvd_kernels::clip::{FACE_SPILLS, FACE_SUMS_EXTRA};
    let per = k + FACE_SUMS_EXTRA;
    let summed = first..first + sums.len() / per;
    // Site `u`'s sums, if it has any.
    let of = |u: usize| summed.contains(&u).then(|| &sums[(u - first) * per..(u - first + 1) * per]);
    // Site `u`'s faces into `row`: its list's slots, then the spilled
    // (maker + 1, area) pairs; one entry per maker (a maker in the list
    // may have spilled too, its pieces finished by the host's pass with no
    // list to look it up in), by maker.
    let row_of = |u: usize, row: &mut Vec<(u32, i64)>| {
        row.clear();
        let Some(s) = of(u) else { return };
        row.extend((0..k).filter(|&q| s[q] != 0).map(|q| (lists.get(lists.slot(u), q), s[q])));
        for spill in 0..FACE_SPILLS {
            let (key, area) = (s[k + 5 + 2 * spill], s[k + 6 + 2 * spill]);
            if key != 0 && area != 0 {
                row.push(((key - 1) as u32, area));
            }
        }
        row.sort_unstable_by_key(|e| e.0);
        row.dedup_by(|later, kept| {
            let same = later.0 == kept.0;
            if same {
                kept.1 += later.1;
            }
            same
        });
    };
    let lens: Vec<usize> = (0..n)
        .into_par_iter()
        .map_init(Vec::new, |row, u| {
            row_of(u, row);
            row.len()
        })
        .collect();
    let mut offsets = Vec::with_capacity(lens.len() + 1);
    offsets.push(0);
    for len in &lens {
        offsets.push(offsets[offsets.len() - 1] + len);
    }
    let total = offsets[lens.len()];
    let (mut neighbors, mut areas) = (vec![0u32; total], vec![0.0f64; total]);
    let rows = split_rows(&mut neighbors, lens.iter().copied())
        .into_par_iter()
        .zip(split_rows(&mut areas, lens.iter().copied()));
    rows.enumerate().for_each_init(Vec::new, |row, (u, (ns, as_))| {
        row_of(u, row);
        for (e, &(v, a)) in row.iter().enumerate() {
            (ns[e], as_[e]) = (v, a as f64 / area_scale);
        }
    });
    let boundary = (0..n).into_par_iter().map(|u| of(u).map_or(0.0, |s| s[k] as f64 / area_scale)).collect();
    let vector = (0..n)
        .into_par_iter()
        .map(|u| of(u).map_or([0.0; 3], |s| [2, 3, 4].map(|c| s[k + c] as f64 / area_scale)))
        .collect();
    let incomplete = summed.clone().filter(|&u| of(u).is_some_and(|s| s[k + 1] != 0)).map(|u| u as u32).collect();
    (FaceRows { offsets, neighbors, areas, boundary, vector, redone: HashMap::new() }, incomplete)
}

/// The faces of the sites `which` from every piece's faces (`all`, from a
/// [`FaceCollector`]) and the tets' boundary bits, replacing theirs in
/// `faces`; each face's area times `weight(tet)` (1, or a density).
pub(crate) fn complete(
    faces: &mut FaceRows,
    which: &[u32],
    all: &[FaceCollector],
    bits: &[u32],
    weight: impl Fn(usize) -> f64,
) {
    type SiteFaceSums = (HashMap<u32, f64>, f64, [f64; 3]);
    let mut redone: HashMap<u32, SiteFaceSums> = which.iter().map(|&u| (u, Default::default())).collect();
    for f in all.iter().flat_map(|c| &c.0) {
        let Some(entry) = redone.get_mut(&f.site) else { continue };
        let t = f.tet as usize;
        let area = f.area as f64 * weight(t);
        if made_by_site(f.maker) {
            *entry.0.entry(f.maker).or_insert(0.0) += area;
        } else if (TET_FACE..NO_ID).contains(&f.maker)
            && (bits[t / 8] >> (4 * (t % 8) + (f.maker - TET_FACE) as usize)) & 1 != 0
        {
            entry.1 += area;
            for (c, n) in entry.2.iter_mut().zip(f.normal) {
                *c += n as f64 * area;
            }
        }
    }
    for (u, (nbrs, boundary, vector)) in redone {
        let mut list: Vec<(u32, f64)> = nbrs.into_iter().collect();
        list.sort_unstable_by_key(|e| e.0);
        faces.redone.insert(u, list.into_iter().unzip());
        faces.boundary[u as usize] = boundary;
        faces.vector[u as usize] = vector;
    }
}

/// The adjacency per input site from each unique site's faces (job
/// indices, job frame): shared faces averaged over their two sides,
/// lengths scaled to the world (`scale`), normals along the sites'
/// difference in the world (`sites`, input order; `map`: input to unique).
/// The rows are built in the job's order, where a site's neighbours lie
/// near it in memory, each written to its input row. With `halves`, each
/// row holds its own half of each face only (the area it saw, halved):
/// a diagram in parts adds the other side's as one process does here.
pub(crate) fn assemble(
    faces: FaceRows,
    map: &crate::job::sites::SiteMap,
    sites: &[[f64; 3]],
    scale: f64,
    halves: bool,
) -> Adjacency {
    let n = faces.len();
    // The input index of each unique site (duplicates map to nothing), and
    // its position in the world, in the job's order.
    let owner = map.inputs(n);
    let at: Vec<[f64; 3]> = owner.par_iter().map(|&i| sites[i as usize]).collect();
    let faces = &faces;
    // Faces seen from one side only (the other side's rounded to nothing):
    // half the area, on both rows.
    let mut one_sided: Vec<(u32, u32, f64)> = (0..n)
        .into_par_iter()
        .filter(|_| !halves)
        .flat_map_iter(|u| {
            let (vs, areas) = faces.row(u);
            vs.iter()
                .zip(areas)
                .filter(move |&(&v, _)| faces.area(v as usize, u as u32).is_none())
                .map(move |(&v, &a)| (v, u as u32, a))
        })
        .collect();
    one_sided.sort_unstable_by_key(|e| (e.0, e.1));
    let extra = |u: usize| {
        let lo = one_sided.partition_point(|e| e.0 < u as u32);
        &one_sided[lo..lo + one_sided[lo..].iter().take_while(|e| e.0 == u as u32).count()]
    };
    // Each input site's row length (duplicates: empty).
    let len: Vec<u32> = (0..n).into_par_iter().map(|u| (faces.row(u).0.len() + extra(u).len()) as u32).collect();
    let mut offsets = Vec::with_capacity(map.len() + 1);
    offsets.push(0);
    for m in map.iter() {
        offsets.push(offsets[offsets.len() - 1] + m.map_or(0, |u| len[u] as usize));
    }
    drop(len);
    let total = offsets[map.len()];
    let (mut neighbors, mut areas, mut normals) = (vec![0u32; total], vec![0.0f64; total], vec![[0.0f64; 3]; total]);
    let lens = || offsets.windows(2).map(|w| w[1] - w[0]);
    let mut rows: Vec<_> = split_rows(&mut neighbors, lens())
        .into_iter()
        .zip(split_rows(&mut areas, lens()))
        .zip(split_rows(&mut normals, lens()))
        .map(Some)
        .collect();
    // The input rows in the job's order.
    let by_job: Vec<_> = owner.iter().map(|&i| rows[i as usize].take().expect("one row per unique site")).collect();
    drop(rows);
    let l2 = scale * scale;
    by_job.into_par_iter().enumerate().for_each_init(Vec::new, |row, (u, ((js, as_), ns))| {
        let p = at[u];
        // Each side's half, scaled, the cell's own first: a diagram in
        // parts adds the other side's half, from another part, the same way.
        let face = |v: u32, own: f64, other: f64| {
            let q = at[v as usize];
            let d = [q[0] - p[0], q[1] - p[1], q[2] - p[2]];
            let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            (owner[v as usize], 0.5 * own * l2 + 0.5 * other * l2, d.map(|c| c / len))
        };
        let (vs, areas) = faces.row(u);
        row.clear();
        let other = |v: u32| if halves { None } else { faces.area(v as usize, u as u32) };
        row.extend(vs.iter().zip(areas).map(|(&v, &a)| face(v, a, other(v).unwrap_or(0.0))));
        row.extend(extra(u).iter().map(|&(_, v, a)| face(v, a, 0.0)));
        row.sort_unstable_by_key(|e: &(u32, f64, [f64; 3])| e.0);
        for (k, &(j, a, n)) in row.iter().enumerate() {
            (js[k], as_[k], ns[k]) = (j, a, n);
        }
    });
    let boundary = map.iter().map(|m| m.map_or(0.0, |u| faces.boundary[u] * l2)).collect();
    let boundary_vector = map.iter().map(|m| m.map_or([0.0; 3], |u| faces.vector[u].map(|c| c * l2))).collect();
    Adjacency { offsets, neighbors, areas, normals, boundary, boundary_vector, shifts: Vec::new() }
}

/// `all` cut into consecutive rows of the lengths `lens`.
fn split_rows<T>(mut all: &mut [T], lens: impl Iterator<Item = usize>) -> Vec<&mut [T]> {
    let mut rows = Vec::new();
    for len in lens {
        let (row, rest) = std::mem::take(&mut all).split_at_mut(len);
        rows.push(row);
        all = rest;
    }
    rows
}

/// A site's pieces, as [`FaceCollector`] takes them, and their volume.
#[derive(Default)]
struct SitePieces {
    faces: FaceCollector,
    volume: f64,
}

impl PieceSink for SitePieces {
    fn piece<const P: usize, const V: usize>(&mut self, tet: u32, site: u32, poly: &Polyhedron<P, V>, volume: f32) {
        self.volume += volume as f64;
        self.faces.piece(tet, site, poly, volume);
    }

    fn discard_tet(&mut self, _tet: u32) {}

    fn discard_site(&mut self, site: u32) {
        self.faces.discard_site(site);
    }
}

/// The faces of the sites `which` (job indices) from their own pieces only:
/// for each, a flood over the mesh's tets from the one holding its cell's
/// centroid, through the faces of the tets where it has a piece, each pair
/// clipped by the kernels' bodies on the CPU. Certified by the volume: the
/// pieces found must add up to the site's volume in the sums (`out`); when
/// one does not (a cell the domain cuts in two), or under a density, `None`
/// — the caller then takes every piece again. Under whole cells, each
/// site's cell is built again instead ([`redo_whole_sites`]).
pub(crate) fn redo_sites(
    job: &crate::job::clip::ClipJob,
    out: &crate::job::clip::ClipOutput,
    which: &[u32],
    lists: &crate::job::knn::PackedLists,
) -> Option<Vec<FaceCollector>> {
    use cvd_kernels::abi::ACCUM_PER_SITE;
    use cvd_kernels::clip::{FaceInputs, Paired};
    use cvd_kernels::walk::GridWalk;
    if job.strategy == crate::job::clip::Strategy::Whole {
        return redo_whole_sites(job, which, lists);
    }
    if job.verts.iter().any(|v| v.hi[3] != 1.0) {
        return None;
    }
    let neighbors = tet_neighbors(&job.tets);
    let g = crate::exec::build_grid(&job.site_knn);
    let walk = GridWalk::new(&job.refine, &[], &g.cell_start, &g.cell_count, &g.sorted);
    let faces = FaceInputs { site_nbrs: &[], tet_faces: &job.tet_faces };
    let verts: Vec<[f64; 3]> = job.verts.iter().map(|v| v.to_f64()).collect();
    let scale = job.params.fixed_scale as f64;
    // The pairs' own sums go nowhere: only their pieces count here.
    let n_sums = job.params.n_sites as usize * ACCUM_PER_SITE + job.tets.len();
    let scratch: Vec<std::sync::atomic::AtomicI64> =
        (0..n_sums).map(|_| std::sync::atomic::AtomicI64::new(0)).collect();
    which
        .par_iter()
        .map(|&u| {
            let u = u as usize;
            let s = &out.sums[u * ACCUM_PER_SITE..(u + 1) * ACCUM_PER_SITE];
            let volume = s[0] as f64 / scale;
            if volume <= 0.0 {
                return Some(SitePieces::default().faces);
            }
            let x = job.sites[u].to_f64();
            let c = [0, 1, 2].map(|a| x[a] + s[1 + a] as f64 / scale / volume);
            let start = tet_holding(&verts, &job.tets, c)?;
            let mut sums = &scratch[..];
            let mut pieces = SitePieces::default();
            let mut seen = std::collections::HashSet::from([start]);
            let mut queue = vec![start];
            while let Some(t) = queue.pop() {
                let before = pieces.volume;
                let mut still = crate::exec::LocalPairs::default();
                let refine = cvd_kernels::abi::RefineParams {
                    clip: cvd_kernels::abi::ClipParams { faces_base: 0, ..job.refine.clip },
                    ..job.refine
                };
                let (sites, tets) = (&job.sites[..], &job.tets[..]);
                cvd_kernels::refine::refine_pair(
                    t as usize,
                    u,
                    Paired::NONE,
                    &refine,
                    walk,
                    sites,
                    &job.verts,
                    tets,
                    faces,
                    &mut sums,
                    &mut still,
                    &mut pieces,
                );
                if !still.0.is_empty() {
                    return None;
                }
                if pieces.volume > before {
                    for &n in &neighbors[t as usize] {
                        if n != u32::MAX && seen.insert(n) {
                            queue.push(n);
                        }
                    }
                }
            }
            ((pieces.volume - volume).abs() <= 1e-5 * volume).then_some(pieces.faces)
        })
        .collect()
}

/// The faces of the sites `which` (job indices) under whole cells: each
/// site's cell built again by the same body (from the domain's box, by a
/// walk of the site grid: no list), its faces collected from its whole
/// cell or its pieces. `None` where a cell could not be built.
fn redo_whole_sites(
    job: &crate::job::clip::ClipJob,
    which: &[u32],
    lists: &crate::job::knn::PackedLists,
) -> Option<Vec<FaceCollector>> {
    use cvd_kernels::abi::{counter, ClipParams, RefineParams, ACCUM_PER_SITE};
    use cvd_kernels::clip::FaceInputs;
    use cvd_kernels::polyhedron::{CELL_PLANES, CELL_VERTS};
    use cvd_kernels::walk::GridWalk;
    use std::sync::atomic::AtomicI64;
    let domain = job.domain.as_deref()?;
    let g = crate::exec::build_grid(&job.site_knn);
    // No face sums: the sink takes the faces. The cells from their lists,
    // as the kernels built them (the same start, planes and order: the
    // same bits; a part's walks stay in its held cells).
    let refine =
        RefineParams { clip: ClipParams { faces_base: 0, list_bits: lists.bits, ..job.refine.clip }, ..job.refine };
    let walk = GridWalk::new(&refine, &lists.words, &g.cell_start, &g.cell_count, &g.sorted);
    let faces = FaceInputs { site_nbrs: &[], tet_faces: &job.tet_faces };
    // The cells' own sums go nowhere: only their faces count here.
    let n_sums = job.params.n_sites as usize * ACCUM_PER_SITE + job.tets.len();
    let scratch: Vec<AtomicI64> = (0..n_sums).map(|_| AtomicI64::new(0)).collect();
    let counted: Vec<AtomicI64> = (0..counter::COUNT).map(|_| AtomicI64::new(0)).collect();
    which
        .par_iter()
        .map(|&u| {
            let (mut sums, mut counters) = (&scratch[..], &counted[..]);
            let mut still = crate::exec::LocalPairs::default();
            let mut out = FaceCollector::default();
            cvd_kernels::whole::whole_cell::<CELL_PLANES, CELL_VERTS, _, _, _, _>(
                u as usize,
                &refine,
                walk,
                &job.sites,
                &job.verts,
                &job.tets,
                domain.view(),
                faces,
                &mut sums,
                &mut counters,
                &mut still,
                &mut out,
            );
            still.0.is_empty().then_some(out)
        })
        .collect()
}

/// The tets across each tet's four faces (`u32::MAX` on the boundary).
fn tet_neighbors(tets: &[[u32; 4]]) -> Vec<[u32; 4]> {
    let mut first: HashMap<[u32; 3], (u32, usize)> = HashMap::with_capacity(2 * tets.len());
    let mut out = vec![[u32::MAX; 4]; tets.len()];
    for (t, v) in tets.iter().enumerate() {
        for f in 0..4 {
            let mut key = [v[(f + 1) % 4], v[(f + 2) % 4], v[(f + 3) % 4]];
            key.sort_unstable();
            if let Some((other, g)) = first.remove(&key) {
                out[t][f] = other;
                out[other as usize][g] = t as u32;
            } else {
                first.insert(key, (t as u32, f));
            }
        }
    }
    out
}

/// The tet holding `p` (barycentric coordinates all above -1e-9), or the
/// one whose centroid is nearest.
fn tet_holding(verts: &[[f64; 3]], tets: &[[u32; 4]], p: [f64; 3]) -> Option<u32> {
    let sub = |a: [f64; 3], b: [f64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    let det = |a: [f64; 3], b: [f64; 3], c: [f64; 3]| {
        a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0]) + a[2] * (b[0] * c[1] - b[1] * c[0])
    };
    let inside = |t: &[u32; 4]| {
        let v = t.map(|i| verts[i as usize]);
        let (a, b, c) = (sub(v[1], v[0]), sub(v[2], v[0]), sub(v[3], v[0]));
        let d = det(a, b, c);
        if d == 0.0 {
            return false;
        }
        let q = sub(p, v[0]);
        let l = [det(q, b, c) / d, det(a, q, c) / d, det(a, b, q) / d];
        l.iter().all(|&x| x >= -1e-9) && l.iter().sum::<f64>() <= 1.0 + 1e-9
    };
    if let Some(t) = tets.iter().position(inside) {
        return Some(t as u32);
    }
    let dist = |t: &[u32; 4]| {
        let c = [0, 1, 2].map(|a| t.iter().map(|&i| verts[i as usize][a]).sum::<f64>() / 4.0);
        (0..3).map(|a| (c[a] - p[a]).powi(2)).sum::<f64>()
    };
    (0..tets.len()).min_by(|&a, &b| dist(&tets[a]).total_cmp(&dist(&tets[b]))).map(|t| t as u32)
}
