"""How well a capture's photos agree on its table: a ceiling for held-out scores.

A NeRF draws each point of the table in one colour, or one that changes smoothly with the
view. If the photos themselves show a point in different colours (the phone's exposure and
white balance changing between shots, the photographer's shadow, a lamp mirrored in a
varnished table), no scene matches them all, and a held-out photo differs from any render
by about as much as the photos differ from each other. Measured before training: project a
grid of points on the table plane around the object into every training photo, and take
the RMS difference of each photo's colour at a point from the mean colour of the photos
that see it, as a PSNR. It is a rough ceiling: a 3-minute run's held-out PSNR comes close to
it when the photos cover the object well and stays under it with few photos
(`benchmarks/photo_consistency.py` prints both side by side).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..cameras import axes_across, project_points
from ..images import sample_bilinear

# below this agreement the photos cannot be matched to the 22 dB that a usable capture's
# held-out views reach, and the notes give advice (benchmarks/photo_consistency.py; figures in BENCHMARKS.md)
AGREEMENT_NOTE_DB = 22.0
# the table's square reaches this many object radii from the object's foot
EXTENT_RADII = 1.4
# a point counts when at least this many photos see it
MIN_PHOTOS = 3
# rounds of the alternating solve of each photo's exposure: the solve settles within a few rounds, and more
# change the agreement by a negligible amount (benchmarks/photo_consistency.py)
EXPOSURE_ROUNDS = 5
# the notes advise locking the exposure too when evening it out gains this much
EXPOSURE_SHARE_DB = 1.0


@dataclass(frozen=True)
class Agreement:
    """``psnr``: the training photos' RMS difference from the table's mean colour at
    ``points`` points of the plane (a square of half-width ``half_width`` scene units
    around the object's foot, each seen by ``photos_per_point`` photos, median), in dB;
    ``psnr_exposure_evened``: the same with each photo's gain per channel (exposure and
    white balance) solved to agree best (:func:`even_exposures`)."""

    psnr: float
    psnr_exposure_evened: float
    points: int
    photos_per_point: float
    half_width: float

    def as_json(self) -> dict:
        return {
            "psnr": round(self.psnr, 2),
            "psnr_exposure_evened": round(self.psnr_exposure_evened, 2),
            "points": self.points,
            "photos_per_point": self.photos_per_point,
            "half_width": round(self.half_width, 4),
            "what": "each training photo's RMS colour difference, over the table points it sees, from the mean "
            "colour of the photos that see each point (a static scene scores about this on held-out "
            "photos); evened: the same with a gain per photo and channel solved to agree best",
        }


def table_points(center: np.ndarray, table: np.ndarray, extent: float, n: int, box=None) -> np.ndarray:
    """(m, 3) points of an ``n x n`` grid on the table plane ``table`` (4,) within
    ``extent`` of the foot of ``center``, less those under the object's ``box``
    (``(lo, hi)`` or None)."""
    normal, d = np.asarray(table[:3], np.float64), float(table[3])
    center = np.asarray(center, np.float64)
    foot = center - (center @ normal + d) * normal
    e1, e2 = axes_across(normal)
    g = np.linspace(-extent, extent, n)
    a, b = np.meshgrid(g, g)
    p = foot + a.reshape(-1, 1) * e1 + b.reshape(-1, 1) * e2
    if box is not None:
        lo, hi = np.asarray(box[0]) - 0.01 * extent, np.asarray(box[1]) + 0.01 * extent
        p = p[~np.all((p[:, :2] > lo[:2]) & (p[:, :2] < hi[:2]), axis=1)]
    return p


def sample_photo(
    image: np.ndarray, K: np.ndarray, c2w: np.ndarray, points: np.ndarray, box=None, blur: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Colours (m, 3) in [0, 1] of world ``points`` (m, 3) in one photo (bilinear; ``K``
    in nerfkit's convention, pixel centres at +0.5) and where they are seen (m,): in front
    of the camera, inside the frame, and the line of sight clear of the object's ``box``."""
    import cv2

    uv, z = project_points(K, c2w, points)
    seen = z > 1e-6
    h, w = image.shape[:2]
    seen &= (uv[:, 0] > 1) & (uv[:, 0] < w - 2) & (uv[:, 1] > 1) & (uv[:, 1] < h - 2)
    if box is not None:  # the object may stand in the way: walk the line of sight
        lo, hi = np.asarray(box[0]), np.asarray(box[1])
        for s in np.linspace(0.02, 0.98, 25):
            q = c2w[:3, 3] + s * (points - c2w[:3, 3])
            seen &= ~np.all((q > lo) & (q < hi), axis=1)
    img: np.ndarray = image.astype(np.float32) / 255.0
    if blur > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur)
    return sample_bilinear(img, uv), seen


def samples(views, points: np.ndarray, box=None, blur: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Colours (n, m, 3) of ``points`` (m, 3) in each of ``views``' n photos and where each
    photo sees them (n, m) as 0/1 (:func:`sample_photo`)."""
    cols, seen = zip(
        *(sample_photo(views.images[i], views.K[i], views.c2w[i], points, box, blur) for i in range(len(views)))
    )
    return np.stack(cols), np.stack(seen).astype(np.float32)


def deviations(C: np.ndarray, S: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Of colours ``C`` (n, m, 3) seen where ``S`` (n, m): the mean colour (m, 3) over the
    photos that see each point, their number (m,) and each photo's squared deviation from
    that mean (n, m; mean over channels, 0 where unseen)."""
    count = S.sum(0)
    mean = (C * S[..., None]).sum(0) / np.maximum(count, 1)[:, None]
    return mean, count, ((C - mean) ** 2).mean(-1) * S


def consistency(
    views, points: np.ndarray, box=None, blur: float = 0.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Of ``points`` (m, 3) in ``views``' photos: the mean colour (m, 3) over the photos
    that see each point, their number (m,), each photo's squared deviation from that mean
    (n, m; mean over channels, 0 where unseen) and where each is seen (n, m) as 0/1."""
    C, S = samples(views, points, box, blur)
    return (*deviations(C, S), S)


def even_exposures(C: np.ndarray, S: np.ndarray, rounds: int = EXPOSURE_ROUNDS) -> np.ndarray:
    """(n, 3) a gain per photo and channel that brings the colours ``C`` (n, m, 3), seen
    where ``S`` (n, m), closest to their mean at each point (alternating least squares:
    the means, then each photo's gains against them), their geometric mean over the photos
    1: what locking the phone's exposure and white balance would have saved."""
    gains = np.ones((len(C), 3))
    for _ in range(rounds):
        mean = deviations(C * gains[:, None], S)[0]
        xx = np.einsum("nm,nmc,nmc->nc", S, C, C)
        gains = np.where(xx > 1e-12, np.einsum("nm,nmc,mc->nc", S, C, mean) / np.maximum(xx, 1e-12), 1.0)
        gains /= np.exp(np.log(np.maximum(gains, 1e-6)).mean(0))
    return gains


def psnr_of(mse: float) -> float:
    return float(-10.0 * np.log10(max(mse, 1e-12)))


def measure_agreement(
    views, center: np.ndarray, table: np.ndarray, radius: float, box=None, grid: int = 201
) -> Agreement | None:
    """:class:`Agreement` of ``views`` (the training photos) on the ``table`` plane around
    the object (``center``, ``radius``: the square reaches :data:`EXTENT_RADII` radii;
    ``box``: the object's, whose points and lines of sight are left out), or None when no
    point is seen by :data:`MIN_PHOTOS` photos."""
    if len(views) < MIN_PHOTOS:
        return None
    extent = EXTENT_RADII * float(radius)
    pts = table_points(center, table, extent, grid, box)
    C, S = samples(views, pts, box)
    good = S.sum(0) >= MIN_PHOTOS
    if not good.any():
        return None
    C, S = C[:, good], S[:, good]
    _, count, dev = deviations(C, S)
    evened = deviations(C * even_exposures(C, S)[:, None], S)[2]
    return Agreement(
        psnr_of(dev.sum() / S.sum()), psnr_of(evened.sum() / S.sum()), int(good.sum()), float(np.median(count)), extent
    )


def agreement_notes(agreement: dict) -> list[str]:
    """What a user should know of an :meth:`Agreement.as_json`: how well the photos agree
    on the table, and, when too little for a good held-out score, what to change: the
    exposure, when evening it out would make them agree well enough, else the light."""
    a = agreement["psnr"]
    lines = [
        f"agreement: the training photos show the table around the object in the same colours to {a:.1f} dB "
        "(each photo against the mean of those that see each spot): about as high as held-out photos can score"
    ]
    if a >= AGREEMENT_NOTE_DB:
        return lines
    evened = agreement["psnr_exposure_evened"]
    low = f"  that is low (under {AGREEMENT_NOTE_DB:.0f} dB)"
    if evened >= AGREEMENT_NOTE_DB:
        lines.append(
            f"{low}, mostly the phone's exposure and white balance changing between photos: evened out, the "
            f"photos agree to {evened:.1f} dB. Lock them while photographing (iPhone: AE/AF lock)"
        )
    else:
        lock = " Locking the exposure (iPhone: AE/AF lock) helps too" if evened - a >= EXPOSURE_SHARE_DB else ""
        lines.append(
            f"{low}, and not only from the phone's exposure (evened out, the photos agree to {evened:.1f} dB): "
            "the light on the table changes between photos: your shadow falls on it, or a glossy table "
            f"mirrors a lamp or window. Keep your shadow off the table and light it evenly.{lock}"
        )
    return lines
