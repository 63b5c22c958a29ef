"""The ``nerfkit`` command: one subcommand per module in :mod:`nerfkit.commands`.

Each command module defines ``register(subparsers)``, which adds its parser and sets
``func`` to a ``run(args) -> int`` function. Heavy imports (torch, OpenCV) happen inside
``run`` so that ``nerfkit --help`` stays instant.
"""

from __future__ import annotations

import argparse
import importlib
import signal
import sys
import traceback

from .errors import NerfkitError, is_out_of_memory, os_error

# In the order --help lists them.
COMMANDS = [
    "demo",
    "capture",
    "frames",
    "train",
    "render",
    "eval",
    "fit-image",
    "convert",
    "export",
    "tags",
    "calibrate",
    "poses",
    "dataset",
    "view",
]

DESCRIPTION = """\
nerfkit: phone photos to neural radiance fields, practical on a CPU.

typical flows:
  nerfkit demo                                  train on the bundled lego scene, write videos and plots
  nerfkit tags --out tags.pdf                   printable ArUco tags: a calibration sheet, a tag for the object
  nerfkit capture photos/ --calib sheet/ --tag-size 0.06 --out my_object/
                                                your phone photos -> dataset, NeRF, videos, mesh
  nerfkit train --data scene.npz --out runs/x   train a NeRF on a dataset
  nerfkit render runs/x                         orbit video + depth video of a trained run
  nerfkit eval runs/x --split val               PSNR/SSIM on held-out views (and a JSON file)
  nerfkit fit-image photo.jpg                   the course warm-up: fit an MLP (x, y) -> RGB to one image
"""


class UsageError(Exception):
    """A bad command line (unknown flag, a number out of range): one line, exit code 2."""


class Parser(argparse.ArgumentParser):
    """argparse, but a bad command line is one line on stderr (as every other error is),
    not the usage block: ``nerfkit render: error: argument --fps: 0 is below the minimum 1``."""

    def error(self, message: str):
        raise UsageError(f"{self.prog}: error: {message} (see {self.prog} --help)")


def build_parser(only: str | None = "") -> argparse.ArgumentParser:
    """The full parser; with ``only`` a command name (or None for no command), the other
    commands get a one-line stub, which is all the top-level ``--help`` shows. Registering
    ``train`` imports torch (its model flags), so ``nerfkit --help`` skips it."""
    parser = Parser(prog="nerfkit", description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
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


def unknown_option(parser: argparse.ArgumentParser, argv: list[str]) -> str | None:
    """The one-line error for a command nerfkit does not have, with the nearest one it has,
    or for the first ``--option`` after the command that the command does not have (nor
    abbreviates), with the nearest one it has: argparse alone names a missing
    required flag first (``--tagsize`` for ``--tag-size``) and points to the top-level help."""
    import difflib

    command = command_in(argv)
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if command is None or not subs:
        return None
    if command not in subs[0].choices:
        near = difflib.get_close_matches(command, list(subs[0].choices), n=1)
        return (
            f"nerfkit: error: unknown command '{command}'"
            + (f": did you mean {near[0]}?" if near else f" (the commands: {', '.join(subs[0].choices)})")
            + " (see nerfkit --help)"
        )
    sub = subs[0].choices[command]
    known = [k for k in sub._option_string_actions if k.startswith("--")]
    for token in argv[argv.index(command) + 1 :]:
        if token == "--":
            break
        name = token.split("=", 1)[0]
        if not name.startswith("--") or any(k.startswith(name) for k in known):
            continue
        if name in parser._option_string_actions:  # --verbose, --version: nerfkit's own
            return (
                f"{sub.prog}: error: {name} goes before the command: nerfkit {name} {command} ... (see nerfkit --help)"
            )
        near = difflib.get_close_matches(name[2:], [k[2:] for k in known], n=1)
        return (
            f"{sub.prog}: error: unrecognized argument {name}"
            + (f": did you mean --{near[0]}?" if near else "")
            + f" (see {sub.prog} --help)"
        )
    return None


def _version() -> str:
    from . import __version__

    return __version__


def main(argv: list[str] | None = None) -> int:
    """Run one command; its exit code (0, 2 for an error, 130 when stopped by Ctrl-C or
    SIGTERM, at any moment: from the first line here, before the heavy imports)."""
    previous_int = signal.getsignal(signal.SIGINT)
    previous = _sigterm_as_ctrl_c()  # first: a signal during the imports below is one line too
    from .io import stop

    stop.take()  # a stop of an earlier command in this process is not this one's
    argv = sys.argv[1:] if argv is None else argv
    try:
        return _main(argv)
    except KeyboardInterrupt:
        command = command_in(argv)
        print(f"nerfkit{' ' + command if command else ''}: interrupted", file=sys.stderr)
        return 130
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
        if previous_int is signal.default_int_handler and signal.getsignal(signal.SIGINT) is _interrupt:
            signal.signal(signal.SIGINT, previous_int)


def _main(argv: list[str]) -> int:
    parser = build_parser(command_in(argv))
    unknown = unknown_option(parser, argv)
    if unknown:
        print(unknown, file=sys.stderr)
        return 2
    try:
        args = parser.parse_args(argv)
    except UsageError as e:
        print(e, file=sys.stderr)
        return 2
    if args.command is None:
        parser.print_help()
        return 2
    empty = empty_output(args)
    if empty:  # (an unset shell variable: '' would write into the current folder)
        print(f"nerfkit {args.command}: error: {empty} is empty: give the path to write", file=sys.stderr)
        return 2
    try:
        return int(args.func(args) or 0)
    except NerfkitError as e:
        if args.verbose:
            traceback.print_exc()
        print(f"nerfkit {args.command}: error: {e}", file=sys.stderr)
        return 2
    except (MemoryError, RuntimeError) as e:
        if not is_out_of_memory(e):
            raise
        if args.verbose:
            traceback.print_exc()
        hint = getattr(sys.modules[args.func.__module__], "MEMORY_HINT", "Use smaller inputs")
        print(f"nerfkit {args.command}: error: out of memory ({type(e).__name__}). {hint}", file=sys.stderr)
        return 2
    except OSError as e:  # the system refused a file: permissions, a folder where a file goes, a full disk
        if args.verbose:
            traceback.print_exc()
        print(f"nerfkit {args.command}: error: {os_error(e)}", file=sys.stderr)
        return 2


# the options that name what a command writes
OUTPUT_OPTIONS = {dest: f"--{dest}" for dest in ("out", "to", "png", "mesh", "points", "splat")}


def empty_output(args: argparse.Namespace) -> str | None:
    """The output option given as an empty (or blank) path (:func:`~nerfkit.config.output_path`), or None."""
    from .config import output_path

    for dest, flag in OUTPUT_OPTIONS.items():
        value = getattr(args, dest, None)
        if isinstance(value, str):
            try:
                output_path(value)
            except argparse.ArgumentTypeError:
                return flag
    return None


def _importing(frame) -> bool:
    """Whether ``frame`` runs inside Python's import machinery (a module being imported)."""
    while frame is not None:
        if frame.f_code.co_filename.startswith("<frozen importlib"):
            return True
        frame = frame.f_back
    return False


def _interrupt(signum, frame):
    """Ctrl-C or SIGTERM: KeyboardInterrupt, but never inside an import, which it could leave
    half done (numpy without its functions): there the stop waits 50 ms and is tried again."""
    from .io import stop

    stop.request()  # remembered, should a library swallow the exception
    if _importing(frame) and hasattr(signal, "setitimer"):
        signal.signal(signal.SIGALRM, lambda _s, f: _retry_stop(signum, f))
        signal.setitimer(signal.ITIMER_REAL, 0.05)
        return
    raise KeyboardInterrupt


def _retry_stop(signum, frame):
    """The retry of a stop that came inside an import: only while nobody took it over (the
    trainer takes it at its start and stops by itself; raising then would cut its save short)."""
    from .io import stop

    if stop.pending():
        _interrupt(signum, frame)


def _sigterm_as_ctrl_c():
    """SIGTERM (kill, timeout, schedulers) stops a command as Ctrl-C does: ``train`` saves,
    anything else ends with exit code 130. Returns the handler it replaced (None off the
    main thread, where handlers cannot be set, and when SIGTERM is ignored: it stays so).
    SIGINT keeps Python's own handler (KeyboardInterrupt), or stays ignored when the
    process was started with it ignored (``nohup``, a script's background job)."""
    try:
        if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
            signal.signal(signal.SIGINT, _interrupt)  # Python's own, but never inside an import
        if signal.getsignal(signal.SIGTERM) is signal.SIG_IGN:
            return None
        return signal.signal(signal.SIGTERM, _interrupt)
    except ValueError:
        return None


if __name__ == "__main__":
    sys.exit(main())
