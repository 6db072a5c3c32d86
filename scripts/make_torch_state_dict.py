#!/usr/bin/env python3
"""Writes PyTorch state dicts of the homework's NeRF (pytorch3d-style module names) for the
`nerf import-torch` tests, and PyTorch's own outputs at a few points to compare against.

    pip install torch numpy safetensors
    python3 scripts/make_torch_state_dict.py tests/fixtures

Writes into the directory:
  tiny_nerf.pth         torch.save(model.state_dict()) of a tiny NeRF (the config in
                        tests/fixtures/tiny_nerf.yaml: harmonics 2/1, 3 layers of 8, skip at 2,
                        direction layer 4)
  tiny_nerf_nested.pth  a homework-style training checkpoint: {"model": state dict of a wrapper
                        holding the NeRF as `implicit_fn`, "epoch": 7}
  tiny_nerf_outputs.safetensors  points (M, 3), directions (M, 3), and the model's density
                        (M, 1) and colour (M, 3) there, computed by PyTorch in float64
"""

import sys
from pathlib import Path

import numpy as np
import torch
import torch.nn as nn
from safetensors.numpy import save_file


def harmonic(x, n):
    """pytorch3d HarmonicEmbedding: [sin(x f), cos(x f), x], f = 2^0 .. 2^(n-1), channel-major."""
    freqs = 2.0 ** torch.arange(n, dtype=x.dtype)
    e = (x[..., None] * freqs).reshape(*x.shape[:-1], -1)
    return torch.cat([e.sin(), e.cos(), x], dim=-1)


class MLPWithInputSkips(nn.Module):
    def __init__(self, n_layers, input_dim, skip_dim, hidden, input_skips):
        super().__init__()
        layers = []
        for i in range(n_layers):
            dimin = input_dim if i == 0 else hidden + (skip_dim if i in input_skips else 0)
            layers.append(nn.Sequential(nn.Linear(dimin, hidden), nn.ReLU(True)))
        self.mlp = nn.ModuleList(layers)
        self._input_skips = set(input_skips)

    def forward(self, x, z):
        y = x
        for i, layer in enumerate(self.mlp):
            if i in self._input_skips:
                y = torch.cat((y, z), dim=-1)
            y = layer(y)
        return y


class NeuralRadianceField(nn.Module):
    def __init__(self, n_xyz, n_dir, hidden, hidden_dir, n_layers, append_xyz):
        super().__init__()
        self.n_xyz, self.n_dir = n_xyz, n_dir
        d_xyz, d_dir = 6 * n_xyz + 3, 6 * n_dir + 3
        self.mlp_xyz = MLPWithInputSkips(n_layers, d_xyz, d_xyz, hidden, append_xyz)
        self.density_layer = nn.Sequential(nn.Linear(hidden, 1), nn.ReLU())
        self.intermediate_linear = nn.Linear(hidden, hidden)
        self.color_layer = nn.Sequential(
            nn.Linear(hidden + d_dir, hidden_dir), nn.ReLU(), nn.Linear(hidden_dir, 3), nn.Sigmoid()
        )

    def forward(self, points, directions):
        xyz = harmonic(points, self.n_xyz)
        y = self.mlp_xyz(xyz, xyz)
        density = self.density_layer(y)
        features = self.intermediate_linear(y)
        colour = self.color_layer(torch.cat([features, harmonic(directions, self.n_dir)], dim=-1))
        return density, colour


class Model(nn.Module):
    """The homework's wrapper: the field lives at `implicit_fn`."""

    def __init__(self, field):
        super().__init__()
        self.implicit_fn = field


def main():
    out = Path(sys.argv[1] if len(sys.argv) > 1 else "tests/fixtures")
    out.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(0)
    field = NeuralRadianceField(n_xyz=2, n_dir=1, hidden=8, hidden_dir=4, n_layers=3, append_xyz=[2])
    # Push the density bias up so that the ReLU is active at most test points.
    with torch.no_grad():
        field.density_layer[0].bias.fill_(0.5)
    torch.save(field.state_dict(), out / "tiny_nerf.pth")
    torch.save({"model": Model(field).state_dict(), "epoch": 7}, out / "tiny_nerf_nested.pth")

    points = torch.randn(16, 3, dtype=torch.float64)
    directions = torch.nn.functional.normalize(torch.randn(16, 3, dtype=torch.float64), dim=-1)
    with torch.no_grad():
        density, colour = field.double()(points, directions)
    save_file(
        {
            "points": points.float().numpy(),
            "directions": directions.float().numpy(),
            "density": density.float().numpy(),
            "colour": colour.float().numpy(),
        },
        str(out / "tiny_nerf_outputs.safetensors"),
    )
    print(f"wrote {out}/tiny_nerf.pth, tiny_nerf_nested.pth, tiny_nerf_outputs.safetensors")


if __name__ == "__main__":
    main()
