"""cvd: clipped Voronoi diagrams and centroidal Voronoi tessellations of tet
meshes, on Vulkan GPUs and CPU cores, from numpy.

    import cvd
    mesh = cvd.builtin("joint")
    sites = cvd.sample(mesh, 20000, seed=1)
    cells = cvd.clipped_voronoi(mesh, sites)
    print(cells.volume.sum(), mesh.volume, cells.e_vol)
    sites, history = cvd.lloyd(mesh, sites, 50)

Arrays may be of any float dtype and layout (converted to C-contiguous
float64 once); results are owned numpy arrays. Errors in the input raise
ValueError (naming the file and line, or the array and row); others
RuntimeError.
"""

import numpy as _np

from . import _cvd
from ._cvd import KERNELS, Cells, Mesh, builtin, devices, mesh_surface, read_mesh

__all__ = [
    "KERNELS",
    "Cells",
    "Mesh",
    "builtin",
    "clipped_voronoi",
    "devices",
    "lloyd",
    "mesh_surface",
    "ParticleCells",
    "particle_voronoi",
    "ParticleVoronoi",
    "periodic_voronoi",
    "read_mesh",
    "sample",
    "transport",
]


def _points(a, name):
    """`a` as a C-contiguous float64 (n, 3) array, or ValueError."""
    try:
        a = _np.ascontiguousarray(a, dtype=_np.float64)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{name} must be an (n, 3) array of numbers: {e}") from None
    if a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"{name} must have shape (n, 3), not {a.shape}")
    if a.shape[0] == 0:
        raise ValueError(f"{name} is empty")
    return a


def _values(a, name):
    if a is None:
        return None
    a = _np.ascontiguousarray(a, dtype=_np.float64)
    if a.ndim != 1:
        raise ValueError(f"{name} must be a 1-d array, not of shape {a.shape}")
    return a


def sample(mesh, n, seed=1):
    """`n` sites uniform in `mesh`, an (n, 3) float64 array."""
    if n < 0:
        raise ValueError(f"n must be at least 0, not {n}")
    return _cvd.sample(mesh, int(n), int(seed))


def clipped_voronoi(
    mesh,
    sites,
    *,
    backend="auto",
    strategy="auto",
    pairing="auto",
    density=None,
    faces=False,
    polyhedra=False,
    weights=None,
    memory_budget=None,
):
    """The Voronoi cells of `sites` ((n, 3)) clipped to `mesh`.

    backend: "auto" (a GPU if there is one, else the CPU), "cpu" or "vulkan".
    strategy: "auto" (whole cells on the CPU, tet-cell under a density or
    on Vulkan), "whole", "tet-cell" or "cell-tet"; pairing: "auto",
    "flood" or "knn" (tet-cell and cell-tet).
    density: one value per mesh vertex (linear in each tet), or None.
    faces: also the adjacency (`cells.adjacency`: CSR arrays of the faces
    the cells share, their areas and normals, each cell's boundary area).
    polyhedra: also each cell as one closed polyhedron (`cells.polyhedra`).
    weights: one per site for power (Laguerre) cells: site i's cell is where
    |x - x_i|² - w_i is least (cells may be empty), or None.
    memory_budget: most bytes the job may hold (default: the memory the
    machine has available); a larger job raises MemoryError before
    anything is allocated, naming both numbers.

    Returns a Cells with numpy arrays `volume`, `centroid`, `energy`, and
    `e_vol`, `mesh_volume`, `counters`, `timings`.
    """
    return _cvd.clipped_voronoi(
        mesh,
        _points(sites, "sites"),
        backend,
        strategy,
        pairing,
        _values(density, "density"),
        bool(faces),
        bool(polyhedra),
        _values(weights, "weights"),
        _budget(memory_budget),
    )


def periodic_voronoi(sites, lo, hi, *, backend="auto", faces=False, weights=None, memory_budget=None):
    """The cells of `sites` ((n, 3)) in the periodic box `lo..hi` (three
    numbers each): each site's Voronoi cell (power cell with `weights`) in
    the space the box tiles, cut into the box. Sites outside the box are
    wrapped into it.

    Returns (cells, wrapped_sites): a Cells as clipped_voronoi's (centroids
    wrapped into the box, energies about each site; with faces=True the
    adjacency also has `shifts`, an (m, 3) int array: the face is shared
    with that neighbour's image, its site plus that many box lengths, and
    there is no boundary), and the sites wrapped, an (n, 3) array.
    memory_budget: as clipped_voronoi's.
    """
    lo = [float(x) for x in lo]
    hi = [float(x) for x in hi]
    if len(lo) != 3 or len(hi) != 3:
        raise ValueError(f"lo and hi must have three numbers each, not {len(lo)} and {len(hi)}")
    return _cvd.periodic_voronoi(
        _points(sites, "sites"), lo, hi, backend, bool(faces), _values(weights, "weights"), _budget(memory_budget)
    )


def _budget(memory_budget):
    """A memory budget in bytes, checked (None: the memory available)."""
    if memory_budget is None:
        return None
    b = int(memory_budget)
    if b <= 0:
        raise ValueError(f"memory_budget must be a positive number of bytes, not {memory_budget}")
    return b


def _cell(box, origin):
    """(origin, vectors) of a cell given as lattice vectors ((3, 3), rows a,
    b, c), lengths (Lx, Ly, Lz), lengths and LAMMPS tilts (Lx, Ly, Lz, xy,
    xz, yz; lengths, not freud's factors), or a freud.box.Box (centred on
    0, as freud's are)."""
    if hasattr(box, "to_matrix"):
        vectors = _np.asarray(box.to_matrix(), dtype=_np.float64).T
        centre = -0.5 * vectors.sum(axis=0)
        return (centre if origin is None else _np.asarray(origin, dtype=_np.float64)), vectors
    b = _np.asarray(box, dtype=_np.float64)
    if b.shape == (3, 3):
        vectors = b
    elif b.shape == (3,):
        vectors = _np.diag(b)
    elif b.shape == (6,):
        lx, ly, lz, xy, xz, yz = b
        vectors = _np.array([[lx, 0.0, 0.0], [xy, ly, 0.0], [xz, yz, lz]])
    else:
        raise ValueError(
            f"box must be lattice vectors (3, 3), lengths (3,), or lengths and tilts (6,), not of shape {b.shape}"
        )
    o = _np.zeros(3) if origin is None else _np.asarray(origin, dtype=_np.float64)
    if o.shape != (3,):
        raise ValueError(f"origin must have three numbers, not shape {o.shape}")
    return o, vectors


class ParticleCells:
    """The cells of particles in a periodic cell (see particle_voronoi).

    Arrays, one row per particle in input order: `volumes`, `centroids`
    (wrapped into the cell), `areas` (surface, walls included),
    `neighbor_counts` (particles sharing a face), and with the index
    `coordination` (faces counted above the thresholds, walls included, as
    OVITO's), `voronoi_index` ((n, 8): faces with 3, 4, ..., 10 or more
    edges) and `max_face_order`. `points`: the particles wrapped into the
    cell. `adjacency`: CSR arrays `offsets`, `neighbors`, `areas`,
    `normals`, `shifts` (lattice vectors to the neighbour's image) and
    `boundary` (area on the walls). `cells`: the underlying Cells
    (`counters`, `timings`, `polyhedra` when asked for). `reused`: cells
    built from the last frame's neighbours (ParticleVoronoi).
    """

    def __init__(self, cells, points, particles, origin, vectors, periodic):
        self.cells = cells
        self.points = points
        self.volumes = cells.volume
        self.centroids = cells.centroid
        self.adjacency = cells.adjacency
        self.neighbor_counts = None if self.adjacency is None else _np.diff(self.adjacency["offsets"])
        if particles is not None:
            self.areas = particles["area"]
            self.coordination = particles["coordination"]
            self.voronoi_index = particles["voronoi_index"]
            self.max_face_order = particles["max_face_order"]
        else:
            self.areas = None
            if self.adjacency is not None:
                n = len(self.volumes)
                rows = _np.repeat(_np.arange(n), self.neighbor_counts)
                self.areas = _np.bincount(rows, weights=self.adjacency["areas"], minlength=n) + self.adjacency["boundary"]
            self.coordination = self.voronoi_index = self.max_face_order = None
        self.origin = origin
        self.vectors = vectors
        self.periodic = periodic
        self.reused = 0

    def neighbor_pairs(self):
        """The shared faces as arrays (i, j, area, shift): particle i's cell
        shares a face of `area` with particle j's image `shift` lattice
        vectors away, each face once from each side (freud's nlist with
        weights)."""
        a = self.adjacency
        if a is None:
            raise ValueError("the faces were not computed (particle_voronoi(..., faces=True))")
        i = _np.repeat(_np.arange(len(a["offsets"]) - 1), self.neighbor_counts)
        return i, a["neighbors"], a["areas"], a["shifts"]

    def __repr__(self):
        return f"ParticleCells({len(self.volumes)} particles, periodic {tuple(self.periodic)})"


def particle_voronoi(points, box, *, origin=None, periodic=True, radii=None, **options):
    """The Voronoi cells of particles `points` ((n, 3)) in a periodic cell,
    as freud's and pyvoro2's users know them.

    box: lattice vectors ((3, 3), rows a, b, c; right-handed), lengths
    (Lx, Ly, Lz), lengths and LAMMPS's tilts (Lx, Ly, Lz, xy, xz, yz, as
    lengths: freud's tilt factors times Ly or Lz), or a freud.box.Box.
    origin: the cell's corner (default 0; a freud box: centred on 0).
    periodic: True, or a flag per axis (a, b, c): along the others the
    cell's faces are walls that cut the cells.
    radii: one per particle for radical (power) cells, weights r², as
    voro++; or None.
    voronoi_index: also each cell's coordination, Voronoi index and largest
    face order, counting edges and faces above the thresholds as OVITO's
    Voronoi analysis does (edge: length, relative_edge: times the cell's
    V^(1/3); face: area, relative_face: fraction of the cell's surface).
    polyhedra: also each cell's polyhedron (`result.cells.polyhedra`).
    faces: the shared faces (`adjacency`, `neighbor_counts`, `areas`);
    with faces=False and voronoi_index=False, the volumes and centroids
    alone (the least work).

    The options (voronoi_index=True, edge_threshold=0.0,
    relative_edge_threshold=0.0, face_threshold=0.0,
    relative_face_threshold=0.0, polyhedra=False, faces=True,
    backend="auto", memory_budget=None: as clipped_voronoi's) are
    ParticleVoronoi's.

    Returns a ParticleCells. For the frames of a trajectory, see
    ParticleVoronoi: each frame starts from the last one's neighbours.
    """
    if "reuse" in options:
        raise TypeError("particle_voronoi() computes one frame: for reuse between frames, use ParticleVoronoi")
    return ParticleVoronoi(reuse=False, **options).compute(points, box, origin=origin, periodic=periodic, radii=radii)


class ParticleVoronoi:
    """The cells of a trajectory's frames, one compute() per frame, as
    freud's Voronoi is used: the options (those of particle_voronoi) once,
    then `compute(points, box, origin=, periodic=, radii=)` per frame,
    which returns a ParticleCells.

    With reuse=True (the default) each frame keeps its particles' nearest
    neighbours (about 300 bytes per particle) and the next one starts from
    them: where the particles' largest displacement since still certifies
    a particle's list, no neighbour search is made for it. The cells are
    those of a frame computed afresh, bit for bit; `result.reused` (and
    `self.reused`) counts the cells built so. Lists are kept on the CPU
    backend; a frame with other particles, radii or another cell starts
    afresh.
    """

    def __init__(
        self,
        *,
        voronoi_index=True,
        edge_threshold=0.0,
        relative_edge_threshold=0.0,
        face_threshold=0.0,
        relative_face_threshold=0.0,
        polyhedra=False,
        faces=True,
        backend="auto",
        reuse=True,
        memory_budget=None,
    ):
        self.voronoi_index = bool(voronoi_index)
        self.thresholds = (
            float(edge_threshold),
            float(relative_edge_threshold),
            float(face_threshold),
            float(relative_face_threshold),
        )
        self.polyhedra = bool(polyhedra)
        self.faces = bool(faces)
        self.backend = backend
        self.reuse = bool(reuse)
        self.memory_budget = _budget(memory_budget)
        self.reused = 0
        self._lists = None

    def compute(self, points, box, *, origin=None, periodic=True, radii=None):
        """The cells of one frame (see particle_voronoi for the
        arguments); returns a ParticleCells."""
        o, vectors = _cell(box, origin)
        flags = (bool(periodic),) * 3 if _np.ndim(periodic) == 0 else tuple(bool(p) for p in periodic)
        if len(flags) != 3:
            raise ValueError(f"periodic must be one flag or three, not {len(flags)}")
        cells, wrapped, particles, lists, reused = _cvd.particle_voronoi(
            _points(points, "points"),
            [float(x) for x in o],
            [[float(x) for x in row] for row in vectors],
            list(flags),
            _values(radii, "radii"),
            self.backend,
            self.voronoi_index,
            self.thresholds,
            self.polyhedra,
            self.faces,
            self.reuse,
            self._lists if self.reuse else None,
            self.memory_budget,
        )
        self._lists = lists
        self.reused = reused
        result = ParticleCells(cells, wrapped, particles, o, vectors, flags)
        result.reused = reused
        return result

    def __repr__(self):
        return f"ParticleVoronoi(reuse={self.reuse}, last frame reused {self.reused} cells)"


def lloyd(mesh, sites, iterations, *, optimizer="lloyd", backend="auto", density=None, progress=False):
    """`iterations` steps of Lloyd's method ("lloyd") or L-BFGS ("lbfgs")
    from `sites`. Returns (sites, history), history a dict of arrays
    `energy` (of the diagram each iteration started from) and
    `empty_cells`. Ctrl-C stops it between iterations."""
    if iterations < 0:
        raise ValueError(f"iterations must be at least 0, not {iterations}")
    return _cvd.lloyd(
        mesh, _points(sites, "sites"), int(iterations), optimizer, backend, _values(density, "density"), bool(progress)
    )


def transport(
    mesh,
    sites,
    capacities=None,
    *,
    backend="auto",
    density=None,
    weights=None,
    tolerance=1e-6,
    max_steps=50,
    return_record=False,
):
    """The power weights for which every cell of `sites` in `mesh` gets its
    target mass: the mesh's volume (or mass under `density`) over the sites,
    or `capacities` (one per site, positive) scaled to it. Damped Newton
    steps from `weights` (default 0: the Voronoi cells) until every cell is
    within `tolerance` of its target, relative to it.

    Returns the weights, an (n,) array (mean 0); with return_record=True,
    (weights, record), record a dict with `max_error` (per diagram the
    steps started from, the last the final error), `step`, `cg_iterations`
    and `seconds` (per Newton step), `converged`, and `stopped` (what
    stopped the solve). A solve that does not
    reach the tolerance warns (RuntimeWarning). Ctrl-C stops it between
    steps.
    """
    if max_steps < 0:
        raise ValueError(f"max_steps must be at least 0, not {max_steps}")
    w, record = _cvd.transport(
        mesh,
        _points(sites, "sites"),
        _values(capacities, "capacities"),
        backend,
        _values(density, "density"),
        _values(weights, "weights"),
        float(tolerance),
        int(max_steps),
    )
    if not record["converged"]:
        import warnings

        warnings.warn(
            f"transport: the masses came within {record['max_error'][-1]:.2e} of their targets, not {tolerance:.0e}: "
            f"{record['stopped']}",
            RuntimeWarning,
            stacklevel=2,
        )
    return (w, record) if return_record else w
