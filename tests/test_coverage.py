"""Coverage of the view sphere: the widest gap among the photos, found against analytic rings."""

import numpy as np
import pytest

from nerfkit.capture.coverage import (
    WIDE_GAP_DEG,
    azimuths_deg,
    cap_outline,
    coverage_notes,
    elevations_deg,
    measure_coverage,
    widest_gap,
)

UP = np.array([0.0, 0.0, 1.0])


def ring(azimuths_deg, elevation_deg: float, radius: float = 0.3) -> np.ndarray:
    """(n, 4, 4) cameras at ``radius`` from the origin, at the given azimuths and one elevation."""
    a, e = np.radians(np.asarray(azimuths_deg, np.float64)), np.radians(elevation_deg)
    c2w = np.tile(np.eye(4), (len(a), 1, 1))
    c2w[:, :3, 3] = radius * np.column_stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.full(len(a), np.sin(e))])
    return c2w


def angle_on_ring(step_deg: float, elevation_deg: float) -> float:
    """Angle (degrees) between two directions at one elevation, ``step_deg`` apart in azimuth."""
    e = np.radians(elevation_deg)
    return float(np.degrees(np.arccos(np.sin(e) ** 2 + np.cos(e) ** 2 * np.cos(np.radians(step_deg)))))


def test_azimuth_and_elevation_follow_the_documented_axes():
    d = np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [-1.0, 0, 0], [0.5, 0, 0.5 * 3**0.5]])
    np.testing.assert_allclose(elevations_deg(d, UP), [0, 0, 90, 0, 60], atol=1e-9)
    np.testing.assert_allclose(azimuths_deg(d[[0, 1, 3]], UP), [0, 90, 180], atol=1e-9)
    # another up: elevation is measured from the plane across it
    np.testing.assert_allclose(elevations_deg(d[:2], np.array([0.0, 2.0, 0.0])), [0, 90], atol=1e-9)


def test_an_even_ring_has_its_gaps_midway_between_photos():
    c2w = ring(np.arange(0, 360, 30), 30.0)
    dirs = c2w[:, :3, 3] / 0.3
    gap = widest_gap(dirs, [f"p{i}" for i in range(12)], UP, (30.0, 30.0))
    assert gap.radius_deg == pytest.approx(angle_on_ring(15, 30), abs=0.3)  # 12.98
    off = (gap.azimuth_deg - 15 + 15) % 30 - 15  # from the nearest midway azimuth (15, 45, ...)
    assert off == pytest.approx(0, abs=1.0) and gap.elevation_deg == pytest.approx(30)


def test_a_missing_photo_is_the_gap_and_its_neighbours_are_named():
    az = [a for a in range(0, 360, 30) if a != 90]
    dirs = ring(az, 30.0)[:, :3, 3] / 0.3
    gap = widest_gap(dirs, [f"az{a}" for a in az], UP, (30.0, 30.0))
    assert gap.radius_deg == pytest.approx(angle_on_ring(30, 30), abs=0.3)  # 25.9
    assert gap.azimuth_deg == pytest.approx(90, abs=1.0)
    assert set(gap.nearest[:2]) == {"az60", "az120"}


def test_a_cap_outline_lies_at_the_gaps_radius_from_its_centre():
    dirs = ring([0, 120, 240], 20.0)[:, :3, 3] / 0.3
    gap = widest_gap(dirs, ["a", "b", "c"], UP, (10.0, 50.0))
    ae = np.radians(cap_outline(gap, UP))
    d = np.column_stack([np.cos(ae[:, 1]) * np.cos(ae[:, 0]), np.cos(ae[:, 1]) * np.sin(ae[:, 0]), np.sin(ae[:, 1])])
    np.testing.assert_allclose(np.degrees(np.arccos(np.clip(d @ gap.direction, -1, 1))), gap.radius_deg, atol=1e-6)
    # no photo inside the cap, and one on its rim
    inside = np.degrees(np.arccos(np.clip(dirs @ gap.direction, -1, 1)))
    assert inside.min() == pytest.approx(gap.radius_deg, abs=1e-9)


def test_a_held_out_photo_that_was_the_only_one_there_is_named():
    az = np.arange(0, 360, 30)
    low, high = ring(az, 30.0), ring(az + 15, 60.0)
    names = [f"low{a}" for a in az]
    val = [3]  # low90
    splits = {
        "train": (
            np.concatenate([np.delete(low, val, 0), high]),
            [n for i, n in enumerate(names) if i not in val] + [f"high{a + 15}" for a in az],
        ),
        "val": (low[val], [names[i] for i in val]),
    }
    cov = measure_coverage(splits, np.zeros(3), UP)
    assert cov.band == pytest.approx((30.0, 60.0))
    assert cov.train.radius_deg > cov.capture.radius_deg + 5
    assert cov.train.azimuth_deg == pytest.approx(90, abs=8) and cov.train.elevation_deg < 45
    assert [(n, s) for n, s, _ in cov.held_out_in_gap] == [("low90", "val")]
    assert cov.held_out_in_gap[0][2] == pytest.approx(angle_on_ring(30, 30), abs=1e-6)  # its neighbours on the ring
    notes = coverage_notes(cov.as_json())
    assert len(notes) == 2 and "low90 (val)" in notes[1]
    # held out from a well-covered place, it opens no gap and gets no note
    splits["val"] = (high[:1], ["high15"])
    splits["train"] = (np.concatenate([low, high[1:]]), names + [f"high{a + 15}" for a in az[1:]])
    assert len(coverage_notes(measure_coverage(splits, np.zeros(3), UP).as_json())) == 1


def test_photos_from_one_side_only_get_advice_where_to_add_some():
    az = np.arange(-60, 61, 20)
    splits = {"train": (np.concatenate([ring(az, 25.0), ring(az, 50.0)]), [f"p{i}" for i in range(2 * len(az))])}
    cov = measure_coverage(splits, np.zeros(3), UP)
    assert cov.capture.radius_deg > WIDE_GAP_DEG
    assert abs(cov.capture.azimuth_deg) > 120  # behind the object
    notes = coverage_notes(cov.as_json())
    assert any("would fill the gap" in n for n in notes)
