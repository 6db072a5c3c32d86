#!/usr/bin/env python3
"""What one ray a pixel costs a perfect model at a downscaled size (docs/hash-grid.md).

The dataset's small images are the full-size files composited on black and resized with a tent
filter spanning +-1 pixel of the small image (the `image` crate's FilterType::Triangle; PIL's
BILINEAR resize is the same filter). A perfect, sharp field rendered with one ray through each
pixel's centre shows the full-size image sampled at that point; averaging k x k points at the
tent's midpoints, weighted by the tent, approaches the small image. This scores both against
the small images, from the ground truth alone (no model).

usage: scripts/point_sampling_ceiling.py [LEGO_DIR] [SIZE] [VIEWS]
       (defaults ../shared/data/lego, 128, 20; needs numpy and Pillow)
"""
import glob
import os
import sys

import numpy as np
from PIL import Image


def composited(path):
    """The RGBA file composited on black, float64 in [0, 1], as the dataset loader does."""
    rgba = np.asarray(Image.open(path).convert("RGBA"), dtype=np.float64) / 255.0
    return rgba[..., :3] * rgba[..., 3:]


def resized(rgb, size):
    """Each channel resized with the tent filter, in float."""
    channels = [
        np.asarray(Image.fromarray(rgb[..., c].astype(np.float32), mode="F").resize(
            (size, size), Image.BILINEAR), dtype=np.float64)
        for c in range(3)
    ]
    return np.stack(channels, -1)


def bilinear(rgb, x, y):
    """The image at continuous pixel coordinates (x, y), pixel centres at whole numbers."""
    h, w, _ = rgb.shape
    x0 = np.clip(np.floor(x).astype(int), 0, w - 2)
    y0 = np.clip(np.floor(y).astype(int), 0, h - 2)
    fx = np.clip(x - x0, 0, 1)[..., None]
    fy = np.clip(y - y0, 0, 1)[..., None]
    return (rgb[y0, x0] * (1 - fx) * (1 - fy) + rgb[y0, x0 + 1] * fx * (1 - fy)
            + rgb[y0 + 1, x0] * (1 - fx) * fy + rgb[y0 + 1, x0 + 1] * fx * fy)


def footprint_mean(rgb, size, k):
    """Each small pixel as the tent-weighted mean of k x k points of the full image."""
    scale = rgb.shape[1] / size
    centres = (np.arange(size) + 0.5) * scale - 0.5
    u = (np.arange(k) + 0.5) / k * 2 - 1
    w = 1 - np.abs(u)
    w /= w.sum()
    out = 0.0
    for dy, wy in zip(u, w):
        for dx, wx in zip(u, w):
            x, y = np.meshgrid(centres + dx * scale, centres + dy * scale)
            out = out + wx * wy * bilinear(rgb, x, y)
    return out


def psnr(a, b):
    return -10 * np.log10(np.mean((a - b) ** 2))


def main():
    lego = sys.argv[1] if len(sys.argv) > 1 else os.path.join(
        os.path.dirname(__file__), "..", "..", "shared", "data", "lego")
    size = int(sys.argv[2]) if len(sys.argv) > 2 else 128
    views = int(sys.argv[3]) if len(sys.argv) > 3 else 20
    files = sorted(glob.glob(os.path.join(lego, "test", "r_*.png")),
                   key=lambda f: int(os.path.basename(f)[2:-4]))[:views]
    if not files:
        sys.exit(f"no test images under {lego}/test")
    scores = {k: [] for k in (1, 2, 3)}
    for f in files:
        rgb = composited(f)
        small = resized(rgb, size)
        for k in scores:
            scores[k].append(psnr(footprint_mean(rgb, size, k), small))
    for k, v in scores.items():
        print(f"{k}x{k} point(s) a pixel, {len(v)} views at {size}x{size}: "
              f"PSNR mean {np.mean(v):.2f} dB, min {np.min(v):.2f}, max {np.max(v):.2f}")


if __name__ == "__main__":
    main()
