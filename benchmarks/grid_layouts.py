"""What the vertex-row lookup costs the compiled kernels, by storage layout.

    python benchmarks/grid_layouts.py [--res 128] [--rays 4096] [--repeats 15] [--sh-degree 1]

One training step (:func:`render_grid` forward + backward of a random linear loss, 4096
rays) through the lego-like random grid of ``ray_grads.py``, stored four ways, interleaved
step by step so that load from other processes hits each alike:

* ``dense``           rows are vertex numbers (no index);
* ``sentinel``        the fast model's dense stages: an empty row 0, then one row per vertex
                      (index = vertex + 1); the kernels compute rows, not read them;
* ``sentinel-lookup`` the same storage, rows read through the index (as before the kernels
                      learned to skip it);
* ``sparse``          the sparse stages: only vertices in or near dense balls stored, rows
                      in a shuffled order, read through the index.

Prints the median wall and process-CPU milliseconds per step and the ratios to ``dense``.
"""

from __future__ import annotations

import os

import torch
from ray_grads import camera_rays, lego_like, model_spec, parse_args, print_medians, step, time_interleaved

from nerfkit.kernels.ops import GradSink, GridGeom


class LookupGeom(GridGeom):
    """A GridGeom whose rows are always read through the index."""

    def row_offset(self) -> int:
        return -1


def layouts(grid: torch.Tensor, geom: GridGeom) -> dict[str, tuple[torch.Tensor, GridGeom]]:
    n, C = grid.shape
    sentinel = torch.cat([torch.zeros(1, C), grid.detach()])
    sentinel[0, 0] = -30.0
    index = torch.arange(1, n + 1, dtype=torch.int32)
    stored = grid.detach()[:, 0] > -10.0
    m = int(stored.sum())
    order = torch.randperm(m, generator=torch.Generator().manual_seed(0))
    sparse_index = torch.zeros(n, dtype=torch.int32)
    sparse_index[stored] = (order + 1).int()
    rows = torch.zeros(m + 1, C)
    rows[0, 0] = -30.0
    rows[order + 1] = grid.detach()[stored]
    return {
        "dense": (grid.detach(), geom),
        "sentinel": (sentinel, GridGeom(geom.lo, geom.voxel, geom.res, index)),
        "sentinel-lookup": (sentinel, LookupGeom(geom.lo, geom.voxel, geom.res, index)),
        "sparse": (rows, GridGeom(geom.lo, geom.voxel, geom.res, sparse_index)),
    }


def main() -> None:
    args = parse_args(__doc__.splitlines()[0])
    grid, geom = lego_like(args.res, args.sh_degree)
    spec = model_spec(grid, geom)
    o, d = camera_rays(args.rays)
    cases = {
        name: (g.requires_grad_(), gm, GradSink(g.shape[0], g.shape[1]))
        for name, (g, gm) in layouts(grid, geom).items()
    }
    wall, cpu = time_interleaved(
        {name: (lambda c=c: step(c[0], c[1], spec, o, d, args.sh_degree, "grid", c[2])) for name, c in cases.items()},
        args.warmup,
        args.repeats,
    )
    sparse_rows = cases["sparse"][0].shape[0] - 1
    print(
        f"grid {args.res}^3, C={grid.shape[1]}, {args.rays} rays, sparse layout stores "
        f"{sparse_rows / geom.n_vertices:.1%} of the vertices, median of {args.repeats}, "
        f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs"
    )
    print_medians("layout", wall, cpu, "dense")


if __name__ == "__main__":
    main()
