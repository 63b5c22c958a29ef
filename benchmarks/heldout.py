"""Every model on every scene, scored on held-out views that no decision was made on.

    python benchmarks/heldout.py --lego-blender DIR [--llff DIR] [--capture NAME=DATASET ...]
                                 [--scenes lego200,lego400,flower,forward,NAME,...] [--models fast,splat]
                                 [--seconds 60,300 | --steps 100,1000] [--out OUT]

For each scene, model and budget B (seconds of training, evaluation excluded) one fresh run
trains in this process as ``nerfkit train --minutes B/60`` would (the same defaults, chosen
from the training views alone), on a copy of the scene whose val and test splits are empty:
training never renders, scores or otherwise sees a held-out view. Only after training does
the benchmark render the held-out views it loaded itself and score them with the project's
PSNR and SSIM (``nerfkit.train.metrics``). The scenes:

* ``lego200``: trained on the train views of the bundled ``lego_200x200.npz``; scored on all
  100 val views of the Blender folder (``--lego-blender``), downscaled to the npz's size the
  way the npz was made (area averaging of the RGBA image, then composited on black: see
  :func:`downscale_rgba`). Beside it, the PSNR on the npz's own 10 val views (the first 10 of
  those 100), so that the gap between the two is visible.
* ``lego400``: trained on the Blender train split at 400x400, scored on its 100 val views.
* ``flower``: an LLFF folder (``--llff``), at ``images_8`` by default (504x378, as the papers
  score it); every 8th photo (0, 8, 16, ...) held out, trained on the rest.
* ``flower17`` and ``flower17b``: stand-ins for a sparser forward-facing capture (17 train
  photos, as LLFF scenes with 20 photos have): the same held-out photos as ``flower``, trained
  on 17 of its 29 training photos chosen evenly (:func:`even_subset`, offsets 0 and 1/2 of a
  gap, so the two share few photos). ``forward`` in ``--scenes`` names all three: a setting of
  the forward-facing scene kind is judged on them together, never on ``flower`` alone.
* each ``--capture NAME=DATASET``: a posed capture dataset (``nerfkit poses``' output),
  trained on its train photos (with the real-capture training ``nerfkit train`` picks for
  it), scored on its val photos as rendered at their given poses.

By default every scene whose data is given runs. Reported per run: steps, training seconds,
mean PSNR and SSIM over the held-out views, render frames per second (those views, after one
warm-up frame), and the size of the saved ``model.pt``. Prints one markdown table; with
``--out``, the run folders go to ``OUT/runs/`` and the table to ``OUT/table.md``,
``OUT/results.csv`` and ``OUT/results.json`` (rewritten after every run; the JSON also holds
the SSIM beside each PSNR, each held-out view's PSNR, the load average around each run, and
splat's Gaussians).
Without ``--out`` the runs go to a temporary folder that is deleted at the end. A run
folder records the scene it was trained on, without its held-out views, so ``nerfkit eval``
refuses to score it against the whole dataset: score it here.

``--variant NAME:FIELD=VALUE[,FIELD=VALUE...]`` (repeatable) adds runs of a model with some
settings changed (``fast+tv:tv_weight=1e-4``): FIELD is a model config or a training config
field, VALUE a Python literal. The default runs appear beside it in the same table, so a
candidate default is judged on every scene in one run.

``--steps`` replaces the time budgets by step counts: a check of the protocol itself on a
machine too busy for its seconds to mean anything (its figures are not the protocol's).
"""

from __future__ import annotations

import argparse
import csv
import gc
import io
import math
import os
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass, fields, replace
from pathlib import Path

import numpy as np

from nerfkit.errors import NerfkitError, fail

REPO = Path(__file__).resolve().parents[1]
LEGO_NPZ = REPO / "src" / "nerfkit" / "assets" / "lego_200x200.npz"
LEGO_SCENES = ("lego200", "lego400")
# the LLFF subsets: name -> (train photos kept, offset in gaps); all are scored on flower's held-out photos
FLOWER_SUBSETS = {"flower17": (17, 0.0), "flower17b": (17, 0.5)}
FORWARD = ("flower", *FLOWER_SUBSETS)
BUILT_IN = ("lego200", "lego400", *FORWARD)
COLUMNS = (
    "scene",
    "model",
    "budget",
    "steps",
    "train_s",
    "psnr",
    "ssim",
    "fps",
    "model_mb",
    "n_heldout",
    "psnr_npz_val",
    "ssim_npz_val",
    "n_train",
    "width",
    "height",
    "loadavg_before",
    "loadavg_after",
)


@dataclass
class BenchScene:
    """One scene of the protocol.

    Attributes:
        name: its row label (lego200, lego400, flower, a capture's NAME).
        train: the scene training sees: its val and test splits empty.
        heldout: the views it is scored on (never given to training).
        extra: other held-out view sets scored beside it, by label (lego200: the npz's 10 val views).
        about: one line saying what was trained on and what is scored.
    """

    name: str
    train: object  # nerfkit.data.scene.Scene
    heldout: object  # nerfkit.data.scene.Views
    extra: dict
    about: str


# -- pure helpers ------------------------------------------------------------------------
def parse_models(text: str, variants: list[str]) -> list[str]:
    """``--models``: the plain models to run; empty beside a ``--variant`` runs only the variants."""
    if variants and not text.replace(",", "").strip():
        return []
    return parse_list(text, str, "--models")


def parse_list(text: str, kind=str, what: str = "list") -> list:
    """``"a,b"`` -> ``[kind("a"), kind("b")]``, empty items dropped; a NerfkitError for a bad item."""
    out = []
    for item in (s.strip() for s in text.split(",")):
        if not item:
            continue
        try:
            out.append(kind(item))
        except ValueError:
            raise fail(what, f"{item!r} is not a {kind.__name__}", "Give a comma-separated list") from None
    if not out:
        raise fail(what, f"{text!r} names nothing", "Give a comma-separated list")
    return out


def parse_captures(pairs: list[str]) -> dict[str, Path]:
    """``["steve=/data/steve_run/poses", ...]`` -> ``{"steve": Path(...)}``; names must be new."""
    out: dict[str, Path] = {}
    for pair in pairs:
        name, sep, path = pair.partition("=")
        name = name.strip()
        if not sep or not name or not path:
            raise fail("--capture", f"{pair!r} is not NAME=PATH", "e.g. --capture steve=runs/steve/poses")
        if name in out or name in BUILT_IN or name in ("captures", "forward"):
            raise fail("--capture", f"the name {name!r} is taken", "Give each capture its own name")
        out[name] = Path(path)
    return out


def budget_label(seconds: float | None, steps: int | None) -> str:
    """A run's budget as the table shows it: ``"60 s"`` or ``"100 steps"``."""
    return f"{seconds:g} s" if steps is None else f"{steps} steps"


def choose_scenes(asked: list[str] | None, have: dict[str, bool], captures: list[str]) -> list[str]:
    """The scenes to run, in table order: ``asked`` (``captures`` standing for every capture,
    ``forward`` for flower and its subsets) or, when None, every scene whose data was given
    (not flower's subsets). ``have``: built-in scene -> data given."""
    if asked is None:
        chosen = [s for s in BUILT_IN if s not in FLOWER_SUBSETS and have[s]] + list(captures)
        if not chosen:
            raise fail("heldout", "no scene to run", "Give --lego-blender, --llff or --capture NAME=DATASET")
        return chosen
    chosen = []
    for s in asked:
        names = list(captures) if s == "captures" else list(FORWARD) if s == "forward" else [s]
        for n in names:
            if n in BUILT_IN and not have[n]:
                flag = "--llff" if n in FORWARD else "--lego-blender"
                raise fail("--scenes", f"{n} needs its data", f"Give {flag} DIR")
            if n not in BUILT_IN and n not in captures:
                raise fail(
                    "--scenes",
                    f"unknown scene {n!r}",
                    f"Choose from {', '.join((*BUILT_IN, 'forward', 'captures', *captures))}",
                )
            if n not in chosen:
                chosen.append(n)
    return chosen


def even_subset(n: int, k: int, offset: float = 0.0) -> np.ndarray:
    """``k`` of the indices ``0..n-1``, evenly spread: ``floor((i + offset) * n / k)`` for
    ``i < k`` (``0 <= offset < 1``: where in each gap of ``n / k`` the pick falls). Increasing."""
    if not 0 < k <= n or not 0 <= offset < 1:
        raise ValueError(f"cannot pick {k} of {n} at offset {offset}")
    return np.floor((np.arange(k) + offset) * (n / k)).astype(int)


def downscale_rgba(image: np.ndarray, width: int, height: int) -> np.ndarray:
    """An (H, W, 4) uint8 RGBA image (or (H, W, 3) RGB) at ``width x height``, on black, (h, w, 3) uint8.

    As the course npz was made: the colour and the alpha are each area-averaged (PIL's box
    filter), then the colour is multiplied by the alpha. (Averaging the colour premultiplied
    by alpha, as a compositor would, differs at the object's edges by up to 36 levels.)
    """
    from PIL import Image

    x = np.asarray(image, np.float32) / 255.0
    if x.ndim != 3 or x.shape[2] not in (3, 4):
        raise ValueError(f"expected an (H, W, 3|4) image, got shape {x.shape}")
    planes = [
        np.asarray(
            Image.fromarray(np.ascontiguousarray(x[..., c]), mode="F").resize((width, height), Image.Resampling.BOX),
            np.float32,
        )
        for c in range(x.shape[2])
    ]
    rgb = np.stack(planes[:3], axis=-1)
    if len(planes) == 4:
        rgb = rgb * planes[3][..., None]
    return np.clip(np.round(rgb * 255.0), 0, 255).astype(np.uint8)


def without_heldout(scene):
    """The scene as training gets it: its val and test splits empty (same size as train)."""
    from nerfkit.data.scene import Views

    empty = Views.empty(scene.train.width, scene.train.height)
    return replace(scene, val=empty, test=Views.empty(scene.train.width, scene.train.height))


def match_views(a, b) -> list[dict]:
    """For each view of ``a`` (Views with images), the view of ``b`` nearest in pose: its
    index and name, the largest difference of their c2w entries, and the images' PSNR (dB;
    both at ``a``'s size, which ``b`` must share)."""
    from nerfkit.train.metrics import psnr

    rows = []
    for i in range(len(a)):
        d = np.abs(b.c2w.astype(np.float64) - a.c2w[i].astype(np.float64)).max(axis=(1, 2))
        j = int(np.argmin(d))
        rows.append(
            {
                "index": i,
                "match": j,
                "name": b.names[j] if b.names else str(j),
                "pose_diff": float(d[j]),
                "psnr": psnr(a.images[i] / 255.0, b.images[j] / 255.0),
            }
        )
    return rows


def markdown_table(results: list[dict]) -> str:
    """The results as a markdown table, rows in the given order; '-' where a figure is missing."""

    def num(v, fmt):
        return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else format(v, fmt)

    lines = [
        "| scene | model | budget | steps | PSNR | SSIM | fps | MB | PSNR, npz's 10 val |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in results:
        lines.append(
            f"| {r['scene']} | {r['model']} | {r['budget']} | {r['steps']} | "
            f"{num(r['psnr'], '.2f')} | {num(r['ssim'], '.3f')} | {num(r['fps'], '.1f')} | "
            f"{num(r['model_mb'], '.2f')} | {num(r.get('psnr_npz_val'), '.2f')} |"
        )
    return "\n".join(lines) + "\n"


def results_csv(results: list[dict]) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(COLUMNS), extrasaction="ignore")
    w.writeheader()
    for r in results:
        w.writerow({k: (" ".join(f"{x:.2f}" for x in v) if isinstance(v, (list, tuple)) else v) for k, v in r.items()})
    return buf.getvalue()


# -- loading -----------------------------------------------------------------------------
def blender_views(folder: Path, split: str, width: int, height: int):
    """A Blender folder's ``split`` as :class:`~nerfkit.data.scene.Views` at ``width x height``:
    poses converted to OpenCV axes, K from ``camera_angle_x`` scaled to that size, images
    through :func:`downscale_rgba`."""
    from PIL import Image

    from nerfkit.cameras import opengl_to_opencv
    from nerfkit.config import load_json
    from nerfkit.data.blender import focal_from_angle, frame_image_path
    from nerfkit.data.resample import scale_intrinsics
    from nerfkit.data.scene import Views
    from nerfkit.data.validate import check_fov, check_poses

    where = folder / f"transforms_{split}.json"
    if not where.is_file():
        raise fail(folder, f"has no transforms_{split}.json", "Give --lego-blender the Blender lego folder")
    meta = load_json(where)
    frames = meta.get("frames") if isinstance(meta, dict) else None
    if not frames:
        raise fail(where, "has no frames", "Is this a Blender-style transforms file?")
    angle = check_fov(meta.get("camera_angle_x"), str(where))
    c2w, images, names, size = [], [], [], None
    for i, fr in enumerate(frames):
        if not isinstance(fr, dict) or "file_path" not in fr or "transform_matrix" not in fr:
            raise fail(where, f"frames[{i}] needs 'file_path' and 'transform_matrix'")
        path = frame_image_path(folder, str(fr["file_path"]), str(where))
        with Image.open(path) as im:
            if im.mode not in ("RGB", "RGBA"):
                raise fail(path, f"is a {im.mode} image", "Expected the Blender scene's 8-bit RGBA PNGs")
            pixels = np.asarray(im)
        if size is None:
            size = pixels.shape[1], pixels.shape[0]
        elif size != (pixels.shape[1], pixels.shape[0]):
            raise fail(path, f"is {pixels.shape[1]}x{pixels.shape[0]}, the split's first image {size[0]}x{size[1]}")
        images.append(downscale_rgba(pixels, width, height))
        c2w.append(np.asarray(fr["transform_matrix"], np.float64).reshape(-1, 4)[:4])
        names.append(str(fr["file_path"]).removeprefix("./"))
    poses = opengl_to_opencv(check_poses(np.stack(c2w), str(where), "transform_matrix").astype(np.float64))
    f = focal_from_angle(float(angle), size[0])
    K = scale_intrinsics(np.array([[f, 0, size[0] / 2], [0, f, size[1] / 2], [0, 0, 1]]), *size, width, height)
    return Views(
        poses.astype(np.float32), np.repeat(K[None], len(frames), axis=0), width, height, np.stack(images), names
    )


def load_lego200(blender: Path, notes: list[str]) -> BenchScene:
    from nerfkit.data.npz import load_npz

    npz = load_npz(LEGO_NPZ)
    val = blender_views(blender, "val", npz.train.width, npz.train.height)
    if not np.allclose(val.K[0], npz.train.K[0], rtol=1e-4, atol=1e-3):
        raise fail(
            blender,
            f"its val cameras at {val.width}x{val.height} have K {val.K[0].tolist()}, the npz's "
            f"{npz.train.K[0].tolist()}",
            "Is this the lego scene?",
        )
    matched = match_views(npz.val, val)
    worst_pose = max(m["pose_diff"] for m in matched)
    psnrs = [m["psnr"] for m in matched]
    notes.append(
        f"lego200 check: the npz's {len(npz.val)} val views are the Blender folder's "
        f"{', '.join(m['name'] for m in matched)} (poses equal to {worst_pose:.1e}; the images, downscaled "
        f"here, agree to {min(psnrs):.1f}-{max(psnrs):.1f} dB PSNR); K equal "
        f"(focal {val.K[0, 0, 0]:.3f} px)"
    )
    return BenchScene(
        "lego200",
        without_heldout(npz),
        val,
        {"npz_val": npz.val},
        f"lego200: {len(npz.train)} npz train views, {len(val)} Blender val views downscaled to "
        f"{val.width}x{val.height} (and the npz's {len(npz.val)} val views)",
    )


def load_lego400(blender: Path) -> BenchScene:
    from nerfkit.data.blender import load_blender

    scene = load_blender(blender, test_images=False)
    if not scene.val.has_images:
        raise fail(blender, "has no val views to score", "Give --lego-blender the Blender lego folder")
    return BenchScene(
        "lego400",
        without_heldout(scene),
        scene.val,
        {},
        f"lego400: {len(scene.train)} Blender train views, its {len(scene.val)} val views, "
        f"{scene.train.width}x{scene.train.height}",
    )


def load_flower(folder: Path, downscale: float, name: str = "flower") -> BenchScene:
    """``flower`` or one of :data:`FLOWER_SUBSETS` (fewer train photos, the same held-out ones)."""
    from nerfkit.data.llff import HOLDOUT_EVERY, load_llff

    scene = load_llff(folder, downscale=downscale if downscale != 1 else None)
    if not scene.val.has_images:
        raise fail(folder, "holds too few photos to hold any out")
    kept = ""
    if name in FLOWER_SUBSETS:
        k, offset = FLOWER_SUBSETS[name]
        if len(scene.train) < k:
            raise fail(folder, f"has {len(scene.train)} training photos, {name} keeps {k}")
        keep = even_subset(len(scene.train), k, offset)
        scene = replace(scene, train=scene.train.subset(keep))
        kept = f" ({', '.join(scene.train.names)})"
    return BenchScene(
        name,
        without_heldout(scene),
        scene.val,
        {},
        f"{name}: {len(scene.train)} train photos{kept}, every {HOLDOUT_EVERY}th held out "
        f"({', '.join(scene.val.names)}), {scene.train.width}x{scene.train.height}",
    )


def load_capture(name: str, path: Path) -> BenchScene:
    from nerfkit.data.load import load_scene

    scene = load_scene(path)
    if not scene.val.has_images:
        raise fail(path, "has no val photos to score", "Give a posed capture dataset (nerfkit poses' output)")
    return BenchScene(
        name,
        without_heldout(scene),
        scene.val,
        {},
        f"{name}: {len(scene.train)} train photos, its {len(scene.val)} val photos as rendered, "
        f"{scene.train.width}x{scene.train.height}",
    )


# -- training and scoring ----------------------------------------------------------------
def score_views(model, views, background, chunk: int, autocast) -> dict:
    """Render every view (one warm-up frame first, not timed) and score it against its image:
    ``{"psnr", "ssim"}`` means, ``"n"`` views, ``"fps"`` (renders only) and ``"views"``: each view's PSNR."""
    import torch

    from nerfkit.output.images import render_image
    from nerfkit.train.metrics import psnr, ssim

    def render(i):
        return render_image(model, views.K[i], views.c2w[i], views.width, views.height, background, chunk, autocast).rgb

    p, s, seconds = [], [], 0.0
    with torch.no_grad():
        render(0)
        for i in range(len(views)):
            t = time.perf_counter()
            rgb = render(i)
            seconds += time.perf_counter() - t
            target = views.images[i].astype(np.float32) / 255.0
            p.append(psnr(rgb, target))
            s.append(ssim(rgb, target))
    return {
        "psnr": float(np.mean(p)),
        "ssim": float(np.mean(s)),
        "n": len(views),
        "fps": len(views) / seconds,
        "views": [round(float(x), 3) for x in p],
    }


def parse_variant(text: str) -> tuple[str, str, dict]:
    """``"NAME:FIELD=VALUE,..."`` -> (label, base model, {field: value}); NAME is
    ``MODEL+SUFFIX`` (``fast+tv``) and each VALUE a Python literal. A comma starts a new
    FIELD=VALUE only where a name and ``=`` follow it, so a value may hold commas
    (``upsample_steps='60,300,1000'``)."""
    import ast
    import re

    label, sep, body = text.partition(":")
    base = label.split("+")[0]
    if not sep or not label or not body:
        raise fail("--variant", f"{text!r} is not NAME:FIELD=VALUE[,FIELD=VALUE...]", "e.g. fast+tv:tv_weight=1e-4")
    changes = {}
    for item in re.split(r",(?=\s*[A-Za-z_]\w*\s*=)", body):
        field, eq, value = item.partition("=")
        if not eq:
            raise fail("--variant", f"{item!r} in {text!r} is not FIELD=VALUE")
        try:
            changes[field.strip()] = ast.literal_eval(value.strip())
        except (ValueError, SyntaxError):
            changes[field.strip()] = value.strip()
    return label, base, changes


def apply_changes(cfg, model_cfg, changes: dict, label: str):
    """(cfg, model_cfg) with ``changes`` applied to whichever config has each field."""
    names_model = {f.name for f in fields(model_cfg)}
    names_train = {f.name for f in fields(cfg)}
    for key, value in changes.items():
        if key in names_model:
            model_cfg = replace(model_cfg, **{key: value})
        elif key in names_train:
            cfg = replace(cfg, **{key: value})
        else:
            raise fail("--variant", f"{label}: no setting named {key!r} in the model or training config")
    return cfg, model_cfg


def train_and_score(
    bench: BenchScene,
    model_name: str,
    seconds: float | None,
    steps: int | None,
    run_dir: Path,
    seed: int,
    changes: dict | None = None,
    label: str | None = None,
) -> dict | None:
    """Train ``model_name`` on ``bench.train`` for ``seconds`` of training (or ``steps``)
    into ``run_dir`` with the defaults ``nerfkit train`` picks, then score the held-out
    views; the run's figures."""
    from nerfkit import presets
    from nerfkit.models import check_config, model_config_class
    from nerfkit.train.checkpoint import MODEL_FILE
    from nerfkit.train.config import TrainConfig
    from nerfkit.train.trainer import Trainer

    scene = bench.train
    cfg = TrainConfig(
        data=scene.source,
        model=model_name,
        out=str(run_dir),
        seed=seed,
        minutes=0.0 if seconds is None else seconds / 60.0,
        steps=steps or 0,
        checkpoint_seconds=1e9,
    )
    cfg, model_cfg = presets.resolve(cfg.validate(), model_config_class(model_name)(), scene).configs()
    cfg, model_cfg = apply_changes(cfg, model_cfg, changes or {}, label or model_name)
    check_config(model_name, model_cfg)
    load_before = os.getloadavg()
    trainer = Trainer(scene, cfg, model_cfg, quiet=True)
    result = trainer.run()
    if result.interrupted:  # a shortened run is not the budget's row
        return None
    load_after = os.getloadavg()
    main = score_views(trainer.model, bench.heldout, trainer.background, cfg.render_chunk, trainer.autocast)
    row = {
        "scene": bench.name,
        "model": label or model_name,
        "budget": budget_label(seconds, steps),
        "budget_s": seconds,
        "budget_steps": steps,
        "steps": result.step,
        "train_s": round(result.train_seconds, 2),
        "psnr": main["psnr"],
        "ssim": main["ssim"],
        "fps": main["fps"],
        "model_mb": (run_dir / MODEL_FILE).stat().st_size / 1e6,
        "n_heldout": main["n"],
        "psnr_views": main["views"],
        "n_train": len(scene.train),
        "width": bench.heldout.width,
        "height": bench.heldout.height,
        "loadavg_before": [round(x, 2) for x in load_before],
        "loadavg_after": [round(x, 2) for x in load_after],
    }
    for label, views in bench.extra.items():
        other = score_views(trainer.model, views, trainer.background, cfg.render_chunk, trainer.autocast)
        row.update({f"psnr_{label}": other["psnr"], f"ssim_{label}": other["ssim"]})
    if hasattr(trainer.model, "n_gaussians"):
        row["n_gaussians"] = int(trainer.model.n_gaussians)
    return row


# -- command line ------------------------------------------------------------------------
def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument(
        "--lego-blender",
        type=Path,
        metavar="DIR",
        help="the Blender lego folder (transforms_train/val.json, RGBA PNGs): lego200's 100 val views and lego400",
    )
    p.add_argument("--llff", type=Path, metavar="DIR", help="the LLFF flower folder (poses_bounds.npy, images_8/)")
    p.add_argument(
        "--llff-downscale",
        type=float,
        default=8.0,
        help="the LLFF photos' divisor (8: images_8, as the papers score it)",
    )
    p.add_argument(
        "--capture",
        action="append",
        default=[],
        metavar="NAME=DATASET",
        help="a posed capture dataset scored on its val photos (repeatable)",
    )
    p.add_argument(
        "--scenes",
        help="comma-separated: lego200, lego400, flower, flower17, flower17b, forward (the "
        "three flower cases), captures (all of them) or a capture's NAME (default: every "
        "scene whose data is given, without flower's subsets)",
    )
    p.add_argument(
        "--models",
        default="fast,splat",
        help="comma-separated model names (empty with --variant: only the variants)",
    )
    p.add_argument("--seconds", default="60,300", help="training budgets in seconds, comma-separated")
    p.add_argument(
        "--steps",
        help="training budgets in steps instead, comma-separated (a check of the protocol on "
        "a busy machine, where seconds buy few steps)",
    )
    p.add_argument(
        "--variant",
        action="append",
        default=[],
        metavar="NAME:FIELD=VALUE,...",
        help="also run model NAME's prefix (fast+tv -> fast) with these settings changed (repeatable)",
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, help="folder for the runs, table.md, results.csv and results.json")
    return p.parse_args(argv)


def run(args) -> int:
    from nerfkit.models import MODEL_NAMES

    models = parse_models(args.models, args.variant)
    for m in models:
        if m not in MODEL_NAMES:
            raise fail("--models", f"unknown model {m!r}", f"Choose from {', '.join(MODEL_NAMES)}")
    if args.steps is not None:
        budgets = [(None, n) for n in sorted(parse_list(args.steps, int, "--steps"))]
        if any(n < 1 for _, n in budgets):
            raise fail("--steps", f"{args.steps!r}: budgets must be positive step counts")
    else:
        budgets = [(b, None) for b in sorted(parse_list(args.seconds, float, "--seconds"))]
        if any(not (b > 0 and math.isfinite(b)) for b, _ in budgets):
            raise fail("--seconds", f"{args.seconds!r}: budgets must be positive seconds")
    runs = [(m, m, {}) for m in models] + [parse_variant(v) for v in args.variant]
    for label, base, _ in runs:
        if base not in MODEL_NAMES:
            raise fail("--variant", f"{label}: unknown model {base!r}", f"Choose from {', '.join(MODEL_NAMES)}")
    captures = parse_captures(args.capture)
    have = {
        "lego200": args.lego_blender is not None,
        "lego400": args.lego_blender is not None,
        **{n: args.llff is not None for n in FORWARD},
    }
    names = choose_scenes(
        None if args.scenes is None else parse_list(args.scenes, str, "--scenes"), have, list(captures)
    )
    notes: list[str] = []
    scenes = []
    for n in names:  # every held-out view is loaded here, before any training
        if n == "lego200":
            scenes.append(load_lego200(args.lego_blender, notes))
        elif n == "lego400":
            scenes.append(load_lego400(args.lego_blender))
        elif n in FORWARD:
            scenes.append(load_flower(args.llff, args.llff_downscale, n))
        else:
            scenes.append(load_capture(n, captures[n]))
        print(scenes[-1].about, flush=True)
    for note in notes:
        print(note, flush=True)

    temp = None
    if args.out is None:
        temp = tempfile.TemporaryDirectory(prefix="nerfkit_heldout_")
        out = Path(temp.name)
    else:
        out = args.out
    (out / "runs").mkdir(parents=True, exist_ok=True)
    results: list[dict] = []
    try:
        for seconds, steps in budgets:
            budget = budget_label(seconds, steps)
            for bench in scenes:
                for label, model, changes in runs:
                    run_dir = out / "runs" / f"{bench.name}_{label}_{budget.replace(' ', '')}"
                    if run_dir.exists():  # this benchmark's own earlier run: redone
                        shutil.rmtree(run_dir)
                    row = train_and_score(bench, model, seconds, steps, run_dir, args.seed, changes, label)
                    if row is None:
                        print(f"{bench.name} {label} {budget}: interrupted, not scored; stopping", flush=True)
                        return 130
                    results.append(row)
                    gc.collect()
                    extra = f" (npz's 10 val: {row['psnr_npz_val']:.2f})" if "psnr_npz_val" in row else ""
                    print(
                        f"{bench.name} {label} {budget}: {row['steps']} steps, PSNR {row['psnr']:.2f} dB"
                        f"{extra}, SSIM {row['ssim']:.3f}, {row['fps']:.1f} fps, {row['model_mb']:.2f} MB",
                        flush=True,
                    )
                    if temp is None:
                        write_outputs(out, results, scenes, notes)
        order = {b.name: i for i, b in enumerate(scenes)}
        results.sort(
            key=lambda r: (
                order[r["scene"]],
                r["budget_steps"] or 0,
                r["budget_s"] or 0,
                [lb for lb, _, _ in runs].index(r["model"]),
            )
        )
        if temp is None:
            write_outputs(out, results, scenes, notes)
        print()
        print(
            markdown_table(results)
            + "\n"
            + "\n".join(f"- {s.about}" for s in scenes)
            + "".join(f"\n- {n}" for n in notes)
        )
    finally:
        if temp is not None:
            temp.cleanup()
    return 0


def write_outputs(out: Path, results: list[dict], scenes: list[BenchScene], notes: list[str]) -> None:
    from nerfkit.io.atomic import write_json, write_text

    text = (
        markdown_table(results)
        + "\n"
        + "\n".join(f"- {s.about}" for s in scenes)
        + "".join(f"\n- {n}" for n in notes)
        + "\n"
    )
    write_text(out / "table.md", text)
    write_text(out / "results.csv", results_csv(results))
    write_json(out / "results.json", {"scenes": [s.about for s in scenes], "notes": notes, "runs": results})


def main(argv=None) -> int:
    try:
        return run(parse_args(argv))
    except NerfkitError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
