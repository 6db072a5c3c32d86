#!/usr/bin/env python3
"""Runs `nerf bench --json` and scripts/bench_pytorch.py on this machine, one after the other,
and prints both sides with their ratio (ours / PyTorch; below 1 means faster).

    cargo build --release
    python3 scripts/bench_compare.py [--nerf target/release/nerf] [--repeats 3] [--markdown OUT.md]

The trained-NeRF rows (dense and accelerated rendering of checkpoints/nerf_lego.safetensors)
are compared with PyTorch's dense render of the same frame size and sample count.
"""

import argparse
import json
import subprocess
import sys
from pathlib import Path

# Our benchmark name -> the PyTorch benchmark doing the same work.
PAIRS = {
    "box render": "box render",
    # The whole command (all five outputs) against PyTorch's render of the frames alone: the
    # yardstick of the speed goal.
    "box command (all outputs)": "box render",
    "train_box step": "train_box step",
    "NeRF training step": "NeRF training step",
    "NeRF render": "NeRF render",
    "trained NeRF render, dense": "NeRF render",
    "trained NeRF render, occupancy grid + early termination": "NeRF render",
}


def run_json(cmd):
    out = subprocess.run(cmd, check=True, capture_output=True, text=True)
    return json.loads(out.stdout)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--nerf", default="target/release/nerf")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--markdown", type=Path, help="also write the table here")
    args = ap.parse_args()
    ours = run_json([args.nerf, "bench", "--config", "box", "--json", "--repeats", str(args.repeats)])
    theirs = run_json(
        [sys.executable, str(Path(__file__).with_name("bench_pytorch.py")), "--json",
         "--repeats", str(args.repeats)]
    )
    torch_by_name = {r["name"]: r for r in theirs["results"]}
    m = ours["machine"]
    lines = [
        f"machine: {m['cpu']} | nerf: {m['threads']} threads, {m['profile']} | "
        f"PyTorch {theirs['machine']['torch']}: {theirs['machine']['threads']} threads",
        "",
        "| benchmark | work | nerf (s) | PyTorch (s) | ratio | error |",
        "|---|---|---|---|---|---|",
    ]
    for r in ours["results"]:
        t = torch_by_name.get(PAIRS.get(r["name"], ""))
        pt = f"{t['seconds']:.3f}" if t else "-"
        ratio = f"{r['seconds'] / t['seconds']:.2f}x" if t else "-"
        lines.append(
            f"| {r['name']} | {r['work']} | {r['seconds']:.3f} | {pt} | {ratio} | "
            f"{r.get('error') or '-'} |"
        )
    table = "\n".join(lines)
    print(table)
    if args.markdown:
        args.markdown.write_text(table + "\n")


if __name__ == "__main__":
    main()
