"""How well a mesh matches the NeRF's silhouette and the photos' colours.

For a trained run, the mesh is extracted once (``nerfkit export``'s defaults: 256^3 grid
over a cube around the model's grid, the scale-free threshold of ``export`` unless
``--threshold`` is given, a capture's table paint cleared up to 5% of the object's height;
``--region scene`` meshes the scene's cube instead, as ``export`` once did).

Its silhouette (every triangle in front of the camera filled) is compared in each
validation view with where the NeRF's object (alone, for a capture) is more than half
opaque: the intersection over the union of the two. Holes in the mesh (a threshold too
high) and a shell of haze around it (too low) both lower it.

The mesh is coloured three ways:

* ``at vertex``:    the field's colour at the vertex (the iso-surface), seen along the normal;
* ``along normal``: what a ray looking at the vertex along the inward normal sees (the field
                    volume-rendered from ``reach`` outside the surface to twice as far
                    inside, ``reach`` 2% of the scene's radius; ``--reach F ...`` scores
                    other fractions too): ``export --color-views 0``;
* ``N views``:      the mean of the NeRF's renders (its object alone) at N training views
                    that see the vertex, along the normal where none does: ``export``'s
                    way, N = 32 (``--color-views N ...`` scores others).

Two scores against the run's validation photos:

* ``pairs``: each vertex is projected into the views; where it is visible (its distance from
  the camera within 1% of the scene radius of the rendered depth, on a pixel with opacity
  above 0.9), its colour is compared with the photo's pixel: PSNR over those (vertex,
  view) pairs;
* ``drawn``: the mesh is drawn (each triangle filled with its vertices' mean colour, far to
  near) and compared with the photo where it covers the NeRF's object more than 90% opaque,
  PSNR per view, averaged; the NeRF's own render on the same pixels is printed beside.

And the seconds each colouring took::

    python benchmarks/mesh_colours.py runs/demo
    python benchmarks/mesh_colours.py CAPTURES/steve/run --views 6     # a capture_real.py run
    python benchmarks/mesh_colours.py CAPTURES/steve/run --views 6 --region scene --table-cut -1
    python benchmarks/mesh_colours.py runs/demo --threshold 25     # a fixed level instead
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def visible_pairs(vertices: np.ndarray, view, K: np.ndarray, c2w: np.ndarray, tol: float):
    """(indices of the vertices visible in this view, their pixels (cols, rows))."""
    from nerfkit.cameras import project_points

    uv, z = project_points(K, c2w, vertices)
    cols, rows = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
    h, w = view.depth.shape
    idx = np.where((z > 1e-6) & (cols >= 0) & (cols < w) & (rows >= 0) & (rows < h))[0]
    dist = np.linalg.norm(vertices[idx] - c2w[:3, 3], axis=1)
    keep = (np.abs(dist - view.depth[rows[idx], cols[idx]]) < tol) & (view.acc[rows[idx], cols[idx]] > 0.9)
    return idx[keep], cols[idx[keep]], rows[idx[keep]]


def draw(
    vertices: np.ndarray, faces: np.ndarray, colours: dict, K: np.ndarray, c2w: np.ndarray, width: int, height: int
) -> tuple[dict, np.ndarray]:
    """The mesh drawn in one view, each triangle in front of the camera filled with the mean
    of its vertices' colours, far to near (painter's algorithm; triangles of a 256^3 mesh
    are about a pixel): ``({name: (H, W, 3) uint8 image}, (H, W) bool covered)`` for each
    colouring of ``colours`` (name -> (V, 3) uint8)."""
    import cv2

    from nerfkit.cameras import project_points

    uv, z = project_points(K, c2w, vertices)
    front = np.nonzero((z[faces] > 1e-6).all(1))[0]
    front = front[np.argsort(-z[faces[front]].mean(1))]
    tris = np.round((uv[faces[front]] - 0.5) * 16).astype(np.int32)  # pixel centres at +0.5; 4 bits of subpixel
    mask = np.zeros((height, width), np.uint8)
    images = {}
    for name, c in colours.items():
        face_colours = c[faces[front]].astype(np.float64).mean(1).round().astype(int).tolist()
        img = np.zeros((height, width, 3), np.uint8)
        for tri, colour in zip(tris, face_colours):
            cv2.fillConvexPoly(img, tri, colour, lineType=cv2.LINE_8, shift=4)
        images[name] = img
    for tri in tris:
        cv2.fillConvexPoly(mask, tri, 1, lineType=cv2.LINE_8, shift=4)
    return images, mask.astype(bool)


def psnr(squared_errors: np.ndarray) -> float:
    return float(-10 * np.log10(max(squared_errors.mean(), 1e-10)))


def main() -> None:
    from nerfkit.commands.options import ExportOptions

    export_defaults = ExportOptions()

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", help="a trained run folder (fast or vanilla)")
    ap.add_argument("--views", type=int, default=10, help="validation views to score against (default: 10)")
    ap.add_argument("--resolution", type=int, default=256)
    ap.add_argument("--threshold", type=float, default=None, help="the surface's density (default: export's)")
    ap.add_argument(
        "--region",
        choices=["model", "scene"],
        default="model",
        help="mesh the cube around the model's grid (export's way) or the scene's cube",
    )
    ap.add_argument(
        "--table-cut",
        type=float,
        default=export_defaults.table_cut,
        help="export's --table-cut; negative: leave a capture's table paint and what is under the table",
    )
    ap.add_argument(
        "--reach",
        type=float,
        nargs="+",
        default=[],
        help="more colour ray reaches to score, as fractions of the scene's radius",
    )
    ap.add_argument(
        "--color-views",
        type=int,
        nargs="+",
        default=[export_defaults.color_views],
        help=f"training views to colour from (default: export's {export_defaults.color_views}; "
        "several: one colouring each)",
    )
    args = ap.parse_args()

    import torch

    from nerfkit.commands._common import open_run, scene_for_run
    from nerfkit.export import (
        COLOUR_REACH,
        COLOUR_VIEW_TOL,
        ColourViews,
        extract_mesh,
        mesh_region,
        mesh_threshold,
        vertex_colors,
        view_colors,
    )
    from nerfkit.output.images import render_image
    from nerfkit.surroundings import object_alone, table_cut_height, table_plane, table_tags

    run = open_run(argparse.Namespace(run=args.run, device="cpu", chunk=0))
    model, bounds = run.model, run.info.bounds
    center, radius = bounds.center, bounds.radius
    if args.region == "model":
        center, radius = mesh_region(model, center, radius)
    table = table_plane(model) if args.table_cut >= 0 else None
    cut = table_cut_height(model, args.table_cut) if table is not None else 0.0
    threshold = args.threshold if args.threshold is not None else mesh_threshold(model, radius)
    mesh = extract_mesh(
        model.density, center, radius, args.resolution, threshold, table=table, table_cut=cut, tags=table_tags(model)
    )
    scene = scene_for_run(run.info, None, need="val")
    alone = object_alone(model).model
    bg = run.background()

    def render(m, K, c2w, w, h):
        return render_image(m, K, c2w, w, h, bg, 65536, run.autocast)

    def render_alone(K, c2w, w, h):
        out = render(alone, K, c2w, w, h)
        return out.rgb, out.depth, out.acc

    reaches = [("at vertex", 0.0), ("along normal", COLOUR_REACH)] + [(f"reach {f:g}", f) for f in args.reach]
    colourings = {}
    with torch.no_grad():
        for name, fraction in reaches:
            t0 = time.perf_counter()
            colours = vertex_colors(model.density, model.query, mesh.vertices, mesh.normals, fraction * bounds.radius)
            colourings[name] = (colours, time.perf_counter() - t0)
        for n in args.color_views:
            t0 = time.perf_counter()
            colours, seen = view_colors(
                render_alone,
                ColourViews.pick(scene.train, n),
                mesh.vertices,
                mesh.normals,
                COLOUR_VIEW_TOL * bounds.radius,
                tuple(bg.tolist()),
            )
            colours[~seen] = colourings["along normal"][0][~seen]
            colourings[f"{n} views"] = (colours, time.perf_counter() - t0 + colourings["along normal"][1])
            print(f"{n} views: {seen.mean():.1%} of the vertices seen")
    views = scene.splits["val"]
    pair_errors = {name: [] for name in colourings}
    drawn_errors = {name: [] for name in colourings}
    nerf_errors = []
    vertices = mesh.vertices.astype(np.float64)
    inter = union = 0
    for i in range(min(args.views, len(views))):
        K, c2w, w, h = views.K[i], views.c2w[i], views.width, views.height
        with torch.no_grad():
            view, obj = render(model, K, c2w, w, h), render(alone, K, c2w, w, h)
        images, covered = draw(vertices, mesh.faces, {k: c for k, (c, _) in colourings.items()}, K, c2w, w, h)
        solid = obj.acc > 0.5
        inter, union = inter + int((solid & covered).sum()), union + int((solid | covered).sum())
        photo = views.images[i] / 255.0
        idx, cols, rows = visible_pairs(vertices, view, K, c2w, 0.01 * bounds.radius)
        both = covered & (obj.acc > 0.9)
        nerf_errors.append(psnr((view.rgb[both] - photo[both]) ** 2))
        for name, (colours, _) in colourings.items():
            pair_errors[name].append(((colours[idx] / 255.0 - photo[rows, cols]) ** 2).mean(1))
            drawn_errors[name].append(psnr((images[name][both] / 255.0 - photo[both]) ** 2))
    cleared = f", table paint cleared up to {cut:.3g}" if table is not None else ""
    print(
        f"{args.run}: {len(mesh.vertices)} vertices, {len(mesh.faces)} faces at threshold {threshold:.3g} "
        f"({args.region}'s cube, {2 * radius:.3g} wide{cleared}); silhouette IoU with the NeRF's "
        f"{inter / max(union, 1):.3f}"
    )
    print(
        f"drawn: PSNR against the photo where the mesh covers the NeRF's solid object, mean over "
        f"{len(nerf_errors)} views; the NeRF's own render there: {np.mean(nerf_errors):.2f}"
    )
    print(f"{'vertex colour':<14} {'pairs':>7} {'PSNR':>6} {'drawn':>6} {'seconds':>8}")
    for name, (_colours, seconds) in colourings.items():
        e = np.concatenate(pair_errors[name])
        print(
            f"{name:<14} {len(e):>7} {-10 * np.log10(e.mean()):>6.2f} {np.mean(drawn_errors[name]):>6.2f} "
            f"{seconds:>8.2f}"
        )


if __name__ == "__main__":
    main()
