"""A calibrated camera (OpenCV pinhole + distortion) and the camera file that stores it.

The camera file (JSON, written by ``nerfkit calibrate``) holds, among other things::

    "width", "height"            image size the calibration is for (upright photos)
    "K"                          3x3, OpenCV pixel convention (pixel centres at integers)
    "dist"                       [k1, k2, p1, p2, k3] (OpenCV order)
    "rms"                        RMS reprojection error in pixels
    "sensor_turns"               clockwise quarter turns from the photos as stored (the
                                 sensor's pixels) to the calibration's frame (EXIF orientation)
    "sanity"/"exif_focal_35mm"   the photos' EXIF focal length (35 mm equivalent): which lens

nerfkit's own convention puts pixel centres at +0.5, so its ``cx, cy`` are the file's plus
0.5 (:func:`nerfkit_K`). Nerfstudio and COLMAP use nerfkit's convention.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..config import load_json
from ..data.validate import MAX_SIDE, check_count, check_intrinsics, check_numbers, short_repr
from ..errors import advice, fail
from ..images import held_as

# Diagonal of a 36 x 24 mm film frame: fx ~= f35 * image_diagonal_px / 43.27.
FILM_DIAGONAL_MM = 43.2666
# Photos whose EXIF focal lengths (35 mm equivalent) differ by more than this share come
# from another lens or zoom (phones: 13, 26, 52, 77 mm ...), not from the same camera.
LENS_TOLERANCE = 0.05


@dataclass
class Camera:
    """Intrinsics of upright photos of one size.

    Attributes:
        K: (3, 3) float64, OpenCV convention (pixel centres at integers).
        dist: (5,) float64 k1, k2, p1, p2, k3.
        width, height: image size in pixels.
        source: where it came from (a file, or "EXIF ...").
        heldout_rms: the calibration's held-out reprojection error (px at this size), or
            None when unknown (EXIF focal length, old camera files).
        sensor_turns: clockwise quarter turns from the photos as stored (the sensor's
            pixels) to this camera's frame, from the EXIF orientation of the photos it was
            fitted to (0: held as the sensor is); None when unknown. A photo held the other
            way is turned into this frame by it.
        exif_f35: the EXIF focal length (35 mm equivalent) of the photos it was fitted to,
            or None: which lens (:func:`other_lens`).
    """

    K: np.ndarray
    dist: np.ndarray
    width: int
    height: int
    source: str = ""
    heldout_rms: float | None = None
    sensor_turns: int | None = None
    exif_f35: float | None = None

    @property
    def has_distortion(self) -> bool:
        return bool(np.any(np.abs(self.dist) > 0))

    def scaled_to(self, width: int, height: int) -> Camera:
        """The same camera for photos resized to ``width x height`` (same aspect ratio).

        Scaling happens in continuous coordinates: ``fx' = fx s``, ``cx' = (cx + 0.5) s - 0.5``.
        """
        sx, sy = width / self.width, height / self.height
        K = self.K.copy()
        K[0, 0] *= sx
        K[1, 1] *= sy
        K[0, 2] = (K[0, 2] + 0.5) * sx - 0.5
        K[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
        held = None if self.heldout_rms is None else self.heldout_rms * float(np.sqrt(sx * sy))
        return Camera(K, self.dist.copy(), width, height, self.source, held, self.sensor_turns, self.exif_f35)

    def compatible(self, width: int, height: int) -> str | None:
        """None when photos of this size can use this camera (same size or same aspect
        ratio), else the reason they cannot."""
        if (width, height) == (self.width, self.height):
            return None
        if (width, height) == (self.height, self.width):
            return (
                f"{held_as(width, height)} but the camera was calibrated on {self.width}x{self.height} "
                "photos: calibrate with photos held the same way"
            )
        if abs(width / height - self.width / self.height) < 0.005:
            return None
        return f"size {width}x{height} has a different aspect ratio from the camera's {self.width}x{self.height}"


def nerfkit_K(K_cv: np.ndarray) -> np.ndarray:
    """OpenCV-convention K -> nerfkit/nerfstudio convention (pixel centres at +0.5)."""
    K = np.array(K_cv, np.float64, copy=True)
    K[0, 2] += 0.5
    K[1, 2] += 0.5
    return K


def opencv_K(K_nk: np.ndarray) -> np.ndarray:
    """nerfkit/nerfstudio-convention K -> OpenCV convention (inverse of :func:`nerfkit_K`)."""
    K = np.array(K_nk, np.float64, copy=True)
    K[0, 2] -= 0.5
    K[1, 2] -= 0.5
    return K


def common_lens(f35s) -> float | None:
    """The most common of the photos' EXIF focal lengths ``f35s`` (None or 0 for photos
    without one), or None when none has one."""
    from collections import Counter

    lenses = Counter(f for f in f35s if f)
    return lenses.most_common(1)[0][0] if lenses else None


def other_lens(f35: float | None, camera_f35: float | None) -> str:
    """Why a photo with EXIF focal length ``f35`` (35 mm equivalent) cannot use a camera
    whose photos had ``camera_f35``, or "" (the same lens, or either unknown)."""
    if not f35 or not camera_f35 or abs(f35 / camera_f35 - 1) <= LENS_TOLERANCE:
        return ""
    return (
        f"taken at {f35:g} mm (EXIF, 35 mm equivalent) while the camera's photos were {camera_f35:g} mm: "
        "another lens or zoom. Take every photo with one lens, or calibrate this one"
    )


def exif_fx(f35: float, width: int, height: int) -> float:
    """Focal length in pixels implied by EXIF FocalLengthIn35mmFilm."""
    return float(f35) * float(np.hypot(width, height)) / FILM_DIAGONAL_MM


def image_centre(width: int, height: int) -> tuple[float, float]:
    """The image's centre in OpenCV's pixel convention (pixel centres at integers), where
    calibrateCamera starts the principal point: ``((width - 1) / 2, (height - 1) / 2)``."""
    return (width - 1) / 2.0, (height - 1) / 2.0


# A lens's principal point lies within a few percent of the frame's centre and a phone's pixels
# are square to a few percent; a fit far beyond either is the noise of too few, or too alike,
# photos (8 photos of one sheet gave fx/fy 0.81 and a principal point outside the frame).
MAX_CENTRE_OFFSET = 0.15  # of the frame's width or height
MAX_ASPECT_OFFSET = 0.10  # |fx / fy - 1|


def implausible(K: np.ndarray, size: tuple[int, int], centre: bool = True, aspect: bool = True) -> str:
    """Why a fitted camera ``K`` of ``size`` (w, h) photos is no lens's (with ``centre``, its
    principal point more than :data:`MAX_CENTRE_OFFSET` of the frame off the centre; with
    ``aspect``, pixels more than :data:`MAX_ASPECT_OFFSET` from square), or ""."""
    w, h = size
    cx0, cy0 = image_centre(w, h)
    off = max(abs(K[0, 2] - cx0) / w, abs(K[1, 2] - cy0) / h)
    if centre and off > MAX_CENTRE_OFFSET:
        return (
            f"its principal point ({K[0, 2]:.0f}, {K[1, 2]:.0f}) lies {off:.0%} of the frame off the centre "
            f"(a lens's lies within {MAX_CENTRE_OFFSET:.0%}): too few or too alike photos"
        )
    ratio = K[0, 0] / K[1, 1]
    if aspect and abs(ratio - 1) > MAX_ASPECT_OFFSET:
        return (
            f"its pixels are {ratio:.2f} times as wide as tall (a phone's are square to "
            f"{MAX_ASPECT_OFFSET:.0%}): too few or too alike photos"
        )
    return ""


def camera_from_focal(fx: float, width: int, height: int, source: str) -> Camera:
    """A distortion-free camera with square pixels and the principal point at the centre."""
    cx, cy = image_centre(width, height)
    K = np.array([[fx, 0, cx], [0, fx, cy], [0, 0, 1]], np.float64)
    return Camera(K, np.zeros(5), width, height, source)


def camera_from_dict(data, where: str, source: str | None = None) -> Camera:
    """A :class:`Camera` from camera-file keys (K, dist, width, height), every value checked."""
    if not isinstance(data, dict):
        raise fail(where, f"a camera must be a JSON object with K, dist, width and height, got {type(data).__name__}")
    for key in ("K", "dist", "width", "height"):
        if key not in data:
            raise fail(where, f"the camera is missing '{key}'")
    width = check_count(data["width"], where, "width", 1, MAX_SIDE)
    height = check_count(data["height"], where, "height", 1, MAX_SIDE)
    K = check_numbers(data["K"], where, "K")
    if K.shape != (3, 3):
        raise fail(where, f"'K' has shape {K.shape}, expected 3x3 [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]")
    if not np.array_equal(K[2], [0, 0, 1]):
        raise fail(where, f"'K' has the bottom row {short_repr(K[2].tolist())}, expected exactly [0, 0, 1]")
    check_intrinsics(K, where, "K", width, height)  # positive focal lengths, no skew
    problem = implausible(K, (width, height)).replace(": too few or too alike photos", "")
    if problem:
        raise fail(
            where,
            f"the camera of {width}x{height} photos is no lens's: {problem}",
            "Check that width and height are those K was calibrated at, or calibrate again with 20-50 photos",
        )
    dist = check_numbers(data["dist"], where, "dist").ravel()
    if dist.size not in (0, 4, 5, 8, 12, 14):
        raise fail(where, f"'dist' must hold 4, 5, 8, 12 or 14 OpenCV coefficients, got {dist.size}")
    if dist.size > 5 and np.any(dist[5:] != 0):
        raise fail(where, "only the k1, k2, p1, p2, k3 distortion model is supported")
    dist = np.pad(dist[:5], (0, 5 - min(dist.size, 5)))
    held = data.get("heldout_rms")
    held = float(held) if isinstance(held, (int, float)) and not isinstance(held, bool) and 0 < held < 1e4 else None
    turns = data.get("sensor_turns")
    turns = turns if isinstance(turns, int) and not isinstance(turns, bool) and 0 <= turns < 4 else None
    f35 = data.get("sanity", {}).get("exif_focal_35mm") if isinstance(data.get("sanity"), dict) else None
    f35 = float(f35) if isinstance(f35, (int, float)) and not isinstance(f35, bool) and 0 < f35 < 1e4 else None
    return Camera(K, dist, width, height, str(where) if source is None else source, held, turns, f35)


def load_camera(path: str | Path) -> Camera:
    """Read a camera file written by ``nerfkit calibrate`` (or the same keys by hand)."""
    path = Path(path)
    data = load_json(
        path,
        "no such camera file",
        "Run nerfkit calibrate first, or omit --camera to use the EXIF focal length",
        "Re-run nerfkit calibrate",
    )
    other = _other_nerfkit_file(data)
    if other is not None:
        raise fail(
            path,
            f"is {other}, not a camera file",
            "Give the camera.json that nerfkit calibrate wrote (or run it on the sheet's photos)",
        )
    with advice("Re-run nerfkit calibrate, or fix the file by hand"):
        return camera_from_dict(data, str(path))


def _other_nerfkit_file(data: object) -> str | None:
    """What ``data`` (a JSON document without a camera's ``K``) is when another nerfkit file:
    the poses report, a detection cache, a capture's record, a run's config; else None."""
    if not isinstance(data, dict) or "K" in data:
        return None
    if data.get("format") == "nerfkit-poses":
        return "the report `nerfkit poses` writes (poses.json)"
    if "photos" in data and "settings" in data:
        return "a cache of tag detections (*.detections.json)"
    if set(data) == {"inputs"}:
        return "a capture's record of its inputs (capture.json)"
    if "train" in data and "bounds" in data:
        return "a trained run's config.json"
    return None
