"""`nerfkit capture`: phone photos to a trained NeRF in one command (calibrate, poses,
train, eval, render, export), each step's output kept for the next run."""

from __future__ import annotations

import argparse
from pathlib import Path

HELP = "phone photos of a tag sheet and of an object -> dataset, NeRF, videos, mesh (every step, in one go)"

DESCRIPTION = """\
Run the whole capture flow into one folder, as the README's steps do one by one:

  OUT/camera.json   nerfkit calibrate CALIB_DIR     (skipped with --camera)
  OUT/dataset/      nerfkit poses OBJECT_DIR        (posed, undistorted, split; with --method auto,
                                                     structure-from-motion poses in the tag's frame)
  OUT/run/          nerfkit train --minutes 3       (capture settings: table, room, pose and colour refinement;
                                                     one resume checkpoint kept, not two: 0.4 GB less)
                    nerfkit eval --split val        (run/eval_val.json and the contact sheet run/eval_val.png)
                    nerfkit render                  (run/videos: orbit.mp4, orbit.gif, depth.mp4)
                    nerfkit render --object         (run/videos: object.mp4, object.gif, object_depth.mp4,
                                                     the object alone on white)
  OUT/run/mesh.ply  nerfkit export --mesh           (the object, without the table)

and print what came out: the calibration, the photos posed, the held-out scores, where
the videos and plots are. Each step prints its own report as it goes. OUT/capture.json
records what the capture was made from.

Run it again with the same inputs and the steps whose results are there are kept: a
training run cut short (Ctrl-C, a crash) goes on from its last checkpoint; a larger
--minutes (or --steps, the unit the NeRF was trained with) trains it on from its checkpoint,
its learning rate back up to where the longer schedule has it; the eval, videos and mesh
are made again when they are older than the NeRF (--frames renders the videos again).
Results made from other inputs are refused, never mixed with new ones (photos added,
removed or replaced count too); a step that failed may be run again with its input mended.
--force redoes every step, replacing the camera file, the dataset and the NeRF.

examples:
  nerfkit capture object_photos/ --calib sheet_photos/ --tag-size 0.06 --out my_object/
  nerfkit capture object_photos/ --camera camera.json --tag-size 0.10 --out my_object/ --minutes 5
  nerfkit capture object_photos/ --calib sheet_photos/ --sheet-tag-size 0.03 --tag-size 0.12 --out my_object/
"""

CAMERA_FILE = "camera.json"
DATASET_DIR = "dataset"
RUN_DIR = "run"
MESH_FILE = "mesh.ply"
RECORD_FILE = "capture.json"
# the summary's note on the phone's exposure when the held-out photos' colour alone (each
# half's solved on the other half) gains this much (see BENCHMARKS.md)
EXPOSURE_NOTE_DB = 0.75


def register(sub: argparse._SubParsersAction) -> None:
    from ..config import MIN_RESAMPLED_SIDE, number, tag_side

    p = sub.add_parser(
        "capture", help=HELP, description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("photos", metavar="OBJECT_DIR", help="folder of photos of the object beside the tag")
    p.add_argument("--out", required=True, help="folder for everything the capture makes")
    p.add_argument(
        "--tag-size",
        type=tag_side,
        required=True,
        help="side of the black square of the tag beside the object, in metres (e.g. 0.06)",
    )
    cam = p.add_mutually_exclusive_group()
    cam.add_argument(
        "--calib",
        metavar="CALIB_DIR",
        help="folder of photos of the printed tag sheet, to calibrate "
        "the camera from (without it or --camera: the photos' EXIF focal length, no distortion)",
    )
    cam.add_argument("--camera", help="a camera file from an earlier `nerfkit calibrate` of the same phone")
    p.add_argument(
        "--sheet-tag-size",
        type=tag_side,
        help="side of a tag's black square on the calibration sheet (default: --tag-size)",
    )
    p.add_argument("--dict", help="ArUco dictionary of the tags (default: the camera file's, else DICT_4X4_50)")
    p.add_argument(
        "--method",
        choices=["auto", "tags"],
        default="auto",
        help="poses: auto (default) takes structure-from-motion poses in the tag's frame when they hold "
        "up; tags: the tag's poses only, as the course does",
    )
    p.add_argument(
        "--max-side",
        type=number(int, MIN_RESAMPLED_SIDE, off=0),
        help="the dataset's photos' longer side in pixels (0: keep their size; default: poses', 512)",
    )
    budget = p.add_mutually_exclusive_group()
    budget.add_argument("--minutes", type=number(float, above=0), default=3.0, help="training time (default: 3)")
    budget.add_argument("--steps", type=number(int, 1), help="train this many steps instead of --minutes")
    p.add_argument("--frames", type=number(int, 1, 100_000), help="frames of the orbit (default: render's, 120)")
    p.add_argument("--no-mesh", action="store_true", help="skip the mesh")
    p.add_argument("--device", default="auto", help="auto, cpu, cuda or cuda:N (default: auto)")
    p.add_argument(
        "--force",
        action="store_true",
        help="redo every step, replacing the camera file, the dataset and the NeRF of an earlier run",
    )
    p.set_defaults(func=run)


def _step(argv: list[str], call, needed: bool = True, verbose: bool = False, times: dict | None = None) -> bool:
    """Run one stage, ``call()`` (a :mod:`nerfkit.api` function), shown as the command
    ``nerfkit ARGV`` that does the same; whether it succeeded. The failure of a ``needed``
    stage stops the capture (its error is printed first, as the command prints it).
    ``verbose``: its errors come with their tracebacks (``nerfkit --verbose capture``).
    ``times`` gets the stage's seconds under its name (``render --object``: "object")."""
    import sys
    import time
    import traceback

    from ..cli import OS_ERROR_HINTS
    from ..errors import NerfkitError, fail, is_out_of_memory

    print(f"\n== nerfkit {' '.join(argv)}", flush=True)
    start = time.perf_counter()
    try:
        call()
        ok = True
    except (NerfkitError, OSError, MemoryError, RuntimeError) as e:
        if isinstance(e, (MemoryError, RuntimeError)) and not is_out_of_memory(e):
            raise
        if verbose:
            traceback.print_exc()
        if isinstance(e, OSError) and not isinstance(e, NerfkitError):
            where = next((f for f in (e.filename2, e.filename) if f is not None), "a file")
            message = f"{where}: {e.strerror or e}. {OS_ERROR_HINTS.get(e.errno, 'Check the path and its permissions')}"
        elif isinstance(e, NerfkitError):
            message = str(e)
        else:
            message = f"out of memory ({type(e).__name__})"
        print(f"nerfkit {argv[0]}: error: {message}", file=sys.stderr)
        ok = False
    if times is not None:
        times["object" if "--object" in argv else argv[0]] = time.perf_counter() - start
    if not ok and needed:
        raise fail(
            f"nerfkit {argv[0]}",
            "failed (its error is above)",
            "Fix that and run the same `nerfkit capture` again: the steps already done are kept",
        )
    return ok


def _trained(result) -> None:
    """A training stage's end: its summary line, as `nerfkit train` prints it; Ctrl-C stops the capture."""
    from .train import summary_line

    print(summary_line(result))
    if result.interrupted:
        raise KeyboardInterrupt


def _kept(what: str, path: Path) -> None:
    print(f"\n== {what}: {path} is there from an earlier run, kept (--force redoes it)", flush=True)


def _digest(data: bytes) -> str:
    """A short digest of ``data``, to tell one input from another in capture.json."""
    import hashlib

    return hashlib.sha1(data).hexdigest()[:10]


def _photo_files(folder) -> str | None:
    """A folder's photos as the capture saw them: their count and a digest of their names
    and sizes (photos added, removed or replaced change it)."""
    from ..images import image_files

    if not folder or not Path(folder).is_dir():
        return None
    files = [(p.name, p.stat().st_size) for p in image_files(folder)]
    listing = "".join(f"{n}\0{size}\n" for n, size in files)
    return f"{len(files)} photos ({_digest(listing.encode())})"


def _file_digest(path) -> str | None:
    """A digest of a small file's contents (a camera file calibrated again changes it)."""
    return _digest(Path(path).read_bytes()) if path and Path(path).is_file() else None


# the inputs the camera file is made from; the dataset and the NeRF depend on every input
CAMERA_INPUTS = ("calib", "calib_files", "calib_tag_size", "dict")


def _inputs(args: argparse.Namespace) -> dict:
    """What a capture is made from: a later run must name the same to keep its results."""

    def where(p):
        return str(Path(p).resolve()) if p else None

    return {
        "photos": where(args.photos),
        "photo_files": _photo_files(args.photos),
        "calib": where(args.calib),
        "calib_files": _photo_files(args.calib),
        "camera": where(args.camera),
        "camera_file": _file_digest(args.camera),
        "tag_size": args.tag_size,
        "sheet_tag_size": args.sheet_tag_size,
        "calib_tag_size": (args.sheet_tag_size or args.tag_size) if args.calib else None,
        "dict": args.dict,
        "method": args.method,
        "max_side": args.max_side,
    }


def _same_inputs(out: Path, inputs: dict, camera: Path | None, made: list[Path]) -> None:
    """Refuse to keep an earlier capture's results when they were made from other inputs
    (``camera``: the capture's camera file, made from CAMERA_INPUTS; ``made``: its dataset
    and NeRF, made from all of them), or when ``out`` holds such results that no capture
    recorded. Inputs whose results are not there yet (a step that failed) may change."""
    import json

    from ..errors import fail

    there = [p for p in ([camera] if camera is not None else []) + made if p.exists()]
    try:
        before = json.loads((out / RECORD_FILE).read_text()).get("inputs")
    except (OSError, ValueError, AttributeError):
        before = None
    if not isinstance(before, dict) or "photos" not in before:  # missing, or not a record
        if there:
            raise fail(
                out,
                f"holds {', '.join(str(p.relative_to(out)) for p in there)} that no `nerfkit capture` "
                f"recorded in {RECORD_FILE}",
                "Pass --force to replace them, or choose another --out",
            )
        return
    if "calib_tag_size" not in before:  # recorded by an older nerfkit
        before["calib_tag_size"] = (
            (before.get("sheet_tag_size") or before.get("tag_size")) if before.get("calib") else None
        )
    # (any other input an older capture did not record is not taken as changed)
    changed = [k for k, v in inputs.items() if k in before and before[k] != v]
    kept = [p for p in made if p.exists()]
    if camera is not None and camera.exists() and not kept:
        changed = [k for k in changed if k in CAMERA_INPUTS]
    elif not kept:
        changed = []
    if changed:
        raise fail(
            out,
            "holds a capture made from other inputs ("
            + ", ".join(f"{k}: {before.get(k)} then, {inputs[k]} now" for k in changed)
            + ")",
            "Pass --force to redo it with these, or choose another --out",
        )


def _finished(run_dir: Path) -> bool:
    """Whether ``run_dir`` holds a run that reached its stopping rule (a run cut short by
    Ctrl-C has its model file too, but not ``finished`` in its metrics)."""
    import json

    from ..train.checkpoint import MODEL_FILE

    if not (run_dir / MODEL_FILE).exists():
        return False
    try:
        return bool(json.loads((run_dir / "metrics.json").read_text()).get("finished", True))
    except (OSError, ValueError, AttributeError):
        return False


def _newer_than_model(path: Path, run_dir: Path) -> bool:
    """Whether ``path`` was written after the run's model file, so it shows that model."""
    from ..train.checkpoint import MODEL_FILE

    model = run_dir / MODEL_FILE
    return path.exists() and model.exists() and path.stat().st_mtime >= model.stat().st_mtime


def _budget(run_dir: Path) -> tuple[int, float] | None:
    """The training budget a run was given: (steps, minutes), steps 0 when it ran by time."""
    import json

    try:
        train = json.loads((run_dir / "config.json").read_text())["train"]
        return int(train["steps"] or 0), float(train["minutes"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _budget_text(steps: int, minutes: float) -> str:
    return f"{steps} steps" if steps else f"{minutes:g} minutes"


def _larger_budget(run_dir: Path, args: argparse.Namespace, need_checkpoint: bool) -> bool:
    """Whether the run is to train on to a larger budget asked for now (in its own unit,
    steps or minutes; from a checkpoint when ``need_checkpoint``: a finished run), said so;
    another budget, which it cannot go on to, is said with what --force does."""
    from ..train.checkpoint import checkpoint_paths

    then = _budget(run_dir)
    if then is None:
        return False
    now = (args.steps or 0, args.minutes)
    if _budget_text(*then) == _budget_text(*now):
        return False
    larger = (then[0] > 0) == (now[0] > 0) and (now[0] > then[0] if now[0] else now[1] > then[1])
    if larger and (checkpoint_paths(run_dir) or not need_checkpoint):
        print(
            f"   its budget was {_budget_text(*then)}: training goes on to the {_budget_text(*now)} asked for now",
            flush=True,
        )
        return True
    print(
        f"   its budget is {_budget_text(*then)}, not the {_budget_text(*now)} asked for now"
        + (" (and no checkpoint is left to go on from)" if larger else "")
        + ": --force trains it again with those",
        flush=True,
    )
    return False


def _replace_run(run_dir: Path) -> None:
    """Remove an earlier run of this capture (``--force``); a folder that is not a nerfkit
    run is refused, never removed."""
    import shutil

    from ..errors import fail

    if not run_dir.exists():
        return
    if not (run_dir / "config.json").is_file():
        raise fail(run_dir, "holds files that are not a nerfkit run", "Move them away, or choose another --out")
    print(f"\n== --force: removing the earlier NeRF {run_dir}", flush=True)
    shutil.rmtree(run_dir)


def run(args: argparse.Namespace) -> int:
    from functools import partial

    from ..errors import fail
    from ..images import list_images
    from ..io.atomic import write_json
    from ..io.paths import guard_outputs
    from ..output.videos import OBJECT_VIDEO_FILES, VIDEO_FILES
    from ..train.checkpoint import MODEL_FILE, checkpoint_paths
    from ..train.config import resolve_device
    from . import pipeline as api

    times: dict[str, float] = {}
    step = partial(_step, verbose=bool(getattr(args, "verbose", False)), times=times)
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise fail(out, "exists and is not a folder", "--out names the folder the capture fills")
    for folder, flag in ((args.photos, "OBJECT_DIR"), (args.calib, "--calib")):
        if folder and not Path(folder).is_dir():
            raise fail(folder, "is not a folder", f"{flag} names a folder of photos")
    if args.calib and Path(args.calib).resolve() == Path(args.photos).resolve():
        raise fail(
            args.calib,
            "is both the calibration folder and the object's",
            "--calib names the photos of the printed tag sheet, OBJECT_DIR those of the object beside its tag",
        )
    # the photos may sit in --out (my_object/photos, --out my_object), but nothing is written among them
    ours = [out / DATASET_DIR, out / RUN_DIR, out / RECORD_FILE] + ([out / CAMERA_FILE] if args.calib else [])
    guard_outputs(ours, [args.photos, args.calib, args.camera], force=True)
    # what would fail a later step is refused before the first one: a folder without photos, a missing GPU
    list_images(args.photos)
    resolve_device(args.device)
    inputs = _inputs(args)
    if not args.force:
        _same_inputs(
            out,
            inputs,
            out / CAMERA_FILE if args.calib else None,
            [out / DATASET_DIR / "dataset.npz", out / RUN_DIR / "config.json"],
        )
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / RECORD_FILE, {"inputs": inputs})
    dictionary = ["--dict", args.dict] if args.dict else []
    dict_option = {"dictionary": args.dict} if args.dict else {}

    camera = Path(args.camera) if args.camera else None
    if args.calib:
        camera = out / CAMERA_FILE
        if camera.exists() and not args.force:
            _kept("calibration", camera)
        else:  # --force: a calibration cut short may have left its detections
            sheet_size = args.sheet_tag_size or args.tag_size
            step(
                ["calibrate", args.calib, *dictionary, "--tag-size", str(sheet_size), "--out", str(camera), "--force"],
                lambda: api.calibrate(args.calib, camera, tag_size=sheet_size, force=True, **dict_option),
            )

    dataset = out / DATASET_DIR
    if (dataset / "dataset.npz").exists() and not args.force:
        _kept("dataset", dataset)
    else:  # --force: the folder is the capture's, and poses cut short leaves poses.json
        step(
            [
                "poses",
                args.photos,
                "--tag-size",
                str(args.tag_size),
                *dictionary,
                "--out",
                str(dataset),
                "--method",
                args.method,
                "--force",
                *(["--camera", str(camera)] if camera else []),
                *(["--max-side", str(args.max_side)] if args.max_side is not None else []),
            ],
            lambda: api.pose(
                args.photos,
                dataset,
                tag_size=args.tag_size,
                camera=camera,
                method=args.method,
                force=True,
                max_side=args.max_side,
                **dict_option,
            ),
        )

    run_dir = out / RUN_DIR
    if args.force:
        _replace_run(run_dir)
    budget = ["--steps", str(args.steps)] if args.steps else ["--minutes", str(args.minutes)]
    budget_option = {"steps": args.steps} if args.steps else {"minutes": args.minutes}
    if _finished(run_dir):
        _kept("NeRF", run_dir)
        if _larger_budget(run_dir, args, need_checkpoint=True):
            step(
                ["train", "--resume", str(run_dir), *budget, "--device", args.device],
                lambda: _trained(api.resume(run_dir, device=args.device, **budget_option)),
            )
    elif (run_dir / MODEL_FILE).exists() and not checkpoint_paths(run_dir):  # cut short, nothing to go on from
        _kept("NeRF", run_dir)
        print("   it was cut short and has no checkpoint to go on from: --force trains it again", flush=True)
    elif (run_dir / "config.json").exists():  # cut short: it goes on, to a larger budget if one is asked for
        larger = _larger_budget(run_dir, args, need_checkpoint=False)
        step(
            ["train", "--resume", str(run_dir), *(budget if larger else []), "--device", args.device],
            lambda: _trained(api.resume(run_dir, device=args.device, **(budget_option if larger else {}))),
        )
    else:
        step(
            ["train", "--data", str(dataset / "dataset.npz"), "--out", str(run_dir), *budget, "--device", args.device],
            lambda: _trained(api.train(dataset / "dataset.npz", run_dir, device=args.device, **budget_option)),
        )
    # what shows the model as it is now is kept; the rest is made again (it belongs to the run)
    evaluated = True
    if _newer_than_model(run_dir / "eval_val.json", run_dir):
        _kept("evaluation", run_dir / "eval_val.json")
    else:
        evaluated = step(
            ["eval", str(run_dir), "--split", "val", "--device", args.device],
            lambda: api.evaluate(run_dir, split="val", device=args.device),
            needed=False,
        )
    videos = run_dir / "videos"
    frames = ["--frames", str(args.frames)] if args.frames else []
    if all(_newer_than_model(videos / name, run_dir) for name in VIDEO_FILES) and not args.frames:
        _kept("videos", videos)
    else:
        step(
            ["render", str(run_dir), "--device", args.device, *frames],
            lambda: api.render(run_dir, device=args.device, frames=args.frames),
        )
    # a NeRF with nothing solid to frame still has its scene videos: the capture goes on
    if all(_newer_than_model(videos / name, run_dir) for name in OBJECT_VIDEO_FILES) and not args.frames:
        _kept("videos of the object", videos)
    else:
        step(
            ["render", str(run_dir), "--object", "--device", args.device, *frames],
            lambda: api.render(run_dir, object=True, device=args.device, frames=args.frames),
            needed=False,
        )
    mesh = None
    if not args.no_mesh:  # a NeRF too faint to mesh is still a NeRF: the capture goes on
        mesh = run_dir / MESH_FILE
        if _newer_than_model(mesh, run_dir):
            _kept("mesh", mesh)
        elif not step(
            ["export", str(run_dir), "--mesh", str(mesh), "--force", "--device", args.device],
            lambda: api.export(run_dir, mesh=mesh, force=True, device=args.device),
            needed=False,
        ):
            mesh = None
    print()
    print(summary(out, camera, dataset, run_dir, mesh, evaluated, mesh_skipped=args.no_mesh, times=times))
    return 0


def summary(
    out: Path,
    camera: Path | None,
    dataset: Path,
    run_dir: Path,
    mesh: Path | None,
    evaluated: bool = True,
    mesh_skipped: bool = False,
    times: dict | None = None,
) -> str:
    """What the capture made, in a few lines: the calibration (and its warnings), the photos
    posed, the NeRF's held-out scores, where the videos, plots and mesh are, and the time
    each step run now took (``times``, seconds by step)."""
    import json

    from ..capture.agreement import agreement_notes
    from ..capture.coverage import coverage_notes
    from ..capture.dataset import FEW_TRAIN_VIEWS, few_views_note, no_object_note
    from ..data.nerfstudio import nerfkit_block
    from ..output.videos import OBJECT_VIDEO_FILES, VIDEO_FILES

    lines = [f"capture done: {out}"]
    if camera is not None:
        c = json.loads(camera.read_text())
        held, rms = c.get("heldout_rms"), c.get("rms")
        lines.append(
            f"  camera    {camera}: distortion model {c.get('dist_model', 'as given')}"
            + (
                f", {held:.2f} px on held-out photos"
                if held is not None
                else f", RMS {rms:.2f} px"
                if rms is not None
                else ""
            )
        )
        warnings = (c.get("sanity") or {}).get("warnings") or []
        for w in warnings:
            lines.append(f"            WARNING: {w}")
    else:
        lines.append("  camera    the photos' EXIF focal length, no lens distortion")
    photos = json.loads((dataset / "poses.json").read_text())["photos"]
    found = sum(1 for p in photos if p.get("tags"))
    posed = sum(1 for p in photos if p.get("used"))
    nk = nerfkit_block(dataset) or {}
    views = nk.get("views") or {}
    choice = nk.get("pose_choice")
    lines.append(f"  photos    {len(photos)}: the tag found in {found}, {posed} posed by it")
    lines.append(
        f"  dataset   {dataset}: "
        + ", ".join(f"{n} {split}" for split, n in views.items())
        + (f"; {choice['why']}" if isinstance(choice, dict) and choice.get("why") else "")
    )
    for note in (
        few_views_note(int(views.get("train", FEW_TRAIN_VIEWS))),
        no_object_note(nk.get("object_points"), int(nk.get("points") or 0)),
    ):
        if note:
            lines.append(f"            {note}")
    if isinstance(nk.get("coverage"), dict):
        notes = coverage_notes(nk["coverage"])
        notes[0] += f" (chart: {dataset / nk['coverage']['plot']})"
        lines += [f"            {note.strip()}" for note in notes]
    agreement = nk.get("agreement") if isinstance(nk.get("agreement"), dict) else None
    if agreement:
        lines += [f"            {note.strip()}" for note in agreement_notes(agreement)]
    m = json.loads((run_dir / "metrics.json").read_text())
    lines.append(f"  NeRF      {run_dir}: {m['step']} steps; plots in {run_dir / 'plots'}")
    lines += [f"            note: {note}" for note in m.get("notes") or []]
    if evaluated:
        e = json.loads((run_dir / "eval_val.json").read_text())
        fitted = e.get("fitted")
        lines.append(
            f"  held out  {e['n_images']} val photos: {e['psnr']:.2f} dB / SSIM {e['ssim']:.3f} as rendered"
            + (
                f", {fitted['psnr']:.2f} dB with each photo's pose fitted and each half's colour solved on the "
                "other half"
                if fitted
                else ""
            )
            + f"; photo beside render: {run_dir / 'eval_val.png'}"
        )
        obj = e.get("object") or {}
        if obj.get("psnr") is not None:
            lines.append(
                f"            the object's own pixels: {obj['psnr']:.2f} dB as rendered"
                + (f", {obj['psnr_fitted']:.2f} fitted" if obj.get("psnr_fitted") is not None else "")
            )
        colour = e.get("colour_only")
        if colour and colour["psnr"] - e["psnr"] >= EXPOSURE_NOTE_DB:
            lines.append(
                "            note: with only their colour solved (each half's on the other half), the "
                "held-out photos score "
                f"{colour['psnr']:.2f} dB: each photo's overall colour changed (the phone's exposure or "
                "white balance, or the light itself), which the scene cannot predict. Locking the exposure "
                "while photographing (iPhone: AE/AF lock) narrows the phone's part"
                + (" (the agreement above says how much)" if agreement else "")
            )
    else:
        lines.append("  held out  not scored (the eval's error is above)")
    videos = run_dir / "videos"
    alone = [name for name in OBJECT_VIDEO_FILES if _newer_than_model(videos / name, run_dir)]
    lines.append(
        f"  videos    {videos}: "
        + ", ".join(VIDEO_FILES)
        + "; the object alone: "
        + (", ".join(alone) if alone else "none (see above)")
    )
    lines.append(
        f"  mesh      {mesh}"
        if mesh is not None
        else "  mesh      not made (--no-mesh)"
        if mesh_skipped
        else "  mesh      none (see above)"
    )
    lines.append(
        f"  look      nerfkit view {run_dir}   (the NeRF live in the browser, with the cameras; "
        '"Object alone" hides the table and room)'
    )
    if times:
        lines.append(
            "  time      "
            + ", ".join(f"{name} {_duration(t)}" for name, t in times.items())
            + f"; {_duration(sum(times.values()))} in all"
        )
    return "\n".join(lines)


def _duration(seconds: float) -> str:
    return f"{seconds:.0f} s" if seconds < 90 else f"{seconds / 60:.1f} min"
