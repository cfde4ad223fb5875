"""Closed-form direct light on the gold sphere of mat_punctual from its one delta light (README
"Normal-map handedness"): glTF BRDF (with --ms the metal compensation) × I cosθ / d², analytic
sphere, the other spheres as occluders, 6×6 sub-pixel samples; nothing else is lit.

    python3 bench/materials/gold_direct_analytic.py gold_only_point.glb 320 240 OUT.npy --ms

writes OUT.npy (H×W×3 radiance) and OUT_cov.npy (gold coverage per pixel); ~3 min."""
import os
import sys, math, numpy as np, json
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import model_difference as md
from punctual_regions import read_glb
W, H, SUB = int(sys.argv[2]), int(sys.argv[3]), 6
j, _ = read_glb(sys.argv[1])
nodes = {n['name']: n for n in j['nodes']}
def quat_rot(q, v):
    x, y, z, w = q; u = np.array([x, y, z]); v = np.asarray(v, float)
    return 2*np.dot(u, v)*u + (w*w - np.dot(u, u))*v + 2*w*np.cross(u, v)
cam = nodes['Camera']; co = np.array(cam['translation']); cq = cam['rotation']
yfov = j['cameras'][0]['perspective']['yfov']; t = math.tan(yfov/2); asp = W/H
spheres = {'GoldSphere': 0.38, 'PlasticSphere': 0.38, 'TexturedSphere': 0.42, 'BlueSphere': 0.22}
centres = {k: np.array(nodes[k]['translation']) for k in spheres}
light = j['extensions']['KHR_lights_punctual']['lights'][0]
ln = [n for n in j['nodes'] if 'extensions' in n][0]
lp = np.array(ln['translation']); I = light['intensity']/683.0
spot = light.get('spot')
if spot:
    ldir = quat_rot(ln['rotation'], [0, 0, -1]); co_out = math.cos(spot['outerConeAngle'])
    blend = 1 - spot['innerConeAngle']/spot['outerConeAngle']
ys, xs = np.mgrid[0:H, 0:W]
sub = (np.arange(SUB)+0.5)/SUB
img = np.zeros((H, W, 3)); cov = np.zeros((H, W))
ms = md.ms_compensation(0.09) if '--ms' in sys.argv else None
base = np.array([1, 0.766, 0.336])
def hit(o, d, c, r):
    oc = o - c; b = np.sum(oc*d, -1); cc = np.sum(oc*oc, -1) - r*r; disc = b*b - cc
    tt = -b - np.sqrt(np.maximum(disc, 0)); return np.where((disc > 0) & (tt > 1e-4), tt, np.inf)
for sy in sub:
    for sx in sub:
        nx = 2*(xs+sx)/W - 1; ny = 1 - 2*(ys+sy)/H
        d = np.stack([nx*t*asp, ny*t, -np.ones_like(nx)], -1); d /= np.linalg.norm(d, axis=-1, keepdims=True)
        d = np.stack([quat_rot(cq, v) for v in d.reshape(-1, 3)]).reshape(H, W, 3)
        ts = {k: hit(co, d, centres[k], r) for k, r in spheres.items()}
        tg = ts['GoldSphere']; first = np.isfinite(tg)
        for k in spheres:
            if k != 'GoldSphere': first &= tg < ts[k]
        p = co + d*tg[..., None]; n = (p - centres['GoldSphere'])/0.38
        v = -d; l = lp - p; dist = np.linalg.norm(l, axis=-1); l /= dist[..., None]
        cos = np.sum(n*l, -1)
        vis = first & (cos > 0)
        for k, r in spheres.items():
            if k != 'GoldSphere':
                th = hit(p, l, centres[k], r); vis &= ~(th < dist)
        f = md.gltf_brdf(n, v, l, base, 1.0, 0.3, ms=ms)
        inten = np.full(dist.shape, I)
        if spot:
            c = np.sum(-l*ldir, -1); x = np.clip((c - co_out)/((1 - co_out)*blend), 0, 1)
            inten = I*np.where(c > co_out, x*x*(3 - 2*x), 0.0)
        L = f*(inten*np.maximum(cos, 0)/dist**2)[..., None]
        img += np.where(vis[..., None], L, 0); cov += first
img /= SUB*SUB; cov /= SUB*SUB
np.save(sys.argv[4], img); np.save(sys.argv[4].replace('.npy', '_cov.npy'), cov)
print('covered pixels', int((cov == 1).sum()), 'mean', img[cov == 1].mean(0))
