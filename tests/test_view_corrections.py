"""Per-view pose and exposure corrections: known perturbations and gains are recovered."""

import copy
from dataclasses import replace

import numpy as np
import pytest
import torch

from nerfkit.cameras import Rays, image_rays, intrinsics_matrix, look_at
from nerfkit.surroundings.table import TablePlane
from nerfkit.train.view_corrections import (
    ExposureCorrection,
    PoseCorrection,
    ViewAdam,
    ViewFitConfig,
    build_view_corrections,
    fit_view,
    row_steps,
    so3_exp,
)


def textured_table(seed: int = 0) -> TablePlane:
    """A table plane z = 0 with a smooth random texture (a frozen 'scene')."""
    table = TablePlane(torch.tensor([0.0, 0.0, 1.0, 0.0]), torch.zeros(3), radius=1.0, resolution=64)
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        noise = torch.randn(1, 3, 16, 16, generator=g) * 2.0
        smooth = torch.nn.functional.interpolate(noise, size=(64, 64), mode="bicubic", align_corners=False)
        table.fine.copy_(smooth[0].permute(1, 2, 0).reshape(-1, 3))
    for p in table.parameters():
        p.requires_grad_(False)
    return table


def render_table(table: TablePlane, rays: Rays) -> torch.Tensor:
    t = table.hit(rays.origins, rays.directions)
    return table.colour(rays.origins + rays.directions * t.unsqueeze(-1))


def camera(eye) -> tuple[torch.Tensor, torch.Tensor]:
    K = torch.as_tensor(intrinsics_matrix(40.0, 40.0, 24.0, 24.0), dtype=torch.float32)
    c2w = torch.as_tensor(look_at(np.asarray(eye, float), np.zeros(3), np.array([0.0, 0.0, 1.0])), dtype=torch.float32)
    return K, c2w


def test_so3_exp_is_a_rotation_by_the_vector_length_about_its_axis():
    R = so3_exp(torch.tensor([[0.0, 0.0, np.pi / 2], [0.0, 0.0, 0.0]]))
    assert torch.allclose(R[0] @ torch.tensor([1.0, 0.0, 0.0]), torch.tensor([0.0, 1.0, 0.0]), atol=1e-6)
    assert torch.allclose(R[1], torch.eye(3))
    w = torch.randn(5, 3, generator=torch.Generator().manual_seed(1))
    R = so3_exp(w)
    assert torch.allclose(R @ R.transpose(1, 2), torch.eye(3).expand(5, 3, 3), atol=1e-5)
    assert torch.allclose(torch.linalg.det(R), torch.ones(5), atol=1e-5)


def test_corrected_c2w_matches_the_corrected_rays():
    K, c2w = camera([0.5, -1.5, 1.2])
    pose = PoseCorrection(1, scale=0.5)
    with torch.no_grad():
        pose.rotation[0] = torch.tensor([0.02, -0.01, 0.03])
        pose.translation[0] = torch.tensor([0.04, 0.0, -0.02])
    rays = image_rays(K, c2w, 8, 8)
    moved = pose(rays, torch.zeros(len(rays), dtype=torch.long))
    c2w_new = torch.as_tensor(pose.corrected_c2w(c2w.numpy()[None])[0])
    direct = image_rays(K, c2w_new, 8, 8)
    assert torch.allclose(moved.origins, direct.origins, atol=1e-6)
    assert torch.allclose(moved.directions, direct.directions, atol=1e-6)


@pytest.mark.slow
def test_fit_view_recovers_a_known_pose_perturbation():
    table = textured_table()
    K, c2w = camera([0.3, -1.6, 1.4])
    target = render_table(table, image_rays(K, c2w, 48, 48)).detach()
    # the view as "posed": rotated by 1.5 degrees and shifted by 3 cm (about 1 px and 2 px here)
    truth = PoseCorrection(1, scale=1.0)
    with torch.no_grad():
        truth.rotation[0] = torch.tensor([0.015, -0.02, 0.01])
        truth.translation[0] = torch.tensor([0.02, 0.02, -0.01])
    wrong = torch.as_tensor(truth.corrected_c2w(c2w.numpy()[None])[0])
    rays = image_rays(K, wrong, 48, 48)
    before = float(torch.mean((render_table(table, rays) - target) ** 2))
    pose, _ = fit_view(
        lambda r: render_table(table, r),
        rays,
        target,
        scale=1.0,
        cfg=ViewFitConfig(steps=300, rays=2304, lr=3e-3, exposure=False),
        generator=torch.Generator().manual_seed(0),
    )
    fixed = torch.as_tensor(pose.corrected_c2w(wrong.numpy()[None])[0])
    after = float(torch.mean((render_table(table, image_rays(K, fixed, 48, 48)) - target) ** 2))
    assert after < 0.05 * before
    # the camera comes back to where it was: centre within 5 mm, axis within 0.2 degrees
    assert float(torch.linalg.norm(fixed[:3, 3] - c2w[:3, 3])) < 5e-3
    cos = float(fixed[:3, 2] @ c2w[:3, 2])
    assert np.degrees(np.arccos(min(cos, 1.0))) < 0.2


@pytest.mark.slow
def test_exposure_correction_recovers_known_gains_while_the_scene_is_learned():
    truth = textured_table(seed=3)
    eyes = [[1.5 * np.cos(a), 1.5 * np.sin(a), 1.3] for a in np.linspace(0, 2 * np.pi, 6, endpoint=False)]
    gains = torch.tensor(
        [[1.0, 1.0, 1.0], [1.3, 1.25, 1.2], [0.8, 0.85, 0.9], [1.1, 1.0, 0.9], [0.9, 1.0, 1.1], [1.2, 1.2, 1.2]]
    )
    rays, targets, views = [], [], []
    for i, eye in enumerate(eyes):
        K, c2w = camera(eye)
        r = image_rays(K, c2w, 32, 32)
        rays.append(r)
        targets.append((render_table(truth, r) * gains[i] * 0.8).detach())  # darker than 1: no clipping
        views.append(torch.full((len(r),), i))
    rays = Rays(torch.cat([r.origins for r in rays]), torch.cat([r.directions for r in rays]))
    target, view = torch.cat(targets), torch.cat(views)
    scene = TablePlane(torch.tensor([0.0, 0.0, 1.0, 0.0]), torch.zeros(3), radius=1.0, resolution=64)
    exposure = ExposureCorrection(len(eyes))
    with torch.no_grad():
        exposure.offset.requires_grad_(False)  # gains only: an offset could trade against dark texels
    opt = torch.optim.Adam([{"params": scene.parameters(), "lr": 0.05}, {"params": [exposure.log_gain], "lr": 0.01}])
    for _ in range(400):
        loss = torch.mean((exposure(render_table(scene, rays), view) - target) ** 2)
        opt.zero_grad()
        loss.backward()
        opt.step()
    expected = (gains / gains.log().mean(0).exp()).numpy()  # relative to the average view
    np.testing.assert_allclose(exposure.gains(), expected, rtol=0.02)


def test_a_common_motion_of_every_view_is_no_correction():
    pose = PoseCorrection(3, scale=1.0)
    with torch.no_grad():
        pose.rotation[:] = torch.tensor([0.1, 0.0, 0.0])
        pose.translation[:] = torch.tensor([0.0, 0.2, 0.0])
    c2w = np.repeat(np.eye(4)[None], 3, 0)
    np.testing.assert_allclose(pose.corrected_c2w(c2w), c2w, atol=1e-7)


def test_least_squares_colour_solves_a_known_transform_exactly():
    from nerfkit.train.view_corrections import least_squares_colour

    rng = np.random.default_rng(0)
    rgb = rng.uniform(0.05, 0.9, (500, 3))
    M = np.array([[0.9, 0.05, -0.02], [0.03, 1.1, 0.04], [-0.05, 0.02, 0.8]])
    b = np.array([0.02, -0.01, 0.03])
    matrix, offset = least_squares_colour(rgb, rgb @ M.T + b, mix=True)
    np.testing.assert_allclose(matrix, M, atol=1e-10)
    np.testing.assert_allclose(offset, b, atol=1e-10)
    # the gain model: a diagonal matrix; exact for per-channel gains, the best diagonal otherwise
    gains = np.diag([0.9, 1.1, 0.8])
    matrix, offset = least_squares_colour(rgb, rgb @ gains + b, mix=False)
    np.testing.assert_allclose(matrix, gains, atol=1e-10)
    np.testing.assert_allclose(offset, b, atol=1e-10)
    matrix, _ = least_squares_colour(rgb, rgb @ M.T + b, mix=False)
    assert np.count_nonzero(matrix - np.diag(np.diag(matrix))) == 0
    mse_diag = np.mean((rgb @ matrix.T + _ - (rgb @ M.T + b)) ** 2)
    assert 0 < mse_diag < np.mean((rgb - (rgb @ M.T + b)) ** 2)


def off_diagonal(M: torch.Tensor) -> torch.Tensor:
    """(n, 3, 3) colour matrices with their diagonals zeroed."""
    return M - torch.diag_embed(torch.diagonal(M, dim1=1, dim2=2))


def test_colour_mix_is_an_affine_transform_per_view_about_the_average():
    exposure = ExposureCorrection(3, mix=True)
    with torch.no_grad():
        exposure.log_gain[:] = torch.tensor([[0.1, 0.0, -0.1], [0.0, 0.2, 0.0], [-0.1, -0.2, 0.1]])
        exposure.mix[:] = torch.tensor(
            [[0.02, 0.0, 0.01, 0.0, 0.0, -0.03], [0.0] * 6, [-0.02, 0.0, -0.01, 0.0, 0.0, 0.03]]
        )
        exposure.offset[:] = torch.tensor([[0.01, 0.0, 0.0], [0.0, 0.0, 0.0], [-0.01, 0.0, 0.0]])
    rgb = torch.rand(9, 3)
    view = torch.arange(9) % 3
    with torch.no_grad():
        M = exposure.matrices()
        b = exposure.centred()[1]
    expected = torch.einsum("nij,nj->ni", M[view], rgb) + b[view]
    torch.testing.assert_close(exposure(rgb, view).detach(), expected)
    # the mixing's mean over views is removed, as the gains' and offsets' are
    torch.testing.assert_close(off_diagonal(M).mean(0), torch.zeros(3, 3))
    assert M[1, 0, 1] == 0 and M[0, 0, 1] == pytest.approx(0.02) and M[0, 2, 1] == pytest.approx(-0.03)


def fit_colour_corrections(rgb, target, view, n_views, weight, steps=600):
    """Fit an ExposureCorrection with colour mixing to fixed renders (the scene frozen)."""
    exposure = ExposureCorrection(n_views, mix=True)
    opt = torch.optim.Adam(exposure.parameters(), lr=1e-2)
    for _ in range(steps):
        loss = torch.mean((exposure(rgb, view) - target) ** 2) + weight * exposure.mix_penalty()
        opt.zero_grad()
        loss.backward()
        opt.step()
    return exposure


@pytest.mark.slow
def test_the_mix_penalty_keeps_photos_of_grey_things_to_a_plain_gain():
    # grey pixels constrain only each row's sum of a colour matrix: a brighter photo of a
    # grey scene is as well explained by mixing in the other channels as by a gain
    g = torch.Generator().manual_seed(0)
    grey = torch.rand(600, 1, generator=g).expand(600, 3) * 0.8
    gains = torch.tensor([[1.2, 1.1, 1.0], [0.8, 0.9, 1.0], [1.0, 1.1, 1.3], [1.05, 0.95, 0.8]])
    view = torch.arange(600) % 4
    target = grey * gains[view]
    free = fit_colour_corrections(grey, target, view, 4, weight=0.0)
    held = fit_colour_corrections(grey, target, view, 4, weight=0.1)
    for exposure in (free, held):  # both explain the photos
        with torch.no_grad():
            assert float(torch.mean((exposure(grey, view) - target) ** 2)) < 1e-4  # 40 dB
    with torch.no_grad():
        M_free, M_held = free.matrices(), held.matrices()
    assert float(off_diagonal(M_free).abs().max()) > 0.05  # without the penalty, mixing takes part of the gain
    assert float(off_diagonal(M_held).abs().max()) < 0.01  # with it, the matrices are the gains
    expected = gains / gains.log().mean(0).exp()  # relative to the average view
    np.testing.assert_allclose(torch.diagonal(M_held, dim1=1, dim2=2).numpy(), expected.numpy(), rtol=0.02)


def test_the_mix_penalty_is_the_mean_squared_mixing_about_the_average():
    exposure = ExposureCorrection(2, mix=True)
    assert float(exposure.mix_penalty().detach()) == 0.0
    with torch.no_grad():
        exposure.mix[0] = torch.tensor([0.1, 0.0, 0.0, 0.0, 0.0, 0.3])
        exposure.mix[1] = torch.tensor([-0.1, 0.0, 0.0, 0.0, 0.0, -0.3])
    assert float(exposure.mix_penalty().detach()) == pytest.approx(0.1**2 + 0.3**2)
    with torch.no_grad():
        exposure.mix[:] = 0.2  # the same mixing in every view is the scene's colour, not a correction
    assert float(exposure.mix_penalty().detach()) == pytest.approx(0.0)
    assert float(ExposureCorrection(2, mix=False).mix_penalty().detach()) == 0.0


# -- ViewAdam: one view per step moves that view's corrections only


def test_view_adam_leaves_the_rows_of_unseen_views_and_their_moments_alone():
    """Every row has a gradient (the mean removal gives one to all), but only the seen
    view's row and its moments change; a later step of another row leaves it as it was."""
    exposure = ExposureCorrection(5)
    opt = ViewAdam(exposure.parameters(), lr=0.1)
    for view in (2, 2, 4):
        rgb = exposure(torch.full((8, 3), 0.5), torch.full((8,), view))
        opt.zero_grad()
        ((rgb - 0.8) ** 2).mean().backward()
        assert float(exposure.log_gain.grad[0].abs().sum()) > 0  # an unseen view's row has a gradient
        before = {k: v.clone() for k, v in opt.state[exposure.log_gain].items()} if opt.state else None
        values = exposure.log_gain.detach().clone()
        opt.step(rows=torch.tensor([view]))
        others = [i for i in range(5) if i != view]
        assert torch.equal(exposure.log_gain.detach()[others], values[others])
        assert not torch.equal(exposure.log_gain.detach()[view], values[view])
        if before is not None:
            for k, v in opt.state[exposure.log_gain].items():
                assert torch.equal(v[others], before[k][others]), k
    assert opt.state[exposure.log_gain]["step"].tolist() == [0, 0, 2, 0, 1]


def test_view_adam_steps_each_row_as_adam_on_that_views_gradients_alone():
    """Row i follows torch's Adam fed only the gradients of the steps that saw view i (its
    own step count for the bias correction); with every row seen, it is torch's Adam."""
    g = torch.Generator().manual_seed(0)
    grads = torch.randn(7, 3, 2, generator=g)
    seen = [0, 2, 0, 0, 1, 2, 0]
    p = torch.nn.Parameter(torch.zeros(3, 2))
    opt = ViewAdam([p], lr=0.05)
    rows = [torch.nn.Parameter(torch.zeros(2)) for _ in range(3)]
    reference = [torch.optim.Adam([r], lr=0.05) for r in rows]
    for grad, view in zip(grads, seen):
        p.grad = grad.clone()
        opt.step(rows=torch.tensor([view]))
        rows[view].grad = grad[view].clone()
        reference[view].step()
    torch.testing.assert_close(p.detach(), torch.stack([r.detach() for r in rows]))

    dense = torch.nn.Parameter(torch.zeros(3, 2))
    every, adam = ViewAdam([p.detach().clone().requires_grad_()], lr=0.05), torch.optim.Adam([dense], lr=0.05)
    q = every.param_groups[0]["params"][0]
    with torch.no_grad():
        dense.copy_(q)
    for grad in grads:
        q.grad, dense.grad = grad.clone(), grad.clone()
        every.step()
        adam.step()
    torch.testing.assert_close(q.detach(), dense.detach())


def test_view_adam_resumes_from_its_state_and_from_a_dense_adams():
    p = torch.nn.Parameter(torch.zeros(4, 3))
    opt = ViewAdam([p], lr=0.1)
    for view in (1, 3, 1):
        p.grad = torch.ones(4, 3)
        opt.step(rows=torch.tensor([view]))
    q = torch.nn.Parameter(p.detach().clone())
    again = ViewAdam([q], lr=0.1)
    again.load_state_dict(copy.deepcopy(opt.state_dict()))  # (as a checkpoint holds it)
    for o, x in ((opt, p), (again, q)):
        x.grad = -torch.ones(4, 3)
        o.step(rows=torch.tensor([1]))
    torch.testing.assert_close(p.detach(), q.detach())
    # a dense Adam's state (a checkpoint from before): every row continues from its count
    dense = torch.optim.Adam([p], lr=0.1)
    p.grad = torch.ones(4, 3)
    dense.step()
    moved = ViewAdam([p], lr=0.1)
    moved.load_state_dict(copy.deepcopy(dense.state_dict()))
    moved.step(rows=torch.tensor([0]))
    assert moved.state[p]["step"].tolist() == [2, 1, 1, 1]


def test_view_adam_steps_on_the_parameters_device_after_loading_a_cpu_checkpoint():
    """torch's load_state_dict moves Adam's moments to the parameter's device but leaves "step"
    on the CPU the checkpoint was loaded to (CUDA in training; the meta device stands in here)."""
    p = torch.nn.Parameter(torch.zeros(4, 3))
    opt = ViewAdam([p], lr=0.1)
    p.grad = torch.ones(4, 3)
    opt.step(rows=torch.tensor([1]))
    q = torch.nn.Parameter(torch.zeros(4, 3, device="meta"))
    again = ViewAdam([q], lr=0.1)
    again.load_state_dict(copy.deepcopy(opt.state_dict()))
    assert again.state[q]["step"].device.type == "cpu"  # (as torch loads it)
    q.grad = torch.ones(4, 3, device="meta")
    again.step()
    assert {t.device.type for t in again.state[q].values()} == {"meta"}
    assert row_steps(torch.tensor(3.0), q).shape == (4,) and row_steps(torch.tensor(3.0), q).device.type == "meta"


def test_one_view_per_step_with_view_adam_recovers_known_pose_offsets():
    """Two views of a frozen splat scene given 1.1 degrees and 3 cm off (opposite ways, so
    the mean correction is zero), rendered in turn, one per step: the learned corrections
    bring both cameras back, each within 30% of its offset."""
    model = gaussian_cloud(sh_degree=1)
    K, c2w = splat_camera(32)
    truth = known_pose([0.015, -0.01, 0.008], [0.02, 0.02, -0.015])
    w, t = truth.rotation.detach()[0], truth.translation.detach()[0]
    offsets = PoseCorrection(2, 1.0)
    with torch.no_grad():
        offsets.rotation[:], offsets.translation[:] = torch.stack([w, -w]), torch.stack([t, -t])
        given = [offsets.camera(c2w, i) for i in range(2)]
        target = splat_rgb(model, K, c2w)

    def errors(pose: PoseCorrection, view: int) -> tuple[float, float]:
        """(distance, rotation angle in degrees) of view's corrected camera from the true one"""
        fixed = pose.camera(given[view], view).detach()
        cos = (float(torch.trace(fixed[:3, :3] @ c2w[:3, :3].T)) - 1) / 2
        return float(torch.linalg.norm(fixed[:3, 3] - c2w[:3, 3])), float(np.degrees(np.arccos(min(cos, 1.0))))

    pose = PoseCorrection(2, 1.0)
    before = [errors(pose, v) for v in range(2)]
    opt = ViewAdam(pose.parameters(), lr=1e-2)
    steps = 120
    for step in range(steps):
        view = step % 2
        opt.param_groups[0]["lr"] = 1e-2 * 0.1 ** (step / steps)
        opt.zero_grad()
        torch.mean((splat_rgb(model, K, pose.camera(given[view], view)) - target) ** 2).backward()
        opt.step(rows=torch.tensor([view]))
    for view in range(2):
        (d0, a0), (d, a) = before[view], errors(pose, view)
        assert d0 > 0.03 and a0 > 1.0
        assert d < 0.3 * d0 and a < 0.3 * a0, (view, d, a)


# -- whole-view models (splat): the correction moves the camera the Gaussians are rendered from


def gaussian_cloud(n: int = 300, seed: int = 0, kernels: str = "auto", sh_degree: int = 0):
    """A frozen splat model of ``n`` opaque, coloured Gaussians in the unit ball (with
    ``sh_degree`` 1: a random view-dependent colour)."""
    from nerfkit.models.base import SceneBounds
    from nerfkit.models.splat import SplatConfig, SplatModel, initial_gaussians

    g = torch.Generator().manual_seed(seed)
    bounds = SceneBounds(2.0, 6.0, np.zeros(3), 1.0, np.array([0.0, 0.0, 1.0]))
    model = SplatModel(SplatConfig(init_points=1, kernels=kernels, torch_threads=0), bounds)
    points = torch.randn(n, 3, generator=g)
    points = points / points.norm(dim=1, keepdim=True) * torch.rand(n, 1, generator=g) ** (1 / 3)
    means, log_scales, quats, opacity, sh_dc, sh_rest = initial_gaussians(
        points, torch.rand(n, 3, generator=g), 0.06, 0.8
    )
    log_scales = log_scales + 0.4 * torch.randn(n, 3, generator=g)  # anisotropic, turned every way
    quats = torch.randn(n, 4, generator=g)
    if sh_degree:
        sh_rest[:, :3] = 0.3 * torch.randn(n, 3, 3, generator=g)
    model._install(means, log_scales, quats, opacity, sh_dc, sh_rest)
    model.active_degree = sh_degree
    model.eval()
    for p in model.parameters():
        p.requires_grad_(False)
    return model


def splat_camera(size: int = 32) -> tuple[torch.Tensor, torch.Tensor]:
    """A camera 2.2 from the centre of :func:`gaussian_cloud`, which fills most of its view
    at a depth from 1.2 to 3.2 (the parallax that tells a rotation from a shift)."""
    K = torch.as_tensor(intrinsics_matrix(size, size, size / 2, size / 2), dtype=torch.float32)
    eye = np.array([1.35, -1.5, 0.9])
    c2w = torch.as_tensor(look_at(eye, np.zeros(3), np.array([0.0, 0.0, 1.0])), dtype=torch.float32)
    return K, c2w


def known_pose(rotation, translation, scale: float = 1.0) -> PoseCorrection:
    pose = PoseCorrection(1, scale)
    with torch.no_grad():
        pose.rotation[0] = torch.tensor(rotation)
        pose.translation[0] = torch.tensor(translation)
    return pose


def splat_rgb(model, K, c2w, size: int = 32) -> torch.Tensor:
    return model.render_view(K, c2w, size, size, torch.zeros(3)).rgb


def quat_multiply(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton products of (w, x, y, z) quaternions: the rotation ``b`` then ``a``."""
    w1, x1, y1, z1 = a.unbind(-1)
    w2, x2, y2, z2 = b.unbind(-1)
    return torch.stack(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ],
        -1,
    )


def test_corrected_c2w_of_many_views_is_each_views_camera():
    g = torch.Generator().manual_seed(3)
    pose = PoseCorrection(4, scale=0.7)
    with torch.no_grad():
        pose.rotation.copy_(0.05 * torch.randn(4, 3, generator=g))
        pose.translation.copy_(0.05 * torch.randn(4, 3, generator=g))
    poses = torch.stack([camera([0.5 + i, -1.5, 1.2])[1] for i in range(4)]).double()
    batched = pose.corrected_c2w(poses.numpy())
    for i in range(4):
        np.testing.assert_allclose(batched[i], pose.camera(poses[i], i).detach().numpy(), atol=1e-6)
    assert not np.allclose(batched, poses.numpy())


def test_a_zero_pose_correction_renders_the_view_as_given():
    model = gaussian_cloud()
    K, c2w = splat_camera()
    pose = PoseCorrection(4, scale=1.0)
    assert torch.equal(pose.camera(c2w, 2), c2w)
    # (a camera that needs a gradient projects on the torch reference, the plain one on the
    # compiled projection: the same render up to float32 rounding)
    rgb = splat_rgb(model, K, c2w)
    torch.testing.assert_close(splat_rgb(model, K, pose.camera(c2w, 2)), rgb, rtol=1e-5, atol=1e-6)
    assert float(rgb.max()) > 0.1


def test_the_corrected_camera_sees_what_the_gaussians_moved_back_show_the_given_one():
    """Rendering from ``T c2w`` (T: the correction, a rigid motion about the camera's centre)
    equals rendering the Gaussians moved by ``T^-1`` from ``c2w``: means moved, rotations
    turned and, for a view-dependent colour, the degree-1 SH turned with them (the camera
    route needs none of that: the view directions follow the camera)."""
    model = gaussian_cloud(kernels="torch", sh_degree=1)
    K, c2w = splat_camera()
    pose = known_pose([0.03, -0.02, 0.04], [0.05, -0.03, 0.02], scale=1.0)
    with torch.no_grad():
        from_corrected = splat_rgb(model, K, pose.camera(c2w, 0))

    R = so3_exp(pose.rotation.detach())[0]
    centre = c2w[:3, 3]
    means = (model.means - centre - pose.scale * pose.translation.detach()[0]) @ R + centre  # R^T (x - o') + o
    w = -pose.rotation.detach()[0]
    turn = torch.cat([torch.cos(w.norm() / 2).reshape(1), torch.sin(w.norm() / 2) * w / w.norm()])
    quats = quat_multiply(turn.expand_as(model.quats), model.quats / model.quats.norm(dim=1, keepdim=True))
    # the degree-1 band is C1 * d . (-c3, -c1, c2) per channel: its vector turns as the directions do
    c1, c2, c3 = model.sh_rest[:, 0], model.sh_rest[:, 1], model.sh_rest[:, 2]
    v = torch.stack([-c3, -c1, c2], 1)  # (n, 3 axes, 3 channels)
    v = R.T @ v
    rest = model.sh_rest.clone()
    rest[:, 0], rest[:, 1], rest[:, 2] = -v[:, 1], v[:, 2], -v[:, 0]
    moved = gaussian_cloud(kernels="torch", sh_degree=1)
    moved._install(means, model.log_scales, quats, model.opacity_logits, model.sh_dc, rest)
    moved.active_degree = 1
    from_given = splat_rgb(moved, K, c2w)
    assert float(from_corrected.mean()) > 0.2  # the cloud fills much of the view
    torch.testing.assert_close(from_corrected, from_given, atol=2e-4, rtol=0)
    # a correction of 2.6 degrees moves the image well beyond that tolerance
    assert float((from_corrected - splat_rgb(model, K, c2w)).abs().max()) > 0.2


@pytest.mark.parametrize("kernels", ["numba", "torch"])
def test_the_image_gradient_reaches_the_pose_correction_through_the_camera(kernels):
    """The compiled rasterizer's gradients (2D means, conics, colours) reach the camera
    through the torch projection: the same pose gradient as the torch reference's, and the
    directional derivative of a finite difference."""
    from nerfkit.kernels.splat_ops import resolve_backend

    if resolve_backend(kernels, torch.device("cpu")) != kernels:
        pytest.skip("numba is not available")
    model = gaussian_cloud(kernels=kernels, sh_degree=1)
    K, c2w = splat_camera()
    target = splat_rgb(model, K, known_pose([0.01, 0.0, -0.01], [0.0, 0.02, 0.0]).camera(c2w, 0))
    pose = PoseCorrection(1, scale=1.0)

    def loss() -> torch.Tensor:
        return torch.mean((splat_rgb(model, K, pose.camera(c2w, 0)) - target) ** 2)

    loss().backward()
    grad = torch.cat([pose.rotation.grad[0], pose.translation.grad[0]])
    assert float(grad.norm()) > 0
    direction = -grad / grad.norm()
    eps = 1e-3
    with torch.no_grad():
        pose.rotation[0], pose.translation[0] = eps * direction[:3], eps * direction[3:]
        ahead = float(loss())
        pose.rotation[0], pose.translation[0] = -eps * direction[:3], -eps * direction[3:]
        behind = float(loss())
    slope = (ahead - behind) / (2 * eps)
    assert slope == pytest.approx(-float(grad.norm()), rel=0.1)


def test_fit_whole_view_recovers_a_known_pose_perturbation():
    """A held-out view of a splat scene posed 1.7 degrees and 5 cm off comes back (eval's fit)."""
    from nerfkit.train.view_corrections import fit_whole_view

    model = gaussian_cloud(sh_degree=1)
    K, c2w = splat_camera(40)
    target = splat_rgb(model, K, c2w, 40).reshape(-1, 3)
    wrong = known_pose([0.02, -0.015, 0.015], [0.03, 0.03, -0.02]).camera(c2w, 0).detach()
    pose, _ = fit_whole_view(
        lambda cam: splat_rgb(model, K, cam, 40).reshape(-1, 3),
        wrong,
        target,
        scale=1.0,
        cfg=ViewFitConfig(steps=150, lr=1e-2, exposure=False),
    )
    fixed = pose.camera(wrong, 0).detach()
    assert float(torch.linalg.norm(fixed[:3, 3] - c2w[:3, 3])) < 5e-3
    cos = float(fixed[:3, 2] @ c2w[:3, 2])
    assert np.degrees(np.arccos(min(cos, 1.0))) < 0.2


def cloud_scene(n_train: int = 10, size: int = 32, offset: PoseCorrection | None = None, view: int = 0):
    """Views of :func:`gaussian_cloud` from a ring of cameras 2.2 from its centre (sparse
    points: its means), training view ``view``'s pose given with ``offset`` applied."""
    from nerfkit.data.scene import Scene, Views
    from nerfkit.data.synthetic import sphere_cameras

    model = gaussian_cloud()
    K = intrinsics_matrix(size, size, size / 2, size / 2)
    c2w = sphere_cameras(n_train + 2, distance=2.2, seed=3, elevation=(15.0, 45.0))
    with torch.no_grad():
        images = np.stack(
            [(splat_rgb(model, torch.as_tensor(K), torch.as_tensor(c), size) * 255).round().byte().numpy() for c in c2w]
        )
    given = c2w.copy()
    if offset is not None:
        given[view] = offset.corrected_c2w(c2w[view][None])[0]
    Ks = np.repeat(K[None].astype(np.float32), len(c2w), 0)
    split = lambda s: Views(given[s], Ks[s], size, size, images[s], [f"cloud_{i}" for i in range(len(c2w))[s]])  # noqa: E731
    colours = (255 * (0.5 + 0.28209479 * model.sh_dc[:, 0])).clamp(0, 255).byte().numpy()
    scene = Scene(
        split(slice(0, n_train)),
        split(slice(n_train, None)),
        Views.empty(size, size),
        near=1.0,
        far=3.5,
        source="synthetic:cloud",
        capture=True,
        points=model.means.numpy().copy(),
        point_colors=colours,
    )
    return scene, c2w


@pytest.mark.slow
def test_training_a_splat_capture_corrects_one_views_known_pose_error(tmp_path):
    """One of ten training views posed 1.7 degrees and 4 cm off (1.3 px at the cloud's
    centre): its learned correction, relative to the others' (a motion common to every
    camera is no correction), puts the scene's points back where the true camera sees them."""
    from nerfkit import presets
    from nerfkit.cameras import project_points
    from nerfkit.models.splat import SplatConfig
    from nerfkit.train.config import TrainConfig
    from nerfkit.train.trainer import Trainer

    offset = known_pose([0.02, -0.015, 0.015], [0.02, 0.03, -0.01])
    scene, truth = cloud_scene(offset=offset, view=3)
    cfg = TrainConfig(
        model="splat",
        out=str(tmp_path / "run"),
        steps=300,
        seed=0,
        capture="on",
        exposure_lr=0.0,
        pose_lr=3e-3,
        pose_start=50,
        eval_views=1,
        checkpoint_seconds=1e9,
    )
    # splat's training settings (presets.MODEL_TRAINING). One view per step: each view's correction
    # steps only on its ~25 visits after pose_start (ViewAdam), about pose_lr each, so 3x fast's rate
    cfg = replace(cfg, **presets.MODEL_TRAINING["splat"])
    trainer = Trainer(scene, cfg, SplatConfig(init_points=300, max_gaussians=2000), quiet=True)
    trainer.run()
    assert trainer.views is not None and trainer.views.pose is not None
    w, t = (p.detach() for p in trainer.views.pose.centred())
    others = [i for i in range(len(w)) if i != 3]
    relative = known_pose((w[3] - w[others].mean(0)).tolist(), (t[3] - t[others].mean(0)).tolist(), 1.0)
    relative.scale = trainer.views.pose.scale
    corrected = relative.corrected_c2w(scene.train.c2w[3][None])[0]
    K, points = scene.train.K[3], scene.points

    def pixels_off(c2w) -> float:
        return float(
            np.linalg.norm(project_points(K, c2w, points)[0] - project_points(K, truth[3], points)[0], axis=1).mean()
        )

    before, after = pixels_off(scene.train.c2w[3]), pixels_off(corrected)
    assert before > 1.0 and after < 0.3 * before, (before, after)


def test_the_colour_mix_keeps_float32_under_bf16_autocast():
    """Training renders under autocast; the colour correction's matrix product must not round
    the corrected colours to bf16 (8 bits of mantissa: an error of several 8-bit levels)."""
    exposure = ExposureCorrection(3, mix=True)
    with torch.no_grad():
        exposure.log_gain.normal_(0, 0.1)
        exposure.mix.normal_(0, 0.05)
    rgb = torch.rand(64, 3, generator=torch.Generator().manual_seed(0))
    view = torch.arange(64) % 3
    plain = exposure(rgb, view).detach()
    with torch.autocast("cpu", dtype=torch.bfloat16):
        under = exposure(rgb, view).detach()
    assert under.dtype == torch.float32
    torch.testing.assert_close(under, plain, atol=1e-6, rtol=0)


def test_view_corrections_are_built_for_the_parts_with_a_learning_rate():
    cpu = torch.device("cpu")
    assert build_view_corrections(4, 1.0, 0.0, 0.0, False, False, cpu) == (None, None)
    views, optimizer = build_view_corrections(4, 1.0, 0.0, 1e-3, True, False, cpu)
    assert views is not None and views.pose is None and views.exposure is not None
    assert type(optimizer) is torch.optim.Adam
    views, optimizer = build_view_corrections(4, 1.0, 1e-4, 0.0, False, True, cpu)
    assert views is not None and views.pose is not None and views.exposure is None
    assert isinstance(optimizer, ViewAdam)  # one view per step: only its rows step
