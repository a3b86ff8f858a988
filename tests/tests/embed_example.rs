//! The standalone example (`examples/standalone`: ash, the exported
//! modules and their manifest, nothing of the library) against the
//! library, on the same input: every cell's volume within 1e-6.

use cvd::exec::CpuBackend;
use cvd::{Backend, ClippedVoronoi, TetMesh};

fn check(dir: &std::path::Path, cubes: u32, n_sites: usize, seed: u64, vulkan: &dyn Backend) {
    let (verts, tets) = cvd_embed_example::cube_mesh(cubes);
    let sites = cvd_embed_example::sites(n_sites, seed);
    let out = cvd_embed_example::run(dir, &verts, &tets, &sites).expect("the example runs");
    eprintln!(
        "example on {}: {} tets, {} sites, unfinished {} -> {}",
        out.device,
        tets.len(),
        sites.len(),
        out.unfinished_first,
        out.unfinished_after
    );
    assert_eq!(out.unfinished_after, 0, "the second pass finished everything");
    let total: f64 = out.volumes.iter().sum();
    assert!((total - 1.0).abs() < 1e-6, "the cells tile the unit cube: {total}");
    let mesh = TetMesh::new(verts, tets).expect("a valid mesh");
    let cpu = CpuBackend::new(None).expect("CPU backend");
    for backend in [&cpu as &dyn Backend, vulkan] {
        let cells = ClippedVoronoi::new(&mesh, &sites).backend(backend).compute().expect("the library computes");
        for (i, (a, b)) in out.volumes.iter().zip(&cells.volume).enumerate() {
            assert!((a - b).abs() <= 1e-6, "site {i}: example {a}, library ({}) {b}", backend.kind());
        }
    }
}

#[test]
fn standalone_example_agrees_with_the_library() {
    let Some(vulkan) = cvd_tests::vulkan() else { return };
    let dir = std::env::temp_dir().join(format!("cvd-embed-example-{}", std::process::id()));
    cvd::spirv::export(&dir).expect("export the modules");
    // The example's own input, then a denser one.
    check(&dir, 2, 40, 7, vulkan);
    check(&dir, 3, 400, 11, vulkan);
    cvd_tests::assert_no_validation_errors();
    let _ = std::fs::remove_dir_all(&dir);
}
