"""The splat rasterizer: compiled kernels against the torch reference (values and float64
gradients), and the reference against analytic facts and gradcheck."""

from __future__ import annotations

import math
import subprocess
import sys

import pytest
import torch

from conftest import fibonacci_sphere
from nerfkit.kernels import splat_kernels
from nerfkit.kernels import splat_reference as ref
from nerfkit.kernels.reference import SH_C1, SH_C2
from nerfkit.kernels.splat_ops import rasterize, render_gaussians, ssim

needs_numba = pytest.mark.skipif(splat_kernels() is None, reason="numba not available")


@needs_numba
def test_the_compiled_kernels_and_the_splat_files_need_no_torch():
    # they share the reference's constants (nerfkit.splat_constants) without importing torch
    code = "import sys, nerfkit.splat_files, nerfkit.kernels.splat_numba as nb; print(nb.SH_C0, 'torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == [repr(ref.SH_C0), "False"]


STALE_CACHE_PROBE = """
import sys
import numpy as np
import nerfkit.splat_constants as constants
constants.DILATION = float(sys.argv[1])  # as if the file said so
from nerfkit.kernels import splat_numba as nb
# sigma 0.1 at depth 2, f = 100: a 25 px^2 screen variance, plus the dilation
params = (np.array([[0.0, 0.0, 2.0]]), np.full((1, 3), np.log(0.1)), np.array([[1.0, 0, 0, 0]]), np.zeros(1),
          np.zeros((1, 1, 3)), np.zeros((1, 15, 3)))
view, cam, intr = np.eye(4)[:3].copy(), np.zeros(3), np.array([100.0, 100.0, 32.0, 32.0])
outs = (np.zeros((1, 2)), np.zeros((1, 3)), np.zeros((1, 3)), np.zeros(1), np.zeros(1))
nb.project_forward(*params, 0, view, cam, intr, 64, 64, 0.01, *outs, np.zeros(1, np.int32), np.zeros((1, 4), np.int32))
print(1 / outs[1][0, 0], sum(nb.project_forward.stats.cache_hits.values()))
"""


@needs_numba
def test_a_changed_constant_is_not_served_stale_from_numbas_cache(tmp_path):
    """numba keys its on-disk cache on the kernel's own file, and the kernels bake in the values
    of nerfkit.splat_constants: a process with another DILATION must compile anew, not load
    the kernel of the old one (each run in its own process, on a cache folder of its own)."""
    import os

    def run(dilation: float) -> tuple[float, int]:  # (the screen variance, cache hits)
        env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}
        cmd = [sys.executable, "-c", STALE_CACHE_PROBE, str(dilation)]
        out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True).stdout.split()
        return float(out[0]), int(out[1])

    assert run(0.3) == (pytest.approx(25.3), 0)  # compiled
    assert run(0.3) == (pytest.approx(25.3), 1)  # loaded from the cache
    assert run(0.5) == (pytest.approx(25.5), 0)  # compiled anew: not the cached kernel's 25.3


def random_gaussians(n: int, seed: int = 0, dtype=torch.float64, spread: float = 0.5, log_scale: float = -2.0):
    g = torch.Generator().manual_seed(seed)
    means = torch.randn(n, 3, generator=g, dtype=dtype) * spread
    log_scales = torch.randn(n, 3, generator=g, dtype=dtype) * 0.3 + log_scale
    quats = torch.randn(n, 4, generator=g, dtype=dtype)
    logits = torch.randn(n, generator=g, dtype=dtype) * 1.5
    sh = torch.randn(n, 16, 3, generator=g, dtype=dtype) * 0.3
    return means, log_scales, quats, logits, sh


def camera(W: int, H: int, dtype=torch.float64, z: float = 3.0):
    w2c = torch.eye(4, dtype=dtype)
    w2c[2, 3] = z
    K = torch.tensor([[1.0 * W, 0, W / 2], [0, 1.0 * W, H / 2], [0, 0, 1]], dtype=dtype)
    return w2c, K


def projected(n: int, W: int, H: int, seed: int = 0, dtype=torch.float64, **kw):
    means, log_scales, quats, logits, sh = random_gaussians(n, seed, dtype, **kw)
    w2c, K = camera(W, H, dtype)
    proj = ref.project_gaussians(means, ref.covariance_3d(log_scales, quats), w2c, K, W, H, 0.01)
    g = torch.Generator().manual_seed(seed + 1)
    colors = torch.rand(n, 3, generator=g, dtype=dtype)
    bg = torch.rand(H, W, 3, generator=g, dtype=dtype)
    leaves = [proj["means2d"].detach(), proj["conics"].detach(), colors, torch.sigmoid(logits)]
    return leaves, proj["depths"].detach(), proj["rects"], bg


def test_sh_dc_only_gives_its_colour_from_every_direction():
    rgb = torch.tensor([[0.2, 0.7, 1.0]], dtype=torch.float64)
    sh = torch.zeros(1, 16, 3, dtype=torch.float64)
    sh[:, 0] = ref.rgb_to_sh_dc(rgb)
    dirs = torch.nn.functional.normalize(torch.randn(50, 3, dtype=torch.float64), dim=-1)
    out = ref.sh_to_rgb(sh.expand(50, 16, 3), dirs, 3)
    torch.testing.assert_close(out, rgb.expand(50, 3))


def test_sh_degree_one_matches_inria_signs():
    # INRIA: -C1 y sh1 + C1 z sh2 - C1 x sh3
    sh = torch.zeros(3, 16, 3, dtype=torch.float64)
    sh[:, 1:4, 0] = torch.eye(3, dtype=torch.float64)
    d = torch.tensor([[0.6, 0.0, 0.8]] * 3, dtype=torch.float64)
    out = ref.sh_to_rgb(sh, d, 1)[:, 0] - 0.5
    torch.testing.assert_close(out, torch.tensor([0.0, SH_C1 * 0.8, -SH_C1 * 0.6], dtype=torch.float64))


def sh_to_rgb_term_by_term(coeffs, dirs, degree):
    """INRIA's formula written out, a term per coefficient (what ``sh_to_rgb`` must equal)."""
    x, y, z = dirs[:, 0:1], dirs[:, 1:2], dirs[:, 2:3]
    c1, c2, c3 = SH_C1, SH_C2, ref.SH_C3
    out = ref.SH_C0 * coeffs[:, 0]
    if degree > 0:
        out = out - c1 * y * coeffs[:, 1] + c1 * z * coeffs[:, 2] - c1 * x * coeffs[:, 3]
    if degree > 1:
        xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
        out = out + c2[0] * xy * coeffs[:, 4] + c2[1] * yz * coeffs[:, 5] + c2[2] * (2 * zz - xx - yy) * coeffs[:, 6]
        out = out + c2[3] * xz * coeffs[:, 7] + c2[4] * (xx - yy) * coeffs[:, 8]
    if degree > 2:
        out = out + c3[0] * y * (3 * xx - yy) * coeffs[:, 9] + c3[1] * xy * z * coeffs[:, 10]
        out = out + c3[2] * y * (4 * zz - xx - yy) * coeffs[:, 11]
        out = out + c3[3] * z * (2 * zz - 3 * xx - 3 * yy) * coeffs[:, 12]
        out = out + c3[4] * x * (4 * zz - xx - yy) * coeffs[:, 13] + c3[5] * z * (xx - yy) * coeffs[:, 14]
        out = out + c3[6] * x * (xx - 3 * yy) * coeffs[:, 15]
    return torch.clamp_min(out + 0.5, 0.0)


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_sh_colour_equals_the_formula_term_by_term_with_its_gradients(degree):
    g = torch.Generator().manual_seed(degree)
    coeffs = (torch.randn(40, 16, 3, generator=g, dtype=torch.float64) * 1.5).requires_grad_()
    dirs = torch.nn.functional.normalize(torch.randn(40, 3, generator=g, dtype=torch.float64), dim=-1)
    dirs.requires_grad_()
    w = torch.randn(40, 3, generator=g, dtype=torch.float64)
    outs, grads = [], []
    for fn in (ref.sh_to_rgb, sh_to_rgb_term_by_term):
        out = fn(coeffs, dirs, degree)
        outs.append(out)
        grads.append(torch.autograd.grad((out * w).sum(), (coeffs, dirs), allow_unused=True, materialize_grads=True))
    assert bool((outs[0] > 0).any()) and bool((outs[0] == 0).any())  # (both sides of the clamp)
    torch.testing.assert_close(outs[0], outs[1])
    for a, b in zip(*grads):
        torch.testing.assert_close(a, b)
    assert bool((grads[0][0][:, ref.sh_coeffs(degree) :] == 0).all())  # unused coefficients
    assert bool((grads[0][0][:, : ref.sh_coeffs(degree)] != 0).any())


def test_sh_basis_up_to_degree_three_is_orthonormal_on_the_sphere():
    # the real SH are orthonormal: the integral of Y_i Y_j over the sphere is the identity.
    # This pins every normalisation constant (SH_C0 .. SH_C3) independently of the code's
    # own numbers; the term-by-term test above only checks the formula's shape.
    d = fibonacci_sphere(20000)
    Y = ref.sh_basis(d, 3)
    assert Y.shape == (20000, 16)
    gram = 4 * math.pi * (Y.T @ Y) / len(d)
    torch.testing.assert_close(gram, torch.eye(16, dtype=torch.float64), atol=1e-4, rtol=0)


def test_covariance_is_rotated_diagonal():
    log_scales = torch.log(torch.tensor([[1.0, 2.0, 3.0]], dtype=torch.float64))
    half = math.sqrt(0.5)  # 90 degrees about z: x -> y
    quats = torch.tensor([[half, 0.0, 0.0, half]], dtype=torch.float64)
    cov = ref.covariance_3d(log_scales, quats)[0]
    torch.testing.assert_close(cov, torch.diag(torch.tensor([4.0, 1.0, 9.0], dtype=torch.float64)))


def test_projection_of_an_isotropic_gaussian_at_the_centre():
    # sigma 0.1 at depth 2 with f = 100: a 5 px sigma on screen, plus the 0.3 px^2 dilation
    means = torch.tensor([[0.0, 0.0, 2.0]], dtype=torch.float64)
    cov = torch.eye(3, dtype=torch.float64).unsqueeze(0) * 0.01
    K = torch.tensor([[100.0, 0, 32], [0, 100.0, 32], [0, 0, 1]], dtype=torch.float64)
    p = ref.project_gaussians(means, cov, torch.eye(4, dtype=torch.float64), K, 64, 64, 0.01)
    torch.testing.assert_close(p["means2d"][0], torch.tensor([32.0, 32.0], dtype=torch.float64))
    var = 25.3  # INRIA's low-pass filter adds 0.3 px^2, written out (not read from the code)
    torch.testing.assert_close(p["conics"][0], torch.tensor([1 / var, 0.0, 1 / var], dtype=torch.float64))
    assert int(p["radii"][0]) == 16  # ceil(3 * sqrt(25.3)) = ceil(15.09)
    assert p["rects"][0].tolist() == [0, 3, 0, 3]  # 16 px tiles touched by x, y in 31.5 +- 16 px


def test_gaussians_behind_the_camera_are_culled():
    means = torch.tensor([[0.0, 0.0, -2.0], [0.0, 0.0, 0.001]], dtype=torch.float64)
    cov = torch.eye(3, dtype=torch.float64).expand(2, 3, 3) * 0.01
    K = torch.tensor([[100.0, 0, 32], [0, 100.0, 32], [0, 0, 1]], dtype=torch.float64)
    p = ref.project_gaussians(means, cov, torch.eye(4, dtype=torch.float64), K, 64, 64, 0.01)
    assert p["radii"].tolist() == [0, 0]


def test_one_opaque_gaussian_composites_analytically():
    # one round Gaussian at a pixel centre: alpha = opacity there, the rest is background
    W = H = 16
    means2d = torch.tensor([[8.5, 8.5]], dtype=torch.float64)
    conics = torch.tensor([[0.5, 0.0, 0.5]], dtype=torch.float64)
    colors = torch.tensor([[1.0, 0.0, 0.0]], dtype=torch.float64)
    rects = torch.tensor([[0, 1, 0, 1]], dtype=torch.int32)
    bg = torch.zeros(H, W, 3, dtype=torch.float64)
    bg[..., 2] = 1.0
    rgb, depth, alpha = ref.rasterize_reference(
        means2d,
        conics,
        colors,
        torch.tensor([0.6], dtype=torch.float64),
        torch.tensor([2.0], dtype=torch.float64),
        rects,
        bg,
        W,
        H,
    )
    torch.testing.assert_close(rgb[8, 8], torch.tensor([0.6, 0.0, 0.4], dtype=torch.float64))
    torch.testing.assert_close(depth[8, 8], torch.tensor(1.2, dtype=torch.float64))
    a = 0.6 * math.exp(-0.5 * 0.5 * 1)  # one pixel to the right
    torch.testing.assert_close(alpha[8, 9], torch.tensor(a, dtype=torch.float64))
    assert float(alpha[0, 0]) == 0.0  # far away: alpha < 1/255 is skipped


def test_compositing_stops_before_transmittance_falls_below_the_threshold():
    # two 0.99-opaque Gaussians leave T = 1e-4 * ... : the second would bring T below 1e-4
    W = H = 16
    means2d = torch.tensor([[8.5, 8.5]] * 3, dtype=torch.float64)
    conics = torch.tensor([[0.5, 0.0, 0.5]] * 3, dtype=torch.float64)
    colors = torch.eye(3, dtype=torch.float64)
    op = torch.tensor([0.99, 0.99, 0.99], dtype=torch.float64)
    rects = torch.tensor([[0, 1, 0, 1]] * 3, dtype=torch.int32)
    depths = torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64)
    bg = torch.zeros(H, W, 3, dtype=torch.float64)
    rgb, _, alpha = ref.rasterize_reference(means2d, conics, colors, op, depths, rects, bg, W, H)
    # 1 - 0.01 * 0.01 = 0.9999: T = 1e-4 is not below 1e-4, so the second counts; the third does not
    torch.testing.assert_close(rgb[8, 8], torch.tensor([0.99, 0.0099, 0.0], dtype=torch.float64))
    if splat_kernels() is not None:
        got = rasterize(means2d, conics, colors, op, depths, rects, bg, W, H, "numba")[0]
        torch.testing.assert_close(got[8, 8], rgb[8, 8])


def test_reference_gradients_pass_gradcheck():
    W, H = 20, 18
    leaves, depths, rects, bg = projected(8, W, H, seed=3)
    leaves = [t.clone().requires_grad_() for t in leaves]

    def f(m, c, col, op):
        return ref.rasterize_reference(m, c, col, op, depths, rects, bg, W, H)[0]

    assert torch.autograd.gradcheck(f, leaves, eps=1e-6, atol=1e-5, fast_mode=True)


def test_projection_and_sh_gradients_pass_gradcheck():
    means, log_scales, quats, logits, sh = random_gaussians(4, seed=5)
    w2c, K = camera(24, 20)
    d = torch.nn.functional.normalize(torch.randn(4, 3, dtype=torch.float64), dim=-1)

    def f(m, s, q, coeffs):
        p = ref.project_gaussians(m, ref.covariance_3d(s, q), w2c, K, 24, 20, 0.01)
        return p["means2d"], p["conics"], ref.sh_to_rgb(coeffs, d, 3)

    args = [t.clone().requires_grad_() for t in (means, log_scales, quats, sh + 0.2)]
    assert torch.autograd.gradcheck(f, args, eps=1e-6, atol=1e-5)


@needs_numba
@pytest.mark.parametrize("seed,n,W,H", [(0, 60, 40, 30), (1, 300, 53, 37), (2, 5, 16, 16)])
def test_numba_matches_reference_values_and_float64_gradients(seed, n, W, H):
    leaves, depths, rects, bg = projected(n, W, H, seed=seed)
    g = torch.randn(H, W, 3, generator=torch.Generator().manual_seed(9), dtype=torch.float64)
    results = {}
    for backend in ("torch", "numba"):
        args = [t.clone().requires_grad_() for t in leaves]
        b = bg.clone().requires_grad_()
        rgb, depth, alpha = rasterize(*args, depths, rects, b, W, H, backend)
        grads = torch.autograd.grad((rgb * g).sum(), [*args, b])
        results[backend] = (rgb, depth, alpha, grads)
    ref_out, nb_out = results["torch"], results["numba"]
    for a, b in zip(ref_out[:3], nb_out[:3]):
        torch.testing.assert_close(b, a, rtol=1e-10, atol=1e-12)
    for a, b in zip(ref_out[3], nb_out[3]):
        torch.testing.assert_close(b, a, rtol=1e-9, atol=1e-10)
    assert any(float(t.abs().max()) > 0 for t in ref_out[3])


@needs_numba
def test_numba_float32_matches_reference_on_a_dense_crowd():
    # many overlapping, large, opaque Gaussians: early termination and the 0.99 clamp happen
    W, H = 48, 40
    leaves, depths, rects, bg = projected(400, W, H, seed=4, dtype=torch.float32, log_scale=-1.5)
    leaves[3] = leaves[3] * 0 + 0.995
    rgb_ref, _, a_ref = rasterize(*leaves, depths, rects, bg, W, H, "torch")
    rgb_nb, _, a_nb = rasterize(*leaves, depths, rects, bg, W, H, "numba")
    assert float((a_ref > 0.999).float().mean()) > 0.3  # two 0.99 layers: many pixels stop early
    torch.testing.assert_close(rgb_nb, rgb_ref, rtol=1e-4, atol=1e-5)


@needs_numba
@pytest.mark.parametrize("seed,n,log_scale", [(4, 400, -1.5), (6, 600, -1.8)])
def test_numba_float32_gradients_are_near_a_float64_run(seed, n, log_scale):
    # the float32 kernels compute per pixel, and sum each Gaussian's footprint, in float32:
    # their gradients stay within float32 rounding of the same kernels' float64 ones (~5e-7 here)
    W, H = 48, 40
    leaves, depths, rects, bg = projected(n, W, H, seed=seed, log_scale=log_scale)
    g = torch.randn(H, W, 3, generator=torch.Generator().manual_seed(9), dtype=torch.float64)
    grads = {}
    for dt in (torch.float64, torch.float32):
        args = [t.to(dt).requires_grad_() for t in leaves]
        rgb = rasterize(*args, depths.to(dt), rects, bg.to(dt), W, H, "numba")[0]
        grads[dt] = torch.autograd.grad((rgb * g.to(dt)).sum(), args)
    for a, b in zip(grads[torch.float32], grads[torch.float64]):
        assert a.dtype == torch.float32 and float(b.norm()) > 0
        assert float((a.double() - b).norm() / b.norm()) < 1e-5


@needs_numba
@pytest.mark.parametrize("sh_dir_grad", [False, True])
def test_full_pipeline_gradients_agree_between_backends(sh_dir_grad):
    W, H = 32, 24
    params = random_gaussians(40, seed=7)
    w2c, K = camera(W, H)
    bg = torch.full((H, W, 3), 0.25, dtype=torch.float64)
    grads = {}
    for backend in ("torch", "numba"):
        ps = [p.clone().requires_grad_() for p in params]
        out = render_gaussians(*ps, 3, w2c, K, W, H, bg, 0.01, backend, sh_dir_grad=sh_dir_grad)
        grads[backend] = torch.autograd.grad(out.rgb.square().sum(), ps)
    for a, b in zip(grads["torch"], grads["numba"]):
        torch.testing.assert_close(b, a, rtol=1e-9, atol=1e-10)


@needs_numba
@pytest.mark.parametrize("H,W", [(23, 31), (7, 40), (16, 5)])  # (sides shorter than the 11-pixel window too)
def test_compiled_ssim_matches_reference_value_and_float64_gradient(H, W):
    g = torch.Generator().manual_seed(H * W)
    target = torch.rand(H, W, 3, generator=g, dtype=torch.float64)
    img = (0.6 * target + 0.4 * torch.rand(H, W, 3, generator=g, dtype=torch.float64)).requires_grad_()
    out = {}
    for backend in ("torch", "numba"):
        value = ssim(img, target, backend)
        out[backend] = (value.detach(), *torch.autograd.grad(3.0 * value, img))
    torch.testing.assert_close(out["numba"][0], out["torch"][0], rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(out["numba"][1], out["torch"][1], rtol=1e-9, atol=1e-12)
    assert 0.2 < float(out["torch"][0]) < 0.99 and float(out["torch"][1].abs().max()) > 0


@needs_numba
def test_compiled_ssim_float32_matches_the_reference():
    g = torch.Generator().manual_seed(3)
    img = torch.rand(40, 50, 3, generator=g).requires_grad_()
    target = torch.rand(40, 50, 3, generator=g)
    (g_ref,) = torch.autograd.grad(ref.ssim_reference(img, target), img)
    value = ssim(img, target, "numba")
    (g_nb,) = torch.autograd.grad(value, img)
    assert value.dtype == torch.float32
    torch.testing.assert_close(value, ref.ssim_reference(img, target), rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(g_nb, g_ref, rtol=1e-3, atol=1e-7)


@pytest.mark.parametrize("backend", ["torch", pytest.param("numba", marks=needs_numba)])
def test_ssim_is_one_for_equal_images_and_lower_for_noise(backend):
    g = torch.Generator().manual_seed(0)
    img = torch.rand(24, 20, 3, generator=g)
    assert float(ssim(img, img, backend)) == pytest.approx(1.0, abs=1e-6)
    assert float(ssim(img, (img + 0.3 * torch.randn(24, 20, 3, generator=g)).clamp(0, 1), backend)) < 0.8


def test_gsplat_renders_on_cuda_only_when_installed_and_its_absence_is_said(monkeypatch):
    from nerfkit.kernels import splat_ops

    monkeypatch.setattr(splat_ops, "_gsplat", lambda: object())
    assert splat_ops.uses_gsplat(torch.device("cuda"), "auto")
    assert not splat_ops.uses_gsplat(torch.device("cuda"), "torch")  # asked for the reference
    assert not splat_ops.uses_gsplat(torch.device("cpu"), "auto")
    monkeypatch.setattr(splat_ops, "_gsplat", lambda: None)
    with pytest.warns(RuntimeWarning, match="gsplat is not installed.*pip install gsplat"):
        assert not splat_ops.uses_gsplat(torch.device("cuda"), "auto")


@needs_numba
def test_numba_forward_is_the_same_on_any_number_of_lanes():
    import numpy as np

    nb = splat_kernels()
    W, H = 70, 45
    leaves, depths, rects, bg = projected(200, W, H, seed=5, dtype=torch.float32, log_scale=-1.8)
    tw, th = -(-W // ref.TILE), -(-H // ref.TILE)
    offsets, ids = nb.bin_tiles(ref.depth_order(depths, rects).numpy(), rects.numpy(), tw, th)
    outs = []
    for lanes in (1, 2, 3):
        bufs = [np.zeros((H, W, 3), np.float32), *(np.zeros((H, W), np.float32) for _ in range(3))]
        bufs.append(np.zeros((H, W), np.int64))
        arrays = [t.contiguous().numpy() for t in (*leaves, depths, bg)]
        nb.rasterize_forward(offsets, ids, *arrays, W, H, tw, *bufs, lanes)
        outs.append(bufs)
    assert float(outs[0][2].max()) > 0.5  # (something was drawn)
    for other in outs[1:]:
        for a, b in zip(outs[0], other):
            assert np.array_equal(a, b)


def reference_projection(params, degree, w2c, K, W, H, near=0.01, dir_grad=False):
    """The torch reference's projection, opacity and SH colour (as render_gaussians wires them)."""
    means, log_scales, quats, logits, sh = params
    p = ref.project_gaussians(means, ref.covariance_3d(log_scales, quats), w2c, K, W, H, near)
    cam = torch.linalg.inv(w2c.to(means))[:3, 3]
    dirs = (means if dir_grad else means.detach()) - cam
    dirs = dirs / dirs.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    colors = ref.sh_to_rgb(sh, dirs, degree)
    return p["means2d"], p["conics"], colors, torch.sigmoid(logits), p["depths"], p["radii"], p["rects"]


def compiled_projection(params, degree, w2c, K, W, H, near=0.01, dir_grad=False):
    from nerfkit.kernels.splat_ops import ProjectFunction

    means, log_scales, quats, logits, sh = params
    return ProjectFunction.apply(
        means, log_scales, quats, logits, sh[:, :1], sh[:, 1:], degree, w2c, K, W, H, near, dir_grad
    )


def crowd_with_edge_cases(n: int, seed: int, dtype=torch.float64):
    """Gaussians in front of the camera and some behind it, beyond the near plane, far outside
    the field of view (the clamp of J), and some with colours clamped at zero."""
    means, log_scales, quats, logits, sh = random_gaussians(n, seed, dtype, spread=1.2, log_scale=-1.5)
    means[:4, 2] = -3.5  # behind the camera (z = 3 + mz)
    means[4:6, 2] = -2.995  # nearer than the near plane
    means[6:10, 0] = torch.tensor([9.0, -9.0, 12.0, -7.0], dtype=dtype)  # outside 1.3 x the half field of view
    means[10:12, 1] = torch.tensor([8.0, -8.0], dtype=dtype)
    sh[12:16, 0] = -3.0  # SH + 0.5 < 0: the colour clamps
    return means, log_scales, quats, logits, sh


@needs_numba
@pytest.mark.parametrize("dir_grad", [False, True])
@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_compiled_projection_matches_the_reference_values_and_float64_gradients(degree, dir_grad):
    W, H = 40, 30
    params = crowd_with_edge_cases(200, seed=degree)
    w2c, K = camera(W, H)
    results = {}
    for name, fn in (("torch", reference_projection), ("numba", compiled_projection)):
        leaves = [p.clone().requires_grad_() for p in params]
        outs = fn(leaves, degree, w2c, K, W, H, dir_grad=dir_grad)
        g = torch.Generator().manual_seed(11)
        loss = sum((o * torch.randn(o.shape, generator=g, dtype=o.dtype)).sum() for o in outs[:5])
        results[name] = (outs, torch.autograd.grad(loss, leaves))
    (ref_out, ref_grads), (nb_out, nb_grads) = results["torch"], results["numba"]
    radii = ref_out[5]
    assert 0 < int((radii > 0).sum()) < len(radii)  # some visible, some culled
    assert torch.equal(nb_out[5], radii) and torch.equal(nb_out[6], ref_out[6])
    for a, b in zip(ref_out[:5], nb_out[:5]):
        torch.testing.assert_close(b.detach(), a.detach(), rtol=1e-10, atol=1e-12)
    for a, b in zip(ref_grads, nb_grads):
        torch.testing.assert_close(b, a, rtol=1e-9, atol=1e-10)
        assert float(a.abs().max()) > 0
    # the coefficients past the degree get a zero gradient, as autograd gives them
    assert int(torch.count_nonzero(nb_grads[4][:, (degree + 1) ** 2 :])) == 0
    if dir_grad:  # the direction's term reaches the means from degree 1 (the DC is constant)
        leaves = [p.clone().requires_grad_() for p in params]
        outs = compiled_projection(leaves, degree, w2c, K, W, H)
        g = torch.Generator().manual_seed(11)
        loss = sum((o * torch.randn(o.shape, generator=g, dtype=o.dtype)).sum() for o in outs[:5])
        off = torch.autograd.grad(loss, leaves[0])[0]
        assert torch.equal(off, nb_grads[0]) == (degree == 0)


@pytest.mark.parametrize("backend", ["torch", pytest.param("numba", marks=needs_numba)])
def test_projection_beyond_the_field_of_view_uses_the_jacobian_at_the_clamped_x(backend):
    # sigma 0.2 at (1, 0, 2), f = 100, 64 x 64: x/z = 0.5 lies beyond INRIA's limit
    # 1.3 * tan(half fov) = 1.3 * 32 / 100 = 0.416, so J is evaluated at x = 0.416 * 2 = 0.832:
    # J = [[f/z, 0, -f x/z^2], [0, f/z, 0]] = [[50, 0, -20.8], [0, 50, 0]],
    # cov2d = 0.04 J J^T + 0.3 I = diag(0.04 * (2500 + 20.8^2) + 0.3, 0.04 * 2500 + 0.3).
    # (Unclamped, J[0, 2] would be -25 and the x variance 125.3.)
    W = H = 64
    K = torch.tensor([[100.0, 0, 32], [0, 100.0, 32], [0, 0, 1]], dtype=torch.float64)
    w2c = torch.eye(4, dtype=torch.float64)
    params = (
        torch.tensor([[1.0, 0.0, 2.0]], dtype=torch.float64),
        torch.full((1, 3), math.log(0.2), dtype=torch.float64),
        torch.tensor([[1.0, 0.0, 0.0, 0.0]], dtype=torch.float64),
        torch.zeros(1, dtype=torch.float64),
        torch.zeros(1, 16, 3, dtype=torch.float64),
    )
    fn = reference_projection if backend == "torch" else compiled_projection
    means2d, conics, _, _, depths, radii, rects = fn(params, 0, w2c, K, W, H)
    var_x, var_y = 0.04 * (2500 + 20.8**2) + 0.3, 0.04 * 2500 + 0.3  # 117.6056, 100.3
    torch.testing.assert_close(means2d[0], torch.tensor([82.0, 32.0], dtype=torch.float64))  # the mean is not clamped
    torch.testing.assert_close(conics[0], torch.tensor([1 / var_x, 0.0, 1 / var_y], dtype=torch.float64))
    assert float(depths[0]) == 2.0
    assert int(radii[0]) == 33  # ceil(3 * sqrt(117.6056)) = ceil(32.53)
    assert rects[0].tolist() == [3, 4, 0, 4]  # x in 81.5 +- 33 px reaches the last 16 px tile column


@needs_numba
def test_compiled_projection_float32_is_near_the_float64_reference():
    W, H = 64, 48
    params = crowd_with_edge_cases(300, seed=7)
    w2c, K = camera(W, H)
    ref_out = reference_projection(params, 3, w2c, K, W, H)
    f32 = [p.float() for p in params]
    nb_out = compiled_projection(f32, 3, w2c.float(), K.float(), W, H)
    assert all(o.dtype == torch.float32 for o in nb_out[:5])
    visible = ref_out[5] > 0
    for a, b in zip(ref_out[:5], nb_out[:5]):
        torch.testing.assert_close(b[visible].double(), a[visible], rtol=1e-5, atol=1e-5)
    assert float((nb_out[5] != ref_out[5]).float().mean()) < 0.02  # (a radius at a rounding edge may differ)


@needs_numba
def test_render_gaussians_takes_the_dc_and_the_rest_apart_and_a_posed_camera_on_the_reference():
    W, H = 32, 24
    params = random_gaussians(40, seed=8)
    w2c, K = camera(W, H)
    bg = torch.full((H, W, 3), 0.25, dtype=torch.float64)
    means, log_scales, quats, logits, sh = params
    whole = render_gaussians(*params, 3, w2c, K, W, H, bg, 0.01, "numba")
    split = render_gaussians(
        means, log_scales, quats, logits, sh[:, :1], 3, w2c, K, W, H, bg, 0.01, "numba", sh_rest=sh[:, 1:]
    )
    assert torch.equal(whole.rgb, split.rgb)
    # a camera that needs a gradient (a pose correction's) renders on the torch projection
    cam = w2c.clone().requires_grad_()
    posed = render_gaussians(*params, 3, cam, K, W, H, bg, 0.01, "numba")
    torch.testing.assert_close(posed.rgb.detach(), whole.rgb, rtol=1e-10, atol=1e-12)
    (g,) = torch.autograd.grad(posed.rgb.square().sum(), cam)
    assert float(g[:3].abs().max()) > 0


@needs_numba
def test_all_finite_finds_any_nan_or_infinity():
    import numpy as np

    nb = splat_kernels()
    for dt in (np.float32, np.float64):
        x = np.linspace(-1e30, 1e30, 1001).astype(dt)
        assert nb.all_finite(x) and nb.all_finite(x[:0])
        for bad in (np.nan, np.inf, -np.inf):
            for at in (0, 517, 1000):
                y = x.copy()
                y[at] = bad
                assert not nb.all_finite(y)


@needs_numba
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_compiled_depth_order_is_the_reference_stable_sort(dtype):
    nb = splat_kernels()
    g = torch.Generator().manual_seed(2)
    n = 5000
    depths = (torch.rand(n, generator=g, dtype=torch.float64) * 50 - 5).to(dtype)
    depths[::7] = depths[3]  # ties: kept in index order
    depths[1::97] = torch.tensor([-0.0, 0.0, 1e-30, -1e-30, 3e38 if dtype == torch.float32 else 1e300], dtype=dtype)[
        torch.arange(len(depths[1::97])) % 5
    ]
    rects = torch.zeros(n, 4, dtype=torch.int32)
    rects[:, 1] = 1 + (torch.rand(n, generator=g) < 0.8).int()  # x1 > x0 = 0 (one or two tiles wide)
    rects[:, 3] = (torch.rand(n, generator=g) < 0.9).int()  # y1 > y0 = 0 for most: those are visible
    want = ref.depth_order(depths, rects)
    got = nb.depth_order(depths.numpy(), rects.numpy())
    assert 0 < len(want) < n
    assert torch.equal(torch.from_numpy(got), want)
    assert len(nb.depth_order(depths[:0].numpy(), rects[:0].numpy())) == 0
