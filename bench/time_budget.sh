#!/usr/bin/env bash
# Does `--time T` end at T, and how good is the image then? Renders every camera of the
# reference table in ../shared/scenes with `--time T` for each T given, measures the wall time
# of the whole process from outside, and scores the image against the reference (masked).
#   bash bench/time_budget.sh OUTDIR "5 15 60" [extra render options...]
# Prints one line per (camera, T): wall, whether it ended within max(1.05 T, T + 0.5 s), passes,
# the pass size the budget chose, masked mean ratio, block error and per-pixel error; writes
# OUTDIR/time_budget.jsonl.
set -euo pipefail
out=${1:-out/time_budget}; shift || true
times=${1:-"5 15 60"}; shift || true
here=$(cd "$(dirname "$0")/.." && pwd)
S=${SCENES:-$here/../shared/scenes}
bin=${PHOTONGRID_BIN:-$here/target/release/photongrid}  # another build: PHOTONGRID_BIN=...
mkdir -p "$out"
: > "$out/time_budget.jsonl"
printf "%-22s %5s %7s %4s %6s %-50s %7s %7s %8s\n" camera T wall ok passes "passes (photons/spp/gather)" ratio block pixel
for T in $times; do
  for sc in cornell_glass:0 cornell_area:0 ring_caustic:0 ring_caustic:1 shadow_edges:0 curved_3d:0 \
            pool_caustic:0 pool_caustic:1 shelf_objects:0 shelf_objects:1; do
    s=${sc%:*}; c=${sc#*:}
    img=$out/${s}_cam${c}_t$T.exr
    t0=$(date +%s.%N)
    "$bin" render "$S/$s.glb" --camera "$c" --output "$img" --stats "$out/${s}_cam${c}_t$T.json" \
      --time "$T" --progress quiet "$@" 2> "$out/${s}_cam${c}_t$T.log"
    t1=$(date +%s.%N)
    m=$("$bin" compare "$img" "$S/refs/${s}_cam$c.exr" --mask "$S/refs/${s}_cam$c.specmask.exr" --json)
    python3 - "$s" "$c" "$T" "$t0" "$t1" "$m" "$out/${s}_cam${c}_t$T.json" "$out/time_budget.jsonl" <<'PY'
import json, sys
s, c, T, t0, t1, m, st, jl = sys.argv[1:]
T, wall = float(T), float(t1) - float(t0)
m, st = json.loads(m), json.load(open(st))
ok = wall <= max(1.05 * T, T + 0.5)
b = st.get("budget") or {}
size = (b.get("plan") or {}).get("size") or {}
fill = b.get("fill")
pas = f"{(size.get('photons',0)+size.get('caustic_photons',0))/1e3:.0f}k/{size.get('spp')}/{size.get('gather')}"
rp = (b.get("replan") or {}).get("plan", {}).get("size")
if rp and rp != size:
    pas += f" then {(rp['photons']+rp['caustic_photons'])/1e3:.0f}k/{rp['spp']}/{rp['gather']}"
if fill:
    pas += f" +fill {(fill['photons']+fill['caustic_photons'])/1e3:.0f}k/{fill['spp']}/{fill['gather']}"
print(f"{s+'_cam'+c:22s} {T:5.0f} {wall:7.2f} {'yes' if ok else 'NO':>4s} {st['passes']['count']:6d} {pas:50s} "
      f"{m['mean_lum_ratio']:7.4f} {m['block_rel_rmse']*100:6.2f}% {m['rel_rmse']*100:7.2f}%")
rec = dict(scene=s, camera=int(c), time=T, wall=wall, within=ok, passes=st["passes"], budget=b,
           seconds=st["seconds"], cpu_seconds=st.get("cpu_seconds"), mean_lum_ratio=m["mean_lum_ratio"],
           block_rel_rmse=m["block_rel_rmse"], rel_rmse=m["rel_rmse"])
open(jl, "a").write(json.dumps(rec) + "\n")
PY
  done
done
