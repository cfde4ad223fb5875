"""Block error of the material rooms split by what the blocks show (issue 10: separating the
Principled-vs-glTF model difference from this renderer's error).

    python3 bench/materials/room_regions.py masks OUTDIR [BIN]
        per room (mat_spheres, mat_punctual, mat_leaves) and material, a GLB in which only that material
        is emissive (1, everything else black), rendered by BIN (default
        target/release/photongrid) at 320x240 with --photons 0: OUTDIR/<scene>_<material>.exr
    python3 bench/materials/room_regions.py lambert SCENE OUT.glb [flat]
        the room with every material made Lambert (as cycles_lambert_variant.py does in Blender;
        `flat`: without normal maps too)
    python3 bench/materials/room_regions.py score SCENE MASKDIR IMG [REF]
        8x8-block relative RMSE (score.py's definition: over the image's mean) of IMG against
        REF (default: the Cycles reference) on the blocks that show Lambert materials only
        (specular 0: the same model in Cycles and glTF) and on the blocks that show any glossy
        material, with the reference's own block noise on each (from its stderr image)

A block belongs to a group when at least 99 % of its pixels' coverage is that group's
materials. Emissive materials (the lamp, the screen) count as Lambert.
"""
import json
import os
import subprocess
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, '..', '..', '..', 'shared', 'tools'))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, '..', '..', 'tools'))
from punctual_regions import BLACK, emissive, read_glb, write_glb  # noqa: E402
from image_stats import blocks  # noqa: E402

ROOMS = ['mat_spheres', 'mat_punctual', 'mat_leaves']
BLOCK = 8


def is_lambert(m):
    ext = m.get('extensions', {})
    return ext.get('KHR_materials_specular', {}).get('specularFactor', 1.0) == 0.0 \
        and m.get('pbrMetallicRoughness', {}).get('metallicFactor', 1.0) == 0.0


def masks(out, binary):
    import copy
    os.makedirs(out, exist_ok=True)
    for scene in ROOMS:
        j, b = read_glb(os.path.join(HERE, scene + '.glb'))
        kinds = {}
        for i, m in enumerate(j['materials']):
            k = copy.deepcopy(j)
            for n, other in enumerate(k['materials']):
                k['materials'][n] = emissive(other['name']) if n == i else dict(copy.deepcopy(BLACK), name=other['name'])
            glb = os.path.join(out, '%s_%s.glb' % (scene, m['name']))
            write_glb(glb, k, b)
            subprocess.run([binary, 'render', glb, '-o', glb[:-4] + '.exr', '--width', '320', '--height', '240',
                            '--photons', '0', '--spp', '4', '--progress', 'quiet'], check=True,
                           stderr=subprocess.DEVNULL)
            kinds[m['name']] = 'lambert' if is_lambert(m) or 'emissiveFactor' in m else 'glossy'
        json.dump(kinds, open(os.path.join(out, scene + '_kinds.json'), 'w'), indent=1)


def lambert(scene, out, flat=False):
    j, b = read_glb(os.path.join(HERE, scene + '.glb'))
    for m in j['materials']:
        if flat:
            m.pop('normalTexture', None)
        pbr = m.setdefault('pbrMetallicRoughness', {})
        pbr.pop('metallicRoughnessTexture', None)
        pbr['metallicFactor'], pbr['roughnessFactor'] = 0.0, 1.0
        ext = m.setdefault('extensions', {})
        ext['KHR_materials_specular'] = {'specularFactor': 0.0}
        ext.pop('KHR_materials_ior', None)
    used = j.setdefault('extensionsUsed', [])
    if 'KHR_materials_specular' not in used:
        used.append('KHR_materials_specular')
    write_glb(out, j, b)


def score(scene, maskdir, img_path, ref_path=None):
    import score as S
    ref_path = ref_path or os.path.join(HERE, 'refs', scene + '_cam0.exr')
    img, ref = S.read_exr(img_path), S.read_exr(ref_path)
    kinds = json.load(open(os.path.join(maskdir, scene + '_kinds.json')))
    cover = {g: np.zeros(img.shape[:2]) for g in ('lambert', 'glossy')}
    for name, kind in kinds.items():
        cover[kind] += np.clip(S.read_exr(os.path.join(maskdir, '%s_%s.exr' % (scene, name)))[..., 0], 0, 1)
    li, lr = img @ S.LUM, ref @ S.LUM
    mr = lr.mean()
    db = blocks(li) - blocks(lr)
    out = {'image': img_path, 'reference': ref_path, 'mean_lum_ratio': round(float(li.mean() / mr), 4),
           'block_rel_rmse_all': round(float(np.sqrt(np.mean(db ** 2)) / mr), 5)}
    stderr_path = ref_path.replace('.exr', '.stderr.exr')
    noise = None
    if os.path.exists(stderr_path):
        se = S.read_exr(stderr_path) @ S.LUM
        h, w = se.shape[0] // BLOCK * BLOCK, se.shape[1] // BLOCK * BLOCK
        noise = np.sqrt((se[:h, :w] ** 2).reshape(h // BLOCK, BLOCK, w // BLOCK, BLOCK).sum(axis=(1, 3))) / BLOCK ** 2
    total = sum(cover.values())
    for g, c in cover.items():
        sel = blocks(c / np.maximum(total, 1e-9)) >= 0.99
        d = db[sel]
        out[g] = {'blocks': int(sel.sum()),
                  'block_rel_rmse': round(float(np.sqrt(np.mean(d ** 2)) / mr), 5) if d.size else None,
                  'mean_ratio': round(float(blocks(li)[sel].mean() / blocks(lr)[sel].mean()), 4) if d.size else None}
        if noise is not None and d.size:
            out[g]['reference_block_noise'] = round(float(np.sqrt(np.mean(noise[sel] ** 2)) / mr), 5)
    print(json.dumps(out))


if __name__ == '__main__':
    if sys.argv[1] == 'masks':
        masks(sys.argv[2], sys.argv[3] if len(sys.argv) > 3 else os.path.join(HERE, '..', '..', 'target', 'release', 'photongrid'))
    elif sys.argv[1] == 'lambert':
        lambert(sys.argv[2], sys.argv[3], len(sys.argv) > 4 and sys.argv[4] == 'flat')
    else:
        score(*sys.argv[2:])
