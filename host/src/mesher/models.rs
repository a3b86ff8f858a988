//! The built-in models, by name, each inside the unit cube.
//!
//! `resolution` is the number of lattice cells along the longest side of
//! the model's bounding box: sub-cubes per side for `cube`, the stuffing
//! lattice's spacing is `longest side / resolution` for the others. The tet
//! count grows as its cube.
//!
//! | name | shape | default resolution | tets | default sites |
//! |---|---|---|---|---|
//! | `cube` | the unit cube, 6 tets per sub-cube | 16 | 24 576 | 5 000 |
//! | `sphere` | ball of radius 0.5 | 16 | 27 192 | 5 000 |
//! | `torus` | ring of radii 0.35 and 0.15 around z | 16 | 8 664 | 5 000 |
//! | `joint` | a mechanical part: two bosses with through-holes joined by a web | 37 | 30 270 | 35 000 |
//!
//! The joint plays the part of the "Joint" model of the clipped Voronoi
//! paper's Table 1 (31k tets, 35 000 sites), hence its site count; the
//! others take the tool's usual 5 000. Every model is positively oriented
//! and conforming with a closed, manifold boundary; the stuffed ones keep
//! their dihedral angles above 18 degrees at these resolutions.

use super::sdf::Sdf;
use super::stuffing::{self, Params};
use crate::error::{Error, Result};
use crate::TetMesh;
use std::f64::consts::PI;

/// The names of the built-in models.
pub const NAMES: [&str; 4] = ["cube", "sphere", "torus", "joint"];

/// The largest resolution accepted (the cube then has 100 million tets).
pub const MAX_RESOLUTION: u32 = 256;

/// A built-in model's fixed data.
struct Model {
    name: &'static str,
    resolution: u32,
    sites: usize,
}

const MODELS: [Model; 4] = [
    Model { name: "cube", resolution: 16, sites: 5000 },
    Model { name: "sphere", resolution: 16, sites: 5000 },
    Model { name: "torus", resolution: 16, sites: 5000 },
    Model { name: "joint", resolution: 37, sites: 35_000 },
];

fn model(name: &str) -> Result<&'static Model> {
    MODELS
        .iter()
        .find(|m| m.name == name)
        .ok_or_else(|| Error::InvalidInput(format!("unknown model '{name}': built-in models are {}", NAMES.join(", "))))
}

/// The mesh of the model `name` at `resolution` (cells along its longest
/// side; `None`: the model's default): `TetMesh::cube` for `cube` (its
/// tets turned positive), isosurface stuffing of [`shape`] for the others.
///
/// Errors: an unknown name, a resolution of 0 or above [`MAX_RESOLUTION`],
/// one too coarse to leave any tet, or one whose lattice would exceed
/// [`stuffing::MAX_LATTICE_VERTICES`] (the sphere stops near 200).
pub fn builtin(name: &str, resolution: Option<u32>) -> Result<TetMesh> {
    let model = model(name)?;
    let resolution = resolution.unwrap_or(model.resolution);
    if resolution == 0 || resolution > MAX_RESOLUTION {
        return Err(Error::InvalidInput(format!(
            "resolution of model '{name}' must be in 1..={MAX_RESOLUTION}, got {resolution}"
        )));
    }
    if name == "cube" {
        // Like every built-in model, positively oriented.
        let mut mesh = TetMesh::cube(resolution as usize);
        for t in 0..mesh.tets.len() {
            if mesh.tet_volume(t) < 0.0 {
                mesh.tets[t].swap(2, 3);
            }
        }
        return Ok(mesh);
    }
    let shape = shape(name)?;
    let (lo, hi) = shape.bounds();
    let longest = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max);
    stuffing::stuff(&shape, &Params::new(longest / resolution as f64)).map_err(|e| match e {
        Error::InvalidInput(why) => Error::InvalidInput(format!("model '{name}' at resolution {resolution}: {why}")),
        other => other,
    })
}

/// The model's default resolution.
pub fn default_resolution(name: &str) -> Result<u32> {
    Ok(model(name)?.resolution)
}

/// The model's default number of sites.
pub fn default_sites(name: &str) -> Result<usize> {
    Ok(model(name)?.sites)
}

/// The model as a signed distance function (the unit cube for `cube`).
pub fn shape(name: &str) -> Result<Sdf> {
    model(name)?;
    let c = [0.5; 3];
    Ok(match name {
        "cube" => Sdf::cuboid(c, [0.5; 3]),
        "sphere" => Sdf::sphere(c, 0.5),
        "torus" => Sdf::torus(c, [0.0, 0.0, 1.0], TORUS_MAJOR, TORUS_MINOR),
        _ => joint(),
    })
}

/// The exact volume of the model's shape, where one is known: the cube,
/// the sphere and the torus. The meshes of the curved ones are a little
/// smaller (their boundary is made of chords of the surface).
pub fn analytic_volume(name: &str) -> Result<Option<f64>> {
    model(name)?;
    Ok(match name {
        "cube" => Some(1.0),
        "sphere" => Some(4.0 / 3.0 * PI * 0.125),
        "torus" => Some(2.0 * PI * PI * TORUS_MAJOR * TORUS_MINOR * TORUS_MINOR),
        _ => None,
    })
}

const TORUS_MAJOR: f64 = 0.35;
const TORUS_MINOR: f64 = 0.15;

/// A mechanical part spanning the unit cube along x: a large boss and a
/// small one (cylinders along z), each with a through-hole, joined by a
/// web (a rounded box) that carries a cross boss (a cylinder along y).
fn joint() -> Sdf {
    let z = [0.0, 0.0, 1.0];
    let (big, small) = ([0.17, 0.5, 0.5], [0.87, 0.5, 0.5]);
    let body = Sdf::cylinder(big, z, 0.17, 0.3)
        .union(Sdf::cylinder(small, z, 0.13, 0.24))
        .union(Sdf::rounded_cuboid([0.52, 0.5, 0.5], [0.34, 0.09, 0.07], 0.02))
        .union(Sdf::cylinder([0.52, 0.5, 0.5], [0.0, 1.0, 0.0], 0.08, 0.3));
    body.difference(Sdf::cylinder(big, z, 0.085, 1.0)).difference(Sdf::cylinder(small, z, 0.06, 1.0))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesher::quality::{Conformity, Quality};

    /// Checks what every stuffed model promises; returns its quality.
    fn check(name: &str, resolution: u32) -> Quality {
        let mesh = builtin(name, Some(resolution)).unwrap();
        let q = Quality::of(&mesh);
        assert!(q.inverted == 0 && q.min_dihedral >= 9.0 && q.max_dihedral <= 165.0, "{name} {resolution}: {q}");
        let c = Conformity::of(&mesh);
        assert!(c.is_manifold(), "{name} {resolution}: {c:?}");
        assert_eq!(c.interior_faces * 2 + c.boundary_faces, 4 * q.tets);
        assert_eq!(q.vertices, mesh.vertices.len(), "no unused vertex");
        // The boundary vertices lie on the surface (cut points and warped
        // vertices), to f32 precision.
        let shape = shape(name).unwrap();
        let mut on_boundary = vec![false; mesh.vertices.len()];
        let mut faces = std::collections::HashMap::new();
        for tet in &mesh.tets {
            for f in [[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]] {
                let mut key = f.map(|i| tet[i]);
                key.sort();
                *faces.entry(key).or_insert(0) += 1;
            }
        }
        for (face, count) in faces {
            if count == 1 {
                face.iter().for_each(|&v| on_boundary[v as usize] = true);
            }
        }
        for (v, p) in mesh.vertices.iter().enumerate().filter(|&(v, _)| on_boundary[v]) {
            let d = shape.eval(p.map(f64::from));
            assert!(d.abs() < 1e-6, "{name} {resolution}: boundary vertex {v} at distance {d}");
        }
        q
    }

    #[test]
    fn stuffed_models_at_small_and_default_resolutions() {
        for (name, small) in [("sphere", 8), ("torus", 8), ("joint", 16)] {
            check(name, small);
            let tets = check(name, default_resolution(name).unwrap()).tets as f64;
            let target = match name {
                "torus" => 8000.0,
                "joint" => 31_000.0,
                _ => tets,
            };
            assert!((tets / target - 1.0).abs() < 0.1, "{name}: {tets} tets, target {target}");
        }
    }

    /// Every boundary vertex lies on the surface, so the error is that of
    /// the chords: a boundary edge of length `l` strays at most `l² / 8ρ`
    /// from a surface whose smallest radius of curvature is `ρ` (the sphere's
    /// radius, the torus' tube radius), and the relative volume error is
    /// about 2 to 3 times that over `ρ`. With boundary edges up to about the
    /// lattice spacing `h`, the bound `0.5 (h / ρ)²` holds with room to
    /// spare; measured: about 0.26 (h / ρ)² for the sphere, 0.08 (h / ρ)²
    /// for the torus. It falls fourfold when the resolution doubles.
    #[test]
    fn curved_volumes_converge_to_the_exact_ones() {
        for (name, rho) in [("sphere", 0.5), ("torus", TORUS_MINOR)] {
            let exact = analytic_volume(name).unwrap().unwrap();
            for resolution in [8, 16, 32] {
                let mesh = builtin(name, Some(resolution)).unwrap();
                let (lo, hi) = shape(name).unwrap().bounds();
                let h = (hi[0] - lo[0]) / resolution as f64;
                let error = (mesh.volume() - exact) / exact;
                assert!(error.abs() < 0.5 * (h / rho).powi(2), "{name} {resolution}: relative volume error {error:e}");
                // Chords of a convex surface lie inside it.
                if name == "sphere" {
                    assert!(error < 0.0);
                }
            }
        }
    }

    #[test]
    fn cube_is_the_unit_cube_positively_oriented() {
        let mesh = builtin("cube", None).unwrap();
        let q = Quality::of(&mesh);
        assert_eq!((q.tets, q.inverted), (6 * 16 * 16 * 16, 0));
        assert!((q.volume - 1.0).abs() < 1e-9);
        assert_eq!(analytic_volume("cube").unwrap(), Some(1.0));
        assert!(Conformity::of(&mesh).is_manifold());
    }

    #[test]
    fn names_defaults_and_errors() {
        for name in NAMES {
            assert!(default_sites(name).unwrap() > 0);
            assert!(builtin(name, Some(4)).is_ok(), "{name}");
        }
        assert_eq!(default_sites("joint").unwrap(), 35_000);
        assert!(analytic_volume("joint").unwrap().is_none());
        for bad in ["", "Cube", "teapot"] {
            let err = builtin(bad, None).unwrap_err().to_string();
            assert!(err.contains("cube, sphere, torus, joint"), "{err}");
            assert!(default_sites(bad).is_err() && shape(bad).is_err() && analytic_volume(bad).is_err());
        }
        for bad in [0, MAX_RESOLUTION + 1] {
            assert!(builtin("torus", Some(bad)).is_err());
            assert!(builtin("cube", Some(bad)).is_err());
        }
        let err = builtin("sphere", Some(MAX_RESOLUTION)).unwrap_err().to_string();
        assert!(err.contains("model 'sphere' at resolution 256") && err.contains("lattice vertices"), "{err}");
    }
}
