"""Shared helpers of the image tools and benches: EXRs as float64 arrays, luminance, and the
8x8-block means that `photongrid compare` and ../shared/tools/score.py score (blocks wholly
inside the image; the caller masks). Needs numpy and OpenEXR."""

import numpy as np
import OpenEXR

LUMINANCE = np.array([0.2126, 0.7152, 0.0722])
BLOCK = 8


def read(path):
    """An EXR's RGB (channels named R, G, B, or ending in .R, .G, .B; else its only channel)
    as float64."""
    channels = OpenEXR.File(path, separate_channels=True).channels()
    names = []
    for c in "RGB":
        names += [n for n in channels if n == c or n.endswith("." + c)][:1]
    if len(names) < 3:
        names = [next(iter(channels))]
    return np.stack([np.asarray(channels[n].pixels, dtype=np.float64) for n in names], axis=-1)


def luminance(image):
    return image[..., :3] @ LUMINANCE if image.shape[-1] >= 3 else image[..., 0]


def blocks(x, b=BLOCK):
    """Means of the image's whole b x b blocks."""
    h, w = x.shape[0] // b * b, x.shape[1] // b * b
    return x[:h, :w].reshape(h // b, b, w // b, b).mean(axis=(1, 3))
