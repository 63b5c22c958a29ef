"""How well a mesh matches the NeRF's silhouette and the photos' colours.

For a trained run, the mesh is extracted once (``nerfkit export``'s defaults: 256^3 grid
over a cube around the model's grid, the scale-free threshold of ``export`` unless
``--threshold`` is given, a capture's table paint cleared up to 5% of the object's height;
``--region scene`` meshes the scene's cube instead, as ``export`` did before session 29).

Its silhouette (every triangle in front of the camera filled) is compared in each
validation view with where the NeRF's object (alone, for a capture) is more than half
opaque: the intersection over the union of the two. Holes in the mesh (a threshold too
high) and a shell of haze around it (too low) both lower it.

The mesh is coloured two ways:

* ``at vertex``: the field's colour at the vertex (the iso-surface), seen along the normal;
* ``ray seen``:  what a ray looking at the vertex along the inward normal sees (the field
                 volume-rendered from ``reach`` outside the surface to twice as far
                 inside: ``export``'s way, with ``reach`` 2% of the scene's radius;
                 ``--reach F ...`` scores other fractions too).

Each vertex is projected into the run's validation views; where it is visible (its
distance from the camera within 1% of the scene radius of the rendered depth, on a pixel
with opacity above 0.9), its colour is compared with the photo's pixel. Prints PSNR over
those (vertex, view) pairs and the seconds each colouring took::

    python benchmarks/mesh_colours.py runs/demo
    python benchmarks/mesh_colours.py /tmp/cr/steve/run_auto --views 6
    python benchmarks/mesh_colours.py /tmp/cr/steve/run_auto --views 6 --region scene --table-cut -1
    python benchmarks/mesh_colours.py runs/demo --threshold 25     # a fixed level instead
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def visible_pairs(vertices: np.ndarray, view, K: np.ndarray, c2w: np.ndarray, tol: float):
    """(indices of the vertices visible in this view, their pixels (cols, rows))."""
    w2c = np.linalg.inv(c2w)
    X = vertices @ w2c[:3, :3].T + w2c[:3, 3]  # OpenCV camera: looks along +z
    z = np.maximum(X[:, 2], 1e-9)
    cols = np.floor(K[0, 0] * X[:, 0] / z + K[0, 2]).astype(int)
    rows = np.floor(K[1, 1] * X[:, 1] / z + K[1, 2]).astype(int)
    h, w = view.depth.shape
    idx = np.where((X[:, 2] > 1e-6) & (cols >= 0) & (cols < w) & (rows >= 0) & (rows < h))[0]
    dist = np.linalg.norm(vertices[idx] - c2w[:3, 3], axis=1)
    keep = (np.abs(dist - view.depth[rows[idx], cols[idx]]) < tol) & (view.acc[rows[idx], cols[idx]] > 0.9)
    return idx[keep], cols[idx[keep]], rows[idx[keep]]


def silhouette(vertices: np.ndarray, faces: np.ndarray, K: np.ndarray, c2w: np.ndarray, width: int,
               height: int) -> np.ndarray:
    """(H, W) bool: the pixels whose centres the mesh's triangles in front of the camera cover."""
    import cv2

    w2c = np.linalg.inv(c2w)
    X = vertices @ w2c[:3, :3].T + w2c[:3, 3]
    front = (X[faces][:, :, 2] > 1e-6).all(1)
    uv = np.stack([K[0, 0] * X[:, 0] / X[:, 2] + K[0, 2], K[1, 1] * X[:, 1] / X[:, 2] + K[1, 2]], 1)
    tris = np.round((uv[faces[front]] - 0.5) * 16).astype(np.int32)  # pixel centres at +0.5; 4 bits of subpixel
    mask = np.zeros((height, width), np.uint8)
    for tri in tris:
        cv2.fillConvexPoly(mask, tri, 1, lineType=cv2.LINE_8, shift=4)
    return mask.astype(bool)


def main() -> None:
    from nerfkit.tabletop import TABLE_CUT

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", help="a trained run folder (fast or vanilla)")
    ap.add_argument("--views", type=int, default=10, help="validation views to score against (default: 10)")
    ap.add_argument("--resolution", type=int, default=256)
    ap.add_argument("--threshold", type=float, default=None, help="the surface's density (default: export's)")
    ap.add_argument("--region", choices=["model", "scene"], default="model",
                    help="mesh the cube around the model's grid (export's way) or the scene's cube")
    ap.add_argument("--table-cut", type=float, default=TABLE_CUT,
                    help="export's --table-cut; negative: leave a capture's table paint and what is under the table")
    ap.add_argument("--reach", type=float, nargs="+", default=[],
                    help="more colour ray reaches to score, as fractions of the scene's radius")
    args = ap.parse_args()

    import torch

    from nerfkit.commands._common import open_run, scene_for_run
    from nerfkit.export import COLOUR_REACH, extract_mesh, mesh_region, mesh_threshold, vertex_colors
    from nerfkit.tabletop import object_alone, table_cut_height
    from nerfkit.output.images import render_image

    run = open_run(argparse.Namespace(run=args.run, device="cpu", chunk=0))
    model, bounds = run.model, run.info.bounds
    center, radius = bounds.center, bounds.radius
    if args.region == "model":
        center, radius = mesh_region(model, center, radius)
    table = model.table_plane() if args.table_cut >= 0 else None
    cut = table_cut_height(model, args.table_cut) if table is not None else 0.0
    threshold = args.threshold if args.threshold is not None else mesh_threshold(model, radius)
    mesh = extract_mesh(model.density, center, radius, args.resolution, threshold, table=table, table_cut=cut,
                        tags=model.table_tags())
    reaches = [("at vertex", 0.0), ("ray seen", COLOUR_REACH)] + [(f"reach {f:g}", f) for f in args.reach]
    colourings = {}
    with torch.no_grad():
        for name, fraction in reaches:
            reach = fraction * bounds.radius
            t0 = time.perf_counter()
            colourings[name] = vertex_colors(model.density, model.query, mesh.vertices, mesh.normals, reach)
            colourings[name] = (colourings[name], time.perf_counter() - t0)
    views = scene_for_run(run.info, None, need="val").splits["val"]
    errors = {name: [] for name in colourings}
    alone = object_alone(model).model
    inter = union = 0
    for i in range(min(args.views, len(views))):
        view = render_image(model, views.K[i], views.c2w[i], views.width, views.height, run.background(), 65536,
                            run.autocast)
        solid = render_image(alone, views.K[i], views.c2w[i], views.width, views.height, run.background(), 65536,
                             run.autocast).acc > 0.5
        covered = silhouette(mesh.vertices.astype(np.float64), mesh.faces, views.K[i], views.c2w[i], views.width,
                             views.height)
        inter, union = inter + int((solid & covered).sum()), union + int((solid | covered).sum())
        idx, cols, rows = visible_pairs(mesh.vertices.astype(np.float64), view, views.K[i], views.c2w[i],
                                        0.01 * bounds.radius)
        photo = views.images[i][rows, cols] / 255.0
        for name, (colours, _) in colourings.items():
            errors[name].append(((colours[idx] / 255.0 - photo) ** 2).mean(1))
    cleared = f", table paint cleared up to {cut:.3g}" if table is not None else ""
    print(f"{args.run}: {len(mesh.vertices)} vertices, {len(mesh.faces)} faces at threshold {threshold:.3g} "
          f"({args.region}'s cube, {2 * radius:.3g} wide{cleared}); silhouette IoU with the NeRF's "
          f"{inter / max(union, 1):.3f}")
    print(f"{'vertex colour':<14} {'pairs':>7} {'PSNR':>6} {'seconds':>8}")
    for name, (colours, seconds) in colourings.items():
        e = np.concatenate(errors[name])
        print(f"{name:<14} {len(e):>7} {-10 * np.log10(e.mean()):>6.2f} {seconds:>8.2f}")


if __name__ == "__main__":
    main()
