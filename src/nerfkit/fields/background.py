"""What rays see beyond a model's box: the room and the table.

A real capture shows an object standing on a table in a room. Inside its box a model
represents the object with density; beyond the box the photos still show the table
(with parallax: it is a plane, not a colour per direction) and the room. Filling that
with density makes haze and floaters; a flat colour makes dark surfaces see-through.

* :func:`sh16`: the basis of a smooth colour per ray direction (real spherical harmonics
  up to degree 3), for what is farthest.
* :class:`RoomShells`: the room as a few textured, semi-transparent spheres around the
  cameras (a multi-sphere image), so that it shows parallax.
* :class:`TablePlane`: an opaque textured plane (the tag's plane in a tag capture). Rays
  stop where they meet it; its texture lives on a 2D grid in *contracted* plane
  coordinates (mip-NeRF 360's contraction in 2D), so a finite texture covers the whole
  infinite plane, finely near the object and ever more coarsely far from it. A glossy
  table also mirrors a small learned map of its surroundings; a floor under the table is
  a second such plane.
* :func:`composite_layers`: front-to-back compositing of these surfaces along each ray;
  :func:`layers_depth`: the distance of the surface a ray meets among them.
"""

from __future__ import annotations

import math
from typing import cast

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from ..cameras import axes_across, pixel_to_ray, plane_hit


def sh16(dirs: Tensor) -> Tensor:
    """(n, 3) unit directions -> (n, 16): the real spherical harmonics up to degree 3
    (unnormalised), a smooth basis for a colour per direction."""
    x, y, z = dirs[:, 0], dirs[:, 1], dirs[:, 2]
    one = torch.ones_like(x)
    return torch.stack(
        [
            one,
            x,
            y,
            z,
            x * y,
            y * z,
            x * z,
            x * x - y * y,
            3 * z * z - 1,
            x * (x * x - 3 * y * y),
            y * (3 * x * x - y * y),
            z * (x * x - y * y),
            x * y * z,
            x * (5 * z * z - 1),
            y * (5 * z * z - 1),
            z * (5 * z * z - 3),
        ],
        dim=-1,
    )


def plane_footprint(views, plane, center, radius: float, stride: int = 8) -> float | None:
    """Median side (scene units) of the patch of ``plane`` one pixel of the photos ``views``
    sees, over the pixels (every ``stride``-th row and column) whose rays meet the plane
    (:func:`plane_hit`) within ``radius`` of ``center``'s foot on it; None when no ray does.

    A pixel's patch has the area ``t^2 cos^3(phi) / (fx fy cos(theta))`` for a ray meeting
    the plane after ``t`` at ``theta`` from its normal, ``phi`` off the optical axis; the side
    is its square root. ``views``: ``c2w`` (n, 4, 4), ``K`` (n, 3, 3), ``width``, ``height``;
    ``plane``: (4,) ``(n, d)``, the normal toward the cameras. Example: a camera 1 m straight
    above the plane with ``fx = fy = 1000`` sees 1 mm a pixel at the image centre."""
    f64 = torch.float64
    plane_t = torch.as_tensor(np.asarray(plane, np.float64))
    normal, c = plane_t[:3], torch.as_tensor(np.asarray(center, np.float64))
    foot = c - (c @ normal + plane_t[3]) * normal
    rows, cols = torch.meshgrid(
        torch.arange(stride // 2, views.height, stride, dtype=f64),
        torch.arange(stride // 2, views.width, stride, dtype=f64),
        indexing="ij",
    )
    uv = torch.stack([cols, rows], dim=-1).reshape(-1, 2) + 0.5
    sides = []
    for K, c2w in zip(
        torch.as_tensor(np.asarray(views.K, np.float64)),
        torch.as_tensor(np.asarray(views.c2w, np.float64)),
        strict=True,
    ):
        o, d = pixel_to_ray(K, c2w, uv)
        t = plane_hit(o, d, plane_t)
        hit = torch.isfinite(t)
        t, d = t[hit], d[hit]
        near = torch.linalg.norm(o[hit] + d * t.unsqueeze(-1) - foot, dim=-1) <= radius
        cos_phi = d @ c2w[:3, 2]  # (the camera's +z: its optical axis)
        area = t**2 * cos_phi**3 / (K[0, 0] * K[1, 1] * -(d @ normal))
        sides.append(area[near].sqrt())
    every = torch.cat(sides) if sides else torch.zeros(0, dtype=f64)
    return float(np.median(every.numpy())) if len(every) else None  # (torch.median takes the lower middle)


def contract_disc(q: Tensor) -> Tensor:
    """mip-NeRF 360's contraction in 2D: (n, 2) -> (n, 2) inside the disc of radius 2.

    ``q`` for ``|q| <= 1``, ``(2 - 1 / |q|) q / |q|`` beyond: the unit disc keeps its
    scale, the rest of the plane is squeezed into the ring ``1 < r < 2``.
    """
    r = torch.linalg.norm(q, dim=-1, keepdim=True).clamp(min=1e-12)
    return torch.where(r <= 1.0, q, (2.0 - 1.0 / r) * q / r)


def _wh(size) -> tuple[int, int]:
    """A texture size given as ``side`` (square) or ``(width, height)`` -> (width, height)."""
    return (int(size), int(size)) if isinstance(size, int) else (int(size[0]), int(size[1]))


def bilinear_taps(uv: Tensor, size) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """The four texels under each texture coordinate, as ``grid_sample`` picks them
    (``align_corners=False``, ``padding_mode="border"``).

    Args:
        uv: (n, 2) coordinates in [-1, 1] (x: column, y: row); size: texels per side, or
            ``(width, height)``.

    Returns:
        ``rows (n, 4)`` texel rows (row-major) of the corners 00, 01 (x + 1), 10 (y + 1), 11;
        ``fx, fy (n,)`` the fractions between them; ``inside (n, 2)`` 1 where the coordinate
        is not clamped to the border (its derivative is 0 there).
    """
    w, h = _wh(size)
    dims = uv.new_tensor([w, h])
    g = ((uv + 1.0) * dims - 1.0) / 2.0  # texel coordinates, texel centres at integers
    inside = ((g >= 0) & (g <= dims - 1)).to(uv.dtype)
    g = torch.minimum(g.clamp(min=0), dims - 1)
    i = torch.minimum(g.floor(), (dims - 2).clamp(min=0))
    f = g - i
    i = i.long()
    x0, y0 = i[:, 0], i[:, 1]
    x1, y1 = (x0 + 1).clamp(max=w - 1), (y0 + 1).clamp(max=h - 1)
    rows = torch.stack([y0 * w + x0, y0 * w + x1, y1 * w + x0, y1 * w + x1], dim=1)
    return rows, f[:, 0], f[:, 1], inside


class _SparseTexture(torch.autograd.Function):
    """Bilinear texture lookup whose texture gradient goes into a GradSink (touched rows
    only, no dense ``.grad``); the coordinates get their ordinary gradient. On the CPU the
    compiled kernels (:func:`~nerfkit.kernels.grid_numba.texture_forward`, ``texture_backward``)
    do it in one pass each; the torch code here is their reference."""

    @staticmethod
    def forward(ctx, tex, uv, size, sink, compiled):
        (w, h), texd = _wh(size), tex.detach()
        ctx.dims, ctx.sink = (w, h), sink
        nb = _compiled(texd, sink) if compiled else None
        if nb is not None:
            uv32 = uv.detach().float().contiguous()
            n = uv32.shape[0]
            rows = torch.empty((n, 4), dtype=torch.int64)
            frac, inside = torch.empty((n, 2)), torch.empty((n, 2))
            out = torch.empty((n, texd.shape[1]))
            nb.texture_forward(
                texd.numpy(), uv32.numpy(), w, h, rows.numpy(), frac.numpy(), inside.numpy(), out.numpy()
            )
            ctx.save_for_backward(texd, rows, frac, inside)
            ctx.compiled = nb
            return out
        rows, fx, fy, inside = bilinear_taps(uv.detach(), size)
        ctx.save_for_backward(texd, rows, torch.stack([fx, fy], dim=-1), inside)
        ctx.compiled = None
        return (_tap_weights(fx, fy).unsqueeze(-1) * texd[rows]).sum(1)

    @staticmethod
    def backward(ctx, g):
        tex, rows, frac, inside = ctx.saved_tensors
        sink, (w, h), nb = ctx.sink, ctx.dims, ctx.compiled
        want_tex, want_uv = ctx.needs_input_grad[0], ctx.needs_input_grad[1]
        if nb is not None and want_tex:
            g_uv = torch.zeros_like(frac)
            nb.texture_backward(
                g.float().contiguous().numpy(),
                tex.numpy(),
                rows.numpy(),
                frac.numpy(),
                inside.numpy(),
                w,
                h,
                sink.grad.numpy(),
                sink.touched.numpy(),
                g_uv.numpy(),
                want_uv,
            )
            sink.dirty = True
            return None, (g_uv.to(g.dtype) if want_uv else None), None, None, None
        fx, fy = frac[:, 0], frac[:, 1]
        if want_tex:
            contrib = (_tap_weights(fx, fy).unsqueeze(-1) * g.unsqueeze(1)).reshape(-1, g.shape[1])
            flat = rows.reshape(-1)
            sink.grad[0].index_add_(0, flat, contrib.to(sink.grad.dtype))
            sink.touched[flat] = 1
            sink.dirty = True
        g_uv = None
        if want_uv:
            t = tex[rows]  # (n, 4, C)
            fx_, fy_ = fx.unsqueeze(-1), fy.unsqueeze(-1)
            dx = (1 - fy_) * (t[:, 1] - t[:, 0]) + fy_ * (t[:, 3] - t[:, 2])  # d value / d texel x
            dy = (1 - fx_) * (t[:, 2] - t[:, 0]) + fx_ * (t[:, 3] - t[:, 1])
            half = g.new_tensor((w, h)) / 2.0
            g_uv = torch.stack([(g * dx).sum(-1), (g * dy).sum(-1)], dim=-1) * inside * half
        return None, g_uv, None, None, None


def _tap_weights(fx: Tensor, fy: Tensor) -> Tensor:
    """(n, 4) bilinear weights of the corners 00, 01, 10, 11 of :func:`bilinear_taps`."""
    return torch.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], dim=1)


def _compiled(tex: Tensor, sink):
    """The compiled kernels for a float32 CPU texture and sink, else None (torch path)."""
    if (
        tex.device.type != "cpu"
        or tex.dtype != torch.float32
        or sink.grad.device.type != "cpu"
        or sink.grad.dtype != torch.float32
        or not tex.is_contiguous()
    ):
        return None
    from ..kernels import numba_kernels

    return numba_kernels()


def sample_texture(tex: Tensor, size, uv: Tensor, sink=None, compiled: bool = True) -> Tensor:
    """Bilinear lookup of a (height * width, C) row-major texture at (n, 2) coordinates in
    [-1, 1] -> (n, C), exactly ``F.grid_sample(..., align_corners=False,
    padding_mode="border")``. ``size``: texels per side, or ``(width, height)``. With a
    ``sink`` (:class:`~nerfkit.kernels.ops.GradSink`) the texture's gradient is added
    there, sparsely, instead of into ``tex.grad``: through the compiled kernels when
    ``compiled`` and they can run (a float32 CPU texture and sink), else in torch."""
    if sink is not None and tex.requires_grad and torch.is_grad_enabled():
        return _SparseTexture.apply(tex, uv, size, sink, compiled)
    w, h = _wh(size)
    img = tex.reshape(1, h, w, -1).permute(0, 3, 1, 2)
    out = F.grid_sample(
        img, uv.reshape(1, 1, -1, 2).to(img.dtype), mode="bilinear", padding_mode="border", align_corners=False
    )
    return out[0, :, 0].t()


# initial coverage logit of the table plane: opaque (0.98) everywhere
COVER_INIT = 4.0
# initial glossiness logit of a glossy table plane: a faint mirror (0.05) everywhere
GLOSS_INIT = -3.0
# texels of a glossy plane's mirrored surroundings (around, zenith to horizon): the
# sheen of a varnished table is blurry, so a coarse map does as well as finer ones and the
# finest tried did worse (`--table-gloss` in BENCHMARKS.md)
ENV_SIZE = (32, 8)
# a table's relief (``relief=True``): its height per texel, in units of this fraction of the
# texture's radius, so that a sparse Adam step of the table's learning rate moves it a fraction
# of a millimetre on a table-top capture (`--table-relief` in BENCHMARKS.md)
RELIEF_UNIT = 0.01
# a ray grazing the plane would move far along itself for a small relief: its slope is capped
RELIEF_MIN_COS = 0.05


def texel_side(radius: float, resolution: int) -> float:
    """Side of one fine texel of a :class:`TablePlane` of ``radius`` and ``resolution`` texels a
    side, within the disc of ``radius`` (half the texels span its diameter, see
    :meth:`TablePlane.texture_coords`): ``4 radius / resolution``."""
    return 4.0 * radius / resolution


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
    learns to be transparent, rays see the room instead (:meth:`look`).

    Args:
        plane: (4,) ``(n, d)``, unit normal toward the cameras.
        center: (3,) the object's centre; its foot on the plane is the texture's centre.
        radius: plane distance from that foot kept at full texture resolution (the rest
            of the plane is contracted).
        resolution: texels per side of the fine texture (half of them cover the disc of
            ``radius``); the coarse texture has 1/16 as many per side.
        gloss: also learn a glossiness per texel and a small map of the surroundings that
            the table mirrors (``ENV_SIZE``).
        relief: also learn a height above the plane per texel (the coverage's resolution):
            a sheet of paper that curls, a plane a little off the true table. A ray then
            meets the table where it meets that height over its hit on the plane (one
            parallax step, :meth:`raise_hits`).
        tags: (n, 4, 3) corners of the printed tags on the plane; with ``tag_texels`` > 0 each
            gets a fine colour texture of that many texels a side over its square doubled,
            added to the table's colour there (:meth:`tag_detail`), zero at first.
    """

    plane: Tensor
    origin: Tensor
    axes: Tensor
    tag_frames: Tensor | None  # (n_tags, 3, 3): each tag's centre, then its axes over their squared lengths

    def __init__(
        self,
        plane,
        center,
        radius: float,
        resolution: int = 512,
        gloss: bool = False,
        relief: bool = False,
        tags=None,
        tag_texels: int = 0,
    ):
        super().__init__()
        plane = torch.as_tensor(plane, dtype=torch.float32).reshape(4)
        n = plane[:3] / plane[:3].norm()
        c = torch.as_tensor(center, dtype=torch.float32).reshape(3)
        origin = c - (c @ n + plane[3]) * n
        e1, e2 = (torch.as_tensor(v, dtype=torch.float32) for v in axes_across(n.numpy()))
        self.register_buffer("plane", torch.cat([n, plane[3:]]))
        self.register_buffer("origin", origin)
        self.register_buffer("axes", torch.stack([e1, e2], dim=1))  # (3, 2)
        self.radius = float(radius)
        self.sizes = (int(resolution), max(int(resolution) // 16, 2))
        self.fine = nn.Parameter(torch.zeros(self.sizes[0] ** 2, 3))
        self.coarse = nn.Parameter(torch.zeros(self.sizes[1] ** 2, 3))
        self.cover_size = max(int(resolution) // 4, 2)
        self.cover = nn.Parameter(torch.full((self.cover_size**2, 1), COVER_INIT))
        if relief:
            self.relief = nn.Parameter(torch.zeros(self.cover_size**2, 1))
        else:
            self.register_parameter("relief", None)
        # a fine colour texture over each printed tag's square doubled (the tag and its white border)
        self.tag_texels = int(tag_texels) if tags is not None and len(tags) else 0
        frames = []
        if self.tag_texels:
            for q in np.asarray(tags, np.float64).reshape(-1, 4, 3):
                e1, e2 = q[1] - q[0], q[3] - q[0]
                frames.append(np.stack([q.mean(0), e1 / (e1 @ e1), e2 / (e2 @ e2)]))
        # (no buffer without tags: a model file from before the tags' texture loads as it was)
        tag_frames = torch.as_tensor(np.array(frames, np.float32).reshape(-1, 3, 3)) if frames else None
        self.register_buffer("tag_frames", tag_frames)
        self.tag_fine = nn.ParameterList([nn.Parameter(torch.zeros(self.tag_texels**2, 3)) for _ in range(len(frames))])
        if gloss:
            self.shine = nn.Parameter(torch.full((self.cover_size**2, 1), GLOSS_INIT))
            self.env = nn.Parameter(torch.zeros(ENV_SIZE[0] * ENV_SIZE[1], 3))
        else:
            self.register_parameter("shine", None)
            self.register_parameter("env", None)

    def textures(self) -> list[tuple[nn.Parameter, int]]:
        """``(parameter (side * side, C), side)`` of the fine and coarse colour textures,
        the coverage texture, and the glossiness and relief textures (if any)."""
        out = [(self.fine, self.sizes[0]), (self.coarse, self.sizes[1]), (self.cover, self.cover_size)]
        out += [(t, self.cover_size) for t in (self.shine, self.relief) if t is not None]
        return out + [(t, self.tag_texels) for t in self.tag_fine]

    def tag_detail(self, logits: Tensor, points: Tensor, sinks: dict, compiled: bool) -> Tensor:
        """``logits`` (n, 3) of the colour at ``points`` (n, 3) plus each tag's fine texture
        where the point lies in that tag's square doubled."""
        assert self.tag_frames is not None, "tag_detail: this table has no tags' texture"
        for frame, tex in zip(self.tag_frames, self.tag_fine, strict=True):
            uv = (points - frame[0]) @ frame[1:].t()  # (n, 2): the tag's square at |u|, |v| < 0.5
            idx = (uv.abs() < 1.0).all(-1).nonzero()[:, 0]
            if len(idx):
                detail = sample_texture(tex, self.tag_texels, uv[idx], sinks.get(tex), compiled)
                logits = logits.index_add(0, idx, detail)
        return logits

    def raise_hits(
        self, points: Tensor, dirs: Tensor, sinks: dict | None = None, compiled: bool = True
    ) -> tuple[Tensor, Tensor]:
        """Where rays meet the relief: ``points`` (n, 3) where rays along ``dirs`` (n, 3)
        meet the plane -> ``(points', dt)``, each moved along its ray by ``dt`` (n,) to the
        height ``h`` of the relief at ``points``: ``dt = h / (d . n)`` (exact where the relief
        is flat; the slope ``d . n`` is capped at ``-RELIEF_MIN_COS``). A table built with
        ``relief`` only."""
        tex = self.relief
        assert tex is not None, "raise_hits: this table has no relief"
        with torch.autocast(points.device.type, enabled=False):
            uv = self.texture_coords(points.float())
            h = (
                RELIEF_UNIT
                * self.radius
                * sample_texture(tex, self.cover_size, uv, (sinks or {}).get(tex), compiled)[:, 0]
            )
            dt = h / (dirs.float() @ self.plane[:3]).clamp(max=-RELIEF_MIN_COS)
            return points.float() + dirs.float() * dt.unsqueeze(-1), dt

    def hit(self, origins: Tensor, dirs: Tensor) -> Tensor:
        """(n,) distance to the plane along each ray, ``inf`` for rays that miss it."""
        with torch.autocast(origins.device.type, enabled=False):
            return plane_hit(origins.float(), dirs.float(), self.plane)

    def texture_coords(self, points: Tensor) -> Tensor:
        """(n, 3) points on the plane -> (n, 2) texture coordinates in [-1, 1]."""
        q = (points - self.origin) @ self.axes / self.radius
        return 0.5 * contract_disc(q)

    def look(
        self, points: Tensor, sinks: dict | None = None, gloss: bool = False, compiled: bool = True
    ) -> tuple[Tensor, Tensor, Tensor | None]:
        """(n, 3) points on the plane -> colour (n, 3), coverage (n,) and, with ``gloss``
        (a glossy plane), glossiness (n,), all in (0, 1), from one set of texture
        coordinates. ``sinks``: a GradSink per texture parameter, to receive the texture
        gradients sparsely; ``compiled``: through the compiled kernels when they can run."""
        sinks = sinks or {}
        with torch.autocast(points.device.type, enabled=False):  # texel indices need float32
            uv = self.texture_coords(points.float())
            logits = cast(
                Tensor, sum(sample_texture(t, side, uv, sinks.get(t), compiled) for t, side in self.textures()[:2])
            )
            if self.tag_texels:
                logits = self.tag_detail(logits, points.float(), sinks, compiled)
            colour = torch.sigmoid(logits)
            cover = self._scalar(self.cover, uv, sinks, compiled)
            shine = self._scalar(self.shine, uv, sinks, compiled) if gloss and self.shine is not None else None
        return colour, cover, shine

    def _scalar(self, tex: Tensor, uv: Tensor, sinks: dict, compiled: bool) -> Tensor:
        return torch.sigmoid(sample_texture(tex, self.cover_size, uv, sinks.get(tex), compiled)[:, 0])

    def colour(self, points: Tensor, sinks: dict | None = None) -> Tensor:
        """(n, 3) points on the plane -> (n, 3) colours in (0, 1)."""
        return self.look(points, sinks)[0]

    def reflection(self, dirs: Tensor) -> Tensor:
        """(n, 3) reflected directions -> (n, 3) colour of the surroundings mirrored that
        way: a small texture over the hemisphere above the plane (x: azimuth, y: from the
        zenith, top row, to the horizon)."""
        with torch.autocast(dirs.device.type, enabled=False):
            d = F.normalize(dirs.float(), dim=-1)
            up = (d @ self.plane[:3]).clamp(0.0, 1.0 - 1e-6)
            local = d @ self.axes
            flat = (local.abs().sum(-1) < 1e-9) * 1e-9
            azimuth = torch.atan2(local[:, 1], local[:, 0] + flat) / math.pi
            v = 1.0 - 2.0 * torch.asin(up) / (0.5 * math.pi)
            return torch.sigmoid(sample_texture(self.env, ENV_SIZE, torch.stack([azimuth, v], dim=-1)))


def table_doubt(clear: Tensor) -> Tensor:
    """(n,) ``4 c (1 - c)`` of the share of light ``c`` (n,) a plane lets through: 0 where
    it is surely there (opaque) or surely not (clear), 1 at half; a prior that a table is
    there or not, not a see-through blend of itself and the room beneath."""
    return 4.0 * clear * (1.0 - clear)


def sphere_exit(origins: Tensor, dirs: Tensor, center: Tensor, radii: Tensor) -> Tensor:
    """Distance along each ray to where it leaves each sphere around ``center``.

    Args:
        origins, dirs: (n, 3) (directions need not be unit); center: (3,); radii: (k,).

    Returns:
        (n, k) the larger root of ``|o + t d - c| = r``; ``inf`` where the ray misses the
        sphere or leaves it behind its origin. Example: from the centre along a unit
        direction, ``t = r``.
    """
    oc = origins - center
    a = (dirs * dirs).sum(-1, keepdim=True).clamp(min=1e-20)  # (n, 1)
    b = (dirs * oc).sum(-1, keepdim=True)
    c = (oc * oc).sum(-1, keepdim=True) - radii.to(oc) ** 2  # (n, k)
    disc = b * b - a * c
    meets = disc > 0
    t = (-b + torch.where(meets, disc, 1.0).sqrt()) / a  # sqrt(0)'s infinite slope would make NaN gradients
    return torch.where(meets & (t > 0), t, torch.full_like(t, math.inf))


def layer_weights(t: Tensor, alpha: Tensor) -> tuple[Tensor, Tensor]:
    """Front-to-back compositing weights of a few surfaces per ray.

    Args:
        t: (n, k) distance of each layer along the ray (any order; ``inf``: not on this
            ray, give it alpha 0); alpha: (n, k) opacity in [0, 1].

    Returns:
        (n, k) ``T_j alpha_j`` in the layers' given order, with ``T_j`` the product of
        ``1 - alpha_i`` over the layers nearer than ``j``; and (n, 1) the transmittance
        through all of them.
    """
    order = torch.argsort(t, dim=1)
    a = torch.gather(alpha, 1, order)
    keep = torch.cumprod(1.0 - a, dim=1)  # (n, k) transmittance after each layer
    trans = torch.cat([torch.ones_like(keep[:, :1]), keep[:, :-1]], dim=1)
    weights = torch.empty_like(a).scatter_(1, order, trans * a)
    return weights, keep[:, -1:]


def composite_layers(t: Tensor, rgb: Tensor, alpha: Tensor, behind: Tensor) -> Tensor:
    """Front-to-back alpha compositing of a few surfaces per ray, in order of distance.

    Args:
        t: (n, k) distance of each layer along the ray (``inf``: not on this ray, give it
            alpha 0); rgb: (n, k, 3); alpha: (n, k) opacity in [0, 1]; behind: (n, 3) what
            is seen through all of them.

    Returns:
        (n, 3) ``sum_j T_j alpha_j rgb_j + T_k behind`` over the layers sorted by ``t``,
        with ``T_j = prod_{i<j} (1 - alpha_i)``.
    """
    weights, through = layer_weights(t, alpha)
    return (weights.unsqueeze(-1) * rgb).sum(1) + through * behind


def layers_depth(t: Tensor, alpha: Tensor) -> tuple[Tensor, Tensor]:
    """The distance of the surface a ray meets among a few: the first one after which
    less than half of the light is left (the median depth), not a blend of distances.

    A capture's table lets some light through where it draws the room's reflection (its
    coverage under 1); an expected depth there mixes the table's distance with the room's
    beneath it, and the table's depth comes out speckled.

    Args:
        t: (n, k) distance of each layer along the ray (any order; ``inf``: not on this
            ray, give it alpha 0); alpha: (n, k) opacity in [0, 1].

    Returns:
        (n,) the distance times ``met`` and (n,) ``met`` in {0, 1} (as a volume's
        unnormalised depth and opacity: divide by it for the distance); ``met`` is 0 where
        more than half of the light passes every layer.
    """
    order = torch.argsort(t, dim=1)
    ts = torch.gather(t, 1, order)
    left = torch.cumprod(1.0 - torch.gather(alpha, 1, order), dim=1)  # (n, k) after each layer
    crossed = (left < 0.5) & torch.isfinite(ts)
    met = crossed.any(dim=1)
    first = torch.gather(ts, 1, crossed.int().argmax(dim=1, keepdim=True))[:, 0]
    return torch.where(met, first, torch.zeros_like(first)), met.to(t.dtype)


# initial opacity logit of the room shells: sigmoid(-1) = 0.27 each
SHELL_ALPHA_INIT = -1.0


class RoomShells(nn.Module):
    """The room around a capture as a few semi-transparent textured spheres (a multi-sphere
    image, as NeRF++'s inverted-sphere background discretised): unlike a colour per
    direction, a surface at the right shell moves against the object as the camera moves.

    Shell ``k`` has radius ``r0 * ratio ** k`` around ``center``; every training camera is
    inside the first one. Each shell holds an RGBA texture (logits; a fine and a coarse
    grid summed, like :class:`TablePlane`) in equirectangular coordinates about ``up``:
    x is the azimuth, y the elevation (top row up). All shells live in one tall texture
    (shell ``k`` in rows ``k * height ...``), sampled sparsely.

    Args:
        center: (3,); up: (3,) world up; r0: radius of the first shell; n_shells; ratio;
        width: texels around the fine texture (height ``width // 2``).
    """

    center: Tensor
    frame: Tensor
    radii: Tensor

    def __init__(self, center, up, r0: float, n_shells: int = 3, ratio: float = 2.5, width: int = 1024):
        super().__init__()
        up = torch.as_tensor(np.asarray(up, np.float32)).reshape(3)
        up = up / up.norm()
        e1, e2 = (torch.as_tensor(v, dtype=torch.float32) for v in axes_across(up.numpy()))
        self.register_buffer("center", torch.as_tensor(np.asarray(center, np.float32)).reshape(3))
        self.register_buffer("frame", torch.stack([e1, e2, up], dim=1))  # (3, 3) world -> (x, y, up)
        self.register_buffer("radii", float(r0) * float(ratio) ** torch.arange(int(n_shells), dtype=torch.float32))
        self.n_shells = int(n_shells)
        w = max(int(width) // 2 * 2, 4)
        self.sizes = ((w, w // 2), (max(w // 16, 2), max(w // 32, 2)))  # fine, coarse (width, height)
        self.fine = nn.Parameter(self._init(*self.sizes[0]))
        self.coarse = nn.Parameter(torch.zeros(self.n_shells * self.sizes[1][0] * self.sizes[1][1], 4))

    def _init(self, w: int, h: int) -> Tensor:
        tex = torch.zeros(self.n_shells * w * h, 4)
        tex[:, 3] = SHELL_ALPHA_INIT
        return tex

    def textures(self) -> list[tuple[nn.Parameter, tuple[int, int]]]:
        """``(parameter (n_shells * height * width, 4), (width, height * n_shells))``."""
        return [(p, (w, h * self.n_shells)) for p, (w, h) in zip((self.fine, self.coarse), self.sizes)]

    def layers(
        self, origins: Tensor, dirs: Tensor, sinks: dict | None = None, compiled: bool = True
    ) -> tuple[Tensor, Tensor, Tensor]:
        """Where each ray leaves each shell and what it sees there.

        Returns ``t (n, k)`` (``inf`` where a ray misses a shell), ``rgb (n, k, 3)`` and
        ``alpha (n, k)`` (0 on missed shells). ``sinks`` and ``compiled``: as in
        :meth:`TablePlane.look`.
        """
        sinks = sinks or {}
        n, k = origins.shape[0], self.n_shells
        with torch.autocast(origins.device.type, enabled=False):
            o, d = origins.float(), dirs.float()
            t = sphere_exit(o, d, self.center, self.radii)  # (n, k)
            hit = torch.isfinite(t)
            p = o.unsqueeze(1) + torch.where(hit, t, 0.0).unsqueeze(-1) * d.unsqueeze(1)  # (n, k, 3)
            local = ((p - self.center) @ self.frame) / self.radii.view(1, k, 1)
            # (the tiny offsets keep atan2's and asin's gradients finite at the poles)
            on_axis = (local[..., 0].abs() + local[..., 1].abs()) < 1e-9
            azimuth = torch.atan2(local[..., 1], local[..., 0] + on_axis * 1e-9) / math.pi  # (n, k) in [-1, 1]
            elevation = torch.asin(local[..., 2].clamp(-1.0 + 1e-6, 1.0 - 1e-6)) / (0.5 * math.pi)
            logits: Tensor | float = 0.0
            for tex, (w, h) in zip((self.fine, self.coarse), self.sizes):
                # row within the shell's band, kept half a texel off its edges so that the
                # bilinear taps never reach the next shell
                row = ((1.0 - elevation) * 0.5 * h).clamp(0.5, h - 0.5)
                shell = torch.arange(k, device=o.device).view(1, k)
                y = (shell * h + row) / (k * h) * 2.0 - 1.0
                uv = torch.stack([azimuth, y], dim=-1).reshape(-1, 2)
                logits = logits + sample_texture(tex, (w, h * k), uv, sinks.get(tex), compiled).reshape(n, k, 4)
            assert isinstance(logits, Tensor)  # (two textures, always)
            rgb = torch.sigmoid(logits[..., :3])
            alpha = torch.sigmoid(logits[..., 3]) * hit
        return torch.where(hit, t, math.inf), rgb, alpha
