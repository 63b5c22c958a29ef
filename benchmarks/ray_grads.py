"""Cost of ray gradients (camera-pose refinement) on the compiled path.

    python benchmarks/ray_grads.py [--res 128] [--rays 4096] [--repeats 15] [--sh-degree 1]

One training step = :func:`render_grid` forward + backward of a random linear loss for
4096 rays through a lego-like random grid (128^3 vertices, density in a few random balls
filling ~10% of the box, occupancy at the model's default thresholds, coarse factor 8).
Three modes, interleaved step by step so that load from other processes hits each alike:

* ``grid``        the normal training step (grid gradient into a GradSink);
* ``grid+rays``   also ``rays_o`` and ``rays_d`` requiring grad (pose refinement while training);
* ``rays``        frozen grid, rays requiring grad, no sink (held-out views' poses).

Prints the median wall and process-CPU milliseconds per step of each mode (after warm-up
steps), and their ratios to ``grid``. On a shared machine trust the CPU column more.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import torch

from nerfkit.estimators.occupancy import OccupancyEstimator
from nerfkit.kernels import numba_kernels
from nerfkit.kernels import reference as ref
from nerfkit.kernels.ops import GradSink, GridGeom, MarchSpec, cell_density_max, render_grid
from nerfkit.render.box import ray_aabb


def lego_like(res: int, sh_degree: int, seed: int = 0):
    """A (res^3, C) grid over [-1, 1]^3: raw density ~ N(2, 1) inside 6 random balls, -10 outside."""
    g = torch.Generator().manual_seed(seed)
    voxel = 2.0 / (res - 1)
    geom = GridGeom(torch.full((3,), -1.0), voxel, (res, res, res))
    grid = torch.randn(geom.n_vertices, 1 + 3 * ref.sh_dim(sh_degree), generator=g)
    pos = geom.vertex_positions()
    inside = torch.zeros(geom.n_vertices, dtype=torch.bool)
    for _ in range(6):
        c = (torch.rand(3, generator=g) - 0.5) * 1.2
        inside |= (pos - c).norm(dim=1) < 0.15 + 0.2 * torch.rand(1, generator=g)
    grid[:, 0] = torch.where(inside, grid[:, 0] + 2.0, torch.full_like(grid[:, 0], -10.0))
    return grid, geom


def model_spec(grid, geom: GridGeom, coarse_factor: int = 8) -> MarchSpec:
    """The fast model's defaults: step half a voxel, density in units of a 32^3 grid's voxel,
    cells skipped below opacity 1e-2, early stop at transmittance 1e-4."""
    step, dscale = 0.5 * geom.voxel, 31 / 2.0
    occ = OccupancyEstimator(geom.box, coarse_factor=coarse_factor)
    occ.set_from_cell_sigma(cell_density_max(grid, geom, dscale), step, 1e-2)
    return occ.march_spec(step, 1e-4, dscale)


def camera_rays(n: int, seed: int = 1):
    """Rays from a sphere of radius 4 towards points near the centre, with box bounds."""
    g = torch.Generator().manual_seed(seed)
    d = torch.randn(n, 3, generator=g)
    d = d / d.norm(dim=1, keepdim=True)
    o = -4.0 * d + 0.3 * torch.randn(n, 3, generator=g)
    return o, d


def step(grid, geom, spec, o, d, sh_degree: int, mode: str, sink: GradSink) -> None:
    """One forward + backward in the given mode (gradients are left where they land)."""
    o = o.clone().requires_grad_(mode != "grid")
    d = d.clone().requires_grad_(mode != "grid")
    t0, t1 = ray_aabb(o.detach(), d.detach(), geom.lo, geom.hi, 0.0, 10.0)
    u = torch.rand(o.shape[0])
    g = grid if mode != "rays" else grid.detach()
    out = render_grid(g, geom, spec, o, d, t0, t1, u, sh_degree, sink if mode != "rays" else None, "numba")
    (out.rgb.sum() + 0.1 * out.depth.sum()).backward()
    sink.clear()


def parse_args(description: str) -> argparse.Namespace:
    """The options these kernel benchmarks share."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--rays", type=int, default=4096)
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--sh-degree", type=int, default=1)
    args = ap.parse_args()
    if numba_kernels() is None:
        raise SystemExit("numba kernels unavailable")
    torch.manual_seed(0)
    return args


def time_interleaved(cases: dict, warmup: int, repeats: int) -> tuple[dict, dict]:
    """Run each ``{name: fn}`` once per round, ``warmup + repeats`` rounds; the wall and
    process-CPU milliseconds of the last ``repeats`` rounds, per name."""
    wall = {name: [] for name in cases}
    cpu = {name: [] for name in cases}
    for rep in range(warmup + repeats):
        for name, fn in cases.items():
            w0, c0 = time.perf_counter(), time.process_time()
            fn()
            if rep >= warmup:
                wall[name].append(1e3 * (time.perf_counter() - w0))
                cpu[name].append(1e3 * (time.process_time() - c0))
    return wall, cpu


def print_medians(label: str, wall: dict, cpu: dict, base: str) -> None:
    """A table of the median wall and CPU milliseconds per name, and their ratios to ``base``."""
    print(f"{label:<16} {'wall ms':>8} {'cpu ms':>8} {'wall ratio':>10} {'cpu ratio':>10}")
    bw, bc = statistics.median(wall[base]), statistics.median(cpu[base])
    for name in wall:
        mw, mc = statistics.median(wall[name]), statistics.median(cpu[name])
        print(f"{name:<16} {mw:8.1f} {mc:8.1f} {mw / bw:10.2f} {mc / bc:10.2f}")


def main() -> None:
    args = parse_args(__doc__.splitlines()[0])
    grid, geom = lego_like(args.res, args.sh_degree)
    grid.requires_grad_()
    spec = model_spec(grid, geom)
    o, d = camera_rays(args.rays)
    sink = GradSink(geom.n_vertices, grid.shape[1])
    modes = ["grid", "grid+rays", "rays"]
    wall, cpu = time_interleaved(
        {m: (lambda m=m: step(grid, geom, spec, o, d, args.sh_degree, m, sink)) for m in modes},
        args.warmup,
        args.repeats,
    )
    with torch.no_grad():
        t0, t1 = ray_aabb(o, d, geom.lo, geom.hi, 0.0, 10.0)
        n_samples = render_grid(
            grid, geom, spec, o, d, t0, t1, torch.full((args.rays,), 0.5), args.sh_degree, None, "numba"
        ).n_samples
    print(
        f"grid {args.res}^3, C={grid.shape[1]}, {args.rays} rays, ~{n_samples / args.rays:.1f} samples/ray, "
        f"occupied {float(spec.occ.float().mean()):.1%}, median of {args.repeats}, "
        f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs"
    )
    print_medians("mode", wall, cpu, "grid")


if __name__ == "__main__":
    main()
