//! Tet meshes of implicit shapes, and the built-in models.
//!
//! - [`sdf`]: shapes as signed distance functions (primitives and CSG).
//! - [`stuffing`]: isosurface stuffing on a BCC lattice, which fills a
//!   shape with tets whose dihedral angles are bounded whatever the shape.
//! - [`quality`]: dihedral angles, inverted tets, volume and conformity of
//!   a mesh.
//! - [`models`]: the built-in models by name (`cube`, `sphere`, `torus`,
//!   `joint`), so the tool needs no data files.
//!
//! ```
//! use cvd::mesher::{models, quality::Quality};
//! let mesh = models::builtin("torus", Some(12))?;
//! let q = Quality::of(&mesh);
//! assert!(q.inverted == 0 && q.min_dihedral > 9.0);
//! # Ok::<(), cvd::Error>(())
//! ```

pub mod models;
pub mod quality;
pub mod sdf;
pub mod stuffing;
