//! The domain as the whole-cell strategy searches it
//! (`cvd_kernels::whole`): a voxel grid listing the tets whose bounding box
//! meets each voxel, and a hierarchy over the boundary's triangles.
//!
//! The voxels' side is about a mean tet's edge (twice the cube root of the
//! mean tet's volume): each tet is listed in a few voxels, and a voxel
//! lists a few dozen tets. A tet's box is padded before it is listed, so
//! that a point or box the kernels compute in f32 (within rounding of where
//! it belongs) finds every tet it may meet.

use crate::geom::mesh::TetMesh;
use crate::geom::surface::bvh::TriangleTree;
use crate::geom::surface::TriSurface;
use cvd_kernels::abi::{domain_whole, DomainParams, SplitPoint};
use cvd_kernels::whole::{voxel_of, Domain};
use rayon::prelude::*;

/// The voxel grid over the tets and the boundary's hierarchy, as the
/// kernels read them ([`Self::view`]).
#[derive(Clone, Debug, Default)]
pub struct DomainIndex {
    /// The grid, the hierarchy's size, and whether cells may be whole.
    pub params: DomainParams,
    /// Where each voxel's tets start in `voxel_tets` (one entry more than
    /// voxels).
    pub voxel_start: Vec<u32>,
    /// The tets listed by each voxel.
    pub voxel_tets: Vec<u32>,
    /// Each tet's first voxel, as a linear index.
    pub tet_voxel: Vec<u32>,
    /// The boundary's hierarchy, two records per node.
    pub nodes: Vec<[f32; 4]>,
    /// The boundary's triangles in the hierarchy's order.
    pub tris: Vec<[u32; 4]>,
}

/// Most voxels per tet the grid may have.
const VOXELS_PER_TET: f64 = 2.0;

impl DomainIndex {
    /// The index of `mesh` (in the clipping frame; its vertices as the
    /// kernels read them, `verts`). `whole`: which cells may be
    /// integrated whole ([`domain_whole`]: none under a density varying
    /// inside the tets; those inside the domain; all, in a periodic box,
    /// where the boundary's hierarchy is not built). `boundary`: the
    /// mesh's boundary when the caller has it ([`TetMesh::boundary`]),
    /// else found here when needed.
    pub fn new(mesh: &TetMesh, verts: &[SplitPoint], whole: u32, boundary: Option<&TriSurface>) -> Self {
        Self::over(mesh, verts, Self::grid_of(mesh, whole), boundary)
    }

    /// The voxel grid of `mesh`'s index ([`Self::new`]), with no hierarchy.
    pub fn grid_of(mesh: &TetMesh, whole: u32) -> DomainParams {
        let n_tets = mesh.tets.len().max(1);
        let (lo, hi) = mesh.bounding_box();
        let extent = [0, 1, 2].map(|a| (hi[a] - lo[a]).max(0.0));
        let longest = extent.iter().fold(0.0f64, |a, &b| a.max(b)).max(1e-30);
        let mean_edge = 2.0 * (mesh.volume() / n_tets as f64).cbrt();
        let box_volume: f64 = extent.iter().map(|&e| e.max(longest * 1e-6)).product();
        let mut side = mean_edge.max((box_volume / (VOXELS_PER_TET * n_tets as f64)).cbrt());
        if !(side.is_finite() && side > 0.0) {
            side = longest;
        }
        let dims = extent.map(|e| ((e / side).ceil() as u32).clamp(1, 1 << 10));
        // The rounding of coordinates of order 1 in f32, many times over.
        let pad = 1e-6 * (1.0 + longest) as f32;
        DomainParams {
            lo_x: lo[0] as f32,
            lo_y: lo[1] as f32,
            lo_z: lo[2] as f32,
            voxel_len: side as f32,
            dim_x: dims[0],
            dim_y: dims[1],
            dim_z: dims[2],
            n_nodes: 0,
            margin: pad,
            whole,
            _pad: [0; 2],
        }
    }

    /// The index of `mesh`'s tets on the voxel grid `params`, which may be
    /// another mesh's ([`Self::grid_of`]: a part of a mesh listed on the
    /// whole mesh's grid, each voxel listing its tets in the same order).
    /// `boundary`: as for [`Self::new`] (a part's: the whole mesh's
    /// boundary, or the triangles of it the part's cells may reach).
    pub fn over(mesh: &TetMesh, verts: &[SplitPoint], mut params: DomainParams, boundary: Option<&TriSurface>) -> Self {
        let (whole, pad) = (params.whole, params.margin);
        let dims = [params.dim_x, params.dim_y, params.dim_z];
        // Each tet's voxel range, from its padded f32 box (computed again
        // in each pass rather than held: 24 bytes a tet).
        let range_of = |t: usize| {
            let p = mesh.tets[t].map(|v| verts[v as usize].hi);
            let range = |a: usize| {
                let lo = p.iter().map(|q| q[a]).fold(f32::INFINITY, f32::min) - pad;
                let hi = p.iter().map(|q| q[a]).fold(f32::NEG_INFINITY, f32::max) + pad;
                (voxel_of(&params, lo, a), voxel_of(&params, hi, a))
            };
            let (x, y, z) = (range(0), range(1), range(2));
            ([x.0, y.0, z.0], [x.1, y.1, z.1])
        };
        let n_voxels = dims.iter().map(|&d| d as usize).product::<usize>();
        let index = |v: [u32; 3]| (v[2] as usize * dims[1] as usize + v[1] as usize) * dims[0] as usize + v[0] as usize;
        let mut count = vec![0u32; n_voxels + 1];
        let each = |(lo, hi): ([u32; 3], [u32; 3]), f: &mut dyn FnMut(usize)| {
            for z in lo[2]..=hi[2] {
                for y in lo[1]..=hi[1] {
                    for x in lo[0]..=hi[0] {
                        f(index([x, y, z]));
                    }
                }
            }
        };
        let tet_voxel: Vec<u32> = (0..mesh.tets.len()).into_par_iter().map(|t| index(range_of(t).0) as u32).collect();
        for t in 0..mesh.tets.len() {
            each(range_of(t), &mut |v| count[v + 1] += 1);
        }
        for v in 0..n_voxels {
            count[v + 1] += count[v];
        }
        let voxel_start = count.clone();
        let mut voxel_tets = vec![0u32; count[n_voxels] as usize];
        for t in 0..mesh.tets.len() {
            each(range_of(t), &mut |v| {
                voxel_tets[count[v] as usize] = t as u32;
                count[v] += 1;
            });
        }
        drop(count);
        let found;
        let boundary = match boundary {
            _ if whole != domain_whole::INSIDE => None,
            Some(b) => Some(b),
            None => {
                found = mesh.boundary();
                Some(&found)
            }
        };
        let (nodes, tris) = match boundary {
            Some(b) if !b.triangles.is_empty() => TriangleTree::new(b).kernel_records(b, pad as f64),
            _ => (Vec::new(), Vec::new()),
        };
        params.n_nodes = (nodes.len() / 2) as u32;
        Self { params, voxel_start, voxel_tets, tet_voxel, nodes, tris }
    }

    /// The index as the kernels read it.
    pub fn view(&self) -> Domain<'_> {
        Domain {
            params: self.params,
            voxel_start: &self.voxel_start,
            voxel_tets: &self.voxel_tets,
            tet_voxel: &self.tet_voxel,
            nodes: &self.nodes,
            tris: &self.tris,
        }
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        4 * (self.voxel_start.len() + self.voxel_tets.len() + self.tet_voxel.len())
            + 16 * (self.nodes.len() + self.tris.len())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use cvd_kernels::polyhedron::{Cell, Point as Vec3};
    use cvd_kernels::whole::{boundary_near, site_in_mesh, triangle_distance2};

    fn split(mesh: &TetMesh) -> Vec<SplitPoint> {
        mesh.vertices.iter().map(|&p| SplitPoint::new(p, 1.0)).collect()
    }

    #[test]
    fn every_tet_is_listed_in_every_voxel_its_box_meets_and_first_in_its_lowest() {
        let mesh = TetMesh::cube(6);
        let verts = split(&mesh);
        let d = DomainIndex::new(&mesh, &verts, domain_whole::INSIDE, None);
        let p = d.params;
        assert_eq!(d.voxel_start.len() as u32, p.dim_x * p.dim_y * p.dim_z + 1);
        let dims = [p.dim_x, p.dim_y, p.dim_z];
        for (t, tet) in mesh.tets.iter().enumerate() {
            let lo = [0, 1, 2].map(|a| tet.iter().map(|&v| mesh.vertices[v as usize][a]).fold(f64::MAX, f64::min));
            let hi = [0, 1, 2].map(|a| tet.iter().map(|&v| mesh.vertices[v as usize][a]).fold(f64::MIN, f64::max));
            let vlo = [0, 1, 2].map(|a| voxel_of(&p, lo[a] as f32, a));
            let vhi = [0, 1, 2].map(|a| voxel_of(&p, hi[a] as f32, a));
            let first = d.tet_voxel[t];
            let f = [first % dims[0], (first / dims[0]) % dims[1], first / (dims[0] * dims[1])];
            assert!((0..3).all(|a| f[a] <= vlo[a]), "tet {t}: first voxel {f:?} above its box's {vlo:?}");
            for z in vlo[2]..=vhi[2] {
                for y in vlo[1]..=vhi[1] {
                    for x in vlo[0]..=vhi[0] {
                        let v = ((z * dims[1] + y) * dims[0] + x) as usize;
                        let list = &d.voxel_tets[d.voxel_start[v] as usize..d.voxel_start[v + 1] as usize];
                        assert!(list.contains(&(t as u32)), "tet {t} not in voxel {:?}", [x, y, z]);
                    }
                }
            }
        }
        let per_tet = d.voxel_tets.len() as f64 / mesh.tets.len() as f64;
        assert!(per_tet < 12.0, "{per_tet} voxels per tet");
    }

    #[test]
    fn the_boundary_is_near_exactly_where_a_triangle_is() {
        // The unit cube: the boundary's distance from a point inside is
        // its distance to the nearest side.
        let mesh = TetMesh::cube(3);
        let verts = split(&mesh);
        let d = DomainIndex::new(&mesh, &verts, domain_whole::INSIDE, None);
        assert_eq!(d.tris.len(), 6 * 2 * 9);
        let view = d.view();
        for (x, nearest) in [([0.5, 0.5, 0.5], 0.5), ([0.1, 0.5, 0.6], 0.1), ([0.3, 0.95, 0.2], 0.05)] {
            let site = SplitPoint::site(x, 0.0);
            let r = nearest as f32;
            let big = Cell::cuboid(Vec3::splat(-10.0).into(), Vec3::splat(10.0).into());
            assert!(boundary_near(&site, (r * 1.001).powi(2), &big, 0.0, &verts, &view), "{x:?} within {r}");
            assert!(!boundary_near(&site, (r * 0.999).powi(2), &big, 0.0, &verts, &view), "{x:?} not within {r}");
            // A cell of half-side r/2 around the site: the nearest side is
            // within its ball (r/2 √3) but beyond its face.
            let small = Cell::cuboid(Vec3::splat(-r / 2.0).into(), Vec3::splat(r / 2.0).into());
            assert!(!boundary_near(&site, (r * 0.9).powi(2), &small, 1e-6, &verts, &view), "{x:?}: beyond a face");
            // Grown past the side, the face no longer separates it.
            let grown = Cell::cuboid(Vec3::splat(-1.2 * r).into(), Vec3::splat(1.2 * r).into());
            assert!(boundary_near(&site, (r * 2.1).powi(2), &grown, 1e-6, &verts, &view), "{x:?}: cut");
            assert!(site_in_mesh(&site, &verts, &mesh.tets, &view));
        }
        for x in [[1.2, 0.5, 0.5], [-0.01, 0.2, 0.2], [0.5, 0.5, 1.5]] {
            assert!(!site_in_mesh(&SplitPoint::site(x, 0.0), &verts, &mesh.tets, &view), "{x:?} outside");
        }
    }

    #[test]
    fn a_triangles_distance_from_each_region() {
        let (a, b, c) = (Vec3::new(0.0, 0.0, 1.0), Vec3::new(2.0, 0.0, 1.0), Vec3::new(0.0, 2.0, 1.0));
        let at = |o: Vec3| triangle_distance2(a - o, b - o, c - o);
        let close = |x: f32, y: f32| (x - y).abs() <= 1e-5 * (1.0 + y);
        assert!(close(at(Vec3::new(0.5, 0.5, 0.0)), 1.0), "over the face");
        assert!(close(at(Vec3::new(-1.0, -1.0, 1.0)), 2.0), "by vertex a");
        assert!(close(at(Vec3::new(3.0, 0.0, 1.0)), 1.0), "by vertex b");
        assert!(close(at(Vec3::new(1.0, -1.0, 1.0)), 1.0), "by edge ab");
        assert!(close(at(Vec3::new(-1.0, 1.0, 1.0)), 1.0), "by edge ca");
        assert!(close(at(Vec3::new(2.0, 2.0, 1.0)), 2.0), "by edge bc");
        assert!(close(at(Vec3::new(0.0, 3.0, 2.0)), 2.0), "by vertex c, above");
    }
}
