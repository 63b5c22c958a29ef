"""`nerfkit capture` heads each stage it runs ``[k/N] stage``, N counted from its route, and
structure-from-motion's steps as parts of the poses stage (the whole run: test_capture_video)."""

from __future__ import annotations

import re

import pytest

from nerfkit.commands.stages.capture import Headings, stage_plan
from nerfkit.sfm import colmap


@pytest.mark.parametrize(
    ("video", "calib", "models", "mesh", "n", "first", "last"),
    [
        (True, False, ["splat"], True, 6, "frames", "export of the splat files"),
        (False, True, ["fast"], True, 6, "calibration", "export of the NeRF's mesh"),
        (False, False, ["fast"], False, 4, "poses", "rendering the NeRF's videos"),
        (True, True, ["fast", "splat"], True, 11, "frames", "export of the splat files"),
        (False, False, ["fast", "splat"], False, 8, "poses", "export of the splat files"),
    ],
)
def test_the_stages_planned_follow_the_route(video, calib, models, mesh, n, first, last):
    plan = stage_plan(video, calib, models, mesh)
    assert len(plan) == n == len(set(plan)) and plan[0] == first and plan[-1] == last
    assert plan.index("poses") == int(video) + int(calib)
    for label in ("NeRF" if "fast" in models else None, "splat" if "splat" in models else None):
        if label:  # each model's stages in this order, one after another
            i = plan.index(f"training the {label}")
            assert plan[i + 1 : i + 3] == [f"evaluation of the {label}", f"rendering the {label}'s videos"]


def test_headings_number_the_stages_and_their_parts(capsys):
    plan = stage_plan(True, False, ["splat"], True)
    h = Headings(plan)
    for name in plan:
        h.start(name)
        if name == "poses":
            with colmap.telling_steps(h.part):  # as run_sfm tells its steps
                for step in ("features", "matching", "mapping"):
                    colmap._started(step)
    colmap._started("features")  # outside: told to no one
    lines = re.findall(r"^\[.*$", capsys.readouterr().out, re.M)
    assert lines == [
        "[1/6] frames",
        "[2/6] poses",
        "[2/6] poses: features",
        "[2/6] poses: matching",
        "[2/6] poses: mapping",
        "[3/6] training the splat",
        "[4/6] evaluation of the splat",
        "[5/6] rendering the splat's videos",
        "[6/6] export of the splat files",
    ]
