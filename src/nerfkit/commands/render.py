"""`nerfkit render`: orbit video, GIF and depth video of a trained run."""

from __future__ import annotations

import argparse

from ._common import add_run_args

HELP = "render a trained run to MP4/GIF and a depth video"
MEMORY_HINT = "Lower --chunk (rays rendered at once)"


def register(sub: argparse._SubParsersAction) -> None:
    from ..config import number

    p = sub.add_parser(
        "render",
        help=HELP,
        description=HELP + ". Uses the dataset's test poses when they are "
        "a camera path (as in the course's lego file), else LLFF's spiral for a forward-facing "
        "capture, else an orbit around the object.",
    )
    add_run_args(p)
    p.add_argument(
        "--path",
        choices=["auto", "test", "orbit", "spiral"],
        default="auto",
        help="camera path: the dataset's test poses, an orbit around the object, a spiral across a "
        "forward-facing capture's view, or auto (chosen as described above)",
    )
    p.add_argument(
        "--frames",
        type=number(int, 1, 100_000),
        default=None,
        help="frames of a generated orbit or spiral (default: 120, 4 s at 30 fps); the test path "
        "has the dataset's own poses",
    )
    p.add_argument("--fps", type=number(int, 1, 1000), default=30, help="frames per second (default: 30)")
    p.add_argument(
        "--object",
        action="store_true",
        help="render the object alone into object.mp4, object.gif and object_depth.mp4: a capture's "
        "table, floor and room left out, the table's paint and the specks apart from the object "
        "cleared from the density (as export --mesh does), on white, zoomed and centred to fill the frame",
    )
    p.add_argument(
        "--background",
        help="override the run's background colour (with --object: white): black, "
        "white, grey, r,g,b in [0, 1] or #rrggbb",
    )
    p.add_argument("--out", help="output folder (default: RUN/videos)")
    p.add_argument(
        "--force",
        action="store_true",
        help="replace videos already in --out (without --out, RUN/videos is replaced: it belongs to the run)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import sys
    from pathlib import Path

    from ..data.load import dataset_inputs
    from ..data.scene import ORBIT_FRAMES
    from ..errors import fail
    from ..io.paths import guard_outputs
    from ..output.images import frame_object, object_aim
    from ..output.videos import OBJECT_VIDEO_FILES, VIDEO_FILES, render_videos
    from ..surroundings import object_alone, table_tags
    from ..tabletop import cleared_note
    from ..train.checkpoint import read_run
    from ._common import open_run, scene_for_run

    out = Path(args.out) if args.out else Path(args.run) / "videos"
    dataset = args.data or read_run(args.run).train.data
    names = OBJECT_VIDEO_FILES if args.object else VIDEO_FILES
    guard_outputs([out / name for name in names], dataset_inputs(dataset), args.force or not args.out)
    run_ = open_run(args)
    scene = scene_for_run(run_.info, args.data, allow_outside=args.allow_outside_paths)
    kind = scene.video_kind(args.path)
    if kind == "test" and len(scene.test) == 0:
        raise fail(scene.source, "has no test poses", "Use --path orbit")
    if kind == "test" and args.frames and args.frames != len(scene.test):
        print(
            f"note: --frames sets the length of an orbit or spiral; the test path is the dataset's "
            f"{len(scene.test)} poses (--path orbit for {args.frames} frames)",
            file=sys.stderr,
        )
    if kind == "spiral" and not scene.forward_facing:
        raise fail(
            "--path spiral",
            "the training cameras do not all look the same way from about the same "
            "place, so a spiral across their view would leave them",
            "Use --path orbit",
        )
    if args.object and (kind == "spiral" or getattr(run_.model, "ndc", None) is not None):
        raise fail(
            "--object",
            "a forward-facing scene, seen from one side and held in one volume out to "
            "infinity, has no object standing apart to frame",
            "Render it without --object",
        )
    background = run_.background(args.background or ("white" if args.object else None))
    alone = ""
    if args.object:  # (in place: this model is only rendered)
        tags = table_tags(run_.model)
        isolated = object_alone(run_.model, copy=False)
        if not isolated.left_out:
            alone = "the object (the model draws nothing around it to leave out"
        else:
            alone = f"the object alone ({_listed(isolated.left_out)} left out"
            if isolated.cut > 0:
                alone += f"; {cleared_note(isolated.cut, tags)}"
    # an orbit looks at the trained object, not at the point the cameras' axes meet
    aim = (
        object_aim(run_.model, scene.train, scene.up, background, run_.chunk, run_.autocast)
        if kind == "orbit"
        else None
    )
    views = scene.render_path(args.frames or ORBIT_FRAMES, aim, kind)
    near, far = scene.near, scene.far
    if args.object:
        looked_at = aim if aim is not None else scene.center  # (what the path's cameras look at)
        framing = frame_object(run_.model, views, background, run_.chunk, run_.autocast, aim=looked_at)
        if framing is None:
            raise fail(
                args.run,
                "renders nothing solid along the video's path, so there is no object to frame",
                "Render the scene without --object, or train longer",
            )
        views, near, far = framing.views, framing.near, framing.far
        alone += f"; zoomed {framing.zoom:.2f}x)"
    paths = render_videos(
        run_.model,
        views,
        out,
        background,
        near,
        far,
        args.fps,
        run_.chunk,
        run_.autocast,
        names=names,
        metres=scene.tags is not None,
    )
    what = f" of {alone}" if alone else ""
    print(f"rendered {len(views)} frames{what} at step {run_.step} ({paths.seconds_per_frame:.2f} s/frame):")
    for p in (paths.rgb_mp4, paths.rgb_gif, paths.depth_mp4):
        print(f"  {p}")
    return 0


def _listed(names: list[str]) -> str:
    """``a``, ``a and b``, ``a, b and c``."""
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]
