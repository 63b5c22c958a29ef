"""The render stage in small steps: the camera path, the object cut out of its surroundings,
and the line that says what was rendered."""

from __future__ import annotations

from typing import Any


def path_kind(scene: Any, path: str, frames: int | None, object_only: bool, ndc: bool) -> tuple[str, str | None]:
    """(the camera path to render, a note or None) for ``path`` ("auto", "test", "orbit" or
    "spiral") over ``scene``; refused when the scene cannot have it, or when ``object_only``
    asks for the object of a forward-facing scene (``ndc``: the model renders in NDC). The note
    says that ``frames`` does not set the length of the test path."""
    from ...errors import fail

    kind = scene.video_kind(path)
    note = None
    if kind == "test" and len(scene.test) == 0:
        raise fail(scene.source, "has no test poses", "Use --path orbit")
    if kind == "test" and frames and frames != len(scene.test):
        note = (
            f"note: --frames sets the length of an orbit or spiral; the test path is the dataset's "
            f"{len(scene.test)} poses (--path orbit for {frames} frames)"
        )
    if kind == "spiral" and not scene.forward_facing:
        raise fail(
            "--path spiral",
            "the training cameras do not all look the same way from about the same "
            "place, so a spiral across their view would leave them",
            "Use --path orbit",
        )
    if object_only and (kind == "spiral" or ndc):
        raise fail(
            "--object",
            "a forward-facing scene, seen from one side and held in one volume out to "
            "infinity, has no object standing apart to frame",
            "Render it without --object",
        )
    return kind, note


def leave_object_alone(model: Any) -> str:
    """Clear ``model`` (in place: it is only rendered) of all but its object; what the videos
    then show, for the report: "the object alone (the table and floor left out; ...", left
    open for the zoom."""
    from ...surroundings import object_alone, table_tags
    from ...surroundings.clearing import cleared_note

    tags = table_tags(model)
    isolated = object_alone(model, copy=False)
    if not isolated.left_out:
        return "the object (the model draws nothing around it to leave out"
    alone = f"the object alone ({listed(isolated.left_out)} left out"
    if isolated.cut > 0:
        alone += f"; {cleared_note(isolated.cut, tags)}"
    return alone


def listed(names: list[str]) -> str:
    """``a``, ``a and b``, ``a, b and c``."""
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]


def render_report(frames: int, alone: str, step: int, seconds_per_frame: float, videos: list) -> str:
    """The printed report: how many frames (of what) at which step, and the videos written."""
    what = f" of {alone}" if alone else ""
    lines = [f"rendered {frames} frames{what} at step {step} ({seconds_per_frame:.2f} s/frame):"]
    return "\n".join(lines + [f"  {p}" for p in videos])
