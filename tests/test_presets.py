"""Scene kinds and their presets (nerfkit.presets): the resolved settings of each kind are pinned."""

from __future__ import annotations

import json
import re
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
import pytest

from nerfkit import presets
from nerfkit.data.npz import load_npz
from nerfkit.data.synthetic import forward_facing_scene, sphere_scene, tabletop_scene
from nerfkit.models import model_config_class
from nerfkit.models.fast import FastConfig
from nerfkit.train.config import TrainConfig

ASSETS = Path(__file__).resolve().parents[1] / "src" / "nerfkit" / "assets"
# The settings `nerfkit train` resolved for each scene and model before the presets
# refactor (computed with the code of that time: capture_settings then resolved_config,
# from TrainConfig(model=M, steps=10) and the model's default config). They are the
# behaviour kept: presets.resolve must give the same values.
REFERENCE = Path(__file__).resolve().parent / "reference" / "resolved_configs.json"
# flags retired since (their recorded value was the one that kept them off)
RETIRED: set[str] = set()
# defaults changed on purpose since: a run keeps one resume checkpoint beside model.pt
CHANGED = {"keep_checkpoints": 1}
# ... and for one scene and model: splat's pose corrections on a capture are off by their
# preset (the trainer then skipped them for models that render whole views)
CHANGED_FOR = {f"{scene}/splat": {"pose_lr": 0.0} for scene in ("tabletop", "tabletop_points")}
# ... and forward-facing splat's learning rate (its preset)
CHANGED_FOR["forward/splat"] = {"lr": 5.0}
# ... and model settings: forward-facing splat's densification schedule (its preset)
FORWARD_SPLAT = {"opacity_reset_every": 0.0, "densify_every": 50}
CHANGED_MODEL_FOR = {"forward/splat": FORWARD_SPLAT}
# ... and a capture's splat keeps one learning rate whatever its length
CHANGED_MODEL_FOR.update({f"{scene}/splat": {"lr_budget": 0} for scene in ("tabletop", "tabletop_points")})
# ... and a capture's table learns its relief
CHANGED_MODEL_FOR.update({f"{scene}/fast": {"table_relief": True} for scene in ("tabletop", "tabletop_points")})
# model options added since, with their default (splat: pruning to the visual hull, the
# learning rates by the run's length, the SH direction's gradient; fast: the table's relief,
# box margin and tags' texture)
ADDED_MODEL = {
    "splat": {"hull_prune": True, "lr_budget": 800, "sh_dir_grad": False},
    "fast": {"table_relief": False, "object_box_margin": 0.0, "table_tag_texels": 0},
}


def sized(scene, size):
    return replace(scene, train=replace(scene.train, width=size, height=size, images=None))


def reference_scenes() -> dict:
    """lego (the bundled npz), tag captures with and without sparse points on the table,
    a forward-facing scene, and an object photographed at 400x400 (the fifth grid stage)."""
    rng = np.random.default_rng(0)
    table = np.concatenate([rng.uniform(-1, 1, (300, 2)), np.zeros((300, 1))], 1).astype(np.float32)
    tabletop = tabletop_scene(n_train=12, n_val=2, size=32)
    return {
        "lego": load_npz(ASSETS / "lego_200x200.npz"),
        "tabletop": tabletop,
        "tabletop_points": replace(tabletop, points=table),
        "forward": forward_facing_scene(n_train=6, n_val=0, size=8),
        "object_400": sized(sphere_scene(n_train=6, size=8), 400),
    }


@pytest.fixture(scope="module")
def scenes():
    return reference_scenes()


@pytest.mark.parametrize("model", ["fast", "vanilla", "splat"])
def test_the_resolved_settings_of_each_scene_kind_are_those_kept_from_before(scenes, model):
    reference = json.loads(REFERENCE.read_text())
    for name, scene in scenes.items():
        r = presets.resolve(TrainConfig(model=model, steps=10), model_config_class(model)(), scene, set())
        want = reference[f"{name}/{model}"]
        got_train = {k: v for k, v in asdict(r.train).items() if k != "preset"}
        got_model = asdict(r.model)
        assert got_train == {**want["train"], **CHANGED, **CHANGED_FOR.get(f"{name}/{model}", {})}, name
        want_model = {k: v for k, v in want["model"].items() if k not in RETIRED}
        added = ADDED_MODEL.get(model, {})
        assert got_model == {**want_model, **added, **CHANGED_MODEL_FOR.get(f"{name}/{model}", {})}, name
        assert (
            r.train.preset
            == r.kind
            == {"lego": "object", "object_400": "object", "forward": "forward-facing"}.get(name, "capture")
        )


def test_given_options_always_win_and_resolve_changes_nothing_it_is_given(scenes):
    cap = scenes["tabletop_points"]
    train, model = (
        TrainConfig(steps=10, lr_final_factor=0.1),
        FastConfig(rgb_loss="mse", room_shells=0, table_cover_weight=0.0),
    )
    before = (asdict(train), asdict(model))
    r = presets.resolve(train, model, cap, {"lr_final_factor", "rgb_loss", "room_shells", "table_cover_weight"})
    assert (asdict(train), asdict(model)) == before  # pure
    assert (r.train.lr_final_factor, r.model.rgb_loss, r.model.room_shells, r.model.table_cover_weight) == (
        0.1,
        "mse",
        0,
        0.0,
    )
    assert (r.model.distortion_weight, r.model.points_weight, r.train.capture) == (0.01, 0.02, "on")  # not given
    # nothing given: the capture's
    r = presets.resolve(train, model, cap, set())
    assert (r.train.lr_final_factor, r.model.rgb_loss, r.model.room_shells, r.model.table_cover_weight) == (
        0.02,
        "charbonnier",
        3,
        0.05,
    )
    # vanilla's own training settings, unless given
    from nerfkit.models.vanilla import VanillaConfig

    r = presets.resolve(TrainConfig(model="vanilla", lr=1e-3), VanillaConfig(), cap, {"lr"})
    assert (r.train.lr, r.train.batch_rays, r.train.render_chunk) == (1e-3, 1024, 4096)
    # --capture off on a capture: an object's settings; on on an object: a capture's
    assert presets.resolve(replace(train, capture="off"), model, cap, set()).kind == "object"
    assert presets.resolve(replace(train, capture="on"), model, scenes["lego"], set()).model.learn_background
    # a table needs a plane: --table on a capture without one stays off
    no_table = replace(cap, table=None)
    assert not presets.resolve(train, FastConfig(table=True), no_table, {"table"}).model.table
    assert not presets.resolve(train, FastConfig(table=False), cap, {"table"}).model.table


def test_an_option_its_run_leaves_without_effect_is_noted_and_one_that_acts_is_not(scenes):
    fields = {f for cls in (TrainConfig, FastConfig) for f in asdict(cls())}
    assert set(presets.NEEDS) <= fields  # real options
    inert = "does nothing in this run"
    # lego: no table, no learned background, no capture corrections, no transient trimming
    every = set(presets.NEEDS)
    r = presets.resolve(TrainConfig(steps=10), FastConfig(), scenes["lego"], every)
    flagged = {n for n in every if any(note.startswith(f"--{n.replace('_', '-')} {inert}") for note in r.notes)}
    assert flagged == every
    assert not any(
        inert in note for note in presets.resolve(TrainConfig(steps=10), FastConfig(), scenes["lego"], set()).notes
    )
    # a capture with its table and room (its 3 room shells: not given): only the cover prior's
    # start (its weight given as 0) and the transient start (no trimming) are idle
    r = presets.resolve(TrainConfig(steps=10), FastConfig(), scenes["tabletop"], every - {"room_shells"})
    assert sorted(n for n in r.notes if inert in n) == [
        f"--table-cover-start {inert}: it acts only with --table-cover-weight above 0",
        f"--transient-start {inert}: it acts only with --transient-quantile above 0",
    ]
    trimmed = presets.resolve(
        TrainConfig(steps=10),
        FastConfig(transient_quantile=0.8),
        scenes["tabletop"],
        {"transient_quantile", "transient_start"},
    )
    assert not [n for n in trimmed.notes if inert in n]
    # --table on a dataset without a table plane is off, and said so; so are the table's own options
    r = presets.resolve(
        TrainConfig(steps=10), FastConfig(table=True, table_gloss=True), scenes["forward"], {"table", "table_gloss"}
    )
    assert not r.model.table
    assert any(n.startswith("--table does nothing on this dataset") for n in r.notes)
    assert any(n.startswith(f"--table-gloss {inert}") for n in r.notes)


def test_the_fifth_stage_is_not_added_when_a_stage_option_is_given(scenes):
    r = presets.resolve(TrainConfig(steps=10), FastConfig(resolutions="16,32"), scenes["object_400"], {"resolutions"})
    assert (r.model.resolutions, r.model.upsample_steps) == ("16,32", FastConfig().upsample_steps)


def test_every_preset_names_real_settings():
    from nerfkit.models import MODEL_NAMES

    train_fields = set(asdict(TrainConfig()))
    for kind in presets.SCENE_KINDS:
        for model in MODEL_NAMES:
            train, model_values = presets.preset_values(kind, model)
            assert set(train) <= train_fields
            assert set(model_values) <= set(asdict(model_config_class(model)()))


def test_a_scene_kind_with_its_own_grid_stages_gets_them_and_the_others_keep_theirs(scenes, monkeypatch):
    """Stages named in a kind's preset are that kind's (a stage option given still wins);
    an object keeps the base stages, and at high resolution the fifth."""
    from nerfkit.models.fast_config import BASE_STAGES, FINE_STAGES

    own = {"resolutions": "16,48", "upsample_steps": "7"}
    table = {**presets.PRESETS, "capture": {**presets.PRESETS["capture"], "fast": {"model": own}}}
    monkeypatch.setattr(presets, "PRESETS", table)
    r = presets.resolve(TrainConfig(steps=10), FastConfig(), scenes["tabletop"], set())
    assert (r.model.resolutions, r.model.upsample_steps) == ("16,48", "7")
    r = presets.resolve(TrainConfig(steps=10), FastConfig(resolutions="8,16"), scenes["tabletop"], {"resolutions"})
    assert (r.model.resolutions, r.model.upsample_steps) == ("8,16", FastConfig().upsample_steps)
    for name, stages in (("lego", BASE_STAGES), ("object_400", FINE_STAGES)):
        r = presets.resolve(TrainConfig(steps=10), FastConfig(), scenes[name], set())
        assert (r.model.resolutions, r.model.upsample_steps) == stages


def test_a_scene_kind_names_the_model_it_trains_when_none_is_named():
    everything = ["fast", "splat", "vanilla"]
    assert presets.default_model(presets.FORWARD_FACING, everything) == "splat"
    assert presets.default_model(presets.OBJECT, everything) == "splat"
    assert presets.default_model(presets.CAPTURE, everything) == presets.DEFAULT_MODEL == "fast"
    for kind in (presets.OBJECT, presets.FORWARD_FACING):
        assert presets.default_model(kind, ["fast", "vanilla"]) == "fast"  # splat not installed


def test_forward_facing_splat_densifies_every_50_steps_without_opacity_resets_and_other_kinds_do_not(scenes):
    from nerfkit.models.splat import SplatConfig

    defaults = SplatConfig()
    assert (defaults.opacity_reset_every, defaults.densify_every) != (0.0, 50)
    for name, scene in scenes.items():
        r = presets.resolve(TrainConfig(model="splat", steps=10), SplatConfig(), scene, set())
        got = (r.model.opacity_reset_every, r.model.densify_every)
        if r.kind == presets.FORWARD_FACING:
            assert got == (0.0, 50), name
        else:
            assert got == (defaults.opacity_reset_every, defaults.densify_every), name
    # a given option still wins on a forward-facing scene
    r = presets.resolve(
        TrainConfig(model="splat", steps=10), SplatConfig(densify_every=100), scenes["forward"], {"densify_every"}
    )
    assert (r.model.opacity_reset_every, r.model.densify_every) == (0.0, 100)
    # the fast model on a forward-facing scene keeps its own settings
    assert "densify_every" not in presets.preset_values(presets.FORWARD_FACING, "fast")[1]


def test_a_model_setting_the_kinds_model_does_not_take_is_a_clear_error(scenes):
    from nerfkit.commands.pipeline import kind_model
    from nerfkit.errors import NerfkitError

    assert kind_model(scenes["forward"], "auto", set()) == "splat"
    assert kind_model(scenes["forward"], "auto", {"sh_degree"}) == "splat"  # fast and splat both take it
    assert kind_model(scenes["lego"], "auto", set()) == "splat"
    assert kind_model(scenes["tabletop"], "auto", set()) == "fast"
    with pytest.raises(
        NerfkitError,
        match="--resolutions: is a setting of the fast model, not of splat .the default "
        "--model for a forward-facing dataset.. Leave it out, or train with --model fast",
    ):
        kind_model(scenes["forward"], "auto", {"resolutions"})
    with pytest.raises(NerfkitError, match="not of splat .the default --model for an object dataset"):
        kind_model(scenes["lego"], "auto", {"resolutions"})
    with pytest.raises(NerfkitError, match="not of fast .the default --model for a capture dataset"):
        kind_model(scenes["tabletop"], "auto", {"densify_every"})


@pytest.mark.slow
def test_a_forward_facing_dataset_trains_splat_when_no_model_is_named(tmp_path):
    import nerfkit.api as api
    from nerfkit.data.npz import save_npz

    save_npz(forward_facing_scene(n_train=6, n_val=1, size=16), tmp_path / "f.npz")
    api.train(tmp_path / "f.npz", tmp_path / "run", steps=1, quiet=True)
    config = json.loads((tmp_path / "run" / "config.json").read_text())
    assert config["train"]["model"] == "splat" and config["train"]["preset"] == "forward-facing"
    api.train(tmp_path / "f.npz", tmp_path / "fast", model="fast", steps=1, quiet=True)
    assert json.loads((tmp_path / "fast" / "config.json").read_text())["train"]["model"] == "fast"


def _help_all(capsys) -> str:
    """`nerfkit train --help-all` on one line (argparse's wrapping undone)."""
    from nerfkit.cli import main

    with pytest.raises(SystemExit):
        main(["train", "--help-all"])
    return " ".join(re.sub(r"-\s+", "-", capsys.readouterr().out).split())


def test_the_help_names_every_model_value_a_scene_kind_presets_and_one_default_per_option(capsys):
    """`nerfkit train --help-all` gives each model option a kind's preset changes the kinds'
    value beside the general default (written from PRESETS, so a preset changed is a help
    changed), and no option says "(default: ...)" twice."""
    text = _help_all(capsys)
    checked = 0
    for kind in presets.SCENE_KINDS:
        for model, tables in presets.PRESETS[kind].items():
            for name, value in tables.get("model", {}).items():
                if model == "*" or name in presets.STAGE_OPTIONS:
                    continue
                shown = ("on" if value else "off") if isinstance(value, bool) else presets._shown(value)
                flag = "--" + name.replace("_", "-")
                said = re.search(rf"{re.escape(flag)}[ ,].*?\(default: ([^)]*)\)", text)
                assert said and re.search(rf"\b{re.escape(shown)} for [\w\- ]*{re.escape(kind)}", said.group(1)), (
                    flag,
                    kind,
                    said and said.group(1),
                )
                checked += 1
    assert checked >= 10
    assert not re.search(r"\(default: [^)]*\) \(default:", text)


def test_kind_default_help_groups_the_kinds_that_share_a_value_and_ends_with_the_general_default():
    """Analytic cases of the help's wording: a value two kinds share is said once for both."""
    assert presets.kind_default_help("fast", "distortion_weight", 0.0) == (
        "0.01 for capture and forward-facing datasets, else 0"
    )
    assert presets.kind_default_help("fast", "learn_background", False) == "on for capture datasets, else off"
    assert presets.kind_default_help("fast", "ray_samples_no_such_option", 1) is None


def test_the_model_help_names_each_kinds_default_model(capsys):
    """`nerfkit train --help` says which model each scene kind trains when --model is not given,
    as :func:`presets.default_model` chooses it."""
    from nerfkit.cli import main
    from nerfkit.models import MODEL_NAMES

    with pytest.raises(SystemExit):
        main(["train", "--help"])
    # undo the wrapping, which may break a line after a hyphen
    text = " ".join(re.sub(r"-\s+", "-", capsys.readouterr().out).split())
    for kind in presets.SCENE_KINDS:
        model = presets.default_model(kind, MODEL_NAMES)
        assert re.search(rf"{model} for [\w\- ]*\b{re.escape(kind)}\b", text), (kind, model)


@pytest.mark.parametrize("model", ["fast", "splat"])
def test_compiled_kernels_asked_for_on_a_gpu_are_refused_not_ignored(model):
    """--kernels numba runs on the CPU only: asked for on CUDA it is one clear error; auto and
    torch are fine there, and numba is fine on the CPU."""
    import torch

    from nerfkit.errors import NerfkitError
    from nerfkit.models import check_config, model_config_class

    cls = model_config_class(model)
    with pytest.raises(NerfkitError, match="CPU only"):
        check_config(model, cls(kernels="numba"), torch.device("cuda"))
    for kernels in ("auto", "torch"):
        check_config(model, cls(kernels=kernels), torch.device("cuda"))
    check_config(model, cls(kernels="numba"), torch.device("cpu"))
