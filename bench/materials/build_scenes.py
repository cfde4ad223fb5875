#!/usr/bin/env python3
"""Build the material test scenes in Blender 5.0.1 (bpy) from nothing, save each .blend, export
each with Blender's own glTF exporter and write <scene>.scene.json beside the GLB.

    ~/.cache/photongrid/venv-bpy-5.0.1/bin/python bench/materials/build_scenes.py \
        [--out bench/materials] [--blend-dir out/materials/blend] [--only mat_spheres,...]

Everything (geometry, procedural 256x256 textures, materials, lights, cameras) is made here;
the textures are packed into the .blend and embedded in the GLB, so both are self-contained.
Export options are the shared scenes' (see ../../../shared/scenes/README.md):
GLB, +Y up, cameras and lights on, lighting mode "Standard" (SPEC), apply modifiers.
"""
import argparse
import json
import math
import os
import struct
import sys

import bpy
import numpy as np
from mathutils import Vector

HERE = os.path.dirname(os.path.abspath(__file__))
EXPORT_OPTIONS = {
    "export_format": "GLB",
    "export_cameras": True,
    "export_lights": True,
    "export_import_convert_lighting_mode": "SPEC",
    "export_yup": True,
    "export_apply": True,
}
RES = (640, 480)
SCENES = ["mat_spheres", "mat_leaves", "mat_punctual", "mat_sphere_single", "mat_sphere_single_metal"]

# Pass indices (not exported): the reference script renders the material-index pass for the
# specular mask (1 = glass or mirror, seen first by the camera).
PASS_GLASS = 1


# ----------------------------------------------------------------------------------------------
# helpers: scene, meshes, cameras, lights
# ----------------------------------------------------------------------------------------------
def reset():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    sc.render.engine = "CYCLES"
    sc.cycles.device = "CPU"
    sc.render.resolution_x, sc.render.resolution_y = RES
    sc.render.resolution_percentage = 100
    world = bpy.data.worlds.new("World")
    world.use_nodes = True
    bg = world.node_tree.nodes["Background"]
    bg.inputs["Color"].default_value = (0, 0, 0, 1)
    bg.inputs["Strength"].default_value = 0.0
    sc.world = world
    sc.view_settings.view_transform = "Standard"
    sc.view_settings.look = "None"
    return sc


def link(obj):
    bpy.context.scene.collection.objects.link(obj)
    return obj


def mesh_object(name, verts, faces, uvs=None, mat=None, smooth=False):
    """uvs: per-face-corner list aligned with faces (list of lists of (u, v))."""
    me = bpy.data.meshes.new(name)
    me.from_pydata([tuple(v) for v in verts], [], [tuple(f) for f in faces])
    if uvs is not None:
        uvl = me.uv_layers.new(name="UVMap")
        k = 0
        for f, fuv in zip(faces, uvs):
            for uv in fuv:
                uvl.data[k].uv = uv
                k += 1
    me.update()
    for p in me.polygons:
        p.use_smooth = smooth
    ob = bpy.data.objects.new(name, me)
    if mat is not None:
        me.materials.append(mat)
    return link(ob)


def quad(name, corners, mat, uv_scale=(1.0, 1.0)):
    """corners in counter-clockwise order seen from the front (normal side): c0 c1 c2 c3,
    uv (0,0) at c0, (su,0) at c1, (su,sv) at c2."""
    su, sv = uv_scale
    return mesh_object(name, corners, [(0, 1, 2, 3)], [[(0, 0), (su, 0), (su, sv), (0, sv)]], mat)


def box(name, center, size, mat):
    """Axis-aligned closed box as real geometry (no object scale)."""
    cx, cy, cz = center
    sx, sy, sz = (s / 2 for s in size)
    v = [(cx + x * sx, cy + y * sy, cz + z * sz) for z in (-1, 1) for y in (-1, 1) for x in (-1, 1)]
    f = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    uv = [[(0, 0), (1, 0), (1, 1), (0, 1)]] * 6
    return mesh_object(name, v, f, uv, mat)


def uv_sphere(name, center, radius, mat, segments=64, rings=32):
    bpy.ops.mesh.primitive_uv_sphere_add(segments=segments, ring_count=rings, radius=radius,
                                         location=center, calc_uvs=True)
    ob = bpy.context.active_object
    ob.name = name
    ob.data.name = name
    bpy.ops.object.shade_smooth()
    ob.data.materials.append(mat)
    return ob


def look_at(ob, target):
    d = Vector(target) - ob.location
    ob.rotation_euler = d.to_track_quat("-Z", "Y").to_euler()


def camera(name, loc, target, vfov_deg=None, ortho_scale=None):
    cam = bpy.data.cameras.new(name)
    cam.sensor_fit = "VERTICAL"
    cam.clip_start = 0.05
    cam.clip_end = 100.0
    if ortho_scale is not None:
        # io_scene_gltf2 maps ortho_scale to the larger image side whatever the sensor fit, so
        # keep Blender's default AUTO fit for orthographic cameras (ortho_scale = image width)
        cam.sensor_fit = "AUTO"
        cam.type = "ORTHO"
        cam.ortho_scale = ortho_scale
    else:
        cam.angle_y = math.radians(vfov_deg)
    ob = link(bpy.data.objects.new(name, cam))
    ob.location = loc
    look_at(ob, target)
    if bpy.context.scene.camera is None:
        bpy.context.scene.camera = ob
    return ob


def light(name, kind, loc=None, target=None, direction=None, **kw):
    la = bpy.data.lights.new(name, kind)
    for k, v in kw.items():
        setattr(la, k, v)
    if kind in ("POINT", "SPOT"):
        la.shadow_soft_size = 0.0  # delta light, as in the GLB
    if kind == "SUN":
        la.angle = 0.0  # glTF drops the angle
    ob = link(bpy.data.objects.new(name, la))
    if loc is not None:
        ob.location = loc
    if target is not None:
        look_at(ob, target)
    if direction is not None:  # direction the light travels
        ob.rotation_euler = Vector(direction).to_track_quat("-Z", "Y").to_euler()
    return ob


# ----------------------------------------------------------------------------------------------
# procedural textures (numpy arrays (H, W, C), row 0 = v = 0, values in [0, 1])
# ----------------------------------------------------------------------------------------------
N = 256


def srgb_encode(lin):
    lin = np.clip(lin, 0, 1)
    return np.where(lin <= 0.0031308, lin * 12.92, 1.055 * lin ** (1 / 2.4) - 0.055)


def grid():
    t = (np.arange(N) + 0.5) / N
    return np.meshgrid(t, t)  # u, v (each (N, N), [row=v, col=u])


def normal_from_height(h, strength):
    """Tangent-space normal map (OpenGL/glTF convention: +X = +u, +Y = +v) from a height field
    in texels; wraps at the borders (tiling)."""
    dhdu = (np.roll(h, -1, axis=1) - np.roll(h, 1, axis=1)) * 0.5
    dhdv = (np.roll(h, -1, axis=0) - np.roll(h, 1, axis=0)) * 0.5
    n = np.stack([-strength * dhdu, -strength * dhdv, np.ones_like(h)], axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    return n * 0.5 + 0.5


def tex_checker():
    u, v = grid()
    iu, iv = np.floor(u * 8).astype(int), np.floor(v * 8).astype(int)
    a = ((iu + iv) % 2 == 0)[..., None]
    c1 = np.array([0.80, 0.78, 0.72])   # linear
    c2 = np.array([0.12, 0.16, 0.22])
    return srgb_encode(np.where(a, c1, c2))  # sRGB-encoded bytes, as an artist's PNG


def tex_floor_normal():
    u, v = grid()
    fu, fv = (u * 8) % 1.0, (v * 8) % 1.0
    d = np.minimum(np.minimum(fu, 1 - fu), np.minimum(fv, 1 - fv)) * 32  # texels to grout
    h = np.clip(d / 3.0, 0, 1)           # bevel of 3 texels: tiles raised 1 unit over the grout
    h = h * 3.0
    return normal_from_height(h, 0.6)


def tex_ball_color():
    u, v = grid()
    iu, iv = np.floor(u * 12).astype(int), np.floor(v * 6).astype(int)
    pal = np.array([[0.70, 0.10, 0.08], [0.85, 0.60, 0.10], [0.10, 0.35, 0.70],
                    [0.80, 0.80, 0.80], [0.15, 0.55, 0.20], [0.55, 0.25, 0.60]])
    c = pal[(iu + 2 * iv) % len(pal)]
    return srgb_encode(c)


def tex_ball_mr():
    """glTF metallicRoughness layout: G = roughness, B = metallic (R unused, 1)."""
    u, v = grid()
    iu, iv = np.floor(u * 12).astype(int), np.floor(v * 6).astype(int)
    metal = ((iu + iv) % 3 == 0).astype(float)
    rough = 0.25 + 0.5 * (0.5 + 0.5 * np.sin(2 * math.pi * v * 3))  # 0.25 .. 0.75
    return np.stack([np.ones_like(u), rough, metal], axis=-1)


def tex_ball_normal():
    u, v = grid()
    fu, fv = (u * 12) % 1.0, (v * 6) % 1.0
    # round bumps (domes) in each tile, radius 0.35 tile
    du, dv = (fu - 0.5), (fv - 0.5)
    r2 = (du * du + dv * dv) / 0.35 ** 2
    h = np.sqrt(np.clip(1 - r2, 0, 1)) * 6.0   # in texels
    return normal_from_height(h, 0.5)


def tex_leaf():
    """RGBA leaf: sRGB colour, alpha with a soft 10-texel ramp at the edge and a few holes."""
    u, v = grid()
    x, y = (u - 0.5) * 2, (v - 0.5) * 2          # [-1, 1]
    yy = (y + 1) / 2                              # 0 at the stem end, 1 at the tip
    w = 0.62 * np.sin(np.pi * np.clip(yy, 0, 1)) ** 0.75 * (1 - 0.25 * yy)
    d = (w - np.abs(x)) * N / 2                   # texels inside the outline
    d = np.where((yy > 0.03) & (yy < 0.97), d, -10)
    alpha = np.clip(0.5 + d / 10.0, 0, 1)
    for cx, cy, r in [(0.18, 0.1, 0.07), (-0.22, -0.25, 0.05), (0.1, 0.45, 0.05)]:
        dd = (np.hypot(x - cx, y - cy) - r) * N / 2
        alpha = np.minimum(alpha, np.clip(0.5 + dd / 4.0, 0, 1))
    base = np.array([0.10, 0.32, 0.05])
    vein = np.array([0.35, 0.50, 0.12])
    midrib = np.exp(-(x * N / 2 / 2.5) ** 2)
    lat = np.exp(-((((y - 0.9 * np.abs(x)) * 6) % 1.0 - 0.5) * 10) ** 2) * (np.abs(x) < w)
    m = np.clip(np.maximum(midrib, 0.6 * lat), 0, 1)[..., None]
    col = srgb_encode(base * (1 - m) + vein * m)
    return np.concatenate([col, alpha[..., None]], axis=-1)


def tex_screen():
    u, v = grid()
    i = np.floor(u * 6).astype(int)
    pal = np.array([[1, 0.2, 0.1], [1, 0.8, 0.1], [0.2, 1, 0.2], [0.1, 0.6, 1], [0.5, 0.2, 1],
                    [1, 1, 1]])
    c = pal[i % 6] * (0.35 + 0.65 * (v > 0.3 + 0.4 * ((i % 2) == 0)))[..., None]
    return srgb_encode(c)


def write_png(path, arr):
    """8-bit PNG (RGB or RGBA) of an array with row 0 = v = 0 (PNG's first row is the top)."""
    import zlib
    h, w, c = arr.shape
    q = np.round(np.clip(arr, 0, 1) * 255).astype(np.uint8)[::-1]
    raw = b"".join(b"\x00" + q[i].tobytes() for i in range(h))

    def chunk(tag, data):
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)
    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 6 if c == 4 else 2, 0, 0, 0)) \
        + chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b"")
    with open(path, "wb") as f:
        f.write(png)


TEX_DIR = None  # set in main(): where the PNGs are written before Blender loads and packs them


def image(name, arr, non_color):
    """Write the texture as a PNG file, load it into Blender and pack it into the .blend, as a
    user would with an image file (the GLB then embeds the same PNG texels)."""
    path = os.path.join(TEX_DIR, name + ".png")
    write_png(path, arr)
    img = bpy.data.images.load(path)
    img.name = name
    img.colorspace_settings.name = "Non-Color" if non_color else "sRGB"
    if arr.shape[2] == 4:
        img.alpha_mode = "STRAIGHT"
    img.pack()
    return img


# ----------------------------------------------------------------------------------------------
# materials (Principled BSDF, as a user would set them)
# ----------------------------------------------------------------------------------------------
MATINFO = {}


def principled(name, **inputs):
    m = bpy.data.materials.new(name)
    m.use_nodes = True
    nt = m.node_tree
    p = nt.nodes["Principled BSDF"]
    rec = {}
    for k, v in inputs.items():
        p.inputs[k].default_value = v
        rec[k] = list(v) if hasattr(v, "__len__") else v
    MATINFO[name] = {"principled_inputs": rec, "distribution": p.distribution,
                     "textures": {}, "notes": []}
    return m, nt, p


def tex_node(nt, img, loc):
    t = nt.nodes.new("ShaderNodeTexImage")
    t.image = img
    t.interpolation = "Linear"
    t.extension = "REPEAT"
    t.location = loc
    return t


def mat_diffuse(name, color):
    m, _, _ = principled(name, **{"Base Color": (*color, 1), "Roughness": 1.0, "Metallic": 0.0,
                                  "Specular IOR Level": 0.0})
    MATINFO[name]["type"] = "diffuse (Lambert: Specular IOR Level 0, roughness 1)"
    return m


def mat_metal(name, color, rough):
    m, _, _ = principled(name, **{"Base Color": (*color, 1), "Metallic": 1.0, "Roughness": rough})
    MATINFO[name]["type"] = "rough metal"
    return m


def mat_plastic(name, color, rough, **extra):
    m, _, _ = principled(name, **{"Base Color": (*color, 1), "Metallic": 0.0, "Roughness": rough,
                                  **extra})
    MATINFO[name]["type"] = "rough dielectric (plastic)"
    return m


def mat_frosted(name, rough=0.3):
    m, _, _ = principled(name, **{"Base Color": (1, 1, 1, 1), "Metallic": 0.0, "Roughness": rough,
                                  "Transmission Weight": 1.0, "IOR": 1.5})
    m.pass_index = PASS_GLASS
    MATINFO[name]["type"] = "rough glass (transmission 1)"
    return m


def mat_emitter(name, strength, color=(1, 1, 1)):
    m, _, _ = principled(name, **{"Base Color": (0, 0, 0, 1), "Roughness": 1.0,
                                  "Specular IOR Level": 0.0, "Emission Color": (*color, 1),
                                  "Emission Strength": strength})
    MATINFO[name]["type"] = "emitter (black base + emission)"
    return m


def mat_textured_ball():
    m, nt, p = principled("TexturedBall", **{"Roughness": 0.5, "Metallic": 0.0})
    tc = tex_node(nt, image("ball_basecolor", tex_ball_color(), False), (-700, 300))
    nt.links.new(tc.outputs["Color"], p.inputs["Base Color"])
    tm = tex_node(nt, image("ball_metalrough", tex_ball_mr(), True), (-700, 0))
    sep = nt.nodes.new("ShaderNodeSeparateColor")
    sep.location = (-400, 0)
    nt.links.new(tm.outputs["Color"], sep.inputs["Color"])
    nt.links.new(sep.outputs["Green"], p.inputs["Roughness"])
    nt.links.new(sep.outputs["Blue"], p.inputs["Metallic"])
    tn = tex_node(nt, image("ball_normal", tex_ball_normal(), True), (-700, -300))
    nm = nt.nodes.new("ShaderNodeNormalMap")
    nm.space = "TANGENT"
    nm.uv_map = "UVMap"
    nm.location = (-400, -300)
    nt.links.new(tn.outputs["Color"], nm.inputs["Color"])
    nt.links.new(nm.outputs["Normal"], p.inputs["Normal"])
    MATINFO["TexturedBall"].update(type="textured: base colour + metallic/roughness (G/B) + tangent normal map",
                                  textures={"Base Color": "ball_basecolor (sRGB)",
                                            "Roughness": "ball_metalrough.G (Non-Color, Separate Color)",
                                            "Metallic": "ball_metalrough.B (Non-Color, Separate Color)",
                                            "Normal": "ball_normal (Non-Color) -> Normal Map node, tangent space, strength 1"})
    return m


def mat_checker_floor():
    m, nt, p = principled("CheckerFloor", **{"Roughness": 0.6, "Metallic": 0.0})
    tc = tex_node(nt, image("floor_checker", tex_checker(), False), (-700, 300))
    nt.links.new(tc.outputs["Color"], p.inputs["Base Color"])
    tn = tex_node(nt, image("floor_normal", tex_floor_normal(), True), (-700, -300))
    nm = nt.nodes.new("ShaderNodeNormalMap")
    nm.uv_map = "UVMap"
    nt.links.new(tn.outputs["Color"], nm.inputs["Color"])
    nt.links.new(nm.outputs["Normal"], p.inputs["Normal"])
    MATINFO["CheckerFloor"].update(type="textured dielectric floor: checker base colour + tangent normal map (grout bevels)",
                                  textures={"Base Color": "floor_checker (sRGB)",
                                            "Normal": "floor_normal (Non-Color) -> Normal Map node"})
    return m


def mat_screen(strength):
    m, nt, p = principled("EmissiveScreen", **{"Base Color": (0.02, 0.02, 0.02, 1), "Roughness": 1.0,
                                              "Specular IOR Level": 0.0,
                                              "Emission Strength": strength})
    t = tex_node(nt, image("screen_emission", tex_screen(), False), (-600, 0))
    nt.links.new(t.outputs["Color"], p.inputs["Emission Color"])
    MATINFO["EmissiveScreen"].update(type="emissive texture (Emission Color <- image, Emission Strength %g)" % strength,
                                    textures={"Emission Color": "screen_emission (sRGB)"})
    return m


def mat_leaf(name, img, cutoff, tint):
    m, nt, p = principled(name, **{"Roughness": 0.6, "Metallic": 0.0})
    t = tex_node(nt, img, (-900, 200))
    mix = nt.nodes.new("ShaderNodeMix")
    mix.data_type = "RGBA"
    mix.blend_type = "MULTIPLY"
    mix.inputs["Factor"].default_value = 1.0
    mix.inputs["B"].default_value = (*tint, 1)
    nt.links.new(t.outputs["Color"], mix.inputs["A"])
    if tint == (1, 1, 1):
        nt.links.new(t.outputs["Color"], p.inputs["Base Color"])
        nt.nodes.remove(mix)
    else:
        nt.links.new(mix.outputs["Result"], p.inputs["Base Color"])
    if cutoff == 0.5:
        # Blender 4.2+ has no "Alpha Clip" blend mode: a Math "Round" node is the clip that the
        # glTF exporter recognises (alphaMode MASK, cutoff 0.5 = glTF default, not written).
        r = nt.nodes.new("ShaderNodeMath")
        r.operation = "ROUND"
        nt.links.new(t.outputs["Alpha"], r.inputs[0])
        nt.links.new(r.outputs[0], p.inputs["Alpha"])
        how = "Alpha <- Math Round(texture alpha)"
    else:
        # 1 - (alpha < cutoff): what the glTF importer builds; exporter writes alphaCutoff.
        lt = nt.nodes.new("ShaderNodeMath")
        lt.operation = "LESS_THAN"
        lt.inputs[1].default_value = cutoff
        sub = nt.nodes.new("ShaderNodeMath")
        sub.operation = "SUBTRACT"
        sub.inputs[0].default_value = 1.0
        nt.links.new(t.outputs["Alpha"], lt.inputs[0])
        nt.links.new(lt.outputs[0], sub.inputs[1])
        nt.links.new(sub.outputs[0], p.inputs["Alpha"])
        how = "Alpha <- 1 - (texture alpha < %g) (Math Less Than + Subtract)" % cutoff
    MATINFO[name].update(type="alpha-masked leaf (clip %g)" % cutoff,
                         textures={"Base Color": "leaf (sRGB RGBA) colour" + ("" if tint == (1, 1, 1) else " x tint %s" % (tint,)),
                                   "Alpha": how})
    return m


def mat_blend_sheet(name, color, alpha):
    m, _, _ = principled(name, **{"Base Color": (*color, 1), "Roughness": 0.8, "Metallic": 0.0,
                                  "Alpha": alpha})
    MATINFO[name]["type"] = "alpha blend (constant Alpha %g)" % alpha
    return m


# ----------------------------------------------------------------------------------------------
# scenes
# ----------------------------------------------------------------------------------------------
GOLD = (1.0, 0.766, 0.336)
PLASTIC = (0.60, 0.06, 0.04)
ROOM = dict(x0=-1.5, x1=1.5, y0=-1.75, y1=1.75, z1=2.4)
HOLE = dict(x0=-0.4, x1=0.4, y0=-0.1, y1=0.7)  # 0.8 x 0.8 m lamp in the ceiling


def room(with_hole, white, side):
    r = ROOM
    x0, x1, y0, y1, z1 = r["x0"], r["x1"], r["y0"], r["y1"], r["z1"]
    floor = mat_checker_floor()
    # floor: UVs 0..2 across 3 m (x) and 0..(3.5/1.5) along y, so checks are 0.1875 m square
    quad("Floor", [(x0, y0, 0), (x1, y0, 0), (x1, y1, 0), (x0, y1, 0)], floor,
         uv_scale=(2.0, 2.0 * (y1 - y0) / (x1 - x0)))
    quad("BackWall", [(x0, y1, 0), (x1, y1, 0), (x1, y1, z1), (x0, y1, z1)], white)
    quad("FrontWall", [(x1, y0, 0), (x0, y0, 0), (x0, y0, z1), (x1, y0, z1)], white)
    quad("LeftWall", [(x0, y0, 0), (x0, y1, 0), (x0, y1, z1), (x0, y0, z1)], side)
    quad("RightWall", [(x1, y1, 0), (x1, y0, 0), (x1, y0, z1), (x1, y1, z1)], white)
    if with_hole:
        h = HOLE
        # four ceiling strips around the hole, facing down
        for nm, (a0, a1, b0, b1) in {"CeilN": (x0, x1, h["y1"], y1), "CeilS": (x0, x1, y0, h["y0"]),
                                     "CeilW": (x0, h["x0"], h["y0"], h["y1"]),
                                     "CeilE": (h["x1"], x1, h["y0"], h["y1"])}.items():
            quad(nm, [(a0, b0, z1), (a0, b1, z1), (a1, b1, z1), (a1, b0, z1)], white)
    else:
        quad("Ceiling", [(x0, y0, z1), (x0, y1, z1), (x1, y1, z1), (x1, y0, z1)], white)


def spheres():
    r = 0.38
    uv_sphere("GoldSphere", (-0.85, 0.55, r), r, mat_metal("Gold", GOLD, 0.3))
    uv_sphere("PlasticSphere", (0.85, 0.55, r), r, mat_plastic("RedPlastic", PLASTIC, 0.5))
    uv_sphere("TexturedSphere", (0.0, 0.05, 0.42), 0.42, mat_textured_ball())
    # KHR_materials_specular + KHR_materials_ior: a dielectric with Specular IOR Level 0.25
    # (specularFactor 0.5) and IOR 1.6
    uv_sphere("BlueSphere", (0.55, -0.55, 0.22), 0.22,
              mat_plastic("BlueSpecIor", (0.08, 0.2, 0.6), 0.35,
                          **{"Specular IOR Level": 0.25, "IOR": 1.6}))


def build_mat_spheres():
    reset()
    white = mat_diffuse("WhiteWall", (0.75, 0.75, 0.75))
    side = mat_diffuse("TealWall", (0.15, 0.45, 0.45))
    room(True, white, side)
    spheres()
    h = HOLE
    quad("CeilingLamp", [(h["x0"], h["y0"], ROOM["z1"]), (h["x0"], h["y1"], ROOM["z1"]),
                         (h["x1"], h["y1"], ROOM["z1"]), (h["x1"], h["y0"], ROOM["z1"])],
         mat_emitter("LampEmission", 40.0))
    y = ROOM["y1"] - 0.002
    quad("Screen", [(-0.5, y, 1.15), (0.5, y, 1.15), (0.5, y, 1.75), (-0.5, y, 1.75)],
         mat_screen(4.0))
    camera("Camera", (0.25, -1.6, 1.35), (0.0, 0.35, 0.62), vfov_deg=50.0)
    return dict(description="Closed 3x3.5x2.4 m room lit only by a 0.8x0.8 m emissive quad (strength 40) "
                            "filling a hole in the ceiling, plus an emissive-textured screen on the back wall "
                            "(strength 4). Rough gold sphere (roughness 0.3), rough red plastic (0.5, default "
                            "specular), textured sphere (base colour + metallic/roughness + normal map), small "
                            "blue dielectric with Specular IOR Level 0.25 and IOR 1.6, checker floor with normal map.")


def build_mat_punctual():
    reset()
    white = mat_diffuse("WhiteWall", (0.75, 0.75, 0.75))
    side = mat_diffuse("TealWall", (0.15, 0.45, 0.45))
    room(False, white, side)
    spheres()
    light("PointLight", "POINT", loc=(0.9, -0.6, 2.1), energy=80.0)
    light("SpotLight", "SPOT", loc=(-1.3, -1.5, 2.2), target=(-0.5, 0.4, 0.2), energy=250.0,
          spot_size=math.radians(45.0), spot_blend=0.2)
    camera("Camera", (1.25, -1.55, 1.5), (-0.2, 0.4, 0.35), vfov_deg=50.0)
    return dict(description="The mat_spheres room and spheres (closed ceiling, no screen) lit only by a "
                            "point light (80 W, radius 0) and a spot light (250 W, 45 deg, blend 0.2, radius 0).")


def build_mat_leaves():
    reset()
    ground = mat_diffuse("Ground", (0.6, 0.58, 0.55))
    wall = mat_diffuse("Wall", (0.7, 0.7, 0.7))
    quad("Ground", [(-4, -4, 0), (4, -4, 0), (4, 4, 0), (-4, 4, 0)], ground)
    quad("BackWall", [(-4, 2.0, 0), (4, 2.0, 0), (4, 2.0, 3), (-4, 2.0, 3)], wall)
    leaf_img = image("leaf", tex_leaf(), False)
    leaf_a = mat_leaf("LeafRound", leaf_img, 0.5, (1, 1, 1))
    leaf_b = mat_leaf("LeafCut035", leaf_img, 0.35, (1.0, 0.8, 0.45))
    rng = np.random.default_rng(7)
    k = 0
    for cx, cy, cz in [(-0.9, 0.2, 1.2), (-0.35, 0.0, 1.35), (0.15, 0.35, 1.15), (-0.6, 0.7, 1.05),
                       (-1.3, 0.6, 1.3), (0.35, 0.85, 1.4), (-0.1, -0.35, 1.0)]:
        L, W = 0.7, 0.55
        a = rng.uniform(0, 2 * math.pi)
        tilt = rng.uniform(-0.35, 0.35)
        ax = Vector((math.cos(a), math.sin(a), tilt)).normalized()       # leaf axis (v)
        side = Vector((-math.sin(a), math.cos(a), 0.0)).normalized()     # across (u)
        c = Vector((cx, cy, cz))
        p0 = c - ax * L / 2 - side * W / 2
        p1 = c - ax * L / 2 + side * W / 2
        p2 = c + ax * L / 2 + side * W / 2
        p3 = c + ax * L / 2 - side * W / 2
        quad("Leaf%d" % k, [p0, p1, p2, p3], leaf_a if k % 2 == 0 else leaf_b)
        k += 1
    # frosted glass panel: closed slab 1.0 x 0.03 x 1.1 m standing on the ground
    g = box("FrostedPanel", (1.1, 0.2, 0.55), (1.0, 0.03, 1.1), mat_frosted("FrostedGlass", 0.3))
    g.rotation_euler = (0, 0, math.radians(-20))
    # something colourful behind the panel to be seen through it
    box("OrangeBlock", (1.25, 0.85, 0.3), (0.5, 0.4, 0.6), mat_plastic("OrangePlastic", (0.8, 0.3, 0.05), 0.4))
    # alpha-blended translucent sheet (alphaMode BLEND)
    quad("BlendSheet", [(-1.9, -0.5, 0.8), (-1.3, -0.5, 0.8), (-1.3, 0.0, 1.45), (-1.9, 0.0, 1.45)],
         mat_blend_sheet("BlueSheet", (0.1, 0.3, 0.9), 0.5))
    quad("SkyLamp", [(-1.2, -1.4, 2.8), (-1.2, -0.6, 2.8), (-0.4, -0.6, 2.8), (-0.4, -1.4, 2.8)],
         mat_emitter("SkyLampEmission", 25.0))
    light("Sun", "SUN", direction=(0.35, 0.45, -0.82), energy=2.5)
    camera("Camera", (-0.2, -3.3, 2.9), (-0.1, 0.45, 0.45), vfov_deg=42.0)
    return dict(description="Ground and back wall under a sun (2.5 W/m2, angle 0) and an emissive 0.8x0.8 m quad "
                            "(strength 25, 2.8 m up, facing down): seven alpha-masked leaf quads (one leaf texture "
                            "with a soft alpha ramp and holes; clip 0.5 via Math Round and clip 0.35 via "
                            "1-(a<0.35)) casting cut-out shadows, a frosted glass slab (transmission 1, roughness 0.3) "
                            "with an orange block behind it, a half-transparent blue sheet (alpha 0.5, BLEND).")


def build_single(metal):
    reset()
    if metal:
        mat = mat_metal("Gold", GOLD, 0.3)
    else:
        mat = mat_plastic("RedPlastic", PLASTIC, 0.5)
    uv_sphere("Sphere", (0, 0, 0), 1.0, mat, segments=192, rings=96)
    light("Sun", "SUN", direction=(0.5, 0.7, -0.5), energy=3.0)
    camera("Camera", (0, -10, 0), (0, 0, 0), ortho_scale=3.2)
    what = "rough gold metal (metallic 1, roughness 0.3)" if metal else \
        "rough red dielectric (roughness 0.5, default specular)"
    return dict(description="One sphere (r 1 m, 192x96 UV sphere, smooth shaded), %s, under a sun "
                            "(3 W/m2, angle 0), orthographic camera (ortho_scale 3.2 = width, 2.4 m high), black world, "
                            "nothing else: for Principled-vs-glTF BRDF comparison." % what)


BUILDERS = {
    "mat_spheres": build_mat_spheres,
    "mat_leaves": build_mat_leaves,
    "mat_punctual": build_mat_punctual,
    "mat_sphere_single": lambda: build_single(False),
    "mat_sphere_single_metal": lambda: build_single(True),
}


# ----------------------------------------------------------------------------------------------
# GLB reading and the scene.json
# ----------------------------------------------------------------------------------------------
def read_glb_json(path):
    with open(path, "rb") as f:
        data = f.read()
    magic, ver, length = struct.unpack_from("<III", data, 0)
    assert magic == 0x46546C67 and ver == 2
    clen, ctype = struct.unpack_from("<II", data, 12)
    assert ctype == 0x4E4F534A
    return json.loads(data[20:20 + clen]), data


def b2g(v):
    return [v[0], v[2], -v[1]]


def describe(name, info, glb, blend_path):
    sc = bpy.context.scene
    gj, raw = read_glb_json(glb)
    dg = bpy.context.evaluated_depsgraph_get()
    tri_bl = {}
    for ob in sc.objects:
        if ob.type == "MESH":
            me = ob.evaluated_get(dg).to_mesh()
            me.calc_loop_triangles()
            tri_bl[ob.name] = len(me.loop_triangles)
            ob.evaluated_get(dg).to_mesh_clear()
    # triangles from the GLB accessors, per node
    tri_node = {}
    for node in gj["nodes"]:
        if "mesh" in node:
            n = 0
            for prim in gj["meshes"][node["mesh"]]["primitives"]:
                assert prim.get("mode", 4) == 4
                n += gj["accessors"][prim["indices"]]["count"] // 3
            tri_node[node["name"]] = n
    cams = []
    for ob in sc.objects:
        if ob.type != "CAMERA":
            continue
        idx = next(i for i, n in enumerate(gj["nodes"]) if n.get("name") == ob.name)
        gc = gj["cameras"][gj["nodes"][idx]["camera"]]
        fwd = ob.matrix_world.to_3x3() @ Vector((0, 0, -1))
        c = {"name": ob.name, "type": ob.data.type, "location_blender": list(ob.location),
             "forward_blender": list(fwd), "sensor_fit": ob.data.sensor_fit,
             "gltf_camera_index": gj["nodes"][idx]["camera"], "gltf_node": ob.name, "gltf": gc}
        if ob.data.type == "ORTHO":
            c["ortho_scale"] = ob.data.ortho_scale
        else:
            c["vfov_deg"] = math.degrees(ob.data.angle_y)
        cams.append(c)
    cams.sort(key=lambda c: c["gltf_camera_index"])
    lights = []
    glights = gj.get("extensions", {}).get("KHR_lights_punctual", {}).get("lights", [])
    for ob in sc.objects:
        if ob.type != "LIGHT":
            continue
        la = ob.data
        node = next(n for n in gj["nodes"] if n.get("name") == ob.name)
        li = node["extensions"]["KHR_lights_punctual"]["light"]
        gl = glights[li]
        d = {"name": ob.name, "type": la.type, "color": list(la.color),
             "gltf_light_index": li, "gltf": gl}
        fwd = ob.matrix_world.to_3x3() @ Vector((0, 0, -1))
        if la.type == "SUN":
            d.update(blender_strength_W_per_m2=la.energy, angle=la.angle, direction_blender=list(fwd),
                     direction_gltf=b2g(fwd), expected_intensity=la.energy * 683,
                     expected_intensity_formula="W_per_m2 * 683", gltf_intensity_unit="lux")
        else:
            d.update(blender_energy_W=la.energy, radius=la.shadow_soft_size, location_blender=list(ob.location),
                     location_gltf=b2g(ob.location), expected_intensity=la.energy / (4 * math.pi) * 683,
                     expected_intensity_formula="W / (4*pi) * 683", gltf_intensity_unit="cd")
            if la.type == "SPOT":
                d.update(spot_size_deg=math.degrees(la.spot_size), spot_blend=la.spot_blend,
                         direction_blender=list(fwd), direction_gltf=b2g(fwd))
        d["intensity_matches_formula"] = abs(gl["intensity"] - d["expected_intensity"]) <= 1e-4 * d["expected_intensity"]
        lights.append(d)
    mats = []
    for i, gm in enumerate(gj.get("materials", [])):
        mats.append({"gltf_index": i, "name": gm["name"], "blender": MATINFO.get(gm["name"]), "gltf": gm})
    textures = []
    for i, t in enumerate(gj.get("textures", [])):
        im = gj["images"][t["source"]]
        bv = gj["bufferViews"][im["bufferView"]]
        textures.append({"gltf_index": i, "image": im.get("name"), "mimeType": im.get("mimeType"),
                         "sampler": gj["samplers"][t["sampler"]] if "sampler" in t else None,
                         "bytes": bv["byteLength"]})
    meshes_attrs = sorted({a for m in gj["meshes"] for p in m["primitives"] for a in p["attributes"]})
    out = {
        "scene": name,
        "file": os.path.basename(glb),
        "glb_bytes": os.path.getsize(glb),
        "blend_file": os.path.relpath(blend_path, os.path.dirname(glb)),
        "description": info["description"],
        "generator": {"blender": bpy.app.version_string, "exporter": gj["asset"].get("generator"),
                      "export_options": EXPORT_OPTIONS, "built_by": "bench/materials/build_scenes.py"},
        "render": {"resolution": list(RES), "world": "black (strength 0)"},
        "coordinate_note": "Blender Z-up values (*_blender); glTF is Y-up: (x, y, z)_blender -> (x, z, -y)_gltf",
        "cameras": cams,
        "lights": lights,
        "materials": mats,
        "textures": textures,
        "mesh_attributes": meshes_attrs,
        "extensions_used": gj.get("extensionsUsed", []),
        "extensions_required": gj.get("extensionsRequired", []),
        "triangles": sum(tri_node.values()),
        "triangles_blender_loop_triangles": sum(tri_bl.values()),
        "triangles_per_node": tri_node,
    }
    return out


def main(argv):
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default=HERE)
    ap.add_argument("--blend-dir", default=os.path.join(HERE, "..", "..", "out", "materials", "blend"))
    ap.add_argument("--only", default="")
    a = ap.parse_args(argv)
    os.makedirs(a.out, exist_ok=True)
    os.makedirs(a.blend_dir, exist_ok=True)
    names = [s for s in a.only.split(",") if s] or SCENES
    global TEX_DIR
    TEX_DIR = os.path.abspath(os.path.join(a.blend_dir, "textures"))
    os.makedirs(TEX_DIR, exist_ok=True)
    for name in names:
        MATINFO.clear()
        info = BUILDERS[name]()
        blend = os.path.abspath(os.path.join(a.blend_dir, name + ".blend"))
        bpy.ops.wm.save_as_mainfile(filepath=blend, compress=True)
        glb = os.path.abspath(os.path.join(a.out, name + ".glb"))
        bpy.ops.export_scene.gltf(filepath=glb, **EXPORT_OPTIONS)
        d = describe(name, info, glb, blend)
        with open(os.path.join(a.out, name + ".scene.json"), "w") as f:
            json.dump(d, f, indent=1)
        print("built %s: %d triangles, %d bytes" % (name, d["triangles"], d["glb_bytes"]), flush=True)


if __name__ == "__main__":
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:]
    main(argv)
