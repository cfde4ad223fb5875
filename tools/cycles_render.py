"""Render a camera of a glTF scene with Blender's Cycles, set up like the references (640x480, box
pixel filter 1 px, 12 bounces of every kind, caustics on, no clamping or denoising, black world,
lights imported in physical units with point radius and sun angle 0). Cycles cannot render the
light of point, spot and sun lights through glass or off mirrors (caustics); it is an independent
check of everything else. Runs under Blender's Python (bpy 5.0.1, e.g. the CI's venv):
  python tools/cycles_render.py SCENE.glb CAMERA OUT.exr SAMPLES [FIRST_ROW LAST_ROW]
The optional rows (from the top, last excluded) render only that band of the full frame."""

import sys

import bpy


def main(glb, camera, out, samples, rows=None):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.import_scene.gltf(filepath=glb, export_import_convert_lighting_mode="SPEC")
    scene = bpy.context.scene
    cameras = [o for o in scene.objects if o.type == "CAMERA"]
    matches = [c for c in cameras if c.name == camera] or [c for c in cameras if c.name.startswith(camera)]
    if not matches:
        sys.exit(f"error: {glb} has no camera {camera!r} (it has {', '.join(c.name for c in cameras)})")
    scene.camera = matches[0]
    c = scene.cycles
    scene.render.engine = "CYCLES"
    c.device, c.samples, c.seed = "CPU", samples, 1
    c.use_denoising = c.use_adaptive_sampling = False
    c.max_bounces = c.diffuse_bounces = c.glossy_bounces = c.transmission_bounces = 12
    c.transparent_max_bounces = 12
    c.caustics_reflective = c.caustics_refractive = True
    c.blur_glossy = c.sample_clamp_direct = c.sample_clamp_indirect = 0.0
    c.pixel_filter_type, c.filter_width = "BOX", 1.0
    r = scene.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = 640, 480, 100
    if rows:
        first, last = rows
        r.use_border, r.use_crop_to_border = True, False
        r.border_min_x, r.border_max_x = 0.0, 1.0
        r.border_min_y, r.border_max_y = 1.0 - last / 480, 1.0 - first / 480
    scene.world = scene.world or bpy.data.worlds.new("black")
    scene.world.use_nodes = True
    background = scene.world.node_tree.nodes.get("Background")
    if background:
        background.inputs[1].default_value = 0.0
    for light in (o.data for o in scene.objects if o.type == "LIGHT"):
        if light.type in ("POINT", "SPOT"):
            light.shadow_soft_size = 0.0
        elif light.type == "SUN":
            light.angle = 0.0
    scene.view_settings.view_transform = "Standard"
    r.image_settings.file_format, r.image_settings.color_depth = "OPEN_EXR", "32"
    r.filepath = out
    bpy.ops.render.render(write_still=True)


if __name__ == "__main__":
    args = sys.argv[1:]
    if len(args) not in (4, 6):
        sys.exit(__doc__)
    main(args[0], args[1], args[2], int(args[3]), (int(args[4]), int(args[5])) if len(args) == 6 else None)
