"""What rays see beyond a model's box: the room (a colour per direction) and the table.

A real capture shows an object standing on a table in a room. Inside its box a model
represents the object with density; beyond the box the photos still show the table
(with parallax: it is a plane, not a colour per direction) and the room. Filling that
with density makes haze and floaters; a flat colour makes dark surfaces see-through.

* :func:`sh16`: the basis of a smooth colour per ray direction (real spherical harmonics
  up to degree 3), for the far room.
* :class:`TablePlane`: an opaque textured plane (the tag's plane in a tag capture). Rays
  stop where they meet it; its texture lives on a 2D grid in *contracted* plane
  coordinates (mip-NeRF 360's contraction in 2D), so a finite texture covers the whole
  infinite plane, finely near the object and ever more coarsely far from it.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn


def sh16(dirs: Tensor) -> Tensor:
    """(n, 3) unit directions -> (n, 16): the real spherical harmonics up to degree 3
    (unnormalised), a smooth basis for a colour per direction."""
    x, y, z = dirs[:, 0], dirs[:, 1], dirs[:, 2]
    one = torch.ones_like(x)
    return torch.stack([one, x, y, z, x * y, y * z, x * z, x * x - y * y, 3 * z * z - 1,
                        x * (x * x - 3 * y * y), y * (3 * x * x - y * y), z * (x * x - y * y), x * y * z,
                        x * (5 * z * z - 1), y * (5 * z * z - 1), z * (5 * z * z - 3)], dim=-1)


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


def contract_disc(q: Tensor) -> Tensor:
    """mip-NeRF 360's contraction in 2D: (n, 2) -> (n, 2) inside the disc of radius 2.

    ``q`` for ``|q| <= 1``, ``(2 - 1 / |q|) q / |q|`` beyond: the unit disc keeps its
    scale, the rest of the plane is squeezed into the ring ``1 < r < 2``.
    """
    r = torch.linalg.norm(q, dim=-1, keepdim=True).clamp(min=1e-12)
    return torch.where(r <= 1.0, q, (2.0 - 1.0 / r) * q / r)


def bilinear_taps(uv: Tensor, side: int) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """The four texels under each texture coordinate, as ``grid_sample`` picks them
    (``align_corners=False``, ``padding_mode="border"``).

    Args:
        uv: (n, 2) coordinates in [-1, 1] (x: column, y: row); side: texels per side.

    Returns:
        ``rows (n, 4)`` texel rows (row-major) of the corners 00, 01 (x + 1), 10 (y + 1), 11;
        ``fx, fy (n,)`` the fractions between them; ``inside (n, 2)`` 1 where the coordinate
        is not clamped to the border (its derivative is 0 there).
    """
    g = ((uv + 1.0) * side - 1.0) / 2.0  # texel coordinates, texel centres at integers
    inside = ((g >= 0) & (g <= side - 1)).to(uv.dtype)
    g = g.clamp(0, side - 1)
    i = g.floor().clamp(max=max(side - 2, 0))
    f = g - i
    i = i.long()
    x0, y0 = i[:, 0], i[:, 1]
    x1, y1 = (x0 + 1).clamp(max=side - 1), (y0 + 1).clamp(max=side - 1)
    rows = torch.stack([y0 * side + x0, y0 * side + x1, y1 * side + x0, y1 * side + x1], dim=1)
    return rows, f[:, 0], f[:, 1], inside


class _SparseTexture(torch.autograd.Function):
    """Bilinear texture lookup whose texture gradient goes into a GradSink (touched rows
    only, no dense ``.grad``); the coordinates get their ordinary gradient."""

    @staticmethod
    def forward(ctx, tex, uv, side, sink):
        rows, fx, fy, inside = bilinear_taps(uv.detach(), side)
        t = tex.detach()[rows]  # (n, 4, C)
        w = torch.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], dim=1)
        ctx.save_for_backward(t, w, fx, fy, inside, rows)
        ctx.side, ctx.sink = side, sink
        return (w.unsqueeze(-1) * t).sum(1)

    @staticmethod
    def backward(ctx, g):
        t, w, fx, fy, inside, rows = ctx.saved_tensors
        sink, side = ctx.sink, ctx.side
        if ctx.needs_input_grad[0]:
            contrib = (w.unsqueeze(-1) * g.unsqueeze(1)).reshape(-1, g.shape[1])
            flat = rows.reshape(-1)
            sink.grad[0].index_add_(0, flat, contrib.to(sink.grad.dtype))
            sink.touched[flat] = 1
            sink.dirty = True
        g_uv = None
        if ctx.needs_input_grad[1]:
            fx_, fy_ = fx.unsqueeze(-1), fy.unsqueeze(-1)
            dx = (1 - fy_) * (t[:, 1] - t[:, 0]) + fy_ * (t[:, 3] - t[:, 2])  # d value / d texel x
            dy = (1 - fx_) * (t[:, 2] - t[:, 0]) + fx_ * (t[:, 3] - t[:, 1])
            g_uv = torch.stack([(g * dx).sum(-1), (g * dy).sum(-1)], dim=-1) * inside * (side / 2.0)
        return None, g_uv, None, None


def sample_texture(tex: Tensor, side: int, uv: Tensor, sink=None) -> Tensor:
    """Bilinear lookup of a (side * side, C) row-major texture at (n, 2) coordinates in
    [-1, 1] -> (n, C), exactly ``F.grid_sample(..., align_corners=False,
    padding_mode="border")``. With a ``sink`` (:class:`~nerfkit.kernels.ops.GradSink`)
    the texture's gradient is added there, sparsely, instead of into ``tex.grad``."""
    if sink is not None and tex.requires_grad and torch.is_grad_enabled():
        return _SparseTexture.apply(tex, uv, side, sink)
    img = tex.reshape(1, side, side, -1).permute(0, 3, 1, 2)
    out = F.grid_sample(img, uv.reshape(1, 1, -1, 2).to(img.dtype), mode="bilinear", padding_mode="border",
                        align_corners=False)
    return out[0, :, 0].t()


# initial coverage logit of the table plane: opaque (0.98) everywhere
COVER_INIT = 4.0


class TablePlane(nn.Module):
    """An opaque textured plane: where rays stop and which colour they see there.

    The texture is the sum of a coarse and a fine grid of colour logits (the coarse one
    fills what few rays see quickly), sampled bilinearly at the contracted plane
    coordinates ``contract_disc((p - origin) . (e1, e2) / radius) / 2`` in [-1, 1]^2.
    Each texture is a (texels, 3) parameter (a row per texel, row-major), so a sparse
    optimizer can update only the texels a step's rays touched: a texel is seen by few
    rays, and dense Adam's momentum would keep moving it long after its one noisy hit.

    A real table ends: beyond its edge the photos show the floor and the room, from each
    view a different part of it. A third, single-channel texture (a quarter of the fine
    one's size per side) holds the plane's *coverage* logit, opaque at first: where it
    learns to be transparent, rays see the room instead (:meth:`coverage`).

    Args:
        plane: (4,) ``(n, d)``, unit normal toward the cameras.
        center: (3,) the object's centre; its foot on the plane is the texture's centre.
        radius: plane distance from that foot kept at full texture resolution (the rest
            of the plane is contracted).
        resolution: texels per side of the fine texture (half of them cover the disc of
            ``radius``); the coarse texture has 1/16 as many per side.
    """

    def __init__(self, plane, center, radius: float, resolution: int = 512):
        super().__init__()
        plane = torch.as_tensor(plane, dtype=torch.float32).reshape(4)
        n = plane[:3] / plane[:3].norm()
        c = torch.as_tensor(center, dtype=torch.float32).reshape(3)
        origin = c - (c @ n + plane[3]) * n
        helper = torch.tensor([1.0, 0.0, 0.0]) if abs(float(n[0])) < 0.9 else torch.tensor([0.0, 1.0, 0.0])
        e1 = torch.linalg.cross(n, helper)
        e1 = e1 / e1.norm()
        e2 = torch.linalg.cross(n, e1)
        self.register_buffer("plane", torch.cat([n, plane[3:]]))
        self.register_buffer("origin", origin)
        self.register_buffer("axes", torch.stack([e1, e2], dim=1))  # (3, 2)
        self.radius = float(radius)
        self.sizes = (int(resolution), max(int(resolution) // 16, 2))
        self.fine = nn.Parameter(torch.zeros(self.sizes[0] ** 2, 3))
        self.coarse = nn.Parameter(torch.zeros(self.sizes[1] ** 2, 3))
        self.cover_size = max(int(resolution) // 4, 2)
        self.cover = nn.Parameter(torch.full((self.cover_size ** 2, 1), COVER_INIT))

    def textures(self) -> list[tuple[nn.Parameter, int]]:
        """``(parameter (side * side, C), side)`` of the fine and coarse colour textures
        and the coverage texture."""
        return [(self.fine, self.sizes[0]), (self.coarse, self.sizes[1]), (self.cover, self.cover_size)]

    def hit(self, origins: Tensor, dirs: Tensor) -> Tensor:
        """(n,) distance to the plane along each ray, ``inf`` for rays that miss it."""
        with torch.autocast(origins.device.type, enabled=False):
            return plane_hit(origins.float(), dirs.float(), self.plane)

    def texture_coords(self, points: Tensor) -> Tensor:
        """(n, 3) points on the plane -> (n, 2) texture coordinates in [-1, 1]."""
        q = (points - self.origin) @ self.axes / self.radius
        return 0.5 * contract_disc(q)

    def colour(self, points: Tensor, sinks: dict | None = None) -> Tensor:
        """(n, 3) points on the plane -> (n, 3) colours in (0, 1). ``sinks``: a GradSink
        per texture parameter, to receive the texture gradients sparsely."""
        sinks = sinks or {}
        with torch.autocast(points.device.type, enabled=False):  # texel indices need float32
            uv = self.texture_coords(points.float())
            return torch.sigmoid(sum(sample_texture(t, side, uv, sinks.get(t)) for t, side in self.textures()[:2]))

    def coverage(self, points: Tensor, sinks: dict | None = None) -> Tensor:
        """(n, 3) points on the plane -> (n,) how opaque the plane is there, in (0, 1)."""
        sinks = sinks or {}
        with torch.autocast(points.device.type, enabled=False):
            uv = self.texture_coords(points.float())
            return torch.sigmoid(sample_texture(self.cover, self.cover_size, uv, sinks.get(self.cover))[:, 0])
