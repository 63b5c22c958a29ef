"""The calibration stage's report: what ``nerfkit calibrate`` (and :func:`nerfkit.api.calibrate`) prints."""

from __future__ import annotations

from pathlib import Path
from typing import Any


def selection_table(sel: dict) -> str:
    """How the camera was chosen: one row per camera tried (distortion model / principal
    point / aspect), or per model in camera files written before cameras were chosen whole."""
    from ...capture.report import table

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


def calibration_report(cal: Any, records: list, out: Path, all_photos: bool = False) -> str:
    """The printed report of a calibration ``cal`` (:class:`~nerfkit.capture.calibrate.Calibration`)
    from photo ``records`` written to ``out``: the photos used or skipped (every one with
    ``all_photos``), the target, the camera with its uncertainties, how it was chosen, the sanity
    checks and the file written."""
    import numpy as np

    from ...capture.report import photo_summary

    lines = [photo_summary(records, "used", full=all_photos), "", f"target: {cal.target}"]
    lines += [f"  {note}" for note in cal.notes]
    if cal.layout is not None and cal.target == "estimated layout":
        centres = ", ".join(
            f"{t}: ({c.mean(0)[0] * 100:.1f}, {c.mean(0)[1] * 100:.1f})" for t, c in sorted(cal.layout.tags.items())
        )
        lines.append(f"  tag centres (cm): {centres}")
    K, d, std = cal.K, cal.dist, cal.std
    lines += [
        f"image size {cal.width}x{cal.height}; RMS reprojection error {cal.rms:.3f} px",
        f"fx {K[0, 0]:.2f} (+/-{std[0]:.2f})  fy {K[1, 1]:.2f} (+/-{std[1]:.2f})  "
        f"cx {K[0, 2]:.2f} (+/-{std[2]:.2f})  cy {K[1, 2]:.2f} (+/-{std[3]:.2f})",
        "dist k1 k2 p1 p2 k3: " + " ".join(f"{v:.5f}" for v in d),
        selection_table(cal.selection),
    ]
    s = cal.sanity
    exif = f", fx / EXIF fx {s['fx_over_exif_fx']:.3f}" if s.get("exif_focal_35mm") else ", no EXIF focal length"
    lines.append(
        f"checks: fx/fy {s['fx_fy_ratio']:.4f}, principal point {np.hypot(*s['principal_point_offset_px']):.1f} px "
        f"from centre{exif}, corner coverage {s['corner_coverage'] * 100:.0f}%"
    )
    lines += [f"WARNING: {w}" for w in s["warnings"]]
    if not s["warnings"]:
        lines.append("all sanity checks passed")
    lines.append(f"wrote {out}")
    return "\n".join(lines)
