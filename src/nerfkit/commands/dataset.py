"""`nerfkit dataset`: (re)build a NeRF dataset from the poses `nerfkit poses` found."""

from __future__ import annotations

import argparse
import contextlib

MEMORY_HINT = "Lower --max-side or --jobs"
HELP = "undistort, resize and split posed photos into a NeRF dataset (npz + transforms.json)"

DESCRIPTION = """\
Build the dataset from DATASET_DIR/poses.json (written by `nerfkit poses`): undistort each
photo (keeping the calibrated focal length, cropped to the largest rectangle of valid
pixels, K updated), downscale it, split the views into train/val/test, estimate near/far
from the cameras and the tag size, and write images/, transforms.json (nerfstudio layout,
OpenGL axes) and dataset.npz (the course layout plus K, near, far, center, up and each
view's photo name), and say how closely the photos surround the object (the widest gap
among the view directions, charted in coverage.png) and how well the training photos agree
on the table around it (a rough ceiling for held-out scores).
`nerfkit poses` runs this step itself; run it again with --out to build another size or
split (or with --force to rebuild it in place: runs trained on the old dataset then refuse
the new one). It keeps the poses `nerfkit poses` gave the dataset: when those came
from structure-from-motion (DATASET_DIR/sfm_report.json and colmap/sparse/0), the dataset
is rebuilt from that model, else from the tag poses in poses.json (transforms.json says
which; --pose-source chooses).

example:
  nerfkit dataset my_object/ --max-side 800 --out my_object_800/
"""


def register(sub: argparse._SubParsersAction) -> None:
    from ..capture.dataset import DatasetConfig
    from ..config import add_dataclass_args, number
    from ._common import add_outside_flag

    p = sub.add_parser(
        "dataset", help=HELP, description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("poses", metavar="DATASET_DIR", help="folder with poses.json from `nerfkit poses` (or the file)")
    p.add_argument("--out", help="folder to write (default: the same folder)")
    p.add_argument(
        "--pose-source",
        choices=["auto", "tags", "sfm"],
        default="auto",
        help="auto (default): the poses the folder's dataset was built from (transforms.json says): "
        "the structure-from-motion model that `nerfkit poses` left (sfm_report.json, colmap/), or "
        "the tag poses of poses.json",
    )
    p.add_argument(
        "--jobs", type=number(int, 0, 256), default=0, help="photos processed in parallel (default: up to 4 cores)"
    )
    p.add_argument(
        "--force",
        action="store_true",
        help="replace an existing dataset (dataset.npz, transforms.json, images/, coverage.png) in the output folder",
    )
    add_outside_flag(p)
    add_dataclass_args(p, DatasetConfig, "dataset")
    p.set_defaults(func=run)


def build_and_report(posed, out, cfg, tag_size: float, jobs: int, extra: dict | None = None, tags=None) -> int:
    """Build the dataset and print what was written."""
    from ..capture.dataset import build_dataset

    _, s = build_dataset(posed, out, cfg, tag_size, jobs=jobs, extra=extra, tags=tags)
    return report_dataset(s, out)


def report_dataset(s: dict, out) -> int:
    """Print what a dataset builder's summary ``s`` says was written to ``out``."""
    from ..capture.agreement import agreement_notes
    from ..capture.coverage import coverage_notes
    from ..capture.dataset import NPZ_FILE, few_views_note, no_object_note

    K = s["K"]
    print(
        f"dataset: {s['views']['train']} train, {s['views']['val']} val, {s['views']['test']} test views of "
        f"{s['size'][0]}x{s['size'][1]} (from {s['source_size'][0]}x{s['source_size'][1]}"
        f"{', undistorted: the largest rectangle of valid pixels' if s['undistorted'] else ''})"
    )
    note = few_views_note(s["views"]["train"])
    if note:
        print(note)
    print(f"K: fx {K[0][0]:.2f} fy {K[1][1]:.2f} cx {K[0][2]:.2f} cy {K[1][2]:.2f} (pixel centres at +0.5)")
    print(f"near {s['near']:.4f}  far {s['far']:.4f}  centre {s['center']} ({s['center_from']})  up {s['up']}")
    print(f"sparse points: {s['points']} ({s['points_from']})")
    if s.get("table_from"):
        print(f"table plane: {s['table_from']}")
    note = no_object_note(s.get("object_points"), s["points"])
    if note:
        print(note)
    if s.get("coverage"):
        print("\n".join(coverage_notes(s["coverage"])))
    if s.get("agreement"):
        print("\n".join(agreement_notes(s["agreement"])))
    plot = f", {s['coverage']['plot']}" if s.get("coverage") else ""
    print(
        f"wrote {out}/{NPZ_FILE}, {out}/transforms.json{', sparse_pc.ply' if s['points'] else ''}{plot} and "
        f"{out}/images/"
    )
    return 0


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ..capture.dataset import (
        DATASET_OUTPUTS,
        POSES_FILE,
        DatasetConfig,
        check_settings,
        read_poses_json,
        recorded_tags,
    )
    from ..capture.photos import default_jobs
    from ..config import dataclass_from_args
    from ..data.validate import check_number
    from ..errors import advice
    from ..io.paths import guard_outputs

    cfg = dataclass_from_args(DatasetConfig, args)
    check_settings(cfg)
    src = Path(args.poses)
    folder = src if src.is_dir() else src.parent
    out = Path(args.out) if args.out else folder
    jobs = args.jobs or default_jobs()
    source = recorded_pose_source(folder) if args.pose_source == "auto" else args.pose_source
    if source == "sfm":
        return rebuild_from_sfm(folder, out, cfg, jobs, args.force, args.allow_outside_paths)
    posed, data = read_poses_json(args.poses, allow_outside=args.allow_outside_paths)
    guard_outputs(
        [out / name for name in DATASET_OUTPUTS],
        [src / POSES_FILE if src.is_dir() else src, *(p.path for p in posed), *{p.path.parent for p in posed}],
        args.force,
    )
    with advice("Re-run nerfkit poses"):
        tag_size = check_number(data.get("tag_size"), args.poses, "tag_size", 0.0, expected="the tag size in metres")
    require_photos([p.path for p in posed], folder)
    return build_and_report(
        posed,
        out,
        cfg,
        float(tag_size),
        jobs,
        {
            "notes": data.get("notes", []),
            "pose_choice": {"poses": "tags", "why": f"rebuilt from {folder / POSES_FILE}"},
        },
        recorded_tags(data),
    )


def recorded_pose_source(folder) -> str:
    """Which poses the dataset in ``folder`` was built from, as its transforms.json says:
    "sfm" or "tags"; with no dataset there, "sfm" when `nerfkit poses` left an SfM report."""
    from ..data.nerfstudio import nerfkit_block
    from ..sfm.dataset import REPORT_FILE

    meta = nerfkit_block(folder)  # None: no dataset yet, or not one nerfkit wrote
    if meta is not None:
        choice = meta.get("pose_choice")
        if isinstance(choice, dict) and choice.get("poses") in ("sfm", "tags"):
            return choice["poses"]
        return "sfm" if "sfm" in meta else "tags"
    return "sfm" if (folder / REPORT_FILE).is_file() else "tags"


def require_photos(paths, folder) -> None:
    """Refuse, naming one, when photos a dataset is built from are gone, or were replaced
    since ``nerfkit poses`` scanned them (their sizes against its detection cache in ``folder``)."""
    from pathlib import Path

    from ..capture.photos import resized_since_scanned
    from ..errors import fail

    missing = [Path(p) for p in paths if not Path(p).is_file()]
    if missing:
        raise fail(
            missing[0].parent,
            f"{len(missing)} posed photos are missing (e.g. {missing[0].name})",
            "The photos moved; re-run nerfkit poses on their new folder",
        )
    changed = resized_since_scanned(Path(folder) / "detections.json", [Path(p) for p in paths])
    if changed:
        raise fail(
            changed[0],
            "changed since nerfkit poses posed it (another size)"
            + (f", as did {len(changed) - 1} more" if len(changed) > 1 else ""),
            "Re-run nerfkit poses (with --force) to pose the photos as they are now",
        )


def rebuild_from_sfm(folder, out, cfg, jobs: int, force: bool, allow_outside: bool) -> int:
    """The dataset from the structure-from-motion model `nerfkit poses` left in ``folder``.
    Elsewhere (``out``), the model and its report are copied along, so that ``out`` is a
    dataset folder of its own."""
    import shutil

    from ..capture.dataset import DATASET_OUTPUTS
    from ..data.nerfstudio import nerfkit_block
    from ..data.validate import check_tags
    from ..errors import NerfkitError
    from ..io.atomic import write_bytes
    from ..io.paths import guard_outputs, refuse_links, resolved_path
    from ..sfm.dataset import REPORT_FILE, build_dataset, load_sfm_result, posed_photos

    result = load_sfm_result(folder, allow_outside=allow_outside)
    in_place = resolved_path(out) == resolved_path(folder)
    model_copy = out / "colmap" / "sparse" / "0"
    outputs = [out / name for name in DATASET_OUTPUTS] + ([] if in_place else [out / REPORT_FILE, model_copy])
    photos = [p.path for p in posed_photos(result)]
    # the photos' folders too: poses refuses to write among the photos, and so does this
    guard_outputs(outputs, [folder / REPORT_FILE, result.model_dir, *photos, *{p.parent for p in photos}], force)
    refuse_links(out, ["colmap", "colmap/sparse"])
    require_photos(photos, folder)
    print(
        f"poses: structure-from-motion, {len(photos)} photos ({result.model_dir}; --pose-source tags for the tag poses)"
    )
    if not in_place:
        if model_copy.exists():
            shutil.rmtree(model_copy)
        for f in sorted(result.model_dir.iterdir()):
            if f.is_file():
                write_bytes(model_copy / f.name, f.read_bytes())
        result.model_dir = model_copy
    tags = None
    if result.tag_size is not None:  # the printed tags the dataset built from this model recorded, if they read
        with contextlib.suppress(NerfkitError):
            tags = check_tags((nerfkit_block(folder) or {}).get("tags"), str(folder / "transforms.json"))
    _, summary = build_dataset(
        result,
        out,
        cfg,
        jobs=jobs,
        write_report=not in_place,
        tags=tags,
        extra={"pose_choice": {"poses": "sfm", "why": f"rebuilt from {result.model_dir}"}},
    )
    return report_dataset(summary, out)
