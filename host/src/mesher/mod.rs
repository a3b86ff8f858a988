//! Tet meshes of implicit shapes.
//!
//! - [`sdf`]: shapes as signed distance functions (primitives and CSG).
//! - [`quality`]: dihedral angles, inverted tets, volume and conformity of
//!   a mesh.

pub mod quality;
pub mod sdf;
