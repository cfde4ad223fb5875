#!/usr/bin/env python3
"""Two renders of one camera that differ only in --seed: how much of the masked 8x8-block error
is noise. Prints the block noise (RMS of the two images' block difference / sqrt 2), each
image's block error and the error left in their mean beyond half the noise (bias together
with the reference's own noise), all relative to the reference's masked mean (%).

    python3 bench/seed_noise.py REF.exr MASK.exr SEED1.exr SEED2.exr

Needs numpy and OpenEXR (`pip install numpy openexr`); reads EXRs and blocks as
../shared/tools/score.py does (tools/image_stats.py).
"""
import json
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', 'tools'))
from image_stats import LUMINANCE as LUM, blocks, read  # noqa: E402


def main():
    ref, mask, a, b = sys.argv[1:5]
    r = read(ref) @ LUM
    keep = read(mask)[..., 0] < 0.5
    ia, ib = read(a) @ LUM, read(b) @ LUM
    mean = r[keep].mean()
    full = blocks(keep.astype(float)) > 0.999
    bl = lambda x: blocks(np.where(keep, x, 0.0))[full]
    rms = lambda x: float(np.sqrt(np.mean(x ** 2)) / mean * 100)
    noise = rms((bl(ia) - bl(ib)) / np.sqrt(2))
    of_mean = rms((bl(ia) + bl(ib)) / 2 - bl(r))
    print(json.dumps({
        'block_noise': round(noise, 3),
        'block_error': [round(rms(bl(ia) - bl(r)), 3), round(rms(bl(ib) - bl(r)), 3)],
        'bias_and_reference_noise': round(float(np.sqrt(max(of_mean ** 2 - noise ** 2 / 2, 0))), 3),
    }))


if __name__ == '__main__':
    main()
