"""Reads a Medit .mesh with meshio, apart from the library that wrote it,
and writes it again as legacy VTK (versions 4.2 and 5.1, ASCII and
binary), VTK XML .vtu (ASCII, raw binary, zlib), Medit binary .meshb and
Gmsh .msh (2.2 binary, 4.1 binary and ASCII);
plus a grid holding a hexahedron. Prints the written paths as JSON."""

import json
import os
import sys

import meshio
import numpy as np

source, out = sys.argv[1], sys.argv[2]
os.makedirs(out, exist_ok=True)
mesh = meshio.read(source)
tets = meshio.Mesh(mesh.points, [("tetra", mesh.get_cells_type("tetra"))])
written = {}
for name, options in {
    "v42_ascii.vtk": dict(file_format="vtk42", binary=False),
    "v42_binary.vtk": dict(file_format="vtk42", binary=True),
    "v51_ascii.vtk": dict(file_format="vtk", binary=False),
    "v51_binary.vtk": dict(file_format="vtk", binary=True),
    "medit.meshb": dict(file_format="medit"),
    "v22_binary.msh": dict(file_format="gmsh22", binary=True),
    "v41_binary.msh": dict(file_format="gmsh", binary=True),
    "v41_ascii.msh": dict(file_format="gmsh", binary=False),
    "ascii.vtu": dict(file_format="vtu", binary=False),
    "raw.vtu": dict(file_format="vtu", binary=True, compression=None),
    "zlib.vtu": dict(file_format="vtu", binary=True, compression="zlib"),
}.items():
    path = os.path.join(out, name)
    meshio.write(path, tets, **options)
    written[name] = path
hexa = meshio.Mesh(
    np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], dtype=float),
    [("hexahedron", np.array([[0, 1, 2, 3, 4, 5, 6, 7]]))],
)
path = os.path.join(out, "hexahedron.vtk")
meshio.write(path, hexa, file_format="vtk")
written["hexahedron"] = path
print(json.dumps(written))
