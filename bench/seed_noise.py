#!/usr/bin/env python3
"""Two renders of one camera that differ only in --seed: how much of the masked 8x8-block error
is noise. Prints the block noise (RMS of the two images' block difference / sqrt 2), each
image's block error and the error left in their mean beyond half the noise (bias together
with the reference's own noise), all relative to the reference's masked mean (%).

    python3 bench/seed_noise.py REF.exr MASK.exr SEED1.exr SEED2.exr

Needs numpy and OpenEXR (`pip install numpy openexr`); reads EXRs and blocks as
../shared/tools/score.py does.
"""
import json
import sys

import numpy as np
import OpenEXR

LUM = np.array([0.2126, 0.7152, 0.0722])


def read(path):
    ch = OpenEXR.File(path, separate_channels=True).channels()
    pick = lambda c: next(n for n in ch if n == c or n.endswith('.' + c))
    return np.stack([np.asarray(ch[pick(c)].pixels, dtype=np.float64) for c in 'RGB'], -1)


def blocks(x, b=8):
    h, w = x.shape[0] // b * b, x.shape[1] // b * b
    return x[:h, :w].reshape(h // b, b, w // b, b).mean(axis=(1, 3))


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
