"""The frames stage's report: what a clip gave, what was kept and dropped, and why."""

from __future__ import annotations

from typing import Any


def report_lines(sel: Any) -> str:
    """The report of a :class:`~nerfkit.capture.video.FrameSelection`, a few lines of text."""
    info = sel.info
    rot = f", turned {info.rotation} degrees upright" if info.rotation else ""
    lines = [
        f"{sel.source}: {info.width}x{info.height} {info.codec}{rot}, {info.duration:.1f} s at {info.fps:g} fps",
        f"  read {sel.read} frames, kept {sel.kept} (asked for {sel.target}), dropped {sel.read - sel.kept}"
        + (":" if sel.dropped else ""),
    ]
    lines += [f"    {n:5d} {reason}" for reason, n in sel.dropped.items()]
    lines.append(
        f"  sharpness (variance of the Laplacian at {sel.score_size[0]}x{sel.score_size[1]}): median "
        f"{sel.median_sharpness:.0f}, frames under {sel.blur_threshold:.0f} counted as blurred"
    )
    if sel.empty_windows:
        lines.append(f"  {sel.empty_windows} of the {sel.target} windows ({sel.spread}) gave no frame")
    lines += [f"  note: {a}" for a in sel.advice]
    lines.append(
        f"wrote {sel.kept} frames ({sel.files[0]} ... {sel.files[-1]}) and frames.json to {sel.out_dir} "
        f"in {sel.seconds:.1f} s"
    )
    return "\n".join(lines)
