"""`nerfkit calibrate`: camera intrinsics and distortion from photos of printed ArUco tags."""

from __future__ import annotations

import argparse

HELP = "calibrate a camera from photos of printed ArUco tags"
MEMORY_HINT = "Lower --detect-size or --jobs"

DESCRIPTION = """\
Estimate the camera matrix K and lens distortion from 20-50 photos of a printed sheet of
ArUco tags taken from varied angles (tilted 20-60 degrees, the sheet in different parts of
the frame). Writes a camera file (JSON) with K, the distortion coefficients, the image
size, the RMS reprojection error ("rms"), each photo's error and whether it was used or
skipped (and why), and sanity checks.

The sheet layout: give it with --layout (a JSON layout file, or an OpenCV GridBoard or
ChArUco description), or leave it out: nerfkit then estimates where the tags sit on the
sheet (all tags on one flat sheet), and never treats different tags as the same points.
Detections are cached beside the output, so re-running is quick.

The camera is chosen whole by cross-validation over photos: every combination of a
distortion model (none, k1, k1k2, k1k2p1p2, k1k2p1p2k3), a centred or fitted principal
point and square or free pixels is fitted on its own; the camera file lists each one
("model_selection" -> "candidates": held-out error, its error at the photos' edges, how
much its folds disagree at the frame's edges, and the verdict) and the one chosen.

example:
  nerfkit calibrate calib_photos/ --dict DICT_4X4_50 --tag-size 0.06 --out camera.json
"""


def register(sub: argparse._SubParsersAction) -> None:
    from ..capture.calibrate import CalibrateConfig
    from ..config import add_dataclass_args, number, tag_side

    p = sub.add_parser(
        "calibrate", help=HELP, description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("photos", metavar="PHOTOS_DIR", help="folder of photos of the tag sheet")
    p.add_argument("--dict", default="DICT_4X4_50", help="ArUco dictionary of the tags (default: DICT_4X4_50)")
    p.add_argument(
        "--tag-size",
        type=tag_side,
        help="side of one tag's black square in metres, e.g. 0.06 (needed unless the layout file gives sizes)",
    )
    p.add_argument("--layout", help="sheet layout JSON (tag id -> corners/centre, or a GridBoard/ChArUco board)")
    p.add_argument("--out", default="camera.json", help="camera file to write (default: camera.json)")
    p.add_argument(
        "--detect-size",
        type=number(int, 64, 100_000),
        default=2000,
        help="detect tags on a copy this many pixels on the long side, then refine corners at full "
        "resolution (default: 2000)",
    )
    p.add_argument(
        "--jobs", type=number(int, 0, 256), default=0, help="photos processed in parallel (default: up to 4 cores)"
    )
    p.add_argument("--no-cache", action="store_true", help="ignore cached detections")
    p.add_argument("--all-photos", action="store_true", help="list every photo in the summary, not only skipped ones")
    p.add_argument("--force", action="store_true", help="replace an existing camera file")
    add_dataclass_args(p, CalibrateConfig, "calibration")
    p.set_defaults(func=run)


def selection_table(sel: dict) -> str:
    """How the camera was chosen: one row per camera tried (distortion model / principal
    point / aspect), or per model in camera files written before cameras were chosen whole."""
    from ..capture.report import table

    def px(v) -> str:
        return "-" if v is None else f"{v:.3f}"

    cands = sel.get("candidates")
    rows = [
        [
            r.get("name", m),
            px(r.get("heldout_rms")),
            px(r.get("edge_heldout_rms")),
            px(r.get("fit_rms")),
            px(r.get("frame_spread_px")),
            px(r.get("edge_limit_px")),
            px((r.get("check") or {}).get("corner_displacement_px")),
            (r.get("verdict") or ("chosen" if r.get("name", m) == sel.get("camera", sel["chosen"]) else "ok"))
            if r.get("eligible")
            else (r.get("rejected") or ""),
        ]
        for m, r in (((r["name"], r) for r in cands) if cands else sel["models"].items())
    ]
    heads = [
        f"{what} {c['chosen']}: {c['why']}"
        for name, what in (("principal_point", "principal point"), ("aspect", "pixels"))
        if (c := sel.get(name))
    ]
    heads.append(f"distortion model {sel['chosen']} ({sel['method']}): {sel['why']}")
    if sel.get("camera_why") and sel["camera_why"] != sel["why"]:
        heads.append(f"camera {sel['camera_why']}")
    return (
        "\n".join(heads)
        + "\n"
        + table(
            rows,
            ["camera", "held-out px", "at edges", "fit px", "edge spread", "spread limit", "corner shift", "verdict"],
            max_width=140,
        )
    )


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    import numpy as np

    from ..capture.aruco import get_dictionary, load_layout
    from ..capture.calibrate import CalibrateConfig, calibrate_records, calibration_json
    from ..capture.photos import blur_hint, default_jobs, group_by_size, keep_one_lens, require_tags, scan_photos
    from ..capture.report import photo_summary
    from ..config import dataclass_from_args
    from ..errors import fail
    from ..io.atomic import write_json
    from ..io.paths import guard_outputs

    cfg = dataclass_from_args(CalibrateConfig, args)
    get_dictionary(args.dict)
    if args.tag_size is not None and not args.tag_size > 0:
        raise fail("--tag-size", f"{args.tag_size} must be a positive length in metres")
    layout = load_layout(args.layout, args.dict, args.tag_size) if args.layout else None
    if layout is None and args.tag_size is None:
        raise fail("--tag-size", "is required without --layout", "Measure one tag's black square, e.g. --tag-size 0.06")
    if args.tag_size:
        tag_size = args.tag_size
    else:
        assert layout is not None  # checked above
        tag_size = layout.tag_size
    out = Path(args.out)
    if out.is_dir():
        out = out / "camera.json"
    guard_outputs([out], [args.photos, args.layout], args.force)
    cache = None if args.no_cache else out.with_name(out.stem + ".detections.json")

    records = scan_photos(args.photos, args.dict, layout, args.detect_size, cache, args.jobs or default_jobs())
    require_tags(records, args.photos, args.dict)
    charuco = layout is not None and layout.charuco is not None
    for r in records:
        if r.detection is not None and len(r.detection.ids) == 0:
            r.skip("no tags found" + blur_hint(records, r))
    size, kept = group_by_size(
        keep_one_lens([r for r in records if r.detection is not None and (len(r.detection.ids) or charuco)]), turn=True
    )
    cal = calibrate_records(kept, size, tag_size, layout, cfg, args.dict)
    data = calibration_json(cal, records, args.dict, tag_size, str(Path(args.photos).resolve()))
    write_json(out, data)

    print(photo_summary(records, "used", full=args.all_photos))
    K, d = cal.K, cal.dist
    print()
    print(f"target: {cal.target}")
    for note in cal.notes:
        print(f"  {note}")
    if cal.layout is not None and cal.target == "estimated layout":
        centres = ", ".join(
            f"{t}: ({c.mean(0)[0] * 100:.1f}, {c.mean(0)[1] * 100:.1f})" for t, c in sorted(cal.layout.tags.items())
        )
        print(f"  tag centres (cm): {centres}")
    std = cal.std
    print(f"image size {cal.width}x{cal.height}; RMS reprojection error {cal.rms:.3f} px")
    print(
        f"fx {K[0, 0]:.2f} (+/-{std[0]:.2f})  fy {K[1, 1]:.2f} (+/-{std[1]:.2f})  "
        f"cx {K[0, 2]:.2f} (+/-{std[2]:.2f})  cy {K[1, 2]:.2f} (+/-{std[3]:.2f})"
    )
    print("dist k1 k2 p1 p2 k3: " + " ".join(f"{v:.5f}" for v in d))
    print(selection_table(cal.selection))
    s = cal.sanity
    exif = f", fx / EXIF fx {s['fx_over_exif_fx']:.3f}" if s.get("exif_focal_35mm") else ", no EXIF focal length"
    print(
        f"checks: fx/fy {s['fx_fy_ratio']:.4f}, principal point {np.hypot(*s['principal_point_offset_px']):.1f} px "
        f"from centre{exif}, corner coverage {s['corner_coverage'] * 100:.0f}%"
    )
    for w in s["warnings"]:
        print(f"WARNING: {w}")
    if not s["warnings"]:
        print("all sanity checks passed")
    print(f"wrote {out}")
    return 0
