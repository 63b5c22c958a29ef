"""What a sparse texture lookup costs, compiled and in torch.

    python benchmarks/texture_lookup.py [--lookups 4096] [--repeats 30]

A capture's training step looks up its table, floor and room-shell textures about ten
times (colour, coverage, glossiness; coarse and fine). One lookup here is the forward and
backward pass of :func:`nerfkit.fields.background.sample_texture` with a GradSink (the
texture's gradient into the sink's lanes, the coordinates' into ``uv.grad``), then the
sink cleared, on textures of the dev captures' sizes:

* ``table``  512 x 512 texels, 3 channels;
* ``shells`` 1024 x 1536 texels, 4 channels (three room shells of 1024 x 512).

Each is timed through the compiled kernels and through the torch path (its reference),
interleaved round by round. Prints the median wall and process-CPU milliseconds and the
ratios to the torch path.
"""

from __future__ import annotations

import argparse
import os

import torch
from ray_grads import print_medians, time_interleaved

import nerfkit.fields.background as background
from nerfkit.kernels import numba_kernels
from nerfkit.kernels.ops import GradSink

TEXTURES = {"table": ((512, 512), 3), "shells": ((1024, 1536), 4)}


def lookup(tex: torch.Tensor, size, uv: torch.Tensor, weights: torch.Tensor, sink: GradSink, compiled: bool) -> None:
    """Forward and backward of one sparse lookup (the torch path when not ``compiled``)."""
    chosen = background._compiled
    if not compiled:
        background._compiled = lambda *_: None
    try:
        uv.grad = None
        (background.sample_texture(tex, size, uv, sink) * weights).sum().backward()
    finally:
        background._compiled = chosen
    sink.clear()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lookups", type=int, default=4096, help="coordinates per lookup (default 4096: a batch of rays)")
    ap.add_argument("--repeats", type=int, default=30)
    ap.add_argument("--warmup", type=int, default=5)
    args = ap.parse_args()
    if numba_kernels() is None:
        raise SystemExit("numba is not available: nothing to compare")
    g = torch.Generator().manual_seed(0)
    cases = {}
    for name, (size, channels) in TEXTURES.items():
        tex = torch.randn(size[0] * size[1], channels, generator=g).requires_grad_()
        uv = (torch.rand(args.lookups, 2, generator=g) * 2 - 1).requires_grad_()
        weights = torch.randn(args.lookups, channels, generator=g)
        sink = GradSink(tex.shape[0], channels)
        for compiled in (False, True):
            cases[f"{name} {'numba' if compiled else 'torch'}"] = (
                lambda t=tex, s=size, u=uv, w=weights, k=sink, c=compiled: lookup(t, s, u, w, k, c)
            )
    wall, cpu = time_interleaved(cases, args.warmup, args.repeats)
    print(
        f"{args.lookups} lookups, forward + backward, median of {args.repeats}, "
        f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs"
    )
    for name in TEXTURES:
        keys = [f"{name} torch", f"{name} numba"]
        print_medians(name, {k: wall[k] for k in keys}, {k: cpu[k] for k in keys}, keys[0])


if __name__ == "__main__":
    main()
