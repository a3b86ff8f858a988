"""The package as users meet it: installed from its wheel where no Rust is,
its build deciding about the SPIR-V kernels, its cells opening in pyvista
and scipy, and the example script."""

import importlib.util
import os
import pathlib
import shutil
import subprocess
import sys

import numpy as np
import pytest

import cvd
from helpers import CI, need

PYTHON_DIR = pathlib.Path(__file__).resolve().parent.parent



def test_the_wheel_runs_where_there_is_no_rust():
    if os.environ.get("CVD_TEST_INSTALLED") != "1":
        if CI:
            pytest.fail("CI=true but the tests do not run on the installed wheel (cargo xtask test-python)")
        pytest.skip("not run on the installed wheel (cargo xtask test-python does)")
    if os.environ.get("CVD_TEST_NO_RUST") == "1":  # else the system's own folders hold it
        assert shutil.which("cargo") is None and shutil.which("rustc") is None
    # The installed package, not the sources beside these tests.
    assert PYTHON_DIR not in pathlib.Path(cvd.__file__).resolve().parents, cvd.__file__
    assert cvd.KERNELS, "cargo xtask test-python installs the wheel with the kernels"
    mesh = cvd.builtin("joint", 12)
    cells = cvd.clipped_voronoi(mesh, cvd.sample(mesh, 300, seed=1), backend="cpu")
    assert abs(cells.volume.sum() - mesh.volume) <= 1e-7 * mesh.volume


def build_backend():
    spec = importlib.util.spec_from_file_location("cvd_build", PYTHON_DIR / "build_backend" / "cvd_build.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize(
    "tools, asked, settings, built",
    [
        (True, None, {}, True),  # spirv-tools here, nothing asked: the kernels
        (False, None, {}, False),  # none here: the CPU backend only
        (True, "0", {}, False),  # told not to
        (False, "0", {}, False),
        (True, None, {"kernels": "no"}, False),  # pip -C kernels=no
        (True, "1", {}, True),
        (True, None, {"kernels": "yes", "build-args": "--locked"}, True),
    ],
)
def test_the_build_decides_about_the_kernels(monkeypatch, capsys, tools, asked, settings, built):
    b = build_backend()
    monkeypatch.setattr(b.shutil, "which", lambda t: None if t.startswith("spirv") and not tools else "/bin/" + t)
    monkeypatch.delenv("MATURIN_PEP517_ARGS", raising=False)
    if asked is None:
        monkeypatch.delenv("CVD_KERNELS", raising=False)
    else:
        monkeypatch.setenv("CVD_KERNELS", asked)
    out = b._configure(settings) or {}
    args = os.environ.get("MATURIN_PEP517_ARGS", "") + " " + str(out.get("build-args", ""))
    assert ("--features vulkan" in args) == built, args
    assert "kernels" not in out
    if "build-args" in settings:
        assert "--locked" in out["build-args"]
    line = capsys.readouterr().err.strip()
    assert line.startswith("cvd: building " + ("with" if built else "without")), line
    assert ("CVD_KERNELS=0" if built else "CVD_KERNELS=1") in line, line


@pytest.mark.parametrize(
    "missing, asked, message",
    [
        ("spirv", "1", "sudo xtask/install-deps build"),  # asked, cannot: the one command
        ("cargo", None, "rustup"),  # no Rust: where to get it
    ],
)
def test_the_build_stops_at_once_naming_what_to_run(monkeypatch, capsys, missing, asked, message):
    b = build_backend()
    monkeypatch.setattr(b.shutil, "which", lambda t: None if t.startswith(missing) else "/bin/" + t)
    if asked is None:
        monkeypatch.delenv("CVD_KERNELS", raising=False)
    else:
        monkeypatch.setenv("CVD_KERNELS", asked)
    with pytest.raises(SystemExit):
        b._configure({})
    assert message in capsys.readouterr().err


def test_a_bad_kernels_value_is_refused(monkeypatch, capsys):
    b = build_backend()
    monkeypatch.setenv("CVD_KERNELS", "maybe")
    with pytest.raises(SystemExit):
        b._configure({})
    assert "CVD_KERNELS='maybe': expected yes or no" in capsys.readouterr().err


@pytest.fixture(scope="module")
def cells():
    mesh = cvd.builtin("joint", 12)
    return cvd.clipped_voronoi(mesh, cvd.sample(mesh, 400, seed=6), backend="cpu", faces=True, polyhedra=True)


def test_to_pyvista_gives_the_cells_with_their_data(cells):
    need("pyvista")
    grid = cells.to_pyvista()
    sites = np.asarray(grid.cell_data["site"])
    assert grid.n_cells == len(cells.polyhedra) == len(sites) and len(sites) > 0
    assert (grid.celltypes == 42).all()
    # VTK's own measure of each polyhedron (its faces as VTK reads them,
    # closed and outward: the volume they enclose; the cells near the
    # joint's concave edges are not convex, which VTK's cell-size filter
    # assumes) against the cell's volume.
    def surface(cell):
        try:
            return cell.extract_surface(algorithm="dataset_surface")
        except TypeError:  # a pyvista before the `algorithm` keyword
            return cell.extract_surface()

    vtk_volume = np.array([surface(grid.extract_cells(i)).triangulate().volume for i in range(grid.n_cells)])
    rel = np.abs(vtk_volume / cells.volume[sites] - 1)
    assert rel.max() <= 2e-6, rel.max()
    assert np.array_equal(grid.cell_data["volume"], cells.volume[sites])
    assert np.array_equal(grid.cell_data["centroid"], cells.centroid[sites])
    offsets = cells.adjacency["offsets"]
    assert np.array_equal(grid.cell_data["neighbors"], np.diff(offsets)[sites])
    assert (np.asarray(grid.cell_data["area"]) > 0).all()


def test_adjacency_matrix_is_the_shared_areas(cells):
    need("scipy")
    m = cells.adjacency_matrix()
    a = cells.adjacency
    n = len(cells.volume)
    assert m.shape == (n, n) and m.nnz == len(a["neighbors"])
    assert abs(m - m.T).max() == 0  # each face's area is the same from both sides
    assert m.diagonal().max() == 0
    i = 17
    row = slice(a["offsets"][i], a["offsets"][i + 1])
    for j, area in zip(a["neighbors"][row], a["areas"][row]):
        assert m[i, j] == area


def test_helpers_say_what_they_need():
    mesh = cvd.builtin("cube", 2)
    bare = cvd.clipped_voronoi(mesh, cvd.sample(mesh, 20), backend="cpu")
    with pytest.raises(ValueError, match="polyhedra=True"):
        bare.to_pyvista()
    with pytest.raises(ValueError, match="faces=True"):
        bare.adjacency_matrix()


def test_the_stl_example_draws_the_cells(tmp_path):
    trimesh = need("trimesh")
    need("matplotlib")
    stl = tmp_path / "torus.stl"
    trimesh.creation.torus(major_radius=1.0, minor_radius=0.4).export(stl)
    picture = tmp_path / "cells.png"
    run = subprocess.run(
        [sys.executable, str(PYTHON_DIR / "examples" / "stl_cvt.py"), str(stl), "300", "5", str(picture)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert run.returncode == 0, run.stderr
    assert "volumes add up to" in run.stdout and picture.stat().st_size > 10_000
