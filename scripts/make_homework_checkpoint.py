#!/usr/bin/env python3
"""Writes a training checkpoint exactly as the homework's main.py keeps one, for the tests of
reading PyTorch checkpoints without an import step; and checks that a checkpoint written by
`nerf train` (which keeps a PyTorch checkpoint in PyTorch's format) loads in PyTorch.

    pip install torch numpy safetensors
    python3 scripts/make_homework_checkpoint.py tests/fixtures
    python3 scripts/make_homework_checkpoint.py --check FILE [--layers 3 --hidden 8 ...]

Writes into the directory:
  tiny_nerf_homework.pth          torch.save({"model": Model.state_dict() (keys implicit_fn.*),
                                  "optimizer": torch.optim.Adam's state_dict after 3 steps,
                                  "epoch": 3}, path), the homework's train_nerf checkpoint, of
                                  the tiny NeRF of tests/fixtures/tiny_nerf.yaml
  tiny_nerf_homework.safetensors  the same weights and Adam moments under our names
                                  (adam.exp_avg.<name>, adam.exp_avg_sq.<name>), epoch 3,
                                  adam_step 3, as `nerf train` writes them

`--check FILE` loads FILE with torch.load (weights_only, PyTorch's default), loads its model
into the homework's Model and its optimizer state into a fresh Adam, takes one step, and
prints what it found.
"""

import argparse
import sys
from pathlib import Path

import torch
from safetensors.torch import save_file

sys.path.insert(0, str(Path(__file__).parent))
from make_torch_state_dict import Model, NeuralRadianceField  # noqa: E402


def tiny_field(args):
    return NeuralRadianceField(
        n_xyz=args.harmonics_xyz, n_dir=args.harmonics_dir, hidden=args.hidden,
        hidden_dir=args.hidden_dir, n_layers=args.layers, append_xyz=args.skip,
    )


def train_a_little(model, steps=3):
    """A few Adam steps on a fixed loss, so that the optimizer has state."""
    opt = torch.optim.Adam(model.parameters(), lr=5e-4)
    points = torch.randn(64, 3)
    dirs = torch.nn.functional.normalize(torch.randn(64, 3), dim=-1)
    for _ in range(steps):
        density, colour = model.implicit_fn(points, dirs)
        loss = ((colour - 0.5) ** 2).mean() + density.mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    return opt


def write(out, args):
    torch.manual_seed(0)
    field = tiny_field(args)
    with torch.no_grad():
        field.density_layer[0].bias.fill_(0.5)
    model = Model(field)
    opt = train_a_little(model)
    epoch = 3
    torch.save({"model": model.state_dict(), "optimizer": opt.state_dict(), "epoch": epoch},
               out / "tiny_nerf_homework.pth")
    # Our names: the field's, without the implicit_fn. prefix; Adam's state by parameter.
    tensors = {}
    names = [n for n, _ in field.named_parameters()]
    state = opt.state_dict()["state"]
    for i, (name, p) in enumerate(field.named_parameters()):
        tensors[name] = p.detach().contiguous()
        tensors[f"adam.exp_avg.{name}"] = state[i]["exp_avg"].contiguous()
        tensors[f"adam.exp_avg_sq.{name}"] = state[i]["exp_avg_sq"].contiguous()
    steps = int(state[0]["step"])
    save_file(tensors, str(out / "tiny_nerf_homework.safetensors"),
              metadata={"epoch": str(epoch), "adam_step": str(steps), "format": "nerf-candle-1"})
    print(f"wrote {out}/tiny_nerf_homework.pth and .safetensors ({len(names)} parameters, "
          f"epoch {epoch}, Adam step {steps})")


def check(path, args):
    data = torch.load(path)  # weights_only=True by default since PyTorch 2.6
    model = Model(tiny_field(args))
    model.load_state_dict(data["model"])
    opt = torch.optim.Adam(model.parameters(), lr=5e-4)
    opt.load_state_dict(data["optimizer"])
    step = opt.state_dict()["state"][0]["step"]
    lr = opt.param_groups[0]["lr"]
    train_a_little(model, 1)
    print(f"{path}: model loaded ({len(data['model'])} tensors), optimizer at step "
          f"{int(step)} with lr {lr:g}, epoch {data['epoch']}; one more Adam step ran")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("out", nargs="?", default="tests/fixtures")
    ap.add_argument("--check", type=Path, help="load this checkpoint in PyTorch instead")
    ap.add_argument("--harmonics-xyz", type=int, default=2)
    ap.add_argument("--harmonics-dir", type=int, default=1)
    ap.add_argument("--hidden", type=int, default=8)
    ap.add_argument("--hidden-dir", type=int, default=4)
    ap.add_argument("--layers", type=int, default=3)
    ap.add_argument("--skip", type=int, nargs="*", default=[2])
    args = ap.parse_args()
    if args.check:
        check(args.check, args)
    else:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        write(out, args)


if __name__ == "__main__":
    main()
