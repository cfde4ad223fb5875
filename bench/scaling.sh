#!/usr/bin/env bash
# Cost against size (issue 15): wall time, phase times and peak memory against the photon
# count (the paper's workload on cornell_glass, 0.5 M to 20 M photons) and against the
# triangle count (samples/shadow_edges.glb subdivided 2 to 8 times: 2.1 k to 2.2 M
# triangles, default pipeline at fixed pass sizes). One run each: run it on a quiet machine.
#
#   bash bench/scaling.sh OUT        then   python3 bench/scaling_table.py OUT/scaling.jsonl
#
# Env: BIN (default target/release/photongrid), PHOTONS ("500k 1M 2M 5M 10M 20M"),
# LEVELS ("2 3 4 5 6 7 8").
set -euo pipefail
OUT=${1:?usage: bash bench/scaling.sh OUT}
BIN=${BIN:-target/release/photongrid}
PHOTONS=${PHOTONS:-500k 1M 2M 5M 10M 20M}
LEVELS=${LEVELS:-2 3 4 5 6 7 8}
mkdir -p "$OUT"
LOG="$OUT/scaling.jsonl"
: > "$LOG"

record() { # record SERIES SIZE STATS.json WALL_S
  python3 - "$@" >> "$LOG" <<'PY'
import json, sys
series, size, stats, wall = sys.argv[1], sys.argv[2], sys.argv[3], float(sys.argv[4])
s = json.load(open(stats))
print(json.dumps({
    "series": series, "size": size, "wall": wall,
    "seconds": s["seconds"], "cpu_seconds": s.get("cpu_seconds"),
    "stored": s["photons"]["stored"], "emitted": s["photons"]["emitted"],
    "peak_bytes": s["memory"].get("peak_bytes"),
}))
PY
}

run() { # run SERIES SIZE ARGS...
  local series=$1 size=$2; shift 2
  local t0 t1
  t0=$(date +%s.%N)
  "$BIN" render "$@" --progress quiet --stats "$OUT/$series-$size.json" -o "$OUT/$series-$size.exr"
  t1=$(date +%s.%N)
  record "$series" "$size" "$OUT/$series-$size.json" "$(echo "$t1 - $t0" | bc)"
  tail -1 "$LOG"
}

for n in $PHOTONS; do
  run photons "$n" samples/cornell_glass.glb --photons "$n" --method knn --direct photons \
    --gather 0 --caustic-photons 0 --spp 1 --width 640 --height 480 --seed 0
done

for l in $LEVELS; do
  scene="$OUT/shadow_edges_x$l.glb"
  [ -f "$scene" ] || python3 bench/subdivide_glb.py samples/shadow_edges.glb "$scene" "$l"
  run triangles "$l" "$scene" --photons 1M --caustic-photons 500k --spp 2 --width 320 \
    --height 240 --seed 0
done
