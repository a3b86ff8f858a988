//! Tet meshes of implicit shapes.
//!
//! - [`sdf`]: shapes as signed distance functions (primitives and CSG).
//! - [`stuffing`]: isosurface stuffing on a BCC lattice, which fills a
//!   shape with tets whose dihedral angles are bounded whatever the shape.
//! - [`quality`]: dihedral angles, inverted tets, volume and conformity of
//!   a mesh.

pub mod quality;
pub mod sdf;
pub mod stuffing;
