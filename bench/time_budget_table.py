#!/usr/bin/env python3
"""Markdown table of bench/time_budget.sh's records (OUT/time_budget.jsonl) beside LuxCore's
15-second figures from ../shared/scenes/README.md (masked block / per-pixel error).
    python3 bench/time_budget_table.py OUT/time_budget.jsonl [../shared/scenes/README.md]"""
import json, re, sys
from pathlib import Path

recs = [json.loads(l) for l in open(sys.argv[1]) if l.strip()]
readme = Path(sys.argv[2] if len(sys.argv) > 2 else Path(__file__).resolve().parents[1] / "../shared/scenes/README.md")
lux = {}
if readme.exists():
    for m in re.finditer(r"^\| (\w+) cam(\d)[^|]*\| ([\d.]+) % \| ([\d.]+) % \| ([\d.]+) \|", readme.read_text(), re.M):
        lux[(m[1], int(m[2]))] = (float(m[3]), float(m[4]))
times = sorted({r["time"] for r in recs})
cams = []
for r in recs:
    if (r["scene"], r["camera"]) not in cams:
        cams.append((r["scene"], r["camera"]))
by = {(r["scene"], r["camera"], r["time"]): r for r in recs}
head = "| camera | " + " | ".join(f"`--time {t:g}`: wall s, block / pixel %" for t in times) + " | LuxCore 15 s block / pixel % |"
print(head)
print("|" + "---|" * (len(times) + 2))
for s, c in cams:
    cells = []
    for t in times:
        r = by.get((s, c, t))
        if r is None:
            cells.append("—")
            continue
        flag = "" if r["within"] else " **over**"
        cells.append(f"{r['wall']:.1f}{flag}, {100 * r['block_rel_rmse']:.2f} / {100 * r['rel_rmse']:.1f}")
    l = lux.get((s, c))
    print(f"| {s} cam{c} | " + " | ".join(cells) + f" | {l[0]:.2f} / {l[1]:.1f} |" if l else " | — |")
