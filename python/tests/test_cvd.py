"""The Python package against the library: the same numbers as the `cvd`
command line (bit for bit), the properties that matter (volumes add up to
the mesh, Lloyd lowers the energy, the backends agree), and clear errors on
bad input."""

import csv
import subprocess

import numpy as np
import pytest

import cvd

from helpers import CI, cli


@pytest.fixture(scope="module")
def mesh():
    return cvd.builtin("joint", 12)


def test_volumes_add_up_to_the_mesh(mesh):
    sites = cvd.sample(mesh, 2000, seed=3)
    assert sites.shape == (2000, 3) and sites.dtype == np.float64
    cells = cvd.clipped_voronoi(mesh, sites, backend="cpu")
    assert cells.volume.shape == (2000,) and cells.centroid.shape == (2000, 3)
    assert abs(cells.volume.sum() - mesh.volume) <= 1e-7 * mesh.volume
    assert cells.e_vol <= 1e-7
    assert (cells.energy > 0).all()
    assert cells.counters["unresolved"] == 0 and "clip" in cells.timings


def test_numbers_equal_the_command_line(mesh, tmp_path):
    exe = cli()
    sites = cvd.sample(mesh, 500, seed=7)
    xyz = tmp_path / "sites.xyz"
    np.savetxt(xyz, sites, fmt="%.17g")
    out = tmp_path / "cells.csv"
    run = subprocess.run(
        [exe, "run", "--model", "joint", "--resolution", "12", "--sites-file", str(xyz), "--backend", "cpu",
         "--no-geometry", "--no-neighbors", "--out", str(tmp_path / "o"), "--output", str(out)],
        capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    with open(out) as f:
        rows = list(csv.DictReader(f))
    cells = cvd.clipped_voronoi(mesh, sites, backend="cpu")
    volume = np.array([float(r["volume"]) for r in rows])
    centroid = np.array([[float(r["cx"]), float(r["cy"]), float(r["cz"])] for r in rows])
    assert np.array_equal(volume, cells.volume), "volumes differ from the command line's"
    assert np.array_equal(centroid, cells.centroid), "centroids differ from the command line's"


def test_any_float_dtype_and_layout(mesh):
    sites = cvd.sample(mesh, 300, seed=5)
    a = cvd.clipped_voronoi(mesh, sites, backend="cpu")
    fortran = np.asfortranarray(sites)
    b = cvd.clipped_voronoi(mesh, fortran, backend="cpu")
    assert np.array_equal(a.volume, b.volume)
    c = cvd.clipped_voronoi(mesh, sites.tolist(), backend="cpu")
    assert np.array_equal(a.volume, c.volume)
    d = cvd.clipped_voronoi(mesh, sites.astype(np.float32), backend="cpu")
    assert abs(d.volume.sum() - mesh.volume) <= 1e-7 * mesh.volume


def test_mesh_from_arrays():
    cube = cvd.builtin("cube", 2)
    again = cvd.Mesh(cube.vertices, cube.tets)
    assert again.volume == cube.volume
    assert np.array_equal(again.tets, cube.tets)
    assert cvd.Mesh(cube.vertices.astype(np.float32), cube.tets.astype(np.int32)).tets.shape == cube.tets.shape
    q = cube.quality()
    assert q["tets"] == len(cube.tets) and 0 < q["min_dihedral"] <= q["max_dihedral"] < 180


@pytest.mark.parametrize(
    "sites, message",
    [
        (np.zeros((10, 2)), "shape"),
        (np.array([[0.5, 0.5, np.nan]]), "not finite"),
        (np.zeros((0, 3)), "empty"),
        ("abc", "array of numbers"),
    ],
)
def test_bad_sites_raise_value_error(mesh, sites, message):
    with pytest.raises(ValueError, match=message):
        cvd.clipped_voronoi(mesh, sites, backend="cpu")


def test_a_job_over_its_memory_budget_raises_memory_error(mesh):
    # Refused before anything is allocated, naming what it needs and the
    # budget; under a budget that holds it, the same cells.
    sites = cvd.sample(mesh, 20000, seed=3)
    with pytest.raises(MemoryError, match=r"needs about .* budget"):
        cvd.clipped_voronoi(mesh, sites, backend="cpu", memory_budget=1 << 20)
    with pytest.raises(MemoryError, match="needs about"):
        cvd.periodic_voronoi(np.random.default_rng(1).random((20000, 3)), [0, 0, 0], [1, 1, 1], memory_budget=1 << 20)
    with pytest.raises(MemoryError, match="needs about"):
        cvd.particle_voronoi(np.random.default_rng(2).random((20000, 3)), (1, 1, 1), memory_budget=1 << 20)
    with pytest.raises(ValueError, match="memory_budget"):
        cvd.clipped_voronoi(mesh, sites, memory_budget=0)
    whole = cvd.clipped_voronoi(mesh, sites, backend="cpu", memory_budget=1 << 32)
    assert np.array_equal(whole.volume, cvd.clipped_voronoi(mesh, sites, backend="cpu").volume)


def test_bad_meshes_raise_value_error():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
    with pytest.raises(ValueError, match="outside"):
        cvd.Mesh(v, np.array([[0, 1, 2, 4]]))
    with pytest.raises(ValueError, match="outside"):
        cvd.Mesh(v, np.array([[0, 1, 2, -1]]))
    with pytest.raises(ValueError, match="shape"):
        cvd.Mesh(v, np.array([[0, 1, 2]]))
    with pytest.raises(ValueError, match="integer"):
        cvd.Mesh(v, np.array([[0, 1, 2, 3.5]]))
    with pytest.raises(ValueError, match="not finite"):
        cvd.Mesh(np.where(v == 1, np.inf, v), np.array([[0, 1, 2, 3]]))
    with pytest.raises(ValueError, match="no-such-model"):
        cvd.builtin("no-such-model")


def test_read_mesh_errors_name_the_file(tmp_path):
    bad = tmp_path / "bad.mesh"
    bad.write_text("MeshVersionFormatted 2\nDimension 3\nVertices\n2\n0 0 0 1\nzero 1 0 1\n")
    with pytest.raises(ValueError, match="bad.mesh"):
        cvd.read_mesh(bad)


def test_read_mesh_reads_meshio_files(tmp_path):
    meshio = pytest.importorskip("meshio") if not CI else __import__("meshio")
    cube = cvd.builtin("cube", 2)
    path = tmp_path / "cube.vtu"
    meshio.write(path, meshio.Mesh(cube.vertices, [("tetra", cube.tets)]))
    again = cvd.read_mesh(path)
    assert abs(again.volume - cube.volume) <= 1e-12


def test_faces_and_polyhedra(mesh):
    sites = cvd.sample(mesh, 200, seed=2)
    cells = cvd.clipped_voronoi(mesh, sites, backend="cpu", faces=True, polyhedra=True)
    adj = cells.adjacency
    assert adj["offsets"].shape == (201,) and adj["normals"].shape[1] == 3
    surface = np.add.reduceat(adj["areas"], adj["offsets"][:-1]) + adj["boundary"]
    assert (surface > 0).all()
    polys = cells.polyhedra
    assert len(polys) == 200
    for p in polys[:20]:
        assert p["vertices"].shape[1] == 3 and len(p["faces"]) == len(p["neighbors"])


def test_lloyd_lowers_the_energy(mesh):
    sites = cvd.sample(mesh, 500, seed=4)
    moved, history = cvd.lloyd(mesh, sites, 5, backend="cpu")
    assert moved.shape == sites.shape
    e = history["energy"]
    assert len(e) == 5 and (np.diff(e) < 0).all(), e
    assert (history["empty_cells"] == 0).all()
    _, lb = cvd.lloyd(mesh, sites, 5, optimizer="lbfgs", backend="cpu")
    assert lb["energy"][-1] <= e[0]


def test_transport_gives_equal_cells_and_weights_give_them_again():
    # (The coarse joint falls apart into pieces, which transport refuses.)
    mesh = cvd.builtin("cube", 8)
    sites = cvd.sample(mesh, 800, seed=5)
    weights, record = cvd.transport(mesh, sites, backend="cpu", return_record=True)
    assert weights.shape == (800,) and record["converged"]
    assert record["max_error"][-1] <= 1e-6 and 1 <= len(record["step"]) <= 15
    assert len(record["max_error"]) == len(record["step"]) + 1
    cells = cvd.clipped_voronoi(mesh, sites, backend="cpu", weights=weights)
    target = mesh.volume / 800
    assert np.abs(cells.volume / target - 1).max() <= 1e-6
    # Capacities: twice the mass for the first half.
    c = np.r_[np.full(400, 2.0), np.ones(400)]
    w = cvd.transport(mesh, sites, c, backend="cpu")
    assert w.shape == (800,)
    v = cvd.clipped_voronoi(mesh, sites, backend="cpu", weights=w).volume
    assert np.allclose(v[:400] / v[400:].mean(), 2.0, rtol=1e-5, atol=0)
    with pytest.warns(RuntimeWarning, match="transport: the masses came within"):
        cvd.transport(mesh, sites, backend="cpu", max_steps=1)
    with pytest.raises(ValueError, match="799 capacities for 800 sites"):
        cvd.transport(mesh, sites, c[1:], backend="cpu")
    with pytest.raises(ValueError, match="weights for 800 sites"):
        cvd.clipped_voronoi(mesh, sites, weights=w[1:])


def test_cpu_and_vulkan_agree(mesh):
    if not any(True for _ in cvd.devices()):
        if CI:
            pytest.fail("CI=true but no Vulkan device (lavapipe) is found")
        pytest.skip("no Vulkan device")
    sites = cvd.sample(mesh, 1000, seed=9)
    a = cvd.clipped_voronoi(mesh, sites, backend="cpu")
    b = cvd.clipped_voronoi(mesh, sites, backend="vulkan")
    assert np.allclose(a.volume, b.volume, rtol=1e-5, atol=0)
    assert abs(b.volume.sum() - mesh.volume) <= 1e-6 * mesh.volume


def test_mesh_surface_meshes_a_trimesh_sphere(tmp_path):
    trimesh = pytest.importorskip("trimesh") if not CI else __import__("trimesh")
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    path = tmp_path / "sphere.stl"
    sphere.export(path)
    mesh = cvd.mesh_surface(path, resolution=16)
    assert abs(mesh.volume - sphere.volume) <= 0.02 * sphere.volume, (mesh.volume, sphere.volume)
    cells = cvd.clipped_voronoi(mesh, cvd.sample(mesh, 300, seed=1), backend="cpu")
    assert abs(cells.volume.sum() - mesh.volume) <= 1e-7 * mesh.volume
    with pytest.raises(ValueError, match="no-such.stl"):
        cvd.mesh_surface(tmp_path / "no-such.stl")


def test_meshio_arrays_in_and_results_out(tmp_path):
    meshio = pytest.importorskip("meshio") if not CI else __import__("meshio")
    cube = cvd.builtin("cube", 2)
    m = meshio.Mesh(cube.vertices, [("tetra", cube.tets)])
    mesh = cvd.Mesh(m.points, m.cells_dict["tetra"])
    assert mesh.volume == cube.volume
    sites = cvd.sample(mesh, 100, seed=6)
    cells = cvd.clipped_voronoi(mesh, sites, backend="cpu")
    out = tmp_path / "sites.vtu"
    vertex = np.arange(len(sites)).reshape(-1, 1)
    meshio.write(out, meshio.Mesh(sites, [("vertex", vertex)], point_data={"volume": cells.volume}))
    back = meshio.read(out)
    assert np.array_equal(back.points, sites)
    assert np.array_equal(back.point_data["volume"], cells.volume)


def test_arrays_out_are_plain_numpy(mesh):
    sites = cvd.sample(mesh, 50, seed=2)
    cells = cvd.clipped_voronoi(mesh, sites, backend="cpu")
    moved, _ = cvd.lloyd(mesh, sites, 1, backend="cpu")
    for a in (sites, moved, cells.volume, cells.centroid, cells.energy, mesh.vertices, mesh.tets):
        assert isinstance(a, np.ndarray) and a.flags.writeable and a.flags.c_contiguous
        assert a.dtype in (np.float64, np.int64)
    assert cells.centroid.shape == (50, 3) and moved.shape == (50, 3)


def test_ctrl_c_stops_lloyd_between_iterations(tmp_path):
    import signal
    import sys
    import time

    script = tmp_path / "long_lloyd.py"
    # Python turns SIGINT into KeyboardInterrupt only where it was not
    # ignored when it started (a background job's children ignore it).
    script.write_text(
        "import signal, sys, cvd\n"
        "signal.signal(signal.SIGINT, signal.default_int_handler)\n"
        "mesh = cvd.builtin('joint', 16)\n"
        "sites = cvd.sample(mesh, 20000, seed=1)\n"
        "print('started', flush=True)\n"
        "try:\n"
        "    cvd.lloyd(mesh, sites, 100000, backend='cpu')\n"
        "except KeyboardInterrupt as e:\n"
        "    print('interrupted:', e, flush=True)\n"
        "    sys.exit(3)\n"
    )
    p = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "started"
    time.sleep(1.0)
    p.send_signal(signal.SIGINT)
    out, _ = p.communicate(timeout=60)
    assert p.returncode == 3, out
    assert "stopped after" in out and "of 100000 iterations" in out, out


def test_periodic_box_cells_fill_it_and_match_the_command_line(tmp_path):
    # Sites outside the box come back wrapped.
    rng = np.random.default_rng(7)
    sites = rng.random((300, 3)) * [2.0, 1.0, 1.0]
    sites[:10] += [2.0, -1.0, 3.0]
    cells, wrapped = cvd.periodic_voronoi(sites, [0, 0, 0], [2, 1, 1], backend="cpu", faces=True)
    assert abs(cells.volume.sum() - 2.0) < 1e-6 and cells.e_vol < 1e-6
    assert np.all(wrapped >= 0) and np.all(wrapped < [2.0, 1.0, 1.0])
    assert np.allclose(wrapped[:10], sites[:10] - [2.0, -1.0, 3.0])
    a = cells.adjacency
    assert a["shifts"].shape == (len(a["neighbors"]), 3) and np.any(a["shifts"] != 0)
    assert np.all(a["boundary"] == 0)
    # The command line gives the same cells, digit for digit.
    path = tmp_path / "s.xyz"
    np.savetxt(path, wrapped, fmt="%.17g")
    exe = cli()
    run = subprocess.run(
        [exe, "run", "--box", "0,0,0,2,1,1", "--sites-file", str(path), "--backend", "cpu", "--out", str(tmp_path / "o")],
        capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    with open(tmp_path / "o" / "cells.csv") as f:
        volumes = [float(row["volume"]) for row in csv.DictReader(f)]
    assert np.array_equal(np.array(volumes), cells.volume)
    with pytest.raises(ValueError, match="along y"):
        cvd.periodic_voronoi(sites, [0, 1, 0], [2, 1, 1])
