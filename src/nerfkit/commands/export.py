"""`nerfkit export`: a trained run as a coloured mesh and/or point cloud (PLY), or a splat
run's Gaussians (3DGS PLY or .splat)."""

from __future__ import annotations

import argparse

# Field points evaluated per call when sampling the density grid and vertex colours.
POINT_CHUNK = 65536

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
format of web viewers (colour without view dependence).

examples:
  nerfkit export runs/lego --mesh lego.ply
  nerfkit export runs/lego --mesh lego.ply --resolution 384 --threshold 10 --color-views 100
  nerfkit export runs/lego --points lego_points.ply --every 5 --stride 2
  nerfkit export runs/lego_splat --splat lego.ply
"""


def register(sub: argparse._SubParsersAction) -> None:
    from ..config import number
    from ..export import COLOUR_VIEWS
    from ..tabletop import TABLE_CUT
    from ._common import add_run_device_args

    p = sub.add_parser(
        "export", help=HELP, description=HELP + ".", epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("run", metavar="RUN", help="run folder written by `nerfkit train`")
    p.add_argument("--mesh", metavar="OUT.ply", help="write a vertex-coloured triangle mesh here")
    p.add_argument("--points", metavar="OUT.ply", help="write a coloured point cloud here")
    p.add_argument("--splat", metavar="OUT.ply", help="(splat runs) write the Gaussians here: 3DGS PLY, or .splat")
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
        type=number(float, above=0),
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
    from pathlib import Path

    from ..errors import fail

    splat = getattr(args, "splat", None)
    if not args.mesh and not args.points and not splat:
        raise fail("export", "nothing to export", "Pass --mesh OUT.ply, --points OUT.ply or --splat OUT.ply")
    for flag, path in (("--mesh", args.mesh), ("--points", args.points)):
        if path and not path.lower().endswith(".ply"):
            raise fail(flag, f"'{path}' should end in .ply")
    if splat and not splat.lower().endswith((".ply", ".splat")):
        raise fail("--splat", f"'{splat}' should end in .ply or .splat")
    outs = [Path(p).resolve() for p in (args.mesh, args.points, splat) if p]
    if len(set(outs)) < len(outs):
        raise fail("--mesh/--points/--splat", "name the same file")
    from ..data.load import dataset_inputs
    from ..io.paths import guard_outputs
    from ._common import open_run

    run_ = open_run(args)
    if splat and not hasattr(run_.model, "n_gaussians"):
        raise fail(args.run, f"is a {run_.info.train.model} run; --splat exports runs of --model splat")
    if (args.mesh) and hasattr(run_.model, "n_gaussians"):
        raise fail(args.run, "is a splat run: it has no density field to mesh", "Use --splat OUT.ply or --points")
    guard_outputs(
        [args.mesh, args.points, splat],
        dataset_inputs(args.data or run_.info.train.data),
        args.force,
        "--mesh/--points/--splat",
    )
    if splat:
        export_splat(run_, splat)
    bounds = run_.info.bounds
    if args.mesh:
        export_mesh(run_, args)
    if args.points:
        export_points(run_, bounds.center, bounds.radius * args.box_scale, args)
    return 0


def export_splat(run_, path: str) -> None:
    from ..splat_files import Gaussians, write_dot_splat, write_splat_ply

    g = Gaussians.from_model(run_.model)
    if path.lower().endswith(".splat"):
        write_dot_splat(path, g)
    else:
        write_splat_ply(path, g)
    print(f"{len(g)} Gaussians of step {run_.step} (SH degree {g.sh_degree}) -> {path}")


def export_mesh(run_, args) -> None:
    from ..errors import advice
    from ..export import ColourViews, mesh_from_model, mesh_region, mesh_threshold, write_mesh_ply
    from ..output.images import render_image
    from ..surroundings import object_alone, table_cut_height, table_plane, table_tags
    from ..tabletop import cleared_note
    from ._common import scene_for_run

    model, bounds = run_.model, run_.info.bounds
    center, radius = mesh_region(model, bounds.center, bounds.radius, args.box_scale)
    height = table_cut_height(model, args.table_cut)
    threshold = args.threshold if args.threshold is not None else mesh_threshold(model, radius)
    views, bg = None, run_.background()
    ndc = getattr(model, "ndc", None) is not None  # (coloured at the vertices: see mesh_from_model)
    if args.color_views > 0 and not ndc:
        with advice("Or pass --color-views 0 to colour the mesh without the dataset"):
            scene = scene_for_run(run_.info, args.data, allow_outside=args.allow_outside_paths)
        views = ColourViews.pick(scene.train, args.color_views)
    # a capture's table and room would show through its object's edges
    alone = object_alone(model).model if views is not None else model

    def render_fn(K, c2w, w, h):
        out = render_image(alone, K, c2w, w, h, bg, run_.chunk, run_.autocast)
        return out.rgb, out.depth, out.acc

    mesh = mesh_from_model(
        model,
        center,
        radius,
        bounds.radius,
        args.resolution,
        threshold,
        args.color_dirs,
        chunk=POINT_CHUNK,
        device=run_.device,
        table_cut=height,
        views=views,
        render_fn=render_fn,
        background=tuple(bg.tolist()),
    )
    write_mesh_ply(args.mesh, mesh)
    cut = ""
    if table_plane(model) is not None:
        cut = f"; {cleared_note(height, table_tags(model))}"
    coloured = (
        f"coloured from {len(views)} training views"
        if views is not None
        else "coloured at the vertices"
        if ndc
        else "coloured along the normals"
    )
    print(
        f"mesh of step {run_.step}: {len(mesh.vertices)} vertices, {len(mesh.faces)} faces "
        f"(threshold {threshold:.3g}, {args.resolution}^3 grid over a {2 * radius:.3g}-wide cube{cut}; "
        f"{coloured}) -> {args.mesh}"
    )


def export_points(run_, center, radius: float, args) -> None:
    from ..export import crop_to_box, points_from_views, write_points_ply
    from ..output.images import render_image
    from ._common import scene_for_run

    scene = scene_for_run(run_.info, args.data, allow_outside=args.allow_outside_paths)
    views = scene.train.subset(list(range(0, len(scene.train), args.every)))
    bg = run_.background()

    def render_fn(K, c2w, w, h):
        out = render_image(run_.model, K, c2w, w, h, bg, run_.chunk)
        return out.rgb, out.depth, out.acc

    pts, cols = points_from_views(render_fn, views, args.acc_min, tuple(bg.tolist()), args.stride)
    n_all = len(pts)
    if not args.no_crop:
        pts, cols = crop_to_box(pts, cols, center, radius)
    write_points_ply(args.points, pts, cols)
    print(
        f"point cloud of step {run_.step}: {len(pts)} points from {len(views)} views "
        f"({n_all - len(pts)} outside the scene box dropped) -> {args.points}"
    )
