"""A centroidal Voronoi tessellation of a part given as an STL surface,
and a picture of its cells.

    python python/examples/stl_cvt.py part.stl [sites] [iterations] [picture.png]

Meshes the surface's inside with tets, samples the sites, runs Lloyd's
method, then computes the cells as polyhedra. With pyvista installed the
picture shows the cells (shrunk a little, coloured by volume) rendered off
screen, and the cells are also saved as cells.vtu beside it; otherwise,
with matplotlib, the sites near the middle plane.
"""

import os
import sys

import numpy as np

import cvd

if len(sys.argv) < 2:
    sys.exit(__doc__)
path = sys.argv[1]
n = int(sys.argv[2]) if len(sys.argv) > 2 else 2000
iterations = int(sys.argv[3]) if len(sys.argv) > 3 else 20
picture = sys.argv[4] if len(sys.argv) > 4 else "cells.png"

mesh = cvd.mesh_surface(path)
print(f"{path}: {mesh}")
sites, history = cvd.lloyd(mesh, cvd.sample(mesh, n, seed=1), iterations)
print(f"CVT energy {history['energy'][0]:.4e} -> {history['energy'][-1]:.4e} in {iterations} iterations")
cells = cvd.clipped_voronoi(mesh, sites, faces=True, polyhedra=True)
print(f"{n} cells, volumes add up to {cells.volume.sum():.6g} of {mesh.volume:.6g}")

try:
    import pyvista as pv
except ImportError:
    pv = None
if pv is not None:
    grid = cells.to_pyvista()
    grid.save(os.path.join(os.path.dirname(os.path.abspath(picture)), "cells.vtu"))
    plotter = pv.Plotter(off_screen=True, window_size=(800, 600))
    plotter.add_mesh(grid.shrink(0.85), scalars="volume", show_edges=True)
    plotter.screenshot(picture)
else:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 6))
    mid = 0.5 * (mesh.vertices[:, 2].min() + mesh.vertices[:, 2].max())
    near = np.abs(sites[:, 2] - mid) < 0.05 * np.ptp(mesh.vertices[:, 2])
    ax.scatter(sites[near, 0], sites[near, 1], s=4, c=cells.volume[near])
    ax.set_aspect("equal")
    fig.savefig(picture, dpi=100)
print(f"wrote {picture}")
