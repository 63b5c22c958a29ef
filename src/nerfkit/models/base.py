"""The contract between the trainer/renderer and a radiance-field model.

The trainer never does camera math and never knows how a model samples its rays: it
hands a model a batch of :class:`~nerfkit.cameras.Rays` and gets a :class:`RenderOutput`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import cast

import numpy as np
import torch
from torch import Tensor, nn

from ..cameras import Rays, mean_camera
from ..render.ndc import NdcSpace
from ..render.output import RenderOutput
from ..scene_extent import object_box_from_points, sphere_radius
from ..surroundings import Surroundings
from .appearance import DirectionalColour


@dataclass
class SceneBounds:
    """What a model may know about the scene: depth range and a bounding sphere.

    Attributes:
        near, far: depth range along rays.
        center: (3,) scene centre; radius: radius of a sphere holding the object.
        up: (3,) world up.
        table: (4,) plane ``(n, d)`` the object stands on (normal toward the cameras), or None.
        camera_radius: distance of the farthest training camera from ``center`` (None: unknown).
        object_box: ``(lo, hi)`` (3,) each, an axis-aligned box around the object from the
            dataset's sparse points (:func:`object_box_from_points`), or None.
        ndc: for a forward-facing scene (every camera looking about the same way, as LLFF
            captures), the NDC of the mean camera from ``near`` to infinity; else None.
        floor: (4,) plane ``(n, d)`` of the floor seen beyond the table's edge (found in
            the sparse points, :func:`~nerfkit.sfm.ground.find_floor`), or None.
        tags: (n, 4, 3) corners of the printed tags lying on the table, or None.
    """

    near: float
    far: float
    center: np.ndarray
    radius: float
    up: np.ndarray
    table: np.ndarray | None = None
    camera_radius: float | None = None
    object_box: tuple[np.ndarray, np.ndarray] | None = None
    ndc: NdcSpace | None = None
    floor: np.ndarray | None = None
    tags: np.ndarray | None = None

    @property
    def reach(self) -> float:
        """How far the cameras are from the centre: ``camera_radius``, else ``far``."""
        return self.camera_radius if self.camera_radius is not None else self.far

    @staticmethod
    def from_scene(scene, ndc: bool | None = None) -> SceneBounds:
        """The bounds of ``scene``; ``ndc``: whether rays live in NDC, as the scene kind the run
        resolved says (a forward-facing scene's; :mod:`nerfkit.presets`), or None: as the
        dataset says (forward-facing cameras, and not a capture with a table)."""
        c2w = scene.train.c2w
        dists = np.linalg.norm(c2w[:, :3, 3] - scene.center, axis=1)
        radius = sphere_radius(scene)
        box = floor = None
        if scene.points is not None and scene.table is not None:
            box = object_box_from_points(scene.points, scene.table, scene.center, radius, views=scene.train)
            plane = scene.floor()
            if plane is not None:
                floor = np.array([*plane.normal, plane.offset], np.float32)
        if ndc is None:
            ndc = not scene.capture and scene.table is None and scene.forward_facing
        space = None
        if ndc:
            space = NdcSpace.from_camera(
                mean_camera(c2w), scene.train.K.mean(0), scene.train.width, scene.train.height, float(scene.near)
            )
            space = space.fit_extent(c2w, scene.train.K, scene.train.width, scene.train.height)
        return SceneBounds(
            float(scene.near),
            float(scene.far),
            np.asarray(scene.center, np.float32),
            float(radius),
            np.asarray(scene.up, np.float32),
            None if scene.table is None else np.asarray(scene.table, np.float32),
            float(dists.max()),
            box,
            space,
            floor,
            None if scene.tags is None else np.asarray(scene.tags, np.float32),
        )

    def to_dict(self) -> dict:
        return {
            "near": self.near,
            "far": self.far,
            "center": [float(c) for c in self.center],
            "radius": self.radius,
            "up": [float(u) for u in self.up],
            "table": None if self.table is None else [float(v) for v in self.table],
            "camera_radius": self.camera_radius,
            "object_box": None if self.object_box is None else [[float(v) for v in b] for b in self.object_box],
            "ndc": None if self.ndc is None else self.ndc.to_dict(),
            "floor": None if self.floor is None else [float(v) for v in self.floor],
            "tags": None if self.tags is None else np.asarray(self.tags, np.float64).round(7).tolist(),
        }

    @staticmethod
    def from_dict(d: dict) -> SceneBounds:
        table = d.get("table")
        return SceneBounds(
            float(d["near"]),
            float(d["far"]),
            np.asarray(d["center"], np.float32),
            float(d["radius"]),
            np.asarray(d["up"], np.float32),
            None if table is None else np.asarray(table, np.float32),
            None if d.get("camera_radius") is None else float(d["camera_radius"]),
            None
            if d.get("object_box") is None
            else cast(
                tuple[np.ndarray, np.ndarray],  # saved by to_dict as [lo, hi]
                tuple(np.asarray(b, np.float32) for b in d["object_box"]),
            ),
            None if d.get("ndc") is None else NdcSpace.from_dict(d["ndc"]),
            None if d.get("floor") is None else np.asarray(d["floor"], np.float32),
            None if d.get("tags") is None else np.asarray(d["tags"], np.float32),
        )


# Charbonnier's epsilon (mip-NeRF 360's): below ~1e-3 of a colour step the loss is quadratic
CHARBONNIER_EPS = 1e-3
RGB_LOSSES = ("mse", "charbonnier")


def rgb_loss(pred: Tensor, target: Tensor, kind: str = "mse") -> Tensor:
    """Photometric loss between (n_rays, 3) colours, averaged over rays and channels.

    ``mse``: the mean squared error (what PSNR scores). ``charbonnier``: the mean of
    ``sqrt(e^2 + eps^2)``, quadratic below ``eps`` and linear above it, so a pixel that no
    consistent scene explains (a shadow of the photographer, a reflection that moved)
    pulls no harder than a small error instead of in proportion to its error (mip-NeRF
    360). Example: errors of 0.5 and 0.05 pull with forces 1.0 and 0.1 under mse, and
    both with about 1.0 under charbonnier.
    """
    return rgb_errors(pred, target, kind).mean()


def rgb_errors(pred: Tensor, target: Tensor, kind: str = "mse") -> Tensor:
    """The terms :func:`rgb_loss` averages: (n_rays, 3) per ray and channel."""
    e2 = (pred - target) ** 2
    if kind == "mse":
        return e2
    if kind == "charbonnier":
        return torch.sqrt(e2 + CHARBONNIER_EPS**2)
    raise ValueError(f"unknown photometric loss {kind!r} (one of {', '.join(RGB_LOSSES)})")


def grads_finite(params) -> bool:
    """True when every ``.grad`` among ``params`` (those that have one) is finite."""
    return all(bool(torch.isfinite(p.grad).all()) for p in params if p.grad is not None)


@dataclass
class StepState:
    """What a :class:`Schedule` sees: the training step (about to run, or just run),
    progress in [0, 1] and the optimizer (a job that edits parameters keeps its moments
    in step with them). After a step, also the step's rays (as rendered, after any pose
    correction) and what the model rendered for them (None for whole-image steps), for
    jobs that learn from the batch."""

    step: int
    progress: float
    optimizer: torch.optim.Optimizer | None = None
    rays: Rays | None = None
    out: RenderOutput | None = None


# when a schedule's job runs within a training step
PHASES = ("before_step", "gradients", "after_step")


@dataclass(frozen=True)
class Schedule:
    """A job a model needs done during training, run by the trainer when ``due``: grid
    growth, occupancy refreshes, densification (nerfacc's ``update_every_n_steps``).

    Attributes:
        name: for logs and errors.
        due: ``StepState -> bool``.
        run: ``StepState -> str | None`` (a line for the training log, or None).
        phase: ``before_step`` (before the forward pass), ``gradients`` (after the
            backward pass, before the optimizer update: a job that adds gradients of its
            own, as Plenoxels' in-place total variation) or ``after_step`` (after the
            update).

    A job that installs new parameter tensors swaps them into ``StepState.optimizer``
    itself (:func:`~nerfkit.kernels.optim.replace_param`), so every other parameter keeps
    its Adam moments.
    """

    name: str
    due: Callable[[StepState], bool]
    run: Callable[[StepState], str | None]
    phase: str = "before_step"

    def __post_init__(self):
        if self.phase not in PHASES:
            raise ValueError(f"schedule {self.name!r}: phase {self.phase!r} is not one of {PHASES}")


def run_schedules(schedules: list[Schedule], state: StepState, phase: str) -> list[str]:
    """Run the due jobs of one phase, in order; returns their log lines."""
    notes = []
    for job in schedules:
        if job.phase == phase and job.due(state):
            note = job.run(state)
            if note:
                notes.append(note)
    return notes


class NerfModel(nn.Module):
    """Base class of radiance-field models.

    Subclasses implement :meth:`render_rays` and may override the hooks. Each training
    step the trainer runs the due :meth:`schedules` jobs, ``out = model.render_rays(...)``,
    ``loss = model.loss(out, rgb)``, backward, the due gradient-phase jobs, the optimizer
    step (an optimizer it builds from :meth:`param_groups` and :meth:`grad_sinks`), then the
    due after-step jobs.
    A model's ``state_dict`` must be loadable into a freshly built model of the same
    config (models that grow their grids resize themselves in ``load_state_dict``).
    """

    # the model renders whole views (splat): the trainer draws one training view per step
    # (no ray batches, no sight lines; its pose is corrected through the camera it renders from)
    whole_images: bool = False

    def __init__(self, bounds: SceneBounds):
        super().__init__()
        self.bounds = bounds
        self.autocast_dtype: torch.dtype | None = None  # see set_precision
        # what the model draws around its object (a capture's), or None: nerfkit.surroundings
        self.surroundings: Surroundings | None = None
        self.isolated = False  # drawing its object alone, for rendering only
        # a capture's: the colour of the training photos near a rendered view (render_image)
        self.appearance: DirectionalColour | None = None

    def set_precision(self, dtype: torch.dtype | None) -> None:
        """The autocast dtype the command resolved from ``--precision`` (None: float32), for
        networks a model runs outside the caller's autocast (e.g. an occupancy refresh)."""
        self.autocast_dtype = dtype

    def render_rays(self, rays: Rays, background: Tensor, perturb: bool) -> RenderOutput:
        """Render rays (differentiable). ``background``: (3,) colour for empty space."""
        raise NotImplementedError

    def query(self, points: Tensor, directions: Tensor) -> tuple[Tensor, Tensor]:
        """The field itself: (n, 3) world points and unit view directions ->
        ((n,) density, (n, 3) colour in [0, 1]). Used by export and viewers."""
        raise NotImplementedError

    def density(self, points: Tensor) -> Tensor:
        """(n, 3) world points -> (n,) density (colour not needed)."""
        d = torch.zeros_like(points)
        d[:, 2] = 1.0
        return self.query(points, d)[0]

    def loss(self, out: RenderOutput, target_rgb: Tensor) -> Tensor:
        """Photometric MSE; models add their own terms (coarse network, regularisers)."""
        return rgb_loss(out.rgb, target_rgb)

    def see_batch(self, progress: float, image_index: Tensor, uv: Tensor, shape: tuple[int, int, int]) -> None:
        """Before :meth:`loss` of a ray batch: where its rays come from (``image_index`` (n,)
        training photo, ``uv`` (n, 2) pixel column and row, of ``shape`` (n_images, width,
        height)), ``progress`` in [0, 1] of the run: for a model that weighs pixels by where
        they lie (the fast model's ``--transient-quantile``). Default: ignored."""

    def init_from_scene(self, scene, background: Tensor, work: Path | None = None) -> str | None:
        """Start a new run's parameters from the dataset (e.g. Gaussians at its sparse
        points); returns a note for the training log, or None. ``work``: a folder for scratch
        files (the run folder). Default: nothing to do."""
        return None

    @property
    def uses_sight_lines(self) -> bool:
        """Whether the model scores the sparse points' sight lines (:meth:`sight_loss`)."""
        return False

    def sight_loss(self, rays: Rays, distance: Tensor) -> Tensor | None:
        """The loss of sight lines ``rays`` (unit directions) to points ``distance`` (n,)
        along them, or None when the model takes none (the default)."""
        return None

    def sight_spread(self) -> float:
        """How far beside its point a drawn sight line may aim (world units)."""
        return 0.0

    def param_groups(self, lr: float) -> list[dict]:
        """Optimizer parameter groups (with their own ``lr``, and ``eps`` where it differs
        from Adam's); ``lr`` is the configured base learning rate."""
        return [{"params": [p for p in self.parameters() if p.requires_grad], "lr": lr}]

    def grad_sinks(self) -> dict:
        """``{parameter: GradSink}`` for parameters whose gradients the model gathers
        outside ``.grad`` (sparse rows); the optimizer updates only their touched rows."""
        return {}

    def schedules(self) -> list[Schedule]:
        """The jobs the trainer runs for this model during training."""
        return []

    def rays_per_step(self, batch_rays: int) -> int:
        """Rays of the next training step, given ``--batch-rays`` (a model may take more as
        it grows finer)."""
        return batch_rays

    def gradients_finite(self) -> bool:
        """True when every gradient of the last backward pass is finite (checked before
        the optimizer step; models keeping gradients outside ``.grad`` check those too)."""
        return grads_finite(self.parameters())

    def load_kernels(self) -> None:
        """Load the compiled kernels the model runs on (compiling them the first time: tens
        of seconds), before training's clock starts, so no step or time budget pays for it."""

    def finish_training(self) -> list[str]:
        """Called once when training reaches its end, before the final evaluation and the
        model file (e.g. to measure an occupancy grid that was never measured). Returns
        notes for the user on the trained model (logged, and kept in ``metrics.json``)."""
        return []

    def object_center(self) -> np.ndarray | None:
        """(3,) where the trained scene's content is (to aim an orbit at), or None when
        the model cannot tell."""
        return None

    def density_box(self) -> tuple[np.ndarray, np.ndarray] | None:
        """World box ``(lo (3,), hi (3,))`` outside which the model holds no density (a
        grid's box: a capture's box around the object), or None when the model cannot tell
        (its density may be anywhere in the scene, or it lives in another space, NDC)."""
        return None

    def clear_density(self, where: Callable[[np.ndarray, list[np.ndarray]], np.ndarray]) -> None:
        """Clear the density where ``where(sigma, axes)`` says ((X, Y, Z) bool over a grid of
        the density at vertices with positions ``axes``: (X,), (Y,), (Z,)), for an object-only
        render (:func:`~nerfkit.surroundings.isolate_object`). Default: nothing to clear."""

    def _not_isolated(self) -> None:
        if self.isolated:
            raise RuntimeError("a model isolated for an object-only render can be neither trained nor saved")

    def pack_state(self) -> tuple[str | None, dict]:
        """What the final model file stores: ``(packing, tensors)``. The default is the plain
        ``state_dict()`` (packing None); a model may store a compact form under a packing
        name that :meth:`unpack_state` reads back."""
        return None, self.state_dict()

    def unpack_state(self, packing: str, state: dict) -> dict:
        """The full ``state_dict`` from :meth:`pack_state`'s tensors (after
        :meth:`load_extra_state`). Raises ValueError for a packing or tensors it cannot read."""
        raise ValueError(f"unknown model packing {packing!r}")

    def extra_state(self) -> dict:
        """JSON-able state beyond tensors (e.g. current grid resolution), saved in checkpoints."""
        return {}

    def load_extra_state(self, state: dict) -> None:
        """Restore :meth:`extra_state` before ``load_state_dict``."""

    def training_state(self) -> dict:
        """Tensors that only training uses, saved in resume checkpoints but not in the model
        file (e.g. the fast model's memory of transients). Default: none."""
        return {}

    def load_training_state(self, state: dict) -> None:
        """Restore :meth:`training_state` on resume (an older checkpoint: ``{}``); ValueError
        for tensors that do not fit."""
