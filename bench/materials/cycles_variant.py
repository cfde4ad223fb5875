"""Cycles render of an isolating variant of a materials room (README "Normal-map handedness"):
every mesh object not in KEEP gets a black material (base 0, Specular IOR Level 0), lights not
in LIGHTS are hidden; the references' Cycles settings (render_refs.setup_cycles), seed 1.

    $PY bench/materials/cycles_variant.py out/materials/blend/mat_punctual.blend OUT.exr \\
        TexturedSphere PointLight,SpotLight 64      # ~30 s at 320x240 on one thread
"""
import os
import sys
import types

import bpy

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.modules.setdefault("OpenEXR", types.ModuleType("OpenEXR"))  # the bpy venv may lack it; unused here
import render_refs  # noqa: E402

blend, out, keep, lights, spp = sys.argv[-5:]
keep, lights = set(keep.split(",")), set(lights.split(","))
bpy.ops.wm.open_mainfile(filepath=blend)
sc = bpy.context.scene
black = bpy.data.materials.new("BlackVariant")
black.use_nodes = True
p = black.node_tree.nodes["Principled BSDF"]
p.inputs["Base Color"].default_value = (0, 0, 0, 1)
p.inputs["Specular IOR Level"].default_value = 0.0
for ob in sc.objects:
    if ob.type == "MESH" and ob.name not in keep:
        for s in ob.material_slots:
            s.material = black
    if ob.type == "LIGHT" and ob.name not in lights:
        ob.hide_render = True
render_refs.setup_cycles(sc, int(spp), 1, threads=1)
sc.render.resolution_x, sc.render.resolution_y, sc.render.resolution_percentage = 320, 240, 100
sc.render.filepath = out
bpy.ops.render.render(write_still=True)
