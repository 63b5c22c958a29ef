"""``splat``: 3D Gaussian splatting (Kerbl et al. 2023), trained and rendered on a CPU.

The scene is a set of 3D Gaussians: mean, log-scale, rotation quaternion ``(w, x, y, z)``,
opacity logit and spherical-harmonic colour up to degree 3 (INRIA's conventions, see
:mod:`nerfkit.kernels.splat_reference`; ``nerfkit export --splat`` writes the standard
PLY). The model renders whole views (``whole_images``): the trainer draws one training
view per step and calls :meth:`SplatModel.render_view`, as do evaluation and videos.

Training as 3DGS does it: L1 + D-SSIM, Adam with a learning rate per parameter
(3DGS's, times ``--lr``; the means' scaled by the scene size and decaying 100x), adaptive density control
(clone small / split large Gaussians whose view-space gradient is large, prune
transparent and huge ones, periodic opacity reset), SH degree raised over time. The
schedules are fractions of the run, so they follow ``--steps`` or ``--minutes``.

Initialisation (:meth:`SplatModel.init_from_scene`): the dataset's sparse points when it
has them (structure-from-motion's, or those `nerfkit poses` triangulates from a tag
capture), each Gaussian as large as the distance to its neighbours (as 3DGS); else the
visual hull of the training images when their background is the flat ``--background``
colour (the object's silhouettes carve a grid); else points triangulated from the
training photos at their given poses (COLMAP's point triangulator, as for a tag capture:
an LLFF scene comes with poses but no points) when pycolmap is installed; else random
points in the object's box plus the table plane of a tag capture; else random in the
scene box.
"""

from __future__ import annotations

import base64
import importlib.util
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor, nn

from ..cameras import Rays, image_rays, project_points
from ..config import check_ranges, option
from ..errors import fail
from ..fields.background import sh16
from ..kernels import splat_kernels
from ..kernels import splat_reference as ref
from ..kernels.optim import replace_param
from ..kernels.splat_ops import SplatRender, render_gaussians, resolve_backend, ssim
from ..surroundings import random_in_ball, random_start
from .base import NerfModel, RenderOutput, SceneBounds, Schedule, StepState

PARAMS = ("means", "log_scales", "quats", "opacity_logits", "sh_dc", "sh_rest")
# most Gaussians a checkpoint may ask to allocate
MAX_GAUSSIANS = 20_000_000
# --init auto starts from the dataset's sparse points when it has at least this many
MIN_INIT_POINTS = 100
# --init auto triangulates points from the training photos when there are at least this many
MIN_TRIANGULATE_VIEWS = 3
# --hull-prune keeps the Gaussians within this many cells of the visual hull (its 64^3 cells are
# coarse and carved by 1-pixel-dilated silhouettes: lego, 4000 steps, removing the centres
# outside the hull grown by 1 cell cost 1.0 dB, by 2 or 3 cells none of the fine detail)
HULL_MARGIN = 3
# ... and counts only the hull's cells at least this fraction of the training views see: a cell
# few views frame (near a camera, off the others' fields of view) is not carved by the rest (lego
# 200: 704 of the 3978 cells, each framed by 1-6 of the 100 views; the object's by all 100)
HULL_MIN_SEEN = 0.25
# --lr-budget: how the learning rates fall with the run's length, and how far at most
LR_BUDGET_POWER = 0.4
LR_BUDGET_FLOOR = 0.5


@dataclass
class SplatConfig:
    """Options of the ``splat`` model (its training settings: ``presets.MODEL_TRAINING``)."""

    sh_degree: int = option(3, "largest spherical-harmonic degree of the colour (0-3)", min=0, max=3)
    sh_up_every: float = option(
        0.05, "raise the SH degree by one each time this fraction of the run is done", above=0, max=1
    )
    init: str = option(
        "auto",
        "initial Gaussians: auto (the dataset's sparse points when it has some, else the "
        "visual hull when the training images have a flat background, else points triangulated "
        "from the training photos at their poses when pycolmap is installed, else random in a "
        "ball of 0.7 times the scene's radius, a quarter on the table of a tag capture), points, "
        "hull, triangulate or random",
        choices=["auto", "points", "hull", "triangulate", "random"],
    )
    init_points: int = option(30_000, "number of initial Gaussians", min=1, max=MAX_GAUSSIANS)
    init_opacity: float = option(0.1, "opacity of the initial Gaussians", above=0, max=0.99)
    max_gaussians: int = option(
        40_000,
        "densification stops adding Gaussians at this count (lego, 10 minutes: "
        "40000 gave 33.1 dB at 28 fps, no cap 32.1 dB at 20 fps)",
        min=1,
        max=MAX_GAUSSIANS,
    )
    densify_every: int = option(100, "steps between densification / pruning rounds", min=1)
    densify_from: float = option(0.02, "first densification, as a fraction of the run", min=0, max=1)
    densify_until: float = option(
        0.5, "no densification (and no opacity reset) after this fraction of the run", min=0, max=1
    )
    densify_grad: float = option(
        2e-4, "clone/split Gaussians whose mean view-space gradient (NDC units, as 3DGS) exceeds this", above=0
    )
    percent_dense: float = option(
        0.01, "Gaussians larger than this fraction of the scene size are split, smaller ones cloned", above=0
    )
    hull_prune: bool = option(
        True,
        "with the visual-hull start (--init hull; auto on synthetic objects): remove the Gaussians whose "
        "centre leaves the hull (its cells a quarter of the views frame, grown by 3 cells) every "
        "--densify-every steps of the whole run: floaters outside it block held-out views (lego 200, "
        "100 val views: 4000 steps 33.54 dB against 33.25, 870 steps 31.52 against 31.40; lego 400, 1946 "
        "steps: 32.28 against 32.12)",
    )
    # (at 1 every Gaussian would go: none is wholly opaque)
    prune_opacity: float = option(0.005, "prune Gaussians less opaque than this", min=0, max=0.5)
    prune_screen: float = option(
        0.15, "after the first opacity reset, prune Gaussians wider than this fraction of the image (0: never)", min=0
    )
    opacity_reset_every: float = option(
        0.2,
        "reset every opacity to at most 0.01 each time this fraction of the run is done (while densifying; 0: never)",
        min=0,
        max=1,
    )
    ssim_weight: float = option(0.2, "weight of D-SSIM in the loss (the rest is L1)", min=0, max=1)
    position_lr: float = option(1.6e-4, "learning rate of the means, times the scene size (x --lr)", min=0)
    position_lr_final: float = option(0.01, "the means' learning rate decays to this fraction of it", above=0, max=1)
    lr_final: float = option(
        1.0,
        "every other learning rate decays to this fraction of it (1: constant, as 3DGS; "
        "lego, 300 steps: 28.1 dB constant, 27.1 decaying to 0.1)",
        above=0,
        max=1,
    )
    lr_budget: int = option(
        800,
        "a run longer than this many steps (--steps, or what --minutes buys at the rate so far) "
        f"scales every learning rate by (lr_budget / its steps) ** {LR_BUDGET_POWER}, down to "
        f"{LR_BUDGET_FLOOR:g} times at most: long runs end sharper with smaller steps (0: never)",
        min=0,
    )
    scale_lr: float = option(5e-3, "learning rate of the log-scales (x --lr)", min=0)
    rotation_lr: float = option(1e-3, "learning rate of the quaternions (x --lr)", min=0)
    opacity_lr: float = option(5e-2, "learning rate of the opacity logits (x --lr)", min=0)
    sh_lr: float = option(2.5e-3, "learning rate of the SH DC colour (higher degrees: /20) (x --lr)", min=0)
    learn_background: bool = option(
        False,
        "learn what rays see behind the Gaussians (a colour per direction) "
        "instead of the --background colour: for real photos",
    )
    torch_threads: int = option(
        1,
        "torch threads while training or rendering splats (0: leave as is): its "
        "operations are small and fastest on one thread; the rasterizer uses every core",
        min=0,
    )
    sh_dir_grad: bool = option(
        False,
        "the colour's view direction (the SH's, mean minus camera) passes its gradient to the means, "
        "as INRIA's 3DGS and gsplat (on CUDA) do; off, the CPU kernels hold it fixed. Off: at equal "
        "steps lego 200 +0.01 dB, flower -0.01, the sreeram capture -0.15 (BENCHMARKS.md)",
    )
    kernels: str = option(
        "auto",
        "auto (compiled numba on the CPU when available; gsplat on CUDA when installed), numba, or torch",
        choices=["auto", "numba", "torch"],
    )

    def validate(self) -> SplatConfig:
        check_ranges(self)
        if self.densify_from > self.densify_until:
            raise fail("--densify-from", "must not be after --densify-until")
        return self


def ray_length_per_z(K: Tensor, width: int, height: int) -> Tensor:
    """(H, W) length of each pixel's ray (through its centre) per unit of camera depth z:
    ``|K^-1 (u + 0.5, v + 0.5, 1)|``."""
    u = (torch.arange(width, dtype=K.dtype, device=K.device) + 0.5 - K[0, 2]) / K[0, 0]
    v = (torch.arange(height, dtype=K.dtype, device=K.device) + 0.5 - K[1, 2]) / K[1, 1]
    return torch.sqrt(1.0 + v[:, None] ** 2 + u[None, :] ** 2)


class SplatModel(NerfModel):
    """3D Gaussians rendered by tile rasterization (see the module docstring)."""

    whole_images = True

    # set by _install (parameters, then buffers registered with register_buffer)
    means: nn.Parameter
    log_scales: nn.Parameter
    quats: nn.Parameter
    opacity_logits: nn.Parameter
    sh_dc: nn.Parameter
    sh_rest: nn.Parameter
    grad_accum: Tensor
    grad_count: Tensor
    max_radii: Tensor
    bg_coef: nn.Parameter | None

    def __init__(self, config: SplatConfig, bounds: SceneBounds):
        super().__init__(bounds)
        self.config = config.validate()
        self.extent = 2.2 * float(bounds.radius)  # 3DGS's "cameras_extent" scales lrs and size thresholds
        # the projection's near plane: Gaussians nearer the camera are not drawn (never 0: a
        # dataset may say near = 0, and depths are divided by it)
        self.near_plane = max(0.05 * float(bounds.near), 1e-3 * float(bounds.radius))
        self.active_degree = 0
        self.n_resets = 0
        self._progress = 0.0
        # the last training render (its 2D means carry the densification gradient)
        self._last: tuple[SplatRender, int, int] | None = None
        self._image_side = 0  # longest side of the training images (for the screen-size prune)
        # the visual hull the Gaussians must stay in (--hull-prune; set by a hull start, kept in checkpoints)
        self._hull: dict | None = None
        pts = random_in_ball(config.init_points, bounds.center, bounds.radius, torch.Generator().manual_seed(0))
        self._install(
            *initial_gaussians(
                pts,
                torch.full_like(pts, 0.5),
                self._volume_scale(4 / 3 * math.pi * bounds.radius**3, len(pts)),
                config.init_opacity,
            )
        )
        if config.learn_background:
            self.bg_coef = nn.Parameter(torch.zeros(3, 16))
        else:
            self.register_parameter("bg_coef", None)

    # -- parameters ------------------------------------------------------------------
    def _install(self, means, log_scales, quats, opacity_logits, sh_dc, sh_rest) -> None:
        """Replace every Gaussian parameter (and reset the densification statistics)."""
        for name, value in zip(PARAMS, (means, log_scales, quats, opacity_logits, sh_dc, sh_rest)):
            setattr(self, name, nn.Parameter(value.detach().float().contiguous()))
        n = means.shape[0]
        device = means.device
        self.register_buffer("grad_accum", torch.zeros(n, device=device))
        self.register_buffer("grad_count", torch.zeros(n, device=device))
        self.register_buffer("max_radii", torch.zeros(n, device=device))

    @property
    def n_gaussians(self) -> int:
        return int(self.means.shape[0])

    @torch.no_grad()
    def object_center(self) -> np.ndarray | None:
        """The per-axis median of the mostly opaque Gaussians' means."""
        solid = self.means[torch.sigmoid(self.opacity_logits.reshape(-1)) > 0.5]
        return None if len(solid) == 0 else solid.double().median(dim=0).values.cpu().numpy()

    def _volume_scale(self, volume: float, n: int) -> float:
        """Initial Gaussian size: the side of a cube holding ``volume / n``."""
        return float((volume / max(n, 1)) ** (1 / 3))

    def sh(self) -> Tensor:
        """(n, 16, 3) all SH coefficients (DC first)."""
        return torch.cat([self.sh_dc, self.sh_rest], 1)

    @torch.no_grad()
    def init_from_scene(self, scene, background, work: Path | None = None) -> str:
        """Place the initial Gaussians from the dataset (see the module docstring); says how.
        ``work``: the folder for triangulation's scratch files (the run folder)."""
        c = self.config
        gen = torch.Generator().manual_seed(0)
        center, radius = np.asarray(self.bounds.center, np.float64), float(self.bounds.radius)
        mode = c.init
        scale: Tensor | float
        bg = np.asarray(background.detach().cpu().numpy() if isinstance(background, Tensor) else background)
        n_points = 0 if scene.points is None else len(scene.points)
        if mode == "auto":
            if n_points >= MIN_INIT_POINTS:
                mode = "points"
            elif not c.learn_background and flat_background(scene.train.images, bg):
                mode = "hull"
            elif len(scene.train) >= MIN_TRIANGULATE_VIEWS and importlib.util.find_spec("pycolmap") is not None:
                mode = "triangulate"
            else:
                mode = "random"
        how = {
            "points": f"the dataset's {n_points} sparse points",
            "hull": "the training images' visual hull",
            "random": "random points in the scene's sphere",
        }.get(mode, "")
        xyz, rgb = scene.points, scene.point_colors
        if mode == "points" and n_points == 0:
            raise fail(
                scene.source or "dataset",
                "has no sparse points to start from",
                "Use --init random, or build the dataset with its points (nerfkit poses --points)",
            )
        if mode == "triangulate":
            xyz, rgb, how = triangulated(scene.train, work)
            if len(xyz) < MIN_INIT_POINTS and c.init == "auto":
                mode, how = "random", f"random points in the scene's sphere ({how}: too few)"
            elif len(xyz) == 0:
                raise fail(scene.source or "dataset", f"{how}: no points", "Use --init random")
        if mode in ("points", "triangulate"):
            pts, cols = points_init(xyz, rgb, c.init_points, gen)
            scale = neighbour_scales(pts)
        elif mode == "hull":
            hull = visual_hull(scene.train, bg, center, radius)
            if hull is None:
                raise fail(
                    scene.source or "dataset",
                    "the visual hull of the training images is empty",
                    "Use --init random, or check --background matches the images' background",
                )
            pts, cols, volume = sample_hull(hull, c.init_points, gen)
            if c.hull_prune:
                framed = hull["grid"] & (hull["seen"] >= HULL_MIN_SEEN * len(scene.train))
                self._hull = {
                    "grid": torch.as_tensor(grow(framed, HULL_MARGIN)),
                    "low": hull["low"],
                    "cell": hull["cell"],
                }
            scale = self._volume_scale(volume, len(pts))
        else:
            pts = random_start(c.init_points, self.bounds, center, radius, gen)
            cols = torch.full_like(pts, 0.5)
            scale = self._volume_scale(4 / 3 * math.pi * (0.7 * radius) ** 3, len(pts))
        device = self.means.device
        self._install(*(t.to(device) for t in initial_gaussians(pts, cols, scale, c.init_opacity)))
        return f"splat: {len(pts)} initial Gaussians from {how}"

    @torch.no_grad()
    def set_gaussians(self, g) -> None:
        """Install raw parameters from a :class:`~nerfkit.splat_files.Gaussians` (e.g. a
        PLY read back); missing higher SH degrees are zero, and a zero quaternion (which some
        tools write for a Gaussian without rotation) is the identity."""
        n = len(g)
        from ..splat_files import rotation_quats

        quats = rotation_quats(g.quats).astype(np.float32)
        rest = torch.zeros(n, 15, 3)
        rest[:, : g.sh_rest.shape[1]] = torch.as_tensor(g.sh_rest)
        device = self.means.device
        self._install(
            *(
                torch.as_tensor(np.asarray(t)).to(device)
                for t in (g.means, g.log_scales, quats, g.opacity_logits, g.sh_dc, rest)
            )
        )
        self.active_degree = max(self.active_degree, g.sh_degree)

    # -- rendering -------------------------------------------------------------------
    def _background_image(self, K: Tensor, c2w: Tensor, width: int, height: int, background: Tensor) -> Tensor:
        if self.bg_coef is None:
            return background.to(self.means).reshape(1, 1, 3).expand(height, width, 3)
        rays = image_rays(K, c2w, width, height)
        return torch.sigmoid(sh16(rays.directions) @ self.bg_coef.t()).reshape(height, width, 3)

    def render_view(self, K, c2w, width: int, height: int, background: Tensor) -> RenderOutput:
        """Render one whole view: ``rgb`` (H, W, 3), ``depth`` (H, W) alpha-weighted depth
        sum, ``acc`` (H, W); the colour is differentiable in the Gaussians and in ``c2w``
        (4, 4) when it is a tensor that requires grad (a pose correction's camera)."""
        device = self.means.device
        if device.type == "cpu" and self.config.torch_threads and torch.get_num_threads() != self.config.torch_threads:
            torch.set_num_threads(self.config.torch_threads)
        K = torch.as_tensor(np.asarray(K) if not isinstance(K, Tensor) else K, dtype=torch.float32).to(device)
        c2w = torch.as_tensor(np.asarray(c2w) if not isinstance(c2w, Tensor) else c2w, dtype=torch.float32).to(device)
        w2c = torch.linalg.inv(c2w.double()).float()
        bg = self._background_image(K, c2w, width, height, background)
        out = render_gaussians(
            self.means,
            self.log_scales,
            self.quats,
            self.opacity_logits,
            self.sh_dc,
            self.active_degree,
            w2c,
            K,
            width,
            height,
            bg,
            self.near_plane,
            self.config.kernels,
            track_means2d=self.training and torch.is_grad_enabled(),
            sh_rest=self.sh_rest,
            sh_dir_grad=self.config.sh_dir_grad,
        )
        if self.training and torch.is_grad_enabled():
            self._last = (out, width, height)
        # the rasterizer weighs each Gaussian's camera z; RenderOutput's depth is along each ray
        return RenderOutput(
            out.rgb, out.depth * ray_length_per_z(K, width, height), out.alpha, int((out.radii > 0).sum())
        )

    def render_rays(self, rays: Rays, background: Tensor, perturb: bool) -> RenderOutput:
        raise fail("splat", "renders whole views, not ray batches", "Use render_view (the trainer and render_image do)")

    def query(self, points: Tensor, directions: Tensor) -> tuple[Tensor, Tensor]:
        raise fail(
            "splat",
            "has no density field to sample",
            "Export Gaussians with `nerfkit export RUN --splat out.ply`, or a point cloud with --points",
        )

    def loss(self, out: RenderOutput, target_rgb: Tensor) -> Tensor:
        """``(1 - w) L1 + w (1 - SSIM)`` over the image (H, W, 3)."""
        l1 = torch.mean(torch.abs(out.rgb - target_rgb))
        w = self.config.ssim_weight
        if w == 0:
            return l1
        return (1 - w) * l1 + w * (1 - ssim(out.rgb, target_rgb, self.config.kernels))

    # -- optimisation ----------------------------------------------------------------
    def param_groups(self, lr: float) -> list[dict]:
        c = self.config
        groups = [
            {
                "params": [self.means],
                "lr": lr * c.position_lr * self.extent,
                "name": "means",
                "lr_final_factor": c.position_lr_final,
            },
            {"params": [self.log_scales], "lr": lr * c.scale_lr, "name": "log_scales", "lr_final_factor": c.lr_final},
            {"params": [self.quats], "lr": lr * c.rotation_lr, "name": "quats", "lr_final_factor": c.lr_final},
            {
                "params": [self.opacity_logits],
                "lr": lr * c.opacity_lr,
                "name": "opacity_logits",
                "lr_final_factor": c.lr_final,
            },
            {"params": [self.sh_dc], "lr": lr * c.sh_lr, "name": "sh_dc", "lr_final_factor": c.lr_final},
            {"params": [self.sh_rest], "lr": lr * c.sh_lr / 20, "name": "sh_rest", "lr_final_factor": c.lr_final},
        ]
        if self.bg_coef is not None:
            groups.append({"params": [self.bg_coef], "lr": lr * 1e-2, "name": "bg_coef"})
        if c.lr_budget:
            groups = [{**g, "lr_budget": (c.lr_budget, LR_BUDGET_POWER, LR_BUDGET_FLOOR)} for g in groups]
        # (3DGS's Adam epsilon; on the CPU torch's fused Adam: one pass over each parameter
        # instead of six, the same update up to float rounding)
        fused = {"fused": True} if self.means.device.type == "cpu" else {}
        return [{**g, "eps": 1e-15, **fused} for g in groups]

    def schedules(self) -> list[Schedule]:
        """Before each step: the SH degree for the progress. After each step: densification
        and opacity resets (3DGS's adaptive density control); they edit the Gaussians and
        carry the optimizer's moments along."""
        always = lambda s: True  # noqa: E731
        return [
            Schedule("sh degree", always, self._set_progress),
            Schedule("density control", always, self._density_control, phase="after_step"),
        ]

    def _set_progress(self, s: StepState) -> None:
        self._progress = s.progress
        self.active_degree = min(self.config.sh_degree, int(s.progress / self.config.sh_up_every))

    @torch.no_grad()
    def _density_control(self, s: StepState) -> None:
        c = self.config
        done = s.step + 1
        densifying = c.densify_from <= self._progress < c.densify_until
        if self._last is not None:
            out, width, height = self._last
            self._last = None
            if densifying and out.means2d is not None and out.means2d.grad is not None:
                self._record_gradients(out.means2d.grad, out.radii, width, height)
        if densifying and done % c.densify_every == 0:
            self.densify_and_prune(self._image_side, s.optimizer)
        elif self._hull is not None and done % c.densify_every == 0:
            self.prune_outside_hull(s.optimizer)
        if c.opacity_reset_every > 0 and self._progress < c.densify_until:
            resets = int(self._progress / c.opacity_reset_every)
            if resets > self.n_resets:
                self.n_resets = resets
                self.reset_opacity(s.optimizer)

    def _record_gradients(self, grad2d: Tensor, radii: Tensor, width: int, height: int) -> None:
        """Accumulate the view-space gradient norm of the visible Gaussians (in NDC units, as 3DGS)."""
        vis = radii > 0
        g = grad2d.reshape(-1, 2)[vis] * torch.tensor([0.5 * width, 0.5 * height], device=grad2d.device)
        self.grad_accum[vis] += g.norm(dim=-1)
        self.grad_count[vis] += 1
        self.max_radii[vis] = torch.maximum(self.max_radii[vis], radii[vis].float())
        self._image_side = max(width, height)

    @torch.no_grad()
    def densify_and_prune(self, image_side: int, optimizer: torch.optim.Optimizer | None = None) -> None:
        """One round of adaptive density control: clone, split, then prune (the Adam
        moments of ``optimizer`` follow the Gaussians; new ones start at zero)."""
        c = self.config
        grads = self.grad_accum / self.grad_count.clamp_min(1)
        big = torch.exp(self.log_scales).amax(1) > c.percent_dense * self.extent
        want = grads >= c.densify_grad
        room = c.max_gaussians - self.n_gaussians
        clone, split = want & ~big, want & big
        n_new = int(clone.sum()) + int(split.sum())
        if room <= 0:
            clone, split = torch.zeros_like(want), torch.zeros_like(want)
        elif n_new > room:  # keep the largest gradients
            keep = torch.zeros_like(want)
            keep[torch.topk(torch.where(want, grads, torch.full_like(grads, -1.0)), room).indices] = True
            clone, split = clone & keep, split & keep
        n = self.n_gaussians
        # clone: a copy in place; split: two samples from the Gaussian, 1.6x smaller, replacing it
        new = {name: getattr(self, name).detach()[clone] for name in PARAMS}
        idx = torch.nonzero(split).squeeze(1)
        if len(idx):
            scales = torch.exp(self.log_scales[idx]).repeat(2, 1)
            R = ref.quat_to_rotmat(self.quats[idx]).repeat(2, 1, 1)
            samples = (R @ (torch.randn_like(scales) * scales).unsqueeze(-1)).squeeze(-1)
            split_new = {
                name: getattr(self, name).detach()[idx].repeat(2, *([1] * (getattr(self, name).dim() - 1)))
                for name in PARAMS
            }
            split_new["means"] = split_new["means"] + samples
            split_new["log_scales"] = torch.log(scales / 1.6)
            new = {name: torch.cat([new[name], split_new[name]]) for name in PARAMS}
        self._append(new, optimizer)
        # prune: the split originals, transparent ones, and (after a reset) huge ones
        remove = torch.cat([split, torch.zeros(self.n_gaussians - n, dtype=torch.bool, device=split.device)])
        remove |= torch.sigmoid(self.opacity_logits) < c.prune_opacity
        if self.n_resets > 0:
            remove |= torch.exp(self.log_scales).amax(1) > 0.1 * self.extent
            if c.prune_screen > 0 and image_side > 0:
                remove |= self.max_radii > c.prune_screen * image_side
        if self._hull is not None:
            remove |= outside_hull(self.means.detach(), self._hull)
        self._remove(remove, optimizer)
        self.grad_accum.zero_()
        self.grad_count.zero_()
        self.max_radii.zero_()

    @torch.no_grad()
    def prune_outside_hull(self, optimizer: torch.optim.Optimizer | None = None) -> None:
        """Remove the Gaussians whose centre is outside the (grown) visual hull (never the last one)."""
        if self._hull is not None:
            self._remove(outside_hull(self.means.detach(), self._hull), optimizer)

    @torch.no_grad()
    def reset_opacity(self, optimizer: torch.optim.Optimizer | None = None) -> None:
        """Opacity to at most 0.01 (3DGS): floaters must earn their opacity again (and
        their Adam moments in ``optimizer`` start again at zero)."""
        self.opacity_logits.clamp_(max=ref.logit(0.01))
        if optimizer is not None:
            state = optimizer.state.get(self.opacity_logits)
            if state:
                state["exp_avg"].zero_()
                state["exp_avg_sq"].zero_()

    def _edit_parameters(self, fn, rows: Tensor, optimizer: torch.optim.Optimizer | None) -> None:
        """Replace each Gaussian parameter ``p`` by ``fn(p, name)``, whose row ``i`` continues
        row ``rows[i]`` of ``p`` (-1: a new row), carrying the Adam moments along
        (:func:`~nerfkit.kernels.optim.replace_param`: new rows start at zero)."""
        for name in PARAMS:
            old = getattr(self, name)
            new = nn.Parameter(fn(old.detach(), name))
            if optimizer is not None:
                replace_param(optimizer, old, new, rows)
            setattr(self, name, new)

    def _append(self, new: dict, optimizer: torch.optim.Optimizer | None) -> None:
        m = new["means"].shape[0]
        if m == 0:
            return
        n = self.means.shape[0]
        rows = torch.cat([torch.arange(n, device=self.means.device), torch.full((m,), -1, device=self.means.device)])
        self._edit_parameters(lambda t, name: torch.cat([t, new[name]]), rows, optimizer)
        for buf in ("grad_accum", "grad_count", "max_radii"):
            setattr(self, buf, torch.cat([getattr(self, buf), getattr(self, buf).new_zeros(m)]))

    def _remove(self, remove: Tensor, optimizer: torch.optim.Optimizer | None) -> None:
        """Drop the Gaussians ``remove`` (n,) marks, never the last one (the most opaque stays)."""
        if bool(remove.all()):
            remove[torch.argmax(self.opacity_logits)] = False
        self._keep(~remove, optimizer)

    def _keep(self, keep: Tensor, optimizer: torch.optim.Optimizer | None) -> None:
        if bool(keep.all()):
            return
        self._edit_parameters(lambda t, name: t[keep].contiguous(), torch.nonzero(keep)[:, 0], optimizer)
        for buf in ("grad_accum", "grad_count", "max_radii"):
            setattr(self, buf, getattr(self, buf)[keep])

    # -- checkpoints -----------------------------------------------------------------
    def extra_state(self) -> dict:
        out: dict = {"n_gaussians": self.n_gaussians, "active_degree": self.active_degree, "n_resets": self.n_resets}
        if self._hull is not None:  # a resumed run prunes with the same hull
            grid = self._hull["grid"].cpu().numpy()
            out["hull"] = {
                "shape": list(grid.shape),
                "bits": base64.b64encode(np.packbits(grid.reshape(-1)).tobytes()).decode("ascii"),
                "low": [float(x) for x in self._hull["low"]],
                "cell": float(self._hull["cell"]),
            }
        return out

    def load_extra_state(self, state: dict) -> None:
        n = state.get("n_gaussians")
        if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= MAX_GAUSSIANS:
            raise fail(
                "checkpoint 'model_extra'",
                f"'n_gaussians' is {n!r}, expected 1 to {MAX_GAUSSIANS}",
                "The checkpoint is corrupt or not from nerfkit; delete it or re-train",
            )
        device = self.means.device
        self._install(
            torch.zeros(n, 3, device=device),
            torch.zeros(n, 3, device=device),
            torch.zeros(n, 4, device=device),
            torch.zeros(n, device=device),
            torch.zeros(n, 1, 3, device=device),
            torch.zeros(n, 15, 3, device=device),
        )
        self.active_degree = int(state.get("active_degree", self.config.sh_degree))
        self.n_resets = int(state.get("n_resets", 0))
        self._hull = None
        hull = state.get("hull")
        if isinstance(hull, dict):
            try:
                shape = tuple(int(x) for x in hull["shape"])
                if len(shape) != 3 or min(shape) < 1 or max(shape) > 1024:
                    raise ValueError(f"a grid of shape {shape}")
                bits = np.frombuffer(base64.b64decode(hull["bits"]), np.uint8)
                grid = np.unpackbits(bits)[: int(np.prod(shape))].reshape(shape).astype(bool)
                low = np.asarray([float(x) for x in hull["low"]], np.float64).reshape(3)
                self._hull = {"grid": torch.as_tensor(grid), "low": low, "cell": float(hull["cell"])}
            except (KeyError, TypeError, ValueError) as e:
                raise fail(
                    "checkpoint 'model_extra'",
                    f"its 'hull' cannot be read ({e})",
                    "The checkpoint is corrupt or not from nerfkit; delete it or re-train",
                ) from None

    def backend(self) -> str:
        return resolve_backend(self.config.kernels, self.means.device)

    def gradients_finite(self) -> bool:
        """As the base class's, in one compiled pass over each gradient on the CPU
        (``torch.isfinite(...).all()`` makes four)."""
        nb = splat_kernels() if self.backend() == "numba" else None
        if nb is None:
            return super().gradients_finite()
        grads = (p.grad.detach().reshape(-1) for p in self.parameters() if p.grad is not None)
        return all(nb.all_finite(g.numpy()) for g in grads)

    def load_kernels(self) -> None:
        self.backend()


# -- initialisation -------------------------------------------------------------------
def triangulated(views, work: Path | None) -> tuple[np.ndarray, np.ndarray | None, str]:
    """Sparse points (m, 3), their colours (m, 3) uint8 and a note, triangulated from
    ``views`` at their poses (:func:`nerfkit.capture.points.triangulate_views`; scratch files
    in a temporary folder inside ``work``, removed)."""
    import time

    from ..capture.points import triangulate_views

    start = time.perf_counter()
    pts = triangulate_views(views, work=work)
    seconds = time.perf_counter() - start
    note = f"{len(pts)} points triangulated from the {len(views)} training photos at their poses ({seconds:.0f} s)"
    return pts.xyz, pts.rgb, note


def initial_gaussians(points: Tensor, colors: Tensor, scale: float | Tensor, opacity: float) -> tuple[Tensor, ...]:
    """Isotropic Gaussians at ``points`` (n, 3) with ``colors`` (n, 3) in [0, 1] and one
    ``scale`` or a scale per point (n,):
    ``(means, log_scales, quats, opacity_logits, sh_dc (n, 1, 3), sh_rest (n, 15, 3))``."""
    n = points.shape[0]
    quats = torch.zeros(n, 4)
    quats[:, 0] = 1
    log_scale = torch.as_tensor(scale, dtype=torch.float32).clamp_min(1e-8).log().reshape(-1, 1).expand(n, 3)
    return (
        points.float(),
        log_scale.clone(),
        quats,
        torch.full((n,), ref.logit(opacity)),
        ref.rgb_to_sh_dc(colors.float()).unsqueeze(1),
        torch.zeros(n, 15, 3),
    )


def points_init(xyz: np.ndarray, rgb: np.ndarray | None, n: int, gen: torch.Generator) -> tuple[Tensor, Tensor]:
    """Sparse points (m, 3) and colours (m, 3) uint8 as initial means and colours in [0, 1]:
    all of them, or a random ``n`` of them when there are more."""
    pts = torch.as_tensor(np.asarray(xyz, np.float32))
    cols = torch.full_like(pts, 0.5) if rgb is None else torch.as_tensor(np.asarray(rgb, np.uint8)).float() / 255.0
    if len(pts) > n:
        pick = torch.randperm(len(pts), generator=gen)[:n]
        pts, cols = pts[pick], cols[pick]
    return pts, cols


def neighbour_scales(points: Tensor, k: int = 3, chunk: int = 1024) -> Tensor:
    """Initial size (n,) of a Gaussian at each point, as 3DGS: the root mean square
    distance to its ``k`` nearest other points (a lone point gets the median size)."""
    n = len(points)
    if n < 2:
        return torch.full((n,), 0.01)
    k = min(k, n - 1)
    out = torch.empty(n)
    p = points.double()
    for i in range(0, n, chunk):
        d2 = torch.cdist(p[i : i + chunk], p).square()
        d2[torch.arange(len(d2)), torch.arange(i, i + len(d2))] = math.inf
        out[i : i + chunk] = d2.topk(k, dim=1, largest=False).values.mean(1).sqrt().float()
    good = out[torch.isfinite(out) & (out > 0)]
    fill = float(good.median()) if len(good) else 0.01
    return torch.where(torch.isfinite(out) & (out > 0), out, torch.full_like(out, fill))


def flat_background(images: np.ndarray, bg: np.ndarray, tol: float = 0.05) -> bool:
    """True when the image borders are mostly the colour ``bg`` (synthetic renders)."""
    border = np.concatenate([images[:, 0], images[:, -1], images[:, :, 0], images[:, :, -1]], 1)
    diff = np.abs(border.astype(np.float32) / 255.0 - bg.reshape(1, 1, 3)).max(-1)
    return float(np.mean(diff < tol)) > 0.9


def visual_hull(
    views, bg: np.ndarray, center: np.ndarray, radius: float, res: int = 64, tol: float = 0.05
) -> dict | None:
    """Carve a ``res``^3 grid over the cube ``center +- radius`` with the views' silhouettes
    (pixels differing from ``bg`` by more than ``tol``). A cell stays when every view that
    sees its centre sees the object there. Returns ``{"points" (m, 3), "colors" (m, 3),
    "cell": side}`` of the kept cells, the whole ``"grid"`` (res, res, res) of kept cells (x, y, z
    order), how many views frame each cell (``"seen"``, the same shape) and the grid's corner
    ``"low"`` (3,), or None when none is kept."""
    ax = np.linspace(-radius, radius, res, endpoint=False) + radius / res
    X, Y, Z = np.meshgrid(ax, ax, ax, indexing="ij")
    pts = np.stack([X, Y, Z], -1).reshape(-1, 3) + center
    keep = np.ones(len(pts), bool)
    col_sum = np.zeros((len(pts), 3))
    seen = np.zeros(len(pts))
    for i in range(len(views)):
        img = views.images[i].astype(np.float32) / 255.0
        mask = np.abs(img - bg.reshape(1, 1, 3)).max(-1) > tol
        mask = _dilate(mask)
        uv, z = project_points(views.K[i], views.c2w[i], pts)
        u, v = uv[:, 0], uv[:, 1]
        inside = (z > 0) & (u >= 0) & (u < views.width) & (v >= 0) & (v < views.height)
        ui = np.clip(u, 0, views.width - 1).astype(int)
        vi = np.clip(v, 0, views.height - 1).astype(int)
        keep &= ~inside | mask[vi, ui]
        col_sum[inside] += img[vi[inside], ui[inside]]
        seen += inside
    keep &= seen > 0
    if not keep.any():
        return None
    return {
        "points": pts[keep],
        "colors": col_sum[keep] / seen[keep, None],
        "cell": 2 * radius / res,
        "grid": keep.reshape(res, res, res),
        "seen": seen.reshape(res, res, res),
        "low": np.asarray(center, np.float64) - radius,
    }


def grow(grid: np.ndarray, cells: int = 1) -> np.ndarray:
    """A boolean 3D grid grown ``cells`` times by one cell along each axis (its 6-neighbours)."""
    out = grid.copy()
    for _ in range(cells):
        last = out.copy()
        for axis in range(3):
            for shift in (1, -1):
                out |= np.roll(last, shift, axis) & ~_rolled_edge(grid.shape, axis, shift)
    return out


def _rolled_edge(shape: tuple, axis: int, shift: int) -> np.ndarray:
    """The cells np.roll by ``shift`` along ``axis`` wraps into (they get no neighbour)."""
    edge = np.zeros(shape, bool)
    index = [slice(None)] * 3
    index[axis] = 0 if shift > 0 else -1  # type: ignore[call-overload]
    edge[tuple(index)] = True
    return edge


def outside_hull(means: Tensor, hull: dict) -> Tensor:
    """(n,) True where a centre lies outside ``hull["grid"]`` (cells of side ``hull["cell"]``
    from the corner ``hull["low"]``), or outside the grid's cube."""
    grid = hull["grid"].to(means.device)
    low = torch.as_tensor(hull["low"], dtype=means.dtype, device=means.device)
    idx = torch.floor((means - low) / float(hull["cell"])).long()
    res = torch.tensor(grid.shape, device=means.device)
    in_cube = ((idx >= 0) & (idx < res)).all(1)
    idx = torch.minimum(idx.clamp_min(0), res - 1)
    return ~(in_cube & grid[idx[:, 0], idx[:, 1], idx[:, 2]])


def _dilate(mask: np.ndarray) -> np.ndarray:
    """A one-pixel dilation (silhouettes are conservative: keep thin parts)."""
    out = mask.copy()
    out[1:] |= mask[:-1]
    out[:-1] |= mask[1:]
    out[:, 1:] |= mask[:, :-1]
    out[:, :-1] |= mask[:, 1:]
    return out


def sample_hull(hull: dict, n: int, gen: torch.Generator) -> tuple[Tensor, Tensor, float]:
    """``n`` points uniformly in the kept cells, their colours, and the hull's volume."""
    pts = torch.as_tensor(hull["points"], dtype=torch.float32)
    cols = torch.as_tensor(hull["colors"], dtype=torch.float32)
    cell = float(hull["cell"])
    pick = torch.randint(0, len(pts), (n,), generator=gen)
    jitter = (torch.rand(n, 3, generator=gen) - 0.5) * cell
    return pts[pick] + jitter, cols[pick].clamp(0, 1), len(pts) * cell**3
