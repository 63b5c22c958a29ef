"""``nerfkit fit-image``: fit a coordinate MLP to one 2D image (the course warm-up)."""

from __future__ import annotations

import argparse

MEMORY_HINT = "Lower --batch and --chunk (pixels at once), --width and --depth (the model), or downscale the image"
HELP = "fit a neural field (x, y) -> RGB to one image; PSNR curve, progression figure, sweeps"

DESCRIPTION = """\
Train a coordinate MLP that maps normalised pixel coordinates (x, y) to RGB, and show how
it learned: sinusoidal positional encoding (L octaves), DEPTH hidden Linear+ReLU layers of
WIDTH, a Linear to 3 and a sigmoid; Adam, MSE on BATCH random pixels per step.

Writes into --out: psnr.png, progression.png, final.png, metrics.json, config.json.
With --sweep, one such folder per combination plus sweep_grid.png, sweep_psnr.png and
sweep.json.

Any JPEG/PNG/TIFF/WebP/HEIC works: greyscale, 16-bit, transparent (composited on
--background), EXIF-rotated phone photos (used upright), 12-megapixel photos (trained by
sampling pixels and rendered in chunks; the PSNR curve then uses a fixed random pixel
subset, the final PSNR every pixel). Without IMAGE, the bundled public-domain NASA
astronaut photo (nerfkit/assets/astronaut.jpg) is used.

examples:
  nerfkit fit-image                                  the bundled image, course defaults
  nerfkit fit-image fox.jpg --steps 1000 --out runs/fox
  nerfkit fit-image fox.jpg --sweep L=3,10 width=64,256
"""


def register(subparsers) -> None:
    from ..config import add_dataclass_args
    from ..fit_image import FitImageConfig

    p = subparsers.add_parser(
        "fit-image", help=HELP, description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("image", nargs="?", default=None, help="image file (default: the bundled astronaut photo)")
    p.add_argument("--out", default=None, help="run folder (default: runs/fit-image/<image name>[-sweep])")
    p.add_argument(
        "--sweep",
        nargs="+",
        default=None,
        metavar="KEY=V1,V2",
        help="train one model per combination, e.g. --sweep L=3,10 width=64,256 "
        "(keys: L, width, depth, lr, batch, steps)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--force", action="store_true", help="replace the results of an earlier fit in --out")
    add_dataclass_args(p, FitImageConfig, group_title="model and training")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """``nerfkit fit-image``: :func:`nerfkit.api.fit_image` with the parsed flags; its ``--quiet``
    drops the progress bar, not the report."""
    from ..config import dataclass_from_args
    from ..fit_image import FitImageConfig
    from .stages.fit_image import fit_report
    from .tools import fit_image

    cfg = dataclass_from_args(FitImageConfig, args)
    image = args.image
    sweep = list(args.sweep) if args.sweep else None
    # "--sweep L=3,10 photo.jpg": argparse hands the image to --sweep; take it back.
    if sweep and image is None and "=" not in sweep[-1]:
        image = sweep.pop()
    result = fit_image(image, out=args.out, sweep=sweep, quiet=args.quiet, force=args.force, settings=cfg)
    if args.quiet:  # (the call printed nothing)
        print(fit_report(result, cfg.eval_every))
    return 130 if result.interrupted else 0
