"""The course API: cameras, rays, sampling, volume rendering, encoding."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from nerfkit import pixel_to_camera, pixel_to_ray, positional_encoding, sample_along_rays, transform, volrend
from nerfkit.cameras import image_rays, look_at, opengl_to_opencv, orbit_path, rotation_angles_deg
from nerfkit.render.sampling import intervals_from_t, sample_pdf, stratified_t
from nerfkit.render.volrend import composite, exclusive_cumsum, regular_ray_indices, render_weights


def random_c2w(gen: torch.Generator, n: int) -> torch.Tensor:
    q, _ = torch.linalg.qr(torch.randn(n, 3, 3, generator=gen, dtype=torch.float64))
    q = q * torch.sign(torch.linalg.det(q))[:, None, None]  # proper rotations
    c2w = torch.eye(4, dtype=torch.float64).repeat(n, 1, 1)
    c2w[:, :3, :3] = q
    c2w[:, :3, 3] = torch.randn(n, 3, generator=gen, dtype=torch.float64) * 3
    return c2w


def rows(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(n_rays, n_samples[, 3]) -> the packed values and their ray indices."""
    n, s = x.shape[:2]
    return x.reshape((n * s,) + tuple(x.shape[2:])), regular_ray_indices(n, s)


def weights_of(sigmas: torch.Tensor, deltas) -> tuple[torch.Tensor, ...]:
    """render_weights on (n_rays, n_samples) densities, results back in that shape."""
    flat, rays = rows(sigmas)
    return tuple(x.view(sigmas.shape) for x in render_weights(flat, deltas, rays))


def test_volrend_matches_course_reference():
    torch.manual_seed(42)
    sigmas = torch.rand((10, 64, 1))
    rgbs = torch.rand((10, 64, 3))
    step_size = (6.0 - 2.0) / 64
    rendered = volrend(sigmas, rgbs, step_size)
    expected = torch.tensor(
        [
            [0.5006, 0.3728, 0.4728],
            [0.4322, 0.3559, 0.4134],
            [0.4027, 0.4394, 0.4610],
            [0.4514, 0.3829, 0.4196],
            [0.4002, 0.4599, 0.4103],
            [0.4471, 0.4044, 0.4069],
            [0.4285, 0.4072, 0.3777],
            [0.4152, 0.4190, 0.4361],
            [0.4051, 0.3651, 0.3969],
            [0.3253, 0.3587, 0.4215],
        ]
    )
    assert torch.allclose(rendered, expected, rtol=1e-4, atol=1e-4)


def test_huge_density_takes_all_weight():
    sigmas = torch.zeros(3, 16)
    sigmas[:, 5] = 1e10
    rgbs = torch.rand(3, 16, 3)
    weights, trans, _ = weights_of(sigmas, 0.1)
    assert torch.allclose(weights[:, 5], torch.ones(3))
    assert torch.all(weights[:, 6:] == 0)
    flat_rgbs, rays = rows(rgbs)
    rgb, _, acc = composite(weights.reshape(-1), flat_rgbs, rays, 3, background=torch.tensor([0.2, 0.3, 0.4]))
    assert torch.allclose(rgb, rgbs[:, 5])
    assert torch.allclose(acc, torch.ones(3))


def test_zero_density_renders_background():
    sigmas = torch.zeros(4, 8)
    rgbs = torch.rand(4, 8, 3)
    bg = torch.tensor([0.1, 0.7, 0.9])
    rgb = volrend(sigmas, rgbs, 0.5, background=bg)
    assert torch.allclose(rgb, bg.expand(4, 3))


@pytest.mark.parametrize("scale", [1e-40, 1e-10, 1.0, 1e3, 1e10])
def test_volrend_finite_values_and_gradients_across_density_scales(scale):
    sigmas = (torch.rand(5, 32, dtype=torch.float64) * scale).requires_grad_()
    rgbs = torch.rand(5, 32, 3, dtype=torch.float64, requires_grad=True)
    flat, rays = rows(sigmas)
    weights, _, _ = render_weights(flat, 0.05, rays)
    rgb, _, acc = composite(weights, rows(rgbs)[0], rays, 5)
    (rgb.sum() + acc.sum()).backward()
    assert torch.isfinite(rgb).all() and torch.isfinite(sigmas.grad).all() and torch.isfinite(rgbs.grad).all()
    assert torch.all(acc <= 1 + 1e-9) and torch.all(weights >= 0)


def test_weights_match_closed_form_for_constant_density():
    # constant sigma: T_i = exp(-sigma * delta * i), alpha = 1 - exp(-sigma * delta)
    sigma, delta, n = 0.7, 0.25, 10
    weights, trans, alphas = weights_of(torch.full((1, n), sigma, dtype=torch.float64), torch.tensor(delta))
    i = torch.arange(n, dtype=torch.float64)
    expected = torch.exp(-sigma * delta * i) * (1 - np.exp(-sigma * delta))
    assert torch.allclose(weights[0], expected)
    assert torch.allclose(weights.sum(), torch.tensor(1 - np.exp(-sigma * delta * n), dtype=torch.float64))


def test_transmittance_float32_large_depth_after_small_ones():
    # cumsum(tau) - tau cancels here in float32 (1e9 + 0.5 - 1e9 = 0, so T2 came out 1.0)
    tau = torch.tensor([[0.25, 0.25, 1e9]], dtype=torch.float32)
    weights, trans, _ = weights_of(tau, torch.tensor(1.0))
    assert trans.dtype == torch.float32
    expected = torch.exp(-torch.tensor([0.0, 0.25, 0.5], dtype=torch.float64))
    assert torch.allclose(trans[0].double(), expected, rtol=1e-6, atol=0)
    assert torch.isclose(weights[0, 2].double(), expected[2], rtol=1e-6)  # the wall takes all the light left
    assert torch.isclose(weights.sum().double(), torch.tensor(1.0, dtype=torch.float64), rtol=1e-6)


def test_exclusive_cumsum_restarts_at_each_ray():
    x = torch.tensor([1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
    assert exclusive_cumsum(x, torch.tensor([0, 0, 0, 1, 1, 1])).tolist() == [0.0, 1.0, 3.0, 0.0, 4.0, 9.0]
    assert exclusive_cumsum(x[:4], torch.tensor([0, 0, 3, 3])).tolist() == [0.0, 1.0, 0.0, 3.0]  # rays 1, 2 empty
    assert exclusive_cumsum(x[:3], torch.tensor([0, 1, 2])).tolist() == [0.0, 0.0, 0.0]
    assert exclusive_cumsum(torch.zeros(0), torch.zeros(0, dtype=torch.long)).shape == (0,)
    assert regular_ray_indices(2, 3).tolist() == [0, 0, 0, 1, 1, 1]


def test_transmittance_float32_after_an_opaque_ray_in_the_same_batch():
    # the batch-wide sums must not let one ray's huge depth wash out the next ray's small ones
    tau = torch.tensor([1e9, 5.0, 1e30, 0.25, 0.25, 1e9, 0.1], dtype=torch.float32)
    rays = torch.tensor([0, 0, 1, 2, 2, 2, 4])
    weights, trans, _ = render_weights(tau, 1.0, rays)
    expected = torch.tensor([1.0, 0.0, 1.0, 1.0, np.exp(-0.25), np.exp(-0.5), 1.0])
    assert torch.allclose(trans.double(), expected.double(), rtol=1e-6, atol=0)
    acc = composite(weights, torch.ones(7, 3), rays, 5)[2]
    assert torch.allclose(acc, torch.tensor([1.0, 1.0, 1.0, 0.0, 1 - np.exp(-0.1)], dtype=torch.float32))


@settings(max_examples=60, deadline=None)
@given(counts=st.lists(st.integers(0, 7), min_size=1, max_size=6), seed=st.integers(0, 2**16))
def test_packed_rendering_equals_rendering_each_ray_alone(counts, seed):
    # any mix of ray lengths (empty rays too): each ray renders as if it were alone
    gen = torch.Generator().manual_seed(seed)
    m = sum(counts)
    rays = torch.repeat_interleave(torch.arange(len(counts)), torch.tensor(counts, dtype=torch.long))
    sig = torch.rand(m, generator=gen, dtype=torch.float64) * 4
    rgbs = torch.rand(m, 3, generator=gen, dtype=torch.float64)
    t = torch.rand(m, generator=gen, dtype=torch.float64)
    w, _, _ = render_weights(sig, 0.3, rays)
    rgb, depth, acc = composite(w, rgbs, rays, len(counts), t, background=0.5)
    for r in range(len(counts)):
        own = rays == r
        w_r, _, _ = render_weights(sig[own], 0.3, torch.zeros(int(own.sum()), dtype=torch.long))
        assert torch.allclose(w[own], w_r)
        rgb_r, depth_r, acc_r = composite(w_r, rgbs[own], torch.zeros_like(rays[own]), 1, t[own], background=0.5)
        assert torch.allclose(rgb[r], rgb_r[0]) and torch.allclose(depth[r], depth_r[0])
        assert torch.allclose(acc[r], acc_r[0])
        if counts[r] == 0:
            assert float(acc[r]) == 0.0 and torch.allclose(rgb[r], torch.full((3,), 0.5, dtype=torch.float64))


def _mixed_scale_taus():
    # optical depths from 1e-6 to 1e9 (and exact zeros), in any order along a ray
    depth = st.one_of(st.just(0.0), st.floats(-6.0, 9.0).map(lambda e: 10.0**e))
    return st.lists(st.lists(depth, min_size=1, max_size=48), min_size=1, max_size=4).map(
        lambda rows: [r + [0.0] * (48 - len(r)) for r in rows]
    )


@settings(max_examples=150, deadline=None)
@given(rows=_mixed_scale_taus())
def test_transmittance_float32_matches_float64_reference(rows):
    tau32 = torch.tensor(rows, dtype=torch.float32)
    weights, trans, alphas = weights_of(tau32, torch.tensor(1.0))
    tau64 = tau32.double()  # the same numbers, summed in float64
    before = torch.cumsum(tau64, -1) - tau64  # exact enough in float64 for these magnitudes
    trans64 = torch.exp(-before)
    w64 = trans64 * -torch.expm1(-tau64)
    assert torch.allclose(trans.double(), trans64, rtol=1e-4, atol=1e-7)
    assert torch.allclose(weights.double(), w64, rtol=1e-4, atol=1e-7)
    assert torch.all(weights >= 0) and torch.all(weights.sum(-1) <= 1 + 1e-5)


def test_rotation_angle_between_camera_orientations():
    gen = torch.Generator().manual_seed(3)
    a = random_c2w(gen, 5).numpy()
    angles = np.array([0.0, 1e-3, 30.0, 90.0, 179.0])
    axes = np.random.default_rng(0).normal(size=(5, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    b = a.copy()
    for i, (deg, k) in enumerate(zip(np.radians(angles), axes)):  # Rodrigues: a turn of deg about k
        K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        b[i, :3, :3] = a[i, :3, :3] @ (np.eye(3) + np.sin(deg) * K + (1 - np.cos(deg)) * K @ K)
    np.testing.assert_allclose(rotation_angles_deg(a, b), angles, atol=2e-3)
    np.testing.assert_allclose(rotation_angles_deg(b, a), angles, atol=2e-3)  # symmetric


def test_transform_round_trips_through_inverse():
    gen = torch.Generator().manual_seed(0)
    c2w = random_c2w(gen, 6)
    x = torch.randn(6, 3, dtype=torch.float64, generator=gen)
    assert torch.allclose(transform(torch.linalg.inv(c2w), transform(c2w, x)), x)
    # a single (4, 4) matrix broadcasts over many points
    pts = torch.randn(10, 3, dtype=torch.float64, generator=gen)
    assert torch.allclose(transform(c2w[0], pts), pts @ c2w[0, :3, :3].T + c2w[0, :3, 3])


def test_pixel_to_camera_projects_back():
    K = torch.tensor([[300.0, 0, 100], [0, 310, 90], [0, 0, 1]], dtype=torch.float64)
    uv = torch.tensor([[10.5, 20.5], [150.0, 5.0]], dtype=torch.float64)
    s = torch.tensor([2.0, 3.5], dtype=torch.float64)
    x = pixel_to_camera(K, uv, s)
    assert torch.allclose(x[:, 2], s)
    proj = (K @ x.T).T
    assert torch.allclose(proj[:, :2] / proj[:, 2:], uv)
    with pytest.raises(ValueError, match=r"s has shape \(2, 1\).*shape \(2,\)"):
        pixel_to_camera(K, uv, s[:, None])  # (2, 1) would broadcast to (2, 2, 3) points
    with pytest.raises(ValueError, match=r"s has shape \(3,\)"):
        pixel_to_camera(K, uv, torch.ones(3, dtype=torch.float64))  # not one per pixel


def test_principal_point_ray_is_camera_z_axis():
    gen = torch.Generator().manual_seed(1)
    c2w = random_c2w(gen, 1)[0]
    K = torch.tensor([[200.0, 0, 64], [0, 200, 48], [0, 0, 1]], dtype=torch.float64)
    o, d = pixel_to_ray(K, c2w, torch.tensor([64.0, 48.0], dtype=torch.float64))
    assert torch.allclose(o, c2w[:3, 3])
    assert torch.allclose(d, c2w[:3, 2])
    # +u goes toward camera +x (right), +v toward camera +y (down)
    _, d_right = pixel_to_ray(K, c2w, torch.tensor([164.0, 48.0], dtype=torch.float64))
    assert torch.dot(d_right - d, c2w[:3, 0]) > 0


def test_opengl_opencv_conversion_flips_y_and_z_and_is_its_own_inverse():
    c2w = random_c2w(torch.Generator().manual_seed(2), 3).numpy()
    cv = opengl_to_opencv(c2w)
    assert np.allclose(cv[:, :3, 0], c2w[:, :3, 0])
    assert np.allclose(cv[:, :3, 1:3], -c2w[:, :3, 1:3])
    assert np.allclose(opengl_to_opencv(cv), c2w)


def test_look_at_and_orbit_point_at_target():
    c2w = look_at(np.array([3.0, 1.0, 2.0]), np.zeros(3), np.array([0.0, 0.0, 1.0]))
    assert np.allclose(c2w[:3, 2], -np.array([3.0, 1.0, 2.0]) / np.linalg.norm([3.0, 1.0, 2.0]))
    assert c2w[:3, 1] @ np.array([0, 0, 1.0]) < 0  # image down is world down-ish
    assert np.isclose(np.linalg.det(c2w[:3, :3]), 1.0)
    poses = orbit_path(np.array([1.0, 2.0, 0.0]), np.array([0, 0, 1.0]), radius=2.0, height=1.0, n_frames=12)
    to_center = np.array([1.0, 2.0, 0.0]) - poses[:, :3, 3]
    cosines = np.einsum("ni,ni->n", poses[:, :3, 2], to_center / np.linalg.norm(to_center, axis=1, keepdims=True))
    assert np.allclose(cosines, 1.0, atol=1e-5)
    assert np.allclose(poses[:, 2, 3], 1.0, atol=1e-5)


def test_stratified_samples_stay_in_their_bins():
    t = stratified_t(2.0, 6.0, n_rays=100, n_samples=8, perturb=True)
    edges = torch.linspace(2.0, 6.0, 9)
    assert torch.all(t >= edges[:-1]) and torch.all(t <= edges[1:])
    assert torch.all(t[:, 1:] > t[:, :-1])
    mid = stratified_t(2.0, 6.0, n_rays=1, n_samples=4, perturb=False)
    assert torch.allclose(mid, torch.tensor([[2.5, 3.5, 4.5, 5.5]]))


def test_sample_along_rays_points_lie_on_rays():
    o = torch.tensor([[0.0, 0, 0], [1, 1, 1]])
    d = torch.nn.functional.normalize(torch.tensor([[0.0, 0, 1], [1, 0, 0]]), dim=-1)
    pts, t = sample_along_rays(o, d, 2.0, 6.0, n_samples=16, perturb=True)
    assert pts.shape == (2, 16, 3) and t.shape == (2, 16)
    assert torch.allclose(pts, o[:, None] + t[..., None] * d[:, None])
    with pytest.raises(ValueError, match=r"\(n_rays, 3\).*got \(3,\)"):
        sample_along_rays(o[0], d[0])  # one ray: the message says to reshape it


def test_intervals_reach_far():
    t = torch.tensor([[1.0, 2.0, 4.0]])
    assert torch.allclose(intervals_from_t(t, 5.0), torch.tensor([[1.0, 2.0, 1.0]]))


def test_sample_pdf_concentrates_where_the_weight_is():
    bins = torch.linspace(0.0, 1.0, 11).expand(4, 11).contiguous()
    weights = torch.zeros(4, 10)
    weights[:, 7] = 1.0
    t = sample_pdf(bins, weights, 64, perturb=True, generator=torch.Generator().manual_seed(0))
    inside = ((t >= 0.7) & (t <= 0.8)).float().mean()
    assert inside > 0.95


def test_positional_encoding_values_and_dims():
    x = torch.zeros(5, 2)
    e = positional_encoding(x, 10)
    assert e.shape == (5, 42)  # the 2D warm-up: 2 * (1 + 2 * 10)
    assert torch.all(e[:, :2] == 0)
    per_octave = e[:, 2:].reshape(5, 10, 4)  # [sin x, sin y, cos x, cos y] for each octave
    assert torch.all(per_octave[..., :2] == 0) and torch.all(per_octave[..., 2:] == 1)
    x = torch.tensor([[0.25, -0.5, 1.0]])
    e = positional_encoding(x, 4)
    assert e.shape == (1, 27)
    assert torch.allclose(e[0, 3 + 6 * 2 : 3 + 6 * 2 + 3], torch.sin(4 * torch.pi * x[0]), atol=1e-6)
    assert torch.allclose(e[0, 3 + 6 * 2 + 3 : 3 + 6 * 3], torch.cos(4 * torch.pi * x[0]), atol=1e-6)
    # octaves 0 and 1 of x = 1/4: sin and cos of pi/4, then of pi/2 (float64 in, float64 out)
    e = positional_encoding(torch.tensor([[0.25]], dtype=torch.float64), 2)[0]
    s = 0.5**0.5
    assert e.dtype == torch.float64
    torch.testing.assert_close(e, torch.tensor([0.25, s, s, 1.0, 0.0], dtype=torch.float64), atol=1e-12, rtol=0)


def test_image_rays_row_major_pixel_centres():
    K = torch.tensor([[50.0, 0, 4], [0, 50, 3], [0, 0, 1]])
    rays = image_rays(K, torch.eye(4), width=8, height=6)
    assert len(rays) == 48
    # pixel (col 4, row 3) -> uv (4.5, 3.5): x and y offsets of +0.5 / 50
    d = rays.directions[3 * 8 + 4]
    assert torch.allclose(d[:2] / d[2], torch.tensor([0.01, 0.01]), atol=1e-6)


def test_the_readme_course_api_imports_and_every_api_name_resolves():
    from pathlib import Path

    import nerfkit

    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    block = readme.split("## The course API")[1].split("```python")[1].split("```")[0]
    names: dict = {}
    exec(block, names)  # the README's own import lines
    assert {"transform", "volrend", "RaysData", "NeRFMLP"} <= set(names)
    for name in nerfkit.__all__:
        value = getattr(nerfkit, name)
        assert value.__name__ in (name, f"nerfkit.{name}")  # a function or class, or a module (nerfkit.api)


def test_sample_along_rays_refuses_near_at_or_past_far():
    o, d = torch.zeros(2, 3), torch.tensor([[0.0, 0, 1], [0, 1, 0]])
    for near, far in ((6.0, 2.0), (2.0, 2.0), (torch.tensor([2.0, 7.0]), torch.tensor([6.0, 6.0]))):
        with pytest.raises(ValueError, match="near < far"):
            sample_along_rays(o, d, near, far, n_samples=4, perturb=False)


def test_the_course_functions_refuse_shapes_they_would_misread():
    from nerfkit.data.rays import RaysData
    from nerfkit.data.scene import Views

    K = torch.tensor([[100.0, 0, 50], [0, 100.0, 40], [0, 0, 1]])
    with pytest.raises(ValueError, match=r"uv of shape \(\.\.\., 2\)"):
        pixel_to_camera(K, torch.tensor([[100.0, 80, 2]]), 1.0)  # homogeneous (u, v, 1) is not taken
    with pytest.raises(ValueError, match="rgbs"):
        volrend(torch.rand(4, 8, 1), torch.rand(8, 4, 3), 0.1)
    with pytest.raises(ValueError, match="step_size"):
        volrend(torch.ones(3, 3), torch.ones(3, 3, 3), torch.tensor([0.1, 1.0, 10.0]))  # per ray: (n_rays, 1)
    # a step per sample of the documented (n_rays, n_samples, 1) shape is taken
    step = torch.full((3, 3, 1), 0.1)
    torch.testing.assert_close(
        volrend(torch.ones(3, 3), torch.ones(3, 3, 3), step), volrend(torch.ones(3, 3), torch.ones(3, 3, 3), 0.1)
    )
    c2w = np.repeat(np.eye(4, dtype=np.float32)[None], 2, 0)
    Ks = np.repeat(K.numpy()[None], 2, 0)
    for images in (
        np.full((2, 4, 6, 3), 0.5, np.float32),
        np.zeros((2, 4, 6, 4), np.uint8),
        np.zeros((2, 6, 4, 3), np.uint8),
    ):
        with pytest.raises(ValueError, match=r"RaysData takes images of \(N, H, W, 3\) = \(2, 4, 6, 3\) uint8"):
            RaysData(Views(c2w, Ks, 6, 4, images))


def test_the_course_functions_keep_float64_and_refuse_a_fractional_octave_count():
    from nerfkit import NeRFMLP, VanillaConfig

    o, d = torch.zeros(2, 3, dtype=torch.float64), torch.tensor([[0.0, 0, 1], [0, 1, 0]], dtype=torch.float64)
    pts, t = sample_along_rays(o, d, 2.0, 2.0 + 1e-9, n_samples=2, perturb=False)
    assert t.dtype == pts.dtype == torch.float64 and t[0, 1] - t[0, 0] == pytest.approx(5e-10, rel=1e-6)
    with pytest.raises(ValueError, match="n_samples must be at least 1"):
        sample_along_rays(o, d, 2.0, 6.0, n_samples=0)
    mlp = NeRFMLP(VanillaConfig(width=8, depth=2)).double()
    sigma, rgb = mlp(torch.zeros(3, 3, dtype=torch.float64), torch.zeros(3, 3, dtype=torch.float64))
    assert sigma.dtype == rgb.dtype == torch.float64
    for bad in (2.5, -1):
        with pytest.raises(ValueError, match="positional_encoding's L"):
            positional_encoding(torch.zeros(2, 3), bad)
    assert positional_encoding(torch.zeros(2, 3), np.int64(2)).shape == (2, 15)


def test_the_course_functions_take_numpy_and_give_numpy_back():
    """numpy in, numpy out, with the values the tensors give; a tensor among the inputs keeps tensors."""
    gen = torch.Generator().manual_seed(3)
    c2w = random_c2w(gen, 1)[0]
    K = torch.tensor([[200.0, 0, 64], [0, 210, 48], [0, 0, 1]], dtype=torch.float64)
    uv = torch.tensor([[3.5, 7.5], [100.0, 60.0]], dtype=torch.float64)
    x = torch.randn(2, 3, dtype=torch.float64, generator=gen)

    out = transform(c2w.numpy(), x.numpy())
    assert isinstance(out, np.ndarray) and out.dtype == np.float64
    np.testing.assert_array_equal(out, transform(c2w, x).numpy())
    np.testing.assert_array_equal(pixel_to_camera(K.numpy(), uv.numpy(), 2.0), pixel_to_camera(K, uv, 2.0).numpy())
    o, d = pixel_to_ray(K.numpy(), c2w.numpy(), uv.numpy())
    to, td = pixel_to_ray(K, c2w, uv)
    assert isinstance(o, np.ndarray) and isinstance(d, np.ndarray)
    np.testing.assert_array_equal(d, td.numpy())
    np.testing.assert_array_equal(o, to.numpy())

    pts, t = sample_along_rays(o, d, 2.0, 6.0, n_samples=4, perturb=False)
    assert isinstance(pts, np.ndarray) and t.shape == (2, 4)
    np.testing.assert_allclose(t[0], [2.5, 3.5, 4.5, 5.5])
    rgb = volrend(np.full((2, 4), 1e3), np.ones((2, 4, 3)) * 0.25, 1.0)
    assert isinstance(rgb, np.ndarray)
    np.testing.assert_allclose(rgb, 0.25)
    enc = positional_encoding(np.zeros((1, 1)), 1)
    assert isinstance(enc, np.ndarray)
    np.testing.assert_array_equal(enc, [[0.0, 0.0, 1.0]])

    # a tensor among the arguments: the results stay tensors
    assert isinstance(transform(c2w, x.numpy()), torch.Tensor)
