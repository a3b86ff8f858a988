"""Reads a pieces.vtu with meshio, apart from the library that wrote it,
and prints as JSON the piece count, the total volume and each site's
volume, every volume computed here from the polyhedra's faces."""

import json
import sys

import meshio
import numpy as np

mesh = meshio.read(sys.argv[1])
volumes = []
for block in mesh.cells:
    if not block.type.startswith("polyhedron"):
        sys.exit(f"unexpected cell type {block.type}")
    for faces in block.data:
        # Divergence theorem: each face fanned from its first corner.
        six = 0.0
        for face in faces:
            p = mesh.points[face]
            for i in range(1, len(p) - 1):
                six += np.dot(p[0], np.cross(p[i], p[i + 1]))
        volumes.append(six / 6.0)
sites = np.concatenate(mesh.cell_data["site"]) if volumes else []
per_site = {}
for site, volume in zip(sites, volumes):
    per_site[int(site)] = per_site.get(int(site), 0.0) + volume
print(json.dumps({"pieces": len(volumes), "volume": sum(volumes), "sites": per_site}))
