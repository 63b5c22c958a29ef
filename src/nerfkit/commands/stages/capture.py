"""The capture stage (``nerfkit capture``, :func:`nerfkit.api.capture`): a phone video or photos
to a trained NeRF and/or Gaussian splat in one go (frames, calibrate, poses, train, eval,
render, export), each step's output kept for the next run; what it decides, prints and
summarises, in small functions over :class:`CaptureArgs`."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from ..pipeline import PoseMethod

CAMERA_FILE = "camera.json"
DATASET_DIR = "dataset"
RUN_DIR = "run"
FRAMES_DIR = "frames"
SPLAT_RUN_DIR = "splat_run"
SPLAT_FILES = ("splat.ply", "splat.splat")
OBJECT_SPLAT_FILE = "splat_object.ply"
# fewer photos (or frames) registered by structure-from-motion than this share of them, or
# than MIN_POSED, stop the capture: the rest would train on a part of the object
MIN_POSED_SHARE = 0.5
MIN_POSED = 10
MESH_FILE = "mesh.ply"
RECORD_FILE = "capture.json"
# the summary's note on the phone's exposure when the held-out photos' colour alone (each
# half's solved on the other half) gains this much (see BENCHMARKS.md)
EXPOSURE_NOTE_DB = 0.75


@dataclass(frozen=True)
class CaptureArgs:
    """A capture's options, named as ``nerfkit capture``'s flags are parsed (``--dict`` is
    ``dict``, ``--no-mesh`` ``no_mesh``), checked as they are (:func:`nerfkit.api.capture`)."""

    photos: str  # a folder of photos of the object, or a video
    out: str
    calib: str | None
    camera: str | None
    tag_size: float | None
    sheet_tag_size: float | None
    dict: str | None
    method: PoseMethod
    clip_frames: int
    model: str
    max_side: int | None
    minutes: float
    steps: int | None
    frames: int | None
    no_mesh: bool
    device: str
    force: bool
    verbose: bool


@dataclass(frozen=True)
class Calls:
    """The API's stages a capture runs (:func:`nerfkit.api.capture` passes its own: this module
    never imports :mod:`~nerfkit.commands.pipeline`, which imports it)."""

    calibrate: Callable[..., Any]
    pose: Callable[..., Any]
    train: Callable[..., Any]
    resume: Callable[..., Any]
    evaluate: Callable[..., Any]
    render: Callable[..., Any]
    export: Callable[..., Any]


@dataclass(frozen=True)
class Made:
    """What :func:`run_capture` made: the folder, the camera file (None: none), the dataset,
    the NeRF's run (None: not trained) with its mesh (None: none) and whether it was scored,
    and the splat's outputs (None: not trained; as :func:`_splat_outputs` gives them)."""

    out: Path
    camera: Path | None
    dataset: Path
    run_dir: Path | None
    mesh: Path | None
    evaluated: bool
    splat: dict | None


def _step(
    argv: list[str], call, needed: bool = True, verbose: bool = False, times: dict | None = None, prefix: str = ""
) -> bool:
    """Run one stage, ``call()`` (a :mod:`nerfkit.api` function), shown as the command
    ``nerfkit ARGV`` that does the same; whether it succeeded. The failure of a ``needed``
    stage stops the capture (its error is printed first, as the command prints it).
    ``verbose``: its errors come with their tracebacks (``nerfkit --verbose capture``).
    ``times`` gets the stage's seconds under its name (``render --object``: "object"), after ``prefix``."""
    import sys
    import time
    import traceback

    from ...errors import NerfkitError, fail, is_out_of_memory, os_error

    print(f"\n== nerfkit {' '.join(argv)}", flush=True)
    start = time.perf_counter()
    message, cause = "", None
    try:
        call()
        ok = True
    except (NerfkitError, OSError, MemoryError, RuntimeError) as e:
        cause = e
        if isinstance(e, (MemoryError, RuntimeError)) and not is_out_of_memory(e):
            raise
        if verbose:
            traceback.print_exc()
        if isinstance(e, OSError):
            message = str(os_error(e))
        elif isinstance(e, NerfkitError):
            message = str(e)
        else:
            message = f"out of memory ({type(e).__name__})"
        print(f"nerfkit {argv[0]}: error: {message}", file=sys.stderr)
        ok = False
    if times is not None:
        times[prefix + ("object" if "--object" in argv else argv[0])] = time.perf_counter() - start
    if not ok and needed:
        raise fail(
            f"nerfkit {argv[0]}",
            f"failed: {message}",
            "Fix that and run the same `nerfkit capture` again: the steps already done are kept",
        ) from cause
    return ok


def _trained(result) -> None:
    """A training stage's end: its summary line, as `nerfkit train` prints it; Ctrl-C stops the capture."""
    from .train import summary_line

    print(summary_line(result))
    if result.interrupted:
        raise KeyboardInterrupt


def _kept(what: str, path: Path) -> None:
    print(f"\n== {what}: {path} is there from an earlier run, kept (--force redoes it)", flush=True)


MODEL_LABELS = {"fast": "NeRF", "splat": "splat"}


def stage_plan(video: bool, calib: bool, models: list[str], mesh: bool) -> list[str]:
    """The stages a capture runs, in order, for its route: the frames of a ``video``, the
    calibration (``calib``), the poses, then per model (``fast``, ``splat``) its training,
    evaluation, videos and files (the NeRF's only with its ``mesh``)."""
    plan = (["frames"] if video else []) + (["calibration"] if calib else []) + ["poses"]
    for model in models:
        label = MODEL_LABELS[model]
        plan += [f"training the {label}", f"evaluation of the {label}", f"rendering the {label}'s videos"]
        if model == "splat":
            plan.append("export of the splat files")
        elif mesh:
            plan.append("export of the NeRF's mesh")
    return plan


class Headings:
    """Prints ``[k/N] stage`` as each stage of ``plan`` starts (N: the stages planned), and
    ``[k/N] stage: part`` as a part of the current one starts."""

    def __init__(self, plan: list[str]):
        self.plan = plan
        self.k = 0

    def start(self, name: str) -> None:
        """The next stage, ``name`` (as :func:`stage_plan` names it), starts."""
        self.k += 1
        print(f"\n[{self.k}/{len(self.plan)}] {name}", flush=True)

    def part(self, what: str) -> None:
        """A part ``what`` of the current stage starts (structure-from-motion's features, ...)."""
        print(f"\n[{self.k}/{len(self.plan)}] {self.plan[self.k - 1]}: {what}", flush=True)


def _digest(data: bytes) -> str:
    """A short digest of ``data``, to tell one input from another in capture.json."""
    import hashlib

    return hashlib.sha1(data).hexdigest()[:10]


def _photo_files(folder) -> str | None:
    """A folder's photos as the capture saw them: their count and a digest of their names
    and sizes (photos added, removed or replaced change it)."""
    from ...images import image_files

    if not folder or not Path(folder).is_dir():
        return None
    files = [(p.name, p.stat().st_size) for p in image_files(folder)]
    listing = "".join(f"{n}\0{size}\n" for n, size in files)
    return f"{len(files)} photos ({_digest(listing.encode())})"


def _clip_file(path) -> str | None:
    """A video as the capture saw it: its name, size and a digest of both (another clip, or
    the same one edited, changes it)."""
    if not path or not Path(path).is_file():
        return None
    size = Path(path).stat().st_size
    return f"{Path(path).name}, {size} bytes ({_digest(f'{Path(path).name}{chr(0)}{size}'.encode())})"


def _file_digest(path) -> str | None:
    """A digest of a small file's contents (a camera file calibrated again changes it)."""
    return _digest(Path(path).read_bytes()) if path and Path(path).is_file() else None


# the inputs the camera file is made from; the dataset and the NeRF depend on every input
CAMERA_INPUTS = ("calib", "calib_files", "calib_tag_size", "dict")


def _inputs(args: CaptureArgs) -> dict:
    """What a capture is made from: a later run must name the same to keep its results."""

    def where(p):
        return str(Path(p).resolve()) if p else None

    from ...capture.video import clip_stamp, is_video

    video = is_video(args.photos)
    clip_content = clip_stamp(args.photos) if video and Path(args.photos).is_file() else None
    return {
        "photos": where(args.photos),
        "photo_files": _clip_file(args.photos) if video else _photo_files(args.photos),
        # (its bytes: a clip edited in place, a rotation fixed in its header, keeps its size)
        **({"clip_frames": args.clip_frames, "clip_content": clip_content} if video else {}),
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


def _same_inputs(
    out: Path, inputs: dict, camera: Path | None, made: list[Path], ours: list[Path], given: Sequence = ()
) -> None:
    """Refuse to keep an earlier capture's results when they were made from other inputs
    (``camera``: the capture's camera file, made from CAMERA_INPUTS; ``made``: its dataset
    and NeRF, made from all of them), or, when no capture recorded its inputs in ``out``, to
    replace any of the files and folders the capture writes (``ours``) that are there, or to
    write beside anything else there but the inputs ``given`` (photos may sit in the capture's folder).
    Inputs whose results are not there yet (a step that failed) may change."""
    import json

    from ...errors import fail
    from ...io.atomic import shown_names

    try:
        before = json.loads((out / RECORD_FILE).read_text()).get("inputs")
    except (OSError, ValueError, AttributeError):
        before = None
    if not isinstance(before, dict) or "photos" not in before:  # missing, or not a record
        there = [p for p in ours if p.exists()]
        if there:
            raise fail(
                out,
                f"holds {', '.join(str(p.relative_to(out)) for p in there)} that no `nerfkit capture` "
                f"recorded in {RECORD_FILE}",
                "Pass --force to replace them, or choose another --out",
            )
        others = _other_entries(out, given)
        if others:  # another command's outputs (`nerfkit poses`'s dataset) or the user's files
            raise fail(
                out,
                f"holds files that are not a capture's ({shown_names(others)}): the capture would be written "
                "beside them",
                "Choose a new or empty --out, or pass --force to write the capture beside them",
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


def _other_entries(out: Path, given: Sequence) -> list[str]:
    """The names in ``out`` (a folder, or nothing yet) other than nerfkit's lock and temporaries
    and those holding (or being) one of the inputs ``given`` (paths or None), sorted."""
    from ...io.lock import left_by_others

    if not out.is_dir():
        return []
    inputs = [Path(g).resolve() for g in given if g]
    return sorted(
        p.name for p in left_by_others(out) if not any(i == p.resolve() or p.resolve() in i.parents for i in inputs)
    )


def _finished(run_dir: Path) -> bool:
    """Whether ``run_dir`` holds a run that reached its stopping rule (a run cut short by
    Ctrl-C has its model file too, but not ``finished`` in its metrics)."""
    import json

    from ...train.checkpoint import MODEL_FILE

    if not (run_dir / MODEL_FILE).exists():
        return False
    try:
        return bool(json.loads((run_dir / "metrics.json").read_text()).get("finished", True))
    except (OSError, ValueError, AttributeError):
        return False


def _newer_than_model(path: Path, run_dir: Path) -> bool:
    """Whether ``path`` was written after the run's model file, so it shows that model."""
    from ...train.checkpoint import MODEL_FILE

    model = run_dir / MODEL_FILE
    return path.exists() and model.exists() and path.stat().st_mtime >= model.stat().st_mtime


def _on_own_dataset(scores: Path) -> bool:
    """Whether ``eval``'s ``scores`` were measured on the run's own dataset (not ``eval --data`` of another)."""
    import json

    try:
        return json.loads(scores.read_text()).get("runs_own_dataset", True) is True
    except (OSError, ValueError, AttributeError):
        return False


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


def _larger_budget(run_dir: Path, args: CaptureArgs, need_checkpoint: bool) -> bool:
    """Whether the run is to train on to a larger budget asked for now (in its own unit,
    steps or minutes; from a checkpoint when ``need_checkpoint``: a finished run), said so;
    another budget, which it cannot go on to, is said with what --force does."""
    from ...train.checkpoint import checkpoint_paths

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

    from ...errors import fail

    if not run_dir.exists():
        return
    if _budget(run_dir) is None:  # no config.json that a nerfkit run wrote
        raise fail(run_dir, "holds files that are not a nerfkit run", "Move them away, or choose another --out")
    print(f"\n== --force: removing the earlier NeRF {run_dir}", flush=True)
    shutil.rmtree(run_dir)


def _route(args: CaptureArgs, video: bool) -> PoseMethod:
    """How the photos are posed (``nerfkit poses --method``): structure-from-motion alone
    ("colmap") without a tag, or for a video's frames (they carry no focal length for the
    tags to start from) unless a camera is given; else the --method asked for."""
    if args.tag_size is None or args.method == "colmap":
        return "colmap"
    if video and not (args.calib or args.camera) and args.method == "auto":
        return "colmap"
    return args.method


def _check_arguments(args: CaptureArgs, video: bool) -> None:
    """Refuse what no route can do, before any step."""
    from ...errors import fail

    if args.tag_size is None and args.method == "tags":
        raise fail(
            "--method tags",
            "poses from the tag need the tag's size",
            "Measure the tag's black square and pass --tag-size (e.g. 0.06), or leave --method out to pose "
            "by structure-from-motion",
        )
    if video and args.method == "tags" and not (args.calib or args.camera):
        raise fail(
            "--method tags",
            "a video's frames carry no focal length for the tag's poses to start from",
            "Give the phone's camera (--calib SHEET_PHOTOS or --camera camera.json), or leave --method out: "
            "structure-from-motion poses the frames and the tag sets the scale",
        )
    if args.calib and not (args.sheet_tag_size or args.tag_size):
        raise fail(
            "--calib",
            "calibrating needs the size of the sheet's tags",
            "Pass --sheet-tag-size (the side of a tag's black square on the sheet, in metres)",
        )
    if not video and Path(args.photos).is_file():
        from ...capture.video import VIDEO_SUFFIXES

        raise fail(
            args.photos,
            "is a file, not a folder of photos or a video",
            f"Pass a folder of photos, or a video ({', '.join(VIDEO_SUFFIXES)})",
        )


def _frames_there(frames_dir: Path, clip: str, target: int, stamp: str | None) -> bool:
    """Whether ``frames_dir`` holds the frames an earlier capture chose from ``clip`` with
    ``target``, the clip unchanged since: its ``stamp`` now (:func:`~nerfkit.capture.video.clip_stamp`,
    read once per capture, in :func:`_inputs`) is the one they were chosen from."""
    import json

    from ...capture.video import REPORT_NAME

    try:
        report = json.loads((frames_dir / REPORT_NAME).read_text())
        return (
            Path(report["source"]).resolve() == Path(clip).resolve()
            and report["source_stamp"] == stamp
            and int(report["target"]) == target
            and all((frames_dir / f["file"]).is_file() for f in report["frames"])
        )
    except (OSError, ValueError, KeyError, TypeError):
        return False


def _say_videos_beside(folder: Path) -> None:
    """Say that the videos in a folder of photos are not read (the photos are)."""
    from ...images import video_names

    clips = video_names(folder)
    if clips:
        print(
            f"note: {folder} also holds {len(clips)} video{'s' * (len(clips) > 1)} ({', '.join(clips[:3])}), "
            "not read: the photos are (pass a video itself to nerfkit capture to use it instead)",
            flush=True,
        )


def _check_posed(dataset: Path, what: str) -> None:
    """Stop the capture when structure-from-motion posed too few of the photos (``what``:
    "frames" or "photos"): a NeRF of part of them would not show the object."""
    import json

    from ...errors import fail
    from ...sfm.dataset import REPORT_FILE

    try:
        report = json.loads((dataset / REPORT_FILE).read_text())
        n, posed = int(report["n_photos"]), int(report["n_registered"])
    except (OSError, ValueError, KeyError, TypeError):
        return
    if posed >= MIN_POSED and posed >= MIN_POSED_SHARE * n:
        return
    need = max(MIN_POSED, round(MIN_POSED_SHARE * n))
    raise fail(
        dataset,
        f"structure-from-motion posed only {posed} of the {n} {what} (at least {need} are needed; the "
        "reasons are listed above)",
        "Film (or photograph) again moving slowly all the way around the object, keeping it sharp and in view, "
        "with some texture around it (a patterned cloth or newspaper under it helps)"
        + ("; or keep more frames of the clip with --clip-frames" if what == "frames" else "")
        + "; then run the capture again with --force",
    )


def _posed(api: Calls, headings: Headings, photos: str, dataset: Path, **options) -> None:
    """:func:`nerfkit.api.pose` of ``photos`` into ``dataset``, structure-from-motion's steps
    (features, matching, mapping) headed as parts of the poses stage."""
    from ...sfm.colmap import telling_steps

    with telling_steps(headings.part):
        api.pose(photos, dataset, **options)


def _train_run(
    api: Calls, run_dir: Path, dataset: Path, args: CaptureArgs, step, model: str, headings: Headings
) -> None:
    """Train ``model`` into ``run_dir`` on the dataset, or keep the run there, going on
    from its checkpoint when it was cut short or a larger budget is asked for."""
    from ...train.checkpoint import MODEL_FILE, checkpoint_paths

    headings.start(f"training the {MODEL_LABELS[model]}")
    budget = ["--steps", str(args.steps)] if args.steps else ["--minutes", str(args.minutes)]
    budget_option = {"steps": args.steps} if args.steps else {"minutes": args.minutes}
    label = "NeRF" if model == "fast" else "splat"
    model_flag = [] if model == "fast" else ["--model", model]
    model_option: dict[str, Any] = {} if model == "fast" else {"model": model}
    if _finished(run_dir):
        _kept(label, run_dir)
        if _larger_budget(run_dir, args, need_checkpoint=True):
            step(
                ["train", "--resume", str(run_dir), *budget, "--device", args.device],
                lambda: _trained(api.resume(run_dir, device=args.device, **budget_option)),
            )
    elif (run_dir / MODEL_FILE).exists() and not checkpoint_paths(run_dir):  # cut short, nothing to go on from
        _kept(label, run_dir)
        print("   it was cut short and has no checkpoint to go on from: --force trains it again", flush=True)
    elif (run_dir / "config.json").exists():  # cut short: it goes on, to a larger budget if one is asked for
        larger = _larger_budget(run_dir, args, need_checkpoint=False)
        step(
            ["train", "--resume", str(run_dir), *(budget if larger else []), "--device", args.device],
            lambda: _trained(api.resume(run_dir, device=args.device, **(budget_option if larger else {}))),
        )
    else:
        step(
            [
                "train",
                "--data",
                str(dataset / "dataset.npz"),
                *model_flag,
                "--out",
                str(run_dir),
                *budget,
                "--device",
                args.device,
            ],
            lambda: _trained(
                api.train(dataset / "dataset.npz", run_dir, device=args.device, **model_option, **budget_option)
            ),
        )


def _evaluated(api: Calls, run_dir: Path, args: CaptureArgs, step) -> bool:
    """Score the run on the held-out photos (kept when newer than its model); whether it is scored."""

    if _newer_than_model(run_dir / "eval_val.json", run_dir) and _on_own_dataset(run_dir / "eval_val.json"):
        _kept("evaluation", run_dir / "eval_val.json")
        return True
    return step(
        ["eval", str(run_dir), "--split", "val", "--device", args.device],
        lambda: api.evaluate(run_dir, split="val", device=args.device),
        needed=False,
    )


def _rendered(api: Calls, run_dir: Path, args: CaptureArgs, step, what: str, needed: bool) -> None:
    """The run's orbit videos (``nerfkit render``), kept when newer than its model."""
    from ...output.videos import VIDEO_FILES

    videos = run_dir / "videos"
    if all(_newer_than_model(videos / name, run_dir) for name in VIDEO_FILES) and not args.frames:
        _kept(what, videos)
        return
    frames = ["--frames", str(args.frames)] if args.frames else []
    step(
        ["render", str(run_dir), "--device", args.device, *frames],
        lambda: api.render(run_dir, device=args.device, frames=args.frames),
        needed=needed,
    )


def _fast_outputs(api: Calls, run_dir: Path, args: CaptureArgs, step, headings: Headings) -> tuple[bool, Path | None]:
    """The NeRF's eval, videos (the scene's and the object's alone) and mesh, each kept when
    newer than the model; (whether it is scored, the mesh or None)."""
    from ...output.videos import OBJECT_VIDEO_FILES

    # what shows the model as it is now is kept; the rest is made again (it belongs to the run)
    headings.start("evaluation of the NeRF")
    evaluated = _evaluated(api, run_dir, args, step)
    videos = run_dir / "videos"
    frames = ["--frames", str(args.frames)] if args.frames else []
    headings.start("rendering the NeRF's videos")
    _rendered(api, run_dir, args, step, "videos", needed=True)
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
        headings.start("export of the NeRF's mesh")
        mesh = run_dir / MESH_FILE
        if _newer_than_model(mesh, run_dir):
            _kept("mesh", mesh)
        elif not step(
            ["export", str(run_dir), "--mesh", str(mesh), "--force", "--device", args.device],
            lambda: api.export(run_dir, mesh=mesh, force=True, device=args.device),
            needed=False,
        ):
            mesh = None
    return evaluated, mesh


def _splat_outputs(api: Calls, out: Path, run_dir: Path, args: CaptureArgs, step, headings: Headings) -> dict:
    """The splat's eval and orbit video (in its run folder), and its Gaussians as
    OUT/splat.ply, OUT/splat.splat and the object alone, OUT/splat_object.ply; what was
    made, for the summary."""
    from ...capture.dome import on_dome
    from ...capture.splats import object_box, write_object_splat
    from ...splat_files import read_splat_ply
    from ...train.checkpoint import read_run

    headings.start("evaluation of the splat")
    evaluated = _evaluated(api, run_dir, args, step)
    headings.start("rendering the splat's videos")
    _rendered(api, run_dir, args, step, "videos of the splat", needed=False)
    headings.start("export of the splat files")
    files = [out / name for name in SPLAT_FILES]
    for path in files:
        if _newer_than_model(path, run_dir):
            _kept("splat file", path)
        else:
            step(
                ["export", str(run_dir), "--splat", str(path), "--force", "--device", args.device],
                lambda path=path: api.export(run_dir, splat=path, force=True, device=args.device),
            )
    alone = out / OBJECT_SPLAT_FILE
    bounds = read_run(run_dir).bounds
    lo, hi, how = object_box(bounds)
    dome = int(on_dome(read_splat_ply(files[0]).means, bounds).sum())
    if _newer_than_model(alone, run_dir):
        _kept("the object's splat", alone)
        kept = None
    else:
        print(f"\n== the object alone: the Gaussians in {how} -> {alone}", flush=True)
        kept = write_object_splat(files[0], alone, (lo, hi))
        kept = (kept[0], kept[1] - dome)  # (the background's dome is never in the object's box)
        print(f"{kept[0]} of {kept[1]} Gaussians -> {alone}", flush=True)
    return {
        "run_dir": run_dir,
        "evaluated": evaluated,
        "files": [*files, alone],
        "object": how,
        "kept": kept,
        "dome": dome,
    }


def run_capture(args: CaptureArgs, api: Calls) -> Made:
    """The whole capture into ``args.out`` (see ``nerfkit capture --help``): each stage run by
    ``api``, or kept from an earlier capture of the same inputs, headed ``[k/N]``; then the summary."""
    from functools import partial

    from ...capture.video import is_video, probe_video
    from ...errors import fail
    from ...images import list_images
    from ...io.atomic import write_json
    from ...io.paths import guard_outputs
    from ...precision import resolve_device

    times: dict[str, float] = {}
    step = partial(_step, verbose=args.verbose, times=times)
    out = Path(args.out)
    video = is_video(args.photos)
    _check_arguments(args, video)
    if out.exists() and not out.is_dir():
        raise fail(out, "exists and is not a folder", "--out names the folder the capture fills")
    for folder, flag in (((None if video else args.photos), "OBJECT_DIR"), (args.calib, "--calib")):
        if folder and not Path(folder).is_dir():
            what = "is not a folder" if Path(folder).exists() else "no such file or folder"
            raise fail(folder, what, f"{flag} names a folder of photos")
    if args.calib and Path(args.calib).resolve() == Path(args.photos).resolve():
        raise fail(
            args.calib,
            "is both the calibration folder and the object's",
            "--calib names the photos of the printed tag sheet, OBJECT_DIR those of the object beside its tag",
        )
    models = ["fast", "splat"] if args.model == "both" else [args.model]
    # the photos may sit in --out (my_object/photos, --out my_object), but nothing is written among them
    ours = [out / DATASET_DIR, out / RECORD_FILE] + ([out / CAMERA_FILE] if args.calib else [])
    ours += [out / FRAMES_DIR] if video else []
    ours += [out / RUN_DIR] if "fast" in models else []
    ours += [out / SPLAT_RUN_DIR, *(out / n for n in SPLAT_FILES), out / OBJECT_SPLAT_FILE] if "splat" in models else []
    guard_outputs(ours, [args.photos, args.calib, args.camera], force=True)
    # what would fail a later step is refused before the first one: a folder without photos,
    # a file that is no video, a missing GPU
    if video:
        probe_video(args.photos)
    else:
        list_images(args.photos)
        _say_videos_beside(Path(args.photos))
    resolve_device(args.device)
    route = _route(args, video)
    inputs = _inputs(args)
    if not args.force:
        _same_inputs(
            out,
            inputs,
            out / CAMERA_FILE if args.calib else None,
            [out / DATASET_DIR / "dataset.npz", out / RUN_DIR / "config.json", out / SPLAT_RUN_DIR / "config.json"],
            ours,
            [args.photos, args.calib, args.camera],
        )
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / RECORD_FILE, {"inputs": inputs})
    dictionary = ["--dict", args.dict] if args.dict else []
    dict_option: dict[str, Any] = {"dictionary": args.dict} if args.dict else {}
    headings = Headings(stage_plan(video, bool(args.calib), models, not args.no_mesh))

    photos = args.photos
    if video:  # the frames are the photos of every later step
        from ...capture.video import select_frames
        from .frames import report_lines

        headings.start("frames")
        photos = str(out / FRAMES_DIR)
        if _frames_there(out / FRAMES_DIR, args.photos, args.clip_frames, inputs["clip_content"]) and not args.force:
            _kept("frames", out / FRAMES_DIR)
        else:  # the folder is the capture's: earlier frames are replaced
            step(
                ["frames", args.photos, "--out", photos, "--frames", str(args.clip_frames), "--force"],
                lambda: print(report_lines(select_frames(args.photos, photos, args.clip_frames, force=True))),
            )

    camera = Path(args.camera) if args.camera else None
    if args.calib:
        headings.start("calibration")
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
    headings.start("poses")
    if (dataset / "dataset.npz").exists() and not args.force:
        _kept("dataset", dataset)
    else:  # --force: the folder is the capture's, and poses cut short leaves poses.json
        step(
            [
                "poses",
                photos,
                *(["--tag-size", str(args.tag_size)] if args.tag_size is not None else []),
                *dictionary,
                "--out",
                str(dataset),
                "--method",
                route,
                "--force",
                *(["--camera", str(camera)] if camera else []),
                *(["--max-side", str(args.max_side)] if args.max_side is not None else []),
            ],
            lambda: _posed(
                api,
                headings,
                photos,
                dataset,
                tag_size=args.tag_size,
                camera=camera,
                method=route,
                force=True,
                max_side=args.max_side,
                **dict_option,
            ),
        )
    if route == "colmap":
        _check_posed(dataset, "frames" if video else "photos")

    run_dir = mesh = None
    evaluated = False
    if "fast" in models:
        run_dir = out / RUN_DIR
        if args.force:
            _replace_run(run_dir)
        _train_run(api, run_dir, dataset, args, step, "fast", headings)
        evaluated, mesh = _fast_outputs(api, run_dir, args, step, headings)
    splat = None
    if "splat" in models:
        splat_run = out / SPLAT_RUN_DIR
        if args.force:
            _replace_run(splat_run)
        splat_step = partial(step, prefix="splat ")
        _train_run(api, splat_run, dataset, args, splat_step, "splat", headings)
        splat = _splat_outputs(api, out, splat_run, args, splat_step, headings)
    print()
    print(
        summary(
            out,
            camera,
            dataset,
            run_dir,
            mesh,
            evaluated,
            mesh_skipped=args.no_mesh,
            times=times,
            splat=splat,
            frames=out / FRAMES_DIR if video else None,
        )
    )
    return Made(out, camera, dataset, run_dir, mesh, evaluated, splat)


def summary(
    out: Path,
    camera: Path | None,
    dataset: Path,
    run_dir: Path | None,
    mesh: Path | None,
    evaluated: bool = True,
    mesh_skipped: bool = False,
    times: dict | None = None,
    splat: dict | None = None,
    frames: Path | None = None,
) -> str:
    """What the capture made, in a few lines: the frames chosen from a video (``frames``,
    their folder), the calibration (and its warnings), the photos posed, the NeRF's
    (``run_dir``, None when none was trained) and the splat's (``splat``, as
    :func:`_splat_outputs` gives it) held-out scores, where the videos, plots, mesh and
    splat files are, a table of the results, and the time each step run now took
    (``times``, seconds by step)."""
    import json

    from ...capture.agreement import agreement_notes
    from ...capture.coverage import coverage_notes
    from ...capture.dataset import FEW_TRAIN_VIEWS, few_views_note, no_object_note
    from ...data.nerfstudio import nerfkit_block
    from ...sfm.dataset import REPORT_FILE

    lines = [f"capture done: {out}"]
    if frames is not None and (frames / "frames.json").is_file():
        f = json.loads((frames / "frames.json").read_text())
        dropped = ", ".join(f"{n} {why}" for why, n in (f.get("dropped") or {}).items())
        lines.append(
            f"  frames    {f['source']}: read {f['read']}, kept {f['kept']} in {frames}"
            + (f" (dropped: {dropped})" if dropped else "")
        )
    sfm = json.loads((dataset / REPORT_FILE).read_text()) if (dataset / REPORT_FILE).is_file() else None
    tagless = not (dataset / "poses.json").is_file()  # posed by structure-from-motion alone
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
    elif tagless and sfm is not None:
        cam = sfm.get("camera") or {}
        params = cam.get("params") or [0.0]
        lines.append(
            f"  camera    solved by structure-from-motion from the photos themselves: {cam.get('model')}, "
            f"focal {params[0]:.1f} px at {cam.get('width')}x{cam.get('height')}"
        )
    else:
        lines.append("  camera    the photos' EXIF focal length, no lens distortion")
    nk = nerfkit_block(dataset) or {}
    views = nk.get("views") or {}
    choice = nk.get("pose_choice")
    if tagless and sfm is not None:
        n_photos, posed = int(sfm["n_photos"]), int(sfm["n_registered"])
        lines.append(
            f"  photos    {n_photos}: {posed} posed by structure-from-motion ({100 * posed / max(n_photos, 1):.0f}%)"
        )
        lines.append(f"  scene     {scene_kind_text(sfm)}")
    else:
        photos = json.loads((dataset / "poses.json").read_text())["photos"]
        found = sum(1 for p in photos if p.get("tags"))
        posed = sum(1 for p in photos if p.get("used"))
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
    if run_dir is not None:
        lines += _nerf_lines(run_dir, mesh, evaluated, mesh_skipped, agreement is not None)
    if splat is not None:
        lines += _splat_lines(splat)
    lines += _results_table(run_dir, mesh, evaluated, splat)
    if times:
        lines.append(
            "  time      "
            + ", ".join(f"{name} {_duration(t)}" for name, t in times.items())
            + f"; {_duration(sum(times.values()))} in all"
        )
    return "\n".join(lines)


def scene_kind_text(sfm: dict) -> str:
    """What structure-from-motion found the scene to be, from its report: an object on a
    table (the plane found in its points, or the tag's), or a scene without one."""
    if str(sfm.get("frame", "")).startswith("metric"):
        return "an object beside its tag: the tag's plane is the table, z = 0, in metres"
    if sfm.get("ground"):
        return (
            "an object on a table: the table found in the sparse points is z = 0 (scale arbitrary: "
            "pass --tag-size with a tag beside the object for metres)"
        )
    return (
        "no table found in the sparse points: trained as a scene without a table, up from the cameras "
        "(the object's videos and mesh may then hold its surroundings)"
    )


def _nerf_lines(run_dir: Path, mesh: Path | None, evaluated: bool, mesh_skipped: bool, agreement: bool) -> list[str]:
    """The summary's lines on the NeRF: its steps and notes, held-out scores, videos, mesh."""
    import json

    from ...output.videos import OBJECT_VIDEO_FILES, VIDEO_FILES

    lines = []
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
    return lines


def _splat_lines(splat: dict) -> list[str]:
    """The summary's lines on the Gaussian splat: its run, held-out scores and files, and what opens them."""
    import json

    from ...capture.splats import DOT_SPLAT_VIEWERS, PLY_VIEWERS

    run_dir = splat["run_dir"]
    m = json.loads((run_dir / "metrics.json").read_text())
    lines = [f"  splat     {run_dir}: {m['step']} steps; plots in {run_dir / 'plots'}"]
    if splat["evaluated"]:
        e = json.loads((run_dir / "eval_val.json").read_text())
        lines.append(
            f"  held out  {e['n_images']} val photos: {e['psnr']:.2f} dB / SSIM {e['ssim']:.3f} as rendered; "
            f"photo beside render: {run_dir / 'eval_val.png'}"
        )
    else:
        lines.append("  held out  not scored (the eval's error is above)")
    ply, dot, alone = splat["files"]
    dome = splat.get("dome") or 0
    behind = f" (the learned background behind it as a far dome of {dome} Gaussians)" if dome else ""
    lines.append(f"  files     {ply}: the 3DGS PLY{behind}, opened by {PLY_VIEWERS}")
    lines.append(f"            {dot}: the same for {DOT_SPLAT_VIEWERS}")
    kept = splat.get("kept")
    lines.append(
        f"            {alone}: the object alone, the Gaussians in {splat['object']}"
        + (f" ({kept[0]} of {kept[1]})" if kept else "")
    )
    return lines


def _results_table(run_dir: Path | None, mesh: Path | None, evaluated: bool, splat: dict | None) -> list[str]:
    """A small table, one row per model trained: steps, held-out PSNR and SSIM, the main file."""
    import json

    rows = []
    for name, folder, scored, main in (
        ("NeRF", run_dir, evaluated, mesh or (run_dir / "videos" / "orbit.mp4" if run_dir else None)),
        ("splat", splat["run_dir"] if splat else None, bool(splat and splat["evaluated"]), splat and splat["files"][0]),
    ):
        if folder is None:
            continue
        steps = json.loads((folder / "metrics.json").read_text())["step"]
        e = json.loads((folder / "eval_val.json").read_text()) if scored else None
        psnr, ssim = (f"{e['psnr']:.2f} dB", f"{e['ssim']:.3f}") if e else ("-", "-")
        rows.append(f"            {name:<6} {steps:>7} {psnr:>10} {ssim:>6}  {main}")
    if not rows:
        return []
    return [f"  results   {'model':<6} {'steps':>7} {'held out':>10} {'SSIM':>6}  file", *rows]


def _duration(seconds: float) -> str:
    return f"{seconds:.0f} s" if seconds < 90 else f"{seconds / 60:.1f} min"
