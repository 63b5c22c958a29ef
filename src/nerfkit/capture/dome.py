"""A splat model's learned background as Gaussians, so that its splat file is self-contained.

A splat model with ``learn_background`` draws, behind its Gaussians, a colour per ray
direction (``sigmoid(sh16(d) @ bg_coef.T)``, :meth:`nerfkit.models.splat.SplatModel._background_image`).
A standard 3DGS viewer knows nothing of it and draws the Gaussians over black or white. The
dome carries that background into the file: flat, nearly opaque Gaussians on a far sphere
around the scene's centre (centres on a Fibonacci sphere, thin along the radius, wide enough
across it that neighbours overlap), each coloured (SH DC term, higher terms zero) by the
background in its direction. The sphere is :data:`DOME_SCALE` times beyond the farthest of
the scene's radius, the far bound and the cameras, so a ray from any camera meets it in
about the direction it leaves the scene's centre (at most 1/DOME_SCALE radian apart).
No far plane culls it in nerfkit's rasterizer, the INRIA code or gsplat, and float32 holds
its positions to a millionth of the radius.
"""

from __future__ import annotations

import math

import numpy as np

# dome Gaussians: the background is smooth (SH up to degree 3), so a few thousand hold it
DOME_GAUSSIANS = 8000
# the dome's radius over the farthest of the scene's radius, far bound and camera distance
DOME_SCALE = 100.0
# tangent standard deviation over the spacing of neighbouring centres: they overlap without gaps
DOME_SPREAD = 0.7
# radial standard deviation over the tangent one: flat discs facing the centre
DOME_THICKNESS = 0.01
# opacity of each dome Gaussian (the rasterizers cap alpha at 0.99)
DOME_OPACITY = 0.99


def fibonacci_sphere(n: int) -> np.ndarray:
    """(n, 3) unit vectors spread evenly over the sphere (the golden-angle spiral)."""
    i = np.arange(n, dtype=np.float64) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(np.clip(1.0 - z * z, 0.0, None))
    phi = math.pi * (3.0 - math.sqrt(5.0)) * i
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], 1)


def z_to(normals: np.ndarray) -> np.ndarray:
    """(n, 4) unit quaternions ``(w, x, y, z)`` rotating +z onto each unit vector of ``normals`` (n, 3)."""
    n = np.asarray(normals, np.float64)
    q = np.stack([1.0 + n[:, 2], -n[:, 1], n[:, 0], np.zeros(len(n))], 1)  # (1 + z.n, z x n)
    q[n[:, 2] < -1 + 1e-9] = (0.0, 1.0, 0.0, 0.0)  # straight down: half a turn about x
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def background_colour(bg_coef: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """What a learned background shows in each direction: ``bg_coef`` (3, 16) and unit
    directions (n, 3) -> (n, 3) colours in (0, 1), as the splat model renders it."""
    import torch

    from ..fields.background import sh16

    d = torch.as_tensor(np.asarray(dirs, np.float32))
    return torch.sigmoid(sh16(d) @ torch.as_tensor(np.asarray(bg_coef, np.float32)).t()).numpy().astype(np.float64)


def dome_radius(radius: float, far: float, camera_radius: float | None) -> float:
    """The dome's radius: :data:`DOME_SCALE` times the farthest of the scene's ``radius``, the
    ``far`` bound and ``camera_radius`` (the farthest camera's distance from the centre)."""
    return DOME_SCALE * max(float(radius), float(far), float(camera_radius or 0.0))


def background_dome(
    center: np.ndarray,
    dome_r: float,
    bg_coef: np.ndarray,
    n: int = DOME_GAUSSIANS,
    n_rest: int = 15,
):
    """The learned background ``bg_coef`` (3, 16) as ``n`` Gaussians on the sphere of radius
    ``dome_r`` around ``center`` (3,): a :class:`~nerfkit.splat_files.Gaussians` with means
    (n, 3), log-scales (n, 3) (tangent, tangent, radial), quaternions (n, 4) turning +z to the
    radius, opacity logits (n,), sh_dc (n, 1, 3) the background's colour in each one's
    direction from ``center``, and sh_rest (n, n_rest, 3) zeros."""
    from ..splat_files import Gaussians, rgb_to_dc

    dirs = fibonacci_sphere(n)
    spacing = math.sqrt(4 * math.pi / n)  # radians between neighbouring centres
    tangent = DOME_SPREAD * spacing * dome_r
    log_scales = np.log([tangent, tangent, DOME_THICKNESS * tangent])
    colour = background_colour(bg_coef, dirs)
    f32 = np.float32
    return Gaussians(
        (np.asarray(center, np.float64) + dome_r * dirs).astype(f32),
        np.broadcast_to(log_scales, (n, 3)).astype(f32),
        z_to(dirs).astype(f32),
        np.full(n, math.log(DOME_OPACITY / (1 - DOME_OPACITY)), f32),
        rgb_to_dc(colour).astype(f32),
        np.zeros((n, n_rest, 3), f32),
    )


def model_dome(model, bounds, n: int = DOME_GAUSSIANS):
    """The dome of a splat ``model``'s learned background (:func:`background_dome`, around
    ``bounds``' centre, at :func:`dome_radius`), or None when it has none."""
    coef = getattr(model, "bg_coef", None)
    if coef is None:
        return None
    r = dome_radius(bounds.radius, bounds.far, bounds.camera_radius)
    return background_dome(bounds.center, r, coef.detach().cpu().numpy(), n, int(model.sh_rest.shape[1]))


def on_dome(means: np.ndarray, bounds) -> np.ndarray:
    """(n,) bool: which of the Gaussian centres ``means`` (n, 3) lie on a dome around ``bounds``
    (farther from its centre than half :func:`dome_radius`)."""
    r = dome_radius(bounds.radius, bounds.far, bounds.camera_radius)
    return np.linalg.norm(np.asarray(means, np.float64) - np.asarray(bounds.center, np.float64), axis=1) > 0.5 * r


def join(a, b):
    """The Gaussians of ``a`` followed by those of ``b`` (same SH degree)."""
    from ..splat_files import Gaussians

    names = ("means", "log_scales", "quats", "opacity_logits", "sh_dc", "sh_rest")
    return Gaussians(*(np.concatenate([getattr(a, k), getattr(b, k)]) for k in names))
