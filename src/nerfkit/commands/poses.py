"""`nerfkit poses`: a camera pose per object photo, from the ArUco tag beside the object or from SfM."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, cast

if TYPE_CHECKING:
    from ..capture.aruco import Layout
    from ..sfm.colmap import SfmResult

MEMORY_HINT = "Lower --max-side, --detect-size or --jobs"
HELP = "pose photos of an object beside an ArUco tag and build a NeRF dataset"

DESCRIPTION = """\
Give every photo a camera-to-world pose from the tag it shows (solvePnP: IPPE_SQUARE for
one tag, or all tags of a layout jointly: --layout, else the camera file's, else, when
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
    from ..config import add_dataclass_args, number, tag_side

    p = sub.add_parser(
        "poses", help=HELP, description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("photos", metavar="OBJECT_DIR", help="folder of photos of the object beside the tag")
    p.add_argument(
        "--method",
        choices=["auto", "tags", "colmap"],
        default="auto",
        help="auto (default): tag poses, replaced by structure-from-motion poses in the tag's frame when "
        "SfM registers the photos and agrees with the tags; tags: poses from the ArUco tag only; "
        "colmap: structure-from-motion with pycolmap, for photos without tags (a tag, with "
        "--tag-size, then fixes scale and up)",
    )
    p.add_argument(
        "--matcher",
        choices=["auto", "exhaustive", "sequential", "spatial"],
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
    p.add_argument(
        "--sfm-max-size",
        type=number(int, 64, 100_000),
        default=1000,
        help="longest side used for SfM features, px (default 1000)",
    )
    p.add_argument("--camera", help="camera file from `nerfkit calibrate` (default: the photos' EXIF focal length)")
    p.add_argument(
        "--focal-px", type=number(float, above=0), help="focal length in pixels, when there is no camera file or EXIF"
    )
    p.add_argument("--tag-size", type=tag_side, help="side of the tag's black square in metres, e.g. 0.06")
    p.add_argument("--tag-id", type=number(int, 0), help="the tag that defines the world (default: the one seen most)")
    p.add_argument(
        "--layout",
        help="layout JSON of several tags to use jointly (their frame is the world); by "
        "default the camera file's layout (e.g. the one calibrate estimated) is used when the photos "
        "show several of its tags, else, when they show several tags, one estimated from them",
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
    p.add_argument(
        "--detect-size",
        type=number(int, 64, 100_000),
        default=2000,
        help="tag detection size (long side, px; default 2000)",
    )
    p.add_argument(
        "--jobs",
        type=number(int, 0, 256),
        default=0,
        help="photos processed in parallel, and structure-from-motion's threads (default: up to 4 cores, "
        "SfM on all; SfM on several threads differs a little from run to run, --jobs 1 repeats "
        "exactly)",
    )
    p.add_argument("--no-cache", action="store_true", help="ignore cached detections")
    p.add_argument("--all-photos", action="store_true", help="list every photo in the summary, not only skipped ones")
    p.add_argument("--force", action="store_true", help="replace the dataset files of an earlier run in --out")
    add_dataclass_args(p, PoseConfig, "poses")
    add_dataclass_args(p, DatasetConfig, "dataset")
    p.set_defaults(func=run)


def camera_layout(camera_file: str, dictionary: str, records) -> tuple[Layout | None, str]:
    """(the camera file's layout, a note) when most photos with tags show two or more of its
    tags; else (None, a note or "")."""
    import json
    from pathlib import Path

    import numpy as np

    from ..capture.aruco import layout_from_json
    from ..capture.poses import several_tags
    from ..errors import NerfkitError

    spec = json.loads(Path(camera_file).read_text()).get("layout")
    if not isinstance(spec, dict):
        return None, ""
    try:
        layout = layout_from_json(spec, camera_file, dictionary)
    except NerfkitError as e:
        return None, f"the camera file's layout is not usable ({e}); posing from one tag"
    if len(layout.tags) < 2 or layout.charuco is not None:
        return None, ""
    several, with_tags, enough = several_tags(records, set(layout.tags))
    if not enough:
        return None, ""
    return layout, (
        f"using the camera file's layout of {len(layout.tags)} tags (world: its frame, tag "
        f"{min(layout.tags, key=lambda t: np.abs(layout.tags[t].mean(0)).sum())} at the origin): "
        f"{len(several)} of {len(with_tags)} photos with tags show 2 or more of them. Pass --single-tag "
        "to pose from one tag"
    )


def run(args: argparse.Namespace) -> int:
    import json
    from pathlib import Path

    from ..capture.aruco import Layout, get_dictionary, load_layout
    from ..capture.camera import camera_from_focal, load_camera
    from ..capture.dataset import DATASET_OUTPUTS, POSES_FILE, DatasetConfig, write_poses_json
    from ..capture.photos import default_jobs, group_by_size, require_tags, scan_photos
    from ..capture.poses import (
        PoseConfig,
        choose_tag,
        exif_camera,
        layout_from_photos,
        pose_records,
        refine_focal,
        sheet_heights,
    )
    from ..capture.report import photo_summary
    from ..config import dataclass_from_args
    from ..errors import fail
    from ..io.paths import guard_outputs

    pcfg = dataclass_from_args(PoseConfig, args)
    dcfg = dataclass_from_args(DatasetConfig, args)
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise fail(out, "exists and is not a folder", "--out names the dataset folder to write")
    outputs = [POSES_FILE] + ([] if args.no_dataset else list(DATASET_OUTPUTS))
    if args.method == "colmap" or (args.method == "auto" and not args.no_dataset):
        from ..sfm.dataset import REPORT_FILE

        outputs = [*outputs, *DATASET_OUTPUTS, REPORT_FILE, "colmap"]
        if args.method == "colmap":
            outputs.remove(POSES_FILE)
    guard_outputs([out / name for name in outputs], [args.photos, args.camera, args.layout], args.force)
    camera = load_camera(args.camera) if args.camera else None
    dictionary = args.dict
    if dictionary is None and args.camera:
        dictionary = json.loads(Path(args.camera).read_text()).get("dictionary")
    dictionary = dictionary or "DICT_4X4_50"
    get_dictionary(dictionary)
    if args.tag_size is not None and not args.tag_size > 0:
        raise fail("--tag-size", f"{args.tag_size} must be a positive length in metres")
    if args.method == "colmap":
        from ..sfm import sfm_dataset

        _, report = sfm_dataset(
            args.photos,
            out,
            dcfg,
            matcher=args.matcher,
            max_image_size=args.sfm_max_size,
            tag_size=args.tag_size,
            tag_id=args.tag_id or 0,
            tag_dict=dictionary,
            threads=args.jobs or -1,
            jobs=args.jobs or default_jobs(),
            ground=not args.no_ground,
            camera=camera,
        )
        print(report.summary())
        return 0
    layout = load_layout(args.layout, dictionary, args.tag_size) if args.layout else None
    if layout is None and args.tag_size is None:
        raise fail("--tag-size", "is required", "Measure the tag's black square, e.g. --tag-size 0.06")
    if args.focal_px is not None and not args.focal_px > 0:
        raise fail("--focal-px", f"{args.focal_px} must be positive")

    cache = None if args.no_cache else out / "detections.json"
    records = scan_photos(args.photos, dictionary, layout, args.detect_size, cache, args.jobs or default_jobs())
    require_tags(records, args.photos, dictionary)
    notes = []
    if layout is None and args.camera and args.tag_id is None and not args.single_tag:
        layout, note = camera_layout(args.camera, dictionary, records)
        if note:
            notes.append(note)
    if camera is None:
        if args.focal_px:
            size, _ = group_by_size(records)
            assert size is not None  # require_tags found readable photos
            camera = camera_from_focal(args.focal_px, size[0], size[1], f"--focal-px {args.focal_px:g}")
            notes.append(f"no --camera: fx = fy = {args.focal_px:g} px, principal point at the centre, no distortion")
        else:
            camera, note = exif_camera(records)
            notes.append(note)
    if layout is None and args.tag_id is None and not args.single_tag:
        layout, note = layout_from_photos(records, camera, args.tag_size, pcfg)
        if note:
            notes.append(note)
    if layout is None:
        tag_id = args.tag_id
        if tag_id is None:
            tag_id, note = choose_tag(records)
            notes.append(note)
        layout = Layout.single(tag_id, args.tag_size)
    elif args.tag_id is not None:
        notes.append("--tag-id is ignored with --layout: the layout's frame is the world")
    tag_size = args.tag_size or layout.tag_size
    if pcfg.refine_focal:
        camera, note = refine_focal(records, camera, layout, pcfg)
        if note:
            notes.append(note)
    layout, note = sheet_heights(records, camera, layout, pcfg)
    if note:
        notes.append(note)
    printed = layout.flattened()  # what the files record and the dataset's tags (the heights: the poses' alone)

    posed = pose_records(records, camera, layout, pcfg)
    scaled = sorted({(p.camera.width, p.camera.height) for p in posed} - {(camera.width, camera.height)})
    if scaled:
        notes.append(
            f"the camera ({camera.width}x{camera.height}) is scaled to the photos' "
            + ", ".join(f"{w}x{h}" for w, h in scaled)
        )
    meta = {
        "photos_dir": str(Path(args.photos).resolve()),
        "dictionary": dictionary,
        "tag_size": tag_size,
        "layout": printed.to_json(),
        "sheet_heights_m": layout.heights_json(),
        "world": "tag frame: origin at the tag centre, x right and y up along the "
        "printed tag, z out of the tag toward the cameras (scene up); metres",
        "notes": notes,
        "max_error_px": pcfg.max_error or "auto: max(3 x held-out error, 1 px, 2% of the tag side)",
    }
    out.mkdir(parents=True, exist_ok=True)
    write_poses_json(out / POSES_FILE, records, posed, camera, meta)

    for n in notes:
        print(n)
    print(f"camera: {camera.source or 'given'} ({camera.width}x{camera.height}, fx {camera.K[0, 0]:.1f})")
    print(photo_summary(records, "posed", full=args.all_photos))
    print(f"wrote {out / POSES_FILE}")
    if not posed:
        raise fail(
            args.photos,
            "no photo could be posed (see the table above)",
            "Check --tag-size/--tag-id and that the tag is sharp and fully visible",
        )
    if args.no_dataset:
        return 0
    from .dataset import build_and_report, report_dataset

    if args.method == "auto":
        from ..sfm.tagged import choose_poses

        ref = reference_tag(records, layout)
        start = camera if (args.camera or args.focal_px) else None  # else SfM starts from the EXIF focal length
        choice = choose_poses(
            args.photos,
            out,
            posed,
            start,
            ref,
            tag_size,
            dictionary,
            tag_corners=None if len(layout.tags) == 1 else layout.tags[ref],
            matcher=args.matcher,
            max_image_size=args.sfm_max_size,
            threads=args.jobs or -1,
            records=records,
            layout=layout,
            pose_cfg=pcfg,
        )
        print(choice.why)
        if choice.result is not None:
            from ..sfm.dataset import build_dataset

            _, summary = build_dataset(
                cast("SfmResult", choice.result),
                out,
                dcfg,
                jobs=args.jobs or default_jobs(),
                extra={"notes": notes, "pose_choice": choice.to_dict()},
                tags=printed.corners(),
            )
            return report_dataset(summary, out)
        from ..sfm.dataset import REPORT_FILE

        (out / REPORT_FILE).unlink(missing_ok=True)  # an earlier --force run's SfM report would not hold
        return build_and_report(
            posed,
            out,
            dcfg,
            tag_size,
            args.jobs or default_jobs(),
            {"notes": notes, "pose_choice": choice.to_dict()},
            printed.corners(),
        )
    return build_and_report(
        posed, out, dcfg, tag_size, args.jobs or default_jobs(), {"notes": notes}, printed.corners()
    )


def reference_tag(records, layout) -> int:
    """The layout's tag seen in the most photos (it fixes the SfM model's frame)."""
    from collections import Counter

    seen = Counter(
        int(i) for r in records if r.detection is not None for i in set(r.detection.ids) if int(i) in layout.tags
    )
    return seen.most_common(1)[0][0] if seen else layout.ids[0]
