"""`nerfkit view`: look at a dataset's cameras, rays and samples (browser or PNG)."""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = (
    "view a dataset's cameras, rays and samples, or a trained run live, in the browser (viser); or a dataset as a PNG"
)

DESCRIPTION = """\
Shows each camera as a frustum textured with its image, the world axes, the tag plane and
the scene centre; --rays N adds N random training rays with their samples between near
and far (as training samples them); --rays-from V draws them from training view V only
(100 of them unless --rays says). DATASET is anything `nerfkit train --data` reads.
The server listens on 127.0.0.1 only, unless you pass --host explicitly.
A run folder (from `nerfkit train`) opens the live viewer of the trained model instead:
the NeRF rendered from the browser's camera, in colour or depth, the whole scene or (the
"Object alone" switch) a capture's object without its table and room.

examples:
  nerfkit view my_object/ --rays 50              then open http://127.0.0.1:8080
  nerfkit view my_object/dataset.npz --rays 30 --png cameras.png
  nerfkit view lego.npz --rays-from 0 --png rays.png   (the course's rays of one camera)
"""


def register(sub: argparse._SubParsersAction) -> None:
    from ..config import MIN_DOWNSCALE, number
    from ._common import add_outside_flag

    p = sub.add_parser("view", help=HELP, description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("path", metavar="DATASET", help="dataset file or folder (or a run folder)")
    p.add_argument(
        "--rays",
        type=number(int, 0, 100_000),
        help="training rays to draw with their samples (default: none; 100 with --rays-from)",
    )
    p.add_argument(
        "--samples", type=number(int, 1, 4096), default=64, help="samples per drawn ray (default: 64, as the course)"
    )
    p.add_argument(
        "--rays-from",
        type=number(int, 0),
        metavar="N",
        help="draw the rays of training view N only (the "
        "course's check that u and v are not swapped: they fill that camera's frustum)",
    )
    p.add_argument("--png", metavar="FILE", help="write a static PNG (matplotlib) instead of serving, then exit")
    p.add_argument(
        "--host",
        default="127.0.0.1",
        help="address to listen on (default: 127.0.0.1, this machine only; 0.0.0.0 exposes the viewer to the network)",
    )
    p.add_argument("--port", type=number(int, 1, 65535), default=8080, help="port (default: 8080)")
    p.add_argument("--force", action="store_true", help="replace an existing --png file")
    p.add_argument(
        "--downscale",
        type=number(float, MIN_DOWNSCALE),
        help="divide the dataset's image size by this (an LLFF scene's 4 or 8 reads its images_4 or images_8)",
    )
    add_outside_flag(p)
    p.set_defaults(func=run)


def dataset_tag_size(path: Path) -> float | None:
    """The tag size a capture dataset records (transforms.json beside it), if any."""
    from ..data.nerfstudio import nerfkit_block

    v = (nerfkit_block(path if path.is_dir() else path.parent) or {}).get("tag_size")
    return float(v) if isinstance(v, (int, float)) and v > 0 else None


def run(args: argparse.Namespace) -> int:
    from ..data.load import is_run_folder
    from ..errors import fail

    path = Path(args.path)
    if args.png is not None:  # (an empty name is refused with every output path: nerfkit.cli)
        png = Path(args.png)
        if png.is_dir():
            raise fail("--png", f"{png} is a folder", f"Name a PNG file, e.g. {png / 'scene.png'}")
        if png.suffix.lower() != ".png":
            raise fail("--png", f"'{png}' should end in .png (the picture is a PNG)")
    if is_run_folder(path):
        if args.downscale:
            raise fail("--downscale", "a trained run loads its dataset as it was trained", "Leave out --downscale")
        if args.rays or args.rays_from is not None:
            raise fail(
                "--rays" if args.rays else "--rays-from",
                "the live viewer of a trained run draws its cameras and renders, not rays",
                "View the run's dataset for its rays: nerfkit view DATASET --rays N",
            )
        if args.png:
            raise fail(path, "--png draws datasets; this is a trained run", "Pass the run's dataset instead")
        try:
            from .live import serve_run
        except ImportError:
            raise fail(
                path,
                "is a trained run, but the live viewer (nerfkit.commands.live) is not available in this build",
                "View its dataset instead: nerfkit view DATASET",
            ) from None
        serve_run(path, host=args.host, port=args.port)
        return 0

    from ..data.load import dataset_inputs, load_scene

    if args.png:
        from ..io.paths import guard_outputs

        guard_outputs([args.png], dataset_inputs(path), args.force, "--png")
    scene = load_scene(path, downscale=args.downscale, allow_outside=args.allow_outside_paths)
    tag_size = dataset_tag_size(path)
    if args.rays_from is not None and args.rays_from >= len(scene.train):
        raise fail(
            "--rays-from",
            f"the dataset has {len(scene.train)} training views (0 to {len(scene.train) - 1}), "
            f"not a view {args.rays_from}",
            "Give a training view's number",
        )
    n_rays = args.rays if args.rays is not None else 100 if args.rays_from is not None else 0  # the course: 100
    if args.png:
        from ..viz.scene_plot import plot_scene

        plot_scene(scene, args.png, n_rays=n_rays, n_samples=args.samples, tag_size=tag_size, rays_from=args.rays_from)
        print(f"wrote {args.png}")
        return 0
    from ..viz.viewer import serve_dataset, viewer_url, wait_until_interrupted

    if args.host not in ("127.0.0.1", "localhost", "::1"):
        print(f"warning: listening on {args.host}: anyone who can reach this machine can see the dataset")
    server, _ = serve_dataset(
        scene,
        host=args.host,
        port=args.port,
        n_rays=n_rays,
        n_samples=args.samples,
        tag_size=tag_size,
        block=False,
        rays_from=args.rays_from,
    )
    print(
        f"{len(scene.train)} train, {len(scene.val)} val, {len(scene.test)} test cameras; near {scene.near:.4g}, "
        f"far {scene.far:.4g}"
    )
    print(f"viewer at {viewer_url(args.host, server.get_port())} (Ctrl-C to stop)")
    wait_until_interrupted(server)
    return 0
