#!/usr/bin/env python3
"""Writes tests/fixtures/sample_pdf.json: coarse depths and weights of a few rays, and the fine
depths PyTorch computes from them with pytorch3d's hierarchical sampling (the NeRF project's
`ProbabilisticRaysampler`: `sample_pdf` over the midpoints of the coarse depths with the
interior weights, then the coarse and fine depths concatenated and sorted), so that `nerf`'s
coarse-to-fine sampling is checked against the reference maths.

    pip install torch
    python3 scripts/make_sample_pdf_fixture.py
"""
import json
import os

import torch

RAYS, COARSE, FINE = 5, 16, 24


def sample_pdf(bins, weights, u, eps=1e-5):
    """pytorch3d.renderer.implicit.sample_pdf (its Python reference), with the quantiles given."""
    weights = weights + eps
    pdf = weights / torch.sum(weights, -1, keepdim=True)
    cdf = torch.cumsum(pdf, -1)
    cdf = torch.cat([torch.zeros_like(cdf[..., :1]), cdf], -1)
    inds = torch.searchsorted(cdf, u.contiguous(), right=True)
    below = torch.clamp(inds - 1, min=0)
    above = torch.clamp(inds, max=cdf.shape[-1] - 1)
    inds_g = torch.stack([below, above], -1)
    shape = [inds_g.shape[0], inds_g.shape[1], cdf.shape[-1]]
    cdf_g = torch.gather(cdf.unsqueeze(1).expand(shape), 2, inds_g)
    bins_g = torch.gather(bins.unsqueeze(1).expand(shape), 2, inds_g)
    denom = cdf_g[..., 1] - cdf_g[..., 0]
    denom = torch.where(denom < eps, torch.ones_like(denom), denom)
    t = (u - cdf_g[..., 0]) / denom
    return bins_g[..., 0] + t * (bins_g[..., 1] - bins_g[..., 0])


def main():
    g = torch.Generator().manual_seed(7)
    step = 4.0 / (COARSE - 1)
    base = torch.linspace(2.0, 6.0, COARSE)
    lengths = base + (torch.rand(RAYS, COARSE, generator=g) - 0.5) * 0.9 * step
    lengths, _ = torch.sort(lengths, -1)
    # Peaked weights, one ray of zeros (uniform after eps), one of a single spike.
    weights = torch.rand(RAYS, COARSE, generator=g) ** 4
    weights[1] = 0.0
    weights[2] = 0.0
    weights[2, 7] = 3.0
    mids = 0.5 * (lengths[..., 1:] + lengths[..., :-1])
    u_render = torch.linspace(0.0, 1.0, FINE).expand(RAYS, FINE)
    u_random, _ = torch.sort(torch.rand(RAYS, FINE, generator=g), -1)
    out = {"rays": RAYS, "coarse": COARSE, "fine": FINE}
    out["lengths"] = lengths.flatten().tolist()
    out["weights"] = weights.flatten().tolist()
    out["u_random"] = u_random.flatten().tolist()
    for name, u in [("render", u_render), ("random", u_random)]:
        fine = sample_pdf(mids, weights[..., 1:-1], u)
        merged, _ = torch.sort(torch.cat([lengths, fine], -1), -1)
        out[f"fine_{name}"] = fine.flatten().tolist()
        out[f"merged_{name}"] = merged.flatten().tolist()
    path = os.path.join(os.path.dirname(__file__), "..", "tests", "fixtures", "sample_pdf.json")
    with open(path, "w") as f:
        json.dump(out, f)
    print("wrote", os.path.normpath(path))


if __name__ == "__main__":
    main()
