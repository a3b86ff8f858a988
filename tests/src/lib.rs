//! Shared helpers of the cross-crate tests: the Vulkan device every test of a
//! binary shares, and references written apart from the kernels.

pub mod reference;
pub mod voro;

use cvd::backends::vulkan::{validation_errors, VulkanBackend, VulkanOptions};
use cvd::exec::CpuBackend;
use cvd::{Backend, KnnJob};
use std::sync::OnceLock;

/// The Vulkan backend shared by all tests of one test binary (pipelines are
/// compiled once), with the Khronos validation layer on. `None` when no
/// device exists, which is a failure under `CI=true`.
pub fn vulkan() -> Option<&'static VulkanBackend> {
    static BACKEND: OnceLock<Result<VulkanBackend, String>> = OnceLock::new();
    let backend = BACKEND.get_or_init(|| {
        let options =
            VulkanOptions { device: std::env::var("CVD_TEST_DEVICE").ok(), validation: true, ..Default::default() };
        VulkanBackend::new(&options).map_err(|e| e.to_string())
    });
    match backend {
        Ok(b) => Some(b),
        Err(e) if std::env::var("CI").is_ok_and(|v| v == "true") => {
            panic!("CI=true but no Vulkan device: {e}")
        }
        Err(e) => {
            eprintln!("SKIPPED (no Vulkan device: {e})");
            None
        }
    }
}

/// Runs `python3 args...` and returns what it printed, or `None` — a skip,
/// saying why (the last line of its error: the module `tool` names is
/// missing) — except under `CI=true`, where it fails. Tests whose inputs
/// are written by other tools (meshio, trimesh, VTK) run them this way.
pub fn python<S: AsRef<std::ffi::OsStr>>(args: &[S], tool: &str) -> Option<Vec<u8>> {
    let why = match std::process::Command::new("python3").args(args).output() {
        Ok(o) if o.status.success() => return Some(o.stdout),
        Ok(o) => String::from_utf8_lossy(&o.stderr).trim().lines().last().unwrap_or("").to_string(),
        Err(e) => format!("python3: {e}"),
    };
    if std::env::var("CI").is_ok_and(|v| v == "true") {
        panic!("CI=true but python3 with {tool} cannot run: {why}");
    }
    eprintln!("SKIPPED (python3 with {tool} is missing: {why})");
    None
}

/// The tests' folder, found from where cargo runs the tests (the
/// compile-time path may be another clone's when clones share a target
/// directory).
fn tests_dir() -> std::path::PathBuf {
    std::env::var_os("CARGO_MANIFEST_DIR")
        .map_or_else(|| std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")), std::path::PathBuf::from)
}

/// `tests/scripts/NAME`: the scripts that write and read other tools'
/// files.
pub fn script(name: &str) -> std::path::PathBuf {
    tests_dir().join("scripts").join(name)
}

/// An L of three unit cubes (a non-convex domain), `n` tets per cube side.
pub fn l_mesh(n: usize) -> cvd::TetMesh {
    let mut mesh = cvd::TetMesh::cube(n);
    for shift in [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]] {
        let base = mesh.vertices.len() as u32;
        let cube = cvd::TetMesh::cube(n);
        mesh.vertices.extend(cube.vertices.iter().map(|v| [v[0] + shift[0], v[1] + shift[1], v[2]]));
        mesh.tets.extend(cube.tets.iter().map(|t| t.map(|k| k + base)));
    }
    mesh
}

/// `n³` sites at the centres of the unit cube's `n³` sub-cubes: cubic
/// cells, every Voronoi vertex degenerate; with `TetMesh::cube(n)` every
/// bisector lies on faces of the mesh's tets.
pub fn cube_lattice(n: usize) -> Vec<[f64; 3]> {
    let h = 1.0 / n as f64;
    let mut out = Vec::with_capacity(n * n * n);
    for i in 0..n {
        for j in 0..n {
            for k in 0..n {
                out.push([i, j, k].map(|c| (c as f64 + 0.5) * h));
            }
        }
    }
    out
}

/// The shared models present in `../shared/models` (torus_8k, bunny_10k,
/// fandisk_26k, joint_31k), by name; an absent one is named and skipped.
/// For the measurements run by hand on them.
pub fn shared_models() -> Vec<(&'static str, cvd::TetMesh)> {
    let dir = tests_dir().join("../../shared/models");
    let mut models = Vec::new();
    for name in ["torus_8k", "bunny_10k", "fandisk_26k", "joint_31k"] {
        let path = dir.join(format!("{name}.mesh"));
        if path.is_file() {
            models.push((name, cvd_io::read_mesh(&path).expect("a shared model")));
        } else {
            println!("{name}: not present, skipped");
        }
    }
    models
}

/// The CPU backend (all cores) and, when a device exists, the shared
/// Vulkan backend.
pub fn backends() -> Vec<&'static dyn Backend> {
    static CPU: OnceLock<CpuBackend> = OnceLock::new();
    let mut b: Vec<&'static dyn Backend> = vec![CPU.get_or_init(|| CpuBackend::new(None).expect("CPU backend"))];
    if let Some(v) = vulkan() {
        b.push(v);
    }
    b
}

/// Fails the test if the validation layer has reported any error so far.
pub fn assert_no_validation_errors() {
    assert_eq!(validation_errors(), 0, "the Vulkan validation layer reported errors (see stderr)");
}

/// The k nearest sites of every query by sorting all distances: squared
/// distances from the job's quantized coordinates (in i128, apart from the
/// kernels' arithmetic), ordered by (distance, index).
pub fn reference_knn(job: &KnnJob) -> (Vec<u32>, Vec<u64>) {
    let k = job.params.k as usize;
    let mut indices = Vec::with_capacity(job.queries.len() * k);
    let mut dist2 = Vec::with_capacity(job.queries.len() * k);
    let mut all = Vec::with_capacity(job.sites.len());
    for q in job.queries.iter() {
        all.clear();
        for s in job.sites.iter() {
            if job.params.exclude_self != 0 && s[3] == q[3] {
                continue;
            }
            let d: i128 = (0..3).map(|a| (q[a] as i128 - s[a] as i128).pow(2)).sum();
            all.push((d as u64, s[3]));
        }
        if all.len() > k {
            all.select_nth_unstable(k);
            all.truncate(k);
        }
        all.sort_unstable();
        indices.extend(all.iter().map(|&(_, i)| i));
        dist2.extend(all.iter().map(|&(d, _)| d));
    }
    (indices, dist2)
}

/// Small test domains: convex, non-convex, and with a hole through it.
#[derive(Clone, Copy, Debug)]
pub enum Shape {
    /// The unit cube in `n`³ sub-cubes.
    Cube(usize),
    /// The letter L: the cube without one quarter column (non-convex).
    Ell,
    /// A cube with a square hole through it.
    Holed,
}

impl Shape {
    /// The shape's tet mesh.
    pub fn mesh(self) -> cvd::TetMesh {
        match self {
            Shape::Cube(n) => cvd::TetMesh::cube(n),
            Shape::Ell => cvd::TetMesh::voxels(4, |i, j, _| i < 2 || j < 2),
            Shape::Holed => cvd::TetMesh::voxels(5, |i, j, _| !(i == 2 && j == 2)),
        }
    }
}

/// An input moved where f32 coordinates would fail: `x -> x * scale +
/// offset`. Results computed on a placed input, mapped back with
/// [`Placement::unplace`], must match the unplaced input's reference.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Placement {
    /// Uniform scale.
    pub scale: f64,
    /// Then added to every coordinate.
    pub offset: f64,
}

impl Placement {
    /// As given.
    pub const NONE: Placement = Placement { scale: 1.0, offset: 0.0 };
    /// Translated by 1e6, scaled by 1e-6 and by 1e6.
    pub const MOVED: [Placement; 3] = [
        Placement { scale: 1.0, offset: 1e6 },
        Placement { scale: 1e-6, offset: 0.0 },
        Placement { scale: 1e6, offset: 0.0 },
    ];

    /// A point placed.
    pub fn point(&self, p: &[f64; 3]) -> [f64; 3] {
        p.map(|c| c * self.scale + self.offset)
    }

    /// A placed point mapped back.
    pub fn back(&self, p: &[f64; 3]) -> [f64; 3] {
        p.map(|c| (c - self.offset) / self.scale)
    }

    /// Every point placed.
    pub fn points(&self, points: &[[f64; 3]]) -> Vec<[f64; 3]> {
        points.iter().map(|p| self.point(p)).collect()
    }

    /// The mesh placed.
    pub fn mesh(&self, mesh: &cvd::TetMesh) -> cvd::TetMesh {
        cvd::TetMesh { vertices: self.points(&mesh.vertices), tets: mesh.tets.clone() }
    }

    /// The input as the placed one is, mapped back: equal to the input for
    /// a scaling (up to 1e-16 of each coordinate, below any tolerance); a
    /// translation rounds each point where it lies, and the reference
    /// must see the rounded points.
    pub fn seen(&self, mesh: &cvd::TetMesh, sites: &[[f64; 3]]) -> (cvd::TetMesh, Vec<[f64; 3]>) {
        let placed = self.mesh(mesh);
        let vertices = placed.vertices.iter().map(|p| self.back(p)).collect();
        let sites = self.points(sites).iter().map(|p| self.back(p)).collect();
        (cvd::TetMesh { vertices, tets: mesh.tets.clone() }, sites)
    }

    /// Cells computed on the placed input, mapped back to the input's frame.
    pub fn unplace(&self, cells: &cvd::Cells) -> cvd::Cells {
        let s3 = self.scale.powi(3);
        cvd::Cells {
            volume: cells.volume.iter().map(|v| v / s3).collect(),
            centroid: cells.centroid.iter().map(|p| self.back(p)).collect(),
            energy: cells.energy.iter().map(|e| e / (s3 * self.scale * self.scale)).collect(),
            total_volume: cells.total_volume / s3,
            mesh_volume: cells.mesh_volume / s3,
            ..cells.clone()
        }
    }
}
