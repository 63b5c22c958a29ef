"""The ``nerfkit`` command: one subcommand per module in :mod:`nerfkit.commands`.

Each command module defines ``register(subparsers)``, which adds its parser and sets
``func`` to a ``run(args) -> int`` function. Heavy imports (torch, OpenCV) happen inside
``run`` so that ``nerfkit --help`` stays instant.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import traceback

from .errors import NerfkitError

# In the order --help lists them.
COMMANDS = [
    "demo",
    "train",
    "render",
    "eval",
    "fit-image",
    "convert",
    "export",
    "calibrate",
    "poses",
    "dataset",
    "view",
]

DESCRIPTION = """\
nerfkit: phone photos to neural radiance fields, practical on a CPU.

typical flows:
  nerfkit demo                                  train on the bundled lego scene, write videos and plots
  nerfkit train --data scene.npz --out runs/x   train a NeRF on a dataset
  nerfkit render runs/x                         orbit video + depth video of a trained run
  nerfkit eval runs/x --split val               PSNR/SSIM on held-out views, as JSON
  nerfkit fit-image photo.jpg                   the course warm-up: fit an MLP (x, y) -> RGB to one image
"""


def build_parser(only: str | None = "") -> argparse.ArgumentParser:
    """The full parser; with ``only`` a command name (or None for no command), the other
    commands get a one-line stub, which is all the top-level ``--help`` shows. Registering
    ``train`` imports torch (its model flags), so ``nerfkit --help`` skips it."""
    parser = argparse.ArgumentParser(prog="nerfkit", description=DESCRIPTION,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--verbose", action="store_true", help="show full tracebacks on errors")
    parser.add_argument("--version", action="version", version=f"nerfkit {_version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        module = importlib.import_module(f"nerfkit.commands.{name.replace('-', '_')}")
        if only == "" or name == only:
            module.register(sub)
        else:
            sub.add_parser(name, help=module.HELP)
    return parser


def command_in(argv: list[str]) -> str | None:
    """The subcommand named in ``argv`` (the first word that is not an option), if any."""
    return next((a for a in argv if not a.startswith("-")), None)


def _version() -> str:
    from . import __version__

    return __version__


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = build_parser(command_in(argv))
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except NerfkitError as e:
        if args.verbose:
            traceback.print_exc()
        print(f"nerfkit {args.command}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"nerfkit {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
