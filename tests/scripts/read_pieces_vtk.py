"""Reads a pieces.vtu, or a pieces.pvtu of them, with VTK and prints as
JSON what VTK sees: the number of points, and each piece's site, tet,
stored volume and number of faces. Usage: read_pieces_vtk.py pieces.pvtu"""

import json
import sys

import vtk
from vtk.util.numpy_support import vtk_to_numpy

parallel = sys.argv[1].endswith(".pvtu")
reader = vtk.vtkXMLPUnstructuredGridReader() if parallel else vtk.vtkXMLUnstructuredGridReader()
reader.SetFileName(sys.argv[1])
reader.Update()
grid = reader.GetOutput()
data = grid.GetCellData()
site, tet, volume = (vtk_to_numpy(data.GetArray(name)) for name in ("site", "tet", "volume"))
pieces = []
for i in range(grid.GetNumberOfCells()):
    cell = grid.GetCell(i)
    assert cell.GetCellType() == vtk.VTK_POLYHEDRON, cell.GetCellType()
    pieces.append([int(site[i]), int(tet[i]), float(volume[i]), cell.GetNumberOfFaces()])
print(json.dumps({"points": grid.GetNumberOfPoints(), "pieces": pieces}))
