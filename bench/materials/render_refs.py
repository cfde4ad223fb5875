#!/usr/bin/env python3
"""Render the Cycles references of the material scenes from their .blend files.

    nice -n 19 ~/.cache/photongrid/venv-bpy-5.0.1/bin/python bench/materials/render_refs.py \
        [--blend-dir out/materials/blend] [--out bench/materials/refs] [--only mat_spheres,...]
        [--passes N] [--spp mat_spheres=768,...] [--scale 1.0] [--work out/materials/passes] [--resume]

For every scene (one camera each) it renders N independent Cycles passes with seeds 1..N
(spp / N samples each; defaults per scene below) and writes

  refs/<scene>_cam0.exr           mean of the passes (the reference), half float, ZIP
  refs/<scene>_cam0.stderr.exr    per-pixel standard error of that mean (std of passes / sqrt(N))
  refs/<scene>_cam0.specmask.exr  1 where the camera first sees glass or a mirror (material
                                  index pass; pass_index 1 is set on those materials)
  refs/refs.json                  settings, spp, seconds, mean luminance/rgb, noise, validity

Cycles settings (all set here, whatever the .blend says): CPU, 2 threads, no adaptive
sampling, no denoising, no clamping, Filter Glossy 0, caustics on, max bounces 24 (diffuse,
glossy, transmission 24, transparent 32), box pixel filter 1 px, view transform Standard,
EXR written scene-linear float32 and converted to half by this script.
"""
import argparse
import json
import math
import os
import sys
import time

import bpy
import numpy as np
import OpenEXR

HERE = os.path.dirname(os.path.abspath(__file__))
LUM = np.array([0.2126, 0.7152, 0.0722])

# total samples per scene (split over the passes); chosen from the measured time per sample so
# that the whole set takes about 2 h of CPU (README: timings)
DEFAULT_SPP = {
    "mat_spheres": 768,
    "mat_leaves": 3072,
    "mat_punctual": 2048,
    "mat_sphere_single": 256,
    "mat_sphere_single_metal": 256,
}
# independent passes per scene (for the per-pixel standard error); mat_punctual got 8 more
# passes after the first 8 (same seeds 1..8, then 9..16)
DEFAULT_PASSES = {"mat_punctual": 16}
# resolution scale per scene (1.0 = 640x480): the room scenes at 320x240 to stay within ~2 h CPU
DEFAULT_SCALE = {
    "mat_spheres": 0.5,
    "mat_leaves": 0.5,
    "mat_punctual": 0.5,
    "mat_sphere_single": 1.0,
    "mat_sphere_single_metal": 1.0,
}
SCENES = list(DEFAULT_SPP)

VALIDITY = {
    "mat_spheres": ("yes", "Only emissive lights (ceiling quad, textured screen): Cycles path traces all "
                    "transport, including light reflected by the rough metal onto the floor (noisy there). "
                    "No glass or mirror: the specmask is empty."),
    "mat_punctual": ("yes", "Point and spot light (delta) but no smooth glass or mirror: every light path has "
                     "a non-delta vertex where Cycles connects to the light (the rough gold sphere's "
                     "reflection of the point/spot light onto the floor is rendered, noisily). "
                     "The specmask is empty."),
    "mat_leaves": ("yes, noisy behind the frosted panel", "Sun (delta) through the rough (0.3) frosted slab: "
                   "Cycles reaches the sun by next-event estimation from the slab's far face (a rough "
                   "interface), so the sun's light through the panel is present, but it converges slowly "
                   "(fireflies in the panel's sun shadow). The specmask marks the pixels where the camera "
                   "sees the panel first."),
    "mat_sphere_single": ("yes", "Direct sun light on one convex sphere: converged quickly."),
    "mat_sphere_single_metal": ("yes", "Direct sun light on one convex sphere: converged quickly."),
}


def read_exr_rgb(path):
    ch = OpenEXR.File(path, separate_channels=True).channels()
    return np.stack([np.asarray(ch[c].pixels, dtype=np.float64) for c in "RGB"], axis=-1)


def read_exr_channel(path, name):
    """A channel of a (Blender 5.0: multi-part) multilayer EXR whose name contains `name`."""
    f = OpenEXR.File(path, separate_channels=True)
    for part in f.parts:
        for k, c in part.channels.items():
            if name in k:
                return np.asarray(c.pixels, dtype=np.float64)
    raise KeyError("%s not in %s" % (name, [list(p.channels) for p in f.parts]))


def write_exr_half(path, rgb):
    rgb = np.asarray(rgb, dtype=np.float32)
    chans = {c: rgb[..., i].astype(np.float16) for i, c in enumerate("RGB")}
    hdr = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(hdr, chans).write(path)


def write_preview(path, rgb):
    """sRGB PNG preview (clipped at 1) of a linear image."""
    import struct
    import zlib
    x = np.clip(rgb, 0, 1)
    x = np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)
    q = np.round(x * 255).astype(np.uint8)
    h, w, _ = q.shape
    raw = b"".join(b"\x00" + q[i].tobytes() for i in range(h))

    def chunk(tag, data):
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)
    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
                + chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b""))


def previews(out):
    os.makedirs(os.path.join(out, "preview"), exist_ok=True)
    for f in sorted(os.listdir(out)):
        if f.endswith("_cam0.exr") or (f.endswith(".exr") and "_cam" in f and f.count(".") == 1):
            write_preview(os.path.join(out, "preview", f[:-4] + ".png"), read_exr_rgb(os.path.join(out, f)))


def setup_cycles(sc, spp, seed, threads=2):
    cy = sc.cycles
    cy.device = "CPU"
    cy.samples = spp
    cy.use_adaptive_sampling = False
    cy.use_denoising = False
    cy.seed = seed
    cy.use_animated_seed = False
    cy.max_bounces = 24
    cy.diffuse_bounces = 24
    cy.glossy_bounces = 24
    cy.transmission_bounces = 24
    cy.volume_bounces = 0
    cy.transparent_max_bounces = 32
    cy.sample_clamp_direct = 0.0
    cy.sample_clamp_indirect = 0.0
    cy.blur_glossy = 0.0
    cy.caustics_reflective = True
    cy.caustics_refractive = True
    cy.pixel_filter_type = "BOX"
    cy.filter_width = 1.0
    cy.use_light_tree = True
    sc.render.threads_mode = "FIXED"
    sc.render.threads = threads
    sc.render.film_transparent = False
    sc.render.use_persistent_data = False
    sc.view_settings.view_transform = "Standard"
    sc.view_settings.look = "None"
    sc.view_settings.exposure = 0.0
    sc.view_settings.gamma = 1.0
    im = sc.render.image_settings
    im.file_format = "OPEN_EXR"
    im.color_depth = "32"
    im.exr_codec = "ZIP"
    im.color_mode = "RGB"


def settings_record(sc):
    cy = sc.cycles
    keys = ["samples", "use_adaptive_sampling", "use_denoising", "max_bounces", "diffuse_bounces",
            "glossy_bounces", "transmission_bounces", "volume_bounces", "transparent_max_bounces",
            "sample_clamp_direct", "sample_clamp_indirect", "blur_glossy", "caustics_reflective",
            "caustics_refractive", "pixel_filter_type", "filter_width", "use_light_tree",
            "sampling_pattern"]
    d = {k: getattr(cy, k) for k in keys if hasattr(cy, k)}
    d["threads"] = sc.render.threads
    d["view_transform"] = sc.view_settings.view_transform
    d["exr"] = "scene-linear float32 from Cycles, stored as half float ZIP"
    return d


def render_mask(sc, path):
    """1 where the camera first sees a material with pass_index 1 (glass/mirror): material index
    pass, 4 spp with the same box filter (each pixel keeps its last sample's index, so the mask is
    binary); alpha-clipped leaf texels are skipped by Cycles as for the beauty pass."""
    vl = sc.view_layers[0]
    vl.use_pass_material_index = True
    sc.cycles.samples = 4
    im = sc.render.image_settings
    im.media_type = "MULTI_LAYER_IMAGE"  # Blender 5.0: multilayer EXR is a media type
    im.file_format = "OPEN_EXR_MULTILAYER"
    sc.render.filepath = path
    bpy.ops.render.render(write_still=True)
    m = read_exr_channel(path, "Material Index")
    vl.use_pass_material_index = False
    im.media_type = "IMAGE"
    im.file_format = "OPEN_EXR"
    return (np.abs(m - 1.0) < 0.5).astype(np.float64)


def main(argv):
    ap = argparse.ArgumentParser()
    ap.add_argument("--blend-dir", default=os.path.join(HERE, "..", "..", "out", "materials", "blend"))
    ap.add_argument("--out", default=os.path.join(HERE, "refs"))
    ap.add_argument("--work", default=os.path.join(HERE, "..", "..", "out", "materials", "passes"))
    ap.add_argument("--only", default="")
    ap.add_argument("--passes", type=int, default=None, help="default 8 (mat_punctual 16)")
    ap.add_argument("--spp", default="", help="scene=spp,... (total over the passes)")
    ap.add_argument("--scale", type=float, default=None,
                    help="resolution scale for all scenes (0.5 = 320x240); default per scene")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--previews-only", action="store_true", help="only (re)write refs/preview/*.png")
    ap.add_argument("--resume", action="store_true",
                    help="reuse pass EXRs in --work rendered with the same spp, seed and size")
    a = ap.parse_args(argv)
    if a.previews_only:
        previews(a.out)
        return
    spp = dict(DEFAULT_SPP)
    for kv in filter(None, a.spp.split(",")):
        k, v = kv.split("=")
        spp[k] = int(v)
    os.makedirs(a.out, exist_ok=True)
    os.makedirs(a.work, exist_ok=True)
    names = [s for s in a.only.split(",") if s] or SCENES
    jpath = os.path.join(a.out, "refs.json")
    refs = json.load(open(jpath)) if os.path.exists(jpath) else {}
    refs["_about"] = {
        "reference": "Blender 5.0.1 Cycles (CPU, path tracing with NEE/MIS and light tree) from the .blend "
                     "that build_scenes.py saved; N independent passes with different seeds, merged by mean; "
                     "<scene>_cam<i>.stderr.exr is the per-pixel standard error of the mean (std of the "
                     "passes / sqrt(N)). Box pixel filter 1 px, linear Rec.709 radiance, half float ZIP EXR.",
        "specmask": "<scene>_cam<i>.specmask.exr is 1 where the camera first sees glass or a mirror "
                    "(Cycles material-index pass). Empty (all 0) in scenes without glass or mirrors.",
        "noise": "noise.rel_rmse_est = sqrt(mean(stderr_lum^2)) / mean(lum): the expected per-pixel relative "
                 "RMSE of the reference itself. Averaging 8x8 blocks divides it by about 8.",
        "settings": "see README.md and the 'cycles_settings' of each entry",
    }
    for name in names:
        blend = os.path.join(a.blend_dir, name + ".blend")
        bpy.ops.wm.open_mainfile(filepath=os.path.abspath(blend))
        sc = bpy.context.scene
        scale = a.scale if a.scale is not None else DEFAULT_SCALE[name]
        sc.render.resolution_percentage = int(round(100 * scale))
        w = sc.render.resolution_x * sc.render.resolution_percentage // 100
        h = sc.render.resolution_y * sc.render.resolution_percentage // 100
        cams = sorted([o for o in sc.objects if o.type == "CAMERA"], key=lambda o: o.name)
        for ci, cam in enumerate(cams):
            sc.camera = cam
            key = "%s_cam%d" % (name, ci)
            n = a.passes if a.passes is not None else DEFAULT_PASSES.get(name, 8)
            per = max(1, spp[name] // n)
            passes = []
            secs = 0.0
            cpu = 0.0
            load0 = os.getloadavg()[0]
            setup_cycles(sc, per, seed=1 + 1000 * ci, threads=a.threads)
            for i in range(n):
                seed = 1 + 1000 * ci + i
                p = os.path.join(a.work, "%s_pass%02d.exr" % (key, i))
                side = p[:-4] + ".json"
                meta = {"spp": per, "seed": seed, "resolution": [w, h]}
                if a.resume and os.path.exists(side):
                    old = json.load(open(side))
                    if all(old.get(k) == v for k, v in meta.items()) and os.path.exists(p):
                        passes.append(read_exr_rgb(p))
                        secs += old["seconds"]
                        cpu += old["cpu_seconds"]
                        print("%s pass %d/%d: reused %s" % (key, i + 1, n, p), flush=True)
                        continue
                setup_cycles(sc, per, seed=seed, threads=a.threads)
                sc.render.filepath = p
                t0, c0 = time.time(), time.process_time()
                bpy.ops.render.render(write_still=True)
                dt = time.time() - t0
                dc = time.process_time() - c0
                secs += dt
                cpu += dc
                with open(side, "w") as f:
                    json.dump(meta | {"seconds": dt, "cpu_seconds": dc}, f)
                passes.append(read_exr_rgb(p))
                print("%s pass %d/%d: %d spp, %.1f s" % (key, i + 1, n, per, dt), flush=True)
            stack = np.stack(passes)                       # (N, H, W, 3)
            mean = stack.mean(axis=0)
            se = stack.std(axis=0, ddof=1) / math.sqrt(n)
            lum_passes = stack @ LUM
            se_lum = lum_passes.std(axis=0, ddof=1) / math.sqrt(n)
            lum = mean @ LUM
            settings = settings_record(sc) | {"samples_per_pass": per}  # before the mask render
            mask = render_mask(sc, os.path.join(a.work, key + "_mask.exr"))
            write_exr_half(os.path.join(a.out, key + ".exr"), mean)
            write_exr_half(os.path.join(a.out, key + ".stderr.exr"), se)
            write_exr_half(os.path.join(a.out, key + ".specmask.exr"), np.repeat(mask[..., None], 3, -1))
            valid, note = VALIDITY.get(name, ("?", ""))
            refs[key] = {
                "scene": name + ".glb",
                "blend": name + ".blend",
                "camera_index": ci,
                "camera_name": cam.name,
                "reference": key + ".exr",
                "resolution": [w, h],
                "renderer": "Blender %s Cycles (CPU)" % bpy.app.version_string,
                "spp": per * n,
                "passes": n,
                "seeds": [1 + 1000 * ci + i for i in range(n)],
                "render_seconds_2_cores": round(secs, 1),
                "render_cpu_seconds": round(cpu, 1),
                "cpu_seconds_per_sample": round(cpu / (per * n), 4),
                "load_average_at_start": round(load0, 2),
                "mean_luminance": float(lum.mean()),
                "mean_rgb": [float(x) for x in mean.reshape(-1, 3).mean(axis=0)],
                "noise": {
                    "rel_rmse_est": float(np.sqrt(np.mean(se_lum ** 2)) / lum.mean()),
                    "rel_stderr_median": float(np.median(se_lum / np.maximum(lum, 1e-6 * lum.mean()))),
                    "block8_rel_rmse_est": float(np.sqrt(np.mean(se_lum ** 2)) / lum.mean() / 8),
                    "specular_pixel_fraction": float(mask.mean()),
                },
                "specmask": key + ".specmask.exr",
                "cycles_valid": valid,
                "cycles_valid_note": note,
                "cycles_settings": settings,
            }
            print(json.dumps({key: {k: refs[key][k] for k in ("spp", "render_seconds_2_cores", "render_cpu_seconds", "mean_luminance")} | {"rel_rmse_est": refs[key]["noise"]["rel_rmse_est"]}}), flush=True)
            with open(jpath, "w") as f:
                json.dump(refs, f, indent=1)
    previews(a.out)


if __name__ == "__main__":
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:]
    main(argv)
