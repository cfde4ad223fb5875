#!/usr/bin/env python3
"""Markdown tables of bench/scaling.sh's records: per photon count and per triangle count,
wall time, the phases, peak memory and bytes per stored photon, with the growth against the
smallest size (1.00 = linear in the size)."""
import json
import sys


def si(x):
    for unit, f in (("G", 1e9), ("M", 1e6), ("k", 1e3)):
        if x >= f:
            return f"{x / f:.3g} {unit}"
    return f"{x:.0f}"


def main():
    rows = [json.loads(l) for l in open(sys.argv[1]) if l.strip()]
    photons = [r for r in rows if r["series"] == "photons"]
    if photons:
        print("| photons emitted | stored | wall s | photons s | index s | render s | peak MiB | bytes / stored photon | wall per photon, × smallest |")
        print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
        base = photons[0]["wall"] / photons[0]["emitted"]
        for r in photons:
            s = r["seconds"]
            peak = r["peak_bytes"] or 0
            print(f"| {si(r['emitted'])} | {si(r['stored'])} | {r['wall']:.2f} | {s['photons']:.2f} | {s['build']:.2f} "
                  f"| {s['render']:.2f} | {peak / 2**20:.0f} | {peak / max(r['stored'], 1):.1f} "
                  f"| {r['wall'] / r['emitted'] / base:.2f} |")
        last = photons[-1]
        per = (last["peak_bytes"] or 0) / max(last["stored"], 1)
        ratio = last["stored"] / last["emitted"]
        if per > 0:
            fits = 24 * 2**30 / per
            print(f"\nAt {per:.1f} bytes per stored photon and {ratio:.2f} stored per emitted path, 24 GiB hold "
                  f"about {si(fits)} stored photons, {si(fits / ratio)} emitted paths (extrapolated).")
    tris = [r for r in rows if r["series"] == "triangles"]
    if tris:
        print("\n| subdivisions | triangles | wall s | load s | BVH s | photons s | grids s | render s | peak MiB |")
        print("|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
        for r in tris:
            s = r["seconds"]
            n = 132 * 4 ** int(r["size"])
            print(f"| {r['size']} | {si(n)} | {r['wall']:.2f} | {s['load']:.2f} | {s['bvh']:.2f} | {s['photons']:.2f} "
                  f"| {s['grids']:.2f} | {s['render']:.2f} | {(r['peak_bytes'] or 0) / 2**20:.0f} |")


if __name__ == "__main__":
    main()
