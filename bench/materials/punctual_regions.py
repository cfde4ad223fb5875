"""Region masks and isolating variants of the material rooms, and per-region scores (issue 10,
branch `punct`; README "Normal-map handedness").

    python3 bench/materials/punctual_regions.py variants OUTDIR
        writes OUTDIR/<scene>_mask_gold.glb, <scene>_mask_ballsplit.glb (mat_punctual and
        mat_spheres), gold_only_point.glb, gold_only_spot.glb, ballonly_both.glb; render the
        masks with `photongrid render X.glb -o X.exr --width 320 --height 240 --photons 0 --spp 16`
    python3 bench/materials/punctual_regions.py score SCENE MASKDIR IMG [REF]
        mean-luminance ratio IMG/REF (default: the Cycles reference) per region, with score.py's
        whole-image figures

A mask GLB keeps the geometry and makes one object emissive (1, base black, specular 0) and
every other material black: the camera's first hits on it render as 1. The ball's mask is an
emissive texture made from its metallicRoughness texture: R metal with roughness < 0.4 (lobes
traced), G metal >= 0.4 (lobes from photons), B dielectric.
"""
import copy
import io
import json
import os
import struct
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, '..', '..', '..', 'shared', 'tools'))
BLACK = {'doubleSided': True, 'extensions': {'KHR_materials_specular': {'specularFactor': 0}},
         'pbrMetallicRoughness': {'baseColorFactor': [0, 0, 0, 1], 'metallicFactor': 0}}


def read_glb(path):
    b = open(path, 'rb').read()
    off, chunks = 12, []
    while off < len(b):
        n, _ = struct.unpack_from('<II', b, off)
        chunks.append(b[off + 8:off + 8 + n])
        off += 8 + n
    return json.loads(chunks[0]), (chunks[1] if len(chunks) > 1 else b'')


def write_glb(path, j, binc):
    js = json.dumps(j).encode()
    js += b' ' * (-len(js) % 4)
    binc += b'\0' * (-len(binc) % 4)
    out = struct.pack('<II', len(js), 0x4E4F534A) + js + struct.pack('<II', len(binc), 0x004E4942) + binc
    open(path, 'wb').write(struct.pack('<III', 0x46546C67, 2, 12 + len(out)) + out)


def emissive(name, tex=None):
    m = dict(copy.deepcopy(BLACK), name=name, emissiveFactor=[1, 1, 1])
    if tex is not None:
        m['emissiveTexture'] = {'index': tex}
    return m


def only(j, keep, make=None):
    """j with every material but `keep` black (`keep` replaced by make(material) if given)."""
    k = copy.deepcopy(j)
    for i, m in enumerate(k['materials']):
        if m['name'] != keep:
            k['materials'][i] = dict(copy.deepcopy(BLACK), name=m['name'])
        elif make:
            k['materials'][i] = make(m)
    return k


def ball_mask_texture(j, b):
    """(json, bin) with a mask PNG appended as a new texture; returns its index."""
    from PIL import Image
    t = j['textures'][4]
    bv = j['bufferViews'][j['images'][t['source']]['bufferView']]
    o = bv.get('byteOffset', 0)
    a = np.array(Image.open(io.BytesIO(b[o:o + bv['byteLength']])))
    metal, rough = a[..., 2] == 255, a[..., 1] / 255.0
    m = np.zeros_like(a)
    m[..., 0] = np.where(metal & (rough < 0.4), 255, 0)
    m[..., 1] = np.where(metal & (rough >= 0.4), 255, 0)
    m[..., 2] = np.where(~metal, 255, 0)
    buf = io.BytesIO()
    Image.fromarray(m).save(buf, 'PNG')
    b2 = b + b'\0' * (-len(b) % 4)
    j['bufferViews'].append({'buffer': 0, 'byteOffset': len(b2), 'byteLength': len(buf.getvalue())})
    b2 += buf.getvalue()
    j['buffers'][0]['byteLength'] = len(b2)
    j['images'].append({'bufferView': len(j['bufferViews']) - 1, 'mimeType': 'image/png', 'name': 'mask'})
    j['textures'].append({'source': len(j['images']) - 1})
    return b2, len(j['textures']) - 1


def one_light(j, keep):
    k = copy.deepcopy(j)
    k['nodes'] = [n for n in k['nodes'] if n.get('extensions', {}).get('KHR_lights_punctual', {}).get('light', keep) == keep]
    k['scenes'][0]['nodes'] = list(range(len(k['nodes'])))
    for n in k['nodes']:
        if 'extensions' in n:
            n['extensions']['KHR_lights_punctual']['light'] = 0
    k['extensions']['KHR_lights_punctual']['lights'] = [j['extensions']['KHR_lights_punctual']['lights'][keep]]
    return k


def variants(out):
    os.makedirs(out, exist_ok=True)
    for scene in ['mat_punctual', 'mat_spheres']:
        j, b = read_glb(os.path.join(HERE, scene + '.glb'))
        write_glb(os.path.join(out, scene + '_mask_gold.glb'), only(j, 'Gold', lambda m: emissive('Gold')), b)
        k = copy.deepcopy(j)
        b2, tex = ball_mask_texture(k, b)
        write_glb(os.path.join(out, scene + '_mask_ballsplit.glb'), only(k, 'TexturedBall', lambda m: emissive('TB', tex)), b2)
    j, b = read_glb(os.path.join(HERE, 'mat_punctual.glb'))
    for i, name in enumerate(['point', 'spot']):
        write_glb(os.path.join(out, 'gold_only_%s.glb' % name), one_light(only(j, 'Gold'), i), b)
    write_glb(os.path.join(out, 'ballonly_both.glb'), only(j, 'TexturedBall'), b)


def score(scene, maskdir, img_path, ref_path=None):
    import score as S
    img = S.read_exr(img_path)
    ref = S.read_exr(ref_path or os.path.join(HERE, 'refs', scene + '_cam0.exr'))
    out = {k: v for k, v in S.score(img, ref).items() if k in ('mean_lum_ratio', 'block_rel_rmse', 'rel_rmse')}
    g = S.read_exr(os.path.join(maskdir, scene + '_mask_gold.exr'))[..., 0] > 0.999
    ball = S.read_exr(os.path.join(maskdir, scene + '_mask_ballsplit.exr')) > 0.99
    li, lr = img @ S.LUM, ref @ S.LUM
    for name, m in [('gold', g), ('ball_metal_traced', ball[..., 0]), ('ball_metal_stored', ball[..., 1]),
                    ('ball_dielectric', ball[..., 2])]:
        out[name] = [round(float(li[m].mean() / lr[m].mean()), 4) if lr[m].mean() > 0 else None, int(m.sum())]
    print(json.dumps(out))


if __name__ == '__main__':
    if sys.argv[1] == 'variants':
        variants(sys.argv[2])
    else:
        score(*sys.argv[2:])
