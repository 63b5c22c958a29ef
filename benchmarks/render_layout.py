"""Volume rendering over packed samples against the padded layout it replaced.

    python benchmarks/render_layout.py [--repeats 20]

One forward and backward pass of :func:`nerfkit.render.volrend.render_weights` and
:func:`~nerfkit.render.volrend.composite` (colour and depth), on batches shaped like the
course NeRF's (64 stratified samples per ray, every one evaluated, or the ~6% an
occupancy grid keeps) and like a dense fine pass (192 per ray). The padded baseline is
the code the packed layout replaced, kept here: (n_rays, n_samples) tensors, the kept samples scattered
into zeros. Prints median wall and CPU milliseconds, interleaved round by round.
"""

from __future__ import annotations

import argparse
import os

import torch
from ray_grads import print_medians, time_interleaved

from nerfkit.render.volrend import composite, render_weights


def padded_step(sig, rgb, t, mask, step) -> None:
    """The padded layout: every ray ``S`` slots, the dropped samples zero density."""
    n, S = mask.shape
    s = torch.zeros(n, S).masked_scatter(mask, sig[mask])
    c = torch.zeros(n, S, 3).masked_scatter(mask[..., None].expand(n, S, 3), rgb[mask])
    tau = s * step
    before = torch.cat([torch.zeros(n, 1), torch.cumsum(tau, -1)[:, :-1]], -1)
    w = torch.exp(-before) * -torch.expm1(-tau)
    out = (w[..., None] * c).sum(1)
    depth = (w * t).sum(1)
    (out.sum() + depth.sum()).backward()


def packed_step(sig, rgb, t, mask, step, ray_indices) -> None:
    w, _, _ = render_weights(sig[mask], step, ray_indices)
    out, depth, _ = composite(w, rgb[mask], ray_indices, mask.shape[0], t[mask])
    (out.sum() + depth.sum()).backward()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=20)
    args = parser.parse_args()
    gen = torch.Generator().manual_seed(0)
    print(
        f"median of {args.repeats}, load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs, "
        f"torch threads {torch.get_num_threads()}"
    )
    for n, S, keep in [(1024, 64, 1.0), (1024, 64, 0.06), (4096, 64, 0.06), (4096, 192, 1.0)]:
        sig = torch.rand(n, S, generator=gen).requires_grad_()
        rgb = torch.rand(n, S, 3, generator=gen).requires_grad_()
        t = torch.rand(n, S, generator=gen).cumsum(1)
        mask = torch.rand(n, S, generator=gen) < keep
        rays = torch.arange(n).unsqueeze(1).expand(n, S)[mask]
        args_ = (sig, rgb, t, mask, 0.01)
        wall, cpu = time_interleaved(
            {"padded": lambda a=args_: padded_step(*a), "packed": lambda a=args_, r=rays: packed_step(*a, r)},
            warmup=2,
            repeats=args.repeats,
        )
        print_medians(f"{n}x{S}, {int(mask.sum()) / n:.1f}/ray", wall, cpu, "padded")


if __name__ == "__main__":
    main()
