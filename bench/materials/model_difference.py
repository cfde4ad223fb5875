#!/usr/bin/env python3
"""The "Principled BSDF vs glTF BRDF" difference, measured on one sphere under a sun.

    nice -n 19 ~/.cache/photongrid/venv-bpy-5.0.1/bin/python bench/materials/model_difference.py \
        [--refs bench/materials/refs] [--blend-dir out/materials/blend] [--no-cycles-variants]

For mat_sphere_single (rough red dielectric) and mat_sphere_single_metal (rough gold), it computes
in numpy the image that the glTF 2.0 metallic-roughness BRDF (specification, Appendix B) gives
for the exported scene: orthographic camera rays hit the analytic sphere (r 1 m at the origin),
radiance = f(V, L) * max(N.L, 0) * E_sun, E_sun = lux / 683, no shadowing but the sphere's own
(N.L <= 0), black world, no interreflection (a convex object), 8x8 sub-pixel samples per pixel
(box filter 1 px like the references). All parameters are read from the exported GLB's
description (<scene>.scene.json: glTF camera, light, material).

    D   = a^2 X+(N.H) / (pi ((N.H)^2 (a^2 - 1) + 1)^2),     a = roughness^2
    Vis = X+(H.L) X+(H.V) / (2 (|N.V| sqrt(a^2 + (1-a^2)(N.L)^2) + |N.L| sqrt(a^2 + (1-a^2)(N.V)^2)))
    dielectric = mix(baseColor/pi, Vis D, F),  F = f0 + (1 - f0)(1 - |V.H|)^5,  f0 = 0.04
                 (f0 = ((ior-1)/(ior+1))^2 * specularFactor with KHR_materials_ior/specular)
    metal      = Vis D (baseColor + (1 - baseColor)(1 - |V.H|)^5)
    material   = mix(dielectric, metal, metallic)

It compares that image with the Cycles reference (refs/<scene>_cam0.exr): mean luminance ratio
glTF/Cycles, 8x8-block relative RMSE and per-pixel relative RMSE (score.py's definitions, the
Cycles image as the reference), and the ratio in bins of N.L and N.V.

With Cycles variants (default on) it also renders, from the same .blend at 64 spp:
  * the Principled BSDF with distribution "GGX" (single scattering) instead of the default
    "Multiscatter GGX", to separate the multiple-scattering energy compensation from the rest;
  * for the dielectric, a pure Lambert sanity check (Specular IOR Level 0, roughness 1),
    compared with baseColor/pi * N.L * E: checks camera, units and normals of this comparison.
Results go to refs/model_difference.json (and are quoted in README.md).

With --ms (numpy only, no Cycles, ~1 min) it computes instead the same model with Cycles'
multiple-scattering compensation (microfacet_ggx_preserve_energy: the lobe times
1 + F_ms (1 - E(N.V)) / E(N.V), F_ms = F_avg E_avg / (1 - F_avg (1 - E_avg)), F_avg = f0 + (1 - f0)/21,
E the F = 1 single-scattering albedo, here by brute-force integration), on the metal lobe (what
photongrid renders: refs/<scene>_cam0.gltf_ms_model.exr for the metal sphere) and additionally on the dielectric's
specular lobe, and compares them with Cycles: refs/model_difference_ms.json.
"""
import argparse
import json
import math
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, '..', '..', 'tools'))
from image_stats import blocks  # noqa: E402

LUM = np.array([0.2126, 0.7152, 0.0722])
SUB = 8  # sub-pixel samples per axis


def read_exr(path):
    import OpenEXR
    ch = OpenEXR.File(path, separate_channels=True).channels()
    return np.stack([np.asarray(ch[c].pixels, dtype=np.float64) for c in "RGB"], axis=-1)


def compare(img, ref, keep=None, blk=8):
    """score.py's metrics (luminance; 'rel' = / reference mean), ref = Cycles."""
    li, lr = img @ LUM, ref @ LUM
    if keep is None:
        keep = np.ones(li.shape, bool)
    mi, mr = li[keep].mean(), lr[keep].mean()
    bi = blocks(np.where(keep, li, 0.0), blk)
    br = blocks(np.where(keep, lr, 0.0), blk)
    full = blocks(keep.astype(float), blk) > 0.999
    db = (bi - br)[full]
    return {
        "mean_lum_ratio": float(mi / mr),
        "rgb_mean_ratio": [float(img[..., c][keep].mean() / ref[..., c][keep].mean()) for c in range(3)],
        "block_rel_rmse": float(np.sqrt(np.mean(db ** 2)) / mr),
        "rel_rmse": float(np.sqrt(np.mean((li - lr)[keep] ** 2)) / mr),
    }


# ---------------------------------------------------------------------------------------------
# glTF 2.0 Appendix B BRDF
# ---------------------------------------------------------------------------------------------
def ggx_albedo(alpha, mus, nt=800, nphi=400):
    """E(mu) = int D G2 / (4 mu) dw_i of single-scattering GGX (F = 1, height-correlated Smith),
    brute force: midpoint rule in (theta_i, phi_i), phi over [0, pi] (symmetric)."""
    a2 = alpha * alpha
    th = (np.arange(nt) + 0.5) * (math.pi / 2 / nt)
    ph = (np.arange(nphi) + 0.5) * (math.pi / nphi)
    T, P = np.meshgrid(th, ph, indexing="ij")
    i = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1)
    lam = lambda c: 0.5 * (-1 + np.sqrt(1 + a2 * (1 - c * c) / np.maximum(c * c, 1e-12)))
    out = []
    for mu in mus:
        o = np.array([math.sqrt(max(1 - mu * mu, 0.0)), 0.0, mu])
        h = i + o
        h /= np.linalg.norm(h, axis=-1, keepdims=True)
        D = a2 / (math.pi * (h[..., 2] ** 2 * (a2 - 1) + 1) ** 2)
        G2 = 1 / (1 + lam(mu) + lam(i[..., 2]))
        out.append(2 * np.sum(D * G2 / (4 * mu) * np.sin(T)) * (math.pi / 2 / nt) * (math.pi / nphi))
    return np.array(out)


def ms_compensation(alpha, nodes=96):
    """Cycles' multiple-scattering factor as a function of (N.V, F_avg) for one alpha."""
    mus = (np.arange(nodes) + 0.5) / nodes
    E = ggx_albedo(alpha, mus)
    E_avg = float(np.sum(2 * E * mus) / nodes)

    def factor(nv, f0):
        e = np.interp(np.clip(nv, 0, 1), mus, E)[..., None]
        f_avg = f0 + (1 - f0) / 21
        f_ms = f_avg * E_avg / (1 - f_avg * (1 - E_avg))
        return 1 + f_ms * (1 - e) / e
    factor.E_avg, factor.E_at_1 = E_avg, float(np.interp(1.0, mus, E))
    return factor


def gltf_brdf(n, v, l, base, metallic, roughness, f0_diel=0.04, ms=None, ms_dielectric=False):
    """n, v, l: (..., 3) unit vectors; base (3,); returns f (..., 3). ms: ms_compensation(alpha)
    for the metal lobe (and the dielectric's specular lobe with ms_dielectric)."""
    a = roughness ** 2
    a2 = a * a
    h = v + l
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    nh = np.sum(n * h, -1)
    nl = np.sum(n * l, -1)
    nv = np.sum(n * v, -1)
    vh = np.sum(v * h, -1)
    lh = np.sum(l * h, -1)
    D = a2 * (nh > 0) / (math.pi * (nh * nh * (a2 - 1) + 1) ** 2)
    anl, anv = np.abs(nl), np.abs(nv)
    den = 2 * (anv * np.sqrt(a2 + (1 - a2) * nl * nl) + anl * np.sqrt(a2 + (1 - a2) * nv * nv))
    Vis = np.where(den > 0, (lh > 0) * (vh > 0) / np.maximum(den, 1e-30), 0.0)
    spec = (Vis * D)[..., None]
    w = ((1 - np.abs(vh)) ** 5)[..., None]
    F_d = f0_diel + (1 - f0_diel) * w
    m_metal = m_diel = 1.0
    if ms is not None:
        m_metal = ms(anv, base)
        if ms_dielectric:
            m_diel = ms(anv, np.full(3, f0_diel))
    dielectric = (1 - F_d) * base / math.pi + F_d * spec * m_diel
    metal = spec * (base + (1 - base) * w) * m_metal
    return (1 - metallic) * dielectric + metallic * metal


def material_params(gm):
    pbr = gm.get("pbrMetallicRoughness", {})
    base = np.array(pbr.get("baseColorFactor", [1, 1, 1, 1])[:3], dtype=np.float64)
    metallic = float(pbr.get("metallicFactor", 1.0))
    rough = float(pbr.get("roughnessFactor", 1.0))
    ext = gm.get("extensions", {})
    ior = float(ext.get("KHR_materials_ior", {}).get("ior", 1.5))
    spec = float(ext.get("KHR_materials_specular", {}).get("specularFactor", 1.0))
    f0 = ((ior - 1) / (ior + 1)) ** 2 * spec
    return base, metallic, rough, f0


def gltf_image(desc, base=None, metallic=None, rough=None, f0=None, lambert=False, ms=None, ms_dielectric=False):
    """Render the analytic sphere with the glTF BRDF for the exported camera and sun."""
    cam = desc["cameras"][0]
    w, h = desc["render"]["resolution"]
    xmag, ymag = cam["gltf"]["orthographic"]["xmag"], cam["gltf"]["orthographic"]["ymag"]
    sun = desc["lights"][0]
    E = sun["gltf"]["intensity"] / 683.0
    col = np.array(sun["gltf"].get("color", [1, 1, 1]), dtype=np.float64)
    dg = np.array(sun["direction_gltf"], dtype=np.float64)   # direction the light travels (glTF)
    # work in Blender coordinates (the scene.json has both): camera at -Y looking +Y, up +Z
    db = np.array(sun["direction_blender"], dtype=np.float64)
    assert np.allclose(dg, [db[0], db[2], -db[1]], atol=1e-6)
    L = -db / np.linalg.norm(db)
    fwd = np.array(cam["forward_blender"], dtype=np.float64)
    assert np.allclose(fwd, [0, 1, 0], atol=1e-6), fwd
    V = -fwd
    gm = desc["materials"][0]["gltf"]
    b0, m0, r0, f00 = material_params(gm)
    base = b0 if base is None else base
    metallic = m0 if metallic is None else metallic
    rough = r0 if rough is None else rough
    f0 = f00 if f0 is None else f0
    out = np.zeros((h, w, 3))
    t = (np.arange(SUB) + 0.5) / SUB
    for sy in t:
        for sx in t:
            px = (np.arange(w) + sx) / w * 2 * xmag - xmag          # Blender x
            pz = ymag - (np.arange(h) + sy) / h * 2 * ymag           # Blender z
            X, Z = np.meshgrid(px, pz)
            r2 = X * X + Z * Z
            hit = r2 < 1.0
            Y = -np.sqrt(np.clip(1 - r2, 0, 1))
            n = np.stack([X, Y, Z], -1)
            n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-30)
            v = np.broadcast_to(V, n.shape)
            l = np.broadcast_to(L, n.shape)
            nl = np.sum(n * l, -1)
            if lambert:
                f = np.broadcast_to(base / math.pi, n.shape)
            else:
                f = gltf_brdf(n, v, l, base, metallic, rough, f0, ms, ms_dielectric)
            rad = f * (np.clip(nl, 0, None) * E)[..., None] * col
            out += np.where(hit[..., None], rad, 0.0)
    return out / (SUB * SUB)


def angle_maps(desc):
    """Per-pixel N.L and N.V at the pixel centre (nan off the sphere)."""
    cam = desc["cameras"][0]
    w, h = desc["render"]["resolution"]
    xmag, ymag = cam["gltf"]["orthographic"]["xmag"], cam["gltf"]["orthographic"]["ymag"]
    db = np.array(desc["lights"][0]["direction_blender"])
    L = -db / np.linalg.norm(db)
    px = (np.arange(w) + 0.5) / w * 2 * xmag - xmag
    pz = ymag - (np.arange(h) + 0.5) / h * 2 * ymag
    X, Z = np.meshgrid(px, pz)
    r2 = X * X + Z * Z
    Y = -np.sqrt(np.clip(1 - r2, 0, 1))
    n = np.stack([X, Y, Z], -1)
    nl = np.where(r2 < 0.98, n @ L, np.nan)
    nv = np.where(r2 < 0.98, -Y, np.nan)   # r < 0.99: leaves out the silhouette pixels
    return nl, nv


def binned_ratio(img, ref, x, edges):
    li, lr = img @ LUM, ref @ LUM
    out = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        m = (x >= lo) & (x < hi)
        if m.sum() > 50 and lr[m].mean() > 0:
            out.append({"range": [round(lo, 2), round(hi, 2)], "pixels": int(m.sum()),
                        "ratio_gltf_over_cycles": round(float(li[m].mean() / lr[m].mean()), 4)})
    return out


def render_cycles_variant(blend, out_exr, distribution=None, lambert=False, spp=64, reuse=False):
    if reuse and os.path.exists(out_exr):
        return read_exr(out_exr)
    import bpy
    sys.path.insert(0, HERE)
    import render_refs
    bpy.ops.wm.open_mainfile(filepath=os.path.abspath(blend))
    sc = bpy.context.scene
    for m in bpy.data.materials:
        if not m.node_tree:
            continue
        for nd in m.node_tree.nodes:
            if nd.type == "BSDF_PRINCIPLED":
                if distribution:
                    nd.distribution = distribution
                if lambert:
                    nd.inputs["Specular IOR Level"].default_value = 0.0
                    nd.inputs["Roughness"].default_value = 1.0
                    nd.inputs["Metallic"].default_value = 0.0
    render_refs.setup_cycles(sc, spp, seed=7)
    sc.render.resolution_percentage = 100
    sc.render.filepath = out_exr
    bpy.ops.render.render(write_still=True)
    return read_exr(out_exr)


def main(argv):
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes-dir", default=HERE)
    ap.add_argument("--refs", default=os.path.join(HERE, "refs"))
    ap.add_argument("--blend-dir", default=os.path.join(HERE, "..", "..", "out", "materials", "blend"))
    ap.add_argument("--work", default=os.path.join(HERE, "..", "..", "out", "materials", "model_diff"))
    ap.add_argument("--no-cycles-variants", action="store_true")
    ap.add_argument("--reuse", action="store_true", help="reuse the variant renders in --work if present")
    ap.add_argument("--ms", action="store_true", help="the model with multiple-scattering compensation instead")
    a = ap.parse_args(argv)
    if a.ms:
        return main_ms(a)
    os.makedirs(a.work, exist_ok=True)
    result = {"_about": __doc__.split("\n\n")[1].strip(),
              "metrics": "mean_lum_ratio = glTF-model / Cycles; block_rel_rmse, rel_rmse: score.py definitions "
                         "with the Cycles image as the reference (whole image; the background is 0 in both)"}
    for name in ("mat_sphere_single", "mat_sphere_single_metal"):
        desc = json.load(open(os.path.join(a.scenes_dir, name + ".scene.json")))
        ref = read_exr(os.path.join(a.refs, name + "_cam0.exr"))
        g = gltf_image(desc)
        from render_refs import write_exr_half
        # the glTF-model image: what a renderer implementing Appendix B exactly should produce
        write_exr_half(os.path.join(a.refs, name + "_cam0.gltf_model.exr"), g)
        nl, nv = angle_maps(desc)
        on = np.isfinite(nv)  # pixel centre inside 0.99 r: the sphere without its silhouette pixels
        r = {"material_gltf": desc["materials"][0]["gltf"],
             "sun_lux": desc["lights"][0]["gltf"]["intensity"],
             "vs_cycles_reference (Principled, Multiscatter GGX)": compare(g, ref),
             "vs_cycles_reference, sphere pixels only": compare(g, ref, on),
             "ratio_by_NdotL": binned_ratio(g, ref, nl, [0, 0.1, 0.2, 0.4, 0.6, 0.8, 1.01]),
             "ratio_by_NdotV": binned_ratio(g, ref, nv, [0, 0.2, 0.4, 0.6, 0.8, 1.01]),
             "silhouette_pixels_gltf_vs_cycles": [int(((g @ LUM) > 0).sum()), int(((ref @ LUM) > 0).sum())]}
        if not a.no_cycles_variants:
            blend = os.path.join(a.blend_dir, name + ".blend")
            single = render_cycles_variant(blend, os.path.join(a.work, name + ".cycles_ggx.exr"), distribution="GGX",
                                           reuse=a.reuse)
            r["vs_cycles_single_scatter_GGX (64 spp)"] = compare(g, single)
            r["vs_cycles_single_scatter_GGX (64 spp), sphere pixels only"] = compare(g, single, on)
            r["cycles_multiscatter_over_single_scatter_mean"] = float((ref @ LUM).mean() / (single @ LUM).mean())
            if name == "mat_sphere_single":
                lam = render_cycles_variant(blend, os.path.join(a.work, name + ".cycles_lambert.exr"), lambert=True,
                                            reuse=a.reuse)
                base = material_params(desc["materials"][0]["gltf"])[0]
                gl = gltf_image(desc, base=base, lambert=True)
                r["sanity_lambert_analytic_vs_cycles (64 spp)"] = compare(gl, lam)
                r["sanity_lambert_analytic_vs_cycles (64 spp), sphere pixels only"] = compare(gl, lam, on)
        result[name] = r
        print(json.dumps({name: r}, indent=1), flush=True)
    with open(os.path.join(a.refs, "model_difference.json"), "w") as f:
        json.dump(result, f, indent=1)


def write_exr_half(path, rgb):
    """render_refs.write_exr_half without importing bpy (half float RGB, ZIP)."""
    import OpenEXR
    rgb = np.asarray(rgb, dtype=np.float32)
    chans = {c: rgb[..., i].astype(np.float16) for i, c in enumerate("RGB")}
    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}, chans).write(path)


def main_ms(a):
    result = {"_about": __doc__.split("\n\n")[-1].strip(),
              "metrics": "as model_difference.json; 'sphere pixels' leaves out the background and silhouette"}
    for name in ("mat_sphere_single", "mat_sphere_single_metal"):
        desc = json.load(open(os.path.join(a.scenes_dir, name + ".scene.json")))
        ref = read_exr(os.path.join(a.refs, name + "_cam0.exr"))
        rough = material_params(desc["materials"][0]["gltf"])[2]
        ms = ms_compensation(rough ** 2)
        nl, nv = angle_maps(desc)
        on = np.isfinite(nv)
        r = {"alpha": rough ** 2, "E(1)": ms.E_at_1, "E_avg": ms.E_avg}
        for key, kw in (("single scattering (glTF spec)", {}),
                        ("metal compensated", {"ms": ms}),
                        ("metal and dielectric specular compensated", {"ms": ms, "ms_dielectric": True})):
            g = gltf_image(desc, **kw)
            if key == "metal compensated" and material_params(desc["materials"][0]["gltf"])[1] > 0:
                write_exr_half(os.path.join(a.refs, name + "_cam0.gltf_ms_model.exr"), g)
            r[key] = {"whole image": compare(g, ref), "sphere pixels": compare(g, ref, on),
                      "ratio_by_NdotV": binned_ratio(g, ref, nv, [0, 0.2, 0.4, 0.6, 0.8, 1.01])}
        result[name] = r
        print(json.dumps({name: r}, indent=1), flush=True)
    with open(os.path.join(a.refs, "model_difference_ms.json"), "w") as f:
        json.dump(result, f, indent=1)


if __name__ == "__main__":
    sys.path.insert(0, HERE)
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:]
    main(argv)
