"""Writes closed surfaces with trimesh, apart from the library that reads
them, in every format it exports (STL binary and ASCII, OBJ, OFF, PLY
binary and ASCII), plus one open surface, two overlapping boxes and a sphere with a
crack; prints as JSON each shape's
files and the volume trimesh computes for it."""

import json
import os
import sys

import trimesh

out = sys.argv[1]
os.makedirs(out, exist_ok=True)
shapes = {
    "box": trimesh.creation.box(extents=[1.0, 2.0, 3.0]),
    "sphere": trimesh.creation.icosphere(subdivisions=3, radius=1.0),
    "cylinder": trimesh.creation.cylinder(radius=0.5, height=2.0, sections=48),
    "capsule": trimesh.creation.capsule(height=1.0, radius=0.4, count=[24, 24]),
    "torus": trimesh.creation.torus(major_radius=1.0, minor_radius=0.35, major_sections=48, minor_sections=24),
    # Non-convex with sharp edges: a thick ring.
    "annulus": trimesh.creation.annulus(r_min=0.3, r_max=0.8, height=0.5, sections=48),
}
formats = {
    "stl": dict(file_type="stl"),
    "ascii.stl": dict(file_type="stl_ascii"),
    "obj": dict(file_type="obj", include_normals=False, include_texture=False),
    "off": dict(file_type="off"),
    "ply": dict(file_type="ply", encoding="binary"),
    "ascii.ply": dict(file_type="ply", encoding="ascii"),
}
listing = {}
for name, mesh in shapes.items():
    assert mesh.is_watertight, name
    files = []
    for ext, options in formats.items():
        path = os.path.join(out, f"{name}.{ext}")
        mesh.export(path, **options)
        files.append(path)
    listing[name] = {"volume": float(mesh.volume), "files": files}
open_box = trimesh.creation.box(extents=[1.0, 1.0, 1.0])
open_box.update_faces([i != 0 for i in range(len(open_box.faces))])
open_path = os.path.join(out, "open_box.stl")
open_box.export(open_path, file_type="stl")
# An icosphere with one triangle missing: a crack 0.6 % of its size, and
# the same closed.
closed = trimesh.creation.icosphere(subdivisions=6, radius=1.0)
closed_path = os.path.join(out, "closed_sphere.stl")
closed.export(closed_path, file_type="stl")
cracked = closed.copy()
cracked.update_faces([i != 100 for i in range(len(cracked.faces))])
cracked_path = os.path.join(out, "cracked_sphere.stl")
cracked.export(cracked_path, file_type="stl")
# Two overlapping boxes left as two shells (a union not joined).
overlap = trimesh.util.concatenate(
    [trimesh.creation.box(extents=[1.0, 1.0, 1.0]),
     trimesh.creation.box(extents=[1.0, 1.0, 1.0]).apply_translation([0.43, 0.31, 0.27])]
)
overlap_path = os.path.join(out, "overlapping_boxes.stl")
overlap.export(overlap_path, file_type="stl")
print(json.dumps({"shapes": listing, "open": open_path, "overlapping": overlap_path,
                  "closed_sphere": closed_path, "cracked_sphere": cracked_path}))
