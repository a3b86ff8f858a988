"""Reads a cells.vtu (or a cells.pvtu of pieces) with VTK and prints, as JSON, what VTK sees: the
number of cells, each cell's site and stored volume, and its volume as
VTK's own vtkMassProperties measures it on the cell's faces (triangulated
by vtkTriangleFilter). Usage: read_cells_vtu.py cells.vtu"""

import json
import sys

import vtk
from vtk.util.numpy_support import vtk_to_numpy

if sys.argv[1].endswith(".pvtu"):
    reader = vtk.vtkXMLPUnstructuredGridReader()
else:
    reader = vtk.vtkXMLUnstructuredGridReader()
reader.SetFileName(sys.argv[1])
reader.Update()
grid = reader.GetOutput()
data = grid.GetCellData()
site = vtk_to_numpy(data.GetArray("site"))
stored = vtk_to_numpy(data.GetArray("volume"))
neighbors = vtk_to_numpy(data.GetArray("neighbors"))
cells = []
for i in range(grid.GetNumberOfCells()):
    cell = grid.GetCell(i)
    assert cell.GetCellType() == vtk.VTK_POLYHEDRON, cell.GetCellType()
    local = {cell.GetPointId(k): k for k in range(cell.GetNumberOfPoints())}
    polys = vtk.vtkCellArray()
    for f in range(cell.GetNumberOfFaces()):
        face = cell.GetFace(f)
        polys.InsertNextCell(face.GetNumberOfPoints(), [local[face.GetPointId(k)] for k in range(face.GetNumberOfPoints())])
    surface = vtk.vtkPolyData()
    surface.SetPoints(cell.GetPoints())
    surface.SetPolys(polys)
    triangles = vtk.vtkTriangleFilter()
    triangles.SetInputData(surface)
    mass = vtk.vtkMassProperties()
    mass.SetInputConnection(triangles.GetOutputPort())
    mass.Update()
    cells.append(
        {
            "site": int(site[i]),
            "volume": float(stored[i]),
            "vtk_volume": mass.GetVolume(),
            "faces": cell.GetNumberOfFaces(),
            "neighbors": int(neighbors[i]),
        }
    )
print(json.dumps({"cells": cells, "points": grid.GetNumberOfPoints()}))
