"""The splat model: training on a tiny scene, density control, resume, export (3DGS PLY and
.splat) read back, the viewer's arrays, and the commands on a splat run."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
import torch

from nerfkit import presets
from nerfkit.cli import main
from nerfkit.data.synthetic import sphere_scene
from nerfkit.errors import NerfkitError
from nerfkit.kernels import splat_reference as ref
from nerfkit.models.base import SceneBounds
from nerfkit.models.splat import (
    HULL_MARGIN,
    LR_BUDGET_POWER,
    SplatConfig,
    SplatModel,
    grow,
    outside_hull,
    visual_hull,
)
from nerfkit.output.images import render_image
from nerfkit.splat_files import Gaussians, ply_property_names, read_splat_ply
from nerfkit.train.config import TrainConfig
from nerfkit.train.optim import budget_factor, build_optimizer
from nerfkit.train.progress import RATE_STEPS
from nerfkit.train.trainer import Trainer, resume, train

SMALL = dict(init_points=1500, densify_every=20, max_gaussians=6000)


def splat_cfg(tmp_path, name="run", **kw):
    base = dict(
        data="sphere", model="splat", out=str(tmp_path / name), steps=120, seed=0, eval_views=1, checkpoint_seconds=1e9
    )
    base.update(kw)
    return presets.without_scene(TrainConfig(**base))  # splat's training settings, as train() resolves them


@pytest.fixture(scope="module")
def trained(tmp_path_factory, sphere, sphere_npz):
    """A splat run of 120 steps on the sphere scene (shared by the tests that only read it)."""
    tmp = tmp_path_factory.mktemp("splat")
    result = train(sphere, splat_cfg(tmp, data=str(sphere_npz)), SplatConfig(**SMALL), quiet=True)
    return result


@pytest.mark.slow
def test_training_rises_well_above_the_empty_render(trained, sphere):
    val = [r for r in trained.rows if r["split"] == "val"]
    empty = -10 * np.log10(np.mean((sphere.val.images.astype(np.float64) / 255) ** 2))
    assert val[0]["step"] == 0 and val[-1]["step"] == 120
    assert val[-1]["psnr"] > empty + 8.0, (empty, val)
    assert val[-1]["psnr"] > val[0]["psnr"] + 5.0, val


def small_model(sphere, **kw) -> SplatModel:
    torch.manual_seed(0)
    return SplatModel(SplatConfig(**{**SMALL, **kw}), SceneBounds.from_scene(sphere))


def test_density_control_clones_splits_prunes_and_keeps_adam_moments(sphere):
    model = small_model(sphere, init_points=100)
    opt = build_optimizer(model, 1.0)
    with torch.no_grad():
        model.log_scales[:50] = np.log(1e-3)  # small: cloned
        model.log_scales[50:] = np.log(0.5)  # large (> 1% of the scene): split
        model.opacity_logits[90:] = ref.logit(0.001)  # transparent: pruned
    model.means.sum().backward()
    opt.step()
    marker = opt.state[model.means]["exp_avg"].clone()
    want = torch.zeros(100, dtype=torch.bool)
    want[[0, 1, 2, 50, 51]] = True  # large view-space gradients
    model.grad_accum[want] = 1.0
    model.grad_count[:] = 1
    model.densify_and_prune(32, opt)
    # 100 + 3 clones + 2 x 2 split samples - 2 split originals - 10 transparent
    assert model.n_gaussians == 100 + 3 + 4 - 2 - 10
    p = model.means
    assert opt.param_groups[0]["params"][0] is p
    state = opt.state[p]["exp_avg"]
    assert state.shape == p.shape
    torch.testing.assert_close(state[:50], marker[:50])  # survivors keep their moments (first 50 unmoved)
    assert torch.all(state[-7:] == 0)  # new rows start at zero
    assert all(
        getattr(model, n).shape[0] == model.n_gaussians
        for n in ("log_scales", "quats", "sh_rest", "grad_accum", "max_radii")
    )
    split_scales = torch.exp(model.log_scales[-4:])
    torch.testing.assert_close(split_scales, torch.full_like(split_scales, 0.5 / 1.6))


def test_a_grown_grid_adds_the_six_neighbours_without_wrapping_around():
    grid = np.zeros((4, 4, 4), bool)
    grid[1, 2, 3] = True  # on the last z layer: its +z neighbour is outside the grid
    grown = grow(grid)
    assert grown.sum() == 6
    assert all(grown[i] for i in [(1, 2, 3), (0, 2, 3), (2, 2, 3), (1, 1, 3), (1, 3, 3), (1, 2, 2)])
    assert not grown[1, 2, 0]  # np.roll would have wrapped it here
    # twice: the cells within L1 distance 2 that lie in the grid
    ball = {
        (1 + dx, 2 + dy, 3 + dz)
        for dx in range(-2, 3)
        for dy in range(-2, 3)
        for dz in range(-2, 3)
        if abs(dx) + abs(dy) + abs(dz) <= 2 and all(0 <= c < 4 for c in (1 + dx, 2 + dy, 3 + dz))
    }
    assert set(map(tuple, np.argwhere(grow(grid, 2)).tolist())) == ball and len(ball) == 17
    assert grow(grid, 0).sum() == 1
    hull = {"grid": torch.as_tensor(grid), "low": np.array([-1.0, -1.0, -1.0]), "cell": 0.5}
    # cell (1, 2, 3) spans x [-0.5, 0), y [0, 0.5), z [0.5, 1)
    means = torch.tensor([[-0.25, 0.25, 0.75], [-0.25, 0.25, 0.25], [-0.25, 0.25, 1.25], [5.0, 5.0, 5.0]])
    assert outside_hull(means, hull).tolist() == [False, True, True, True]


def test_hull_prune_removes_a_floater_outside_the_objects_hull_and_nothing_inside(sphere):
    model = small_model(sphere, init_points=200)
    model.init_from_scene(sphere, torch.zeros(3))
    assert model._hull is not None
    # no point of the sphere (radius 1 at the origin) is outside
    g = torch.Generator().manual_seed(0)
    inner = torch.randn(200, 3, generator=g)
    inner = 0.9 * inner / inner.norm(dim=1, keepdim=True) * torch.rand(200, 1, generator=g)
    assert not outside_hull(inner, model._hull).any()
    # points near a camera, framed by few views: outside; the silhouettes alone keep some of them
    # (no other view carves them), and the hull start puts Gaussians there
    carved = visual_hull(sphere.train, np.zeros(3), np.zeros(3), model._hull["cell"] * 32)
    assert carved is not None
    raw = {**carved, "grid": torch.as_tensor(grow(carved["grid"], HULL_MARGIN))}
    near = torch.tensor(
        np.array([f * c2w[:3, 3] for c2w in sphere.train.c2w for f in (0.6, 0.7, 0.8)]), dtype=torch.float32
    )
    assert outside_hull(near, model._hull).all() and not outside_hull(near, raw).all()
    # the Gaussians in the sphere, a floater above it between the cameras, and one at the centre
    with torch.no_grad():
        model.means.copy_(inner)
        model.means[0] = torch.tensor([0.0, 0.0, 1.8])
        model.means[1] = torch.tensor([0.0, 0.0, 0.0])
    kept = model.means[1:].detach().clone()
    opt = build_optimizer(model, 1.0)
    model.prune_outside_hull(opt)
    assert model.n_gaussians == 199
    torch.testing.assert_close(model.means.detach(), kept)
    assert opt.param_groups[0]["params"][0] is model.means
    # a checkpoint keeps the hull; a corrupt one is refused
    back = small_model(sphere, init_points=10)
    back.load_extra_state(json.loads(json.dumps(model.extra_state())))
    assert back._hull is not None and torch.equal(back._hull["grid"], model._hull["grid"])
    assert outside_hull(kept, back._hull).tolist() == outside_hull(kept, model._hull).tolist()
    for bad in ({"shape": [8, 1], "bits": "AA==", "low": [0, 0, 0], "cell": 1.0}, {"bits": "!"}):
        with pytest.raises(NerfkitError, match="hull"):
            back.load_extra_state({**model.extra_state(), "hull": bad})
    # off, or without a hull start: no hull
    off = small_model(sphere, init_points=200, hull_prune=False)
    off.init_from_scene(sphere, torch.zeros(3))
    rand = small_model(sphere, init_points=200, init="random")
    rand.init_from_scene(sphere, torch.zeros(3))
    assert off._hull is None and rand._hull is None


def test_gradient_check_finds_a_nan_or_infinity_in_any_parameter_on_both_paths(sphere):
    for kernels in ("auto", "torch"):
        model = small_model(sphere, init_points=50, kernels=kernels)
        for p in model.parameters():
            p.grad = torch.ones_like(p)
        assert model.gradients_finite()
        for name in ("means", "sh_rest"):
            for bad in (float("nan"), float("inf")):
                grad = getattr(model, name).grad
                grad.view(-1)[7] = bad
                assert not model.gradients_finite(), (kernels, name, bad)
                grad.view(-1)[7] = 0.0
        assert model.gradients_finite()


def test_adam_of_the_gaussians_steps_as_the_unfused_one_up_to_rounding(sphere):
    model, twin = small_model(sphere, init_points=200), small_model(sphere, init_points=200)
    start = [p.detach().clone() for p in model.parameters()]
    assert all(g.get("fused") for g in model.param_groups(1.0))  # (on the CPU)
    fused = build_optimizer(model, 1.0)
    plain = torch.optim.Adam([{k: v for k, v in g.items() if k != "fused"} for g in twin.param_groups(1.0)])
    g = torch.Generator().manual_seed(0)
    for _ in range(5):
        for a, b in zip(model.parameters(), twin.parameters()):
            a.grad = torch.randn(a.shape, generator=g)
            b.grad = a.grad.clone()
        fused.step()
        plain.step()
    for a, b, s in zip(model.parameters(), twin.parameters(), start):
        assert not torch.equal(a, s)
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-6)


def test_opacity_reset_caps_opacity(sphere):
    model = small_model(sphere, init_points=50, init_opacity=0.9)
    opt = build_optimizer(model, 1.0)
    opt.state[model.opacity_logits] = {
        "exp_avg": torch.ones_like(model.opacity_logits),
        "exp_avg_sq": torch.ones_like(model.opacity_logits),
    }
    model.reset_opacity(opt)
    assert not opt.state[model.opacity_logits]["exp_avg"].any()  # its moments start again
    assert float(torch.sigmoid(model.opacity_logits.detach()).max()) <= 0.01 + 1e-6


def test_budget_factor_is_one_for_short_runs_then_falls_by_the_power_to_the_floor():
    assert budget_factor(None, 800, 0.4, 0.5) == budget_factor(800, 800, 0.4, 0.5) == 1.0
    assert budget_factor(3200, 800, 0.5, 0.1) == pytest.approx(0.5)
    assert budget_factor(10**7, 800, 0.4, 0.5) == 0.5


def test_lr_budget_scales_every_learning_rate_by_the_runs_length(tmp_path, sphere):
    cfg, model_cfg = presets.resolve(
        splat_cfg(tmp_path, steps=200), SplatConfig(**SMALL, lr_budget=50), sphere
    ).configs()
    trainer = Trainer(sphere, cfg, model_cfg, quiet=True)
    trainer.step = 40
    trainer._set_lr()
    for g in trainer.optimizer.param_groups:
        decay = g["lr_final_factor"] ** (40 / 200)
        assert g["lr"] == pytest.approx(g["initial_lr"] * decay * (50 / 200) ** LR_BUDGET_POWER)
    # a timed run: the steps its minutes buy at the rate so far, unknown (factor 1) at first
    trainer.cfg = replace(cfg, steps=0, minutes=1.0)
    trainer.train_seconds = 6.0
    assert trainer.run_steps() == pytest.approx(40 * 60 / 6)
    trainer.step = RATE_STEPS - 1
    assert trainer.run_steps() is None
    trainer._set_lr()
    g = trainer.optimizer.param_groups[1]
    assert g["lr"] == pytest.approx(g["initial_lr"] * g["lr_final_factor"] ** 0.1)


@pytest.mark.slow
@pytest.mark.parametrize("capture", ["off", "on"])
def test_resume_continues_exactly(tmp_path, sphere, capture):
    """Also a capture's run, its per-view pose and exposure corrections (poses from step 5)."""
    cfg = dict(steps=30, eval_every=15, capture=capture, pose_start=5, pose_lr=2e-3)
    # density control before and after the stop; learning rates scaled by the run's length
    model_cfg = SplatConfig(**{**SMALL, "densify_every": 5, "lr_budget": 10})
    train(sphere, splat_cfg(tmp_path, "a", **cfg), model_cfg, quiet=True)
    b_cfg, b_model_cfg = presets.resolve(splat_cfg(tmp_path, "b", **cfg), model_cfg, sphere).configs()  # as train()
    first = Trainer(sphere, b_cfg, b_model_cfg, quiet=True).run(stop_after=12)
    assert first.step == 12
    resumed = resume(tmp_path / "b", sphere, quiet=True)
    assert resumed.step == 30
    a = torch.load(tmp_path / "a" / "checkpoints" / "step_00000030.pt", weights_only=True)
    b = torch.load(tmp_path / "b" / "checkpoints" / "step_00000030.pt", weights_only=True)
    assert json.loads(a["model_extra"])["n_gaussians"] != SMALL["init_points"]  # density control acted
    assert json.loads(a["model_extra"]) == json.loads(b["model_extra"])
    for k in a["model"]:
        torch.testing.assert_close(a["model"][k], b["model"][k], rtol=1e-4, atol=1e-5)
    assert ("views" in a) == (capture == "on")
    if capture == "on":
        assert float(a["views"]["pose.rotation"].abs().max()) > 0
        for k in a["views"]:
            torch.testing.assert_close(a["views"][k], b["views"][k], rtol=1e-4, atol=1e-6)


def test_a_run_resumed_before_its_first_checkpoint_starts_from_the_scene_as_a_new_one(tmp_path, sphere):
    """Killed before its first checkpoint, a run resumes from step 0 with the Gaussians a new
    run places from the dataset, not random ones."""
    cfg = dict(steps=4, eval_views=0)
    model_cfg = SplatConfig(**{**SMALL, "init": "hull"})
    new = Trainer(sphere, splat_cfg(tmp_path, "a", **cfg), model_cfg, quiet=True)
    Trainer(sphere, splat_cfg(tmp_path, "b", **cfg), model_cfg, quiet=True)  # config.json, then killed
    assert not (tmp_path / "b" / "checkpoints").exists()
    again = Trainer(sphere, splat_cfg(tmp_path, "b", **cfg), model_cfg, resume=True, quiet=True)
    assert again.step == 0 and again.model.n_gaussians == new.model.n_gaussians
    for k, v in new.model.state_dict().items():
        torch.testing.assert_close(again.model.state_dict()[k], v)
    new.run()
    assert resume(tmp_path / "b", sphere, quiet=True).step == 4
    a = torch.load(tmp_path / "a" / "checkpoints" / "step_00000004.pt", weights_only=True)
    b = torch.load(tmp_path / "b" / "checkpoints" / "step_00000004.pt", weights_only=True)
    for k in a["model"]:
        torch.testing.assert_close(a["model"][k], b["model"][k])


def test_export_ply_has_the_3dgs_layout_and_renders_identically(trained, sphere, tmp_path):
    from plyfile import PlyData

    from nerfkit.train.checkpoint import load_run

    out = tmp_path / "g.ply"
    assert main(["export", str(trained.run_dir), "--splat", str(out)]) == 0
    model, info, _ = load_run(trained.run_dir)
    ply = PlyData.read(str(out))
    v = ply["vertex"]
    assert [p.name for p in v.properties] == ply_property_names(15)
    assert ply_property_names(15)[:9] == ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    assert ply_property_names(15)[-8:] == [
        "opacity",
        "scale_0",
        "scale_1",
        "scale_2",
        "rot_0",
        "rot_1",
        "rot_2",
        "rot_3",
    ]
    assert all(p.val_dtype in ("f4", "float32") for p in v.properties) and not ply.text
    n = model.n_gaussians
    assert len(v.data) == n
    # raw values: log-scale, logit opacity, quaternion w first, DC = (rgb - 0.5) / C0, f_rest channel-major
    np.testing.assert_array_equal(v["scale_1"], model.log_scales[:, 1].detach().numpy())
    np.testing.assert_array_equal(v["opacity"], model.opacity_logits.detach().numpy())
    np.testing.assert_array_equal(v["rot_0"], model.quats[:, 0].detach().numpy())
    np.testing.assert_array_equal(v["f_dc_2"], model.sh_dc[:, 0, 2].detach().numpy())
    np.testing.assert_array_equal(v["f_rest_15"], model.sh_rest[:, 0, 1].detach().numpy())  # green, degree 1
    np.testing.assert_array_equal(v["f_rest_1"], model.sh_rest[:, 1, 0].detach().numpy())  # red, 2nd coefficient
    # read back into a fresh model: the same image
    fresh = SplatModel(info.model_config, info.bounds)
    fresh.set_gaussians(read_splat_ply(out))
    fresh.active_degree = model.active_degree
    bg = torch.zeros(3)
    a = render_image(model, sphere.val.K[0], sphere.val.c2w[0], 32, 32, bg)
    b = render_image(fresh, sphere.val.K[0], sphere.val.c2w[0], 32, 32, bg)
    np.testing.assert_array_equal(a.rgb, b.rgb)
    assert float(a.acc.max()) > 0.9


def test_a_splat_file_holds_the_sh_degree_the_run_trained_and_reads_back_the_same_image(sphere, tmp_path):
    """A degree-1 model's file has 3 higher coefficients per channel (not degree 3's 15, all
    zero), and installed in a fresh model it renders the same image."""
    from nerfkit.splat_files import write_splat_ply

    model = small_model(sphere, sh_degree=1)
    with torch.no_grad():
        model.sh_rest.normal_(0, 0.1)  # (degree 3's 15 coefficients held; the run uses 3)
    model.active_degree = 1
    g = Gaussians.from_model(model)
    assert g.sh_rest.shape[1:] == (3, 3) and g.sh_degree == 1
    write_splat_ply(tmp_path / "g.ply", g)
    back = read_splat_ply(tmp_path / "g.ply")
    assert back.sh_degree == 1
    fresh = small_model(sphere, sh_degree=1)
    fresh.set_gaussians(back)
    bg = torch.zeros(3)
    a = render_image(model, sphere.val.K[0], sphere.val.c2w[0], 24, 24, bg)
    b = render_image(fresh, sphere.val.K[0], sphere.val.c2w[0], 24, 24, bg)
    np.testing.assert_allclose(a.rgb, b.rgb, atol=1e-6)


def test_a_zero_quaternion_read_from_a_file_is_no_rotation(sphere):
    """Some tools write (0, 0, 0, 0) for a Gaussian without rotation: it renders as the identity
    would, not as NaN (or a division by zero in the compiled kernel)."""
    model = small_model(sphere)
    g = Gaussians.from_model(model)
    g.quats[:5] = 0.0
    model.set_gaussians(g)
    torch.testing.assert_close(model.quats[:5], torch.tensor([[1.0, 0.0, 0.0, 0.0]]).expand(5, 4))
    out = render_image(model, sphere.val.K[0], sphere.val.c2w[0], 16, 16, torch.zeros(3))
    assert np.isfinite(out.rgb).all()


@pytest.mark.parametrize("kernels", ["numba", "torch"])
def test_a_dataset_with_near_zero_renders_gaussians_at_and_behind_the_camera(sphere, kernels):
    """near = 0 is a valid dataset; the projection's near plane must stay above 0, or a
    Gaussian at the camera divides by zero (compiled) or turns the loss to NaN (torch)."""
    bounds = replace(SceneBounds.from_scene(sphere), near=0.0)
    torch.manual_seed(0)
    model = SplatModel(SplatConfig(**{**SMALL, "kernels": kernels}), bounds)
    assert model.near_plane > 0
    c2w = torch.as_tensor(sphere.val.c2w[0], dtype=torch.float32)
    with torch.no_grad():  # one Gaussian at the camera, one just behind it
        model.means[0] = c2w[:3, 3]
        model.means[1] = c2w[:3, 3] + 0.1 * c2w[:3, 2]
    out = model.render_view(sphere.val.K[0], sphere.val.c2w[0], 16, 16, torch.zeros(3))
    out.rgb.sum().backward()
    assert torch.isfinite(out.rgb).all()
    assert all(torch.isfinite(p.grad).all() for p in (model.means, model.log_scales, model.quats) if p.grad is not None)


def test_dot_splat_is_32_bytes_a_gaussian(trained, tmp_path):
    from nerfkit.train.checkpoint import load_run

    out = tmp_path / "g.splat"
    assert main(["export", str(trained.run_dir), "--splat", str(out)]) == 0
    model = load_run(trained.run_dir)[0]
    raw = out.read_bytes()
    assert len(raw) == 32 * model.n_gaussians
    rec = np.frombuffer(raw, dtype=[("pos", "<f4", 3), ("scale", "<f4", 3), ("rgba", "u1", 4), ("rot", "u1", 4)])
    first = int(
        np.argmax(
            torch.exp(model.log_scales.sum(1)).detach().numpy() * torch.sigmoid(model.opacity_logits).detach().numpy()
        )
    )
    np.testing.assert_allclose(rec["pos"][0], model.means[first].detach().numpy())
    np.testing.assert_allclose(rec["scale"][0], torch.exp(model.log_scales[first]).detach().numpy(), rtol=1e-6)


def test_dc_colour_conversions_invert_each_other_and_match_the_kernels():
    from nerfkit.kernels.reference import SH_C0 as KERNEL_C0
    from nerfkit.splat_files import SH_C0, dc_to_rgb, rgb_to_dc

    assert SH_C0 == KERNEL_C0 == pytest.approx(0.5 / np.sqrt(np.pi), rel=1e-15)  # Y_00 = 1 / (2 sqrt(pi))
    rgb = np.random.default_rng(0).random((7, 3))
    assert rgb_to_dc(rgb).shape == (7, 1, 3)
    np.testing.assert_allclose(dc_to_rgb(rgb_to_dc(rgb)), rgb, atol=1e-15)
    np.testing.assert_array_equal(dc_to_rgb(np.zeros((2, 1, 3))), np.full((2, 3), 0.5))  # DC 0 is mid-grey


def test_export_refuses_a_non_splat_target_and_existing_files(trained, tmp_path, capsys):
    assert main(["export", str(trained.run_dir), "--splat", str(tmp_path / "g.txt")]) != 0
    assert "should end in .ply or .splat" in capsys.readouterr().err
    out = tmp_path / "g.ply"
    out.write_text("mine")
    assert main(["export", str(trained.run_dir), "--splat", str(out)]) != 0
    assert "--force" in capsys.readouterr().err
    assert out.read_text() == "mine"


def test_viewer_arrays_match_scales_and_rotations(trained):
    from nerfkit.train.checkpoint import load_run
    from nerfkit.viz.splats import splat_arrays

    model = load_run(trained.run_dir)[0]
    arr = splat_arrays(Gaussians.from_model(model))
    cov = arr["covariances"].astype(np.float64)
    np.testing.assert_allclose(cov, cov.transpose(0, 2, 1), atol=1e-12)
    eig = np.linalg.eigvalsh(cov)
    want = np.sort(np.exp(2 * model.log_scales.detach().double().numpy()), axis=1)
    np.testing.assert_allclose(eig, want, rtol=2e-3, atol=1e-9)
    torch.testing.assert_close(
        torch.as_tensor(cov),
        ref.covariance_3d(model.log_scales.detach().double(), model.quats.detach().double()),
        rtol=1e-5,
        atol=1e-9,
    )
    assert arr["opacities"].shape == (model.n_gaussians, 1) and arr["rgbs"].min() >= 0 and arr["rgbs"].max() <= 1


def test_depth_of_the_sphere_lies_between_near_and_far(trained, sphere):
    from nerfkit.train.checkpoint import load_run

    model = load_run(trained.run_dir)[0]
    view = render_image(model, sphere.val.K[0], sphere.val.c2w[0], 32, 32, torch.zeros(3))
    hit = view.acc > 0.9
    assert hit.sum() > 50
    cam = np.linalg.norm(sphere.val.c2w[0][:3, 3])
    # the unit sphere's front lies cam - 1 to sqrt(cam^2 - 1) along the rays; a 120-step splat is
    # fuzzy at the silhouette, where its depth blends in some of the back
    front = view.depth[hit]
    assert cam - 1 - 0.05 < np.median(front) < np.sqrt(cam**2 - 1)
    assert np.all(front > cam - 1.5) and np.all(front < cam + 0.25)


def test_cli_eval_and_render_a_splat_run(trained, sphere, capsys, tmp_path):
    import imageio.v3 as iio

    assert main(["eval", str(trained.run_dir)]) == 0
    scores = json.loads((trained.run_dir / "eval_val.json").read_text())
    empty = -10 * np.log10(np.mean((sphere.val.images.astype(np.float64) / 255) ** 2))
    assert scores["n_images"] == 2 and scores["psnr"] > empty + 8.0  # both val views, as training scored one
    assert main(["render", str(trained.run_dir), "--path", "orbit", "--frames", "3", "--out", str(tmp_path / "v")]) == 0
    frames = iio.imread(tmp_path / "v" / "orbit.mp4")
    assert frames.shape[0] == 3 and frames.std() > 5  # the sphere, not a blank frame
    assert len(iio.imread(tmp_path / "v" / "depth.mp4")) == 3


@pytest.mark.slow
def test_capture_mode_learns_the_background_exposure_and_poses(tmp_path):
    """A coloured backdrop behind the sphere: the learned background, which starts grey,
    takes its colour where the cameras see it."""
    colour = np.array([200, 60, 100], np.uint8)
    grey = sphere_scene(n_train=12, n_val=2, size=32)
    for split in (grey.train, grey.val):
        split.images[(split.images == 0).all(-1)] = colour
    cfg = splat_cfg(tmp_path, steps=150, capture="on", eval_views=1, pose_lr=2e-3)  # (the preset: off)
    trainer = Trainer(grey, cfg, *_capture(grey), quiet=True)
    assert trainer.model.bg_coef is not None
    assert trainer.views is not None and trainer.views.pose is not None and trainer.views.exposure is not None
    v = grey.val
    with torch.no_grad():
        before = trainer.model._background_image(
            torch.from_numpy(v.K[0]), torch.from_numpy(v.c2w[0]), 32, 32, torch.zeros(3)
        )
    trainer.run()
    with torch.no_grad():
        after = trainer.model._background_image(
            torch.from_numpy(v.K[0]), torch.from_numpy(v.c2w[0]), 32, 32, torch.zeros(3)
        )
    backdrop = torch.from_numpy((v.images[0] == colour).all(-1))
    target = torch.from_numpy(colour / 255.0).float()
    assert (before[backdrop].mean(0) - target).abs().max() > 0.25  # the grey it starts from
    torch.testing.assert_close(after[backdrop].mean(0), target, atol=0.05, rtol=0)
    assert float(trainer.views.exposure.log_gain.detach().abs().max()) > 0
    assert float(trainer.views.pose.rotation.detach().abs().max()) > 0  # (from --pose-start on)


def _capture(sphere):
    from nerfkit import presets

    train_cfg = TrainConfig(model="splat", steps=15, capture="on")
    cfg, model_cfg = presets.resolve(train_cfg, SplatConfig(**SMALL), sphere).configs()
    return (model_cfg,)


def test_live_viewer_draws_the_splats_and_renders_a_splat_run(trained, sphere, monkeypatch):
    from nerfkit.commands import live
    from nerfkit.train.checkpoint import load_run

    watcher = live.RunWatcher(trained.run_dir, load_run)
    viewer = live.LiveViewer(watcher, None, host="127.0.0.1", port=0, max_side=32, watch=True)
    drawn = []
    real = viewer.server.scene.add_gaussian_splats
    monkeypatch.setattr(
        viewer.server.scene, "add_gaussian_splats", lambda name, **kw: drawn.append(kw) or real(name, **kw)
    )
    try:
        viewer.step()  # loads the run and draws its Gaussians
        assert len(drawn) == 1 and drawn[0]["centers"].shape == (watcher.current.model.n_gaussians, 3)
        c2w = sphere.val.c2w[0]
        img = viewer.render_for(live.matrix_to_quat(c2w[:3, :3]), c2w[:3, 3], np.radians(40), 1.0, 32, "RGB")
        assert img.shape == (32, 32, 3) and img[12:20, 12:20].mean() > 40  # the sphere, not the black background
    finally:
        viewer.server.stop()


@pytest.mark.slow
def test_eval_of_a_capture_splat_run_fits_each_held_out_views_pose(tmp_path, sphere, sphere_npz, capsys):
    """Splats render whole views, and ``eval`` fits each held-out view's pose from whole
    renders as it does a ray model's: the fitted score is written beside the rendered one."""
    (model_cfg,) = _capture(sphere)
    cfg = splat_cfg(tmp_path, data=str(sphere_npz), steps=15, capture="on", pose_lr=2e-3, pose_start=5)
    run = train(sphere, cfg, model_cfg, quiet=True)
    corrections = json.loads((run.run_dir / "view_corrections.json").read_text())["views"]
    assert len(corrections) == len(sphere.train) and "rotation_deg" in corrections[0]
    capsys.readouterr()
    assert main(["eval", str(run.run_dir), "--fit-views", "5"]) == 0
    assert "with each view's pose fitted" in capsys.readouterr().out
    result = json.loads((run.run_dir / "eval_val.json").read_text())
    assert result["psnr"] > 10 and "5 steps" in result["fitted"]["what"]
    assert all(v["psnr_fitted"] is not None and v["fitted_rotation_deg"] >= 0 for v in result["per_image"])


def test_viewer_arrays_rotate_by_the_quaternion():
    """A quarter turn about z swaps the x and y spreads; a zero quaternion is no rotation."""
    from nerfkit.viz.splats import splat_arrays

    s = np.log([[0.1, 0.2, 0.3]] * 3)
    half = np.sqrt(0.5)
    quats = np.array([[1, 0, 0, 0], [half, 0, 0, half], [0, 0, 0, 0]], np.float32)
    g = Gaussians(np.zeros((3, 3)), s, quats, np.zeros(3), np.zeros((3, 1, 3)), np.zeros((3, 0, 3)))
    cov = splat_arrays(g)["covariances"]
    np.testing.assert_allclose(cov[0], np.diag([0.01, 0.04, 0.09]), atol=1e-7)
    np.testing.assert_allclose(cov[1], np.diag([0.04, 0.01, 0.09]), atol=1e-7)
    np.testing.assert_allclose(cov[2], cov[0], atol=1e-7)


def test_the_depth_of_a_flat_wall_is_along_each_ray_and_its_exported_points_lie_on_it(sphere):
    # a wall of small opaque Gaussians 2 units in front of a camera at the origin (OpenCV axes):
    # a pixel's depth is its ray's length to the wall, 2 / cos(angle), and the points export
    # puts back on the wall (the rasterizer weighs camera z: 2 everywhere)
    from nerfkit.export import depth_to_points
    from nerfkit.splat_files import Gaussians

    model = small_model(sphere).eval()
    xs = np.linspace(-1.2, 1.2, 97, dtype=np.float32)
    x, y = np.meshgrid(xs, xs)
    n = x.size
    means = np.stack([x.ravel(), y.ravel(), np.full(n, 2.0, np.float32)], 1)
    model.set_gaussians(
        Gaussians(
            means,
            np.full((n, 3), np.log(0.02), np.float32),
            np.tile(np.array([1, 0, 0, 0], np.float32), (n, 1)),
            np.full(n, 6.0, np.float32),
            np.full((n, 1, 3), 1.0, np.float32),
            np.zeros((n, 0, 3), np.float32),
        )
    )
    K, c2w = np.array([[40.0, 0, 24], [0, 40.0, 24], [0, 0, 1]]), np.eye(4)
    with torch.no_grad():
        out = model.render_view(K, c2w, 48, 48, torch.zeros(3))
    acc, depth = out.acc.numpy(), out.depth.numpy()
    hit = acc > 0.99
    assert hit.sum() > 1500
    u, v = np.meshgrid(np.arange(48) + 0.5, np.arange(48) + 0.5)
    length = np.sqrt(1 + ((u - 24) / 40) ** 2 + ((v - 24) / 40) ** 2)
    np.testing.assert_allclose(depth[hit] / acc[hit], 2.0 * length[hit], rtol=2e-3)
    pts, _ = depth_to_points(out.rgb.numpy(), depth / np.maximum(acc, 1e-6), acc, K, c2w, acc_min=0.99)
    np.testing.assert_allclose(pts[:, 2], 2.0, atol=5e-3)
