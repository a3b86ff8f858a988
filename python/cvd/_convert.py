"""Cells as other Python libraries take them: a pyvista grid of the cells'
polyhedra, and the adjacency as a scipy sparse matrix. Reached through
`Cells.to_pyvista()` and `Cells.adjacency_matrix()`."""

import numpy as _np

# VTK's cell type of a polyhedron given by its faces.
_VTK_POLYHEDRON = 42


def _needs(module, why):
    try:
        return __import__(module)
    except ImportError:
        raise ImportError(f"{why} needs {module}: python -m pip install {module}") from None


def to_pyvista(cells):
    """The cells' polyhedra as a `pyvista.UnstructuredGrid`, one VTK
    polyhedron per cell with a volume, with cell data `site`, `volume`,
    `centroid`, `energy` and, when the faces were computed, `neighbors`
    (how many cells it shares a face with) and `area` (its surface)."""
    pv = _needs("pyvista", "Cells.to_pyvista()")
    if cells.polyhedra is None:
        raise ValueError("Cells.to_pyvista() needs the cells' polyhedra: compute them with polyhedra=True")
    points, stream, sites = [], [], []
    base = 0
    for p in cells.polyhedra:
        v = p["vertices"]
        faces = p["faces"]
        # A polyhedron's entry: its length, its face count, then each face
        # as its vertex count and vertex ids (into the grid's points).
        cell = [len(faces)]
        for f in faces:
            cell.append(len(f))
            cell.extend((_np.asarray(f) + base).tolist())
        stream.append(len(cell))
        stream.extend(cell)
        points.append(v)
        sites.append(p["site"])
        base += len(v)
    if not sites:
        return pv.UnstructuredGrid()
    grid = pv.UnstructuredGrid(
        _np.asarray(stream, dtype=_np.int64),
        _np.full(len(sites), _VTK_POLYHEDRON, dtype=_np.uint8),
        _np.concatenate(points).astype(_np.float64),
    )
    site = _np.asarray(sites, dtype=_np.int64)
    grid.cell_data["site"] = site
    grid.cell_data["volume"] = cells.volume[site]
    grid.cell_data["centroid"] = cells.centroid[site]
    grid.cell_data["energy"] = cells.energy[site]
    a = cells.adjacency
    if a is not None:
        offsets = a["offsets"]
        grid.cell_data["neighbors"] = (offsets[1:] - offsets[:-1])[site]
        rows = _np.repeat(_np.arange(len(offsets) - 1), offsets[1:] - offsets[:-1])
        area = _np.bincount(rows, weights=a["areas"], minlength=len(offsets) - 1) + a["boundary"]
        grid.cell_data["area"] = area[site]
    return grid


def adjacency_matrix(cells):
    """The adjacency as a `scipy.sparse.csr_array` (n, n): entry (i, j) the
    area of the face cells i and j share (symmetric; no diagonal)."""
    sparse = _needs("scipy", "Cells.adjacency_matrix()").sparse
    a = cells.adjacency
    if a is None:
        raise ValueError("Cells.adjacency_matrix() needs the cells' faces: compute them with faces=True")
    n = len(a["offsets"]) - 1
    if "shifts" in a:
        # A periodic box: one site may share several faces with one
        # neighbour (or with itself), summed here.
        rows = _np.repeat(_np.arange(n), a["offsets"][1:] - a["offsets"][:-1])
        return sparse.csr_array((a["areas"], (rows, a["neighbors"])), shape=(n, n))
    return sparse.csr_array((a["areas"], a["neighbors"], a["offsets"]), shape=(n, n))
