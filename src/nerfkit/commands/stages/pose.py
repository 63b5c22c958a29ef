"""The posing stage in small steps: which files it writes, the tag frame it poses in (camera,
layout, tag), what poses.json records and prints, and the dataset built from the poses."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

if TYPE_CHECKING:
    from ...capture.aruco import Layout
    from ...capture.camera import Camera
    from ...capture.dataset import DatasetConfig
    from ...capture.focal import FocalCheck
    from ...capture.poses import PoseConfig, TagFocal
    from ...data.scene import Scene
    from ...sfm.colmap import SfmResult


def output_names(method: str, build_dataset: bool) -> list[str]:
    """The files and folders posing with ``method`` writes into its dataset folder (for the
    guard that refuses to replace them without ``force``)."""
    from ...capture.dataset import DATASET_OUTPUTS, POSES_FILE

    outputs = [POSES_FILE] + (list(DATASET_OUTPUTS) if build_dataset else [])
    if method == "colmap" or (method == "auto" and build_dataset):
        from ...sfm.dataset import REPORT_FILE

        outputs = [*outputs, *DATASET_OUTPUTS, REPORT_FILE, "colmap"]
        if method == "colmap":
            outputs.remove(POSES_FILE)
    return outputs


def dictionary_of(dictionary: str | None, camera_file: str | None) -> str:
    """The ArUco dictionary to detect: ``dictionary``, else the camera file's, else DICT_4X4_50."""
    if dictionary is None and camera_file:
        dictionary = json.loads(Path(camera_file).read_text()).get("dictionary")
    return dictionary or "DICT_4X4_50"


def camera_layout(camera_file: str, dictionary: str, records) -> tuple[Layout | None, str]:
    """(the camera file's layout, a note) when most photos with tags show two or more of its
    tags; else (None, a note or "")."""
    import numpy as np

    from ...capture.aruco import layout_from_json
    from ...capture.poses import several_tags
    from ...errors import NerfkitError

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


def sized_layout(layout: Layout, tag_size: float, records) -> tuple[Layout, str]:
    """(the camera file's ``layout`` at ``--tag-size``, a note) when its tags' side (calibrate's
    --tag-size) differs from ``tag_size`` by more than 1% and the photos show no tag outside
    it (so --tag-size measures its tags); else (``layout``, "")."""
    seen = {int(i) for r in records if r.detection is not None for i in r.detection.ids}
    if abs(layout.tag_size / tag_size - 1) <= 0.01 or not seen <= set(layout.tags):
        return layout, ""
    return layout.scaled(tag_size / layout.tag_size), (
        f"the camera file's layout has tags of {layout.tag_size * 1000:.1f} mm (calibrate's --tag-size) and "
        f"--tag-size says {tag_size * 1000:.1f} mm; the photos show only the layout's tags: it is scaled to "
        "--tag-size (the scene's scale follows it; the lens does not depend on it)"
    )


def layout_misfit(records, camera: Camera, layout: Layout, cfg: PoseConfig, sample: int = 12) -> str:
    """Why the photos' tags do not sit as ``layout`` says, or "": most of (up to ``sample``)
    photos that show two or more of its tags fit it only after dropping half of them or more
    (:func:`~nerfkit.capture.poses.solve_pose_robust`), as photos of another sheet with the
    same ids do."""
    from ...capture.poses import detection_limit, solve_pose_robust

    shown = [
        r
        for r in records
        if r.detection is not None
        and camera.compatible(*r.detected_size) is None
        and len({int(i) for i in r.detection.ids} & set(layout.tags)) >= 2
    ]
    shown = shown[:: max(1, len(shown) // sample)][:sample]
    bad = 0
    for r in shown:
        cam = camera if r.detected_size == (camera.width, camera.height) else camera.scaled_to(*r.detected_size)
        limit = detection_limit(r.detection, cam, layout, cfg)[0]
        c2w, err, _, info = solve_pose_robust(r.detection, cam, layout, limit)
        used, dropped = len(info.get("tags_used", [])), len(info.get("tags_dropped", {}))
        bad += c2w is None or err > limit or 2 * dropped >= used + dropped
    if not shown or bad <= len(shown) / 2:
        return ""
    return f"{bad} of {len(shown)} photos showing several of its tags fit it only without half of them or more"


def starting_camera(records, focal_px: float | None) -> tuple[Camera, str]:
    """(the camera to pose with when no camera file is given, a note): ``focal_px`` with the
    principal point at the centre, else the photos' EXIF focal length."""
    from ...capture.camera import camera_from_focal
    from ...capture.photos import group_by_size
    from ...capture.poses import exif_camera

    if focal_px:
        size, _ = group_by_size(records)
        assert size is not None  # require_tags found readable photos
        camera = camera_from_focal(focal_px, size[0], size[1], f"--focal-px {focal_px:g}")
        return camera, f"no --camera: fx = fy = {focal_px:g} px, principal point at the centre, no distortion"
    return exif_camera(records)


def tag_frame(
    records,
    camera: Camera | None,
    layout: Layout | None,
    *,
    camera_file: str | None,
    dictionary: str,
    focal_px: float | None,
    tag_id: int | None,
    tag_size: float | None,
    single_tag: bool,
    cfg: PoseConfig,
) -> tuple[Camera, Layout, float, TagFocal | None, list[str]]:
    """(camera, layout, tag side in metres, the tags' focal length, notes): the frame the photos are posed
    in. The layout: ``layout``,
    else the camera file's (when the photos show several of its tags), else one estimated from
    the photos, else the single tag ``tag_id`` (or the one seen most); never a layout with
    ``tag_id`` or ``single_tag``. The camera: ``camera``, else :func:`starting_camera`, its focal
    length fitted to the tags when ``cfg.refine_focal``. The layout's tags get their heights
    above the sheet (:func:`~nerfkit.capture.poses.sheet_heights`). The tag side: ``tag_size``, else
    the layout's (as printed). The tags' focal length (:func:`~nerfkit.capture.poses.tag_focal`): the
    one the photos' tags want of ``camera``, a camera file's, to check it by; None without ``camera``."""
    from ...capture.aruco import Layout
    from ...capture.poses import (
        choose_tag,
        focal_refined,
        layout_from_photos,
        sheet_heights,
        tag_focal,
        turn_into_camera_frame,
    )

    notes: list[str] = []
    given = camera is not None  # a camera file: its focal length is checked against the photos' (capture.focal)
    free = tag_id is None and not single_tag  # a layout may be chosen
    from_file, file_notes = None, []
    if layout is None and camera_file and free:
        from_file, note = camera_layout(camera_file, dictionary, records)
        file_notes.append(note)
        if from_file is not None and tag_size:
            from_file, note = sized_layout(from_file, tag_size, records)
            file_notes.append(note)
    if camera is None:
        camera, note = starting_camera(records, focal_px)
        notes.append(note)
    turn_into_camera_frame(records, camera)  # photos held the other way count in the steps below too
    misfit = layout_misfit(records, camera, from_file, cfg) if from_file is not None else ""
    if misfit:
        notes.append(f"the camera file's layout does not fit these photos' tags ({misfit}): another sheet? Not used")
    else:
        notes += [n for n in file_notes if n]  # (a usable layout's, or why the file has none)
        layout = layout or from_file
    if layout is None:
        assert tag_size is not None  # the caller requires it without a layout
        if free:
            layout, note = layout_from_photos(records, camera, tag_size, cfg)
            if note:
                notes.append(note)
        if layout is None:
            if tag_id is None:
                tag_id, note = choose_tag(records)
                notes.append(note)
            layout = Layout.single(tag_id, tag_size)
    elif tag_id is not None:
        notes.append("--tag-id is ignored with --layout: the layout's frame is the world")
    side = tag_size or layout.tag_size
    estimate = tag_focal(records, camera, layout, cfg) if cfg.refine_focal or given else None
    if cfg.refine_focal:  # (a camera file's too far off is warned of by the focal length check)
        camera, note = focal_refined(camera, estimate, warn=not given)
        if note:
            notes.append(note)
    layout, note = sheet_heights(records, camera, layout, cfg)
    if note:
        notes.append(note)
    return camera, layout, side, estimate if given else None, notes


def scaled_note(posed: list, camera: Camera) -> str | None:
    """A note when photos of another size than the camera's were posed with it scaled."""
    scaled = sorted({(p.camera.width, p.camera.height) for p in posed} - {(camera.width, camera.height)})
    if not scaled:
        return None
    return f"the camera ({camera.width}x{camera.height}) is scaled to the photos' " + ", ".join(
        f"{w}x{h}" for w, h in scaled
    )


def poses_meta(
    photos: str,
    dictionary: str,
    tag_size: float,
    printed: Layout,
    layout: Layout,
    notes: list[str],
    cfg: PoseConfig,
    focal: FocalCheck | None = None,
) -> dict[str, Any]:
    """What poses.json records about the posing besides each photo: the frame, the tags
    (``printed``: the layout as printed; ``layout``: with the tags' heights), the notes and the
    camera file's focal length against the tags' (``focal``)."""
    return {
        "photos_dir": str(Path(photos).resolve()),
        "dictionary": dictionary,
        "tag_size": tag_size,
        "layout": printed.to_json(),
        "sheet_heights_m": layout.heights_json(),
        "world": "tag frame: origin at the tag centre, x right and y up along the "
        "printed tag, z out of the tag toward the cameras (scene up); metres",
        "notes": notes,
        "max_error_px": cfg.max_error or "auto: max(3 x held-out error, 1 px, 2% of the tag side)",
        "focal_check": None if focal is None else focal.as_json(),
    }


def poses_report(
    notes: list[str], camera: Camera, records: list, written: Path, all_photos: bool, focal: FocalCheck | None = None
) -> str:
    """The printed report of the tag poses: the notes, the camera (and ``focal``, the camera
    file's focal length against the photos'), the photos posed or skipped (every one with
    ``all_photos``) and the poses.json written."""
    from ...capture.report import photo_summary

    return "\n".join(
        [
            *notes,
            f"camera: {camera.source or 'given'} ({camera.width}x{camera.height}, fx {camera.K[0, 0]:.1f})",
            *([focal.line()] if focal is not None else []),
            photo_summary(records, "posed", full=all_photos),
            f"wrote {written}",
        ]
    )


def reference_tag(records, layout) -> int:
    """The layout's tag seen in the most photos (it fixes the SfM model's frame)."""
    from collections import Counter

    seen = Counter(
        int(i) for r in records if r.detection is not None for i in set(r.detection.ids) if int(i) in layout.tags
    )
    return seen.most_common(1)[0][0] if seen else layout.ids[0]


def tag_dataset(
    posed: list,
    out: Path,
    cfg: DatasetConfig,
    tag_size: float,
    jobs: int,
    extra: dict,
    tags,
) -> tuple[Scene, dict]:
    """(scene, summary) of the dataset built from the tag poses ``posed`` into ``out``."""
    from ...capture.dataset import build_dataset

    return build_dataset(posed, out, cfg, tag_size, jobs=jobs, extra=extra, tags=tags)


def chosen_dataset(
    photos: str,
    out: Path,
    posed: list,
    records: list,
    start: Camera | None,
    layout: Layout,
    printed: Layout,
    *,
    tag_size: float,
    dictionary: str,
    notes: list[str],
    matcher: str,
    sfm_max_size: int,
    jobs: int,
    threads: int,
    pose_cfg: PoseConfig,
    dataset_cfg: DatasetConfig,
    say: Callable[[str], None],
    progress: bool = True,
    camera_file: Camera | None = None,
    tags_focal: TagFocal | None = None,
) -> tuple[Scene, dict]:
    """(scene, summary) of the dataset of ``--method auto``: the photos posed by SfM in the tag's
    frame, or by the tags (``posed``) when SfM registers too few, misses the tag or disagrees
    with the tags; ``say`` is told which and why, and how the focal length SfM found (else the
    tags', ``tags_focal``) compares with the camera file's (``camera_file``; None: none given;
    :mod:`~nerfkit.capture.focal`). ``start``: the camera SfM starts from (None: the photos' EXIF
    focal length)."""
    from ...capture.focal import focal_check
    from ...sfm.dataset import REPORT_FILE
    from ...sfm.tagged import choose_poses

    ref = reference_tag(records, layout)
    choice = choose_poses(
        photos,
        out,
        posed,
        start,
        ref,
        tag_size,
        dictionary,
        tag_corners=None if len(layout.tags) == 1 else layout.tags[ref],
        matcher=matcher,
        max_image_size=sfm_max_size,
        threads=threads,
        records=records,
        layout=layout,
        pose_cfg=pose_cfg,
        progress=progress,
    )
    say(choice.why)
    checked = focal_check(camera_file, tags_focal, choice.focal)
    focal = None if checked is None else checked.as_json()
    if checked is not None:
        say(checked.line())
    extra = {"notes": notes, "pose_choice": choice.to_dict(), "focal_check": focal}
    if choice.result is not None:
        from ...sfm.dataset import build_dataset

        cast("SfmResult", choice.result).report.focal_check = focal  # (sfm_report.json records it too)
        return build_dataset(
            cast("SfmResult", choice.result),
            out,
            dataset_cfg,
            jobs=jobs,
            extra=extra,
            tags=printed.corners(),
            progress=progress,
        )
    (out / REPORT_FILE).unlink(missing_ok=True)  # an earlier --force run's SfM report would not hold
    return tag_dataset(posed, out, dataset_cfg, tag_size, jobs, extra, printed.corners())
