"""`nerfkit demo`: the main job on the bundled lego scene, end to end."""

from __future__ import annotations

import argparse

HELP = "train on the bundled lego scene, then write videos, plots and metrics"
DESCRIPTION = """\
Train a NeRF on the bundled lego scene (200x200, 100 training views; NeRF synthetic
dataset, Mildenhall et al. 2020, CC BY 3.0), then render the 60 test poses to an MP4, a
GIF and a depth video, evaluate PSNR/SSIM on the 10 validation views, and print where
everything is. Defaults finish in a few minutes on a 2-core CPU.
"""


def register(sub: argparse._SubParsersAction) -> None:
    from ..config import MAX_SEED, number

    p = sub.add_parser("demo", help=HELP, description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--model", choices=["fast", "vanilla"], default="fast", help="which NeRF (default: fast)")
    p.add_argument(
        "--minutes",
        type=number(float, above=0),
        default=None,
        help="training-time budget (default: 3 for fast, 8 for vanilla)",
    )
    p.add_argument(
        "--out", default="runs/demo", help="run folder; a fresh one is picked if it exists (default: runs/demo)"
    )
    p.add_argument("--device", default="auto", help="auto, cpu, cuda (default: auto)")
    p.add_argument("--seed", type=number(int, 0, MAX_SEED), default=0, help="random seed (default: 0)")
    p.set_defaults(func=run)


def bundled_lego():
    from importlib.resources import files

    return files("nerfkit") / "assets" / "lego_200x200.npz"


def _fresh_folder(path: str):
    from pathlib import Path

    p = Path(path)
    i = 2
    while (p / "config.json").exists():
        p = Path(f"{path}-{i}")
        i += 1
    return p


def run(args: argparse.Namespace) -> int:
    import json
    import time

    import torch

    from ..data.npz import load_npz
    from ..io.atomic import write_json
    from ..models import model_config_class
    from ..output.videos import render_videos
    from ..train.checkpoint import load_run
    from ..train.config import TrainConfig, parse_background, resolve_autocast, resolve_device
    from ..train.trainer import train
    from .pipeline import evaluate

    t_start = time.perf_counter()
    device = resolve_device(args.device)  # a device that is not there: refused before anything is said or written
    data = str(bundled_lego())
    scene = load_npz(data)
    out = _fresh_folder(args.out)
    minutes = args.minutes if args.minutes is not None else (3.0 if args.model == "fast" else 8.0)
    cfg = TrainConfig(data=data, model=args.model, out=str(out), minutes=minutes, seed=args.seed, device=args.device)
    print(f"nerfkit demo: training '{args.model}' on lego for {minutes:g} min into {out}")
    result = train(
        scene, cfg, model_config_class(args.model)(), user_set={"data", "model", "out", "minutes", "seed", "device"}
    )  # the rest: the preset's

    model, info, _ = load_run(out, device)
    bg = torch.tensor(parse_background(info.train.background), device=device)
    autocast = resolve_autocast(info.train.precision, device)
    views = scene.render_path()
    if args.model == "vanilla":  # the big MLP renders ~10 s per frame on a CPU: half the frames
        views = views.subset(range(0, len(views), 2))
    videos = render_videos(
        model, views, out / "videos", bg, scene.near, scene.far, 30, info.train.render_chunk, autocast
    )
    # scored as `nerfkit eval` scores it: eval_val.json and the photos beside the renders
    metrics = evaluate(out, split="val", device=args.device, quiet=True).scores
    summary = {
        "model": args.model,
        "steps": result.step,
        "train_seconds": round(result.train_seconds, 1),
        "val_psnr": metrics["psnr"],
        "val_ssim": metrics["ssim"],
        "render_seconds_per_frame": round(videos.seconds_per_frame, 3),
        "total_seconds": round(time.perf_counter() - t_start, 1),
    }
    write_json(out / "summary.json", summary)
    print(json.dumps(summary, indent=2))
    print("outputs:")
    for label, path in [
        ("orbit video", videos.rgb_mp4),
        ("orbit GIF", videos.rgb_gif),
        ("depth video", videos.depth_mp4),
        ("PSNR curve", out / "plots" / "psnr.png"),
        ("loss curve", out / "plots" / "loss.png"),
        ("progression", out / "plots" / "progress.png"),
        ("metrics", out / "metrics.csv"),
        ("evaluation", out / "eval_val.json"),
        ("val views", out / "eval_val.png"),
    ]:
        print(f"  {label:12s} {path}")
    return 0
