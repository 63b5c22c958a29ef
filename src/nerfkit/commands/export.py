"""`nerfkit export`: a trained run as a coloured mesh and/or point cloud (PLY), or a splat
run's Gaussians (3DGS PLY or .splat)."""

from __future__ import annotations

import argparse

MEMORY_HINT = "Lower --resolution or --chunk"
HELP = "export a trained run as a coloured mesh (marching cubes) and/or a point cloud (PLY), or Gaussian splats"

EPILOG = """\
mesh: the density is sampled on a RESOLUTION^3 grid over a cube around the model's grid
(a capture's box around the object; the scene's cube for a model without one), its
half-size times --box-scale. A capture's table paint is cleared first: the density under
the table, the tags and sheet painted into density just above it (within --table-cut
of the object's height, where nothing rises out of that slab), and pieces apart from the
object that stand less than three times that high; what stands on the table keeps its
base. The THRESHOLD iso-surface (scale-free by default, see --threshold) is extracted with
marching cubes (closed where it meets the box or the cut). Each vertex takes the mean of
the NeRF's renders of its object at the training views that see it (--color-views of them,
evenly spread; seen: the normal faces the camera and the vertex lies within 5% of the
scene's radius of the rendered depth). A vertex no view sees (or every vertex, with
--color-views 0) is coloured by what a ray looking at it along the inward normal sees (the
field rendered from 2% of the scene's radius outside the surface to 4% inside), not by
the field's colour at the iso-surface itself, which training leaves as noise. A
forward-facing run in NDC, whose density is per NDC unit, takes the colour at the vertex.
points: every --every-th training view is rendered; pixels with opacity > --acc-min are
back-projected to their expected depth and coloured by the rendered colour.
splat (runs of --model splat): the Gaussians as the standard 3DGS PLY (what the INRIA code,
gsplat, SuperSplat and Brush read), or, for a name ending in .splat, the 32-byte-per-Gaussian
format of web viewers (colour without view dependence). A run that learned its background (a
colour per direction behind the Gaussians, as captures do) gets it as a dome: a few thousand
flat, nearly opaque Gaussians on a sphere 100 times beyond the cameras and the far bound,
each coloured by the background in its direction, so other viewers show what `nerfkit
render` shows; --no-background-dome leaves it out.

examples:
  nerfkit export runs/lego --mesh lego.ply
  nerfkit export runs/lego --mesh lego.ply --resolution 384 --threshold 10 --color-views 100
  nerfkit export runs/lego --points lego_points.ply --every 5 --stride 2
  nerfkit export runs/lego_splat --splat lego.ply
"""


def register(sub: argparse._SubParsersAction) -> None:
    from ..config import add_dataclass_args
    from ._common import add_run_device_args
    from .options import ExportOptions

    p = sub.add_parser(
        "export", help=HELP, description=HELP + ".", epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("run", metavar="RUN", help="run folder written by `nerfkit train`")
    p.add_argument("--mesh", metavar="OUT.ply", help="write a vertex-coloured triangle mesh here")
    p.add_argument("--points", metavar="OUT.ply", help="write a coloured point cloud here")
    p.add_argument("--splat", metavar="OUT.ply", help="(splat runs) write the Gaussians here: 3DGS PLY, or .splat")
    add_dataclass_args(p, ExportOptions)  # --no-background-dome here; the mesh and points groups
    p.add_argument(
        "--data", help="dataset whose training views the mesh's colours and the points come from (default: the run's)"
    )
    p.add_argument("--force", action="store_true", help="replace existing output files")
    add_run_device_args(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """``nerfkit export``: :func:`nerfkit.api.export` with the parsed flags (unset options: the defaults
    of :class:`~nerfkit.commands.options.ExportOptions`)."""
    import dataclasses

    from ..config import dataclass_from_args
    from ._common import run_device_options
    from .options import ExportOptions
    from .pipeline import export

    export(
        args.run,
        mesh=args.mesh,
        points=args.points,
        splat=args.splat,
        **dataclasses.asdict(dataclass_from_args(ExportOptions, args)),
        **run_device_options(args),
        force=args.force,
    )
    return 0
