"""Particles in periodic cells, as molecular-dynamics users meet them:
triclinic cells and walls against voro++ (through pyvoro2), the per-atom
quantities against OVITO's Voronoi analysis, and freud's boxes accepted as
they are. The tools come from the package registry; without them the
tests skip (and fail under CI=true)."""

import os

import numpy as np
import pytest

import cvd

CI = os.environ.get("CI") == "true"


def need(module):
    """`module`, or a skip with the reason (a failure under CI=true)."""
    try:
        return __import__(module)
    except ImportError:
        if CI:
            pytest.fail(f"CI=true but {module} is not installed (python3 -m pip install {module})")
        pytest.skip(f"{module} is not installed")


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
