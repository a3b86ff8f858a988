//! Tet meshes written by a real tool (meshio, installed from PyPI, apart
//! from the library): legacy VTK 4.2 and 5.1, ASCII and binary, VTK XML
//! (ASCII, raw binary, zlib), Medit binary `.meshb`, Gmsh `.msh` 2.2
//! binary and 4.1 binary and ASCII; and by VTK itself (the `vtk` package,
//! ParaView's writer): `.vtu` with appended raw or base64 data, with and
//! without zlib, 32- and 64-bit headers. Each reads back equal to the mesh
//! it was made from; a volume cell other than a tet is a named error.

use cvd::TetMesh;
use std::path::{Path, PathBuf};

/// Runs `tests/scripts/SCRIPT SOURCE DIR` and returns the JSON listing it
/// prints, or `None` where python3 with `tool` is missing (see
/// [`cvd_tests::python`]).
fn written_by(script: &str, tool: &str, source: &Path, dir: &Path) -> Option<serde_json::Value> {
    let out = cvd_tests::python(&[cvd_tests::script(script).as_os_str(), source.as_os_str(), dir.as_os_str()], tool)?;
    Some(serde_json::from_slice(&out).expect("the script's JSON"))
}

/// A torus mesh with coordinates no format rounds the same way by chance,
/// written as `.mesh` into a fresh folder.
fn source(tag: &str) -> (TetMesh, PathBuf, PathBuf) {
    let dir = std::env::temp_dir().join(format!("cvd-mesh-formats-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut mesh = cvd::mesher::models::builtin("torus", Some(8)).unwrap();
    for v in &mut mesh.vertices {
        *v = v.map(|c| c * 1.000_000_1 + 1e6);
    }
    let source = dir.join("source.mesh");
    cvd_io::write_medit(&source, &mesh).unwrap();
    let expected = cvd_io::read_mesh(&source).unwrap();
    (expected, source, dir)
}

#[test]
fn vtu_files_written_by_vtk_read_back_exactly() {
    let (expected, source, dir) = source("vtk");
    let Some(listing) = written_by("write_vtk_xml.py", "vtk", &source, &dir) else { return };
    for (name, path) in listing.as_object().unwrap() {
        let read = cvd_io::read_mesh(Path::new(path.as_str().unwrap())).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(read, expected, "{name}");
    }
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn vtk_files_written_by_meshio_read_back() {
    let (expected, source, dir) = source("meshio");
    let Some(listing) = written_by("write_tet_formats.py", "meshio", &source, &dir) else { return };
    for name in [
        "v42_ascii.vtk",
        "v42_binary.vtk",
        "v51_ascii.vtk",
        "v51_binary.vtk",
        "medit.meshb",
        "v22_binary.msh",
        "v41_binary.msh",
        "v41_ascii.msh",
        "ascii.vtu",
        "raw.vtu",
        "zlib.vtu",
    ] {
        let path = PathBuf::from(listing[name].as_str().unwrap());
        let read = cvd_io::read_mesh(&path).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(read.tets, expected.tets, "{name}");
        assert_eq!(read.vertices.len(), expected.vertices.len(), "{name}");
        for (a, b) in read.vertices.iter().zip(&expected.vertices) {
            // ASCII holds as many digits as meshio prints; binary is exact.
            let tol = if name.contains("ascii") { 1e-9 } else { 0.0 };
            assert!((0..3).all(|k| (a[k] - b[k]).abs() <= tol * b[k].abs()), "{name}: {a:?} vs {b:?}");
        }
    }
    let hexa = listing["hexahedron"].as_str().unwrap();
    let e = cvd_io::read_mesh(&PathBuf::from(hexa)).unwrap_err().to_string();
    assert!(e.contains(hexa) && e.contains("1 of VTK cell type 12"), "{e}");
    std::fs::remove_dir_all(&dir).ok();
}
