"""Cycles render of a materials scene with the microfacet distribution of its transmissive
Principled BSDFs set to DIST ('GGX': single scattering, as the glTF spec's rough dielectric;
'MULTI_GGX': Blender's default, as the references), the references' Cycles settings
(render_refs.setup_cycles), seed 1, 320x240: measures the model difference of rough glass
(README, "Rough glass: single against multiple scattering").

    $PY bench/materials/cycles_glass_distribution.py out/materials/blend/mat_leaves.blend OUT.exr GGX 256
"""
import os
import sys
import types

import bpy

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.modules.setdefault("OpenEXR", types.ModuleType("OpenEXR"))  # the bpy venv may lack it; unused here
import render_refs  # noqa: E402

blend, out, dist, spp = sys.argv[-4:]
bpy.ops.wm.open_mainfile(filepath=blend)
sc = bpy.context.scene
changed = []
for m in bpy.data.materials:
    if not m.use_nodes:
        continue
    for n in m.node_tree.nodes:
        if n.type == "BSDF_PRINCIPLED" and n.inputs["Transmission Weight"].default_value > 0:
            n.distribution = dist
            changed.append(m.name)
print("distribution", dist, "on", changed)
render_refs.setup_cycles(sc, int(spp), 1, threads=2)
sc.render.resolution_x, sc.render.resolution_y, sc.render.resolution_percentage = 320, 240, 100
sc.render.image_settings.file_format = "OPEN_EXR"
sc.render.image_settings.color_depth = "32"
sc.render.filepath = out
bpy.ops.render.render(write_still=True)
