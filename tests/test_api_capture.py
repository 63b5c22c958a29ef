"""`nerfkit.api.capture`: the capture command's flags as typed arguments, checked as the command
line checks them, before anything is written (the whole run: test_capture_video, test_capture_command)."""

from __future__ import annotations

import inspect

import pytest

from nerfkit import api
from nerfkit.errors import NerfkitError


def test_every_flag_of_capture_is_an_argument_with_its_default():
    """The flags of api.CaptureOptions are unset (None) when not given, and the command fills in
    its defaults, which are the function's."""
    import argparse
    import dataclasses

    from nerfkit.cli import build_parser
    from nerfkit.config import dataclass_from_args

    args = build_parser("capture").parse_args(["capture", "photos", "--out", "o"])
    assert all(getattr(args, f.name) is None for f in dataclasses.fields(api.CaptureOptions))
    args = argparse.Namespace(**{**vars(args), **dataclasses.asdict(dataclass_from_args(api.CaptureOptions, args))})
    params = inspect.signature(api.capture).parameters
    checked = set()
    for dest, value in vars(args).items():
        if dest in ("command", "func", "verbose", "photos", "out"):
            continue
        assert params[dest].default == value, (dest, params[dest].default, value)
        checked.add(dest)
    assert set(params) - checked == {"photos", "out", "verbose", "quiet"}  # (the API alone prints nothing)


@pytest.mark.parametrize(
    ("options", "flag"),
    [
        ({"clip_frames": 5}, "--clip-frames"),
        ({"tag_size": -0.06}, "--tag-size"),
        ({"model": "nerf"}, "--model"),
        ({"method": "sift"}, "--method"),
        ({"steps": 0}, "--steps"),
        ({"max_side": 3}, "--max-side"),
        ({"calib": "sheet", "camera": "camera.json"}, "--camera"),
        ({"method": "tags"}, "--method tags"),  # (no --tag-size: no route does it)
    ],
)
def test_capture_refuses_what_the_command_line_refuses_before_writing(tmp_path, options, flag):
    (tmp_path / "photos").mkdir()
    with pytest.raises(NerfkitError, match=flag):
        api.capture(tmp_path / "photos", tmp_path / "out", **options)
    assert not (tmp_path / "out").exists()
