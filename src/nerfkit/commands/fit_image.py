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
    from pathlib import Path

    from ..config import dataclass_from_args
    from ..errors import fail
    from ..fit_image import (
        RUN_FILES,
        FitImageConfig,
        default_image_path,
        parse_sweep,
        run_fit,
        run_sweep,
        sweep_folder,
        sweep_outputs,
    )
    from ..io.paths import guard_outputs, refuse_links

    cfg = dataclass_from_args(FitImageConfig, args)
    image = args.image
    sweep = list(args.sweep) if args.sweep else None
    # "--sweep L=3,10 photo.jpg": argparse hands the image to --sweep; take it back.
    if sweep and image is None and "=" not in sweep[-1]:
        image = sweep.pop()
    if sweep is not None and not sweep:
        raise fail("--sweep", "no KEY=V1,V2 items", "Example: --sweep L=3,10 width=64,256")
    stem = Path(image).stem if image else default_image_path().stem
    out = Path(args.out) if args.out else Path("runs") / "fit-image" / (stem + ("-sweep" if sweep else ""))
    combos = parse_sweep(sweep) if sweep else None
    outputs = sweep_outputs(out, combos) if combos else [out / name for name in RUN_FILES]
    guard_outputs(outputs, [image], args.force)
    if combos:  # each combination's run folder is the sweep's own
        refuse_links(out, [sweep_folder(out, c).name for c in combos])
    progress = not args.quiet

    if combos:
        entries = run_sweep(image, out, cfg, combos, progress=progress)
        for e in entries:
            print(f"{e['label']:30s} PSNR {e['final_psnr_db']:6.2f} dB  {e['steps_per_s']:6.1f} steps/s")
        print(
            f"wrote {out}/sweep_grid.png, sweep_psnr.png, sweep.json and {len(entries)} "
            f"run folder{'s' * (len(entries) != 1)}"
        )
    else:
        r = run_fit(image, out, cfg, progress=progress)
        if r.interrupted:
            print(f"interrupted at step {r.config.steps}: what was fitted is written")
        print(
            f"final PSNR {r.final_psnr:.2f} dB (every pixel, {r.width}x{r.height}) after {r.config.steps} steps; "
            f"{r.steps_per_s:.1f} steps/s on {r.device} ({r.precision}), "
            f"{r.train_seconds:.1f} s training + {r.eval_seconds:.1f} s evaluation"
        )
        print(f"curve: {r.eval_note}, every {cfg.eval_every} steps")
        print(f"wrote {out}/psnr.png, progression.png, final.png, metrics.json, config.json")
        return 130 if r.interrupted else 0
    return 0
