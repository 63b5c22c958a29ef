"""The export stage in small steps: the output names checked, and a run written as Gaussians,
a mesh or a point cloud; each returns the line that says what it wrote."""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import Any

# Field points evaluated per call when sampling the density grid and vertex colours.
POINT_CHUNK = 65536


def check_outputs(mesh: str | None, points: str | None, splat: str | None) -> None:
    """Refuse an export of nothing, a mesh or points not named .ply, Gaussians named neither
    .ply nor .splat, and two outputs that name the same file."""
    from ...errors import fail

    if not mesh and not points and not splat:
        raise fail("export", "nothing to export", "Pass --mesh OUT.ply, --points OUT.ply or --splat OUT.ply")
    for flag, path in (("--mesh", mesh), ("--points", points)):
        if path and not path.lower().endswith(".ply"):
            raise fail(flag, f"'{path}' should end in .ply")
    if splat and not splat.lower().endswith((".ply", ".splat")):
        raise fail("--splat", f"'{splat}' should end in .ply or .splat")
    outs = [Path(p).resolve() for p in (mesh, points, splat) if p]
    if len(set(outs)) < len(outs):
        raise fail("--mesh/--points/--splat", "name the same file")


def note_idle_options(options: Any, mesh: str | None, points: str | None, splat: str | None, data: str | None) -> None:
    """Say on stderr which of ``options`` (an :class:`~nerfkit.commands.options.ExportOptions`)
    differ from their defaults but act only with an output not asked for (a field's ``needs``),
    and ``data`` without a mesh or points: said, not silently dropped."""
    import dataclasses
    import sys

    from ...config import flag_of, switch_flag

    asked = {"--mesh": mesh, "--points": points, "--mesh or --points": mesh or points, "--splat": splat}
    defaults = type(options)()
    idle: dict[str, list[str]] = {needs: [] for needs in asked}
    for f in dataclasses.fields(options):
        if getattr(options, f.name) != getattr(defaults, f.name):
            idle[f.metadata["needs"]].append(switch_flag(f) if f.metadata.get("switch") else flag_of(f.name))
    if data is not None:
        idle["--mesh or --points"].append("--data")
    for needs, flags in idle.items():
        if flags and not asked[needs]:
            print(f"note: {', '.join(flags)} {'acts' if len(flags) == 1 else 'act'} only with {needs}", file=sys.stderr)


def export_splat(opened: Any, path: str, background_dome: bool = True) -> str:
    """Write the Gaussians of the splat run ``opened`` to ``path`` (3DGS PLY, or .splat); with
    ``background_dome``, a model's learned background follows them as a far dome of Gaussians
    (:mod:`nerfkit.capture.dome`), so that other viewers show it too."""
    from ...capture.dome import join, model_dome
    from ...splat_files import Gaussians, write_dot_splat, write_splat_ply

    g = Gaussians.from_model(opened.model)
    dome = model_dome(opened.model, opened.info.bounds) if background_dome else None
    out = g if dome is None else join(g, dome)
    if path.lower().endswith(".splat"):
        write_dot_splat(path, out)
    else:
        write_splat_ply(path, out)
    what = f"{len(g)} Gaussians of step {opened.step} (SH degree {g.sh_degree})"
    if dome is not None:
        what += f" and {len(dome)} of the learned background's dome (--no-background-dome leaves them out)"
    return f"{what} -> {path}"


def train_longer(opened: Any) -> str:
    """The advice to train the run ``opened`` on: a run that holds no surface yet exports none."""
    return f"train it longer (nerfkit train --resume {opened.info.run_dir} --minutes 3)"


def export_mesh(
    opened: Any,
    path: str,
    *,
    resolution: int,
    threshold: float | None,
    box_scale: float,
    table_cut: float,
    color_views: int,
    color_dirs: int,
    data: str | None,
    allow_outside: bool,
) -> str:
    """Write the run ``opened`` as a vertex-coloured mesh to ``path`` (see ``nerfkit export --help``)."""
    from ...errors import advice
    from ...export import ColourViews, mesh_from_model, mesh_region, mesh_threshold, write_mesh_ply
    from ...output.images import render_image
    from ...surroundings import object_alone, table_cut_height, table_plane, table_tags
    from ...surroundings.clearing import cleared_note
    from .._common import scene_for_run

    model, bounds = opened.model, opened.info.bounds
    center, radius = mesh_region(model, bounds.center, bounds.radius, box_scale)
    height = table_cut_height(model, table_cut)
    # the automatic threshold missing every density: likely a run trained too briefly to hold a surface
    young = (
        advice(
            f"Or, as the run is at step {opened.step}, {train_longer(opened)}: "
            "a run trained briefly holds no surface yet"
        )
        if threshold is None
        else contextlib.nullcontext()
    )
    threshold = threshold if threshold is not None else mesh_threshold(model, radius)
    views, bg = None, opened.background()
    ndc = getattr(model, "ndc", None) is not None  # (coloured at the vertices: see mesh_from_model)
    if color_views > 0 and not ndc:
        with advice("Or pass --color-views 0 to colour the mesh without the dataset"):
            scene = scene_for_run(opened.info, data, allow_outside=allow_outside)
        views = ColourViews.pick(scene.train, color_views)
    # a capture's table and room would show through its object's edges
    alone = object_alone(model).model if views is not None else model

    def render_fn(K, c2w, w, h):
        out = render_image(alone, K, c2w, w, h, bg, opened.chunk, opened.autocast)
        return out.rgb, out.depth, out.acc

    with young:
        mesh = mesh_from_model(
            model,
            center,
            radius,
            bounds.radius,
            resolution,
            threshold,
            color_dirs,
            chunk=POINT_CHUNK,
            device=opened.device,
            table_cut=height,
            views=views,
            render_fn=render_fn,
            background=tuple(bg.tolist()),
        )
    write_mesh_ply(path, mesh)
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
    return (
        f"mesh of step {opened.step}: {len(mesh.vertices)} vertices, {len(mesh.faces)} faces "
        f"(threshold {threshold:.3g}, {resolution}^3 grid over a {2 * radius:.3g}-wide cube{cut}; "
        f"{coloured}) -> {path}"
    )


def export_points(
    opened: Any,
    path: str,
    *,
    every: int,
    stride: int,
    acc_min: float,
    crop_radius: float | None,
    data: str | None,
    allow_outside: bool,
) -> str:
    """Write the run ``opened`` as a coloured point cloud to ``path``: every ``every``-th
    training view rendered, every ``stride``-th pixel with opacity above ``acc_min`` placed at
    its depth; points farther than ``crop_radius`` from the scene's centre along an axis
    dropped (None: kept)."""
    from ...errors import fail
    from ...export import crop_to_box, points_from_views, write_points_ply
    from ...output.images import render_image
    from .._common import scene_for_run

    scene = scene_for_run(opened.info, data, allow_outside=allow_outside)
    views = scene.train.subset(list(range(0, len(scene.train), every)))
    bg = opened.background()

    def render_fn(K, c2w, w, h):
        out = render_image(opened.model, K, c2w, w, h, bg, opened.chunk, opened.autocast)
        return out.rgb, out.depth, out.acc

    pts, cols = points_from_views(render_fn, views, acc_min, tuple(bg.tolist()), stride)
    n_all = len(pts)
    if n_all == 0:
        raise fail(
            opened.info.run_dir,
            f"at step {opened.step} no pixel of the {len(views)} views rendered is more than {acc_min:g} opaque: "
            "the run holds no surface yet",
            f"Lower --acc-min, or {train_longer(opened)}",
        )
    if crop_radius is not None:
        pts, cols = crop_to_box(pts, cols, opened.info.bounds.center, crop_radius)
        if len(pts) == 0:
            raise fail(
                opened.info.run_dir, f"all {n_all} points lie outside the scene's box", "Pass --no-crop to keep them"
            )
    write_points_ply(path, pts, cols)
    return (
        f"point cloud of step {opened.step}: {len(pts)} points from {len(views)} views "
        f"({n_all - len(pts)} outside the scene box dropped) -> {path}"
    )
