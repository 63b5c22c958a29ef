"""How much detail a capture's photos show on its object, before any training.

In the tight box its sparse points give, the ``fast`` model's grid serves a textured object's
print, and lets a plain one (a can's uniform label and lid) fray: shards off its outline, a
grainy top. Where the photos hold no more detail on the object than on the table it stands
on, the box is widened (``--object-box-margin``; the presets, :func:`nerfkit.presets.scene_values`).

Which pixels show the object, without a model: a pixel of the table shows the same colour
from every photo, a pixel of something standing above it does not. Each pixel inside the
object box's outline is followed to the table's plane and looked up in the photos nearest
in direction; where they disagree (after a gain per photo, for exposure) it shows the
object. Over those pixels, the median magnitude of the brightness gradient, against the
same over the pixels of the table in the outline. Pure numpy and OpenCV on a scene's arrays.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import cv2
import numpy as np
import torch

from .cameras import pixel_to_ray, plane_hit, project_points
from .images import sample_bilinear
from .scene_extent import box_corners, object_box_from_points, sphere_radius

# an object is plain when the median gradient on it is under both of these: an absolute
# level (white paper in the dev captures' photos scores 0.0020-0.0029, their objects
# 0.0054-0.021, a synthetic plain can 0.0018-0.0020) and a multiple of the table's own
PLAIN_GRADIENT = 0.004
PLAIN_RATIO = 1.5
# a pixel shows the object when the photos near it disagree about its table point by more
# than this (mean absolute difference of the blurred colours in [0, 1])
DISAGREE = 0.08


@dataclass(frozen=True)
class ObjectDetail:
    """The median brightness gradient (:func:`gradient_magnitude`) over the object's pixels
    and over the table's inside the object box's outline, and the object's share of the
    outline's pixels; medians over the photos looked at."""

    on_object: float
    on_table: float
    object_share: float

    @property
    def plain(self) -> bool:
        """Whether the object shows no more detail than plain paper and its table do."""
        return self.on_object < PLAIN_GRADIENT and self.on_object < PLAIN_RATIO * self.on_table

    def describe(self) -> str:
        return f"median gradient {self.on_object:.4f} on the object, {self.on_table:.4f} on the table"


def gradient_magnitude(rgb: np.ndarray) -> np.ndarray:
    """(H, W) magnitude of the brightness gradient of ``rgb`` (H, W, 3) in [0, 1], blurred by a
    Gaussian of sigma ``W / 512`` pixels, in grey levels per ``W / 512`` pixels (a ramp rising
    by ``s`` a pixel scores ``s W / 512`` away from the border): photos of any size compare."""
    width = rgb.shape[1]
    grey = cv2.GaussianBlur(cv2.cvtColor(rgb.astype(np.float32), cv2.COLOR_RGB2GRAY), (0, 0), width / 512)
    gx = cv2.Sobel(grey, cv2.CV_32F, 1, 0, borderType=cv2.BORDER_REPLICATE) / 8
    gy = cv2.Sobel(grey, cv2.CV_32F, 0, 1, borderType=cv2.BORDER_REPLICATE) / 8
    return np.hypot(gx, gy) * (width / 512)


def box_outline(K: np.ndarray, c2w: np.ndarray, box, width: int, height: int) -> np.ndarray:
    """(H, W) bool: the pixels inside the outline of ``box`` ``(lo, hi)`` seen by the camera
    ``(K, c2w)`` (OpenCV axes); none when a corner is behind the camera."""
    uv, z = project_points(K, c2w, box_corners(box))
    mask = np.zeros((height, width), np.uint8)
    if (z > 0).all():
        cv2.fillConvexPoly(mask, cv2.convexHull(np.round(uv - 0.5).astype(np.int32)), 1)
    return mask.astype(bool)


def table_points(K: np.ndarray, c2w: np.ndarray, uv: np.ndarray, table: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where the rays through pixels ``uv`` (n, 2) (centres at +0.5) of camera ``(K, c2w)``
    meet the plane ``table`` ``(n, d)`` from its front (:func:`~nerfkit.cameras.plane_hit`):
    points (n, 3) (the camera's centre where a ray misses), and (n,) bool, whether it meets it."""
    f64 = torch.float64
    o, d = pixel_to_ray(*(torch.as_tensor(np.asarray(a), dtype=f64) for a in (K, c2w, uv)))
    t = plane_hit(o, d, torch.as_tensor(np.asarray(table), dtype=f64))
    hit = torch.isfinite(t)
    return (o + torch.where(hit, t, 0.0).unsqueeze(-1) * d).numpy(), hit.numpy()


# photos wider than this are looked at downscaled to it (the figures are per 512th of the width)
ANALYSIS_WIDTH = 512


class Photos:
    """A split's photos at most :data:`ANALYSIS_WIDTH` wide (``K``, ``c2w``, ``width``,
    ``height`` to match), each converted to float (:meth:`rgb`) and blurred (:meth:`blurred`)
    once, when first asked for: a capture of many large photos is not all held at once."""

    def __init__(self, views) -> None:
        self.views = views
        scale = min(1.0, ANALYSIS_WIDTH / views.width)
        self.width, self.height = max(1, round(views.width * scale)), max(1, round(views.height * scale))
        self.K = np.array(views.K, np.float64)
        self.K[:, 0] *= self.width / views.width
        self.K[:, 1] *= self.height / views.height
        self.c2w = np.asarray(views.c2w, np.float64)
        self._rgb: dict[int, np.ndarray] = {}
        self._blurred: dict[int, np.ndarray] = {}

    def rgb(self, j: int) -> np.ndarray:
        """(H, W, 3) float32 in [0, 1]: photo ``j``."""
        if j not in self._rgb:
            im = np.asarray(self.views.images[j])[..., :3]
            if (im.shape[1], im.shape[0]) != (self.width, self.height):
                im = cv2.resize(im, (self.width, self.height), interpolation=cv2.INTER_AREA)
            self._rgb[j] = im.astype(np.float32) / 255.0
        return self._rgb[j]

    def blurred(self, j: int) -> np.ndarray:
        """(H, W, 3) photo ``j`` blurred by a Gaussian of sigma 2 512ths of its width."""
        if j not in self._blurred:
            self._blurred[j] = cv2.GaussianBlur(self.rgb(j), (0, 0), 2.0 * self.width / 512)
        return self._blurred[j]


def disagreement(photos: Photos, i: int, pts: np.ndarray, colours: np.ndarray, neighbours: int) -> np.ndarray:
    """(n,) the median over the ``neighbours`` photos nearest photo ``i`` (by camera position)
    of the mean absolute difference between ``colours`` (n, 3) and what each shows at
    ``pts`` (n, 3) (blurred), after that photo's gain (the median ratio of the brightnesses);
    NaN where no photo shows the point."""
    centres = photos.c2w[:, :3, 3]
    order = np.argsort(np.linalg.norm(centres - centres[i], axis=1))[1 : neighbours + 1]
    diffs = []
    for j in order:
        uv, z = project_points(photos.K[j], photos.c2w[j], pts)
        ok = (z > 0) & (uv[:, 0] >= 0.5) & (uv[:, 1] >= 0.5)
        ok &= (uv[:, 0] <= photos.width - 0.5) & (uv[:, 1] <= photos.height - 0.5)
        if ok.sum() < 10:
            continue
        seen = sample_bilinear(photos.blurred(int(j)), uv)
        gain = np.median(colours[ok].sum(1) / np.maximum(seen[ok].sum(1), 1e-3))
        diff = np.abs(colours - gain * seen).mean(1)
        diff[~ok] = np.nan
        diffs.append(diff)
    if not diffs:
        return np.full(len(pts), np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # (all-NaN columns: no photo shows the point)
        return np.nanmedian(np.stack(diffs), 0)


def object_detail(
    views, table: np.ndarray, box, photos: int = 6, stride: int = 4, neighbours: int = 8
) -> ObjectDetail | None:
    """How much detail ``views``' photos (``images`` (n, H, W, 3) uint8, ``K``, ``c2w``,
    ``width``, ``height``) show on the object in ``box`` ``(lo, hi)`` standing on the plane
    ``table``, against the table around it; from ``photos`` photos spread over the set, every
    ``stride``-th pixel (of the photos at most :data:`ANALYSIS_WIDTH` wide). None without
    enough pixels of both (fewer than 3 photos, say)."""
    n = len(views.c2w)
    if n < 3 or views.images is None:
        return None
    seen = Photos(views)
    figures = []
    for i in (int(i) for i in np.unique(np.linspace(0, n - 1, min(photos, n)).astype(int))):
        outline = box_outline(seen.K[i], seen.c2w[i], box, seen.width, seen.height)
        rows, cols = np.nonzero(outline[::stride, ::stride])
        rows, cols = rows * stride, cols * stride
        if len(rows) < 50:
            continue
        pts, ahead = table_points(seen.K[i], seen.c2w[i], np.stack([cols, rows], 1) + 0.5, table)
        differ = disagreement(seen, i, pts, seen.blurred(i)[rows, cols], neighbours)
        grad = gradient_magnitude(seen.rgb(i))[rows, cols]
        obj = ahead & (differ > DISAGREE)
        tab = ahead & (differ <= DISAGREE)
        if obj.sum() >= 20 and tab.sum() >= 20:
            figures.append((np.median(grad[obj]), np.median(grad[tab]), obj.sum() / len(rows)))
    if not figures:
        return None
    on_object, on_table, share = np.median(np.array(figures), 0)
    return ObjectDetail(float(on_object), float(on_table), float(share))


def scene_object_detail(scene) -> ObjectDetail | None:
    """:func:`object_detail` of a capture ``scene``'s training photos, for the object in the box
    its sparse points give (:func:`~nerfkit.scene_extent.object_box_from_points`, as the models'
    bounds take it); None without a table, sparse points, images or such a box."""
    if scene.table is None or scene.points is None or not scene.train.has_images:
        return None
    box = object_box_from_points(scene.points, scene.table, scene.center, sphere_radius(scene), views=scene.train)
    return None if box is None else object_detail(scene.train, scene.table, box)


__all__ = [
    "PLAIN_GRADIENT",
    "PLAIN_RATIO",
    "ObjectDetail",
    "gradient_magnitude",
    "object_detail",
    "scene_object_detail",
]
