#!/usr/bin/env python3
"""The same benchmarks as `nerf bench`, in PyTorch on the CPU, for comparison on your machine.

    pip install torch numpy          # PyTorch from PyPI
    python3 scripts/bench_pytorch.py [--threads N] [--repeats 3] [--json]

Measures, with the homework's pipeline written in plain PyTorch (pytorch3d conventions: row-vector
cameras, NDC with +X left / +Y up, look_at, the homework's pixel grid, stratified sampling, last
delta 1e10, exclusive-cumprod weights):

* box render: the homework's box.yaml, 20 surround frames 256x256 x 64 points (no gradients);
* train_box step: the homework's `train` loop on train_box.yaml (box centre and side lengths
  trainable), 4096 random pixels x 64 points of a 256x256 target, forward, MSE, backward,
  Adam(5e-4); the mean over --box-steps steps (best of the repeats);
* NeRF training step: the homework's NeRF (harmonics 6/2, 6x128 layers, skip at 3, 64-wide
  direction layer), 1024 random rays x 128 jittered points, forward, MSE, backward, Adam(5e-4);
* NeRF render: one dense 128x128 frame x 128 points, no gradients, 4096 rays per chunk.

`scripts/bench_compare.py` runs this and `nerf bench --json` together and prints both sides.
"""

import argparse
import json
import math
import platform
import time

import numpy as np
import torch
import torch.nn as nn


# ---------------------------------------------------------------- cameras and rays (float64)


def look_at(eye, at, up):
    """pytorch3d look_at_view_transform: R (3x3, columns = camera axes), T."""
    eye, at, up = (np.asarray(v, dtype=np.float64) for v in (eye, at, up))
    z = at - eye
    z /= np.linalg.norm(z)
    x = np.cross(up, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    y /= np.linalg.norm(y)
    r = np.stack([x, y, z], axis=1)
    t = -(r.T @ eye)
    return r, t


def surround_cameras(radius, n_poses, up, focal):
    """The homework's create_surround_cameras."""
    cams = []
    for i in range(n_poses):
        theta = i * 2.0 * math.pi / n_poses + math.pi / 2.0
        if abs(up[1]) > 0:
            eye = [math.cos(theta) * radius, 0.0, -math.sin(theta) * radius]
        else:
            eye = [math.cos(theta) * radius, math.sin(theta) * radius, 2.0]
        r, t = look_at(eye, [0.0, 0.0, 0.0], up)
        cams.append((r, t, focal))
    return cams


def rays_for_pixels(cam, width, height, pixels):
    """Unit rays through the homework pixel grid (x = -linspace(-1,1,W), y = -linspace(-1,1,H))."""
    r, t, focal = cam
    xs = -np.linspace(-1.0, 1.0, width)
    ys = -np.linspace(-1.0, 1.0, height)
    px, py = xs[pixels % width], ys[pixels // width]
    view = np.stack([px / focal, py / focal, np.ones_like(px)], axis=1)
    world = (view - t) @ r.T  # X_view = X_world R + T
    centre = -t @ r.T
    d = world - centre
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    origins = np.broadcast_to(centre, d.shape)
    return (
        torch.tensor(np.ascontiguousarray(origins), dtype=torch.float32),
        torch.tensor(d, dtype=torch.float32),
    )


def sample_lengths(n_rays, n_pts, near, far, jitter):
    z = torch.linspace(near, far, n_pts)
    if not jitter:
        return z.expand(n_rays, n_pts)
    mids = 0.5 * (z[1:] + z[:-1])
    lower = torch.cat([z[:1], mids])
    upper = torch.cat([mids, z[-1:]])
    return lower + (upper - lower) * torch.rand(n_rays, n_pts)


# ---------------------------------------------------------------- renderer


def composite(sigma, lengths, features):
    """sigma (N,S), lengths (N,S), features (N,S,C) -> colour (N,C), depth (N)."""
    deltas = torch.cat(
        [lengths[:, 1:] - lengths[:, :-1], torch.full_like(lengths[:, :1], 1e10)], dim=1
    )
    alpha = 1.0 - torch.exp(-sigma * deltas)
    trans = torch.cumprod(
        torch.cat([torch.ones_like(alpha[:, :1]), 1.0 - alpha + 1e-10], dim=1), dim=1
    )[:, :-1]
    w = trans * alpha
    return (w[..., None] * features).sum(1), (w * lengths).sum(1)


# ---------------------------------------------------------------- box SDF volume


def box_volume(points, deltas, side=1.75, alpha=1.0, beta=0.05):
    diff = points.abs() - side / 2.0
    sdf = diff.clamp(min=0).norm(dim=-1) + diff.max(dim=-1).values.clamp(max=0)
    e = torch.exp(-sdf.abs() / beta)
    density = alpha * torch.where(sdf > 0, 0.5 * e, 1.0 - 0.5 * e)
    sigma = -torch.log(1.0 - density) / deltas
    colour = points.abs().clamp(0.02, 0.98)
    return sigma, colour


def render_box(cam, size=256, n_pts=64, chunk=32768):
    n = size * size
    origins, dirs = rays_for_pixels(cam, size, size, np.arange(n))
    colours = []
    for s in range(0, n, chunk):
        o, d = origins[s : s + chunk], dirs[s : s + chunk]
        lengths = sample_lengths(o.shape[0], n_pts, 0.0, 5.0, False)
        points = o[:, None] + lengths[..., None] * d[:, None]
        deltas = torch.cat(
            [lengths[:, 1:] - lengths[:, :-1], torch.full_like(lengths[:, :1], 1e10)], dim=1
        )
        sigma, colour = box_volume(points, deltas)
        c, _ = composite(sigma, lengths, colour)
        colours.append(c)
    return torch.cat(colours)


class BoxVolume(nn.Module):
    """The homework's SDF volume for train_box: a rainbow box whose centre and side lengths
    are parameters (opt: True), alpha 1, beta 0.05."""

    def __init__(self, center, side_lengths, alpha=1.0, beta=0.05):
        super().__init__()
        self.center = nn.Parameter(torch.tensor(center, dtype=torch.float32)[None])
        self.side_lengths = nn.Parameter(torch.tensor(side_lengths, dtype=torch.float32)[None])
        self.alpha, self.beta = alpha, beta

    def forward(self, points, deltas):
        p = points - self.center
        diff = p.abs() - self.side_lengths / 2.0
        sdf = diff.clamp(min=0).norm(dim=-1) + diff.max(dim=-1).values.clamp(max=0)
        e = torch.exp(-sdf.abs() / self.beta)
        density = self.alpha * torch.where(sdf > 0, 0.5 * e, 1.0 - 0.5 * e)
        sigma = -torch.log(1.0 - density) / deltas
        colour = p.abs().clamp(0.02, 0.98)
        return sigma, colour


def render_volume(volume, origins, dirs, n_pts=64, near=0.0, far=5.0):
    lengths = sample_lengths(origins.shape[0], n_pts, near, far, False)
    points = origins[:, None] + lengths[..., None] * dirs[:, None]
    deltas = torch.cat(
        [lengths[:, 1:] - lengths[:, :-1], torch.full_like(lengths[:, :1], 1e10)], dim=1
    )
    sigma, colour = volume(points, deltas)
    return composite(sigma, lengths, colour)[0]


def train_box_cameras():
    """The four cameras of the homework's train_box.yaml."""
    eyes = [[-2.5, 0.0, 0.0], [-1.0, 0.0, -2.2], [0.0, 0.0, -2.5], [1.0, 0.0, -2.2]]
    return [look_at(e, [0.0, 0.0, 0.0], [0.0, 1.0, 0.0]) + (1.0,) for e in eyes]


def train_box_steps(n_steps, size=256, batch=4096):
    """n_steps of the homework's train loop on train_box.yaml: targets rendered from another
    box, the fit starting from train_box's (centre 0, sides 1.5); returns seconds per step."""
    cams = train_box_cameras()
    truth = BoxVolume([0.1, -0.1, 0.05], [1.7, 1.3, 1.6])
    with torch.no_grad():
        targets = []
        for cam in cams:
            o, d = rays_for_pixels(cam, size, size, np.arange(size * size))
            targets.append(torch.cat([render_volume(truth, o[s:s + 32768], d[s:s + 32768])
                                      for s in range(0, size * size, 32768)]))
    model = BoxVolume([0.0, 0.0, 0.0], [1.5, 1.5, 1.5])
    opt = torch.optim.Adam(model.parameters(), lr=5e-4)
    start = time.perf_counter()
    for step in range(n_steps):
        i = np.random.randint(len(cams))
        pixels = np.random.choice(size * size, batch)
        o, d = rays_for_pixels(cams[i], size, size, pixels)
        loss = ((render_volume(model, o, d) - targets[i][pixels]) ** 2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    return (time.perf_counter() - start) / n_steps


# ---------------------------------------------------------------- the homework NeRF


def harmonic(x, n):
    freqs = 2.0 ** torch.arange(n, dtype=x.dtype)
    e = (x[..., None] * freqs).reshape(*x.shape[:-1], -1)
    return torch.cat([e.sin(), e.cos(), x], dim=-1)


class Nerf(nn.Module):
    def __init__(self, n_xyz=6, n_dir=2, hidden=128, hidden_dir=64, layers=6, skip=(3,)):
        super().__init__()
        self.n_xyz, self.n_dir, self.skip = n_xyz, n_dir, skip
        d_xyz, d_dir = 6 * n_xyz + 3, 6 * n_dir + 3
        self.mlp = nn.ModuleList(
            nn.Linear(d_xyz if i == 0 else hidden + (d_xyz if i in skip else 0), hidden)
            for i in range(layers)
        )
        self.density = nn.Linear(hidden, 1)
        self.intermediate = nn.Linear(hidden, hidden)
        self.color0 = nn.Linear(hidden + d_dir, hidden_dir)
        self.color2 = nn.Linear(hidden_dir, 3)

    def forward(self, points, dirs):
        n, s, _ = points.shape
        xyz = harmonic(points, self.n_xyz)
        y = xyz
        for i, layer in enumerate(self.mlp):
            if i in self.skip:
                y = torch.cat([y, xyz], dim=-1)
            y = torch.relu(layer(y))
        sigma = torch.relu(self.density(y))[..., 0]
        d = harmonic(dirs, self.n_dir)[:, None].expand(n, s, -1)
        h = torch.relu(self.color0(torch.cat([self.intermediate(y), d], dim=-1)))
        return sigma, torch.sigmoid(self.color2(h))


def nerf_render(model, origins, dirs, n_pts=128, jitter=False):
    lengths = sample_lengths(origins.shape[0], n_pts, 2.0, 6.0, jitter)
    points = origins[:, None] + lengths[..., None] * dirs[:, None]
    sigma, colour = model(points, dirs)
    return composite(sigma, lengths, colour)[0]


# ---------------------------------------------------------------- benchmarks


def best_of(fn, repeats):
    runs = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        runs.append(time.perf_counter() - t)
    return min(runs), runs


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--box-steps", type=int, default=40,
                    help="train_box steps timed per repeat (the mean step is reported)")
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    np.random.seed(0)
    results = []

    box_cams = surround_cameras(3.0, 20, [0.0, 1.0, 0.0], 1.0)
    with torch.no_grad():
        secs, runs = best_of(lambda: [render_box(c) for c in box_cams], args.repeats)
    results.append({"name": "box render", "work": "20 frames 256x256 x 64 points",
                    "seconds": secs, "runs": runs})

    runs = [train_box_steps(args.box_steps) for _ in range(args.repeats)]
    results.append({"name": "train_box step",
                    "work": "4096 rays x 64 points of 256x256, fwd+bwd+Adam (box SDF)",
                    "seconds": min(runs), "runs": runs})

    model = Nerf()
    opt = torch.optim.Adam(model.parameters(), lr=5e-4)
    cam = surround_cameras(4.0, 20, [0.0, 0.0, 1.0], 2.0)[0]

    def step():
        pixels = np.random.randint(0, 128 * 128, 1024)
        o, d = rays_for_pixels(cam, 128, 128, pixels)
        target = torch.full((1024, 3), 0.5)
        loss = ((nerf_render(model, o, d, jitter=True) - target) ** 2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()

    secs, runs = best_of(step, args.repeats)
    results.append({"name": "NeRF training step", "work": "1024 rays x 128 points, fwd+bwd+Adam",
                    "seconds": secs, "runs": runs})

    def frame():
        o, d = rays_for_pixels(cam, 128, 128, np.arange(128 * 128))
        with torch.no_grad():
            return torch.cat([nerf_render(model, o[s:s + 4096], d[s:s + 4096])
                              for s in range(0, 128 * 128, 4096)])

    secs, runs = best_of(frame, min(args.repeats, 2))
    results.append({"name": "NeRF render", "work": "1 frame 128x128 x 128 points, dense",
                    "seconds": secs, "runs": runs})

    report = {
        "machine": {"cpu": platform.processor() or platform.machine(),
                    "threads": torch.get_num_threads(), "torch": torch.__version__},
        "results": results,
    }
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        print(f"torch {torch.__version__}, {torch.get_num_threads()} threads")
        for r in results:
            print(f"{r['name']:<22} {r['work']:<40} {r['seconds']:.3f} s")


if __name__ == "__main__":
    main()
