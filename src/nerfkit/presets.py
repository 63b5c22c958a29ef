"""Scene kinds and the settings each trains with: the one place where defaults depend on the scene.

A dataset says what it is (:func:`scene_kind`): a synthetic ``object`` (lego), a
``capture`` (real photos of an object on a table, posed from tags or SfM: ``nerfkit poses``
records it), or ``forward-facing`` (every camera looks the same way, as LLFF's). Each kind
has a table of the settings that differ from the dataclasses' own defaults
(:data:`PRESETS`), and each model one of its training settings (:data:`MODEL_TRAINING`).
:func:`resolve` applies them, once, to the options the user did not give: a given option
wins (but ``--table`` on a dataset with no table plane, which is turned off with a note), and
an option left without effect by the others (:data:`NEEDS`) is noted. The run's config.json
records the kind (``preset``) and every resolved value.
Why each default is what it is: BENCHMARKS.md ("why the defaults are what they are").
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from .scene_extent import FEW_TRAIN_VIEWS

if TYPE_CHECKING:
    from .object_detail import ObjectDetail

OBJECT, CAPTURE, FORWARD_FACING = "object", "capture", "forward-facing"
SCENE_KINDS = (OBJECT, CAPTURE, FORWARD_FACING)

# Training settings (TrainConfig fields) of each model where they differ from TrainConfig's
# defaults, which are the default model's (fast). vanilla renders small chunks (4096 rays x 64
# samples x 256 floats is ~270 MB) and scores 4096 pixels per periodic evaluation (whole views
# took a minute before its occupancy grid starts); splat trains on one whole view per step,
# with 3DGS's rates times 8 (runs of a few hundred to a few thousand steps converge faster;
# longer runs scale them down: splat's --lr-budget).
MODEL_TRAINING: dict[str, dict[str, Any]] = {
    "fast": {},
    "vanilla": {"batch_rays": 1024, "lr": 5e-4, "render_chunk": 4096, "eval_pixels": 4096},
    "splat": {"batch_rays": 1, "lr": 8.0},
}

# Per scene kind and model: {"train": TrainConfig values, "model": model config values} that
# differ from the defaults ("*": every model). A capture learns the room (a colour per
# direction, and for fast textured room shells), a glossy table texture, a robust photometric
# loss, the sparse points' sight lines and a small total variation of the view-dependent colour;
# its learning rate ends lower (a table texel is hit by few rays a step). Captures and
# forward-facing scenes (content at every depth) take the distortion loss. A kind whose fast
# model values name "resolutions" / "upsample_steps" trains with those grid stages
# (:func:`grid_stages`); the others take the base stages.
PRESETS: dict[str, dict[str, dict[str, dict[str, Any]]]] = {
    OBJECT: {},
    CAPTURE: {
        "*": {"train": {"capture": "on"}},
        "fast": {
            "train": {"lr_final_factor": 0.02},
            "model": {
                "learn_background": True,
                "distortion_weight": 0.01,
                "room_shells": 3,
                "table_gloss": True,
                "rgb_loss": "charbonnier",
                "points_weight": 0.02,
                "tv_view_weight": 1e-8,
                # a height per texel of the table: sheets that curl, a tag's plane off the
                # table's (BENCHMARKS.md, why the defaults are what they are)
                "table_relief": True,
            },
        },
        # splat can learn the pose corrections too (through the camera it renders from); they are
        # off until they help on the captures, as is the smaller rate of long runs (BENCHMARKS.md,
        # why the defaults are what they are)
        "splat": {"train": {"pose_lr": 0.0}, "model": {"learn_background": True, "lr_budget": 0}},
    },
    # forward-facing splat: no opacity reset and a densification every 50 steps (flower and
    # its two 17-photo subsets +0.4-0.8 dB at equal steps), and lr 5 (+0.1-0.4 dB on each;
    # BENCHMARKS.md, why the defaults are what they are)
    FORWARD_FACING: {
        "fast": {"model": {"distortion_weight": 0.01}},
        "splat": {"train": {"lr": 5.0}, "model": {"opacity_reset_every": 0.0, "densify_every": 50}},
    },
}


# The model a scene kind trains when --model is not given: the one that scored higher on
# held-out views at the budgets people use (BENCHMARKS.md, why the defaults are what they are).
# Synthetic objects: splat from the visual hull; forward-facing: splat from points triangulated
# at the given poses; captures: fast (the splat scored lower on the benchmark captures).
DEFAULT_MODEL = "fast"
KIND_MODELS = {OBJECT: "splat", FORWARD_FACING: "splat"}


def default_model(kind: str, available: Iterable[str]) -> str:
    """The model a run of scene kind ``kind`` trains when none is named: the kind's
    (:data:`KIND_MODELS`) when it is among the ``available`` models, else :data:`DEFAULT_MODEL`."""
    name = KIND_MODELS.get(kind, DEFAULT_MODEL)
    return name if name in set(available) else DEFAULT_MODEL


# the fast model's grid stages: a kind's preset may name its own (:func:`grid_stages`)
STAGE_OPTIONS = frozenset({"resolutions", "upsample_steps"})


@dataclass(frozen=True)
class Resolved:
    """A run's settings after :func:`resolve`: the training and model configs, and the scene kind."""

    train: Any  # TrainConfig
    model: Any  # the model's config
    kind: str
    notes: tuple[str, ...] = ()  # what the scene itself decided, for the run's log

    def configs(self) -> tuple[Any, Any]:
        """``(train, model)``: what a Trainer is built from."""
        return self.train, self.model


def scene_kind(scene, capture: str = "auto") -> str:
    """What ``scene`` is, with ``--capture`` (auto: as the dataset records; on; off):
    a capture, else forward-facing when every camera looks about the same way, else an object."""
    if capture == "on" or (capture == "auto" and scene.capture):
        return CAPTURE
    return FORWARD_FACING if scene.forward_facing else OBJECT


def preset_values(kind: str, model: str) -> tuple[dict, dict]:
    """(TrainConfig values, model config values) of scene kind ``kind`` for ``model``: the
    model's training table, then the kind's for every model, then the kind's for this model."""
    table = PRESETS[kind]
    train = {
        **MODEL_TRAINING.get(model, {}),
        **table.get("*", {}).get("train", {}),
        **table.get(model, {}).get("train", {}),
    }
    model_values = {**table.get("*", {}).get("model", {}), **table.get(model, {}).get("model", {})}
    return train, model_values


def kind_default_help(model: str, field: str, default: Any) -> str | None:
    """What ``--help`` says model ``model``'s option ``field`` (dataclass default ``default``)
    defaults to when a scene kind's preset changes it, e.g. ``"3 for capture datasets, else 0"``;
    None when no kind does. Written from :data:`PRESETS`, so the help cannot drift from them."""
    by_value: dict[str, list[str]] = {}
    for kind in SCENE_KINDS:
        values = preset_values(kind, model)[1]
        if field in values:
            by_value.setdefault(_shown(values[field]), []).append(kind)
    if not by_value:
        return None
    kinds = "; ".join(f"{value} for {' and '.join(names)} datasets" for value, names in by_value.items())
    return f"{kinds}, else {_shown(default)}"


def _shown(value: Any) -> str:
    """A setting as --help shows it: on/off for a switch, a number as written (``:g``)."""
    if isinstance(value, bool):
        return "on" if value else "off"
    return f"{value:g}".replace("e-0", "e-") if isinstance(value, float) else str(value)


def table_cover_default(scene, capture: bool) -> float:
    """``--table-cover-weight`` left unset: :data:`~nerfkit.models.fast_config.TABLE_COVER_WEIGHT` on a capture with a
    table, fewer than :data:`~nerfkit.scene_extent.FEW_TRAIN_VIEWS` training photos and
    sparse points that show no floor under the table; else 0.

    With few photos a table's coverage under 1 blends the room shells into it in blotches
    that the photos cannot average out: the prior helps a capture of a couple of dozen
    training photos, not one of 40 or more (`--table-cover-weight` in BENCHMARKS.md). Where a
    floor shows past the table's edge (a carpet below it, say) the coverage must learn to turn
    clear there, and the prior holds it opaque: the floor is painted onto the table's plane,
    which lowers the held-out score.
    Without sparse points the floor is unknown: off.
    """
    from .models import fast_config

    if not capture or scene.table is None or scene.points is None or not 0 < len(scene.train) < FEW_TRAIN_VIEWS:
        return 0.0
    return fast_config.TABLE_COVER_WEIGHT if scene.floor() is None else 0.0


def grid_stages(kind: str, scene) -> tuple[str, str]:
    """The fast model's grid stages (resolutions, upsample steps) for scene kind ``kind``:
    the kind's own when its preset (:data:`PRESETS`) names them, else the base stages, with a
    fifth for an object photographed at high resolution."""
    from .models.fast_config import BASE_STAGES, FINE_STAGE_PIXELS, FINE_STAGES

    own = preset_values(kind, "fast")[1]
    if STAGE_OPTIONS & own.keys():
        return own.get("resolutions", BASE_STAGES[0]), own.get("upsample_steps", BASE_STAGES[1])
    fine = kind == OBJECT and len(scene.train) > 0 and scene.train.width * scene.train.height > FINE_STAGE_PIXELS
    return FINE_STAGES if fine else BASE_STAGES


# a capture's printed tags get a fine colour texture of at most this many texels a side
# (--table-tag-texels; BENCHMARKS.md, why the defaults are what they are)
TAG_MAX_TEXELS = 256


def tag_texels_for(side: float, footprint: float | None) -> int:
    """Texels a side of the fine texture over a printed tag of ``side`` (its square doubled,
    ``2 side`` across) seen at ``footprint`` (the side of table one training pixel sees; None:
    unknown, no texture): the largest power of two whose texel is at least the footprint, at
    most :data:`TAG_MAX_TEXELS`; 0 when not even 16 fit. Example: a 10 cm tag seen at
    0.68 mm a pixel takes 256 (0.78 mm texels), a 5.5 cm one at 0.81 mm 128, a 6 cm one at
    1.28 mm 64."""
    if footprint is None or footprint <= 0 or side <= 0:
        return 0
    n = TAG_MAX_TEXELS
    while n >= 16 and 2.0 * side / n < footprint:
        n //= 2
    return n if n >= 16 else 0


def tag_texels_default(scene) -> int:
    """``--table-tag-texels`` left unset on a capture: :func:`tag_texels_for` the median side
    of its printed tags and the training photos' median pixel footprint on the table within
    the scene's radius (:func:`~nerfkit.surroundings.table.plane_footprint`); 0 without tags
    or a table."""
    import numpy as np

    from .scene_extent import sphere_radius
    from .surroundings.table import plane_footprint

    if scene.table is None or scene.tags is None or not len(scene.tags) or not len(scene.train):
        return 0
    tags = np.asarray(scene.tags, np.float64)
    side = float(np.median(np.linalg.norm(tags[:, 1] - tags[:, 0], axis=1)))
    radius = sphere_radius(scene)
    return tag_texels_for(side, plane_footprint(scene.train, scene.table, scene.center, radius))


# a plain object's box (--object-box-margin) is widened by this share of its size on every
# side, about three times the width of the object itself (BENCHMARKS.md, why the defaults are
# what they are)
PLAIN_BOX_MARGIN = 0.65


def plain_object(scene) -> ObjectDetail | None:
    """The detail a capture's photos show on its object
    (:func:`~nerfkit.object_detail.scene_object_detail`) when the object is plain; else None."""
    from .object_detail import scene_object_detail

    detail = scene_object_detail(scene)
    return detail if detail is not None and detail.plain else None


def scene_values(kind: str, model_config: Any, scene, given: frozenset[str]) -> tuple[dict, list[str]]:
    """The model settings that follow from the scene itself rather than its kind alone (fast
    only), and notes on them: a capture's table plane, table cover prior
    (:func:`table_cover_default`) and, for a plain object (:func:`plain_object`), a box
    widened by :data:`PLAIN_BOX_MARGIN`; the grid stages (:func:`grid_stages`; unless a stage
    option is given)."""
    from .models.fast_config import FastConfig

    if not isinstance(model_config, FastConfig):
        return {}, []
    out: dict[str, Any] = {"table_cover_weight": table_cover_default(scene, kind == CAPTURE)}
    notes = []
    if kind == CAPTURE:
        out["table"] = scene.table is not None
        if "table_tag_texels" not in given:
            out["table_tag_texels"] = tag_texels_default(scene)
        told = {"object_box", "object_box_margin"} & given or not model_config.object_box
        plain = None if told else plain_object(scene)
        if plain is not None:
            out["object_box_margin"] = PLAIN_BOX_MARGIN
            notes.append(
                f"the object shows no more detail than the table it stands on ({plain.describe()}): its "
                f"box is widened by {PLAIN_BOX_MARGIN:g} of its size on every side, as a plain object frays "
                "in a tight one (--object-box-margin 0 keeps it tight)"
            )
    if not STAGE_OPTIONS & given:
        out["resolutions"], out["upsample_steps"] = grid_stages(kind, scene)
    return out, notes


def differing_fields(cfg: Any) -> frozenset[str]:
    """The fields of dataclass ``cfg`` whose value is not the field's default: what a caller
    that built ``cfg`` in Python evidently chose (used when it does not say what it gave)."""
    out = set()
    for f in dataclasses.fields(cfg):
        default = (
            f.default
            if f.default is not dataclasses.MISSING
            else (f.default_factory() if f.default_factory is not dataclasses.MISSING else dataclasses.MISSING)
        )
        if getattr(cfg, f.name) != default:
            out.add(f.name)
    return frozenset(out)


# Options that act only beside another: option -> (the flag it needs, whether a run's resolved
# (train, model) settings have it). A given option whose need is unmet is noted in the run's log.
NEEDS: dict[str, tuple[str, Callable[[Any, Any], bool]]] = {
    **{
        k: ("--table", lambda t, m: bool(getattr(m, "table", False)))
        for k in (
            "table_gloss",
            "table_relief",
            "table_tag_texels",
            "table_resolution",
            "table_lr_ratio",
            "opacity_weight",
            "table_cover_weight",
            "box_follows",
        )
    },
    "floor": ("--table and --learn-background", lambda t, m: bool(m.table and m.learn_background)),
    "room_shells": ("--learn-background", lambda t, m: bool(m.learn_background)),
    **{
        k: ("--room-shells above 0 (with --learn-background)", lambda t, m: bool(m.learn_background and m.room_shells))
        for k in ("room_ratio", "room_resolution", "room_lr_ratio")
    },
    "table_cover_start": ("--table-cover-weight above 0", lambda t, m: bool(m.table and m.table_cover_weight > 0)),
    "transient_start": ("--transient-quantile above 0", lambda t, m: m.transient_quantile > 0),
    **{k: ("--capture on", lambda t, m: t.capture == "on") for k in ("pose_lr", "exposure_lr", "colour_mix")},
    "pose_start": ("--pose-lr above 0 (with --capture on)", lambda t, m: t.capture == "on" and t.pose_lr > 0),
    "colour_mix_weight": (
        "--colour-mix and --exposure-lr above 0 (with --capture on)",
        lambda t, m: t.capture == "on" and t.colour_mix and t.exposure_lr > 0,
    ),
}


def unmet_needs(train: Any, model_config: Any, given: Iterable[str]) -> list[str]:
    """A note for each option in ``given`` that the run's settings leave without effect
    (:data:`NEEDS`), e.g. ``--table-gloss`` on a run without the table plane."""
    from .config import flag_of

    names = {f.name for f in dataclasses.fields(train)} | {f.name for f in dataclasses.fields(model_config)}
    notes = []
    for name in sorted(set(given) & set(NEEDS) & names):
        need, met = NEEDS[name]
        if not met(train, model_config):
            notes.append(f"{flag_of(name)} does nothing in this run: it acts only with {need}")
    return notes


def resolve(train: Any, model_config: Any, scene, user_set: Iterable[str] | None = None) -> Resolved:
    """The run's settings: every option of ``train`` (TrainConfig) and ``model_config`` that is
    not in ``user_set`` (the names of the options the user gave; None: those that differ from
    their defaults) takes the value of the scene's kind (:func:`scene_kind`, from ``train.capture``).
    Pure: the arguments are not changed. Example: the fast model on a tag capture, nothing
    given -> lr 0.3, lr_final_factor 0.02, capture "on", rgb_loss "charbonnier", ...; with
    ``--rgb-loss mse`` given, rgb_loss stays "mse"."""
    given = (differing_fields(train) | differing_fields(model_config)) if user_set is None else frozenset(user_set)
    kind = scene_kind(scene, train.capture)
    train_values, model_values = preset_values(kind, train.model)
    from_scene, notes = scene_values(kind, model_config, scene, given)
    model_values = {**model_values, **from_scene}
    if STAGE_OPTIONS & given:  # the stages go together: one given, the other keeps its default
        model_values = {k: v for k, v in model_values.items() if k not in STAGE_OPTIONS}
    train_values["capture"] = "on" if kind == CAPTURE else "off"  # what --capture auto resolved to
    train_values["preset"] = kind
    # the model's options that do not apply to it are not its
    names = {f.name for f in dataclasses.fields(model_config)}
    model_new = {k: v for k, v in model_values.items() if k in names and (k not in given or k == "table" and not v)}
    train_new = {k: v for k, v in train_values.items() if k not in given or k in ("capture", "preset")}
    if getattr(model_config, "table", False) and getattr(scene, "table", None) is None:
        model_new["table"] = False  # nothing to stop at
        if "table" in given:
            notes.append(
                "--table does nothing on this dataset: it records no table plane (`nerfkit poses` "
                "records a tag capture's)"
            )
    model_cfg = dataclasses.replace(model_config, **model_new)
    train_cfg = dataclasses.replace(train, **train_new)
    notes += unmet_needs(train_cfg, model_cfg, given)
    return Resolved(train_cfg, model_cfg, kind, tuple(notes))


def without_scene(train: Any) -> Any:
    """``train`` (TrainConfig) with the training settings of its model (:data:`MODEL_TRAINING`)
    and, with ``--capture on``, a capture's, for the options left at their defaults: for callers
    that build a Trainer without a scene to resolve by (:func:`resolve` does both)."""
    kind = CAPTURE if train.capture == "on" else OBJECT
    values, _ = preset_values(kind, train.model)
    given = differing_fields(train)
    return dataclasses.replace(train, **{k: v for k, v in values.items() if k not in given and k != "capture"})


__all__ = [
    "CAPTURE",
    "FORWARD_FACING",
    "MODEL_TRAINING",
    "OBJECT",
    "PRESETS",
    "Resolved",
    "SCENE_KINDS",
    "NEEDS",
    "grid_stages",
    "preset_values",
    "resolve",
    "scene_kind",
    "table_cover_default",
    "unmet_needs",
    "without_scene",
]
