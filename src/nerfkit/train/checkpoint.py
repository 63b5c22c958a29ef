"""Checkpoints and run folders.

A run folder::

    RUN/config.json                 resolved train + model config, scene bounds, data path + fingerprint
    RUN/model.pt                    the final model: parameters and buffers only (what eval/render use),
                                    compact where the model packs its state (fast: occupied vertices, fp16)
    RUN/checkpoints/step_00001234.pt   model, optimizer, RNG streams, metric rows (what --resume uses)
    RUN/checkpoints/broken/         checkpoints a resume set aside: they did not load, or were newer
                                    than the one it went on from
    RUN/.nerfkit.lock               held by the one process training the run (earlier versions: RUN/.lock)
    RUN/metrics.csv, metrics.json   one row per logged step (train) or evaluation (val); the
                                    model's notes at the end of training (metrics.json)
    RUN/plots/, RUN/progress/, RUN/videos/

Checkpoints are written atomically and read with ``torch.load(weights_only=True)``,
so a crafted file cannot run code. A checkpoint that fails to load is reported and the
previous one is used; a resume moves it to ``checkpoints/broken/``.
"""

from __future__ import annotations

import contextlib
import json
import sys
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import torch

from ..config import dataclass_from_dict, load_json
from ..errors import NerfkitError, fail
from ..io.atomic import atomic_path, remove_stale_temporaries, write_json
from ..io.lock import folder_lock
from ..io.paths import refuse_links
from ..models import MODEL_NAMES, SceneBounds, build_model, config_from_dict, model_config_class
from ..models.appearance import DirectionalColour
from ..models.base import NerfModel
from .config import TrainConfig

FORMAT = "nerfkit-checkpoint"
VERSION = 1
MODEL_FILE = "model.pt"


@dataclass
class RunInfo:
    """What a run folder says about itself."""

    run_dir: Path
    train: TrainConfig
    model_config: Any
    bounds: SceneBounds
    scene: dict = field(default_factory=dict)  # what config.json says about the dataset (fingerprint, ...)


def write_run_config(
    run_dir: Path, train: TrainConfig, model_config: Any, bounds: SceneBounds, scene_info: dict
) -> None:
    from .. import __version__

    write_json(
        run_dir / "config.json",
        {
            "nerfkit_version": __version__,
            "train": asdict(train),
            "model": asdict(model_config),
            "bounds": bounds.to_dict(),
            "scene": scene_info,
        },
    )


def read_run(run_dir: str | Path) -> RunInfo:
    run_dir = Path(run_dir)
    cfg_path = run_dir / "config.json"
    if run_dir.exists() and not run_dir.is_dir():
        from ..data.load import is_run_folder

        if is_run_folder(run_dir.parent):  # a file of a run (its config.json, model.pt, ...)
            raise fail(run_dir, "is a file of a run, not the run", f"Give its folder: {run_dir.parent}")
        raise fail(
            run_dir,
            "is a file, not a run folder",
            "Give the --out folder of a `nerfkit train` run"
            + (
                " (this looks like a dataset: train on it with `nerfkit train --data`)"
                if run_dir.suffix.lower() in (".npz", ".json")
                else ""
            ),
        )
    if not run_dir.is_dir():
        raise fail(run_dir, "no such run folder", "Give the --out folder of a `nerfkit train` run")
    if not cfg_path.exists():
        if (run_dir / "run" / "config.json").is_file():
            raise fail(run_dir, "is a capture's folder, not a run", f"Its NeRF is {run_dir / 'run'}")
        raise fail(cfg_path, "missing", "This folder is not a nerfkit run (train writes config.json first)")
    d = load_json(cfg_path)
    if not isinstance(d, dict):
        raise fail(cfg_path, f"expected a JSON object, got {type(d).__name__}", "This is not a run's config.json")
    for key in ("train", "model", "bounds"):
        if not isinstance(d.get(key), dict):
            raise fail(cfg_path, f"'{key}' is missing or not an object", "This is not a run's config.json")
    try:
        # a run from before the colour-mix penalty resumes as it was trained, without it
        train = dataclass_from_dict(TrainConfig, {"colour_mix_weight": 0.0, **d["train"]}, str(cfg_path))
        if train.model not in MODEL_NAMES:
            raise fail(cfg_path, f"unknown model '{train.model}'", f"Expected one of {', '.join(MODEL_NAMES)}")
        # ... and a fast run from before the view-dependent colour's total variation, without it
        old = {"tv_view_weight": 0.0} if train.model == "fast" else {}
        model_class = model_config_class(train.model)
        model_config = dataclass_from_dict(
            model_class, {**old, **unset_as_default(model_class, d["model"])}, str(cfg_path)
        )
        bounds = SceneBounds.from_dict(d["bounds"])
    except (KeyError, TypeError, ValueError) as e:
        raise fail(cfg_path, f"malformed run config ({type(e).__name__}: {e})") from None
    for cfg in (train, model_config):
        if hasattr(cfg, "validate"):
            try:
                cfg.validate()
            except NerfkitError as e:
                raise fail(cfg_path, f"invalid {type(cfg).__name__} settings ({e})") from None
    _check_bounds(bounds, str(cfg_path))
    return RunInfo(run_dir, train, model_config, bounds, d["scene"] if isinstance(d.get("scene"), dict) else {})


def read_settings(path: str | Path) -> tuple[TrainConfig, Any, set[str]]:
    """(TrainConfig, model config, names of the settings it records) of a run's config.json
    (or of the run folder that holds it), for ``nerfkit train --config``: the new run starts
    from these settings, each of them counting as given (the scene kind's preset changes none).
    Its ``out`` is the old run's: a new run needs another --out."""
    path = Path(path)
    if path.is_dir():
        path = path / "config.json"
    d = load_json(path, missing_fix="Give a run's config.json (nerfkit train writes one into every run)")
    if not isinstance(d, dict) or not isinstance(d.get("train"), dict) or not isinstance(d.get("model"), dict):
        raise fail(
            path,
            "is not a run's config.json (it needs 'train' and 'model' objects)",
            "Give the config.json of a `nerfkit train` run",
        )
    train = dataclass_from_dict(TrainConfig, d["train"], str(path))
    if train.model not in MODEL_NAMES:
        raise fail(path, f"unknown model '{train.model}'", f"Expected one of {', '.join(MODEL_NAMES)}")
    model_class = model_config_class(train.model)
    model_config = dataclass_from_dict(model_class, unset_as_default(model_class, d["model"]), str(path))
    return train, model_config, set(d["train"]) | set(d["model"])


def unset_as_default(cls: type, values: Any) -> Any:
    """A run's recorded model settings without the ones an older nerfkit left unset (null) where
    a setting now always has a value (a grid's --upsample-steps when only --resolutions was given):
    they take the default, as that version did."""
    import typing

    from ..config import base_type

    if not isinstance(values, dict):
        return values
    hints = typing.get_type_hints(cls)
    return {k: v for k, v in values.items() if not (v is None and k in hints and not base_type(hints[k])[1])}


def dataset_fingerprint(scene) -> dict:
    """What identifies a dataset: its view counts, image size, and hashes of every pose, of
    every view's intrinsics, of the training images and of the val and test images. Stored in
    the run's config.json, checked on resume and eval."""
    import hashlib

    import numpy as np

    poses, intrinsics, held_out = hashlib.sha256(), hashlib.sha256(), hashlib.sha256()
    for name, v in scene.splits.items():
        poses.update(np.ascontiguousarray(v.c2w, np.float32).tobytes())
        intrinsics.update(np.ascontiguousarray(v.K, np.float32).tobytes())
        if name != "train" and v.has_images:
            held_out.update(name.encode() + np.ascontiguousarray(v.images).tobytes())
    images = hashlib.sha256(np.ascontiguousarray(scene.train.images).tobytes()) if scene.train.has_images else None
    return {
        "views": [len(v) for v in scene.splits.values()],
        "image_size": [scene.train.width, scene.train.height],
        "poses_sha256": poses.hexdigest(),
        "train_images_sha256": images.hexdigest() if images else None,
        "intrinsics_sha256": intrinsics.hexdigest(),
        "held_out_images_sha256": held_out.hexdigest(),
    }


def scene_record(scene) -> dict:
    """What config.json records of the dataset a run trains on: its source, image size, view
    counts, near and far, and :func:`dataset_fingerprint`."""
    return {
        "source": scene.source,
        "width": scene.train.width,
        "height": scene.train.height,
        "n_train": len(scene.train),
        "n_val": len(scene.val),
        "n_test": len(scene.test),
        "near": scene.near,
        "far": scene.far,
        "fingerprint": dataset_fingerprint(scene),
    }


def dataset_differences(info: RunInfo, scene) -> list[str]:
    """Which parts of the run's recorded dataset fingerprint ``scene`` does not match (empty:
    the run's own dataset, or a run from before fingerprints were recorded). Only the parts
    the run recorded count: a run from before a part was added is not checked on it."""
    stored = info.scene.get("fingerprint")
    if not isinstance(stored, dict):
        return []
    now = dataset_fingerprint(scene)
    return [k for k in now if k in stored and stored[k] != now[k]]


def check_dataset(info: RunInfo, scene) -> None:
    """Refuse a dataset that is not the one the run was trained on (runs from before
    fingerprints were recorded are not checked)."""
    differ = dataset_differences(info, scene)
    if differ:
        raise fail(
            scene.source or info.train.data,
            f"is not the dataset run {info.run_dir} was trained on "
            f"({', '.join(k.replace('_sha256', '') for k in differ)} differ)",
            "Pass --data with the run's own dataset; a dataset changed in place cannot continue or score this run",
        )


def _check_bounds(b: SceneBounds, where: str) -> None:
    import numpy as np

    from ..data.validate import MAX_EXTENT, check_near_far, check_tags, check_vector3

    check_near_far(b.near, b.far, where)
    if b.tags is not None:
        b.tags = check_tags(b.tags, where, "bounds.tags")
    b.center = check_vector3(b.center, where, "bounds.center")
    b.up = check_vector3(b.up, where, "bounds.up", unit=True)
    if not (np.isfinite(b.radius) and b.radius > 0):
        raise fail(where, f"'bounds.radius' is {b.radius}, expected a positive number")
    reach = max(b.far, b.radius, float(np.abs(b.center).max()))
    if reach > MAX_EXTENT:  # (no dataset reaches so far: check_extent)
        raise fail(where, f"'bounds' reach {reach:.3g} units, more than the {MAX_EXTENT:.0e} a scene may")


def checkpoint_paths(run_dir: Path) -> list[Path]:
    """Checkpoints of a run, newest first."""
    return sorted((run_dir / "checkpoints").glob("step_*.pt"), reverse=True)


def _model_payload(step: int, model: NerfModel) -> dict:
    payload = {
        "format": FORMAT,
        "version": VERSION,
        "model_name": type(model).__name__,
        "step": step,
        "model": model.state_dict(),
        "model_extra": json.dumps(model.extra_state()),
    }
    if model.appearance is not None:  # (a capture's run: the colour of a view by its direction)
        payload["appearance"] = model.appearance.payload()
    return payload


def save_checkpoint(
    run_dir: Path, step: int, model: NerfModel, optimizer: torch.optim.Optimizer, extra: dict, keep: int = 1
) -> Path:
    """Write ``checkpoints/step_XXXXXXXX.pt`` atomically (a temporary file, renamed once complete),
    then delete the older ones but the ``keep - 1`` newest: a crash at any point leaves a whole
    checkpoint, and the one just written is always kept (one of a higher step is never deleted)."""
    path = run_dir / "checkpoints" / f"step_{step:08d}.pt"
    with atomic_path(path) as tmp:
        torch.save({**_model_payload(step, model), "optimizer": optimizer.state_dict(), **extra}, tmp)
    older = [p for p in checkpoint_paths(run_dir) if 0 <= _checkpoint_step(p) < step]
    for old in older[keep - 1 :]:
        old.unlink(missing_ok=True)
    return path


def set_aside(run_dir: Path, loaded: Path, step: int) -> list[Path]:
    """After a resume from checkpoint ``loaded`` (at ``step``): move the checkpoints tried before
    it (they did not load) and any of a higher step into ``checkpoints/broken/``, never over a
    file there, so that pruning keeps the new ones. Returns where they went."""
    paths = checkpoint_paths(run_dir)
    first = paths.index(loaded) if loaded in paths else 0
    aside = [p for i, p in enumerate(paths) if p != loaded and (i < first or _checkpoint_step(p) > step)]
    folder = run_dir / "checkpoints" / BROKEN_FOLDER
    moved = []
    for p in aside:
        folder.mkdir(exist_ok=True)
        target, n = folder / p.name, 1
        while target.exists():
            target, n = folder / f"{p.stem}.{n}{p.suffix}", n + 1
        p.rename(target)
        moved.append(target)
    return moved


def save_model(run_dir: Path, step: int, model: NerfModel, compact: bool = True) -> Path:
    """Write ``RUN/model.pt`` atomically: the model's parameters, buffers and extra state at
    ``step``, without the optimizer state. ``compact`` stores what the model's
    :meth:`~nerfkit.models.base.NerfModel.pack_state` gives (``fast``: the occupied part of
    the grid in half precision); else the plain state dict."""
    path = run_dir / MODEL_FILE
    payload = _model_payload(step, model)
    if compact:
        packing, state = model.pack_state()
        if packing is not None:
            payload.update(model=state, model_packing=packing)
    with atomic_path(path) as tmp:
        torch.save(payload, tmp)
    return path


def _checkpoint_step(path: Path) -> int:
    try:
        return int(path.stem.split("_")[1])
    except (IndexError, ValueError):
        return -1


# where a resume moves the checkpoints it could not go on from (inside checkpoints/)
BROKEN_FOLDER = "broken"
# the subfolders a run writes into
RUN_FOLDERS = ("checkpoints", f"checkpoints/{BROKEN_FOLDER}", "plots", "progress", "videos")


@contextlib.contextmanager
def run_lock(run_dir: str | Path):
    """Hold the run folder's lock (one process per run), and remove the temporaries a
    killed process left there."""
    refuse_links(run_dir, RUN_FOLDERS)
    with folder_lock(run_dir) as folder:
        remove_stale_temporaries(folder)
        yield folder


def not_a_torch_file(path: Path) -> bool:
    """Whether ``path`` is neither a zip archive laid out as ``torch.save`` writes it (every
    member under one folder, a ``data.pkl`` in it) nor a legacy pickle."""
    import zipfile

    try:
        with zipfile.ZipFile(path) as z:
            names = z.namelist()
    except (zipfile.BadZipFile, OSError):
        with open(path, "rb") as f:
            return f.read(1) != b"\x80"  # pickle's PROTO opcode begins every legacy torch file
    tops = {n.split("/", 1)[0] for n in names}
    return not (len(tops) == 1 and all("/" in n for n in names) and any(n.endswith("/data.pkl") for n in names))


def cut_short_zip(path: Path) -> bool:
    """Whether ``path`` begins as a zip archive (what ``torch.save`` writes) that cannot be
    opened as one: its end, where a zip lists its members, is missing."""
    import zipfile

    try:
        with open(path, "rb") as f:
            if f.read(4) != b"PK\x03\x04":
                return False
    except OSError:
        return False
    try:
        with zipfile.ZipFile(path):
            return False
    except (zipfile.BadZipFile, OSError):
        return True


def _read_checkpoint(path: Path, model_name: str) -> dict:
    """The checkpoint at ``path``; a NerfkitError says what is wrong (the caller says what to do)."""
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # noqa: BLE001 - truncated zip, unpickling refused, ...
        text = " ".join(str(e).split())
        if "central directory" in text or "zip archive" in text or "file is truncated" in text or cut_short_zip(path):
            why = "the file is cut short or damaged (a write, copy or download that did not finish?)"
        elif not_a_torch_file(path):
            why = "the file is not a PyTorch checkpoint (it holds something else: text, an array file, ...)"
        else:
            why = f"{type(e).__name__}: {text[:160]}{'...' if len(text) > 160 else ''}"
        raise fail(path, f"cannot load checkpoint: {why}") from None
    if not isinstance(ckpt, dict) or ckpt.get("format") != FORMAT:
        raise fail(path, "not a nerfkit checkpoint")
    if ckpt.get("version") != VERSION:
        raise fail(path, f"checkpoint version {ckpt.get('version')} is not {VERSION} (another nerfkit's)")
    if ckpt.get("model_name") != model_name:
        raise fail(path, f"checkpoint is for model {ckpt.get('model_name')}, this run uses {model_name}")
    step = ckpt.get("step")
    if isinstance(step, bool) or not isinstance(step, int) or step < 0:
        raise fail(path, f"checkpoint step is {step!r}, expected a whole number >= 0")
    return ckpt


def load_latest_checkpoint(run_dir: Path, model: NerfModel, final_model: bool = False) -> tuple[dict, Path] | None:
    """Load the newest loadable checkpoint into ``model``; warn about and skip broken ones.

    Returns the checkpoint dict (optimizer state, RNG streams, ...) and its path, or None
    when the run has no checkpoint. Raises when checkpoints exist but none loads. With
    ``final_model``, ``RUN/model.pt`` comes before every checkpoint of its step or older (it has
    no optimizer state: for rendering, not for resuming); a newer checkpoint that loads wins
    (training went on after model.pt was written: resumed, then killed).
    """
    name = type(model).__name__
    paths: list[tuple[Path, dict | None]] = [(p, None) for p in checkpoint_paths(run_dir)]
    errors: list[str] = []
    if final_model and (run_dir / MODEL_FILE).is_file():
        try:
            final = _read_checkpoint(run_dir / MODEL_FILE, name)
            at = next((i for i, (p, _) in enumerate(paths) if _checkpoint_step(p) <= final["step"]), len(paths))
            paths.insert(at, (run_dir / MODEL_FILE, final))
        except NerfkitError as e:
            errors.append(str(e))
    for path, read in paths:
        try:
            ckpt = read if read is not None else _read_checkpoint(path, name)
            if not isinstance(ckpt.get("model_extra"), str) or not isinstance(ckpt.get("model"), dict):
                raise fail(path, "malformed checkpoint ('model' or 'model_extra' has the wrong type)")
            packing = ckpt.get("model_packing")
            if not (packing is None or isinstance(packing, str)):
                raise fail(path, "malformed checkpoint ('model_packing' is not a name)")
            model.load_extra_state(json.loads(ckpt["model_extra"]))  # checks sizes before allocating
            appearance = ckpt.get("appearance")
            model.appearance = None if appearance is None else DirectionalColour.from_payload(appearance)
            state = ckpt["model"] if packing is None else model.unpack_state(packing, ckpt["model"])
            # weights must be finite; buffers may hold inf on purpose (e.g. "not measured yet"), never NaN
            params = {name for name, _ in model.named_parameters()}
            floats = {name: t for name, t in state.items() if isinstance(t, torch.Tensor) and t.is_floating_point()}
            if not all(torch.isfinite(t).all() for name, t in floats.items() if name in params):
                raise fail(path, "the model weights hold NaN or inf values")
            if any(torch.isnan(t).any() for t in floats.values()):
                raise fail(path, "the model state holds NaN values")
            model.load_state_dict(state)
            for msg in errors:  # the newer checkpoints that were skipped
                print(f"warning: {msg}; used the older {path.name}", file=sys.stderr)
            return ckpt, path
        except (
            NerfkitError,
            RuntimeError,
            KeyError,
            ValueError,
            TypeError,
            IndexError,
            AttributeError,
            OverflowError,
            MemoryError,
        ) as e:
            # one line: load_state_dict lists every mismatched tensor on its own line
            msg = " ".join(str(e).split())[:300]
            if not isinstance(e, NerfkitError):
                msg = f"{path}: {type(e).__name__}: {msg}"
            errors.append(msg)  # reported once: as warnings if an older one loads, else in the error
    if errors:
        raise fail(
            run_dir,
            "no checkpoint could be loaded: " + "; ".join(errors),
            "Copy the run again from where it was made, or train it again",
        )
    return None


def load_run(run_dir: str | Path, device: torch.device | str = "cpu") -> tuple[NerfModel, RunInfo, int]:
    """A trained model from a run folder: (model in eval mode, run info, step)."""
    info = read_run(run_dir)
    try:
        model = build_model(info.train.model, info.model_config, info.bounds)
    except NerfkitError as e:
        raise fail(info.run_dir / "config.json", str(e)) from None
    except (RuntimeError, ValueError, TypeError, ArithmeticError, MemoryError) as e:  # e.g. a negative width
        raise fail(
            info.run_dir / "config.json",
            f"its model settings do not build a model "
            f"({type(e).__name__}: {str(e).splitlines()[0][:200] if str(e) else ''})",
        ) from None
    loaded = load_latest_checkpoint(info.run_dir, model, final_model=True)
    if loaded is None:
        raise fail(info.run_dir, "has no checkpoint yet", "Wait for training to write one, or train longer")
    model.to(device).eval()
    return model, info, int(loaded[0]["step"])


__all__ = [
    "MODEL_FILE",
    "RunInfo",
    "check_dataset",
    "dataset_fingerprint",
    "load_latest_checkpoint",
    "load_run",
    "read_run",
    "run_lock",
    "save_checkpoint",
    "set_aside",
    "save_model",
    "write_run_config",
    "config_from_dict",
]
