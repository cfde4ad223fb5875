#!/usr/bin/env python3
"""Error against time from bench/time_budget.sh's records: one panel per camera, masked block
error (solid) and per-pixel error (dashed) of photongrid's default at each `--time`, LuxCore's
15-second figures from ../shared/scenes/README.md (crosses) and the target of issue 16 (half of
LuxCore's block error, or 1.5x the reference's own block noise where that is higher; dotted).
    python3 bench/time_budget_chart.py OUT/time_budget.jsonl OUT.svg [../shared/scenes]"""
import json, math, re, sys
from pathlib import Path

recs = [json.loads(l) for l in open(sys.argv[1]) if l.strip()]
out = Path(sys.argv[2])
scenes = Path(sys.argv[3] if len(sys.argv) > 3 else Path(__file__).resolve().parents[1] / "../shared/scenes")
lux, floor = {}, {}
readme = scenes / "README.md"
if readme.exists():
    for m in re.finditer(r"^\| (\w+) cam(\d)[^|]*\| ([\d.]+) % \| ([\d.]+) % \| ([\d.]+) \|", readme.read_text(), re.M):
        lux[(m[1], int(m[2]))] = (float(m[3]), float(m[4]))
refs = scenes / "refs" / "refs.json"
if refs.exists():
    for k, v in json.load(open(refs)).items():
        if not k.startswith("_"):
            floor[(v["scene"].removesuffix(".glb"), v["camera_index"])] = 1.5 * v["noise"]["rel_rmse_est"] / 8 * 100

cams = []
for r in recs:
    if (r["scene"], r["camera"]) not in cams:
        cams.append((r["scene"], r["camera"]))
times = sorted({r["time"] for r in recs})
W, H, cols = 230, 190, 5
rows = math.ceil(len(cams) / cols)
ml, mr, mt, mb = 42, 10, 22, 30
tx0, tx1 = math.log(min(times) / 1.5), math.log(max(times) * 1.5)
ylo, yhi = math.log(0.2), math.log(80.0)
svg = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{W*cols}" height="{H*rows+30}" font-family="sans-serif" font-size="10">',
       f'<rect width="100%" height="100%" fill="white"/>',
       f'<text x="8" y="{H*rows+20}">photongrid default (masked error vs reference, %): block — solid, per pixel — dashed; '
       f'LuxCore 15 s: crosses (red block, grey per pixel); target (block): dotted. Log-log axes.</text>']
for i, (s, c) in enumerate(cams):
    ox, oy = (i % cols) * W, (i // cols) * H
    pw, ph = W - ml - mr, H - mt - mb
    X = lambda t: ox + ml + (math.log(t) - tx0) / (tx1 - tx0) * pw
    Y = lambda e: oy + mt + (1 - (math.log(max(e, 0.2)) - ylo) / (yhi - ylo)) * ph
    svg.append(f'<text x="{ox+ml}" y="{oy+14}" font-weight="bold">{s} cam{c}</text>')
    svg.append(f'<rect x="{ox+ml}" y="{oy+mt}" width="{pw}" height="{ph}" fill="none" stroke="#999"/>')
    for e in (0.5, 1, 2, 5, 10, 20, 50):
        svg.append(f'<line x1="{ox+ml}" x2="{ox+ml+pw}" y1="{Y(e):.1f}" y2="{Y(e):.1f}" stroke="#eee"/>')
        svg.append(f'<text x="{ox+ml-4}" y="{Y(e)+3:.1f}" text-anchor="end">{e:g}</text>')
    for t in times:
        svg.append(f'<text x="{X(t):.1f}" y="{oy+mt+ph+12}" text-anchor="middle">{t:g} s</text>')
    pts = sorted((r["time"], r["block_rel_rmse"] * 100, r["rel_rmse"] * 100) for r in recs if (r["scene"], r["camera"]) == (s, c))
    for k, dash in ((1, ""), (2, ' stroke-dasharray="4 3"')):
        path = " ".join(f"{X(p[0]):.1f},{Y(p[k]):.1f}" for p in pts)
        svg.append(f'<polyline points="{path}" fill="none" stroke="#1f5fbf" stroke-width="1.6"{dash}/>')
        for p in pts:
            svg.append(f'<circle cx="{X(p[0]):.1f}" cy="{Y(p[k]):.1f}" r="2.4" fill="#1f5fbf"/>')
    if (s, c) in lux:
        for v, col in ((lux[(s, c)][0], "#d22"), (lux[(s, c)][1], "#888")):
            x, y = X(15), Y(v)
            svg.append(f'<path d="M{x-4:.1f},{y-4:.1f}L{x+4:.1f},{y+4:.1f}M{x-4:.1f},{y+4:.1f}L{x+4:.1f},{y-4:.1f}" stroke="{col}" stroke-width="1.6"/>')
        target = max(lux[(s, c)][0] / 2, floor.get((s, c), 0.0))
        svg.append(f'<line x1="{ox+ml}" x2="{ox+ml+pw}" y1="{Y(target):.1f}" y2="{Y(target):.1f}" stroke="#d22" stroke-dasharray="1 2"/>')
svg.append("</svg>")
out.write_text("\n".join(svg) + "\n")
print(f"wrote {out}")
