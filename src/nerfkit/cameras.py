"""Cameras, rays and the one camera convention nerfkit uses.

Convention (everywhere in nerfkit):

* Camera axes are **OpenCV**: +x right, +y down, +z forward (the camera looks along +z).
* ``c2w`` is a 4x4 camera-to-world matrix; ``x_w = R @ x_c + t`` with ``R = c2w[:3, :3]``,
  ``t = c2w[:3, 3]`` (the camera centre in world coordinates).
* Pixels are ``uv = (x, y) = (column, row)``; the centre of pixel ``(col, row)`` is at
  ``uv = (col + 0.5, row + 0.5)``.
* ``K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``. A course file with only ``focal``
  means ``cx = W / 2``, ``cy = H / 2``.
* Blender / nerfstudio ``transform_matrix`` uses OpenGL axes (+y up, +z backward);
  :func:`opengl_to_opencv` is the one place that converts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from nerfkit.arrays import accepts_numpy

# Flips camera y and z: OpenGL camera axes <-> OpenCV camera axes (its own inverse).
_GL_CV_FLIP = np.diag([1.0, -1.0, -1.0, 1.0])


def opengl_to_opencv(c2w: np.ndarray) -> np.ndarray:
    """Convert camera-to-world matrices (..., 4, 4) between OpenGL and OpenCV axes.

    ``c2w_cv = c2w_gl @ diag(1, -1, -1, 1)``; the same formula converts back.
    """
    return np.asarray(c2w) @ _GL_CV_FLIP.astype(np.asarray(c2w).dtype)


opencv_to_opengl = opengl_to_opencv


def intrinsics_matrix(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """The 3x3 pinhole matrix ``K`` (float32)."""
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], dtype=np.float32)


@accepts_numpy
def transform(c2w: Tensor, x: Tensor) -> Tensor:
    """Apply rigid transforms to points.

    Args:
        c2w: (..., 4, 4) or (4, 4) transform (camera-to-world for camera points).
        x: (..., 3) points in the source frame; broadcast against ``c2w``'s batch shape.

    Returns:
        (..., 3) points in the target frame: ``R @ x + t``.

    Example: ``transform(torch.linalg.inv(c2w), transform(c2w, x)) == x``.
    """
    R = c2w[..., :3, :3]
    t = c2w[..., :3, 3]
    return (R @ x.unsqueeze(-1)).squeeze(-1) + t


def _broadcasts_to(shape: torch.Size, target: torch.Size) -> bool:
    try:
        return torch.broadcast_shapes(shape, target) == target
    except RuntimeError:
        return False


@accepts_numpy
def pixel_to_camera(K: Tensor, uv: Tensor, s: Tensor | float) -> Tensor:
    """Back-project pixels to camera-frame points at depth ``s`` (the z coordinate).

    Args:
        K: (..., 3, 3) or (3, 3) intrinsics.
        uv: (..., 2) pixel coordinates (x, y); pixel centres are at +0.5.
        s: (...) or scalar depth along the camera's +z axis: one depth per pixel, not
            (..., 1) (which would broadcast against the points' 3 coordinates).

    Returns:
        (..., 3) points ``s * K^-1 @ [u, v, 1]``.
    """
    if uv.shape[-1] != 2:
        raise ValueError(f"pixel_to_camera takes uv of shape (..., 2), pixel (x, y), got {tuple(uv.shape)}")
    fx, fy = K[..., 0, 0], K[..., 1, 1]
    cx, cy = K[..., 0, 2], K[..., 1, 2]
    skew = K[..., 0, 1]
    y = (uv[..., 1] - cy) / fy
    x = (uv[..., 0] - cx - skew * y) / fx
    xyz = torch.stack([x, y, torch.ones_like(x)], dim=-1)
    s = torch.as_tensor(s, dtype=xyz.dtype, device=xyz.device)
    if s.ndim and not _broadcasts_to(s.shape, xyz.shape[:-1]):
        raise ValueError(
            f"pixel_to_camera: s has shape {tuple(s.shape)} for pixels of shape {tuple(uv.shape)}: give "
            f"one depth per pixel, shape {tuple(xyz.shape[:-1])}, or a scalar"
        )
    return xyz * s.unsqueeze(-1) if s.ndim else xyz * s


@dataclass
class Rays:
    """A batch of rays in world coordinates.

    Attributes:
        origins: (n_rays, 3) ray origins (camera centres).
        directions: (n_rays, 3) unit directions.
    """

    origins: Tensor
    directions: Tensor

    def __len__(self) -> int:
        return self.origins.shape[0]

    def __getitem__(self, idx) -> Rays:
        return Rays(self.origins[idx], self.directions[idx])

    def to(self, device: torch.device | str) -> Rays:
        return Rays(self.origins.to(device), self.directions.to(device))


@accepts_numpy
def pixel_to_ray(K: Tensor, c2w: Tensor, uv: Tensor) -> tuple[Tensor, Tensor]:
    """Rays through pixels.

    Args:
        K: (..., 3, 3) or (3, 3) intrinsics.
        c2w: (..., 4, 4) or (4, 4) camera-to-world (OpenCV axes).
        uv: (..., 2) pixel coordinates (x, y), pixel centres at +0.5.
        The leading dimensions broadcast as numpy's: N cameras against (N, M) pixels each is
        ``c2w[:, None]`` (N, 1, 4, 4) with ``uv`` (N, M, 2).

    Returns:
        ``(rays_o, rays_d)``, each (..., 3); ``rays_d`` has unit length. ``rays_o`` is the
        camera centre broadcast over the pixels (a view: ``.clone()`` it to edit in place).
    """
    x_c = pixel_to_camera(K, uv, 1.0)
    rays_d = (c2w[..., :3, :3] @ x_c.unsqueeze(-1)).squeeze(-1)
    rays_d = rays_d / torch.linalg.norm(rays_d, dim=-1, keepdim=True)
    rays_o = c2w[..., :3, 3].expand_as(rays_d)
    return rays_o, rays_d


def image_rays(K: Tensor, c2w: Tensor, width: int, height: int) -> Rays:
    """All pixel-centre rays of one image, row-major: (height * width) rays."""
    rows, cols = torch.meshgrid(
        torch.arange(height, dtype=torch.float32, device=c2w.device),
        torch.arange(width, dtype=torch.float32, device=c2w.device),
        indexing="ij",
    )
    uv = torch.stack([cols, rows], dim=-1).reshape(-1, 2) + 0.5
    o, d = pixel_to_ray(K.to(c2w.device, torch.float32), c2w.float(), uv)
    return Rays(o, d)


def plane_hit(origins: Tensor, dirs: Tensor, plane: Tensor) -> Tensor:
    """Distance along each ray to the plane ``n . x + d = 0`` from its front side.

    Args:
        origins, dirs: (n, 3); plane: (4,) ``(nx, ny, nz, d)`` with a unit normal pointing
            to the side the cameras are on.

    Returns:
        (n,) ``t > 0`` where the ray meets the plane coming from the front, ``inf`` elsewhere.
        Example: a ray from (0, 0, 2) straight down meets z = 0 at t = 2.
    """
    n, d = plane[:3].to(origins), plane[3].to(origins)
    height = origins @ n + d  # (n,) signed distance of the origin to the plane
    speed = dirs @ n  # (n,) rate of approach (negative: heading to the plane)
    t = -height / speed.clamp(max=-1e-12)
    hits = (height > 0) & (speed < -1e-9)
    return torch.where(hits, t, torch.full_like(t, math.inf))


def project_points(K: np.ndarray, c2w: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World points (n, 3) -> their pixel coordinates ``uv`` (n, 2) (pixel ``(col, row)``
    covers ``[col, col + 1) x [row, row + 1)``) and their depth ``z`` (n,) along the
    camera's axis (in front of the camera where ``z > 0``; ``uv`` is meaningless elsewhere)."""
    w2c = np.linalg.inv(np.asarray(c2w, np.float64))
    x = np.asarray(points, np.float64) @ w2c[:3, :3].T + w2c[:3, 3]
    z = x[:, 2]
    xy = x[:, :2] / np.where(np.abs(z) > 1e-12, z, 1e-12)[:, None]
    K = np.asarray(K, np.float64)
    uv = xy @ K[:2, :2].T + K[:2, 2]
    return uv, z


def strided_camera(K, width: int, height: int, stride: int):
    """The camera whose pixels are every ``stride``-th pixel of ``(K, width, height)``.

    Pixel ``(j, i)`` of the result sees exactly what pixel ``(stride j, stride i)`` of the
    original sees (same ray through the same pixel centre), so an image rendered with it
    equals ``full[::stride, ::stride]``.

    Args:
        K: (3, 3) intrinsics (numpy or torch); width, height: image size; stride >= 1.

    Returns:
        ``(K', ceil(width / stride), ceil(height / stride))``, K' of the same kind as K.
    """
    if stride < 1:
        raise ValueError(f"stride must be >= 1, got {stride}")
    Ks = K.clone() if isinstance(K, Tensor) else np.array(K, dtype=np.float64, copy=True)
    # centre u' + 0.5 of the new pixel j must map to s j + 0.5: fx' = fx / s, cx' = (cx - 0.5) / s + 0.5
    Ks[0, 0], Ks[1, 1] = K[0, 0] / stride, K[1, 1] / stride
    Ks[0, 1] = K[0, 1] / stride
    Ks[0, 2] = (K[0, 2] - 0.5) / stride + 0.5
    Ks[1, 2] = (K[1, 2] - 0.5) / stride + 0.5
    return Ks, -(-width // stride), -(-height // stride)


def rotation_angles_deg(c2w_a: np.ndarray, c2w_b: np.ndarray) -> np.ndarray:
    """(n,) angle in degrees of the rotation between each pair of camera orientations
    ``c2w_a[i]`` and ``c2w_b[i]`` ((n, 3 or 4, 3 or 4) each).

    Example: the identity against a quarter turn about any axis gives 90."""
    rel = np.swapaxes(c2w_a[:, :3, :3], 1, 2).astype(np.float64) @ c2w_b[:, :3, :3].astype(np.float64)
    cos = np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)
    return np.degrees(np.arccos(cos))


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray) -> np.ndarray:
    """OpenCV camera-to-world (4, 4) at ``eye`` looking at ``target``; image-up is ``up``."""
    forward = target - eye
    forward = forward / np.linalg.norm(forward)
    right = np.cross(forward, up)  # +x = forward x up gives +y (down) = forward x right
    if np.linalg.norm(right) < 1e-8:
        raise ValueError("look_at: up is parallel to the viewing direction")
    right = right / np.linalg.norm(right)
    down = np.cross(forward, right)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, down, forward, eye
    return c2w


def axes_across(normal) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors ``(a, b)`` across ``normal`` (3,), with ``(a, b, normal)`` a
    right-handed frame: an orbit about ``normal`` starts along ``a`` and passes ``b`` at 90
    degrees; a plane with this normal is textured along ``a`` and ``b``."""
    n = np.asarray(normal, dtype=np.float64).reshape(3)
    n = n / np.linalg.norm(n)
    helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    a = np.cross(n, helper)
    a /= np.linalg.norm(a)
    return a, np.cross(n, a)


def orbit_path(
    center: np.ndarray,
    up: np.ndarray,
    radius: float | np.ndarray,
    height: float | np.ndarray,
    n_frames: int,
) -> np.ndarray:
    """Camera-to-world poses (n_frames, 4, 4) circling ``center`` about the ``up`` axis.

    Cameras sit ``height`` above the centre along ``up``, ``radius`` away from the axis
    (each a number, or one per frame), and look at ``center``.
    """
    up = np.asarray(up, dtype=np.float64)
    up = up / np.linalg.norm(up)
    a, b = axes_across(up)
    thetas = np.linspace(0.0, 2.0 * np.pi, n_frames, endpoint=False)
    radius, height = np.broadcast_to(radius, thetas.shape), np.broadcast_to(height, thetas.shape)
    poses = []
    for theta, r, h in zip(thetas, radius, height):
        eye = center + r * (np.cos(theta) * a + np.sin(theta) * b) + h * up
        poses.append(look_at(eye, center, up))
    return np.stack(poses).astype(np.float32)


def forward_facing(c2w: np.ndarray, center: np.ndarray, max_angle_deg: float = 30.0, max_spread: float = 0.25) -> bool:
    """True for an LLFF-style capture: every camera looks within ``max_angle_deg`` of the
    cameras' mean viewing direction, and the cameras stand close together (each within
    ``max_spread`` times the distance from their mean to ``center``, the scene's middle),
    so that the NDC of their mean camera covers what they all see."""
    c2w = np.asarray(c2w, np.float64)
    z = c2w[:, :3, 2] / np.linalg.norm(c2w[:, :3, 2], axis=1, keepdims=True)
    mean = z.mean(0)
    if len(c2w) < 2 or np.linalg.norm(mean) < 1e-6:
        return False
    mean = mean / np.linalg.norm(mean)
    eyes = c2w[:, :3, 3]
    depth = float(np.linalg.norm(np.asarray(center, np.float64) - eyes.mean(0)))
    spread = float(np.linalg.norm(eyes - eyes.mean(0), axis=1).max())
    return bool((z @ mean).min() >= np.cos(np.deg2rad(max_angle_deg)) and spread <= max_spread * depth)


def mean_camera(c2w: np.ndarray) -> np.ndarray:
    """(4, 4) the average camera: mean centre, mean viewing direction, the mean down axis
    made orthogonal to it (OpenCV axes)."""
    c2w = np.asarray(c2w, np.float64)
    z = c2w[:, :3, 2].mean(0)
    z /= np.linalg.norm(z)
    y = c2w[:, :3, 1].mean(0)
    y -= (y @ z) * z
    y /= np.linalg.norm(y)
    out = np.eye(4)
    out[:3, 0], out[:3, 1], out[:3, 2], out[:3, 3] = np.cross(y, z), y, z, c2w[:, :3, 3].mean(0)
    return out


def spiral_path(c2w: np.ndarray, focus_depth: float, n_frames: int) -> np.ndarray:
    """A forward-facing capture's video path (LLFF's spiral): camera-to-world poses
    (n_frames, 4, 4) circling the mean camera (:func:`mean_camera`) across its view, as far
    out as the cameras spread (90th percentile per axis), all looking at the point
    ``focus_depth`` ahead of it."""
    ref = mean_camera(c2w)
    right, down, forward, centre = ref[:3, 0], ref[:3, 1], ref[:3, 2], ref[:3, 3]
    offsets = (np.asarray(c2w, np.float64)[:, :3, 3] - centre) @ ref[:3, :3]
    rx, ry = np.percentile(np.abs(offsets[:, :2]), 90, axis=0)
    target = centre + focus_depth * forward
    poses = []
    for theta in np.linspace(0.0, 2.0 * np.pi, n_frames, endpoint=False):
        eye = centre + rx * np.cos(theta) * right + ry * np.sin(theta) * down
        poses.append(look_at(eye, target, -down))
    return np.stack(poses).astype(np.float32)
