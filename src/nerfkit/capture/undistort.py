"""Undistort photos to pinhole images (OpenCV), crop to the valid region, and resize.

All ``K`` here are OpenCV-convention (pixel centres at integers) except where a function
says otherwise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import fail
from .camera import Camera


@dataclass
class Undistorter:
    """Maps from a distorted camera to a cropped pinhole camera.

    Attributes:
        camera: the source camera (size of the photos it takes).
        K: (3, 3) pinhole intrinsics of the cropped undistorted image, OpenCV convention.
        roi: (x, y, w, h): the output is this window (it may reach past the photo's frame) of
            an undistorted image with the source's ``K`` (every output pixel has a source pixel).
        maps: the two ``cv2.remap`` maps straight to the crop, or None without distortion.
    """

    camera: Camera
    K: np.ndarray
    roi: tuple[int, int, int, int]
    maps: tuple[np.ndarray, np.ndarray] | None

    @property
    def size(self) -> tuple[int, int]:
        return self.roi[2], self.roi[3]

    def __call__(self, image: np.ndarray) -> np.ndarray:
        """(H, W, 3) photo of the camera's size -> (h, w, 3) undistorted, cropped."""
        import cv2

        if image.shape[:2] != (self.camera.height, self.camera.width):
            raise ValueError(
                f"image is {image.shape[1]}x{image.shape[0]}, camera is {self.camera.width}x{self.camera.height}"
            )
        if self.maps is None:
            return image
        return cv2.remap(image, *self.maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def valid_rectangle(camera: Camera, K_new: np.ndarray, samples: int = 200) -> tuple[float, float, float, float]:
    """Bounds (left, top, right, bottom), in pixels of an undistorted image with intrinsics
    ``K_new``, of the largest axis-aligned rectangle inside the image of the photo's border:
    every pixel inside it has a source pixel."""
    import cv2

    w, h = camera.width, camera.height
    t = np.linspace(0.0, 1.0, samples)
    x0, x1, y0, y1 = -0.5, w - 0.5, -0.5, h - 0.5  # outer edges of the border pixels
    borders = {
        "left": np.column_stack([np.full(samples, x0), y0 + t * (y1 - y0)]),
        "right": np.column_stack([np.full(samples, x1), y0 + t * (y1 - y0)]),
        "top": np.column_stack([x0 + t * (x1 - x0), np.full(samples, y0)]),
        "bottom": np.column_stack([x0 + t * (x1 - x0), np.full(samples, y1)]),
    }
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-10)
    out = {
        k: cv2.undistortPoints(v.reshape(-1, 1, 2), camera.K, camera.dist, P=K_new, criteria=crit).reshape(-1, 2)
        for k, v in borders.items()
    }
    return (
        float(out["left"][:, 0].max()),
        float(out["top"][:, 1].max()),
        float(out["right"][:, 0].min()),
        float(out["bottom"][:, 1].min()),
    )


def make_undistorter(camera: Camera) -> Undistorter:
    """A pinhole camera for undistorted photos and the maps to get there.

    The undistorted image keeps the calibrated focal lengths and principal point (so square
    pixels stay square and the centre keeps its resolution) and spans the largest rectangle
    of valid pixels (smaller than the photo for pincushion distortion, larger for barrel);
    ``K`` is shifted by the rectangle's corner.
    """
    import cv2

    w, h = camera.width, camera.height
    if not camera.has_distortion:
        return Undistorter(camera, camera.K.copy(), (0, 0, w, h), None)
    left, top, right, bottom = valid_rectangle(camera, camera.K)
    # Pixel centres (integers) inside the rectangle, half a pixel in from its edges. With
    # barrel distortion the rectangle is larger than the photo: the output grows to keep
    # the photo's whole field of view.
    x0, y0 = int(np.ceil(left + 0.5)), int(np.ceil(top + 0.5))
    x1, y1 = int(np.floor(right - 0.5)), int(np.floor(bottom - 0.5))
    rw, rh = x1 - x0 + 1, y1 - y0 + 1
    if rw > 2 * w or rh > 2 * h:
        raise fail(
            camera.source or "camera",
            f"undistortion would stretch {w}x{h} photos to {rw}x{rh}",
            "The distortion coefficients look wrong; re-calibrate (try --dist-model k1k2)",
        )
    if rw < 0.3 * w or rh < 0.3 * h:
        raise fail(
            camera.source or "camera",
            f"undistortion leaves only a {max(rw, 0)}x{max(rh, 0)} valid region of {w}x{h}",
            "The distortion coefficients look wrong; re-calibrate (try --dist-model k1k2)",
        )
    K = camera.K.astype(np.float64).copy()
    K[0, 2] -= x0
    K[1, 2] -= y0
    maps = cv2.initUndistortRectifyMap(camera.K, camera.dist, None, K, (rw, rh), cv2.CV_16SC2)
    return Undistorter(camera, K, (x0, y0, rw, rh), maps)


def output_size(width: int, height: int, max_side: int) -> tuple[int, int]:
    """Size after downscaling so the longer side is at most ``max_side`` (0: keep)."""
    if max_side <= 0 or max(width, height) <= max_side:
        return width, height
    s = max_side / max(width, height)
    return max(1, round(width * s)), max(1, round(height * s))


def resize_K_nerfkit(K_nk: np.ndarray, src: tuple[int, int], dst: tuple[int, int]) -> np.ndarray:
    """Scale a nerfkit-convention K (pixel centres at +0.5) from ``src`` to ``dst`` (w, h):
    in that convention resizing is a plain scale of fx, cx (and fy, cy)."""
    sx, sy = dst[0] / src[0], dst[1] / src[1]
    K = np.array(K_nk, np.float64, copy=True)
    K[0, 0] *= sx
    K[0, 2] *= sx
    K[1, 1] *= sy
    K[1, 2] *= sy
    return K
