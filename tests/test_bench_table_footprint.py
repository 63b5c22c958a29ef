"""benchmarks/table_footprint.py: a table texel against the pixel footprint, per capture."""

from __future__ import annotations

import importlib.util
from dataclasses import replace
from pathlib import Path

import pytest

from nerfkit.data.synthetic import tabletop_scene
from nerfkit.scene_extent import sphere_radius
from nerfkit.surroundings.table import plane_footprint

_spec = importlib.util.spec_from_file_location(
    "table_footprint", Path(__file__).resolve().parents[1] / "benchmarks" / "table_footprint.py"
)
tf = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(tf)


def test_a_row_holds_the_texel_the_footprint_and_their_ratio_at_each_resolution():
    scene = tabletop_scene(n_train=6, n_val=0, size=32)
    row = tf.footprint_row("toy", scene, [256, 512])
    r = sphere_radius(scene)
    foot = plane_footprint(scene.train, scene.table, scene.center, r)
    assert row["photos"] == 6 and row["radius_m"] == pytest.approx(r)
    assert row["footprint_mm"] == pytest.approx(1000 * foot)
    # half the texels span the disc's diameter: 4 r / resolution a texel
    assert row["texel_256_mm"] == pytest.approx(1000 * 4 * r / 256)
    assert row["ratio_256"] == pytest.approx(2 * row["ratio_512"])
    assert row["ratio_512"] == pytest.approx(row["texel_512_mm"] / row["footprint_mm"])


def test_a_scene_without_a_table_has_no_footprint_and_the_table_shows_a_dash():
    scene = replace(tabletop_scene(n_train=3, n_val=0, size=16), table=None)
    row = tf.footprint_row("bare", scene, [512])
    assert row["footprint_mm"] is None and row["ratio_512"] is None
    text = tf.table_markdown([row], [512])
    assert text.splitlines()[2].startswith("| bare | 3 |") and text.splitlines()[2].endswith("| - |")
