#!/usr/bin/env bash
# The paper's single-map setting (issue 13, acceptance 1): direct light from photons, no final
# gathering, no caustic map, 1 spp, 1 M photons, seed 0. Renders every camera of the reference
# table with the multiscale estimate (the default), the paper's adaptive estimate at n = 100 and
# kNN at k = 50, 100, 200, 400, and prints the masked mean ratio, block and per-pixel error.
#   bash bench/single_map.sh OUTDIR   (ESTIMATES="multiscale knn:100" picks some; PHOTONGRID_BIN another build)
# Writes OUTDIR/single_map.jsonl.
set -euo pipefail
out=${1:-out/single_map}
here=$(cd "$(dirname "$0")/.." && pwd)
S=${SCENES:-$here/../shared/scenes}
bin=${PHOTONGRID_BIN:-$here/target/release/photongrid}
mkdir -p "$out"
: > "$out/single_map.jsonl"
printf "%-20s %-14s %7s %7s %8s\n" camera estimate ratio block pixel
for sc in cornell_glass:0 cornell_area:0 ring_caustic:0 ring_caustic:1 shadow_edges:0 curved_3d:0 \
          pool_caustic:0 pool_caustic:1 shelf_objects:0 shelf_objects:1; do
  s=${sc%:*}; c=${sc#*:}
  for est in ${ESTIMATES:-multiscale adaptive:100 knn:50 knn:100 knn:200 knn:400}; do
    m=${est%:*}; k=${est#*:}; [ "$k" = "$est" ] && k=100
    img=$out/${s}_cam${c}_${m}_$k.exr
    "$bin" render "$S/$s.glb" --camera "$c" --output "$img" --progress quiet --seed 0 \
      --direct photons --gather 0 --caustic-photons 0 --spp 1 --photons 1M --method "$m" --neighbours "$k"
    j=$("$bin" compare "$img" "$S/refs/${s}_cam$c.exr" --mask "$S/refs/${s}_cam$c.specmask.exr" --json)
    python3 - "$s" "$c" "$est" "$j" "$out/single_map.jsonl" <<'PY'
import json, sys
s, c, est, j, jl = sys.argv[1:]
m = json.loads(j)
print(f"{s+'_cam'+c:20s} {est:14s} {m['mean_lum_ratio']:7.4f} {m['block_rel_rmse']*100:6.2f}% {m['rel_rmse']*100:7.2f}%")
open(jl, "a").write(json.dumps(dict(scene=s, camera=int(c), estimate=est, mean_lum_ratio=m["mean_lum_ratio"],
    block_rel_rmse=m["block_rel_rmse"], rel_rmse=m["rel_rmse"])) + "\n")
PY
  done
done
