//! `cvd._cvd`: the library's clipped Voronoi diagrams and CVT for Python,
//! numpy arrays in and out (the package `cvd` wraps it: python/cvd).
//!
//! Arrays come in as C-contiguous float64 (the Python wrapper converts any
//! float dtype and layout once) and go out as owned arrays. Computations
//! run with the GIL released. The library's errors become `ValueError`
//! when they lie in the input (file, line and what was expected in the
//! message) and `RuntimeError` otherwise.

use cvd::cvt::SiteDiagram;
use numpy::{
    IntoPyArray, PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2, PyUntypedArrayMethods,
};
use pyo3::exceptions::{PyKeyboardInterrupt, PyMemoryError, PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::path::PathBuf;

/// The library's error as a Python exception.
fn err(e: cvd::Error) -> PyErr {
    if matches!(e, cvd::Error::TooLarge { .. }) {
        // Refused before allocating: what it needs and what there is.
        PyMemoryError::new_err(e.to_string())
    } else if e.is_input_error() {
        PyValueError::new_err(e.to_string())
    } else {
        PyRuntimeError::new_err(e.to_string())
    }
}

/// Points as their coordinates one after another, without a copy (numpy
/// then owns the vector).
fn flat(points: Vec<[f64; 3]>) -> Vec<f64> {
    bytemuck::allocation::cast_vec(points)
}

/// `(n, 3)` rows of an array, or a `ValueError` naming `what`.
fn rows3(a: &PyReadonlyArray2<'_, f64>, what: &str) -> PyResult<Vec<[f64; 3]>> {
    let v = a.as_array();
    if v.ncols() != 3 {
        return Err(PyValueError::new_err(format!("{what} must have shape (n, 3), not {:?}", v.shape())));
    }
    let rows: Vec<[f64; 3]> = v.rows().into_iter().map(|r| [r[0], r[1], r[2]]).collect();
    if let Some(i) = rows.iter().position(|p| p.iter().any(|c| !c.is_finite())) {
        return Err(PyValueError::new_err(format!("{what}: row {i} is not finite: {:?}", rows[i])));
    }
    Ok(rows)
}

/// A tet mesh: vertices `(n, 3)` float64 and tets `(m, 4)` vertex indices.
#[pyclass(module = "cvd", frozen)]
pub struct Mesh {
    inner: cvd::TetMesh,
}

#[pymethods]
impl Mesh {
    /// A mesh from arrays: `vertices` `(n, 3)` numbers, `tets` `(m, 4)`
    /// integer indices into them (any orientation); any dtype and layout
    /// (converted once).
    #[new]
    fn new(py: Python<'_>, vertices: &Bound<'_, PyAny>, tets: &Bound<'_, PyAny>) -> PyResult<Self> {
        let np = py.import("numpy")?;
        let float64 = np.getattr("float64")?;
        let kw = PyDict::new(py);
        kw.set_item("dtype", &float64)?;
        let vertices: PyReadonlyArray2<'_, f64> = np
            .call_method("ascontiguousarray", (vertices,), Some(&kw))
            .and_then(|a| a.extract())
            .map_err(|e| PyValueError::new_err(format!("vertices must be an (n, 3) array of numbers: {e}")))?;
        let t = np.call_method1("asarray", (tets,))?;
        let kind: String = t.getattr("dtype")?.getattr("kind")?.extract()?;
        let integral = kind == "i" || kind == "u" || {
            kind == "f" && np.call_method1("array_equal", (&t, np.call_method1("round", (&t,))?))?.extract::<bool>()?
        };
        if !integral {
            return Err(PyValueError::new_err(format!(
                "tets must hold integer vertex indices, not dtype kind {kind:?}"
            )));
        }
        let tets: PyReadonlyArray2<'_, i64> = t
            .call_method1("astype", ("int64",))
            .and_then(|a| a.extract())
            .map_err(|e| PyValueError::new_err(format!("tets must be an (m, 4) array of indices: {e}")))?;
        let vertices = rows3(&vertices, "vertices")?;
        let t = tets.as_array();
        if t.ncols() != 4 {
            return Err(PyValueError::new_err(format!("tets must have shape (m, 4), not {:?}", t.shape())));
        }
        let mut out = Vec::with_capacity(t.nrows());
        for (i, r) in t.rows().into_iter().enumerate() {
            let mut tet = [0u32; 4];
            for (k, &v) in r.iter().enumerate() {
                if v < 0 || v as usize >= vertices.len() {
                    return Err(PyValueError::new_err(format!(
                        "tets: row {i} names vertex {v}, outside 0..{}",
                        vertices.len()
                    )));
                }
                tet[k] = v as u32;
            }
            out.push(tet);
        }
        cvd::TetMesh::new(vertices, out).map(|inner| Mesh { inner }).map_err(err)
    }

    /// Vertex positions, `(n, 3)` float64.
    #[getter]
    fn vertices<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        let flat: Vec<f64> = self.inner.vertices.iter().flatten().copied().collect();
        let n = self.inner.vertices.len();
        flat.into_pyarray(py).reshape([n, 3]).expect("n x 3 values")
    }

    /// Tets, `(m, 4)` int64 vertex indices.
    #[getter]
    fn tets<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<i64>> {
        let flat: Vec<i64> = self.inner.tets.iter().flatten().map(|&v| v as i64).collect();
        let m = self.inner.tets.len();
        flat.into_pyarray(py).reshape([m, 4]).expect("m x 4 values")
    }

    /// The mesh's volume.
    #[getter]
    fn volume(&self) -> f64 {
        self.inner.volume()
    }

    /// Tets, vertices used, and the smallest and largest dihedral angles
    /// (degrees), as a dict.
    fn quality<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let q = cvd::mesher::quality::Quality::of(&self.inner);
        let d = PyDict::new(py);
        d.set_item("tets", q.tets)?;
        d.set_item("vertices", q.vertices)?;
        d.set_item("min_dihedral", q.min_dihedral)?;
        d.set_item("max_dihedral", q.max_dihedral)?;
        Ok(d)
    }

    fn __repr__(&self) -> String {
        format!(
            "Mesh({} vertices, {} tets, volume {})",
            self.inner.vertices.len(),
            self.inner.tets.len(),
            self.inner.volume()
        )
    }
}

/// A built-in model (`cube`, `sphere`, `torus`, `joint`, ...) meshed at
/// `resolution` (its default when None).
#[pyfunction]
#[pyo3(signature = (name, resolution=None))]
fn builtin(py: Python<'_>, name: &str, resolution: Option<u32>) -> PyResult<Mesh> {
    let name = name.to_string();
    py.detach(move || cvd::mesher::models::builtin(&name, resolution)).map(|inner| Mesh { inner }).map_err(err)
}

/// A tet mesh read from a file (every format `cvd run --mesh` reads).
#[pyfunction]
fn read_mesh(py: Python<'_>, path: PathBuf) -> PyResult<Mesh> {
    py.detach(move || cvd_io::read_mesh(&path)).map(|inner| Mesh { inner }).map_err(err)
}

/// The inside of a closed triangle surface (STL, OBJ, OFF, PLY), meshed
/// into tets at `resolution` lattice steps across (the library's default
/// when None).
#[pyfunction]
#[pyo3(signature = (path, resolution=None))]
fn mesh_surface(py: Python<'_>, path: PathBuf, resolution: Option<u32>) -> PyResult<Mesh> {
    py.detach(move || {
        let surface = cvd_io::read_surface(&path)?;
        cvd::mesher::mesh_surface(&surface, resolution.unwrap_or(cvd::mesher::DEFAULT_SURFACE_RESOLUTION))
    })
    .map(|inner| Mesh { inner })
    .map_err(err)
}

/// `n` sites uniform in `mesh`, `(n, 3)` float64.
#[pyfunction]
#[pyo3(signature = (mesh, n, seed=1))]
fn sample<'py>(py: Python<'py>, mesh: &Mesh, n: usize, seed: u64) -> Bound<'py, PyArray2<f64>> {
    let points = py.detach(|| cvd::geom::points::in_mesh(&mesh.inner, n, seed));
    flat(points).into_pyarray(py).reshape([n, 3]).expect("n x 3 values")
}

/// The backend options for a name.
fn backend(name: &str) -> PyResult<cvd::BackendOptions> {
    let Some(choice) = cvd::BackendChoice::from_name(name) else {
        return Err(PyValueError::new_err(format!("backend must be 'auto', 'cpu' or 'vulkan', not {name:?}")));
    };
    Ok(cvd::BackendOptions { choice, ..Default::default() })
}

/// The clipped cells, as numpy arrays and dicts.
#[pyclass(module = "cvd", frozen)]
pub struct Cells {
    /// Volume of each site's clipped cell, `(n,)`.
    #[pyo3(get)]
    volume: Py<PyArray1<f64>>,
    /// Centroid of each cell (the site itself when empty), `(n, 3)`.
    #[pyo3(get)]
    centroid: Py<PyArray2<f64>>,
    /// `∫ |x - x_i|²` over each cell, `(n,)`.
    #[pyo3(get)]
    energy: Py<PyArray1<f64>>,
    /// `|Σ V_i - V| / V`.
    #[pyo3(get)]
    e_vol: f64,
    /// The mesh's volume.
    #[pyo3(get)]
    mesh_volume: f64,
    /// The kernels' counters, by name.
    #[pyo3(get)]
    counters: Py<PyDict>,
    /// Seconds per phase, by name.
    #[pyo3(get)]
    timings: Py<PyDict>,
    /// With `faces=True`: the adjacency as a dict of arrays (`offsets`,
    /// `neighbors`, `areas`, `normals`, `boundary`), else None.
    #[pyo3(get)]
    adjacency: Option<Py<PyDict>>,
    /// With `polyhedra=True`: each cell with a volume as a dict (`site`,
    /// `vertices` `(k, 3)`, `faces` a list of index arrays, `neighbors`
    /// per face, -1 on the boundary), else None.
    #[pyo3(get)]
    polyhedra: Option<Py<pyo3::types::PyList>>,
}

#[pymethods]
impl Cells {
    fn __repr__(&self, py: Python<'_>) -> String {
        format!("Cells({} sites, E_vol {:e})", self.volume.bind(py).len(), self.e_vol)
    }

    /// The cells' polyhedra as a `pyvista.UnstructuredGrid` with their cell
    /// data (needs `polyhedra=True` and pyvista).
    fn to_pyvista<'py>(slf: &Bound<'py, Self>) -> PyResult<Bound<'py, PyAny>> {
        slf.py().import("cvd._convert")?.call_method1("to_pyvista", (slf,))
    }

    /// The adjacency as a `scipy.sparse.csr_array` of shared face areas
    /// (needs `faces=True` and scipy).
    fn adjacency_matrix<'py>(slf: &Bound<'py, Self>) -> PyResult<Bound<'py, PyAny>> {
        slf.py().import("cvd._convert")?.call_method1("adjacency_matrix", (slf,))
    }
}

fn to_python(py: Python<'_>, cells: cvd::Cells) -> PyResult<Cells> {
    let n = cells.volume.len();
    let counters = PyDict::new(py);
    let c = &cells.counters;
    for (name, value) in [
        ("pairs", c.pairs),
        ("nonempty", c.nonempty),
        ("clips", c.clips),
        ("security_missed", c.security_missed),
        ("overflows", c.overflows),
        ("broken", c.broken),
        ("second_pass", c.second_pass),
        ("unresolved", c.unresolved),
        ("duplicate_sites", c.duplicate_sites),
        ("empty_cells", c.empty_cells),
        ("missed_tets", c.missed_tets),
        ("faces_redone", c.faces_redone),
    ] {
        counters.set_item(name, value)?;
    }
    let timings = PyDict::new(py);
    for (phase, seconds) in &cells.timings.phases {
        timings.set_item(phase, seconds)?;
    }
    let adjacency = match &cells.adjacency {
        Some(a) => {
            let d = PyDict::new(py);
            d.set_item("offsets", a.offsets.iter().map(|&o| o as i64).collect::<Vec<_>>().into_pyarray(py))?;
            d.set_item("neighbors", a.neighbors.iter().map(|&j| j as i64).collect::<Vec<_>>().into_pyarray(py))?;
            d.set_item("areas", a.areas.clone().into_pyarray(py))?;
            let normals: Vec<f64> = a.normals.iter().flatten().copied().collect();
            d.set_item("normals", normals.into_pyarray(py).reshape([a.normals.len(), 3])?)?;
            d.set_item("boundary", a.boundary.clone().into_pyarray(py))?;
            if !a.shifts.is_empty() {
                let shifts: Vec<i64> = a.shifts.iter().flatten().map(|&x| x as i64).collect();
                d.set_item("shifts", shifts.into_pyarray(py).reshape([a.shifts.len(), 3])?)?;
            }
            Some(d.unbind())
        }
        None => None,
    };
    let polyhedra = match &cells.polyhedra {
        Some(all) => {
            let list = pyo3::types::PyList::empty(py);
            for p in all {
                let d = PyDict::new(py);
                d.set_item("site", p.site)?;
                let flat: Vec<f64> = p.vertices.iter().flatten().copied().collect();
                d.set_item("vertices", flat.into_pyarray(py).reshape([p.vertices.len(), 3])?)?;
                let faces = pyo3::types::PyList::empty(py);
                for f in p.faces() {
                    faces.append(f.iter().map(|&v| v as i64).collect::<Vec<_>>().into_pyarray(py))?;
                }
                d.set_item("faces", faces)?;
                d.set_item("neighbors", p.face_neighbors.clone().into_pyarray(py))?;
                list.append(d)?;
            }
            Some(list.unbind())
        }
        None => None,
    };
    let centroid = flat(cells.centroid);
    Ok(Cells {
        volume: cells.volume.into_pyarray(py).unbind(),
        centroid: centroid.into_pyarray(py).reshape([n, 3])?.unbind(),
        energy: cells.energy.into_pyarray(py).unbind(),
        e_vol: cells.e_vol,
        mesh_volume: cells.mesh_volume,
        counters: counters.unbind(),
        timings: timings.unbind(),
        adjacency,
        polyhedra,
    })
}

/// The clipped Voronoi diagram of `sites` (`(n, 3)` float64) in `mesh`.
#[pyfunction]
#[pyo3(signature = (mesh, sites, backend="auto", strategy="auto", pairing="auto", density=None, faces=false, polyhedra=false, weights=None, memory_budget=None))]
#[allow(clippy::too_many_arguments)]
fn clipped_voronoi(
    py: Python<'_>,
    mesh: &Mesh,
    sites: PyReadonlyArray2<'_, f64>,
    backend: &str,
    strategy: &str,
    pairing: &str,
    density: Option<PyReadonlyArray1<'_, f64>>,
    faces: bool,
    polyhedra: bool,
    weights: Option<PyReadonlyArray1<'_, f64>>,
    memory_budget: Option<u64>,
) -> PyResult<Cells> {
    let sites = rows3(&sites, "sites")?;
    let strategy = match strategy {
        "auto" => None,
        name => Some(cvd::Strategy::from_name(name).ok_or_else(|| {
            let names: Vec<&str> = cvd::Strategy::ALL.iter().map(|s| s.name()).collect();
            PyValueError::new_err(format!("strategy must be 'auto', '{}', not {name:?}", names.join("', '")))
        })?),
    };
    let pairing = match pairing {
        "auto" => None,
        "flood" => Some(cvd::Pairing::Flood),
        "knn" => Some(cvd::Pairing::Knn),
        other => return Err(PyValueError::new_err(format!("pairing must be 'auto', 'flood' or 'knn', not {other:?}"))),
    };
    let density: Option<Vec<f64>> = density.map(|d| d.as_array().to_vec());
    let weights: Option<Vec<f64>> = weights.map(|w| w.as_array().to_vec());
    let options = self::backend(backend)?;
    let cells = py
        .detach(|| -> cvd::Result<cvd::Cells> {
            let mut cv = cvd::ClippedVoronoi::new(&mesh.inner, &sites)
                .strategy(strategy)
                .density(density.as_deref())
                .faces(faces)
                .memory_budget(memory_budget);
            if let Some(p) = pairing {
                cv = cv.pairing(p);
            }
            if let Some(w) = &weights {
                cv = cv.weights(w);
            }
            let b = cvd::backends::open(&options)?;
            let cv = cv.backend(b.as_ref());
            if !polyhedra {
                return cv.compute();
            }
            Ok(cv.compute_with_geometry(&cvd::exec::CpuBackend::new(None)?)?.0)
        })
        .map_err(err)?;
    to_python(py, cells)
}

/// The cells of `sites` in the periodic box `lo..hi`: their Voronoi (or
/// power) cells in the space the box tiles, cut into the box; with the
/// sites wrapped into it.
#[pyfunction]
#[pyo3(signature = (sites, lo, hi, backend="auto", faces=false, weights=None, memory_budget=None))]
#[allow(clippy::too_many_arguments)]
fn periodic_voronoi<'py>(
    py: Python<'py>,
    sites: PyReadonlyArray2<'_, f64>,
    lo: [f64; 3],
    hi: [f64; 3],
    backend: &str,
    faces: bool,
    weights: Option<PyReadonlyArray1<'_, f64>>,
    memory_budget: Option<u64>,
) -> PyResult<(Cells, Bound<'py, PyArray2<f64>>)> {
    let sites = rows3(&sites, "sites")?;
    let weights: Option<Vec<f64>> = weights.map(|w| w.as_array().to_vec());
    let options = self::backend(backend)?;
    let out = py
        .detach(|| -> cvd::Result<cvd::PeriodicCells> {
            let domain = cvd::PeriodicBox::new(lo, hi)?;
            let b = cvd::backends::open(&options)?;
            let mut pv =
                cvd::PeriodicVoronoi::new(domain, &sites).faces(faces).backend(b.as_ref()).memory_budget(memory_budget);
            if let Some(w) = &weights {
                pv = pv.weights(w);
            }
            pv.compute()
        })
        .map_err(err)?;
    let n = out.sites.len();
    let wrapped = flat(out.sites).into_pyarray(py).reshape([n, 3])?;
    Ok((to_python(py, out.cells)?, wrapped))
}

/// What `particle_voronoi` gives: the cells, the points wrapped, and the
/// particles' arrays.
type ParticleResult<'py> = (Cells, Bound<'py, PyArray2<f64>>, Option<Bound<'py, PyDict>>, Option<FrameLists>, usize);

/// What a frame leaves for the next (`cvd::FrameLists`): each particle's
/// nearest sites and images, opaque to Python.
#[pyclass(module = "cvd", frozen)]
struct FrameLists(cvd::FrameLists);

/// The cells of particles in a periodic (possibly triclinic, possibly
/// walled) cell: `origin`, lattice vectors `vectors` (rows a, b, c),
/// `periodic` per axis, radii (power weights r²) or None, the Voronoi
/// index's `thresholds` (edge, relative edge, face, relative face) when
/// `index`; returns (cells, with their faces if `faces`, wrapped points, a
/// dict of the particles' arrays or None).
#[pyfunction]
#[pyo3(signature = (points, origin, vectors, periodic, radii=None, backend="auto", index=true, thresholds=(0.0, 0.0, 0.0, 0.0), polyhedra=false, faces=true, keep=false, last=None, memory_budget=None))]
#[allow(clippy::too_many_arguments)]
fn particle_voronoi<'py>(
    py: Python<'py>,
    points: PyReadonlyArray2<'_, f64>,
    origin: [f64; 3],
    vectors: [[f64; 3]; 3],
    periodic: [bool; 3],
    radii: Option<PyReadonlyArray1<'_, f64>>,
    backend: &str,
    index: bool,
    thresholds: (f64, f64, f64, f64),
    polyhedra: bool,
    faces: bool,
    keep: bool,
    last: Option<PyRef<'_, FrameLists>>,
    memory_budget: Option<u64>,
) -> PyResult<ParticleResult<'py>> {
    let last = last.as_deref().map(|l| &l.0);
    let points = rows3(&points, "points")?;
    let radii: Option<Vec<f64>> = radii.map(|r| r.as_array().to_vec());
    let options = self::backend(backend)?;
    let t = cvd::IndexThresholds {
        edge: thresholds.0,
        relative_edge: thresholds.1,
        face: thresholds.2,
        relative_face: thresholds.3,
    };
    let (mut out, particles) = py
        .detach(|| -> cvd::Result<(cvd::PeriodicCells, Option<cvd::ParticleCells>)> {
            t.check()?;
            let domain = cvd::PeriodicBox::triclinic(origin, vectors)?.with_periodic(periodic);
            let weights = match &radii {
                Some(r) if r.len() != points.len() => {
                    return Err(cvd::Error::InvalidInput(format!("{} radii for {} points", r.len(), points.len())))
                }
                Some(r) => Some(cvd::diagram::particles::radii_weights(r)?),
                None => None,
            };
            let b = cvd::backends::open(&options)?;
            let mut pv = cvd::PeriodicVoronoi::new(domain, &points)
                .faces(faces)
                .backend(b.as_ref())
                .keep_lists(keep)
                .after(last)
                .memory_budget(memory_budget);
            if let Some(w) = &weights {
                pv = pv.weights(w);
            }
            if !(index || polyhedra) {
                return Ok((pv.compute()?, None));
            }
            let out = pv.compute_with_polyhedra(&cvd::CpuBackend::new(None)?)?;
            let particles =
                index.then(|| cvd::ParticleCells::of(points.len(), out.cells.polyhedra().unwrap_or(&[]), &t));
            Ok((out, particles))
        })
        .map_err(err)?;
    if !polyhedra {
        out.cells.polyhedra = None;
    }
    let lists = out.lists.take().map(FrameLists);
    let reused = out.reused;
    let n = out.sites.len();
    let wrapped = flat(out.sites).into_pyarray(py).reshape([n, 3])?;
    let particles = match particles {
        Some(p) => {
            let d = PyDict::new(py);
            d.set_item("area", p.area.into_pyarray(py))?;
            d.set_item("coordination", p.coordination.iter().map(|&c| c as i64).collect::<Vec<_>>().into_pyarray(py))?;
            d.set_item(
                "max_face_order",
                p.max_face_order.iter().map(|&c| c as i64).collect::<Vec<_>>().into_pyarray(py),
            )?;
            let index: Vec<i64> = p.index.iter().flatten().map(|&c| c as i64).collect();
            d.set_item("voronoi_index", index.into_pyarray(py).reshape([n, cvd::INDEX_ORDERS])?)?;
            Some(d)
        }
        None => None,
    };
    Ok((to_python(py, out.cells)?, wrapped, particles, lists, reused))
}

/// `iterations` of Lloyd's method (`optimizer="lloyd"`) or L-BFGS
/// (`"lbfgs"`) from `sites`; returns the sites and the history (a dict of
/// arrays `energy` and `empty_cells`, one entry per iteration). Ctrl-C
/// stops it between iterations (`KeyboardInterrupt`).
#[pyfunction]
#[pyo3(signature = (mesh, sites, iterations, optimizer="lloyd", backend="auto", density=None, progress=false))]
#[allow(clippy::too_many_arguments)]
fn lloyd<'py>(
    py: Python<'py>,
    mesh: &Mesh,
    sites: PyReadonlyArray2<'_, f64>,
    iterations: usize,
    optimizer: &str,
    backend: &str,
    density: Option<PyReadonlyArray1<'_, f64>>,
    progress: bool,
) -> PyResult<(Bound<'py, PyArray2<f64>>, Bound<'py, PyDict>)> {
    let mut sites = rows3(&sites, "sites")?;
    let lbfgs = match optimizer {
        "lloyd" => false,
        "lbfgs" => true,
        other => return Err(PyValueError::new_err(format!("optimizer must be 'lloyd' or 'lbfgs', not {other:?}"))),
    };
    let density: Option<Vec<f64>> = density.map(|d| d.as_array().to_vec());
    let options = self::backend(backend)?;
    let b = py.detach(|| cvd::backends::open(&options)).map_err(err)?;
    let (mut energy, mut empty) = (Vec::new(), Vec::new());
    // One iteration at a time (L-BFGS: all at once, its memory spans
    // them), the signals checked in between.
    let step = if lbfgs { iterations.max(1) } else { 1 };
    let mut done = 0;
    while done < iterations {
        let n = step.min(iterations - done);
        let run = py
            .detach(|| {
                let cv = cvd::ClippedVoronoi::new(&mesh.inner, &sites).density(density.as_deref()).backend(b.as_ref());
                if lbfgs {
                    cv.lbfgs(n, &mut |_, _| {})
                } else {
                    cv.lloyd(n, &mut |_, _| {})
                }
            })
            .map_err(err)?;
        for it in &run.iterations {
            energy.push(it.energy);
            empty.push(it.empty_cells as i64);
        }
        sites = run.sites;
        done += n;
        if progress {
            eprintln!("cvd: iteration {done}/{iterations}, energy {:e}", energy.last().copied().unwrap_or(0.0));
        }
        if py.check_signals().is_err() {
            return Err(PyKeyboardInterrupt::new_err(format!("stopped after {done} of {iterations} iterations")));
        }
    }
    let history = PyDict::new(py);
    history.set_item("energy", energy.into_pyarray(py))?;
    history.set_item("empty_cells", empty.into_pyarray(py))?;
    let n = sites.len();
    Ok((flat(sites).into_pyarray(py).reshape([n, 3])?, history))
}

/// The power weights for which every cell of `sites` in `mesh` gets its
/// target mass (uniform, or `capacities` scaled to the mesh's mass); returns
/// the weights and the Newton record (a dict of arrays `max_error`, one per
/// diagram the steps started from, `step`, `cg_iterations`, `seconds`, one
/// per step; and `converged`). Ctrl-C stops it between steps.
#[pyfunction]
#[pyo3(signature = (mesh, sites, capacities=None, backend="auto", density=None, weights=None, tolerance=1e-6, max_steps=50))]
#[allow(clippy::too_many_arguments)]
fn transport<'py>(
    py: Python<'py>,
    mesh: &Mesh,
    sites: PyReadonlyArray2<'_, f64>,
    capacities: Option<PyReadonlyArray1<'_, f64>>,
    backend: &str,
    density: Option<PyReadonlyArray1<'_, f64>>,
    weights: Option<PyReadonlyArray1<'_, f64>>,
    tolerance: f64,
    max_steps: usize,
) -> PyResult<(Bound<'py, PyArray1<f64>>, Bound<'py, PyDict>)> {
    let sites = rows3(&sites, "sites")?;
    let capacities: Option<Vec<f64>> = capacities.map(|c| c.as_array().to_vec());
    let density: Option<Vec<f64>> = density.map(|d| d.as_array().to_vec());
    let start: Option<Vec<f64>> = weights.map(|w| w.as_array().to_vec());
    if tolerance.is_nan() || tolerance <= 0.0 {
        return Err(PyValueError::new_err(format!("tolerance must be positive, not {tolerance}")));
    }
    let options = self::backend(backend)?;
    let b = py.detach(|| cvd::backends::open(&options)).map_err(err)?;
    let cv = cvd::ClippedVoronoi::new(&mesh.inner, &sites).density(density.as_deref()).backend(b.as_ref());
    let mut ot = cvd::cvt::transport::Transport::new(cv).tolerance(tolerance).max_steps(max_steps);
    if let Some(c) = &capacities {
        ot = ot.capacities(c);
    }
    if let Some(w) = &start {
        ot = ot.start(w);
    }
    // The signals checked after each Newton step.
    let mut stopped = false;
    let run = py
        .detach(|| {
            ot.solve(&mut |_| {
                stopped = Python::attach(|py| py.check_signals().is_err());
                !stopped
            })
        })
        .map_err(err)?;
    if stopped {
        return Err(PyKeyboardInterrupt::new_err(format!("stopped after {} Newton steps", run.steps.len())));
    }
    let steps = &run.steps;
    let record = PyDict::new(py);
    record.set_item("max_error", steps.iter().map(|s| s.max_error).collect::<Vec<_>>().into_pyarray(py))?;
    let taken = &steps[..steps.len() - 1];
    record.set_item("step", taken.iter().map(|s| s.step).collect::<Vec<_>>().into_pyarray(py))?;
    record
        .set_item("cg_iterations", taken.iter().map(|s| s.cg_iterations as i64).collect::<Vec<_>>().into_pyarray(py))?;
    record.set_item("seconds", taken.iter().map(|s| s.seconds).collect::<Vec<_>>().into_pyarray(py))?;
    record.set_item("converged", run.converged)?;
    record.set_item("stopped", &run.stopped)?;
    Ok((run.weights.into_pyarray(py), record))
}

/// The Vulkan devices: a list of dicts (`index`, `name`, `type`, `gpu`);
/// empty without a Vulkan loader or driver.
#[pyfunction]
fn devices<'py>(py: Python<'py>) -> PyResult<Vec<Bound<'py, PyDict>>> {
    let list = match py.detach(cvd::backends::vulkan::list_devices) {
        Ok(list) => list,
        Err(cvd::Error::VulkanUnavailable(_)) => Vec::new(),
        Err(e) => return Err(err(e)),
    };
    list.into_iter()
        .map(|d| {
            let out = PyDict::new(py);
            out.set_item("index", d.index)?;
            out.set_item("name", &d.name)?;
            out.set_item("type", d.kind_name())?;
            out.set_item("gpu", d.is_gpu())?;
            Ok(out)
        })
        .collect()
}

#[pymodule]
fn _cvd(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Mesh>()?;
    m.add_class::<Cells>()?;
    m.add_class::<FrameLists>()?;
    m.add_function(wrap_pyfunction!(builtin, m)?)?;
    m.add_function(wrap_pyfunction!(read_mesh, m)?)?;
    m.add_function(wrap_pyfunction!(mesh_surface, m)?)?;
    m.add_function(wrap_pyfunction!(sample, m)?)?;
    m.add_function(wrap_pyfunction!(clipped_voronoi, m)?)?;
    m.add_function(wrap_pyfunction!(lloyd, m)?)?;
    m.add_function(wrap_pyfunction!(transport, m)?)?;
    m.add_function(wrap_pyfunction!(periodic_voronoi, m)?)?;
    m.add_function(wrap_pyfunction!(particle_voronoi, m)?)?;
    m.add_function(wrap_pyfunction!(devices, m)?)?;
    // Whether this build has the SPIR-V kernels (the Vulkan backend).
    m.add("KERNELS", cvd::backends::vulkan::HAS_KERNELS)?;
    Ok(())
}
