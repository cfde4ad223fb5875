#!/usr/bin/env python3
"""Does Cycles render the sun's light through the frosted slab of mat_leaves, or only a shadow?

    nice -n 19 ~/.cache/photongrid/venv-bpy-5.0.1/bin/python bench/materials/check_leaves_caustic.py

Renders mat_leaves with the sun only (sky lamp off) at 160x120, 256 spp, twice: as is, and with
the slab invisible to shadow rays. On the ground in the slab's sun shadow (pixels where the two
differ by > 20 %, outside the slab's silhouette from the specmask) it prints the mean luminance
of both. A path tracer that could not reach the sun through the rough slab would give a ratio
near 0 there (only indirect light); Cycles reaches it by next-event estimation from the slab's
rough far face.
"""
import os
import sys

import bpy
import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import render_refs  # noqa: E402

blend = os.path.join(HERE, "..", "..", "out", "materials", "blend", "mat_leaves.blend")
work = os.path.join(HERE, "..", "..", "out", "materials", "caustic_check")
os.makedirs(work, exist_ok=True)
bpy.ops.wm.open_mainfile(filepath=os.path.abspath(blend))
sc = bpy.context.scene
bpy.data.materials["SkyLampEmission"].node_tree.nodes["Principled BSDF"].inputs["Emission Strength"].default_value = 0.0
img = {}
for label, shadow in (("glass", True), ("no_glass_shadow", False)):
    bpy.data.objects["FrostedPanel"].visible_shadow = shadow
    render_refs.setup_cycles(sc, 256, seed=3)
    sc.render.resolution_percentage = 25
    sc.render.filepath = os.path.join(work, label + ".exr")
    bpy.ops.render.render(write_still=True)
    img[label] = render_refs.read_exr_rgb(sc.render.filepath) @ render_refs.LUM
a, b = img["glass"], img["no_glass_shadow"]
m = render_refs.read_exr_rgb(os.path.join(HERE, "refs", "mat_leaves_cam0.specmask.exr"))[..., 0]
h, w = a.shape
slab = m.reshape(h, m.shape[0] // h, w, m.shape[1] // w).max(axis=(1, 3)) > 0
sel = (b > 0.05) & (np.abs(b - a) > 0.2 * b) & ~slab
print("ground in the slab's sun shadow (%d px at %dx%d): with the slab %.4f, slab invisible to shadow "
      "rays %.4f, ratio %.3f" % (sel.sum(), w, h, a[sel].mean(), b[sel].mean(), a[sel].mean() / b[sel].mean()))
