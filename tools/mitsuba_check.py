#!/usr/bin/env python3
"""Render a Blender-exported .glb with Mitsuba 3's particle tracer: an independent check of
photongrid's light transport, on the scene as exported or edited (objects dropped or lifted).

Mitsuba's `ptracer` follows light from the lights and splats every diffuse vertex onto the
camera, so it renders the caustics of point and sun lights (not what the camera sees through
glass or in a mirror: those pixels are black, as the references' specular masks say). With
`--write-glb` the same edit is written as a .glb for photongrid, so both renderers see one scene:

    python3 tools/mitsuba_check.py ../shared/scenes/shelf_objects.glb mi.exr --camera 1 \\
        --spp 1024 --lift Obj02,Obj08,Obj10:0.001 --write-glb lifted.glb
    photongrid render lifted.glb --camera 1 -o ours.exr

Handles what the public scenes use: a flat node list (no children), triangle meshes with
normals, Lambert (KHR_materials_specular 0), smooth glass (KHR_materials_transmission, IOR
1.5), smooth metal (Mitsuba's principled BSDF: Schlick's Fresnel on the base colour, as
glTF's), point and directional lights (radiometric = photometric / 683, UNITS.md),
perspective cameras, box filter, path length at most `--max-depth` segments (12, as the
references). Anything else is refused.

Needs `pip install mitsuba==3.9.1` (its scalar_rgb variant: the LLVM variants need a newer
libLLVM than this machine's 15).
"""

import argparse
import os
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from glb import accessor, read_glb, write_glb  # noqa: E402


class Unsupported(Exception):
    """Something in the scene this check does not render; main names the file."""


def node_matrix(nd):
    if "matrix" in nd:
        return np.array(nd["matrix"], float).reshape(4, 4).T
    x, y, z, w = nd.get("rotation", [0, 0, 0, 1])
    r = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    m = np.eye(4)
    m[:3, :3] = r @ np.diag(nd.get("scale", [1, 1, 1]))
    m[:3, 3] = nd.get("translation", [0, 0, 0])
    return m


def edit(j, drop, lift):
    """Drop the nodes whose names contain a string of `drop`; move those matching `lift`
    (names, metres) up along glTF's +Y."""
    scene = j["scenes"][j.get("scene", 0)]
    scene["nodes"] = [i for i in scene["nodes"] if not any(s in j["nodes"][i].get("name", "") for s in drop)]
    names, dy = lift
    for nd in j["nodes"]:
        if any(s in nd.get("name", "") for s in names):
            if "matrix" in nd:
                nd["matrix"][13] += dy
            else:
                nd["translation"] = list(nd.get("translation", [0, 0, 0]))
                nd["translation"][1] += dy


def bsdf(j, index):
    m = j["materials"][index]
    pbr = m.get("pbrMetallicRoughness", {})
    ext = m.get("extensions", {})
    name = m.get("name", index)
    if "baseColorTexture" in pbr or any(m.get("emissiveFactor", [0, 0, 0])):
        raise Unsupported(f"material {name}: textures and emission are not handled")
    base = pbr.get("baseColorFactor", [1, 1, 1, 1])[:3]
    glass = ext.get("KHR_materials_transmission", {}).get("transmissionFactor", 0) > 0
    metal = pbr.get("metallicFactor", 1.0) > 0.5
    if (glass or metal) and pbr.get("roughnessFactor", 1.0) != 0:
        raise Unsupported(f"material {name}: rough glass and metal are not handled")
    if glass:
        ior = ext.get("KHR_materials_ior", {}).get("ior", 1.5)
        return {"type": "dielectric", "int_ior": ior, "ext_ior": 1.0}
    if metal:
        return {"type": "principled", "base_color": {"type": "rgb", "value": base}, "metallic": 1.0, "roughness": 0.0}
    if ext.get("KHR_materials_specular", {}).get("specularFactor", 1.0) != 0:
        raise Unsupported(f"material {name}: only Lambert (specularFactor 0), glass and metal are handled")
    return {"type": "diffuse", "reflectance": {"type": "rgb", "value": base}}


def write_ply(path, p, n, tris):
    v = np.hstack([p, n]).astype("<f4")
    faces = np.zeros(len(tris), dtype=[("n", "u1"), ("i", "<u4", 3)])
    faces["n"], faces["i"] = 3, tris
    with open(path, "wb") as f:
        f.write(
            (
                f"ply\nformat binary_little_endian 1.0\nelement vertex {len(p)}\n"
                + "".join(f"property float {c}\n" for c in ("x", "y", "z", "nx", "ny", "nz"))
                + f"element face {len(tris)}\nproperty list uchar uint vertex_indices\nend_header\n"
            ).encode()
        )
        f.write(v.tobytes() + faces.tobytes())


def scene_dict(j, binary, camera, spp, max_depth, workdir):
    d = {"type": "scene", "integrator": {"type": "ptracer", "max_depth": max_depth, "hide_emitters": True}}
    lights = j.get("extensions", {}).get("KHR_lights_punctual", {}).get("lights", [])
    for k in j["scenes"][j.get("scene", 0)]["nodes"]:
        nd = j["nodes"][k]
        name = nd.get("name", f"node{k}")
        if nd.get("children"):
            raise Unsupported(f"node {name}: node hierarchies are not handled (flat node lists only)")
        m = node_matrix(nd)
        if "mesh" in nd:
            for pi, prim in enumerate(j["meshes"][nd["mesh"]]["primitives"]):
                if prim.get("mode", 4) != 4 or "NORMAL" not in prim["attributes"]:
                    raise Unsupported(f"node {name}: only triangle meshes with normals are handled")
                p = accessor(j, binary, prim["attributes"]["POSITION"]).astype(float) @ m[:3, :3].T + m[:3, 3]
                n = accessor(j, binary, prim["attributes"]["NORMAL"]).astype(float) @ np.linalg.inv(m[:3, :3])
                n /= np.linalg.norm(n, axis=1, keepdims=True)
                tris = accessor(j, binary, prim["indices"]).astype(np.uint32).reshape(-1, 3)
                ply = os.path.join(workdir, f"{k}_{pi}.ply")
                write_ply(ply, p, n, tris)
                d[f"{name}_{pi}"] = {"type": "ply", "filename": ply, "bsdf": bsdf(j, prim["material"])}
        elif nd.get("camera") == camera:
            cam = j["cameras"][camera]["perspective"]
            d["sensor"] = {
                "type": "perspective",
                "fov": float(np.degrees(cam["yfov"])),
                "fov_axis": "y",
                # glTF cameras look down -Z with +X right; Mitsuba's look down +Z with +X left.
                "to_world": np.asarray(m @ np.diag([-1, 1, -1, 1])),
                "film": {"type": "hdrfilm", "width": 640, "height": 480, "rfilter": {"type": "box"}, "pixel_format": "rgb"},
                "sampler": {"type": "independent", "sample_count": spp},
            }
        elif "KHR_lights_punctual" in nd.get("extensions", {}):
            light = lights[nd["extensions"]["KHR_lights_punctual"]["light"]]
            power = {"type": "rgb", "value": (np.array(light.get("color", [1, 1, 1])) * light["intensity"] / 683).tolist()}
            if light["type"] == "point":
                d[name] = {"type": "point", "position": m[:3, 3].tolist(), "intensity": power}
            elif light["type"] == "directional":
                forward = -m[:3, 2] / np.linalg.norm(m[:3, 2])
                d[name] = {"type": "directional", "direction": forward.tolist(), "irradiance": power}
            else:
                raise Unsupported(f"light {name}: {light['type']} lights are not handled (point and directional only)")
    if "sensor" not in d:
        raise Unsupported(f"no camera {camera} among the scene's nodes")
    return d


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("glb")
    ap.add_argument("output", help="the EXR written")
    ap.add_argument("--camera", type=int, default=0, help="glTF camera index (default 0)")
    ap.add_argument("--spp", type=int, default=256, help="light paths per pixel of the image (default 256)")
    ap.add_argument("--max-depth", type=int, default=12, help="path segments at most, as Mitsuba counts (default 12)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--drop", default="", help="leave out the nodes whose names contain any of these (comma-separated)")
    ap.add_argument("--lift", default="", help="NAMES:METRES: move the nodes whose names contain any of NAMES up")
    ap.add_argument("--write-glb", help="also write the edited scene as a .glb (for photongrid)")
    a = ap.parse_args()
    import mitsuba as mi

    mi.set_variant(os.environ.get("MI_VARIANT", "scalar_rgb"))
    j, binary = read_glb(a.glb)
    names, _, dy = a.lift.rpartition(":")
    edit(j, [s for s in a.drop.split(",") if s], ([s for s in names.split(",") if s], float(dy or 0)))
    if a.write_glb:
        write_glb(a.write_glb, j, binary)
    with tempfile.TemporaryDirectory() as work:
        try:
            d = scene_dict(j, binary, a.camera, a.spp, a.max_depth, work)
        except Unsupported as e:
            sys.exit(f"{a.glb}: {e}")
        d["sensor"]["to_world"] = mi.ScalarTransform4f(d["sensor"]["to_world"].tolist())
        t = time.time()
        image = mi.render(mi.load_dict(d), seed=a.seed)
    mi.util.write_bitmap(a.output, image)
    print(f"{a.output}: {time.time() - t:.1f} s", file=sys.stderr)


if __name__ == "__main__":
    main()
