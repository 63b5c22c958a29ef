"""The dataset stage in small steps: which poses a dataset folder was built from, the dataset
rebuilt from them (the tag poses of poses.json, or the structure-from-motion model), and what
was written."""

from __future__ import annotations

import contextlib


def report_dataset(s: dict, out) -> int:
    """Print what a dataset builder's summary ``s`` says was written to ``out``."""
    from ...capture.agreement import agreement_notes
    from ...capture.coverage import coverage_notes
    from ...capture.dataset import NPZ_FILE, few_views_note, no_object_note

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


def rebuild_from_tags(poses: str, out, cfg, jobs: int, force: bool, allow_outside: bool) -> dict:
    """The dataset from the tag poses of the poses.json at ``poses`` (or in that folder); the
    builder's summary."""
    from pathlib import Path

    from ...capture.dataset import DATASET_OUTPUTS, POSES_FILE, build_dataset, read_poses_json, recorded_tags
    from ...data.validate import check_number
    from ...errors import advice
    from ...io.paths import guard_outputs

    src = Path(poses)
    folder = src if src.is_dir() else src.parent
    posed, data = read_poses_json(poses, allow_outside=allow_outside)
    guard_outputs(
        [out / name for name in DATASET_OUTPUTS],
        [src / POSES_FILE if src.is_dir() else src, *(p.path for p in posed), *{p.path.parent for p in posed}],
        force,
    )
    with advice("Re-run nerfkit poses"):
        tag_size = check_number(data.get("tag_size"), poses, "tag_size", 0.0, expected="the tag size in metres")
    require_photos([p.path for p in posed], folder)
    extra = {
        "notes": data.get("notes", []),
        "pose_choice": {"poses": "tags", "why": f"rebuilt from {folder / POSES_FILE}"},
    }
    _, summary = build_dataset(posed, out, cfg, float(tag_size), jobs=jobs, extra=extra, tags=recorded_tags(data))
    return summary


def recorded_pose_source(folder) -> str:
    """Which poses the dataset in ``folder`` was built from, as its transforms.json says:
    "sfm" or "tags"; with no dataset there, "sfm" when `nerfkit poses` left an SfM report."""
    from ...data.nerfstudio import nerfkit_block
    from ...sfm.dataset import REPORT_FILE

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

    from ...capture.photos import resized_since_scanned
    from ...errors import fail

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


def rebuild_from_sfm(folder, out, cfg, jobs: int, force: bool, allow_outside: bool, say=print) -> dict:
    """The dataset from the structure-from-motion model `nerfkit poses` left in ``folder``; the
    builder's summary. Elsewhere (``out``), the model and its report are copied along, so that
    ``out`` is a dataset folder of its own. ``say``: where the line on the poses goes."""
    import shutil

    from ...capture.dataset import DATASET_OUTPUTS
    from ...data.nerfstudio import nerfkit_block
    from ...data.validate import check_tags
    from ...errors import NerfkitError
    from ...io.atomic import write_bytes
    from ...io.paths import guard_outputs, refuse_links, resolved_path
    from ...sfm.dataset import REPORT_FILE, build_dataset, load_sfm_result, posed_photos

    result = load_sfm_result(folder, allow_outside=allow_outside)
    in_place = resolved_path(out) == resolved_path(folder)
    model_copy = out / "colmap" / "sparse" / "0"
    outputs = [out / name for name in DATASET_OUTPUTS] + ([] if in_place else [out / REPORT_FILE, model_copy])
    photos = [p.path for p in posed_photos(result)]
    # the photos' folders too: poses refuses to write among the photos, and so does this
    guard_outputs(outputs, [folder / REPORT_FILE, result.model_dir, *photos, *{p.parent for p in photos}], force)
    refuse_links(out, ["colmap", "colmap/sparse"])
    require_photos(photos, folder)
    say(
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
    return summary
