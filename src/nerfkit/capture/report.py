"""Plain-text summaries of a capture run, printed by the capture commands."""

from __future__ import annotations

import re
import shutil
import textwrap

import numpy as np

from .photos import PhotoRecord


def table(rows: list[list[str]], headers: list[str], max_width: int = 90) -> str:
    """A fixed-width text table; the last column wraps onto more lines to keep them under
    ``max_width`` (a reason is never cut short)."""
    cols = [headers] + rows
    widths = [max(len(str(r[i])) for r in cols) for i in range(len(headers))]
    room = max(20, max_width - sum(widths[:-1]) - 2 * (len(widths) - 1))
    widths[-1] = min(widths[-1], room)
    indent = " " * (sum(widths[:-1]) + 2 * (len(widths) - 1))

    def fmt(r: list) -> str:
        cells = [str(c) for c in r]
        last = textwrap.wrap(cells[-1], widths[-1], break_on_hyphens=False) or [""]
        first = "  ".join([c.ljust(w) for c, w in zip(cells[:-1], widths[:-1])] + [last[0]]).rstrip()
        return "\n".join([first] + [indent + more for more in last[1:]])

    line = "  ".join("-" * w for w in widths)
    return "\n".join([fmt(headers), line] + [fmt(r) for r in rows])


def _reason_kind(reason: str) -> str:
    """A reason's kind ('bad fit: reprojection error 3.1 px > 2 px' -> 'bad fit')."""
    return reason.split(":")[0].split(" (")[0]


def reason_counts(reasons: list[str]) -> str:
    """The reasons photos were skipped, counted by kind, most common first; kinds that differ
    only in their numbers count together, shown by the first one ('2 x taken at 52 mm (or
    similar)')."""
    groups: dict[str, list[str]] = {}
    for reason in reasons:
        kind = _reason_kind(reason)
        groups.setdefault(re.sub(r"\d+(\.\d+)?", "N", kind), []).append(kind)
    ranked = sorted(groups.values(), key=len, reverse=True)
    return "; ".join(f"{len(g)} x {g[0]}" + (" (or similar)" if len(set(g)) > 1 else "") for g in ranked)


def photo_summary(records: list[PhotoRecord], used_word: str = "used", full: bool = False) -> str:
    """Counts, the error of the photos used, and a table of every skipped photo with its reason
    (every photo when ``full``)."""
    used = [r for r in records if r.used]
    skipped = [r for r in records if not r.used]
    lines = [f"{len(records)} photos: {len(used)} {used_word}, {len(skipped)} skipped"]
    errs = [r.error_px for r in used if r.error_px is not None]
    if errs:
        lines.append(
            f"reprojection error of the photos {used_word} (RMS px): median {np.median(errs):.3f}, "
            f"max {np.max(errs):.3f}"
        )
    turned = [r.name for r in used if r.turns]
    if turned:
        lines.append(
            f"{len(turned)} photo{'s' if len(turned) > 1 else ''} held the other way turned back by "
            f"{'their' if len(turned) > 1 else 'its'} EXIF orientation: {', '.join(turned[:5])}"
            + (", ..." if len(turned) > 5 else "")
        )
    if skipped:
        lines.append("skipped: " + reason_counts([r.reason for r in skipped]))
    shown = records if full else skipped
    if shown:
        rows = []
        for r in shown:
            tags = (
                "-"
                if r.detection is None
                else (",".join(map(str, sorted(set(int(i) for i in r.detection.ids)))) or "none")
            )
            err = "" if r.error_px is None else f"{r.error_px:.3f}"
            rows.append([r.name, used_word if r.used else "skipped", tags, err, r.reason])
        lines.append("")
        width = max(90, shutil.get_terminal_size((90, 24)).columns)
        lines.append(table(rows, ["photo", "status", "tags", "err px", "reason"], max_width=width))
    return "\n".join(lines)
