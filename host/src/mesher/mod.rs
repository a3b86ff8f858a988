//! Tet meshes of implicit shapes, and the built-in models.
//!
//! - [`sdf`]: shapes as signed distance functions (primitives and CSG).
//! - [`stuffing`]: isosurface stuffing on a BCC lattice, which fills a
//!   shape with tets whose dihedral angles are bounded whatever the shape.
//! - [`surface_field`]: the signed distance to a closed triangle surface,
//!   so that a user's surface is filled the same way ([`mesh_surface`]).
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
pub mod surface_field;

/// Fills the volume a closed, outward-oriented triangle surface encloses
/// ([`crate::surface::TriSurface::into_closed`]) with tets by isosurface
/// stuffing on a lattice of `resolution` cubes along the surface's longest
/// side. Sharp creases and corners are bevelled at the lattice's scale.
pub fn mesh_surface(surface: &crate::surface::TriSurface, resolution: u32) -> crate::Result<crate::TetMesh> {
    let field = surface_field::SurfaceDistance::new(surface);
    let (lo, hi) = surface.bounding_box();
    let longest = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max);
    if resolution == 0 || !longest.is_finite() || longest <= 0.0 {
        return Err(crate::Error::InvalidInput(format!(
            "cannot mesh a surface of extent {longest} at resolution {resolution}"
        )));
    }
    stuffing::stuff(&field, &stuffing::Params::new(longest / resolution as f64))
}
