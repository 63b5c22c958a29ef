"""The ``fast`` model: interface, training on a tiny generated scene, growth, checkpoints."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from conftest import train_loop
from nerfkit.cameras import Rays
from nerfkit.data.rays import RaysData
from nerfkit.data.synthetic import sphere_scene
from nerfkit.kernels import numba_kernels
from nerfkit.models import build_model
from nerfkit.models.base import SceneBounds
from nerfkit.models.fast import FastConfig, FastNeRF
from nerfkit.output.images import render_image
from nerfkit.render.box import GridBox
from nerfkit.train.optim import build_optimizer

# small stages so that a test trains in seconds: 24^3, then 48^3 at step 40
SMALL = dict(resolutions="24,48", upsample_steps="40")


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    return float(-10 * np.log10(np.mean((a - b) ** 2)))


def val_psnr(model, scene, background=(0.0, 0.0, 0.0)) -> float:
    bg = torch.tensor(background)
    scores = []
    for i in range(len(scene.val)):
        view = render_image(model, scene.val.K[i], scene.val.c2w[i], scene.val.width, scene.val.height, bg)
        scores.append(psnr(view.rgb, scene.val.images[i] / 255.0))
    return float(np.mean(scores))


@pytest.fixture(scope="module")
def scene():
    return sphere_scene(n_train=20, n_val=3, size=32)


@pytest.fixture(scope="module")
def trained(scene):
    model = FastNeRF(FastConfig(**SMALL), SceneBounds.from_scene(scene))
    train_loop(model, scene, 100)
    return model


def test_registry_builds_fast_model(scene):
    model = build_model("fast", FastConfig(**SMALL), SceneBounds.from_scene(scene))
    assert isinstance(model, FastNeRF)


def test_render_rays_and_query_shapes(scene):
    model = FastNeRF(FastConfig(**SMALL), SceneBounds.from_scene(scene))
    n = 64
    d = torch.nn.functional.normalize(torch.randn(n, 3), dim=-1)
    out = model.render_rays(Rays(-4 * d, d), torch.zeros(3), perturb=True)
    assert out.rgb.shape == (n, 3) and out.depth.shape == (n,) and out.acc.shape == (n,)
    assert out.n_samples == int(out.extras["samples_per_ray"].sum()) > 0
    # at init the field is nearly empty: a ray keeps almost all of the background
    assert out.acc.max() < 0.05
    pts = torch.tensor([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0]])
    sigma, rgb = model.query(pts, torch.tensor([[0.0, 0.0, 1.0]] * 2))
    assert sigma.shape == (2,) and rgb.shape == (2, 3)
    assert sigma[1] == 0  # outside the box there is nothing
    torch.testing.assert_close(model.density(pts), sigma)


@pytest.mark.slow
def test_short_training_reconstructs_held_out_views(scene, trained):
    """100 steps of 1024 rays: a model that learned nothing scores ~10 dB (the mean colour
    scores 10.2 dB on these views); the fast model must clearly reconstruct the sphere."""
    score = val_psnr(trained, scene)
    mean_colour = scene.train.images.reshape(-1, 3).mean(0) / 255.0
    baseline = np.mean([psnr(mean_colour[None, None], scene.val.images[i] / 255.0) for i in range(len(scene.val))])
    assert score > 22.0, score
    assert score > baseline + 10.0
    # and empty-space skipping is active: far fewer samples than the lattice holds
    assert trained.occupied_fraction < 0.3


def test_rendering_changes_nothing_in_the_model_and_a_schedule_remembers_surfaces(scene):
    """``render_rays`` is pure (even in training, with perturbed samples); where opaque
    rays ended is recorded by the after-step job, from the step's rays and output."""
    from nerfkit.models.base import StepState, run_schedules

    model = FastNeRF(FastConfig(**SMALL), SceneBounds.from_scene(scene))
    train_loop(model, scene, 30)
    before = {k: v.clone() for k, v in model.state_dict().items()}
    batch = RaysData(scene.train, "cpu", seed=1).sample(1024)
    out = model.render_rays(batch.rays, torch.zeros(3), perturb=True)
    for k, v in model.state_dict().items():
        assert torch.equal(v, before[k]), k
    # the job stores the expected end points of the opaque rays: inside the unit sphere
    n0 = int(model.surfaces.count)
    opaque = out.acc > 0.5
    run_schedules(
        [j for j in model.schedules() if j.name == "remember surfaces"],
        StepState(30, 0.3, None, batch.rays, out),
        phase="after_step",
    )
    assert int(model.surfaces.count) == n0 + int(opaque.sum()) > n0
    new = model.surfaces.pts[n0 : int(model.surfaces.count)]
    o, d = batch.rays.origins[opaque], batch.rays.directions[opaque]
    torch.testing.assert_close(new, o + d * (out.depth / out.acc)[opaque].unsqueeze(-1))
    assert new.norm(dim=-1).max() < 1.1


def test_growth_shrinks_the_box_around_the_object(scene, trained):
    lo, hi = trained.field.geom.lo.numpy(), trained.field.geom.hi.numpy()
    assert trained.field.geom.res == tuple(int(r) for r in trained.field.geom.res) and trained.stage == 1
    assert np.all(lo <= -0.95) and np.all(hi >= 0.95)  # the unit sphere is inside
    assert np.all(hi - lo < 3.2)  # the scene bounds' box was [-2, 2]^3
    # the grid holds about 48^3 vertices with cubic voxels
    assert 0.8 * 48**3 < np.prod(trained.field.geom.res) < 1.3 * 48**3


@pytest.mark.slow
def test_sparse_growth_stores_the_vertices_near_the_object_and_renders_as_well(scene):
    """The same training with the 48^3 stage sparse: it stores a fraction of the vertices,
    the rest share one empty row that training never changes, and the views score as the
    dense grid's do."""
    late = dict(resolutions="24,48", upsample_steps="70", sparse_margin=1)
    dense = FastNeRF(FastConfig(**late), SceneBounds.from_scene(scene))
    sparse = FastNeRF(FastConfig(**late, sparse_from=40), SceneBounds.from_scene(scene))
    train_loop(dense, scene, 100)
    train_loop(sparse, scene, 100)
    assert sparse.field.geom.res == dense.field.geom.res and dense.field.stored_vertices == dense.field.geom.n_vertices
    assert sparse.field.stored_vertices < 0.6 * sparse.field.geom.n_vertices
    from nerfkit.models.fast import EMPTY_RAW

    shared = sparse.field.grid[0]
    assert shared[0] == EMPTY_RAW and torch.all(shared[1:] == 0)  # the shared row is untouched
    # every occupied cell has all its corners stored
    from nerfkit.models.packing import vertices_touching

    assert torch.all(sparse.field.vertex_rows[vertices_touching(sparse.estimator.occ)] > 0)
    assert abs(val_psnr(sparse, scene) - val_psnr(dense, scene)) < 0.5
    # vertices without storage hold no density
    empty = torch.nonzero(sparse.field.vertex_rows == 0)[:, 0]
    assert float(sparse.density(sparse.field.geom.vertex_positions(empty)).detach().max()) < 1e-9


def test_a_growth_in_the_last_steps_of_a_run_is_skipped_and_caught_up_on_resume(scene):
    """A growth due at step 40 runs when a fifth of the run is left, not when the run is
    all but over (the finer grid would have no steps to recover); a resumed run with a
    longer budget catches up on it."""
    from nerfkit.models.base import StepState, run_schedules

    jobs = lambda m: m.schedules()  # noqa: E731
    for progress, grows in ((0.8, True), (0.9, True), (0.96, False), (1.0, False)):
        model = FastNeRF(FastConfig(**SMALL), SceneBounds.from_scene(scene))
        run_schedules(jobs(model), StepState(40, progress), phase="before_step")
        assert model.stage == int(grows), progress
    model = FastNeRF(FastConfig(**SMALL), SceneBounds.from_scene(scene))
    run_schedules(jobs(model), StepState(40, 0.99), phase="before_step")
    run_schedules(jobs(model), StepState(41, 0.5), phase="before_step")
    assert model.stage == 1


def test_photos_with_finer_detail_get_a_fifth_grid_stage_unless_the_stages_are_given():
    """An object scene photographed at 400x400 grows on to 256 vertices; at 200x200, on a
    capture, on a forward-facing scene, or with the stages given, the stages are as set."""
    from dataclasses import replace

    from nerfkit import presets
    from nerfkit.data.synthetic import forward_facing_scene, sphere_scene
    from nerfkit.models.fast_config import BASE_STAGES, FINE_STAGES
    from nerfkit.train.config import TrainConfig

    def sized(scene, size):
        return replace(scene, train=replace(scene.train, width=size, height=size, images=None))

    def stages(scene, model=FastConfig(), capture="auto"):
        m = presets.resolve(TrainConfig(capture=capture), model, scene).configs()[1]
        return m.resolutions, m.upsample_steps

    sphere = sphere_scene(n_train=6, size=8)
    assert (
        stages(sized(sphere, 400)) == FINE_STAGES
        and FastConfig(resolutions=FINE_STAGES[0], upsample_steps=FINE_STAGES[1]).stages()[0][-1] == 256
    )
    assert stages(sized(sphere, 200)) == BASE_STAGES
    assert stages(sized(sphere, 400), capture="on") == BASE_STAGES
    assert stages(sized(forward_facing_scene(n_train=6, n_val=0, size=8), 400)) == BASE_STAGES
    assert stages(sized(sphere, 400), FastConfig(resolutions="16,32")) == (
        "16,32",
        BASE_STAGES[1],
    )  # (the default, no unset sentinel)
    assert FastConfig(resolutions="16,32").stages() == ([16, 32], [60])  # unset steps: the base's


def test_a_vertex_index_outside_the_grid_is_refused_before_the_kernels_see_it(scene, trained):
    state = {k: v.clone() for k, v in trained.state_dict().items()}
    state["field.vertex_rows"][7] = trained.field.grid.shape[0]  # one past the last row
    fresh = FastNeRF(FastConfig(**SMALL), SceneBounds.from_scene(scene))
    fresh.load_extra_state(trained.extra_state())
    with pytest.raises(ValueError, match="outside the grid"):
        fresh.load_state_dict(state)


def test_a_grid_of_another_sh_degree_is_refused_not_taken_for_fewer_rows(scene, trained):
    other = FastNeRF(FastConfig(**{**SMALL, "sh_degree": trained.config.sh_degree + 1}), SceneBounds.from_scene(scene))
    other.load_extra_state(trained.extra_state())
    with pytest.raises(RuntimeError, match="channels a vertex"):
        other.load_state_dict(trained.state_dict())


def test_fit_grid_covers_the_box_with_cubic_voxels():
    box = GridBox.fit(np.array([-1.0, -2.0, 0.0]), np.array([1.0, 2.0, 0.5]), 40)
    lo, voxel, res = box.lo_array, box.voxel, box.res
    hi = lo + voxel * (np.array(res) - 1)
    assert np.allclose(box.hi_array, hi) and box.cell_shape == (res[2] - 1, res[1] - 1, res[0] - 1)
    assert np.all(lo <= [-1.0, -2.0, 0.0]) and np.all(hi >= [1.0, 2.0, 0.5])
    assert 0.8 * 40**3 < np.prod(res) < 1.3 * 40**3


def test_checkpoint_round_trip_after_growth(scene, trained):
    fresh = FastNeRF(FastConfig(**SMALL), SceneBounds.from_scene(scene))
    fresh.load_extra_state(trained.extra_state())
    fresh.load_state_dict(trained.state_dict())
    assert fresh.field.geom.res == trained.field.geom.res
    assert torch.equal(fresh.estimator.occ, trained.estimator.occ)
    d = torch.nn.functional.normalize(torch.randn(200, 3, generator=torch.Generator().manual_seed(0)), dim=-1)
    rays = Rays(-4 * d, d)
    with torch.no_grad():
        a = trained.render_rays(rays, torch.zeros(3), perturb=False)
        b = fresh.render_rays(rays, torch.zeros(3), perturb=False)
    assert torch.equal(a.rgb, b.rgb)


@pytest.mark.skipif(numba_kernels() is None, reason="numba not available")
def test_torch_path_trains_like_the_compiled_path(scene):
    """The pure-torch path (used on CUDA) follows the compiled one step for step,
    through occupancy refreshes and a growth of the grid."""
    cfg = dict(resolutions="12,20", upsample_steps="6", occ_start=4, occ_every=4, sparse_from=16, sparse_margin=0)
    models = {}
    for kernels in ("numba", "torch"):
        model = FastNeRF(FastConfig(kernels=kernels, **cfg), SceneBounds.from_scene(scene))
        train_loop(model, scene, 10, batch=256)
        models[kernels] = model
    a, b = models["numba"], models["torch"]
    assert a.field.geom.res == b.field.geom.res
    assert a.field.stored_vertices == b.field.stored_vertices < a.field.geom.n_vertices  # sparse
    torch.testing.assert_close(a.field.grid.detach(), b.field.grid.detach(), atol=2e-4, rtol=1e-3)
    assert torch.equal(a.estimator.occ, b.estimator.occ)


def test_learned_background_recovers_a_grey_backdrop():
    grey = sphere_scene(n_train=12, n_val=2, size=24)
    for split in (grey.train, grey.val):
        black = (split.images == 0).all(-1)
        split.images[black] = 128
    model = FastNeRF(FastConfig(learn_background=True, **SMALL), SceneBounds.from_scene(grey))
    train_loop(model, grey, 50, batch=512)
    # rays that miss the box see only the learned background
    d = torch.nn.functional.normalize(torch.randn(100, 3, generator=torch.Generator().manual_seed(1)), dim=-1)
    with torch.no_grad():
        out = model.render_rays(Rays(torch.full((100, 3), 50.0), d), torch.zeros(3), perturb=False)
    seen = d[:, 2] < 0  # directions of the training rays' backdrop (cameras sit above the sphere)
    assert out.acc.max() == 0
    torch.testing.assert_close(out.rgb[seen].mean(0), torch.full((3,), 128 / 255), atol=0.05, rtol=0)
    assert val_psnr(model, grey) > 18.0


@pytest.mark.slow
def test_trainer_runs_fast_model_and_resumes_exactly(tmp_path, scene):
    from nerfkit import presets
    from nerfkit.train.config import TrainConfig
    from nerfkit.train.trainer import Trainer, resume

    cfg = FastConfig(resolutions="16,24", upsample_steps="20", occ_start=8, occ_every=8)

    def tc(name):
        return presets.without_scene(
            TrainConfig(
                data="sphere",
                model="fast",
                out=str(tmp_path / name),
                steps=40,
                batch_rays=256,
                seed=0,
                eval_views=1,
                checkpoint_seconds=1e9,
            )
        )

    Trainer(scene, tc("a"), cfg, quiet=True).run()
    first = Trainer(scene, tc("b"), cfg, quiet=True).run(stop_after=25)  # after the growth
    assert first.step == 25
    resumed = resume(tmp_path / "b", scene, quiet=True)
    assert resumed.step == 40
    a = torch.load(tmp_path / "a" / "checkpoints" / "step_00000040.pt", weights_only=True)
    b = torch.load(tmp_path / "b" / "checkpoints" / "step_00000040.pt", weights_only=True)
    for k in a["model"]:
        torch.testing.assert_close(a["model"][k], b["model"][k], rtol=1e-4, atol=1e-5)


def test_each_stage_trains_on_its_multiple_of_the_batch(tmp_path, scene):
    from nerfkit import presets
    from nerfkit.train.config import TrainConfig
    from nerfkit.train.trainer import Trainer

    cfg = FastConfig(resolutions="16,20,24", upsample_steps="10,20", stage_rays="1,3", occ_start=8, occ_every=8)
    tc = presets.without_scene(
        TrainConfig(
            data="sphere",
            model="fast",
            out=str(tmp_path / "run"),
            steps=30,
            batch_rays=64,
            seed=0,
            eval_views=1,
            checkpoint_seconds=1e9,
        )
    )
    rows = Trainer(scene, tc, cfg, quiet=True).run().rows
    # a row at step s holds step s - 1: the first stage's, then the second's, then the last factor again
    assert [r["rays"] for r in rows if r["split"] == "train"] == [64, 192, 192]


@pytest.mark.parametrize("text", ["0,1", "a", "", "1,,x", "1,1000"])
def test_bad_stage_rays_are_refused_in_one_line(text):
    from nerfkit.errors import NerfkitError

    with pytest.raises(NerfkitError, match="--stage-rays") as e:
        FastConfig(stage_rays=text).stage_ray_factors()
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("kernels", ["numba", "torch"])
def test_a_non_finite_grid_gradient_is_refused_and_counted(scene, kernels):
    # The compiled path keeps the grid gradient in a sink, not in .grad: the optimizer itself
    # must refuse a NaN there (and say so), or Adam would write it into the grid.
    if kernels == "numba" and numba_kernels() is None:
        pytest.skip("numba is not installed")
    model = FastNeRF(FastConfig(kernels=kernels, **SMALL), SceneBounds.from_scene(scene))
    opt = build_optimizer(model, 0.1)
    batch = RaysData(scene.train, "cpu", seed=0).sample(256)
    model.render_rays(batch.rays, torch.zeros(3), perturb=True).rgb.sum().backward()
    before = model.field.grid.detach().clone()
    if model.field.grid.grad is not None:  # torch path: a dense .grad
        touched = torch.nonzero(model.field.grid.grad.abs().sum(1)).squeeze(1)
        model.field.grid.grad[touched[0], 0] = float("nan")
    else:
        touched = torch.nonzero(model.field.sink.touched).squeeze(1)
        model.field.sink.grad[-1, touched[0], 1] = float("inf")
    opt.step()
    assert opt.nonfinite_rows == 1
    after = model.field.grid.detach()
    assert torch.isfinite(after).all()
    assert torch.equal(after[touched[0]], before[touched[0]])  # the bad row is left as it was
    assert not torch.equal(after[touched[1:]], before[touched[1:]])  # the others are updated
    model.render_rays(batch.rays, torch.zeros(3), perturb=True).rgb.sum().backward()
    opt.step()
    assert opt.nonfinite_rows == 0


def density_variation(model, channels=(0,)) -> float:
    """Mean over pairs of neighbouring stored vertices of the squared difference of the
    grid's ``channels`` (default: the raw density), summed over the channels."""
    rx, ry, rz = model.field.geom.res
    rows = model.field.vertex_rows.long().reshape(rz, ry, rx)
    raw = model.field.grid.detach()[:, list(channels)]
    total, pairs = 0.0, 0
    for dim in range(3):
        a, b = rows.narrow(dim, 0, rows.shape[dim] - 1), rows.narrow(dim, 1, rows.shape[dim] - 1)
        both = (a > 0) & (b > 0)
        total += float(((raw[a[both]] - raw[b[both]]) ** 2).sum())
        pairs += int(both.sum())
    return total / pairs


@pytest.mark.slow
def test_total_variation_smooths_the_density_and_keeps_the_views(scene, trained):
    """The same training with ``--tv-weight``: the density varies clearly less between
    neighbouring vertices, and the held-out views are still reconstructed."""
    smooth = FastNeRF(FastConfig(**SMALL, tv_weight=1e-7), SceneBounds.from_scene(scene))
    train_loop(smooth, scene, 100)
    plain = density_variation(trained)
    assert density_variation(smooth) < 0.5 * plain, (density_variation(smooth), plain)
    assert val_psnr(smooth, scene) > 22.0


@pytest.mark.parametrize("degree", [0, 1, 2])
def test_the_view_dependent_colours_total_variation_weighs_only_the_harmonics_above_degree_0(scene, degree):
    m = FastNeRF(
        FastConfig(**SMALL, sh_degree=degree, tv_weight=2.0, tv_colour=0.5, tv_view_weight=3.0),
        SceneBounds.from_scene(scene),
    )
    K = (degree + 1) ** 2
    expect = [2.0] + [1.0 + (3.0 if k > 0 else 0.0) for _ in range(3) for k in range(K)]
    assert m.tv.weights.tolist() == expect
    assert not FastNeRF(FastConfig(**SMALL), SceneBounds.from_scene(scene)).tv.weights.any()  # off by default


@pytest.mark.slow
def test_the_view_dependent_colours_total_variation_smooths_it_alone(scene, trained):
    """With ``--tv-view-weight`` the view-dependent colour coefficients vary clearly less
    between neighbouring vertices; the base colour (degree 0) is not pulled, and the views
    are still reconstructed."""
    smooth = FastNeRF(FastConfig(**SMALL, tv_view_weight=1e-6), SceneBounds.from_scene(scene))
    train_loop(smooth, scene, 100)
    K = smooth.field.K
    view = [1 + c * K + k for c in range(3) for k in range(1, K)]
    base = [1 + c * K for c in range(3)]
    assert density_variation(smooth, view) < 0.5 * density_variation(trained, view)
    assert density_variation(smooth, base) > 0.7 * density_variation(trained, base)
    assert val_psnr(smooth, scene) > 22.0


def test_the_kernels_load_before_the_training_clock_starts(tmp_path, scene, monkeypatch, capsys):
    """A first run compiles the kernels (tens of seconds): that must not be spent from the
    time budget. On a fake clock (the trainer's ``time.perf_counter``) loading them takes 6 s
    (the trainer says so from 5 s) and each step 0.125 s; the budget is 1.2 s of training, so
    the run stops after exactly 10 steps, 1.25 s. Had the load counted, it would stop at step 0
    with 6 s trained."""
    import time

    from nerfkit import presets
    from nerfkit.train import trainer as trainer_module
    from nerfkit.train.config import TrainConfig
    from nerfkit.train.trainer import Trainer

    class FakeTime:
        now = 1000.0

        def perf_counter(self):
            return self.now

        def __getattr__(self, name):  # the rest of the time module, real
            return getattr(time, name)

    clock = FakeTime()
    monkeypatch.setattr(trainer_module, "time", clock)

    def load_kernels(self):
        loads.append(1)
        clock.now += 6.0

    def train_step(self, _step=Trainer.train_step):
        out = _step(self)
        clock.now += 0.125
        return out

    loads = []
    monkeypatch.setattr(FastNeRF, "load_kernels", load_kernels)
    monkeypatch.setattr(Trainer, "train_step", train_step)
    cfg = FastConfig(resolutions="16", upsample_steps="", occ_start=8, occ_every=8)
    tc = presets.without_scene(
        TrainConfig(
            data="sphere",
            model="fast",
            out=str(tmp_path / "run"),
            minutes=0.02,
            batch_rays=64,
            seed=0,
            eval_views=1,
            checkpoint_seconds=1e9,
        )
    )
    result = Trainer(scene, tc, cfg).run()
    assert loads == [1]
    assert result.step == 10 and result.train_seconds == 1.25
    assert "compiled the kernels in 6 s" in capsys.readouterr().err
