"""Per-view corrections learned beside the scene: camera poses and exposure.

Real captures have small pose errors (a tag's corners are found to a fraction of a
pixel, not exactly) and photos whose exposure and white balance change between shots.
The scene cannot explain either, so without corrections it blurs the object and grows
floaters to make up for them. As in nerfstudio, each training view gets:

* :class:`PoseCorrection`: a rigid motion about its camera centre (rotation vector and
  translation, zero at start), applied to the view's rays;
* :class:`ExposureCorrection`: a per-channel gain and offset applied to the rendered colour,
  ``rgb * exp(log_gain) + offset`` (with colour mixing, an affine colour transform), with
  the mean over views held at zero so that the scene keeps the photos' average exposure;
  a new view is rendered with the corrections of the photos near it in direction
  (:meth:`ViewCorrections.directional_colour`).

To score held-out photos fairly, :func:`fit_view` fits the same corrections to one photo
with the scene frozen (as BARF does) before its PSNR is measured.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

from ..cameras import Rays
from ..models.appearance import DirectionalColour


def skew(v: Tensor) -> Tensor:
    """(n, 3) vectors -> (n, 3, 3) cross-product matrices ``[v]_x``."""
    z = torch.zeros_like(v[:, 0])
    return torch.stack(
        [
            torch.stack([z, -v[:, 2], v[:, 1]], -1),
            torch.stack([v[:, 2], z, -v[:, 0]], -1),
            torch.stack([-v[:, 1], v[:, 0], z], -1),
        ],
        dim=1,
    )


def so3_exp(w: Tensor) -> Tensor:
    """(n, 3) rotation vectors (axis * angle, radians) -> (n, 3, 3) rotation matrices."""
    return torch.linalg.matrix_exp(skew(w))


def mean_removed(*params: Tensor) -> tuple[Tensor, ...]:
    """Each (n_views, k) parameter less its mean over views; a single view's as it is."""
    return tuple(p if p.shape[0] == 1 else p - p.mean(0) for p in params)


def corrected_poses(c2w: Tensor, R: Tensor, shift: Tensor) -> Tensor:
    """(..., 4, 4) camera-to-world poses, (..., 3, 3) rotations about each camera's centre and
    (..., 3) world shifts of the centres -> the corrected poses (..., 4, 4)."""
    top = torch.cat([R @ c2w[..., :3, :3], (c2w[..., :3, 3] + shift).unsqueeze(-1)], -1)
    return torch.cat([top, c2w[..., 3:, :]], -2)


class PoseCorrection(nn.Module):
    """Per-view rigid corrections in the world frame, about each camera's centre.

    View ``i`` sees along ``R_i d`` from ``o + scale * t_i``, with ``R_i = exp([w_i]_x)``;
    ``scale`` (the scene's size) makes one unit of ``t`` comparable to one radian of ``w``
    for the optimizer. With several views the mean of ``w`` and of ``t`` is removed: moving
    every camera and the scene together changes no photo, so without this the whole rig
    could drift away from the poses the held-out views are given in.

    Args:
        n_views: number of views; scale: scene length unit of the translations.
    """

    def __init__(self, n_views: int, scale: float):
        super().__init__()
        self.rotation = nn.Parameter(torch.zeros(n_views, 3))
        self.translation = nn.Parameter(torch.zeros(n_views, 3))
        self.scale = float(scale)

    def centred(self) -> tuple[Tensor, Tensor]:
        """(n_views, 3) rotation vectors and translations, mean removed (one view: as is)."""
        rotation, translation = mean_removed(self.rotation, self.translation)
        return rotation, translation

    def forward(self, rays: Rays, view: Tensor) -> Rays:
        """Rays (n_rays) of views ``view`` (n_rays,) -> the corrected rays."""
        w, t = self.centred()
        R = so3_exp(w)[view]  # (n_rays, 3, 3)
        d = (R @ rays.directions.unsqueeze(-1)).squeeze(-1)
        o = rays.origins + self.scale * t[view]
        return Rays(o, d)

    def camera(self, c2w: Tensor, view: int) -> Tensor:
        """(4, 4) camera-to-world of view ``view`` -> its corrected pose (4, 4), differentiable
        in the corrections: the camera that sees along the corrected rays of :meth:`forward`.

        A model that renders whole views (splat) renders from it; its projection is plain
        torch, so the image's gradient reaches the correction through the camera."""
        w, t = self.centred()
        return corrected_poses(c2w, so3_exp(w[view : view + 1])[0].to(c2w), self.scale * t[view].to(c2w))

    @torch.no_grad()
    def corrected_c2w(self, c2w: np.ndarray) -> np.ndarray:
        """(n_views, 4, 4) camera-to-world poses with the corrections applied."""
        poses = torch.as_tensor(np.asarray(c2w, np.float64))
        w, t = self.centred()
        out = corrected_poses(poses, so3_exp(w).to(poses), self.scale * t.to(poses))
        return out.numpy().astype(np.asarray(c2w).dtype)

    @torch.no_grad()
    def magnitudes(self) -> tuple[np.ndarray, np.ndarray]:
        """Per view: rotation angle (degrees) and translation length (scene units)."""
        w, t = self.centred()
        return np.degrees(w.norm(dim=1).cpu().numpy()), self.scale * t.norm(dim=1).cpu().numpy()


class ExposureCorrection(nn.Module):
    """Per-view colour correction, ``rgb * exp(g_i) + rgb @ m_i^T + b_i`` with the mean over
    views of ``g``, ``m`` and ``b`` removed (the scene keeps the photos' average colour).

    ``g`` (3,) is a gain per channel (exposure and white balance). With ``mix``, ``m``
    (3, 3, zero diagonal) lets each channel take some of the others: with the gains, an
    affine colour transform per photo, as Urban Radiance Fields' exposure compensation
    (a phone's colour processing changes with the scene it sees). ``b`` (3,) is an offset.

    A single view (a held-out photo fitted alone) keeps its raw ``g``, ``m`` and ``b``.
    """

    def __init__(self, n_views: int, mix: bool = False):
        super().__init__()
        self.log_gain = nn.Parameter(torch.zeros(n_views, 3))
        self.offset = nn.Parameter(torch.zeros(n_views, 3))
        self.mix = nn.Parameter(torch.zeros(n_views, 6)) if mix else None

    def centred(self) -> tuple[Tensor, Tensor]:
        """(n_views, 3) log gains and offsets with their mean over views removed."""
        log_gain, offset = mean_removed(self.log_gain, self.offset)
        return log_gain, offset

    def matrices(self) -> Tensor:
        """(n_views, 3, 3) each view's colour matrix, ``diag(exp(g)) + m`` (mean removed)."""
        g = self.centred()[0]
        M = torch.diag_embed(torch.exp(g))
        if self.mix is not None:
            off = torch.zeros_like(M)
            off[:, OFF_DIAGONAL[0], OFF_DIAGONAL[1]] = mean_removed(self.mix)[0]
            M = M + off
        return M

    def forward(self, rgb: Tensor, view: Tensor) -> Tensor:
        """(n_rays, 3) rendered colours of views ``view`` (n_rays,) -> corrected colours, in
        float32 under autocast too (a bf16 matrix product would round them to 2-3 bits of 8)."""
        g, b = self.centred()
        if self.mix is None:
            return rgb * torch.exp(g[view]) + b[view]
        with torch.autocast(rgb.device.type, enabled=False):
            return (self.matrices()[view] @ rgb.float().unsqueeze(-1)).squeeze(-1) + b[view]

    def mix_penalty(self) -> Tensor:
        """Mean over views of ``|m_i|^2`` (squared Frobenius norm of the colour mixing, mean
        removed); 0 without mixing. Grey pixels constrain only each row's sum of a colour
        matrix, and a capture is mostly grey (sheet, tags, table): without this pull towards
        no mixing, views that see little colour take wild matrices (off-diagonal entries
        above 1; ``--colour-mix`` in BENCHMARKS.md) and the colours of what few photos see
        drift with them."""
        if self.mix is None:
            return self.log_gain.new_zeros(())
        return mean_removed(self.mix)[0].square().sum(1).mean()

    @torch.no_grad()
    def gains(self) -> np.ndarray:
        """(n_views, 3) multiplicative gains relative to the average view."""
        return torch.exp(self.centred()[0]).cpu().numpy()


def rounded(values) -> list[float]:
    """Numbers as floats rounded to 4 decimals, for the JSON reports."""
    return [round(float(v), 4) for v in values]


# (rows, columns) of the off-diagonal entries of a 3x3 colour matrix, in ExposureCorrection.mix's order
OFF_DIAGONAL = (torch.tensor([0, 0, 1, 1, 2, 2]), torch.tensor([1, 2, 0, 2, 0, 1]))


class ViewCorrections(nn.Module):
    """The corrections of every training view, either part possibly off (None)."""

    def __init__(self, n_views: int, scale: float, pose: bool, exposure: bool, colour_mix: bool = False):
        super().__init__()
        self.pose = PoseCorrection(n_views, scale) if pose else None
        self.exposure = ExposureCorrection(n_views, colour_mix) if exposure else None

    def param_groups(self, pose_lr: float, exposure_lr: float) -> list[dict]:
        groups = []
        if self.pose is not None:
            groups.append({"params": list(self.pose.parameters()), "lr": pose_lr})
        if self.exposure is not None:
            groups.append({"params": list(self.exposure.parameters()), "lr": exposure_lr})
        return groups

    @torch.no_grad()
    def directional_colour(self, c2w: np.ndarray, center: np.ndarray) -> DirectionalColour | None:
        """The views' colour corrections by direction from ``center`` (3,), the views' poses
        ``c2w`` (n, 4, 4) as given, for rendering new views; None without exposure correction."""
        if self.exposure is None:
            return None
        offsets = self.exposure.centred()[1]
        return DirectionalColour.of_photos(
            c2w, self.exposure.matrices().cpu().double().numpy(), offsets.cpu().double().numpy(), center
        )

    @torch.no_grad()
    def report(self, names: list[str] | None) -> list[dict]:
        """Per view: name, pose correction (degrees, scene units), ``gain_rgb`` (the
        exposure gain of each channel, the colour matrix's diagonal) and, with colour
        mixing, the colour matrix (rows: output channels)."""
        if self.pose is not None:
            n = self.pose.rotation.shape[0]
        else:
            assert self.exposure is not None  # (a ViewCorrections corrects something)
            n = self.exposure.log_gain.shape[0]
        rows: list[dict[str, Any]] = [{"view": i, "name": names[i] if names else None} for i in range(n)]
        if self.pose is not None:
            deg, dist = self.pose.magnitudes()
            for r, a, t in zip(rows, deg, dist):
                r.update(rotation_deg=round(float(a), 4), translation=round(float(t), 6))
        if self.exposure is not None:
            for r, g in zip(rows, self.exposure.gains()):
                r["gain_rgb"] = rounded(g)
            if self.exposure.mix is not None:
                for r, M in zip(rows, self.exposure.matrices().cpu().numpy()):
                    r["colour_matrix"] = [rounded(row) for row in M]
        return rows


class ViewAdam(torch.optim.Optimizer):
    """Adam over per-view parameters (row ``i`` of each: view ``i``'s) that steps only the
    rows of the views a step saw, each with its own moments and step count.

    A model that renders one whole view per step (splat) sees each view once in ``n_views``
    steps. A dense Adam then moves every row every step: the rows of unseen views by the
    momentum of their last visit and by the small gradient the mean removal
    (:func:`mean_removed`) passes to them, and at each visit by about ``sqrt(n_views)``
    times the learning rate (the second moment averages the view's rare gradients with
    the zeros in between). Here a row moves only when its view is rendered, by about
    ``lr`` as Adam does for a parameter seen every step (as ``torch.optim.SparseAdam``,
    with a step count per row for the bias correction). Parameters: (n_views, ...) each.

    Args:
        params: parameters or groups (``lr`` per group); betas, eps: as in Adam.
    """

    def __init__(self, params, lr: float = 1e-3, betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-8):
        super().__init__(params, dict(lr=lr, betas=betas, eps=eps))

    @torch.no_grad()
    def step(self, closure=None, rows: Tensor | None = None):
        """One Adam step of rows ``rows`` ((k,) long, the views seen; None: every row)
        of each parameter that has a gradient; the other rows and their moments stay."""
        loss = None
        if closure is not None:
            with torch.enable_grad():
                loss = closure()
        for group in self.param_groups:
            beta1, beta2 = group["betas"]
            for p in group["params"]:
                if p.grad is None:
                    continue
                state = self.state[p]
                if not state:
                    state["step"] = torch.zeros(p.shape[0], dtype=torch.float32, device=p.device)
                    state["exp_avg"] = torch.zeros_like(p)
                    state["exp_avg_sq"] = torch.zeros_like(p)
                else:
                    state["step"] = row_steps(state["step"], p)
                r = torch.arange(p.shape[0], device=p.device) if rows is None else rows.to(p.device).unique()
                g = p.grad[r]
                step = state["step"][r] + 1
                m = state["exp_avg"][r].mul_(beta1).add_(g, alpha=1 - beta1)
                v = state["exp_avg_sq"][r].mul_(beta2).addcmul_(g, g, value=1 - beta2)
                shape = (-1,) + (1,) * (p.dim() - 1)
                denom = (v / (1 - beta2**step).reshape(shape)).sqrt_().add_(group["eps"])
                p[r] -= group["lr"] * m / (1 - beta1**step).reshape(shape) / denom
                state["step"][r], state["exp_avg"][r], state["exp_avg_sq"][r] = step, m, v
        return loss


def build_view_corrections(
    n_views: int,
    radius: float,
    pose_lr: float,
    exposure_lr: float,
    colour_mix: bool,
    one_view_per_step: bool,
    device: torch.device,
) -> tuple[ViewCorrections | None, torch.optim.Optimizer | None]:
    """The corrections of ``n_views`` training views (a pose one with ``pose_lr`` > 0, its
    translations scaled by the scene's ``radius``; an exposure one, with ``colour_mix``, with
    ``exposure_lr`` > 0) on ``device``, and their optimizer: :class:`ViewAdam` when a step
    renders ``one_view_per_step`` (only its row steps), else Adam. Neither: (None, None)."""
    pose, exposure = pose_lr > 0, exposure_lr > 0
    if not (pose or exposure):
        return None, None
    views = ViewCorrections(n_views, radius, pose, exposure, colour_mix).to(device)
    groups = views.param_groups(pose_lr, exposure_lr)
    return views, ViewAdam(groups) if one_view_per_step else torch.optim.Adam(groups)


def row_steps(step: Tensor, p: Tensor) -> Tensor:
    """:class:`ViewAdam`'s step counts of parameter ``p``, one per row, on ``p``'s device:
    torch's ``load_state_dict`` leaves a state named "step" where it was loaded (the CPU of
    ``map_location="cpu"``), and a dense Adam's state (an older checkpoint) has one count."""
    step = step.to(p.device)
    return step.expand(p.shape[0]).clone() if step.dim() == 0 else step


def least_squares_colour(rgb: np.ndarray, target: np.ndarray, mix: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The colour correction of one view that best maps its render onto its photo (least
    squares, so the lowest MSE): :class:`ExposureCorrection`'s model solved exactly.

    Args:
        rgb, target: (..., 3) rendered and photo colours of the same pixels.
        mix: an affine colour transform (3x3 matrix and offset); else a gain and an offset
            per channel.

    Returns:
        ``(matrix (3, 3), offset (3,))``; apply as ``rgb @ matrix.T + offset``.
    """
    X = np.asarray(rgb, np.float64).reshape(-1, 3)
    Y = np.asarray(target, np.float64).reshape(-1, 3)
    ones = np.ones((len(X), 1))
    if mix:
        coef, *_ = np.linalg.lstsq(np.concatenate([X, ones], 1), Y, rcond=None)  # (4, 3)
        return coef[:3].T.copy(), coef[3].copy()
    matrix, offset = np.zeros((3, 3)), np.zeros(3)
    for c in range(3):
        (matrix[c, c], offset[c]), *_ = np.linalg.lstsq(np.concatenate([X[:, c : c + 1], ones], 1), Y[:, c], rcond=None)
    return matrix, offset


@dataclass
class ViewFitConfig:
    """Test-time fit of one held-out photo's pose and exposure (scene frozen)."""

    steps: int = 100
    rays: int = 4096
    lr: float = 2e-3
    exposure: bool = True
    colour_mix: bool = False  # the exposure is an affine colour transform (as the run's, see ExposureCorrection)


def fit_view(
    render_fn, rays: Rays, target: Tensor, scale: float, cfg: ViewFitConfig, generator: torch.Generator | None = None
) -> tuple[PoseCorrection, ExposureCorrection]:
    """Fit a pose correction (and exposure) of one view to its photo, the scene frozen.

    Args:
        render_fn: ``Rays -> (n, 3) rgb`` of the frozen scene (differentiable in the rays).
        rays: every pixel ray of the view (H*W); target: (H*W, 3) the photo's colours.
        scale: scene length unit of the translation (as :class:`PoseCorrection`).

    Returns:
        the fitted single-view corrections (apply with view index 0).
    """
    n = target.shape[0]

    def batch(pose: PoseCorrection) -> tuple[Tensor, Tensor]:
        idx = torch.randint(0, n, (min(cfg.rays, n),), generator=generator).to(target.device)
        view = torch.zeros(len(idx), dtype=torch.long, device=target.device)
        return render_fn(pose(Rays(rays.origins[idx], rays.directions[idx]), view)), idx

    return _fit(batch, target, scale, cfg)


def fit_whole_view(
    render_fn, c2w: Tensor, target: Tensor, scale: float, cfg: ViewFitConfig
) -> tuple[PoseCorrection, ExposureCorrection]:
    """:func:`fit_view` for a model that renders whole views (splat): each step renders the
    view from the corrected camera (:meth:`PoseCorrection.camera`) and compares every pixel.

    Args:
        render_fn: ``c2w (4, 4) -> (H*W, 3) rgb`` of the frozen scene (differentiable in the camera).
        c2w: (4, 4) the view's given pose; target: (H*W, 3) the photo's colours.
    """
    every = torch.arange(target.shape[0], device=target.device)
    return _fit(lambda pose: (render_fn(pose.camera(c2w, 0)), every), target, scale, cfg)


def _fit(batch, target: Tensor, scale: float, cfg: ViewFitConfig) -> tuple[PoseCorrection, ExposureCorrection]:
    """Adam on one view's corrections; ``batch(pose) -> (rgb (n, 3), pixel indices (n,))``
    renders some of its pixels through the pose correction."""
    pose = PoseCorrection(1, scale).to(target.device)
    exposure = ExposureCorrection(1, cfg.colour_mix).to(target.device)
    params = list(pose.parameters()) + (list(exposure.parameters()) if cfg.exposure else [])
    opt = torch.optim.Adam(params, lr=cfg.lr)
    for step in range(cfg.steps):
        for g in opt.param_groups:  # cosine decay to 10%
            g["lr"] = cfg.lr * (0.1 + 0.9 * 0.5 * (1 + np.cos(np.pi * step / max(cfg.steps, 1))))
        rgb, idx = batch(pose)
        if cfg.exposure:
            rgb = exposure(rgb, torch.zeros(len(idx), dtype=torch.long, device=target.device))
        loss = torch.mean((rgb - target[idx]) ** 2)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        if all(bool(torch.isfinite(p.grad).all()) for p in params if p.grad is not None):
            opt.step()  # a step with a non-finite gradient is skipped, as in training
    return pose, exposure
