"""Reads a Medit .mesh with meshio and writes it again with VTK's own XML
writer (the `vtk` package from PyPI, what ParaView uses): appended raw
binary (ParaView's default), appended base64 and inline base64, each with
and without zlib, with 32- and 64-bit headers. Prints the paths as JSON."""

import json
import os
import sys

import meshio
import numpy as np
import vtk
from vtk.util import numpy_support

source, out = sys.argv[1], sys.argv[2]
os.makedirs(out, exist_ok=True)
mesh = meshio.read(source)
tets = mesh.get_cells_type("tetra").astype(np.int64)

points = vtk.vtkPoints()
points.SetData(numpy_support.numpy_to_vtk(np.ascontiguousarray(mesh.points, dtype=np.float64), deep=True))
cells = vtk.vtkCellArray()
offsets = numpy_support.numpy_to_vtkIdTypeArray(np.arange(0, 4 * len(tets) + 1, 4, dtype=np.int64), deep=True)
connectivity = numpy_support.numpy_to_vtkIdTypeArray(np.ascontiguousarray(tets.ravel()), deep=True)
cells.SetData(offsets, connectivity)
grid = vtk.vtkUnstructuredGrid()
grid.SetPoints(points)
grid.SetCells(vtk.VTK_TETRA, cells)

written = {}
for name, (mode, base64, zlib, header64) in {
    "appended_raw_zlib.vtu": ("appended", False, True, False),
    "appended_raw.vtu": ("appended", False, False, True),
    "appended_base64_zlib.vtu": ("appended", True, True, True),
    "appended_base64.vtu": ("appended", True, False, False),
    "inline_base64_zlib.vtu": ("binary", True, True, False),
}.items():
    writer = vtk.vtkXMLUnstructuredGridWriter()
    path = os.path.join(out, name)
    writer.SetFileName(path)
    writer.SetInputData(grid)
    if mode == "appended":
        writer.SetDataModeToAppended()
    else:
        writer.SetDataModeToBinary()
    writer.SetEncodeAppendedData(base64)
    if zlib:
        writer.SetCompressorTypeToZLib()
    else:
        writer.SetCompressorTypeToNone()
    if header64:
        writer.SetHeaderTypeToUInt64()
    else:
        writer.SetHeaderTypeToUInt32()
    if not writer.Write():
        sys.exit(f"vtk could not write {path}")
    written[name] = path
print(json.dumps(written))
