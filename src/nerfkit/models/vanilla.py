"""The course NeRF (Mildenhall et al. 2020): an 8x256 MLP with positional encoding.

Architecture: PE(x) with L=10 (63 inputs) -> 8 Linear+ReLU layers of width 256, with
PE(x) concatenated back in before the 5th -> density head (Linear to 1, ReLU) and a
feature Linear(256, 256) -> concat PE(d) with L=4 (27 inputs) -> Linear(283, 128) +
ReLU -> Linear(128, 3) + sigmoid.

Two changes are on by default, neither touching the network:

* The density head's bias starts at ``density_bias_init`` (0.1). With a bias at or
  below zero, a fresh run sometimes outputs zero density everywhere and ReLU passes no
  gradient back (PSNR stuck near 11 dB on lego); a small positive bias keeps every ray's
  density alive at the start.
* Empty-space skipping (``occupancy``): after ``occupancy_warmup`` steps, an occupancy
  grid refreshed from the MLP's own density decides which of the stratified samples are
  evaluated; the others count as empty. On lego about 3-6 of 64 samples per ray remain,
  and steps get ~15x faster (BENCHMARKS.md).

``--density-bias-init 0 --no-occupancy`` turns both off: the course's network and sampling.
Two details stay nerfkit's: each sample's interval is its gap to the next one (the last
reaches ``far``), where the course uses one step size; and without ``near``/``far`` in
the npz the depth range is 0.5x and 1.5x the cameras' mean distance (2.02 and 6.05 on
lego, where the course uses 2 and 6).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor, nn

from ..cameras import Rays
from ..config import check_ranges, option
from ..estimators.occupancy import OccupancyEstimator, RefreshRule
from ..fields.encoding import encoded_dim, positional_encoding
from ..precision import autocast
from ..render.box import GridBox
from ..render.sampling import intervals_from_t, sample_pdf, stratified_t
from ..render.volrend import composite, regular_ray_indices, render_weights
from .base import NerfModel, RenderOutput, SceneBounds, Schedule, StepState, rgb_loss

# A cell stays occupied while alpha = 1 - exp(-sigma * sample spacing) exceeds this.
OCCUPANCY_ALPHA = 0.01
# Cell densities decay by this factor per refresh before taking the new maximum (instant-ngp).
OCCUPANCY_DECAY = 0.8


@dataclass
class VanillaConfig:
    """Options of the ``vanilla`` model (its training settings: ``presets.MODEL_TRAINING``)."""

    n_samples: int = option(64, "stratified samples per ray", min=1, max=4096)
    n_importance: int = option(
        0, "extra samples per ray from hierarchical (coarse-to-fine) sampling; 0 = off", min=0, max=4096
    )
    pos_freqs: int = option(10, "positional-encoding octaves L for positions", min=0, max=32)
    dir_freqs: int = option(4, "positional-encoding octaves L for view directions", min=0, max=32)
    width: int = option(256, "MLP width", min=1, max=4096)
    depth: int = option(8, "MLP layers before the density head", min=2, max=64)
    density_bias_init: float = option(0.1, "initial bias of the density head (0 = the course's init)")
    occupancy: bool = option(
        True,
        "skip samples in empty space (an occupancy grid refreshed from the MLP's "
        "density); the network and the sampling are the course's, only fewer samples "
        "are evaluated",
    )
    occupancy_res: int = option(64, "occupancy grid cells per axis", min=4, max=512)
    occupancy_every: int = option(200, "steps between occupancy refreshes", min=1)
    occupancy_warmup: int = option(200, "steps before the first refresh (every sample is evaluated until then)", min=0)


class NeRFMLP(nn.Module):
    """(points, directions) -> (sigma, rgb), the course network."""

    def __init__(self, cfg: VanillaConfig):
        super().__init__()
        self.cfg = cfg
        in_x, in_d = encoded_dim(3, cfg.pos_freqs), encoded_dim(3, cfg.dir_freqs)
        self.skip = cfg.depth // 2  # PE(x) joins again before this layer
        layers = []
        for i in range(cfg.depth):
            n_in = in_x if i == 0 else cfg.width + (in_x if i == self.skip else 0)
            layers.append(nn.Linear(n_in, cfg.width))
        self.layers = nn.ModuleList(layers)
        self.density_head = nn.Linear(cfg.width, 1)
        nn.init.constant_(self.density_head.bias, cfg.density_bias_init)
        self.feature = nn.Linear(cfg.width, cfg.width)
        self.color_hidden = nn.Linear(cfg.width + in_d, cfg.width // 2)
        self.color_out = nn.Linear(cfg.width // 2, 3)

    def forward(self, x: Tensor, d: Tensor) -> tuple[Tensor, Tensor]:
        """x, d: (n, 3) positions and unit directions -> ((n,) sigma, (n, 3) rgb)."""
        ex = positional_encoding(x, self.cfg.pos_freqs)
        h = ex
        for i, layer in enumerate(self.layers):
            if i == self.skip:
                h = torch.cat([h, ex], dim=-1)
            h = torch.relu(layer(h))
        sigma = torch.relu(self.density_head(h)).squeeze(-1)
        ed = positional_encoding(d, self.cfg.dir_freqs)
        c = torch.relu(self.color_hidden(torch.cat([self.feature(h), ed], dim=-1)))
        rgb = torch.sigmoid(self.color_out(c))
        dtype = torch.promote_types(torch.float32, self.color_out.weight.dtype)  # (bf16 under autocast: float32)
        return sigma.to(dtype), rgb.to(dtype)


class VanillaNeRF(NerfModel):
    """Course NeRF with stratified sampling and optional hierarchical sampling.

    With ``n_importance > 0`` a second (fine) network is evaluated at samples drawn from
    the coarse weights, as in the paper; the loss sums both.
    """

    def __init__(self, cfg: VanillaConfig, bounds: SceneBounds):
        super().__init__(bounds)
        check_ranges(cfg)
        self.cfg = cfg
        self.coarse = NeRFMLP(cfg)
        self.fine = NeRFMLP(cfg) if cfg.n_importance > 0 else None
        self.estimator: OccupancyEstimator | None = None
        if cfg.occupancy:
            # refreshed before a step, every occupancy_every steps from occupancy_warmup; its
            # per-cell density estimate (inf: not measured yet, so occupied) is saved in checkpoints
            r = cfg.occupancy_res
            lo_x, lo_y, lo_z = (torch.as_tensor(bounds.center) - bounds.radius).tolist()
            box = GridBox((lo_x, lo_y, lo_z), 2.0 * bounds.radius / r, (r + 1, r + 1, r + 1))
            self.estimator = OccupancyEstimator(
                box, RefreshRule(cfg.occupancy_warmup, cfg.occupancy_every), running_max=True
            )

    def _spacing(self) -> float:
        return (self.bounds.far - self.bounds.near) / self.cfg.n_samples

    def load_state_dict(self, state_dict, strict: bool = True, assign: bool = False):
        if "cell_sigma" in state_dict:  # a checkpoint from before the occupancy estimator
            state_dict = {("estimator.cell_sigma" if k == "cell_sigma" else k): v for k, v in state_dict.items()}
        result = super().load_state_dict(state_dict, strict, assign)
        if self.estimator is not None:
            self.estimator.refresh_from_running_max(self._spacing(), OCCUPANCY_ALPHA)
        return result

    @torch.no_grad()
    def update_occupancy(self) -> None:
        """Re-measure each cell's density at a random point inside it (decayed running max)."""
        net = self.fine if self.fine is not None else self.coarse

        def occ_eval_fn(pts: Tensor) -> Tensor:
            dirs = torch.zeros_like(pts)
            dirs[:, 2] = 1.0
            return net(pts, dirs)[0]

        assert self.estimator is not None  # only called with --occupancy
        with autocast(self.estimator.occ.device, self.autocast_dtype):  # the precision the trainer resolved
            self.estimator.measure(occ_eval_fn, self._spacing(), OCCUPANCY_ALPHA, OCCUPANCY_DECAY)

    def schedules(self) -> list[Schedule]:
        """Occupancy updates, with ``--occupancy`` (the estimator decides when)."""
        if self.estimator is None:
            return []

        def refresh(s: StepState) -> None:
            assert self.estimator is not None
            self.estimator.update_every_n_steps(s.step, self.update_occupancy)

        return [Schedule("occupancy", lambda s: True, refresh)]

    def finish_training(self) -> list[str]:
        """A run that ends before ``occupancy_warmup`` measures its occupancy grid once here,
        so that the final evaluation, the renders and the saved model skip empty space
        (all 64 samples of 10 validation views took minutes). The RNG streams are left as
        they were."""
        if self.estimator is not None and not self.estimator.measured:
            device = self.estimator.occ.device
            with torch.random.fork_rng(devices=[device] if device.type == "cuda" else []):
                self.update_occupancy()
        return []

    def query(self, points: Tensor, directions: Tensor) -> tuple[Tensor, Tensor]:
        net = self.fine if self.fine is not None else self.coarse
        return net(points, directions)

    def _render(self, net: NeRFMLP, rays: Rays, t: Tensor, background: Tensor) -> tuple[RenderOutput, Tensor]:
        """Render stratified samples ``t`` (n_rays, n_samples); also returns their weights
        (n_rays, n_samples) for hierarchical sampling."""
        n_rays, n_samples = t.shape
        ray_indices = regular_ray_indices(n_rays, n_samples, t.device)
        t_flat = t.reshape(-1)
        deltas = intervals_from_t(t, self.bounds.far).reshape(-1)
        pts = rays.origins[ray_indices] + t_flat[:, None] * rays.directions[ray_indices]
        grid = self.estimator
        if grid is not None:  # evaluate the network only where the grid says there may be matter
            keep = ((pts >= grid.lo) & (pts <= grid.hi)).all(-1)
            keep[keep.clone()] = grid.is_occupied(pts[keep])
            kept = torch.nonzero(keep)[:, 0]  # the other samples are empty: they add no weight
            ray_indices, t_flat, deltas, pts = ray_indices[kept], t_flat[kept], deltas[kept], pts[kept]
        sigma, rgb = net(pts, rays.directions[ray_indices])
        weights, _, _ = render_weights(sigma, deltas, ray_indices)
        color, depth, acc = composite(weights, rgb, ray_indices, n_rays, t_flat, background)
        assert depth is not None  # composite returns a depth when given t
        if grid is not None:  # the skipped samples' weights are 0
            weights = weights.new_zeros(n_rays * n_samples).index_copy(0, kept, weights)
        return RenderOutput(color, depth, acc, len(ray_indices)), weights.view(n_rays, n_samples)

    def render_rays(self, rays: Rays, background: Tensor, perturb: bool) -> RenderOutput:
        n = len(rays)
        t = stratified_t(self.bounds.near, self.bounds.far, n, self.cfg.n_samples, perturb, rays.origins.device)
        coarse, weights = self._render(self.coarse, rays, t, background)
        if self.fine is None:
            return coarse
        mids = 0.5 * (t[:, 1:] + t[:, :-1])
        edges = torch.cat([t[:, :1], mids, t[:, -1:]], dim=-1)
        t_fine = sample_pdf(edges, weights, self.cfg.n_importance, perturb)
        t_all, _ = torch.sort(torch.cat([t, t_fine], dim=-1), dim=-1)
        fine, _ = self._render(self.fine, rays, t_all, background)
        fine.n_samples += coarse.n_samples
        fine.extras["rgb_coarse"] = coarse.rgb
        return fine

    def loss(self, out: RenderOutput, target_rgb: Tensor) -> Tensor:
        loss = rgb_loss(out.rgb, target_rgb)
        if "rgb_coarse" in out.extras:
            loss = loss + rgb_loss(out.extras["rgb_coarse"], target_rgb)
        return loss
