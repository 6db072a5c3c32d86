#!/usr/bin/env python3
"""Writes tests/fixtures/ssim.json: two small deterministic RGB images and their SSIM computed
by scikit-image, so that `nerf`'s SSIM is checked against an independent implementation.

    pip install scikit-image numpy
    python3 scripts/make_ssim_fixture.py
"""
import json
import os

import numpy as np
import skimage
from skimage.metrics import structural_similarity

WIDTH, HEIGHT = 24, 20


def images():
    """A smooth pattern and a noisy, shifted, contrast-changed copy (seeded, so reproducible)."""
    y, x = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float64)
    a = np.stack(
        [
            0.5 + 0.4 * np.sin(x / 3.0) * np.cos(y / 4.0),
            (x + y) / (WIDTH + HEIGHT),
            0.5 + 0.5 * np.cos((x - y) / 5.0) ** 2 - 0.25,
        ],
        axis=-1,
    )
    rng = np.random.default_rng(13)
    b = 0.8 * np.roll(a, 1, axis=1) + 0.1 + 0.05 * rng.standard_normal(a.shape)
    # Stored as float32 (what RgbImage holds), so both sides see the same values.
    return np.clip(a, 0, 1).astype(np.float32), np.clip(b, 0, 1).astype(np.float32)


def main():
    a, b = images()
    kwargs = dict(gaussian_weights=True, sigma=1.5, use_sample_covariance=False,
                  data_range=1.0, channel_axis=-1)
    value = structural_similarity(a.astype(np.float64), b.astype(np.float64), **kwargs)
    per_channel = [
        structural_similarity(a[..., c].astype(np.float64), b[..., c].astype(np.float64),
                              **{k: v for k, v in kwargs.items() if k != "channel_axis"})
        for c in range(3)
    ]
    fixture = {
        "width": WIDTH,
        "height": HEIGHT,
        "a": [float(v) for v in a.reshape(-1)],
        "b": [float(v) for v in b.reshape(-1)],
        "ssim": float(value),
        "ssim_per_channel": [float(v) for v in per_channel],
        "skimage_version": skimage.__version__,
        "call": "structural_similarity(a, b, gaussian_weights=True, sigma=1.5, "
                "use_sample_covariance=False, data_range=1, channel_axis=-1)",
    }
    out = os.path.join(os.path.dirname(__file__), "..", "tests", "fixtures", "ssim.json")
    with open(out, "w") as f:
        json.dump(fixture, f)
        f.write("\n")
    print(f"SSIM {value:.10f} (per channel {per_channel}) -> {out}")


if __name__ == "__main__":
    main()
