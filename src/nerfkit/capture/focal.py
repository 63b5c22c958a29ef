"""The camera file's focal length against the one the object photos themselves want.

A camera file calibrated with another phone, another lens (0.5x, 1x, 3x), another zoom, or at
another resolution or orientation than the object photos poses them with the wrong focal
length: the tag poses' distances, the scene's scale and every ray come out wrong, and nothing
else says so. ``nerfkit poses`` has two estimates of the photos' own focal length at hand:

- the tags' (:func:`~nerfkit.capture.poses.tag_focal`): the photos' tag corners fitted with the
  focal length free and the camera file's principal point and distortion, with its standard
  error. It is the one comparable with the camera file's, lens model for lens model;
- structure-from-motion's (``--method auto`` and ``colmap``): bundle adjustment refines the
  focal length, with one radial term of its own, over thousands of feature tracks. It does not
  depend on where it starts: on sreeram's photos it ends at 1554.1 px from the calibrated
  1564.6 px and at 1554.0 px from a focal length 20% longer (steve 807.0 px from both,
  labubu 219.6 / 219.9 px).

:func:`focal_check` compares the first that is pinned (the tags' to :data:`TAGS_PINNED`, else
SfM's, else the tags' however loosely) with the camera file's, the other beside it. They may
differ a little with the right camera file: a phone focused nearer than when it photographed the
sheet has a longer focal length (a thin 5.1 mm lens focused at 10 cm instead of 30 cm: 3.6%
longer), and SfM's radial term takes up part of the focal length (its k1 -0.04 on labubu, whose
calibration has none). On the dev captures, each calibrated with its own photos of the sheet, the
tags want 1.013, 1.029 and 0.999 times the camera file's focal length (sreeram, steve, labubu)
and SfM 0.993, 1.043 and 1.036; with camera files 20% long, 0.844, 0.863 and 0.832 and SfM
0.828, 0.869 and 0.864 (``nerfkit poses``, ``--method auto``). So the estimate must be off by
more than :data:`FOCAL_AGREE`, and by more than :data:`FOCAL_SIGMAS` of its standard error where
it has one, before the check warns. Another lens or zoom is off by 30% or more; another phone's
main lens often by 8% or more (24, 26 and 28 mm equivalents), though some differ by less.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .camera import Camera
    from .poses import TagFocal

# The photos' focal length and the camera file's agree within this share: focusing nearer
# moves a phone's focal length by up to 4%, SfM's lens model by a few percent more (the dev
# captures with their own camera files: up to 4.3% apart, see the module's docstring).
FOCAL_AGREE = 0.06
# ... and within this many standard errors of the estimate, where it has one.
FOCAL_SIGMAS = 3.0
# An estimate counts from this many photos (the tags' focal length needs as many: poses.FOCAL_MIN_PHOTOS).
MIN_PHOTOS = 8
# The tags' estimate comes first when its standard error is at most this share (poses.FOCAL_MAX_STD:
# what refining the focal length on them asks).
TAGS_PINNED = 0.01


def focal_tolerance(std: float | None) -> float:
    """How far (a share) the photos' focal length may lie from the camera file's before it
    counts as another camera: :data:`FOCAL_AGREE`, or :data:`FOCAL_SIGMAS` times the
    estimate's relative standard error ``std`` when that is more."""
    if std is None or not math.isfinite(std):
        return FOCAL_AGREE
    return max(FOCAL_AGREE, FOCAL_SIGMAS * std)


@dataclass(frozen=True)
class FocalCheck:
    """The camera file's focal length against the photos' own.

    Attributes:
        camera_px: the camera file's fx, in pixels of the photos' size.
        photos_px: the focal length the photos want, at the same size.
        source: which estimate ("structure-from-motion", "the tags").
        photos: how many photos it comes from.
        std: its relative standard error, or None when unknown.
        other: the other estimate, when there is one: ``{"source", "photos_px", "ratio", ...}``.
    """

    camera_px: float
    photos_px: float
    source: str
    photos: int
    std: float | None = None
    other: dict | None = None

    @property
    def ratio(self) -> float:
        """The photos' focal length over the camera file's."""
        return self.photos_px / self.camera_px

    @property
    def tolerance(self) -> float:
        return focal_tolerance(self.std)

    @property
    def disagree(self) -> bool:
        """Whether the two lie further apart than :func:`focal_tolerance` allows."""
        return not abs(self.ratio - 1.0) <= self.tolerance

    def line(self) -> str:
        """One line for the report: both focal lengths, their ratio and, when they disagree, a
        warning with what it likely means and what to do."""
        pm = f", +/- {self.std * 100:.2f}%" if self.std is not None else ""
        said = (
            f"focal length: the camera file's {self.camera_px:.1f} px, the photos' own {self.photos_px:.1f} px "
            f"({self.source}, {self.photos} photos{pm}): ratio {self.ratio:.3f} (photos' / file's)"
        )
        if self.other is not None:
            o = self.other
            said += f" ({o['source']}: {o['photos_px']:.1f} px, ratio {o['ratio']:.3f})"
        if not self.disagree:
            return f"{said}, within {self.tolerance * 100:.0f}%"
        return (
            f"WARNING: {said}, {abs(self.ratio - 1) * 100:.0f}% apart, more than the {self.tolerance * 100:.0f}% "
            "that focusing and the fit allow. The camera file is likely of another phone, lens (1x/0.5x/3x), zoom, "
            "orientation or resolution than these photos: what is posed with it is off. Calibrate again with the "
            "same phone, lens, zoom, orientation and resolution as these photos, or run without --camera"
        )

    @staticmethod
    def from_json(data: dict) -> FocalCheck:
        """The check :meth:`as_json` wrote."""
        return FocalCheck(
            float(data["camera_px"]),
            float(data["photos_px"]),
            str(data["source"]),
            int(data["photos"]),
            None if data.get("std") is None else float(data["std"]),
            data.get("other"),
        )

    def as_json(self) -> dict:
        return {
            "camera_px": round(self.camera_px, 2),
            "photos_px": round(self.photos_px, 2),
            "ratio": round(self.ratio, 4),
            "source": self.source,
            "photos": self.photos,
            "std": None if self.std is None else round(self.std, 5),
            "tolerance": round(self.tolerance, 4),
            "disagree": self.disagree,
            "other": self.other,
        }


def check_focal(
    camera_px: float,
    estimates: list[tuple[str, float, int, float | None]],
) -> FocalCheck | None:
    """The camera file's focal length ``camera_px`` against the photos' own: the first of
    ``estimates`` (``(source, focal px, photos, relative std or None)``, the most trusted first:
    structure-from-motion's, then the tags'), with the second beside it; None without any."""
    if not estimates:
        return None
    (source, focal, photos, std), *rest = estimates
    other = None
    if rest:
        s, f, n, sd = rest[0]
        other = {
            "source": s,
            "photos_px": round(f, 2),
            "ratio": round(f / camera_px, 4),
            "photos": n,
            "std": None if sd is None else round(sd, 5),
        }
    return FocalCheck(camera_px, focal, source, photos, std, other)


SFM = "structure-from-motion"
TAGS = "the tags"


def focal_check(
    camera: Camera | None, tags: TagFocal | None = None, sfm: tuple[float, int, int, int] | None = None
) -> FocalCheck | None:
    """The camera file's ``camera`` against the focal length the photos want (:func:`check_focal`):
    the tags' (``tags``, :func:`~nerfkit.capture.poses.tag_focal`, at the camera's size) when they
    pin it to :data:`TAGS_PINNED`, else structure-from-motion's (``sfm``: ``(fx, width, height,
    photos registered)`` of its shared camera), else the tags' however loose; the other beside it.
    None without a camera file or an estimate. Estimates from fewer than :data:`MIN_PHOTOS` photos
    are left out."""
    if camera is None:
        return None
    estimates: list[tuple[str, float, int, float | None]] = []
    if tags is not None and tags.photos >= MIN_PHOTOS:
        estimates.append((TAGS, tags.focal_px, tags.photos, tags.std))
    if sfm is not None and sfm[3] >= MIN_PHOTOS:
        fx, width, _, n = sfm
        by_sfm = (SFM, fx * camera.width / width, n, None)
        pinned = bool(estimates) and tags is not None and tags.std <= TAGS_PINNED
        estimates.insert(len(estimates) if pinned else 0, by_sfm)
    return check_focal(float(camera.K[0, 0]), estimates)
