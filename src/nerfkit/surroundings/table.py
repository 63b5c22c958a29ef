"""The table a capture's object stands on, as rays see it beyond the model's box.

A real capture shows an object standing on a table in a room. Inside its box a model
represents the object with density; beyond the box the photos still show the table
(with parallax: it is a plane, not a colour per direction) and the room. Filling that
with density makes haze and floaters; a flat colour makes dark surfaces see-through.

* :class:`TablePlane`: an opaque textured plane (the tag's plane in a tag capture). Rays
  stop where they meet it; its texture lives on a 2D grid in *contracted* plane
  coordinates (mip-NeRF 360's contraction in 2D), so a finite texture covers the whole
  infinite plane, finely near the object and ever more coarsely far from it. A glossy
  table also mirrors a small learned map of its surroundings; a floor under the table is
  a second such plane.
* :func:`table_doubt`: the prior that a table is there or not; :func:`plane_footprint` and
  :func:`texel_side`: a photo's pixel and the table's texel on the plane.
"""

from __future__ import annotations

import math
from typing import cast

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from ..cameras import axes_across, pixel_to_ray, plane_hit
from ..fields.background import contract_disc, sample_texture


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
