"""The room around a capture's cameras, as rays see it beyond the model's box.

* :class:`RoomShells`: the room as a few textured, semi-transparent spheres around the
  cameras (a multi-sphere image), so that it shows parallax.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor, nn

from ..cameras import axes_across
from ..fields.background import sample_texture, sphere_exit

# initial opacity logit of the room shells: sigmoid(-1) = 0.27 each
SHELL_ALPHA_INIT = -1.0


class RoomShells(nn.Module):
    """The room around a capture as a few semi-transparent textured spheres (a multi-sphere
    image, as NeRF++'s inverted-sphere background discretised): unlike a colour per
    direction, a surface at the right shell moves against the object as the camera moves.

    Shell ``k`` has radius ``r0 * ratio ** k`` around ``center``; every training camera is
    inside the first one. Each shell holds an RGBA texture (logits; a fine and a coarse
    grid summed, like :class:`~.table.TablePlane`) in equirectangular coordinates about ``up``:
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
        :meth:`~.table.TablePlane.look`.
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
