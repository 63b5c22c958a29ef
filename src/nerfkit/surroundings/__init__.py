"""The capture composition: what a model draws around its object, and the object alone.

A capture's object stands on a table in a room. A grid model holds the object in its box
and leaves the rest to :class:`Surroundings`: a learned colour per direction (spherical
harmonics) far away, ``room_shells`` textured, semi-transparent spheres around the cameras
(:class:`~nerfkit.surroundings.room.RoomShells`), the table where rays stop and the floor
beyond its edge (:class:`~nerfkit.surroundings.table.TablePlane`), composited in order of
distance behind the volume (:mod:`nerfkit.render.layers`).

The functions below are how the rest of nerfkit reaches a model's surroundings
(:func:`of`, :func:`table_plane`, :func:`table_tags`, :func:`names`), isolates its object
for a video or a mesh (:func:`isolate_object`, :func:`object_alone`) and finds how high
above the table the table's paint reaches (:func:`table_cut_height`).
"""

from __future__ import annotations

import copy as copying
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import torch
from torch import Tensor, nn

from ..cameras import axes_across
from ..fields.background import sh16
from ..kernels.ops import GradSink
from ..losses import LossTerm, mean_extra, mean_opacity
from ..render.layers import composite_layers, layers_depth
from ..scene_extent import SURFACE_DENSITY, box_corners, box_radius, surface_threshold
from .clearing import TABLE_CUT, around_object, heights
from .room import RoomShells
from .table import TablePlane, table_doubt

Layer = tuple[Tensor, Tensor, Tensor]  # t (n, k), rgb (n, k, 3), alpha (n, k)


def flat_background(d: Tensor, background: Tensor | None) -> Tensor:
    """(n, 3) the flat ``background`` colour behind rays ``d`` (n, 3) (black when None)."""
    if background is None:
        return torch.zeros_like(d)
    return torch.as_tensor(background, dtype=torch.float32, device=d.device).expand_as(d)


def cut_height(plane: np.ndarray | None, box, fraction: float) -> float:
    """``fraction`` of the height of ``box``'s top above ``plane`` (0 without either)."""
    if plane is None or box is None:
        return 0.0
    return fraction * max(float((box_corners(box) @ plane[:3] + plane[3]).max()), 0.0)


class Surroundings(nn.Module):
    """The learned background, room, table and floor of a model (each optional; see the
    module docstring), built from a model's config (``learn_background``, ``room_shells``,
    ``table``, ``floor`` and their settings) and the scene's bounds."""

    bg_coef: nn.Parameter | None

    def __init__(self, config: Any, bounds: Any):
        super().__init__()
        self.config = config
        self.tags = bounds.tags
        if config.learn_background:
            self.bg_coef = nn.Parameter(torch.zeros(3, 16))
        else:
            self.register_parameter("bg_coef", None)
        self.room = None
        if config.learn_background and config.room_shells:
            r0 = 1.25 * max(bounds.reach, bounds.radius)
            self.room = RoomShells(
                bounds.center, bounds.up, r0, config.room_shells, config.room_ratio, config.room_resolution
            )
        self.table = None
        if config.table and bounds.table is not None:
            self.table = TablePlane(
                bounds.table,
                bounds.center,
                bounds.radius,
                config.table_resolution,
                gloss=config.table_gloss,
                relief=config.table_relief,
                tags=bounds.tags,
                tag_texels=config.table_tag_texels,
            )
        self.floor = None
        if config.floor and self.table is not None and config.learn_background and bounds.floor is not None:
            self.floor = TablePlane(bounds.floor, bounds.center, bounds.reach, config.table_resolution)
        self.cover_prior_on = False  # set by the "table cover prior" job
        self.texture_sinks = self.new_sinks(torch.device("cpu"))

    @staticmethod
    def build(config: Any, bounds: Any) -> Surroundings | None:
        """The surroundings ``config`` asks for in a scene of ``bounds``, or None when it draws none."""
        made = Surroundings(config, bounds)
        return made if made.names() else None

    def names(self) -> list[str]:
        """The parts drawn: of "table", "floor", "room", "background"."""
        parts = {"table": self.table, "floor": self.floor, "room": self.room, "background": self.bg_coef}
        return [name for name, part in parts.items() if part is not None]

    @property
    def holds_object(self) -> bool:
        """Whether the object stands on a table (its box then holds only the object)."""
        return self.table is not None

    @property
    def plane(self) -> np.ndarray | None:
        """(4,) the table's plane ``(n, d)``, or None."""
        return None if self.table is None else self.table.plane.cpu().numpy()

    # -- optimisation ----------------------------------------------------------------
    def new_sinks(self, device) -> dict:
        """A one-lane gradient sink per table and room texture (its optimizer updates touched
        texels only)."""
        textures = [p for part in (self.table, self.floor, self.room) if part is not None for p in part.textures()]
        return {p: GradSink(p.shape[0], p.shape[1], device, lanes=1) for p, _ in textures}

    def param_groups(self, lr: float, eps: float) -> list[dict]:
        c = self.config
        groups = [] if self.bg_coef is None else [{"params": [self.bg_coef], "lr": 0.1 * lr, "eps": eps}]
        for part, ratio in (
            (self.table, c.table_lr_ratio),
            (self.floor, c.table_lr_ratio),
            (self.room, c.room_lr_ratio),
        ):
            if part is not None:
                groups.append({"params": list(part.parameters()), "lr": ratio * lr, "eps": eps})
        return groups

    def loss_terms(self) -> list[LossTerm]:
        """The table's opacity term (``opacity_weight``) and its cover prior (once switched on)."""
        c, terms = self.config, []
        if self.table is not None and c.opacity_weight > 0:
            terms.append(mean_opacity(c.opacity_weight))
        terms.append(mean_extra("table_doubt", c.table_cover_weight, lambda: self.cover_prior_on))
        return terms

    def jobs(self) -> list[tuple[str, Callable, Callable]]:
        """``(name, due, run)`` of the training jobs: the table's cover prior applies from
        ``table_cover_start`` of the run on."""

        def switch(s) -> None:
            self.cover_prior_on = s.progress >= self.config.table_cover_start

        return [("table cover prior", lambda s: bool(self.config.table_cover_weight), switch)]

    # -- rendering -------------------------------------------------------------------
    def stop(self, o: Tensor, d: Tensor) -> Tensor | None:
        """(n,) where rays end at the table (inf: they miss it), or None without one."""
        return None if self.table is None else self.table.hit(o, d)

    def distortion_end(self, t_stop: Tensor | None) -> Tensor | None:
        """Where the distortion loss puts a ray's leftover weight: the table, with ``distortion_table``."""
        return t_stop if self.config.distortion_table else None

    def far(self, d: Tensor, background: Tensor | None) -> Tensor:
        """(n, 3) what is seen infinitely far along ``d``: the learned colour per direction,
        else the flat ``background``; in float32 under autocast too (the layers in front are
        composited in its dtype)."""
        if self.bg_coef is not None:
            with torch.autocast(d.device.type, enabled=False):
                return torch.sigmoid(sh16(d.float()) @ self.bg_coef.float().t())
        return flat_background(d, background)

    def behind(
        self, o: Tensor, d: Tensor, t_stop: Tensor | None, background: Tensor | None, through: Tensor, compiled: bool
    ) -> tuple[Tensor, tuple[Tensor, Tensor] | None, dict[str, Tensor]]:
        """(n, 3) colour behind the volume: the table (where rays meet it, ``t_stop``), the
        floor and the room shells, composited in order of distance, in front of what is
        infinitely far (:meth:`far`). A glossy table also shows its map of the surroundings
        along the mirrored ray. Out of training, also the (n,) distance of the layer each ray
        meets and whether it meets one (:func:`layers_depth`); else, or with no layers, None.
        Last, render extras: in training with the cover prior's weight, ``table_doubt``
        (:func:`table_doubt` of the light the table lets through, times ``through`` (n,),
        the light the volume lets through)."""
        bg = self.far(d, background)
        layers = [] if self.room is None else [self.room.layers(o, d, self.texture_sinks, compiled)]
        extras = {}
        if t_stop is not None:
            assert self.table is not None  # (t_stop comes from the table)
            layers.append(self._plane_layer(self.table, o, d, t_stop, self.config.table_gloss, compiled))
            if self.training and self.config.table_cover_weight:  # for the cover prior
                clear = torch.isfinite(t_stop) * (1.0 - layers[-1][2][:, 0])
                extras["table_doubt"] = through.detach() * table_doubt(clear)
        if self.floor is not None:
            layers.append(self._plane_layer(self.floor, o, d, self.floor.hit(o, d), False, compiled))
        if not layers:
            return bg, None, extras
        t, rgb, alpha = (torch.cat(parts, dim=1) for parts in zip(*layers))
        alpha = alpha.to(bg.dtype)
        depth = None if self.training else layers_depth(t.float(), alpha.float())
        return composite_layers(t, rgb.to(bg.dtype), alpha, bg), depth, extras

    def _plane_layer(
        self, plane: TablePlane, o: Tensor, d: Tensor, t_hit: Tensor, gloss: bool, compiled: bool
    ) -> Layer:
        """One textured plane as a compositing layer: ``t (n, 1)`` where each ray meets it
        (``inf``: misses), ``rgb (n, 1, 3)`` and coverage ``(n, 1)``."""
        hit = torch.isfinite(t_hit).nonzero()[:, 0]
        on_plane = o[hit] + d[hit] * t_hit[hit].unsqueeze(-1)
        if plane.relief is not None:  # (it moves the hit along the ray, nearer or farther)
            on_plane, dt = plane.raise_hits(on_plane, d[hit], self.texture_sinks, compiled)
            t_hit = t_hit.index_put((hit,), t_hit[hit] + dt.to(t_hit.dtype))
        seen, cover, shine = plane.look(on_plane, self.texture_sinks, gloss=gloss and len(hit) > 0, compiled=compiled)
        if shine is not None:
            n = plane.plane[:3].to(d)
            mirrored = d[hit] - 2.0 * (d[hit] @ n).unsqueeze(-1) * n
            seen = (1.0 - shine.unsqueeze(-1)) * seen + shine.unsqueeze(-1) * plane.reflection(mirrored)
        colour = torch.zeros_like(d).index_put((hit,), seen.to(d.dtype))
        cover = d.new_zeros(len(d)).index_put((hit,), cover.to(d.dtype))
        return t_hit.unsqueeze(1), colour.unsqueeze(1), cover.unsqueeze(1)

    # -- where the object is ---------------------------------------------------------
    def above_paint(self, points: Tensor, box) -> Tensor | None:
        """(n,) bool: world ``points`` (n, 3) above the table's paint (:data:`TABLE_CUT` of
        the height of ``box`` above the table), or None without a table."""
        if self.table is None:
            return None
        plane = self.table.plane.to(points)
        return points @ plane[:3] + plane[3] > cut_height(self.plane, box, TABLE_CUT)

    def above_paint_grid(self, axes: list[np.ndarray], box) -> np.ndarray | bool:
        """As :meth:`above_paint`, over the vertices of a grid with vertex positions ``axes``
        ((X,), (Y,), (Z,)): (X, Y, Z) bool (True without a table)."""
        if self.table is None:
            return True
        return heights(axes, self.plane) > cut_height(self.plane, box, TABLE_CUT)


# the surroundings' parts in model files from before they were a module of their own
OLD_PARTS = ("bg_coef", "table.", "floor.", "room.")


def renamed_keys(state: dict) -> dict:
    """A model's ``state_dict`` with the keys of the surroundings' parts from an older model
    file (at the model's top level, :data:`OLD_PARTS`) under ``surroundings.``."""
    return {("surroundings." + k if k.startswith(OLD_PARTS) else k): v for k, v in state.items()}


def random_in_ball(n: int, center, radius: float, gen: torch.Generator) -> Tensor:
    """``n`` points uniformly in a ball (n, 3)."""
    d = torch.randn(n, 3, generator=gen)
    d = d / d.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    r = radius * torch.rand(n, 1, generator=gen) ** (1 / 3)
    return torch.as_tensor(np.asarray(center, np.float32)) + d * r


def random_on_plane(n: int, plane, center, radius: float, gen: torch.Generator) -> Tensor:
    """``n`` points uniformly on the disc of ``radius`` of the plane ``(n, d)`` nearest ``center``."""
    nrm = np.asarray(plane[:3], np.float64)
    c = np.asarray(center, np.float64)
    foot = c - (c @ nrm + float(plane[3])) * nrm
    a, b = axes_across(nrm)
    r = radius * torch.rand(n, generator=gen).double().sqrt()
    th = 2 * math.pi * torch.rand(n, generator=gen).double()
    pts = (
        torch.as_tensor(foot)
        + (r * th.cos()).unsqueeze(1) * torch.as_tensor(a)
        + (r * th.sin()).unsqueeze(1) * torch.as_tensor(b)
    )
    return pts.float()


def random_start(n: int, bounds: Any, center, radius: float, gen: torch.Generator) -> Tensor:
    """``n`` random starting points (n, 3): uniformly in the ball of ``0.7 radius`` around
    ``center``, and in a scene with a table (``bounds.table``) a quarter of them on it, on the
    disc of ``1.5 radius`` around the centre's foot."""
    n_table = n // 4 if bounds.table is not None else 0
    pts = random_in_ball(n - n_table, center, 0.7 * radius, gen)
    if n_table:
        pts = torch.cat([pts, random_on_plane(n_table, bounds.table, center, 1.5 * radius, gen)])
    return pts


class WithSurroundings(Protocol):
    """A model that may draw surroundings (:class:`~nerfkit.models.base.NerfModel`)."""

    surroundings: Surroundings | None
    isolated: bool
    appearance: Any  # DirectionalColour | None (models.appearance: imported by models, not here)

    def density_box(self) -> tuple[np.ndarray, np.ndarray] | None: ...

    def clear_density(self, where: Callable[[np.ndarray, list[np.ndarray]], np.ndarray]) -> None: ...


def of(model: Any) -> Surroundings | None:
    """The surroundings ``model`` draws, or None (a model that draws only its volume)."""
    return getattr(model, "surroundings", None)


def names(model: Any) -> list[str]:
    """The parts ``model`` draws around its object (what :func:`isolate_object` leaves out)."""
    s = of(model)
    return [] if s is None else s.names()


def table_plane(model: Any) -> np.ndarray | None:
    """(4,) ``(n, d)`` of the table where ``model``'s rays stop (unit normal ``n`` toward the
    cameras), or None."""
    s = of(model)
    return None if s is None else s.plane


def table_tags(model: Any) -> np.ndarray | None:
    """(n, 4, 3) corners of the printed tags lying on ``model``'s table, or None (no table,
    or no tags recorded)."""
    s = of(model)
    return None if s is None or s.table is None else s.tags


def table_cut_height(model: Any, fraction: float) -> float:
    """``fraction`` of the height of the model's density box's top above its table plane
    (world units; 0 without a table or a box)."""
    return cut_height(table_plane(model), model.density_box(), fraction)


def isolate_object(model: WithSurroundings, cut: float, threshold: float) -> list[str]:
    """Keep only the object, for a video of it alone: stop drawing what surrounds it (a
    capture's table, floor, room and learned background) and clear the table's paint and
    the specks apart from the object from the density
    (:func:`~nerfkit.surroundings.clearing.around_object`: paint up to ``cut`` world units above the
    table; ``threshold``: the surface's density). Changes the model in place, for rendering
    only: it can then be neither trained nor saved. Returns the names of the parts left out
    (:func:`names`): none when the model draws nothing apart from its volume."""
    s = of(model)
    left_out = [] if s is None else s.names()
    if s is None or not left_out:
        return []
    model.isolated = True
    model.appearance = None  # (drawn alone in the scene's own colour, on a colour of the user's)
    if s.table is not None:
        plane, tags = s.plane, table_tags(model)
        model.clear_density(lambda sigma, axes: around_object(sigma, axes, plane, cut, threshold, tags))
    model.surroundings = None
    return left_out


@dataclass
class ObjectAlone:
    """A model that draws its object alone (:func:`object_alone`): ``model``, the names of
    the parts it ``left_out`` (none: the model as it was), and the height ``cut`` above the
    table up to which the table's paint was cleared (0 without a table)."""

    model: Any
    left_out: list[str]
    cut: float


def box_surface_threshold(model: Any) -> float:
    """The surface's density for ``model``'s object: :func:`surface_threshold` of its density
    box (half its largest side; the mesh's default level), or :data:`SURFACE_DENSITY`
    without a box."""
    box = model.density_box()
    if box is None:
        return SURFACE_DENSITY
    return surface_threshold(box_radius(box))


def object_alone(model: Any, copy: bool = True) -> ObjectAlone:
    """``model`` (a copy of it, unless ``copy`` is False) drawing its object alone
    (:func:`isolate_object`), with the table's paint cleared up to :data:`TABLE_CUT` of the
    object's height and the specks apart from the object cleared (at
    :func:`box_surface_threshold`: the mesh's surface, whatever the scene's units). A model
    with nothing around its object, or a forward-facing one in NDC (whose one volume holds
    everything), comes back as it is, with nothing left out."""
    if getattr(model, "ndc", None) is not None or not names(model):  # (not copied for nothing)
        return ObjectAlone(model, [], 0.0)
    cut = table_cut_height(model, TABLE_CUT)
    alone = copying.deepcopy(model) if copy else model
    left_out = isolate_object(alone, cut, box_surface_threshold(model))
    return ObjectAlone(alone, left_out, cut if "table" in left_out else 0.0)
