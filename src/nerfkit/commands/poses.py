"""`nerfkit poses`: a camera pose per object photo, from the ArUco tag beside the object or from SfM."""

from __future__ import annotations

import argparse
from typing import get_args

from .pipeline import Matcher, PoseMethod

MEMORY_HINT = "Lower --max-side, --detect-size or --jobs"
HELP = "pose photos of an object beside an ArUco tag and build a NeRF dataset"

DESCRIPTION = """\
Give every photo a camera-to-world pose from the tag it shows (solvePnP: IPPE_SQUARE for
one tag, or all tags of a layout jointly: --layout, else the camera file's when the
photos' tags sit as it says (at --tag-size when the photos show only its tags), else, when
most photos show several tags, one estimated from the photos themselves), with the
camera's focal length fitted to the photos' tags when they pin it (--no-refine-focal
keeps it), skip photos with no tag or a bad fit (with the reason), then build the
dataset (as `nerfkit dataset` does): undistort, crop, resize, split into train/val/test,
estimate near/far, and write dataset.npz, transforms.json, the images and coverage.png
(where the photos look from, and the widest gap among them) into DATASET_DIR, plus
poses.json with every photo's outcome. It also says how well the training photos agree on
the table around the object (a rough ceiling for held-out scores).

With --method auto (the default) the photos are then also posed by structure-from-motion
(pycolmap), starting from the camera of --camera (bundle adjustment refines its focal
length and radial distortion on these photos), and put in the tag's (or the layout's)
frame: features across all photos pin a pose far better than one small tag (held-out
views score higher: see BENCHMARKS.md), and photos where no tag was found get poses
too. The dataset takes the SfM poses unless SfM registers fewer than 90% of the photos
the tags posed, misses the tag, or disagrees with the tags; the output says which and why
(--method tags, or --no-dataset: tag poses only, as the course does).

The report compares the focal length of --camera with the one the photos want (their
tags', or SfM's), and warns when the two are more than 6% apart: the camera file is then
likely of another phone, lens, zoom, orientation or resolution than the photos.

World frame: the tag's (a layout's own; an estimated layout's most-seen tag's). Origin at
the tag centre, x to the right and y up along the printed tag, z out of the tag toward the
cameras; the scene's up is +z. Units: metres.

Without --camera the EXIF focal length of the photos is used (no lens distortion).

With --method colmap, poses come from structure-from-motion (pycolmap) alone; a tag
seen in the photos (give --tag-size) fixes the metric scale and up, otherwise the scene is
centred and scaled to a mean camera distance of 4 and the report says so. Without a tag
the table the object stands on is found in the SfM points (a plane facing up, under the
point the cameras look at) and becomes z = 0, so training treats it as the tag's plane
(--no-ground: keep the cameras' up and no table).

examples:
  nerfkit poses object_photos/ --camera camera.json --tag-size 0.06 --out my_object/
  nerfkit poses object_photos/ --method colmap --out my_object/
  nerfkit train --data my_object/dataset.npz --minutes 3     (capture settings are automatic)
"""


def register(sub: argparse._SubParsersAction) -> None:
    from ..capture.dataset import DatasetConfig
    from ..capture.poses import PoseConfig
    from ..config import add_dataclass_args, tag_side
    from .options import PosesOptions

    p = sub.add_parser(
        "poses", help=HELP, description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("photos", metavar="OBJECT_DIR", help="folder of photos of the object beside the tag")
    p.add_argument(
        "--method",
        choices=get_args(PoseMethod),
        default="auto",
        help="auto (default): tag poses, replaced by structure-from-motion poses in the tag's frame when "
        "SfM registers the photos and agrees with the tags; tags: poses from the ArUco tag only; "
        "colmap: structure-from-motion with pycolmap, for photos without tags (a tag, with "
        "--tag-size, then fixes scale and up)",
    )
    p.add_argument(
        "--matcher",
        choices=get_args(Matcher),
        default="auto",
        help="the photo pairs SfM matches: exhaustive (every pair), sequential (each photo with the next "
        "10 in name order) or spatial (--method auto: sequential's, and each photo with the 20 whose "
        "tag poses see most alike; faster than exhaustive, a little less exact). auto (default): "
        "exhaustive up to 100 photos; beyond, spatial when the tags pose half of them, else sequential",
    )
    p.add_argument(
        "--no-ground",
        action="store_true",
        help="with --method colmap and no tag: do not look for the table plane in the SfM points",
    )
    p.add_argument("--camera", help="camera file from `nerfkit calibrate` (default: the photos' EXIF focal length)")
    p.add_argument("--tag-size", type=tag_side, help="side of the tag's black square in metres, e.g. 0.06")
    p.add_argument(
        "--layout",
        help="layout JSON of several tags to use jointly (their frame is the world); by "
        "default the camera file's layout (e.g. the one calibrate estimated) is used when the photos "
        "show several of its tags and they sit as it says (scaled to --tag-size when the photos show "
        "only its tags), else, when they show several tags, one estimated from them",
    )
    p.add_argument(
        "--single-tag",
        action="store_true",
        help="pose from one tag: never use the camera file's layout or one estimated from the photos",
    )
    p.add_argument("--dict", help="ArUco dictionary (default: the camera file's, else DICT_4X4_50)")
    p.add_argument("--out", required=True, metavar="DATASET_DIR", help="dataset folder to write")
    p.add_argument(
        "--no-dataset", action="store_true", help="only write poses.json (build later with `nerfkit dataset`)"
    )
    add_dataclass_args(p, PosesOptions)  # --focal-px, --tag-id, --sfm-max-size, --detect-size, --jobs
    p.add_argument("--no-cache", action="store_true", help="ignore cached detections")
    p.add_argument("--all-photos", action="store_true", help="list every photo in the summary, not only skipped ones")
    p.add_argument("--force", action="store_true", help="replace the dataset files of an earlier run in --out")
    add_dataclass_args(p, PoseConfig, "poses")
    add_dataclass_args(p, DatasetConfig, "dataset")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """``nerfkit poses``: :func:`nerfkit.api.pose` with the parsed flags (unset options: the defaults
    of :class:`~nerfkit.commands.options.PosesOptions`)."""
    import dataclasses

    from ..capture.dataset import DatasetConfig
    from ..capture.poses import PoseConfig
    from ..config import dataclass_from_args
    from .options import PosesOptions
    from .pipeline import pose

    pose(
        args.photos,
        args.out,
        tag_size=args.tag_size,
        camera=args.camera,
        method=args.method,
        matcher=args.matcher,
        ground=not args.no_ground,
        layout=args.layout,
        single_tag=args.single_tag,
        dictionary=args.dict,
        build_dataset=not args.no_dataset,
        **dataclasses.asdict(dataclass_from_args(PosesOptions, args)),
        cache=not args.no_cache,
        pose_settings=dataclass_from_args(PoseConfig, args),
        dataset_settings=dataclass_from_args(DatasetConfig, args),
        all_photos=args.all_photos,
        force=args.force,
    )
    return 0
