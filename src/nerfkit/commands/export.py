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
    from ..config import number
    from ..export import COLOUR_VIEWS
    from ..surroundings.clearing import TABLE_CUT
    from ._common import add_run_device_args

    p = sub.add_parser(
        "export", help=HELP, description=HELP + ".", epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("run", metavar="RUN", help="run folder written by `nerfkit train`")
    p.add_argument("--mesh", metavar="OUT.ply", help="write a vertex-coloured triangle mesh here")
    p.add_argument("--points", metavar="OUT.ply", help="write a coloured point cloud here")
    p.add_argument("--splat", metavar="OUT.ply", help="(splat runs) write the Gaussians here: 3DGS PLY, or .splat")
    p.add_argument(
        "--no-background-dome",
        dest="background_dome",
        action="store_false",
        help="(splat runs with a learned background, as captures) leave out the dome of Gaussians "
        "that carries the background into the file",
    )
    g = p.add_argument_group("mesh")
    g.add_argument("--resolution", type=number(int, 8, 1024), default=256, help="grid cells per side (default: 256)")
    g.add_argument(
        "--threshold",
        type=number(float, above=0),
        default=None,
        help="density of the surface (default: the density at which 1/256 of the meshed cube's width "
        "is 7%% opaque, whatever the scene's units: lego's about 6, a 15-cm object's in metres about "
        "120; printed; higher = tighter, fewer floaters)",
    )
    g.add_argument(
        "--box-scale",
        type=number(float, above=0, max=100),
        default=1.0,
        help="scale the cube meshed, and the scene box points are cropped to (default: 1)",
    )
    g.add_argument(
        "--table-cut",
        type=number(float, 0, 1),
        default=TABLE_CUT,
        help="(captures) clear density within this fraction of the object's height above the table, "
        "where nothing rises out of that slab, and pieces apart from the object lower than three times "
        "that: the tags and sheet painted into density (0: clear only under the table; default: "
        "%(default)g)",
    )
    g.add_argument(
        "--color-views",
        type=number(int, 0, 10000),
        default=COLOUR_VIEWS,
        metavar="N",
        help="training views rendered for the vertex colours (0: colour along the normals only, "
        "without the dataset; default: %(default)s)",
    )
    g.add_argument(
        "--color-dirs",
        type=number(int, 1, 64),
        default=1,
        metavar="N",
        help="directions averaged per colour of a vertex no view sees (1 = along the normal; default: 1)",
    )
    p.add_argument(
        "--data", help="dataset whose training views the mesh's colours and the points come from (default: the run's)"
    )
    g = p.add_argument_group("points")
    g.add_argument("--every", type=number(int, 1), default=1, help="use every N-th training view (default: 1)")
    g.add_argument(
        "--stride", type=number(int, 1, 4096), default=1, help="use every N-th pixel in each direction (default: 1)"
    )
    g.add_argument(
        "--acc-min",
        type=number(float, 0, 0.999),
        default=0.5,
        help="keep pixels with opacity above this (default: 0.5)",
    )
    g.add_argument("--no-crop", action="store_true", help="keep points outside the scene box")
    p.add_argument("--force", action="store_true", help="replace existing output files")
    add_run_device_args(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """``nerfkit export``: :func:`nerfkit.api.export` with the parsed flags."""
    from ._common import run_device_options
    from .pipeline import export

    export(
        args.run,
        mesh=args.mesh,
        points=args.points,
        splat=args.splat,
        resolution=args.resolution,
        threshold=args.threshold,
        box_scale=args.box_scale,
        table_cut=args.table_cut,
        color_views=args.color_views,
        color_dirs=args.color_dirs,
        every=args.every,
        stride=args.stride,
        acc_min=args.acc_min,
        crop=not args.no_crop,
        background_dome=args.background_dome,
        **run_device_options(args),
        force=args.force,
    )
    return 0
