"""Rendering 3D Gaussians on either path.

On the CPU with numba, projection, opacity and SH colour are :class:`ProjectFunction` (one
compiled pass over the Gaussians forward and one backward, in place of the torch
reference's few dozen small operations over every Gaussian and autograd's graph of them),
and the rasterizer, where the time goes, is :class:`RasterizeFunction`:
the compiled kernels of :mod:`nerfkit.kernels.splat_numba` forward and backward.
Otherwise (CUDA tensors, no numba, ``backend="torch"``, or a camera that needs a gradient)
projection and colour are the torch reference and (except on the CPU) so is the
rasterizer, :func:`~nerfkit.kernels.splat_reference.rasterize_reference` under autograd.
On CUDA with ``gsplat`` installed, :func:`render_gaussians` hands the whole pipeline to gsplat.

Only the colour output carries gradients on the compiled path (depth and alpha are for
display); ``tests/test_splat_kernels.py`` compares values and gradients of the two paths.
The training loss's SSIM (:func:`ssim`) is compiled on the CPU too (:class:`SSIMFunction`),
beside its reference :func:`~nerfkit.kernels.splat_reference.ssim_reference`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from . import splat_kernels
from . import splat_reference as ref
from .ops import default_lanes


class RasterizeFunction(torch.autograd.Function):
    """The compiled rasterizer as an autograd function (CPU tensors, float32 or float64)."""

    @staticmethod
    def forward(ctx, means2d, conics, colors, opacities, depths, background, rects, width, height):
        nb = splat_kernels()
        tw, th = -(-width // ref.TILE), -(-height // ref.TILE)
        r = rects.contiguous().numpy()
        offsets, ids = nb.bin_tiles(nb.depth_order(depths.detach().contiguous().numpy(), r), r, tw, th)
        dt = means2d.dtype
        arrays = [t.detach().contiguous() for t in (means2d, conics, colors, opacities, depths, background)]
        rgb = torch.empty((height, width, 3), dtype=dt)
        depth = torch.empty((height, width), dtype=dt)
        alpha = torch.empty((height, width), dtype=dt)
        final_T = torch.empty((height, width), dtype=dt)
        n_contrib = torch.empty((height, width), dtype=torch.int64)
        nb.rasterize_forward(
            offsets,
            ids,
            *(a.numpy() for a in arrays),
            width,
            height,
            tw,
            rgb.numpy(),
            depth.numpy(),
            alpha.numpy(),
            final_T.numpy(),
            n_contrib.numpy(),
            default_lanes(),
        )
        ctx.save_for_backward(*arrays, final_T, n_contrib)
        ctx.bins = (offsets, ids)
        ctx.size = (width, height, tw)
        ctx.mark_non_differentiable(depth, alpha)
        return rgb, depth, alpha

    @staticmethod
    def backward(ctx, grad_rgb, grad_depth, grad_alpha):
        nb = splat_kernels()
        means2d, conics, colors, opacities, depths, background, final_T, n_contrib = ctx.saved_tensors
        width, height, tw = ctx.size
        offsets, ids = ctx.bins
        n = means2d.shape[0]
        grads = torch.zeros((default_lanes(), n, nb.N_GRAD), dtype=means2d.dtype)
        g_rgb = grad_rgb.contiguous().to(means2d.dtype)
        nb.rasterize_backward(
            offsets,
            ids,
            means2d.numpy(),
            conics.numpy(),
            colors.numpy(),
            opacities.numpy(),
            depths.numpy(),
            background.numpy(),
            width,
            height,
            tw,
            final_T.numpy(),
            n_contrib.numpy(),
            g_rgb.numpy(),
            grads.numpy(),
        )
        g = grads.sum(0)
        g_bg = final_T.unsqueeze(-1) * g_rgb if ctx.needs_input_grad[5] else None
        return g[:, 0:2], g[:, 2:5], g[:, 6:9], g[:, 5], None, g_bg, None, None, None


class ProjectFunction(torch.autograd.Function):
    """Projection, opacity and SH colour of every Gaussian in one compiled pass forward and
    one backward (:func:`~nerfkit.kernels.splat_numba.project_forward` /
    ``project_backward``): what :func:`render_gaussians` computes with the torch reference
    (``project_gaussians``, ``sigmoid``, ``sh_to_rgb``), without autograd's graph of a few
    dozen small operations over every Gaussian (CPU tensors, float32 or float64; the camera
    carries no gradient). Returns ``means2d, conics, colors, opacities, depths, radii, rects``.
    With ``dir_grad`` the colour's view direction passes its gradient to the means (see
    :func:`render_gaussians`)."""

    @staticmethod
    def forward(
        ctx,
        means,
        log_scales,
        quats,
        opacity_logits,
        sh_dc,
        sh_rest,
        degree,
        w2c,
        K,
        width,
        height,
        near,
        dir_grad=False,
    ):
        nb = splat_kernels()
        n, dt = means.shape[0], means.dtype
        params = [t.detach().contiguous() for t in (means, log_scales, quats, opacity_logits, sh_dc, sh_rest)]
        view, cam, intr = camera_arrays(w2c, K, dt)
        means2d, conics, colors = (torch.empty((n, k), dtype=dt) for k in (2, 3, 3))
        opacities, depths = torch.empty(n, dtype=dt), torch.empty(n, dtype=dt)
        radii, rects = torch.empty(n, dtype=torch.int32), torch.empty((n, 4), dtype=torch.int32)
        outs = (means2d, conics, colors, opacities, depths, radii, rects)
        nb.project_forward(
            *(p.numpy() for p in params), degree, view, cam, intr, width, height, near, *(t.numpy() for t in outs)
        )
        ctx.save_for_backward(*params)
        ctx.camera = (degree, view, cam, intr, width, height, near, bool(dir_grad))
        ctx.mark_non_differentiable(radii, rects)
        return outs

    @staticmethod
    def backward(ctx, g_means2d, g_conics, g_colors, g_opacities, g_depths, _radii, _rects):
        params = ctx.saved_tensors
        n, dt = params[0].shape[0], params[0].dtype
        shapes = ((n, 2), (n, 3), (n, 3), (n,), (n,))
        grads_out = [
            torch.zeros(shape, dtype=dt) if g is None else g.to(dt).contiguous()
            for g, shape in zip((g_means2d, g_conics, g_colors, g_opacities, g_depths), shapes)
        ]
        grads_in = [torch.empty_like(p) for p in params]
        splat_kernels().project_backward(
            *(p.numpy() for p in params), *ctx.camera, *(g.numpy() for g in grads_out), *(g.numpy() for g in grads_in)
        )
        return (*grads_in, None, None, None, None, None, None, None)


def camera_arrays(w2c: Tensor, K: Tensor, dtype: torch.dtype) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The compiled projection's camera: ``view`` (3, 4) world-to-camera rows, ``cam`` (3,) the
    camera centre (as the reference computes it: the inverse in ``dtype``), ``intr`` (4,)
    ``fx, fy, cx, cy``, all float64 arrays of the values the reference sees in ``dtype``."""
    w = w2c.detach().to(dtype)
    cam = torch.linalg.inv(w)[:3, 3]
    k = K.detach()
    intr = [float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2])]
    return w[:3].double().numpy().copy(), cam.double().numpy().copy(), np.array(intr, np.float64)


def rasterize(
    means2d: Tensor,
    conics: Tensor,
    colors: Tensor,
    opacities: Tensor,
    depths: Tensor,
    rects: Tensor,
    background: Tensor,
    width: int,
    height: int,
    backend: str = "auto",
) -> tuple[Tensor, Tensor, Tensor]:
    """Composite projected Gaussians into ``(rgb (H, W, 3), depth (H, W), alpha (H, W))``.

    Arguments as :func:`~nerfkit.kernels.splat_reference.rasterize_reference`; ``backend``:
    ``auto`` (compiled on the CPU when available), ``numba`` or ``torch``.
    """
    if resolve_backend(backend, means2d.device) == "numba":
        return RasterizeFunction.apply(means2d, conics, colors, opacities, depths, background, rects, width, height)
    return ref.rasterize_reference(means2d, conics, colors, opacities, depths, rects, background, width, height)


class SSIMFunction(torch.autograd.Function):
    """The compiled mean SSIM of an image (H, W, 3) against a fixed target (CPU tensors,
    float32 or float64); the gradient flows to the image only."""

    @staticmethod
    def forward(ctx, img, target, window, sigma):
        nb = splat_kernels()
        x = img.detach().permute(2, 0, 1).contiguous()
        y = target.detach().to(img.dtype).permute(2, 0, 1).contiguous()
        g = ref.ssim_window(window, sigma, x).numpy()
        dmaps = np.empty((3, *x.shape), x.numpy().dtype)
        value = nb.ssim_forward(x.numpy(), y.numpy(), g, ref.SSIM_C1, ref.SSIM_C2, dmaps)
        ctx.save_for_backward(x, y)
        ctx.dmaps, ctx.g = dmaps, g
        return torch.tensor(value, dtype=img.dtype)

    @staticmethod
    def backward(ctx, grad):
        x, y = ctx.saved_tensors
        grad_x = torch.empty_like(x)
        splat_kernels().ssim_backward(x.numpy(), y.numpy(), ctx.g, ctx.dmaps, float(grad) / x.numel(), grad_x.numpy())
        return grad_x.permute(1, 2, 0), None, None, None


def ssim(
    img: Tensor, target: Tensor, backend: str = "auto", window: int = ref.SSIM_WINDOW, sigma: float = ref.SSIM_SIGMA
) -> Tensor:
    """Mean SSIM of two (H, W, 3) images in [0, 1], as
    :func:`~nerfkit.kernels.splat_reference.ssim_reference`: compiled on the CPU (``backend``
    as :func:`rasterize`) unless ``target`` needs a gradient."""
    if resolve_backend(backend, img.device) == "numba" and not target.requires_grad:
        return SSIMFunction.apply(img, target, window, sigma)
    return ref.ssim_reference(img, target, window, sigma)


def resolve_backend(backend: str, device: torch.device) -> str:
    """``numba`` or ``torch`` for a requested backend on a device."""
    if backend == "torch" or device.type != "cpu":
        return "torch"
    if splat_kernels() is None:
        if backend == "numba":
            from . import numba_refused

            raise numba_refused(splat=True)
        return "torch"
    return "numba"


@dataclass
class SplatRender:
    """One rendered view: ``rgb`` (H, W, 3), ``depth`` (H, W) alpha-weighted depth sum,
    ``alpha`` (H, W); ``means2d`` (n, 2), or (1, n, 2) from gsplat (its ``.grad`` drives
    densification) and ``radii`` (n,) int pixels (0: not visible)."""

    rgb: Tensor
    depth: Tensor
    alpha: Tensor
    means2d: Tensor | None
    radii: Tensor


def render_gaussians(
    means: Tensor,
    log_scales: Tensor,
    quats: Tensor,
    opacity_logits: Tensor,
    sh: Tensor,
    sh_degree: int,
    w2c: Tensor,
    K: Tensor,
    width: int,
    height: int,
    background: Tensor,
    near_plane: float,
    backend: str = "auto",
    track_means2d: bool = False,
    sh_rest: Tensor | None = None,
    sh_dir_grad: bool = False,
) -> SplatRender:
    """Render Gaussians (parameters as stored, see :mod:`splat_reference`) into one camera.

    ``background`` is (H, W, 3). With ``track_means2d`` the 2D means keep their gradient.
    ``sh`` (n, K, 3) every SH coefficient, or with ``sh_rest`` (n, K - 1, 3) the DC (n, 1, 3)
    alone (a model's two parameters, not concatenated for each view). On the compiled path,
    projection, opacity and colour are :class:`ProjectFunction` (unless the camera ``w2c``
    or ``K`` needs a gradient: a pose correction's, then the torch reference).
    ``sh_dir_grad``: the colour's view direction ``normalize(mean - camera)`` passes its
    gradient to the means (as INRIA's 3DGS and gsplat, which renders on CUDA here, always do);
    off, the direction is held fixed on the CPU paths.
    """
    numba = resolve_backend(backend, means.device) == "numba" and not uses_gsplat(means.device, backend)
    if numba and not any(isinstance(t, Tensor) and t.requires_grad for t in (w2c, K)):
        dc, rest = (sh, sh_rest) if sh_rest is not None else (sh[:, :1], sh[:, 1:])
        means2d, conics, colors, opacities, depths, radii, rects = ProjectFunction.apply(
            means,
            log_scales,
            quats,
            opacity_logits,
            dc,
            rest,
            sh_degree,
            w2c,
            K,
            width,
            height,
            near_plane,
            sh_dir_grad,
        )
        if track_means2d and means2d.requires_grad:
            means2d.retain_grad()
        rgb, depth, alpha = rasterize(
            means2d, conics, colors, opacities, depths, rects, background, width, height, backend
        )
        return SplatRender(rgb, depth, alpha, means2d, radii)
    if sh_rest is not None:
        sh = torch.cat([sh, sh_rest], 1)
    if uses_gsplat(means.device, backend):
        return _render_gsplat(
            means, log_scales, quats, opacity_logits, sh, sh_degree, w2c, K, width, height, background, near_plane
        )
    proj = ref.project_gaussians(means, ref.covariance_3d(log_scales, quats), w2c, K, width, height, near_plane)
    means2d = proj["means2d"]
    if track_means2d and means2d.requires_grad:
        means2d.retain_grad()
    cam = torch.linalg.inv(w2c.to(means))[:3, 3]
    # the colour's view direction passes its gradient to the means only with sh_dir_grad (as the
    # compiled kernel); INRIA's and gsplat's (CUDA) always do
    dirs = (means if sh_dir_grad else means.detach()) - cam
    dirs = dirs / dirs.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    colors = ref.sh_to_rgb(sh, dirs, sh_degree)
    rgb, depth, alpha = rasterize(
        means2d,
        proj["conics"],
        colors,
        torch.sigmoid(opacity_logits),
        proj["depths"],
        proj["rects"],
        background,
        width,
        height,
        backend,
    )
    return SplatRender(rgb, depth, alpha, means2d, proj["radii"])


def _gsplat():
    try:
        import gsplat

        return gsplat
    except ImportError:
        return None


def uses_gsplat(device: torch.device, backend: str) -> bool:
    """Whether gsplat renders on ``device``: CUDA, ``backend`` auto and gsplat installed. On
    CUDA without gsplat, warns (once per process, Python's default) that the torch reference
    renders, tile by tile: slowly."""
    if device.type != "cuda" or backend != "auto":
        return False
    if _gsplat() is None:
        import warnings

        warnings.warn(
            "gsplat is not installed: splats render on CUDA with nerfkit's torch reference, one 16x16 "
            "tile at a time (slow); pip install gsplat",
            RuntimeWarning,
            stacklevel=3,
        )
        return False
    return True


def _render_gsplat(
    means, log_scales, quats, opacity_logits, sh, sh_degree, w2c, K, width, height, background, near_plane
) -> SplatRender:  # pragma: no cover - needs CUDA
    from gsplat import rasterization

    colors, alphas, meta = rasterization(
        means,
        quats,
        torch.exp(log_scales),
        torch.sigmoid(opacity_logits),
        sh,
        w2c[None].to(means),
        K[None].to(means),
        width,
        height,
        near_plane=near_plane,
        sh_degree=sh_degree,
        render_mode="RGB+ED",
        packed=False,
    )  # (C, N, ...) per-Gaussian outputs: the packed default gives (nnz, ...)
    alpha = alphas[0, ..., 0]
    rgb = colors[0, ..., :3] + (1 - alpha).unsqueeze(-1) * background
    depth = colors[0, ..., 3] * alpha  # expected depth x alpha, as the CPU path returns
    means2d = meta["means2d"]  # (1, n, 2) pixels: its gradient drives densification as on the CPU
    if means2d.requires_grad:
        means2d.retain_grad()
    return SplatRender(rgb, depth, alpha, means2d, meta["radii"][0].reshape(len(means), -1).amax(-1))
