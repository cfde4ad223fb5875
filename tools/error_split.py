#!/usr/bin/env python3
"""Split an image's per-pixel error against a reference into its parts.

Two renders of one command with different seeds (A, B) give the render's own noise: the RMS
of (A - B) / sqrt(2). The reference's standard-error map gives its noise. What is left of the
squared error of A is the render's bias (blur of sharp light, and light too bright or dark
where the estimate is systematically off).

All figures are luminance, over the pixels the specular mask keeps (mask <= 0.5), relative to
the reference's mean luminance there: the per-pixel error is `photongrid compare`'s rel_rmse.
The same split of the error of 8x8-block means (blocks wholly kept, as `compare`'s
block_rel_rmse) follows; a block's reference noise is its pixels' standard errors combined.

Usage: tools/error_split.py A.exr B.exr REF.exr [--mask MASK.exr] [--stderr STDERR.exr]
Needs numpy and OpenEXR (as ../shared/tools/score.py).
"""

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from image_stats import BLOCK, blocks, luminance, read  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("a")
    ap.add_argument("b")
    ap.add_argument("reference")
    ap.add_argument("--mask")
    ap.add_argument("--stderr")
    args = ap.parse_args()
    a, b, r = (luminance(read(p)) for p in (args.a, args.b, args.reference))
    keep = np.ones(r.shape, bool) if args.mask is None else luminance(read(args.mask)) <= 0.5
    err = np.zeros(r.shape) if args.stderr is None else luminance(read(args.stderr))
    mean = r[keep].mean()
    pct = lambda v: 100.0 * np.sqrt(v) / mean
    full = blocks(keep.astype(float)) > 0.999
    block = lambda x: blocks(np.where(keep, x, 0.0))[full]
    for name, what, parts in (
        ("per-pixel", "RMS of its standard error", lambda x: x[keep]),
        ("block", "its pixels' standard errors combined", block),
    ):
        total = np.mean((parts(a) - parts(r)) ** 2)
        noise = np.mean(((parts(a) - parts(b)) / np.sqrt(2.0)) ** 2)
        ref_noise = np.mean(block(err**2) / BLOCK**2) if parts is block else np.mean(parts(err) ** 2)
        bias = max(total - noise - ref_noise, 0.0)
        print(f"{name + ' error':18s} {pct(total):6.2f} %  (A against the reference)")
        print(f"  render's noise   {pct(noise):6.2f} %  (RMS of (A - B) / sqrt 2)")
        print(f"  reference noise  {pct(ref_noise):6.2f} %  ({what})")
        print(f"  render's bias    {pct(bias):6.2f} %  (what is left)")



if __name__ == "__main__":
    main()
