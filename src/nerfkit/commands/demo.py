"""`nerfkit demo`: the main job on the bundled lego scene, end to end (:func:`nerfkit.api.demo`)."""

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
    from .tools import DEMO_MINUTES

    minutes = ", ".join(f"{m:g} for {name}" for name, m in DEMO_MINUTES.items())
    p = sub.add_parser("demo", help=HELP, description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--model", choices=list(DEMO_MINUTES), default="fast", help="which NeRF (default: fast)")
    p.add_argument(
        "--minutes", type=number(float, above=0), default=None, help=f"training-time budget (default: {minutes})"
    )
    p.add_argument(
        "--out", default="runs/demo", help="run folder; a fresh one is picked if it exists (default: runs/demo)"
    )
    p.add_argument("--device", default="auto", help="auto, cpu, cuda (default: auto)")
    p.add_argument("--seed", type=number(int, 0, MAX_SEED), default=0, help="random seed (default: 0)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import json

    from .tools import demo

    result = demo(args.out, model=args.model, minutes=args.minutes, device=args.device, seed=args.seed)
    print(json.dumps(result.summary, indent=2))
    print("outputs:")
    for label, path in result.outputs.items():
        print(f"  {label:12s} {path}")
    return 0
