#!/usr/bin/env bash
# Render all six reference cameras of ../shared/scenes and score them with both the crate's
# `photongrid compare` and ../shared/tools/score.py (the independent check).
#   bash bench/reference.sh OUTDIR [extra render options...]
# Prints one line per camera: mean ratio and block error, unmasked and with the specular mask.
set -euo pipefail
out=${1:-out/bench}; shift || true
here=$(cd "$(dirname "$0")/.." && pwd)
S=${SCENES:-$here/../shared/scenes}
bin=$here/target/release/photongrid
mkdir -p "$out"
printf "%-22s %8s %8s %9s %9s %8s\n" camera ratio block ratio_m block_m seconds
for sc in cornell_glass:0 cornell_area:0 ring_caustic:0 ring_caustic:1 shadow_edges:0 curved_3d:0; do
  s=${sc%:*}; c=${sc#*:}
  img=$out/${s}_cam$c.exr
  "$bin" render "$S/$s.glb" --camera "$c" --output "$img" --stats "$out/${s}_cam$c.json" --progress quiet "$@"
  a=$("$bin" compare "$img" "$S/refs/${s}_cam$c.exr" --json)
  b=$("$bin" compare "$img" "$S/refs/${s}_cam$c.exr" --mask "$S/refs/${s}_cam$c.specmask.exr" --json)
  if python3 -c "import numpy, OpenEXR" 2>/dev/null; then
    python3 "$S/../tools/score.py" "$img" "$S/refs/${s}_cam$c.exr" --mask "$S/refs/${s}_cam$c.specmask.exr" > "$out/${s}_cam$c.score_py.json"
  fi
  python3 - "$s" "$c" "$a" "$b" "$out/${s}_cam$c.json" <<'PY'
import json, sys
s, c, a, b, st = sys.argv[1:]
a, b = json.loads(a), json.loads(b)
t = json.load(open(st))["seconds"]["total"]
print(f"{s+'_cam'+c:22s} {a['mean_lum_ratio']:8.4f} {a['block_rel_rmse']*100:7.2f}% {b['mean_lum_ratio']:9.4f} {b['block_rel_rmse']*100:8.2f}% {t:8.2f}")
PY
done
