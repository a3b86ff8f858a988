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

/// The lattice resolution [`mesh_surface`] is used with when none is
/// asked for: the shared models' surfaces (a torus, the bunny, the fandisk
/// with its creases, the joint) come within 0.38 % of their enclosed volume
/// at 40 (0.47 % at 32; docs/BENCHMARKS.md, Surfaces).
pub const DEFAULT_SURFACE_RESOLUTION: u32 = 40;

/// Fills the volume a closed, outward-oriented triangle surface encloses
/// ([`crate::geom::surface::TriSurface::into_closed`]) with tets by isosurface
/// stuffing on a lattice of `resolution` cubes along the surface's longest
/// side. Sharp creases and corners are bevelled at the lattice's scale.
pub fn mesh_surface(surface: &crate::geom::surface::TriSurface, resolution: u32) -> crate::Result<crate::TetMesh> {
    let field = surface_field::SurfaceDistance::new(surface);
    let (lo, hi) = surface.bounding_box();
    let longest = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max);
    if resolution == 0 || !longest.is_finite() || longest <= 0.0 {
        return Err(crate::Error::InvalidInput(format!(
            "cannot mesh a surface of extent {longest} at resolution {resolution}"
        )));
    }
    // Users' parts have faces on round coordinates, which a lattice centred
    // on their box would often meet exactly: off by irrational-looking
    // fractions of a cell, the faces cross lattice edges instead of holding
    // lattice points, and the mesh does not jump with the formats' rounding.
    let params = stuffing::Params {
        shift: [0.190_983, 0.127_322, 0.055_728],
        ..stuffing::Params::new(longest / resolution as f64)
    };
    stuffing::stuff(&field, &params)
}

/// The resolution at which [`mesh_surface`] gives about `tets` tets: the
/// count at a coarse lattice, scaled by the cube root of the ratio (the
/// count grows as the cube of the resolution).
pub fn resolution_for_tets(surface: &crate::geom::surface::TriSurface, tets: usize) -> crate::Result<u32> {
    const PROBE: u32 = 12;
    let probe = mesh_surface(surface, PROBE)?.tets.len().max(1);
    let r = PROBE as f64 * (tets.max(1) as f64 / probe as f64).cbrt();
    Ok(r.round().clamp(1.0, 4096.0) as u32)
}
