"""What rays see beyond a model's box: the generic pieces a capture's surroundings are built of.

* :func:`sh16`: the basis of a smooth colour per ray direction (real spherical harmonics
  up to degree 3), for what is farthest.
* :func:`sample_texture`: a bilinear texture lookup whose gradient can go sparsely into a
  GradSink (:func:`bilinear_taps`), and :func:`contract_disc`, mip-NeRF 360's contraction
  in 2D, with which a finite texture covers an infinite plane.
* :func:`sphere_exit`: where rays leave spheres around a point.

The table and the room made of these are in :mod:`nerfkit.surroundings`
(:mod:`~nerfkit.surroundings.table`, :mod:`~nerfkit.surroundings.room`); their compositing
along each ray is :mod:`nerfkit.render.layers`.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor


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
