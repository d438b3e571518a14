# Blender side of scripts/check_interop.py (runs inside Blender, any 3.x):
#   blender --background --factory-startup --python-exit-code 3 \
#           --python scripts/check_interop_blender.py -- FILE RESULT.json FACE...
# Imports FILE (.ply, .glb or .obj) with Blender's own importer and writes the
# vertex and face counts, the colour attributes and, for the given faces, each
# corner's colour as sRGB (display) values into RESULT.json.
import json
import os
import sys

import bpy

args = sys.argv[sys.argv.index("--") + 1:]
path, result_path, faces = args[0], args[1], [int(f) for f in args[2:]]

bpy.ops.wm.read_factory_settings(use_empty=True)
ext = os.path.splitext(path)[1].lower()
if ext == ".ply":
    bpy.ops.import_mesh.ply(filepath=path)
elif ext in (".glb", ".gltf"):
    # Blender 3.4's glTF importer still says np.bool, which NumPy 1.24 (Debian
    # 12's python3-numpy) removed; the alias meant the builtin.
    import numpy
    if not hasattr(numpy, "bool"):
        numpy.bool = bool
    bpy.ops.import_scene.gltf(filepath=path)
elif ext == ".obj":
    # The C++ importer (3.2+; reads "v x y z r g b" colours from 3.4 on); the
    # older Python add-on where it is missing (bpy.ops.wm.<name> exists for
    # any name; dir() lists the registered operators).
    if "obj_import" in dir(bpy.ops.wm):
        bpy.ops.wm.obj_import(filepath=path)
    else:
        bpy.ops.import_scene.obj(filepath=path)
else:
    raise SystemExit(f"{path}: unknown extension {ext}")

meshes = [o.data for o in bpy.context.scene.objects if o.type == "MESH"]
out = {"objects": len(meshes), "faces": sum(len(m.polygons) for m in meshes),
       "vertices": sum(len(m.vertices) for m in meshes), "colour_attributes": []}
if meshes:
    mesh = meshes[0]
    out["colour_attributes"] = [[a.name, a.data_type, a.domain] for a in mesh.color_attributes]
    if len(mesh.color_attributes):
        attr = mesh.color_attributes[0]
        colours = {}
        for f in faces:
            if f >= len(mesh.polygons):
                continue
            corners = []
            for loop in mesh.polygons[f].loop_indices:
                i = loop if attr.domain == "CORNER" else mesh.loops[loop].vertex_index
                corners.append(list(attr.data[i].color_srgb))
            colours[str(f)] = corners
        out["colours_srgb"] = colours

with open(result_path, "w") as f:
    json.dump(out, f)
