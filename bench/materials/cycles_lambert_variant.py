"""Cycles render of a materials room with every Principled BSDF made Lambert (Specular IOR
Level 0, Metallic 0, Roughness 1; base colours, textures and normal maps kept), where the
glTF and Principled models agree: what is left between photongrid and Cycles is transport, not
model. The references' Cycles settings (render_refs.setup_cycles), seed 1, 320x240.

    $PY bench/materials/cycles_lambert_variant.py out/materials/blend/mat_punctual.blend OUT.exr 256 [flat]

`flat` also unlinks every Normal input (no normal maps).

photongrid's side: `python3 bench/materials/room_regions.py lambert SCENE OUT.glb` writes the
same change into the exported GLB (KHR_materials_specular 0, metallic 0, roughness 1, no
metallicRoughness texture), as Blender's exporter writes a Principled BSDF with those inputs.
"""
import os
import sys
import types

import bpy

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.modules.setdefault("OpenEXR", types.ModuleType("OpenEXR"))  # the bpy venv may lack it; unused here
import render_refs  # noqa: E402

flat = sys.argv[-1] == "flat"
blend, out, spp = sys.argv[-4:-1] if flat else sys.argv[-3:]
bpy.ops.wm.open_mainfile(filepath=blend)
sc = bpy.context.scene
for m in bpy.data.materials:
    if not m.use_nodes:
        continue
    for n in m.node_tree.nodes:
        if n.type != "BSDF_PRINCIPLED":
            continue
        if flat:
            for link in list(n.inputs["Normal"].links):
                m.node_tree.links.remove(link)
        for name, value in (("Specular IOR Level", 0.0), ("Metallic", 0.0), ("Roughness", 1.0)):
            sock = n.inputs[name]
            for link in list(sock.links):
                m.node_tree.links.remove(link)
            sock.default_value = value
render_refs.setup_cycles(sc, int(spp), 1, threads=2)
sc.render.resolution_x, sc.render.resolution_y, sc.render.resolution_percentage = 320, 240, 100
sc.render.filepath = out
bpy.ops.render.render(write_still=True)
