"""Peak memory of the memory-hungry paths.

Each case runs in a fresh child process, which reports its own peak RSS
(``getrusage(RUSAGE_SELF).ru_maxrss``) right after setup (imports, model, data) and after
the work; the difference is what the work itself added. The cases:

* ``render_vanilla``  one 800x800 frame from a small vanilla NeRF, chunked renderer
                      (also at a 4x larger chunk: the peak follows the chunk, not the image);
* ``render_fast``     one 800x800 frame from the ``fast`` model (briefly trained, so its
                      occupancy grid is active), when ``nerfkit.models.fast`` imports;
* ``eval_views``      ``evaluate_views`` over 30 and over 120 validation views of a
                      synthetic sphere (the peak must not grow with the number of views);
* ``train_steps``     current RSS of a small vanilla ``Trainer`` after 50 and after 500 steps;
* ``photo_12mp``      one 12-MP JPEG through ``load_image_uint8`` and through the float32
                      path (``load_image``), to show what each costs;
* ``photos_folder``   ``nerfkit.capture.photos.scan_photos`` over 100 synthetic 12-MP JPEGs
                      (made in a temporary folder and deleted afterwards), 2 worker threads.

Usage::

    python benchmarks/memory.py                 # every case, then a table
    python benchmarks/memory.py --quick         # smaller counts (20 photos, 200 steps)
    python benchmarks/memory.py --cases render_vanilla,eval_views

Linux/macOS only (``resource``). Single-threaded torch unless ``--threads`` says otherwise.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CASES = ["render_vanilla", "render_fast", "eval_views", "train_steps", "photo_12mp", "photos_folder"]


def peak_mb() -> float:
    """Peak RSS of this process so far, MB (ru_maxrss is KB on Linux, bytes on macOS)."""
    r = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return r / (1024 * 1024) if sys.platform == "darwin" else r / 1024


def current_mb() -> float:
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return float("nan")


# ----------------------------------------------------------------------------- cases (run in a child)


def _sphere_bounds(size: int = 32):
    from nerfkit.data.synthetic import sphere_scene
    from nerfkit.models import SceneBounds

    scene = sphere_scene(n_train=8, n_val=1, size=size)
    return scene, SceneBounds.from_scene(scene)


def case_render_vanilla(args) -> dict:
    import torch

    from nerfkit.models.vanilla import VanillaConfig, VanillaNeRF
    from nerfkit.output.images import render_image
    from nerfkit.presets import MODEL_TRAINING

    scene, bounds = _sphere_bounds()
    model = VanillaNeRF(VanillaConfig(n_samples=16, width=32, depth=2), bounds)
    bg = torch.zeros(3)
    K = scene.train.K[0].copy()
    K[:2] *= 800 / scene.train.width
    chunk = args.chunk or MODEL_TRAINING["vanilla"]["render_chunk"]
    base = peak_mb()
    t = time.perf_counter()
    view = render_image(model, K, scene.train.c2w[0], 800, 800, bg, chunk=chunk)
    seconds = time.perf_counter() - t
    full = 800 * 800 * 16 * 32 * 4 / 1e9  # one activation of the whole image at once, GB
    return {
        "base": base,
        "peak": peak_mb(),
        "seconds": seconds,
        "shape": list(view.rgb.shape),
        "note": f"chunk {chunk} rays, 16 samples, width 32; unchunked, one activation alone is {full:.1f} GB",
    }


def case_render_fast(args) -> dict:
    import torch

    try:
        from nerfkit.models.fast import FastConfig
    except ImportError as e:
        return {"skipped": f"nerfkit.models.fast does not import ({e})"}
    from nerfkit import presets
    from nerfkit.output.images import render_image
    from nerfkit.train.config import TrainConfig
    from nerfkit.train.trainer import Trainer

    scene, _ = _sphere_bounds(size=32)
    out = Path(tempfile.mkdtemp(prefix="nerfkit-mem-"))
    try:
        mcfg = FastConfig(resolutions="64", upsample_steps="")
        cfg = presets.without_scene(
            TrainConfig(
                data="x",
                model="fast",
                out=str(out / "run"),
                steps=60,
                eval_every=10**6,
                eval_views=1,
                checkpoint_seconds=1e9,
            )
        )
        trainer = Trainer(scene, cfg, mcfg, quiet=True)
        trainer.run()
        model = trainer.model.eval()
        chunk = args.chunk or cfg.render_chunk
        K = scene.train.K[0].copy()
        K[:2] *= 800 / scene.train.width
        base = peak_mb()
        t = time.perf_counter()
        render_image(model, K, scene.val.c2w[0], 800, 800, torch.zeros(3), chunk=chunk)
        seconds = time.perf_counter() - t
    finally:
        shutil.rmtree(out, ignore_errors=True)
    return {"base": base, "peak": peak_mb(), "seconds": seconds, "note": f"chunk {chunk} rays, 64^3 grid, 60 steps"}


def case_eval_views(args) -> dict:
    import torch

    from nerfkit.data.synthetic import sphere_scene
    from nerfkit.models import SceneBounds
    from nerfkit.models.vanilla import VanillaConfig, VanillaNeRF
    from nerfkit.train.evaluate import evaluate_views

    scene = sphere_scene(n_train=4, n_val=args.views, size=args.size, n_test=1)
    model = VanillaNeRF(VanillaConfig(n_samples=16, width=32, depth=2), SceneBounds.from_scene(scene))
    base = peak_mb()
    t = time.perf_counter()
    result = evaluate_views(model, scene.val, torch.zeros(3), chunk=4096, progress=False)
    seconds = time.perf_counter() - t
    images_mb = scene.val.images.nbytes / 1e6
    return {
        "base": base,
        "peak": peak_mb(),
        "seconds": seconds,
        "n": result["n_images"],
        "note": f"{args.views} views of {args.size}x{args.size}; their uint8 images hold {images_mb:.1f} MB",
    }


def case_train_steps(args) -> dict:
    import gc

    from nerfkit import presets
    from nerfkit.data.synthetic import sphere_scene
    from nerfkit.models.vanilla import VanillaConfig
    from nerfkit.train.config import TrainConfig
    from nerfkit.train.trainer import Trainer

    scene = sphere_scene(n_train=20, n_val=2, size=32)
    out = Path(tempfile.mkdtemp(prefix="nerfkit-mem-"))
    try:
        mcfg = VanillaConfig(n_samples=16, width=32, depth=2)
        cfg = presets.without_scene(
            TrainConfig(
                data="x",
                model="vanilla",
                out=str(out / "run"),
                steps=args.steps,
                batch_rays=256,
                eval_every=10**6,
                eval_views=1,
                checkpoint_seconds=1e9,
            )
        )
        trainer = Trainer(scene, cfg, mcfg, quiet=True)
        trainer.run(stop_after=50)
        gc.collect()
        at_50, peak_50 = current_mb(), peak_mb()
        t = time.perf_counter()
        trainer.run()
        seconds = time.perf_counter() - t
        gc.collect()
        at_end = current_mb()
    finally:
        shutil.rmtree(out, ignore_errors=True)
    return {
        "base": peak_50,
        "peak": peak_mb(),
        "seconds": seconds,
        "rss_50": at_50,
        "rss_end": at_end,
        "note": f"current RSS {at_50:.0f} MB after 50 steps, {at_end:.0f} MB after {args.steps} "
        f"({(at_end - at_50) / max(args.steps - 50, 1) * 1024:.1f} KB/step)",
    }


def make_photos(folder: Path, n: int, width: int = 4000, height: int = 3000) -> None:
    """n synthetic 12-MP JPEGs (one encoded photo copied under n names: decoding is what costs)."""
    import numpy as np
    from PIL import Image

    small = np.random.default_rng(0).integers(0, 256, (height // 16, width // 16, 3), dtype=np.uint8)
    Image.fromarray(small).resize((width, height), Image.Resampling.BICUBIC).save(folder / "IMG_0000.jpg", quality=90)
    for i in range(1, n):
        shutil.copyfile(folder / "IMG_0000.jpg", folder / f"IMG_{i:04d}.jpg")


def case_photo_12mp(args) -> dict:
    import numpy as np

    from nerfkit.images import load_image, load_image_uint8

    photo = Path(args.photos_dir) / "IMG_0000.jpg"
    base = peak_mb()
    if args.path == "float":
        img = (load_image(photo) * 255.0 + 0.5).astype(np.uint8)  # what load_image_uint8 did before the fix
    else:
        img = load_image_uint8(photo)
    return {"base": base, "peak": peak_mb(), "note": f"{args.path} path, result {img.nbytes / 1e6:.0f} MB uint8"}


def case_photos_folder(args) -> dict:
    try:
        from nerfkit.capture.photos import scan_photos
    except ImportError as e:
        return {"skipped": f"nerfkit.capture.photos does not import ({e})"}
    files = sorted(Path(args.photos_dir).glob("*.jpg"))[: args.photos]
    size_mb = sum(p.stat().st_size for p in files) / 1e6
    base = peak_mb()
    t = time.perf_counter()
    records = scan_photos(args.photos_dir, "DICT_4X4_50", jobs=2, progress=False, files=files)
    seconds = time.perf_counter() - t
    all_f32 = args.photos * 4000 * 3000 * 3 * 4 / 1e9
    return {
        "base": base,
        "peak": peak_mb(),
        "seconds": seconds,
        "n": len(records),
        "note": f"{args.photos} JPEGs ({size_mb:.0f} MB on disk), 2 threads; all as float32 would be {all_f32:.1f} GB",
    }


# ----------------------------------------------------------------------------- driver


def run_child(case: str, extra: list[str], threads: int) -> dict:
    env = {**os.environ, "OMP_NUM_THREADS": str(threads), "MKL_NUM_THREADS": str(threads)}
    cmd = [sys.executable, __file__, "--child", case, "--threads", str(threads), *extra]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    if proc.returncode != 0 or not lines:
        return {"error": (proc.stderr.strip().splitlines() or [f"exit {proc.returncode}"])[-1]}
    return json.loads(lines[-1])


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--cases", default=",".join(CASES), help="comma-separated cases (default: all)")
    p.add_argument("--quick", action="store_true", help="20 photos and 200 training steps")
    p.add_argument("--threads", type=int, default=1, help="torch/OpenMP threads in each child (default: 1)")
    p.add_argument("--child", help=argparse.SUPPRESS)
    p.add_argument("--chunk", type=int, default=0, help=argparse.SUPPRESS)
    p.add_argument("--views", type=int, default=120, help=argparse.SUPPRESS)
    p.add_argument("--size", type=int, default=100, help=argparse.SUPPRESS)
    p.add_argument("--steps", type=int, default=500, help=argparse.SUPPRESS)
    p.add_argument("--photos", type=int, default=100, help=argparse.SUPPRESS)
    p.add_argument("--path", default="uint8", help=argparse.SUPPRESS)
    p.add_argument("--photos-dir", help=argparse.SUPPRESS)
    args = p.parse_args()

    if args.child:
        import torch

        torch.set_num_threads(args.threads)
        print(json.dumps(globals()[f"case_{args.child}"](args)), flush=True)
        return 0

    steps, photos = ("200", "20") if args.quick else ("500", "100")
    runs = {
        "render_vanilla": [("800x800, default chunk", []), ("800x800, chunk x4", ["--chunk", "16384"])],
        "render_fast": [("800x800, default chunk", [])],
        "eval_views": [("30 views", ["--views", "30"]), ("120 views", ["--views", "120"])],
        "train_steps": [(f"50 -> {steps} steps", ["--steps", steps])],
        "photo_12mp": [("load_image_uint8", ["--path", "uint8"]), ("float32 path", ["--path", "float"])],
        "photos_folder": [(f"scan_photos, {photos} x 12 MP", ["--photos", photos])],
    }
    rows = []
    cases = [c.strip() for c in args.cases.split(",") if c.strip()]
    photos_dir = Path(tempfile.mkdtemp(prefix="nerfkit-mem-photos-"))  # made here, outside the measured children
    try:
        if {"photo_12mp", "photos_folder"} & set(cases):
            print(f"making {photos} synthetic 12-MP JPEGs in {photos_dir} ...", file=sys.stderr, flush=True)
            make_photos(photos_dir, int(photos))
        for case in cases:
            for label, extra in runs[case]:
                print(f"running {case}: {label} ...", file=sys.stderr, flush=True)
                r = run_child(case, [*extra, "--photos-dir", str(photos_dir)], args.threads)
                rows.append((case, label, r))
    finally:
        shutil.rmtree(photos_dir, ignore_errors=True)
    print()
    print(f"{'case':16s} {'run':28s} {'setup MB':>9s} {'peak MB':>8s} {'added MB':>9s} {'time s':>7s}  note")
    print("-" * 120)
    for case, label, r in rows:
        if "error" in r or "skipped" in r:
            print(f"{case:16s} {label:28s} {'':>9s} {'':>8s} {'':>9s} {'':>7s}  {r.get('error') or r.get('skipped')}")
            continue
        added = r["peak"] - r["base"]
        secs = f"{r['seconds']:.1f}" if "seconds" in r else ""
        print(f"{case:16s} {label:28s} {r['base']:9.0f} {r['peak']:8.0f} {added:9.0f} {secs:>7s}  {r.get('note', '')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
