"""Where the photos of an object look from, and the widest patch of directions none covers.

A view of the object from a direction no training photo is near is interpolated across a gap:
there the renders blur and ghost. The gap is measured on the sphere of view directions around
the object's centre, within the band of elevations the photos themselves span (a capture is
not expected to look from under the table, nor higher than its highest photo).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..cameras import axes_across

# a gap wider than this (its radius: from its centre to the nearest photo) is worth filling
WIDE_GAP_DEG = 30.0
# held-out photos "open" a gap when the training photos' gap is this much wider than the capture's
OPENED_BY_DEG = 5.0
# directions of the search grid compared with every photo at once
GRID_CHUNK = 4096


@dataclass(frozen=True)
class Gap:
    """The widest patch of view directions with no photo: a spherical cap around ``direction``
    whose ``radius_deg`` is the angle to the nearest photo. ``azimuth_deg`` is measured about the
    up axis from the world's +x (a tag's right), ``elevation_deg`` above the table's plane;
    ``nearest`` names the photos nearest to its centre, nearest first."""

    radius_deg: float
    direction: np.ndarray
    azimuth_deg: float
    elevation_deg: float
    nearest: tuple[str, ...]


def view_directions(c2w: np.ndarray, center: np.ndarray) -> np.ndarray:
    """(n, 3) unit vectors from ``center`` to each camera of ``c2w`` (n, 4, 4)."""
    d = np.asarray(c2w, np.float64)[:, :3, 3] - np.asarray(center, np.float64)
    return d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)


def elevations_deg(directions: np.ndarray, up: np.ndarray) -> np.ndarray:
    """(n,) angle of each unit direction above the plane normal to ``up``, degrees."""
    return np.degrees(np.arcsin(np.clip(directions @ up_axes(up)[0], -1.0, 1.0)))


def up_axes(up: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(up, e1, e2): the unit up vector and two unit axes across it, e1 along the world's +x
    projected (+y when up is along x) and e2 = up x e1 (counter-clockwise seen from above)."""
    u = np.asarray(up, np.float64) / np.linalg.norm(up)
    a, b = axes_across(u)  # the orbit's axes: b = u x a is minus +x projected, so e1 = -b and e2 = a
    return u, -b, a


def azimuths_deg(directions: np.ndarray, up: np.ndarray) -> np.ndarray:
    """(n,) angle of each direction about ``up``, from :func:`up_axes`'s e1 toward e2, in
    (-180, 180]."""
    _, e1, e2 = up_axes(up)
    return np.degrees(np.arctan2(directions @ e2, directions @ e1))


def band_directions(up: np.ndarray, band: tuple[float, float], step_deg: float = 1.0) -> np.ndarray:
    """(m, 3) unit vectors on a grid of azimuth and elevation, ``step_deg`` apart or closer,
    covering the elevations ``band`` (lo, hi degrees) about ``up``, both ends included."""
    u, e1, e2 = up_axes(up)
    rows = max(1, int(np.ceil((band[1] - band[0]) / step_deg)) + 1)
    el = np.radians(np.linspace(band[0], band[1], rows))
    az = np.radians(np.arange(0.0, 360.0, step_deg))
    el, az = np.meshgrid(el, az, indexing="ij")
    flat = np.cos(az)[..., None] * e1 + np.sin(az)[..., None] * e2
    return (np.cos(el)[..., None] * flat + np.sin(el)[..., None] * u).reshape(-1, 3)


def widest_gap(
    directions: np.ndarray, names: list[str], up: np.ndarray, band: tuple[float, float], step_deg: float = 1.0
) -> Gap:
    """The widest cap of view directions, centred within the elevations ``band`` (lo, hi degrees),
    that holds none of ``directions`` (n, 3) (unit vectors of the photos called ``names``).

    The centre is searched on a grid ``step_deg`` apart, so the radius is within about half a
    step of the largest."""
    if len(directions) == 0:
        raise ValueError("no photos to measure coverage from")
    grid = band_directions(up, band, step_deg)
    dirs = np.asarray(directions, np.float64)
    # the largest cosine to any photo is the nearest photo's; in chunks, so that thousands of
    # photos need no (grid x photos) array
    closest = np.concatenate([(grid[i : i + GRID_CHUNK] @ dirs.T).max(axis=1) for i in range(0, len(grid), GRID_CHUNK)])
    k = int(closest.argmin())
    centre = grid[k]
    angles = np.degrees(np.arccos(np.clip(dirs @ centre, -1.0, 1.0)))
    order = np.argsort(angles)[:3]
    return Gap(
        radius_deg=float(angles[order[0]]),
        direction=centre,
        azimuth_deg=float(azimuths_deg(centre[None], up)[0]),
        elevation_deg=float(elevations_deg(centre[None], up)[0]),
        nearest=tuple(str(names[j]) for j in order),
    )


@dataclass(frozen=True)
class Coverage:
    """How the photos of a dataset surround its object: the widest gap among all of them
    (``capture``) and among the training photos (``train``), and the held-out photos taken
    inside the training photos' gap: (name, split, angle to the nearest training photo in
    degrees)."""

    band: tuple[float, float]
    capture: Gap
    train: Gap
    held_out_in_gap: tuple[tuple[str, str, float], ...]
    azimuth_elevation: dict[str, np.ndarray]  # split -> (n, 2) each photo's azimuth and elevation, degrees

    def as_json(self) -> dict:
        def gap(g: Gap) -> dict:
            return {
                "radius_deg": round(g.radius_deg, 1),
                "azimuth_deg": round(g.azimuth_deg, 1),
                "elevation_deg": round(g.elevation_deg, 1),
                "nearest_photos": list(g.nearest),
            }

        return {
            "elevations_deg": [round(self.band[0], 1), round(self.band[1], 1)],
            "widest_gap": gap(self.capture),
            "widest_gap_of_training_photos": gap(self.train),
            "held_out_in_that_gap": [
                {"photo": n, "split": s, "nearest_training_photo_deg": round(a, 1)} for n, s, a in self.held_out_in_gap
            ],
        }


def measure_coverage(splits: dict[str, tuple[np.ndarray, list[str]]], center: np.ndarray, up: np.ndarray) -> Coverage:
    """Coverage of the photos of ``splits`` (split name -> (c2w (n, 4, 4), names)) around
    ``center``, with ``up`` the scene's up. Needs at least one training photo."""
    dirs = {s: view_directions(c2w, center) for s, (c2w, _) in splits.items() if len(c2w)}
    names = {s: list(splits[s][1]) for s in dirs}
    every = np.concatenate(list(dirs.values()))
    every_name = sum(names.values(), [])
    el = elevations_deg(every, up)
    band = (float(el.min()), float(el.max()))
    capture = widest_gap(every, every_name, up, band)
    train = widest_gap(dirs["train"], names["train"], up, band)
    inside = []
    for s in dirs:
        if s == "train":
            continue
        within = np.degrees(np.arccos(np.clip(dirs[s] @ train.direction, -1.0, 1.0))) < train.radius_deg
        to_train = np.degrees(np.arccos(np.clip(dirs[s] @ dirs["train"].T, -1.0, 1.0))).min(axis=1)
        inside += [(str(n), s, float(a)) for n, w, a in zip(names[s], within, to_train) if w]
    where = {s: np.column_stack([azimuths_deg(d, up), elevations_deg(d, up)]) for s, d in dirs.items()}
    return Coverage(band, capture, train, tuple(inside), where)


def cap_outline(gap: Gap, up: np.ndarray, n: int = 120) -> np.ndarray:
    """(n + 1, 2) azimuth and elevation (degrees) of the closed circle bounding ``gap``'s cap."""
    c = gap.direction / np.linalg.norm(gap.direction)
    a = np.cross(c, up_axes(up)[0])
    a = a / np.linalg.norm(a) if np.linalg.norm(a) > 1e-9 else up_axes(c)[1]
    b = np.cross(c, a)
    r = np.radians(gap.radius_deg)
    phi = np.linspace(0.0, 2.0 * np.pi, n + 1)
    d = np.cos(r) * c + np.sin(r) * (np.cos(phi)[:, None] * a + np.sin(phi)[:, None] * b)
    return np.column_stack([azimuths_deg(d, up), elevations_deg(d, up)])


def coverage_notes(coverage: dict) -> list[str]:
    """What a user should know of a :meth:`Coverage.as_json`: how closely the photos surround the
    object, whether held-out photos left a gap open, and where a photo would fill a wide gap."""
    lo, hi = coverage["elevations_deg"]
    c, t = coverage["widest_gap"], coverage["widest_gap_of_training_photos"]
    lines = [
        f"coverage: the photos look from {lo:.0f} to {hi:.0f} degrees above the horizontal; every direction there "
        f"is within {c['radius_deg']:.0f} degrees of a photo, and within {t['radius_deg']:.0f} of a training "
        "photo"
    ]
    held = coverage["held_out_in_that_gap"]
    if held and t["radius_deg"] >= c["radius_deg"] + OPENED_BY_DEG:
        each = [f"{h['photo']} ({h['split']})" for h in held]
        names = each[0] if len(each) == 1 else f"{', '.join(each[:-1])} and {each[-1]}"
        near = sorted(h["nearest_training_photo_deg"] for h in held)
        span = f"{near[0]:.0f}" if round(near[0]) == round(near[-1]) else f"{near[0]:.0f}-{near[-1]:.0f}"
        lines.append(
            f"  held out, {names} leave{'s' if len(held) == 1 else ''} the training photos' widest gap open: "
            f"{t['elevation_deg']:.0f} degrees up, azimuth {t['azimuth_deg']:.0f} (nearest training photos "
            f"{', '.join(t['nearest_photos'][:2])}; {span} degrees from the held-out "
            f"{'one' if len(held) == 1 else 'ones'})"
        )
    if c["radius_deg"] > WIDE_GAP_DEG:
        lines.append(
            f"  no photo looks from within {c['radius_deg']:.0f} degrees of {c['elevation_deg']:.0f} degrees "
            f"up, azimuth {c['azimuth_deg']:.0f} (nearest photos: {', '.join(c['nearest_photos'][:2])}): "
            "views from there will blur; photos from there would fill the gap"
        )
    return lines
