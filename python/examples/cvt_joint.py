"""A centroidal Voronoi tessellation of the built-in joint, from Python.

    python python/examples/cvt_joint.py [sites] [iterations]

Prints the energy per iteration; with matplotlib installed, plots it and
the sites near the middle plane (cvt_joint.png).
"""

import sys

import numpy as np

import cvd

n = int(sys.argv[1]) if len(sys.argv) > 1 else 5000
iterations = int(sys.argv[2]) if len(sys.argv) > 2 else 30

mesh = cvd.builtin("joint")
print(mesh, "quality:", mesh.quality())
sites = cvd.sample(mesh, n, seed=1)
sites, history = cvd.lloyd(mesh, sites, iterations)
for i, e in enumerate(history["energy"]):
    print(f"iteration {i}: energy {e:.6e}")
cells = cvd.clipped_voronoi(mesh, sites, faces=True)
print(f"{n} cells, volumes add up to {cells.volume.sum():.6f} of {mesh.volume:.6f} (E_vol {cells.e_vol:.1e})")
print("neighbours per cell:", np.diff(cells.adjacency["offsets"]).mean())

try:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
except ImportError:
    sys.exit(0)
fig, (a, b) = plt.subplots(1, 2, figsize=(11, 5))
a.semilogy(history["energy"])
a.set_xlabel("iteration")
a.set_ylabel("CVT energy")
mid = 0.5 * (mesh.vertices[:, 2].min() + mesh.vertices[:, 2].max())
near = np.abs(sites[:, 2] - mid) < 0.02
b.scatter(sites[near, 0], sites[near, 1], s=2, c=cells.volume[near])
b.set_aspect("equal")
b.set_title("sites near the middle plane, by cell volume")
fig.savefig("cvt_joint.png", dpi=120)
print("wrote cvt_joint.png")
