"""The pipeline from Python (:mod:`nerfkit.api`): calibrate, pose, train, render, evaluate, export,
and capture, all of them in a row.

Each function takes typed keyword arguments named as the flags of its command
(``tag_size=0.06`` for ``--tag-size 0.06``; a ``--no-X`` flag is ``X=False``; the exceptions:
:mod:`nerfkit.api`), checks them as
the command line is checked, does the work, prints the report the command prints (unless
``quiet``) and returns a typed result. The commands parse their command line into these
calls; ``nerfkit capture`` is these functions in a row. Example::

    from nerfkit import api

    camera = api.calibrate("sheet_photos/", "camera.json", tag_size=0.04)
    poses = api.pose("object_photos/", "my_object/", tag_size=0.06, camera=camera.camera_path)
    run = api.train(poses.dataset_path, "runs/my_object", minutes=3)
    print(run.val_psnr, api.render(run.run_dir).videos)
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import functools
import inspect
import os
import types
import typing
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, ParamSpec, TypeVar, get_args

from .options import (
    CalibrateOptions,
    CaptureModel,
    CaptureOptions,
    EvalOptions,
    ExportOptions,
    PoseMethod,
    PosesOptions,
    RenderOptions,
    RunDeviceOptions,
    Split,
    VideoPath,
)

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

    from ..capture.calibrate import CalibrateConfig
    from ..capture.dataset import DatasetConfig
    from ..capture.poses import PoseConfig

# the choices of the commands' flags of the same names (--method: commands/options.py's PoseMethod)
Matcher = Literal["auto", "exhaustive", "sequential", "spatial"]

T = TypeVar("T", bound="DataclassInstance")
P = ParamSpec("P")
R = TypeVar("R")


@dataclass(frozen=True)
class CalibrationResult:
    """A camera file written by :func:`calibrate`."""

    camera_path: Path
    heldout_px: float | None  # reprojection error (px) of the chosen lens model on held-out photos
    model: str  # the lens distortion model chosen
    rms_px: float  # reprojection error (px) on the photos it was fitted to
    photos_used: int


@dataclass(frozen=True)
class PoseResult:
    """A dataset written by :func:`pose`."""

    dataset_path: Path | None  # dataset.npz (None with build_dataset=False)
    posed: int  # photos with a pose in the dataset (or from the tags, without a dataset)
    total: int  # photos in the folder
    out: Path


@dataclass(frozen=True)
class TrainResult:
    """A run trained by :func:`train`."""

    run_dir: Path
    steps: int
    train_seconds: float
    val_psnr: float | None  # the final validation PSNR (dB), all views, whole images
    interrupted: bool
    preset: str  # the scene kind whose settings it took (nerfkit.presets)


@dataclass(frozen=True)
class RenderResult:
    """Videos written by :func:`render`."""

    videos: tuple[Path, ...]  # colour MP4, colour GIF and depth MP4
    frames: int = 0  # frames in each video
    step: int = 0  # the training step of the model rendered


@dataclass(frozen=True)
class EvaluationResult:
    """Scores written by :func:`evaluate` (RUN/eval_<split>.json)."""

    split: str
    psnr: float  # mean over the split's views (dB), as the command prints it
    ssim: float
    report_path: Path  # RUN/eval_<split>.json
    sheet_path: Path | None = None  # RUN/eval_<split>.png (photos beside renders), when written
    scores: dict[str, Any] = field(default_factory=dict, compare=False)  # what report_path holds


@dataclass(frozen=True)
class ExportResult:
    """Files written by :func:`export`."""

    files: tuple[Path, ...]  # the mesh, the points and the Gaussians asked for, in that order
    step: int = 0  # the training step of the model exported


# what ``nerfkit train --resume`` may change: the stopping rule and how the run is carried out
RESUME_APPLIES = (
    "steps",
    "minutes",
    "device",
    "checkpoint_seconds",
    "keep_checkpoints",
    "eval_every",
    "eval_views",
    "eval_pixels",
    "render_chunk",
)


def _accepts(tp: Any, value: Any) -> bool:
    """Whether ``value`` fits the annotation ``tp``: unions, ``Literal`` choices, None, whole
    numbers (not True or False), numbers, text, paths (text or ``os.PathLike``), classes."""
    origin = typing.get_origin(tp)
    if tp is Any:
        return True
    if origin in (typing.Union, types.UnionType):
        return any(_accepts(a, value) for a in get_args(tp))
    if origin is Literal:
        return value in get_args(tp)
    if tp is None or tp is type(None):
        return value is None
    if tp in (bool, int, float, str):
        from ..config import fits

        return fits(tp, value)
    if tp is Path:
        return isinstance(value, (str, os.PathLike))
    if origin is not None:
        return isinstance(value, origin)
    return isinstance(value, tp) if isinstance(tp, type) else True


def _takes_path(tp: Any) -> bool:
    """Whether the annotation ``tp`` is, or is a union holding, ``Path``."""
    return tp is Path or any(_takes_path(a) for a in get_args(tp))


def _describe(tp: Any) -> str:
    """What the annotation ``tp`` asks for, in words (:func:`_accepts`)."""
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        words = list(dict.fromkeys(_describe(a) for a in get_args(tp)))
        return " or ".join(w for w in words if w != "text") if "a path" in words else " or ".join(words)
    if origin is Literal:
        return "one of " + ", ".join(map(str, get_args(tp)))  # as _choice and the command line say it
    names = {bool: "True or False", int: "a whole number", float: "a number", str: "text", Path: "a path"}
    return "None" if tp is None or tp is type(None) else names.get(tp, getattr(tp, "__name__", str(tp)))


def _checked(func: Callable[P, R]) -> Callable[P, R]:
    """``func`` with each argument checked against its annotation first (:func:`_accepts`): a
    wrong kind of value is a NerfkitError naming the flag (``--fps: None is not a whole number``),
    not a TypeError from deep inside; the system's refusal of a file (an OSError) is one too
    (:func:`~nerfkit.errors.os_error`). Annotations that name types only imported for checking
    are not checked here (the settings objects: :func:`_settings`)."""
    signature = inspect.signature(func)
    hints: dict[str, Any] = {}
    for name, annotation in func.__annotations__.items():
        with contextlib.suppress(NameError):
            hints[name] = eval(annotation, func.__globals__) if isinstance(annotation, str) else annotation

    @functools.wraps(func)
    def checked(*args: P.args, **kwargs: P.kwargs) -> R:
        import numpy as np

        from ..config import flag_of
        from ..errors import fail, os_error

        try:
            bound = signature.bind(*args, **kwargs)
        except TypeError:
            return func(*args, **kwargs)  # a missing or unknown argument: Python's own message
        for name, value in bound.arguments.items():  # numpy's scalars as Python's (np.True_, np.int64(3))
            if isinstance(value, np.generic):
                bound.arguments[name] = value.item()
            elif signature.parameters[name].kind is inspect.Parameter.VAR_KEYWORD:
                bound.arguments[name] = {k: v.item() if isinstance(v, np.generic) else v for k, v in value.items()}
        args, kwargs = bound.args, bound.kwargs  # type: ignore[assignment]
        for name, value in bound.arguments.items():
            param = signature.parameters[name]
            if param.kind is param.VAR_KEYWORD or name not in hints or _accepts(hints[name], value):
                continue
            shown = flag_of(name) if param.default is not param.empty else name
            raise fail(shown, f"{value!r} is not {_describe(hints[name])}")
        for name, value in bound.arguments.items():  # "" is no path (Path("") is the current folder)
            output = name in ("out", "to", "png", "mesh", "points", "splat")  # (output_path says so, in its words)
            if isinstance(value, str) and not value.strip() and _takes_path(hints.get(name)) and not output:
                default = signature.parameters[name].default
                shown = flag_of(name) if default is not inspect.Parameter.empty else name
                raise fail(shown, "is empty", "Give a path" + (f", or leave {shown} out" if default is None else ""))
        try:
            return func(*args, **kwargs)
        except OSError as e:  # the system refused a file: the command line's one line, as an error
            raise os_error(e) from e

    return checked


def _given(flag: str, value: Any) -> str | None:
    """An optional path or name given as ``flag``, as a string; None when not given. An empty
    one is refused (it used to fall back to the default without a word)."""
    from ..errors import fail

    if value is None:
        return None
    if str(value).strip() == "":
        raise fail(flag, "is empty", f"Give a value, or leave {flag} out for the default")
    return str(value)


def _check(flag: str, value: Any, parse: Callable[[str], Any]) -> Any:
    """``value`` checked as the command line checks ``flag`` (``parse``: the flag's argparse
    type), converted as the flag converts it; None passes as None."""
    from ..errors import fail

    if value is None:
        return None
    try:
        return parse(str(value))
    except (argparse.ArgumentTypeError, TypeError, ValueError) as e:
        raise fail(flag, str(e)) from None


def _choice(flag: str, value: str, choices: tuple[str, ...]) -> None:
    """Refuse ``value`` when it is not one of the ``choices`` of ``flag``."""
    from ..errors import fail

    if value not in choices:
        raise fail(flag, f"'{value}' is not one of {', '.join(choices)}")


def _settings(given: Any, kind: type[T], name: str) -> T:
    """The settings object ``given`` as argument ``name`` (None: ``kind``'s defaults), checked as
    its flags are: of the right class, each value of the right kind (:func:`~nerfkit.config.check_values`)
    and numbers in their ranges."""
    from ..config import check_ranges, check_values
    from ..errors import fail

    if given is None:
        return kind()
    if not isinstance(given, kind):
        raise fail(name, f"{given!r} is not a {kind.__name__}", f"Pass {kind.__name__}(...) or None")
    check_values(kind, {f.name: getattr(given, f.name) for f in dataclasses.fields(given)})
    return check_ranges(given)


def _options(kind: type[T], given: dict[str, Any]) -> T:
    """The options dataclass ``kind`` (a command's, :mod:`nerfkit.commands.options`) of the
    ``given`` keyword arguments, checked as its flags are (:func:`_settings`; two of one
    ``exclusive`` set: :func:`~nerfkit.config.check_exclusive`) and converted as
    they convert (a whole number given for a float field: a float)."""
    from ..config import base_type, check_exclusive

    options = check_exclusive(_settings(kind(**given), kind, kind.__name__))
    hints = typing.get_type_hints(kind)
    floats = {
        f.name: float(getattr(options, f.name))
        for f in dataclasses.fields(options)
        if base_type(hints[f.name])[0] is float and getattr(options, f.name) is not None
    }
    return dataclasses.replace(options, **floats)


def _say(quiet: bool) -> Callable[[str], None]:
    """Where a stage's report goes: printed, or nowhere when ``quiet``."""
    return (lambda text: None) if quiet else print


@_checked
def calibrate(
    photos: str | Path,
    out: str | Path = "camera.json",
    *,
    tag_size: float | None = None,
    dictionary: str = "DICT_4X4_50",
    layout: str | Path | None = None,
    detect_size: int = CalibrateOptions.detect_size,
    jobs: int = CalibrateOptions.jobs,
    cache: bool = True,
    settings: CalibrateConfig | None = None,
    all_photos: bool = False,
    force: bool = False,
    quiet: bool = False,
) -> CalibrationResult:
    """Calibrate the camera from photos of the printed tag sheet (``nerfkit calibrate``). The
    defaults and ranges of ``detect_size`` and ``jobs`` are those of
    :class:`~nerfkit.commands.options.CalibrateOptions`, as the command's are.

    Args:
        photos: folder of photos of the tag sheet, taken from varied angles.
        out: camera file to write (a folder: its camera.json).
        tag_size: side of one tag's black square in metres (needed unless ``layout`` gives sizes).
        dictionary: ArUco dictionary of the tags.
        layout: sheet layout JSON; None: where the tags sit on the sheet is estimated.
        detect_size: tags are detected on a copy this many pixels on the long side.
        jobs: photos processed in parallel (0: up to 4 cores).
        cache: reuse the detections cached beside ``out``.
        settings: the calibration options (lens model choice, folds, ...); None: the defaults.
        all_photos: the report lists every photo, not only skipped ones.
        force: replace an existing camera file.
        quiet: print no report.
    """
    from ..capture.aruco import get_dictionary, load_layout
    from ..capture.calibrate import CalibrateConfig, calibrate_records, calibration_json
    from ..capture.photos import blur_hint, default_jobs, group_by_size, keep_one_lens, require_tags, scan_photos
    from ..config import output_path, tag_side
    from ..errors import NerfkitError, fail
    from ..io.atomic import write_json
    from ..io.paths import guard_outputs
    from .stages.calibrate import calibration_report

    tag_size = _check("--tag-size", tag_size, tag_side)
    detect_size, jobs = dataclasses.astuple(_options(CalibrateOptions, {"detect_size": detect_size, "jobs": jobs}))
    cfg = _settings(settings, CalibrateConfig, "settings")
    photos_dir, layout_file = str(photos), str(layout) if layout else None
    get_dictionary(dictionary)
    if tag_size is not None and not tag_size > 0:
        raise fail("--tag-size", f"{tag_size} must be a positive length in metres")
    sheet = load_layout(layout_file, dictionary, tag_size) if layout_file else None
    if sheet is None and tag_size is None:
        raise fail("--tag-size", "is required without --layout", "Measure one tag's black square, e.g. --tag-size 0.06")
    if not tag_size:
        assert sheet is not None  # checked above
        tag_size = sheet.tag_size
    path = Path(_check("--out", out, output_path))
    if path.is_dir() or str(out).endswith(("/", os.sep)):  # a folder, or one to make ("cams/")
        path = path / "camera.json"
    guard_outputs([path], [photos_dir, layout_file], force)
    detections = path.with_name(path.stem + ".detections.json") if cache else None

    records = scan_photos(photos_dir, dictionary, sheet, detect_size, detections, jobs or default_jobs())
    require_tags(records, photos_dir, dictionary)
    charuco = sheet is not None and sheet.charuco is not None
    for r in records:
        if r.detection is not None and len(r.detection.ids) == 0:
            r.skip("no tags found" + blur_hint(records, r))
    size, kept = group_by_size(
        keep_one_lens([r for r in records if r.detection is not None and (len(r.detection.ids) or charuco)]),
        turn=True,
        resize=True,
    )
    resized = sorted({r.info["resized_from"] for r in kept if "resized_from" in r.info})
    if resized and size is not None:
        n = sum("resized_from" in r.info for r in kept)
        _say(quiet)(f"{n} photos of {', '.join(resized)}, the shape of the others, are resized to {size[0]}x{size[1]}")
    try:
        cal = calibrate_records(kept, size, tag_size, sheet, cfg, dictionary)
    except NerfkitError as e:
        if layout_file and ("could not calibrate" in str(e) or "cross-validated" in str(e)):
            raise NerfkitError(
                f"{e}; or --layout {layout_file} is not the sheet in these photos: leave it out to estimate "
                "the layout from them"
            ) from None
        raise
    data = calibration_json(cal, records, dictionary, tag_size, str(Path(photos_dir).resolve()))
    write_json(path, data)
    _say(quiet)(calibration_report(cal, records, path, all_photos))
    return CalibrationResult(
        path,
        data.get("heldout_rms"),
        str(data.get("dist_model")),
        float(data["rms"]),
        int(data.get("photos_used", 0)),
    )


@_checked
def pose(
    photos: str | Path,
    out: str | Path,
    *,
    tag_size: float | None = None,
    camera: str | Path | None = None,
    method: PoseMethod = "auto",
    matcher: Matcher = "auto",
    ground: bool = True,
    sfm_max_size: int = PosesOptions.sfm_max_size,
    focal_px: float | None = PosesOptions.focal_px,
    tag_id: int | None = PosesOptions.tag_id,
    layout: str | Path | None = None,
    single_tag: bool = False,
    dictionary: str | None = None,
    build_dataset: bool = True,
    detect_size: int = PosesOptions.detect_size,
    jobs: int = PosesOptions.jobs,
    cache: bool = True,
    max_side: int | None = None,
    pose_settings: PoseConfig | None = None,
    dataset_settings: DatasetConfig | None = None,
    all_photos: bool = False,
    force: bool = False,
    quiet: bool = False,
) -> PoseResult:
    """Pose the photos of an object beside a tag (or by SfM) and build its dataset (``nerfkit poses``).
    The defaults and ranges of ``sfm_max_size``, ``focal_px``, ``tag_id``, ``detect_size`` and
    ``jobs`` are those of :class:`~nerfkit.commands.options.PosesOptions`, as the command's are.

    Args:
        photos: folder of photos of the object beside the tag.
        out: dataset folder to write (poses.json, dataset.npz, transforms.json, images/, ...).
        tag_size: side of the tag's black square in metres (needed unless ``layout`` gives it).
        camera: camera file from :func:`calibrate`; None: the photos' EXIF focal length.
        method: "auto" (tag poses, replaced by SfM poses in the tag's frame when SfM agrees),
            "tags" (the tags alone) or "colmap" (SfM alone; a tag, with ``tag_size``, fixes scale and up).
        matcher: the photo pairs SfM matches ("auto", "exhaustive", "sequential", "spatial").
        ground: with method "colmap" and no tag, find the table plane in the SfM points.
        sfm_max_size: longest side (px) of the images SfM extracts features from.
        focal_px: focal length in pixels to pose with instead of the photos' EXIF (not with
            ``camera`` or ``method="colmap"``).
        tag_id: the tag that defines the world (None: the one seen most; never a layout).
        layout: layout JSON of several tags used jointly (None: the camera file's, or estimated).
        single_tag: pose from one tag, never a layout.
        dictionary: ArUco dictionary (None: the camera file's, else DICT_4X4_50).
        build_dataset: build the dataset (False: only poses.json).
        detect_size: tags are detected on a copy this many pixels on the long side.
        jobs: photos processed in parallel and SfM's threads (0: up to 4 cores, SfM on all).
        cache: reuse the detections cached in ``out``.
        max_side: the dataset's views' longer side in pixels (0: keep; None: ``dataset_settings``').
        pose_settings: the posing options (error limits, focal refinement); None: the defaults.
        dataset_settings: the dataset options (size, splits, near/far, ...); None: the defaults.
        all_photos: the report lists every photo, not only skipped ones.
        force: replace the dataset files of an earlier run in ``out``.
        quiet: print no report.
    """
    from ..capture.aruco import get_dictionary, load_layout
    from ..capture.camera import load_camera
    from ..capture.dataset import POSES_FILE, DatasetConfig, posed_none, write_poses_json
    from ..capture.dataset import check_settings as check_dataset_settings
    from ..capture.focal import focal_check
    from ..capture.photos import default_jobs, require_tags, scan_photos
    from ..capture.poses import PoseConfig, pose_records
    from ..capture.report import reason_counts
    from ..config import output_path, tag_side
    from ..errors import fail
    from ..images import list_images
    from ..io.paths import guard_outputs, refuse_links
    from .stages import pose as stage

    _choice("--method", method, get_args(PoseMethod))
    _choice("--matcher", matcher, get_args(Matcher))
    tag_size = _check("--tag-size", tag_size, tag_side)
    given = {"focal_px": focal_px, "tag_id": tag_id, "sfm_max_size": sfm_max_size}
    focal_px, tag_id, sfm_max_size, detect_size, jobs = dataclasses.astuple(
        _options(PosesOptions, {**given, "detect_size": detect_size, "jobs": jobs})
    )
    pcfg = _settings(pose_settings, PoseConfig, "pose_settings")
    dcfg = _settings(dataset_settings, DatasetConfig, "dataset_settings")
    if max_side is not None:  # (checked with the settings it joins)
        dcfg = _settings(dataclasses.replace(dcfg, max_side=max_side), DatasetConfig, "--max-side")
    check_dataset_settings(dcfg)
    say = _say(quiet)
    photos_dir, folder = str(photos), Path(_check("--out", out, output_path))
    camera_file, layout_file = (str(camera) if camera else None), (str(layout) if layout else None)
    if folder.exists() and not folder.is_dir():
        raise fail(folder, "exists and is not a folder", "--out names the dataset folder to write")
    outputs = [folder / name for name in stage.output_names(method, build_dataset)]
    outputs = [p for p in outputs if not (p.name == POSES_FILE and posed_none(p))]  # an earlier failed try's
    guard_outputs(outputs, [photos_dir, camera_file, layout_file], force)
    refuse_links(folder, ["colmap"])  # structure-from-motion's work folder
    given_camera = load_camera(camera_file) if camera_file else None
    dictionary = stage.dictionary_of(dictionary, camera_file)
    get_dictionary(dictionary)
    if tag_size is not None and not tag_size > 0:
        raise fail("--tag-size", f"{tag_size} must be a positive length in metres")
    workers = jobs or default_jobs()
    if focal_px is not None and (camera_file or method == "colmap"):
        raise fail(
            "--focal-px",
            "does nothing "
            + ("with --camera: the camera file's focal length is used" if camera_file else "with --method colmap"),
            "Leave out one of them",
        )
    if method == "colmap" and not build_dataset:
        raise fail(
            "--no-dataset",
            "does not apply to --method colmap: structure-from-motion poses the photos as it builds the dataset",
            "Leave out --no-dataset, or pose by the tags alone with --method tags",
        )
    if method == "colmap":
        from ..sfm import sfm_dataset

        scene, report, summary = sfm_dataset(
            photos_dir,
            folder,
            dcfg,
            matcher=matcher,
            max_image_size=sfm_max_size,
            tag_size=tag_size,
            tag_id=tag_id or 0,
            tag_dict=dictionary,
            threads=jobs or -1,
            jobs=workers,
            ground=ground,
            camera=given_camera,
            progress=not quiet,
        )
        say(report.summary())
        return _dataset_built(scene, summary, folder, len(list_images(photos_dir)), quiet)
    sheet = load_layout(layout_file, dictionary, tag_size) if layout_file else None
    if sheet is None and tag_size is None:
        raise fail("--tag-size", "is required", "Measure the tag's black square, e.g. --tag-size 0.06")

    detections = folder / "detections.json" if cache else None
    records = scan_photos(photos_dir, dictionary, sheet, detect_size, detections, workers)
    require_tags(
        records,
        photos_dir,
        dictionary,
        "; photos without a tag are posed by structure-from-motion: --method colmap (metric scale needs a tag)",
    )
    cam, frame, side, tags_focal, notes = stage.tag_frame(
        records,
        given_camera,
        sheet,
        camera_file=camera_file,
        dictionary=dictionary,
        focal_px=focal_px,
        tag_id=tag_id,
        tag_size=tag_size,
        single_tag=single_tag,
        cfg=pcfg,
    )
    printed = frame.flattened()  # what the files record and the dataset's tags (the heights: the poses' alone)
    posed = pose_records(records, cam, frame, pcfg)
    note = stage.scaled_note(posed, cam)
    if note:
        notes.append(note)
    folder.mkdir(parents=True, exist_ok=True)
    checked = focal_check(given_camera, tags_focal)  # the camera file's focal length against the tags'
    meta = stage.poses_meta(photos_dir, dictionary, side, printed, frame, notes, pcfg, checked)
    write_poses_json(folder / POSES_FILE, records, posed, cam, meta)
    sfm_next = method == "auto" and build_dataset and bool(posed)  # (it says so with SfM's focal length)
    say(stage.poses_report(notes, cam, records, folder / POSES_FILE, all_photos, None if sfm_next else checked))
    if not posed:  # (a poses.json that posed none is replaced by the next try without --force)
        camera_wrong = camera_file and all("camera" in r.reason for r in records if r.detection is not None)
        raise fail(
            photos_dir,
            f"no photo could be posed ({reason_counts([r.reason for r in records])}; each photo's reason: "
            f"{folder / POSES_FILE})",
            f"Calibrate with photos of this size, shape and lens, or leave out --camera {camera_file}"
            if camera_wrong
            else "Check --tag-size/--tag-id and that the tag is sharp and fully visible",
        )
    total = len(list_images(photos_dir))
    if not build_dataset:
        return PoseResult(None, len(posed), total, folder)
    if method == "auto":
        scene, summary = stage.chosen_dataset(
            photos_dir,
            folder,
            posed,
            records,
            cam if (camera_file or focal_px) else None,  # else SfM starts from the EXIF focal length
            frame,
            printed,
            tag_size=side,
            dictionary=dictionary,
            notes=notes,
            matcher=matcher,
            sfm_max_size=sfm_max_size,
            jobs=workers,
            threads=jobs or -1,
            pose_cfg=pcfg,
            dataset_cfg=dcfg,
            say=say,
            progress=not quiet,
            camera_file=given_camera,
            tags_focal=tags_focal,
        )
    else:
        extra = {"notes": notes, "focal_check": None if checked is None else checked.as_json()}
        scene, summary = stage.tag_dataset(posed, folder, dcfg, side, workers, extra, printed.corners())
    return _dataset_built(scene, summary, folder, total, quiet)


def _dataset_built(scene: Any, summary: dict, folder: Path, total: int, quiet: bool) -> PoseResult:
    """The end of :func:`pose` on every route (the tags, SfM in their frame, SfM alone): what
    the dataset builder's ``summary`` says was written (the split, K, near/far, the table, the
    coverage, ...: :func:`~nerfkit.commands.stages.dataset.report_dataset`) unless ``quiet``, and
    the result (``total``: the photos in the folder)."""
    from ..capture.dataset import NPZ_FILE
    from .stages.dataset import report_dataset

    if not quiet:
        report_dataset(summary, folder)
    return PoseResult(folder / NPZ_FILE, _views(scene), total, folder)


def _views(scene: Any) -> int:
    """The views of a dataset, every split."""
    return sum(len(v) for v in scene.splits.values())


def train_settings(options: dict[str, Any], config: str | Path | None = None) -> tuple[Any, Any, set[str]]:
    """(TrainConfig, model config, names given): the settings ``nerfkit train`` builds from its
    flags. A name neither config has is a TypeError; one of another model, a NerfkitError.

    Args:
        options: TrainConfig and model settings by field name.
        config: a run's config.json (or its run folder) to start from; None: the defaults.
    """
    from ..config import check_ranges, check_values
    from ..errors import fail
    from ..models import MODEL_NAMES, model_config_class
    from ..train.config import TrainConfig

    check_values(TrainConfig, options)
    if config is not None:
        from ..train.checkpoint import read_settings

        base, base_model, given = read_settings(config)
    else:
        base, base_model, given = TrainConfig(), None, set()
    train_names = {f.name for f in dataclasses.fields(TrainConfig)}
    cfg = check_ranges(dataclasses.replace(base, **{k: v for k, v in options.items() if k in train_names}))
    if cfg.model not in MODEL_NAMES:
        raise fail("--model", f"'{cfg.model}' is not a model", f"Choose one of: {', '.join(MODEL_NAMES)}")
    model_class = model_config_class(cfg.model)
    if base_model is not None and not isinstance(base_model, model_class):  # another model than the config's
        given -= {f.name for f in dataclasses.fields(type(base_model))}
        base_model = None
    if config is not None and base.model != cfg.model:
        # the training settings each model presets (its learning rate, its batch) are the new model's
        from ..presets import MODEL_TRAINING

        preset = {k for values in MODEL_TRAINING.values() for k in values} - set(options)
        cfg = dataclasses.replace(cfg, **{k: getattr(TrainConfig(), k) for k in preset})
        given -= preset
    model_names = {f.name for f in dataclasses.fields(model_class)}
    unknown = set(options) - train_names - model_names
    owned = {k: sorted(m for m, names in model_fields().items() if k in names) for k in sorted(unknown)}
    foreign = {k: v for k, v in owned.items() if v}
    if foreign:
        from ..config import flag_of

        name, owners = next(iter(foreign.items()))
        raise fail(
            flag_of(name),
            f"is a setting of the {' and '.join(owners)} model{'s' if len(owners) > 1 else ''}, not of {cfg.model}",
            f"Leave it out, or train with model {' or '.join(repr(m) for m in owners)}",
        )
    if unknown:
        raise TypeError(
            f"train() got settings that neither training nor the {cfg.model} model has: {', '.join(sorted(unknown))}"
        )
    model_values = {k: v for k, v in options.items() if k in model_names}
    check_values(model_class, model_values, owner=f"the {cfg.model} model")
    model_cfg = (
        dataclasses.replace(base_model, **model_values) if base_model is not None else model_class(**model_values)
    )
    return cfg, model_cfg, given | set(options)


@_checked
def train(
    data: str | Path | None = None,
    out: str | Path | None = None,
    *,
    model: str | None = None,
    steps: int | None = None,
    minutes: float | None = None,
    config: str | Path | None = None,
    quiet: bool = False,
    **options: Any,
) -> TrainResult:
    """Train a new run on a dataset (``nerfkit train``): ``options`` are training and model
    settings by name (``lr=0.1``, ``resolutions="32,64"``); the ones not given take the
    dataset's kind's (:mod:`nerfkit.presets`). ``config``: start from a run's settings. With
    neither ``steps`` nor ``minutes`` (nor a config's), it trains for 5 minutes.

    Args:
        data: the dataset: a course .npz or any format ``nerfkit convert`` reads (None: the config's).
        out: the run folder to create (None: the config's, else runs/latest).
        model: "fast", "splat" or "vanilla" (None: the config's, else the dataset's kind chooses:
            :func:`nerfkit.presets.default_model`).
        steps: optimizer steps (None: the config's; 0: until ``minutes`` is spent).
        minutes: training-time budget in minutes, evaluation excluded.
        config: a run's config.json (or its folder) whose settings this run starts from.
        quiet: print no progress or report.
        options: any other TrainConfig or model setting by its field name (``device="cpu"``).
    """
    from ..config import output_path
    from ..errors import fail
    from ..models import check_config
    from ..train.config import TrainConfig
    from ..train.trainer import check_new_run_folder
    from ..train.trainer import train as train_run
    from ._common import load_as_trained

    _check("--out", out, output_path)
    given = {
        k: str(v) if k in ("data", "out") else v
        for k, v in (("data", data), ("out", out), ("model", model), ("steps", steps), ("minutes", minutes))
        if v is not None
    }
    # no model named (nor a config's): the dataset's kind chooses it, once the dataset is loaded
    choose = model is None and config is None
    train_names = {f.name for f in dataclasses.fields(TrainConfig)}
    train_only = {k: v for k, v in {**options, **given}.items() if k in train_names}
    unknown = (set(options) - train_names - set().union(*model_fields().values())) if choose else set()
    if unknown:
        raise TypeError(f"train() got settings that neither training nor any model has: {', '.join(sorted(unknown))}")
    cfg, model_cfg, user_set = train_settings(train_only if choose else {**options, **given}, config)
    if not cfg.data:
        raise fail(
            "train",
            "no dataset given",
            "Pass --data FILE (try the bundled src/nerfkit/assets/lego_200x200.npz, or run `nerfkit demo`)",
        )
    check_new_run_folder(Path(cfg.out))  # before loading the dataset: a refusal should be quick
    scene = None
    if choose:
        scene = load_as_trained(cfg, cfg.data, allow_outside=cfg.allow_outside_paths)
        name = kind_model(scene, cfg.capture, set(options) - set(train_only))
        cfg, model_cfg, user_set = train_settings({**options, **given, "model": name})
        user_set.discard("model")
    if cfg.steps == 0 and cfg.minutes == 0:
        cfg = dataclasses.replace(cfg, minutes=5.0)
        if not quiet:
            import sys

            print("no --steps or --minutes: training for 5 minutes", file=sys.stderr)
    model_cfg = check_config(cfg.model, model_cfg)  # its own bounds
    # RGBA images are composited on the colour the model renders behind the scene
    if scene is None:
        scene = load_as_trained(cfg, cfg.data, allow_outside=cfg.allow_outside_paths)
    result = train_run(scene, cfg, model_cfg, quiet=quiet, user_set=user_set)
    return _train_result(result)


def model_fields() -> dict[str, frozenset[str]]:
    """Each model of this installation -> its setting names."""
    from ..models import MODEL_NAMES, model_config_class

    fields = {}
    for m in MODEL_NAMES:
        with contextlib.suppress(ImportError):  # a model whose optional parts are missing
            fields[m] = frozenset(f.name for f in dataclasses.fields(model_config_class(m)))
    return fields


def kind_model(scene, capture: str, settings: set[str]) -> str:
    """The model to train on ``scene`` when none is named: its kind's
    (:func:`nerfkit.presets.default_model`). A model ``settings`` given that it does not take
    is refused, naming the models that do (training would ignore it)."""
    from ..errors import fail
    from ..presets import default_model, scene_kind

    fields = model_fields()
    kind = scene_kind(scene, capture)
    name = default_model(kind, fields)
    foreign = sorted(settings - fields[name])
    if foreign:
        owners = [m for m in fields if foreign[0] in fields[m]]
        flag = "--" + foreign[0].replace("_", "-")
        raise fail(
            flag,
            f"is a setting of the {' and '.join(owners)} model{'s' * (len(owners) > 1)}, not of {name} (the "
            f"default --model for a{'n' * (kind[0] in 'aeiou')} {kind} dataset)",
            f"Leave it out, or train with --model {' or --model '.join(owners)}",
        )
    return name


def _train_result(result) -> TrainResult:
    from ..train.checkpoint import read_run

    return TrainResult(
        Path(result.run_dir),
        result.step,
        result.train_seconds,
        result.final_val_psnr,
        result.interrupted,
        read_run(result.run_dir).train.preset,
    )


@_checked
def resume(
    run: str | Path,
    *,
    steps: int | None = None,
    minutes: float | None = None,
    data: str | Path | None = None,
    allow_outside_paths: bool = False,
    quiet: bool = False,
    **changes: Any,
) -> TrainResult:
    """Continue a run from its newest good checkpoint (``nerfkit train --resume``), with a new
    stopping rule or the settings ``nerfkit train --resume`` applies (``device``, ``eval_every``, ...).

    Args:
        run: the run folder to continue.
        steps: the new step budget (None: the run's).
        minutes: the new time budget, the run's total training time, not more time (None: the run's).
        data: the dataset, when it has moved (None: the one the run records).
        allow_outside_paths: read dataset images outside the dataset's folder (also when the
            run was trained so).
        quiet: print no progress or report.
        changes: settings of :data:`RESUME_APPLIES` by name; any other is refused.
    """
    from ..errors import fail
    from ..train.checkpoint import read_run
    from ..train.trainer import resume as resume_run
    from ._common import load_as_trained, run_dataset_path

    refused = sorted(set(changes) - set(RESUME_APPLIES))
    if refused:
        raise fail(
            "resume",
            f"{', '.join(refused)} cannot change when a run continues (it keeps its own settings)",
            "Resume without them: it applies only " + ", ".join(RESUME_APPLIES),
        )
    info = read_run(run)
    allow = allow_outside_paths or info.train.allow_outside_paths
    scene = load_as_trained(info.train, str(data or run_dataset_path(info)), allow_outside=allow)
    changes = {**changes, **{k: v for k, v in (("steps", steps), ("minutes", minutes)) if v is not None}}
    return _train_result(resume_run(run, scene, quiet=quiet, changes=changes, data=data or None))


def _run_checks(chunk: int) -> int:
    """``chunk`` (rays rendered at once) checked as ``--chunk`` is
    (:class:`~nerfkit.commands.options.RunDeviceOptions`)."""
    return _options(RunDeviceOptions, {"chunk": chunk}).chunk


@_checked
def render(
    run: str | Path,
    *,
    out: str | Path | None = None,
    path: VideoPath = RenderOptions.path,
    frames: int | None = RenderOptions.frames,
    fps: int = RenderOptions.fps,
    object: bool = RenderOptions.object,  # noqa: A002 - the flag's name
    background: str | None = RenderOptions.background,
    data: str | Path | None = None,
    device: str = RunDeviceOptions.device,
    chunk: int = RunDeviceOptions.chunk,
    allow_outside_paths: bool = False,
    force: bool = False,
    quiet: bool = False,
) -> RenderResult:
    """Render a run's videos (``nerfkit render``): colour (MP4 and GIF) and depth. The defaults
    and ranges of its options (``path`` to ``background``) are those of
    :class:`~nerfkit.commands.options.RenderOptions`, as the command's are.

    Args:
        run: run folder written by :func:`train`.
        out: folder of the videos (None: RUN/videos, replaced: it belongs to the run).
        path: the camera path: the dataset's "test" poses, an "orbit" around the object, a
            "spiral" across a forward-facing capture's view, or "auto" (the test poses when they
            are a camera path, else a spiral for a forward-facing capture, else an orbit).
        frames: frames of an orbit or spiral (None: 120).
        fps: frames per second.
        object: render the object alone (object.mp4, object.gif, object_depth.mp4): a capture's
            table, floor and room left out, on white, centred and framed whole (one zoom for the path).
        background: the colour behind the scene (black, white, grey, "r,g,b" or "#rrggbb";
            None: the run's, white with ``object``).
        data: dataset (None: the one the run was trained on).
        device: "auto", "cpu", "cuda" or "cuda:N".
        chunk: rays rendered at once (0: the run's render chunk).
        allow_outside_paths: read dataset images outside the dataset's folder.
        force: replace videos already in ``out``.
        quiet: print no report (a note on ``frames`` still goes to stderr).
    """
    import sys

    from ..config import output_path
    from ..data.load import dataset_inputs
    from ..data.scene import ORBIT_FRAMES
    from ..errors import fail
    from ..io.paths import guard_outputs, refuse_links
    from ..output.images import frame_object, object_aim
    from ..output.videos import OBJECT_VIDEO_FILES, VIDEO_FILES, render_videos
    from ..train.checkpoint import read_run
    from . import _common
    from .stages import render as stage

    _options(RenderOptions, dict(path=path, frames=frames, fps=fps, object=object, background=background))
    chunk = _run_checks(chunk)
    data = _given("--data", data)
    folder = Path(_check("--out", out, output_path)) if out is not None else Path(run) / "videos"
    if out is None:
        refuse_links(run, ["videos"])
    names = OBJECT_VIDEO_FILES if object else VIDEO_FILES
    guard_outputs([folder / name for name in names], dataset_inputs(data or read_run(run).train.data), force or not out)
    opened = _common.open_run(_common.RunToOpen(run, device, chunk))
    scene = _common.scene_for_run(opened.info, data, allow_outside=allow_outside_paths)
    kind, note = stage.path_kind(scene, path, frames, object, getattr(opened.model, "ndc", None) is not None)
    if note:
        print(note, file=sys.stderr)
    colour = opened.background(_given("--background", background) or ("white" if object else None))
    alone = stage.leave_object_alone(opened.model) if object else ""
    # an orbit looks at the trained object, not at the point the cameras' axes meet
    aim = (
        object_aim(opened.model, scene.train, scene.up, colour, opened.chunk, opened.autocast)
        if kind == "orbit"
        else None
    )
    views = scene.render_path(frames or ORBIT_FRAMES, aim, kind)
    near, far = scene.near, scene.far
    if object:
        looked_at = aim if aim is not None else scene.center  # (what the path's cameras look at)
        framing = frame_object(opened.model, views, colour, opened.chunk, opened.autocast, aim=looked_at)
        if framing is None:
            raise fail(
                run,
                "renders nothing solid along the video's path, so there is no object to frame",
                "Render the scene without --object, or train longer",
            )
        views, near, far = framing.views, framing.near, framing.far
        alone += f"; zoomed {framing.zoom:.2f}x)"
    paths = render_videos(
        opened.model,
        views,
        folder,
        colour,
        near,
        far,
        fps,
        opened.chunk,
        opened.autocast,
        names=names,
        metres=scene.tags is not None,
    )
    videos = (Path(paths.rgb_mp4), Path(paths.rgb_gif), Path(paths.depth_mp4))
    _say(quiet)(stage.render_report(len(views), alone, opened.step, paths.seconds_per_frame, list(videos)))
    return RenderResult(videos, len(views), opened.step)


@_checked
def evaluate(
    run: str | Path,
    *,
    split: Split = EvalOptions.split,
    fit_views: int | None = EvalOptions.fit_views,
    data: str | Path | None = None,
    device: str = RunDeviceOptions.device,
    chunk: int = RunDeviceOptions.chunk,
    allow_outside_paths: bool = False,
    quiet: bool = False,
) -> EvaluationResult:
    """Score a run on a split's held-out views (``nerfkit eval``): PSNR and SSIM, written to
    RUN/eval_<split>.json, with photos beside renders in RUN/eval_<split>.png. The defaults and
    ranges of ``split`` and ``fit_views`` are those of
    :class:`~nerfkit.commands.options.EvalOptions`, as the command's are.

    Args:
        run: run folder written by :func:`train`.
        split: which views: "val", "test" or "train".
        fit_views: also score each view with its pose fitted for this many steps and each half's
            colour solved on the other half (None: 100 for a capture's run, else 0: off).
        data: dataset (None: the one the run was trained on).
        device: "auto", "cpu", "cuda" or "cuda:N".
        chunk: rays rendered at once (0: the run's render chunk).
        allow_outside_paths: read dataset images outside the dataset's folder.
        quiet: do not print the summary (the result holds it).
    """
    from ..data.load import dataset_inputs
    from ..io.atomic import write_json
    from ..io.paths import guard_outputs, safe_output_name
    from ..train.checkpoint import dataset_differences
    from . import _common
    from .stages import evaluate as stage

    _options(EvalOptions, dict(split=split, fit_views=fit_views))
    chunk = _run_checks(chunk)
    say = _say(quiet)
    opened = _common.open_run(_common.RunToOpen(run, device, chunk))
    scene = _common.scene_for_run(opened.info, _given("--data", data), need=split, allow_outside=allow_outside_paths)
    stage.held_out_views(scene, split)
    # a run kept inside its dataset's folder: nothing is written among a dataset's files
    guard_outputs([Path(run) / f"eval_{split}.json"], dataset_inputs(data or opened.info.train.data), force=True)
    capture = getattr(opened.info.train, "capture", "off") == "on"
    steps = stage.fit_steps(capture, fit_views)
    sheet: list = []
    result = stage.scores(opened, scene, split, steps, sheet)
    differ = dataset_differences(opened.info, scene) if data else []
    result["runs_own_dataset"] = not differ
    # the run's own score stays: one on another dataset is written beside it, under its name
    name = f"eval_{split}" + (f"_{safe_output_name(Path(str(data)).stem)}" if differ else "")
    json_path, sheet_path = Path(run) / f"{name}.json", Path(run) / f"{name}.png"
    if differ:
        parts = ", ".join(d.replace("_sha256", "") for d in differ)
        say(
            f"note: {data} is not the dataset the run was trained on ({parts} differ): scores on another "
            f"dataset, written to {json_path.name}"
        )
    write_json(json_path, result)
    stage.write_contact_sheet(sheet_path, sheet, split)
    say(stage.summary(result))
    say(f"wrote {json_path}" + (f" and {sheet_path} (photo beside render)" if sheet else ""))
    return EvaluationResult(
        split,
        float(result["psnr"]),
        float(result["ssim"]),
        json_path,
        sheet_path if sheet else None,
        result,
    )


@_checked
def export(
    run: str | Path,
    *,
    mesh: str | Path | None = None,
    points: str | Path | None = None,
    splat: str | Path | None = None,
    resolution: int = ExportOptions.resolution,
    threshold: float | None = ExportOptions.threshold,
    box_scale: float = ExportOptions.box_scale,
    table_cut: float = ExportOptions.table_cut,
    color_views: int = ExportOptions.color_views,
    color_dirs: int = ExportOptions.color_dirs,
    every: int = ExportOptions.every,
    stride: int = ExportOptions.stride,
    acc_min: float = ExportOptions.acc_min,
    crop: bool = ExportOptions.crop,
    background_dome: bool = ExportOptions.background_dome,
    data: str | Path | None = None,
    device: str = RunDeviceOptions.device,
    chunk: int = RunDeviceOptions.chunk,
    allow_outside_paths: bool = False,
    force: bool = False,
    quiet: bool = False,
) -> ExportResult:
    """Export a run as a mesh, a point cloud or (splat runs) Gaussians (``nerfkit export``).
    The defaults and ranges of its options (``resolution`` to ``background_dome``) are those of
    :class:`~nerfkit.commands.options.ExportOptions`, as the command's are.

    Args:
        run: run folder written by :func:`train`.
        mesh: write a vertex-coloured triangle mesh here (.ply).
        points: write a coloured point cloud here (.ply).
        splat: (splat runs) write the Gaussians here: 3DGS PLY, or a name ending in .splat.
        resolution: mesh: grid cells per side.
        threshold: mesh: density of the surface (None: scale-free, see ``nerfkit export --help``).
        box_scale: scale of the cube meshed and of the box points are cropped to.
        table_cut: mesh, captures: the fraction of the object's height above the table whose
            painted density is cleared.
        color_views: mesh: training views rendered for the vertex colours (0: along the normals
            only).
        color_dirs: mesh: directions averaged per colour of a vertex no view sees.
        every: points: use every N-th training view.
        stride: points: use every N-th pixel in each direction.
        acc_min: points: keep pixels with opacity above this.
        crop: points: drop points outside the scene box.
        background_dome: splat: a model's learned background follows its Gaussians as a far
            dome of Gaussians (:mod:`nerfkit.capture.dome`), so that other viewers show it too.
        data: dataset whose training views colour the mesh and give the points (None: the run's).
        device: "auto", "cpu", "cuda" or "cuda:N".
        chunk: rays rendered at once (0: the run's render chunk).
        allow_outside_paths: read dataset images outside the dataset's folder.
        force: replace existing output files.
        quiet: print no report (a note that an option of an output not asked for does nothing
            still goes to stderr).
    """
    from ..config import output_path
    from ..data.load import dataset_inputs
    from ..errors import fail
    from ..io.atomic import all_or_none
    from ..io.paths import guard_outputs
    from . import _common
    from .stages import export as stage

    given = dict(
        resolution=resolution,
        threshold=threshold,
        box_scale=box_scale,
        table_cut=table_cut,
        color_views=color_views,
        color_dirs=color_dirs,
        every=every,
        stride=stride,
        acc_min=acc_min,
        crop=crop,
        background_dome=background_dome,
    )
    options = _options(ExportOptions, given)
    chunk = _run_checks(chunk)
    say = _say(quiet)
    mesh_file, points_file, splat_file = (
        _check(flag, p, output_path) for flag, p in (("--mesh", mesh), ("--points", points), ("--splat", splat))
    )
    data = _given("--data", data)
    stage.check_outputs(mesh_file, points_file, splat_file)
    stage.note_idle_options(options, mesh_file, points_file, splat_file, data)
    opened = _common.open_run(_common.RunToOpen(run, device, chunk))
    if splat_file and not hasattr(opened.model, "n_gaussians"):
        raise fail(
            run,
            f"is a {opened.info.train.model} run; --splat exports runs of --model splat",
            f"Train one on the same data: nerfkit train --data {opened.info.train.data or 'DATASET'} "
            "--model splat --out RUN",
        )
    if mesh_file and hasattr(opened.model, "n_gaussians"):
        raise fail(
            run,
            "is a splat run: it has no density field to mesh",
            "Use --splat OUT.ply or --points, or train a NeRF (--model fast) to export a mesh",
        )
    guard_outputs(
        [mesh_file, points_file, splat_file],
        dataset_inputs(data or opened.info.train.data),
        force,
        "--mesh/--points/--splat",
    )
    targets = [p for p in (mesh_file, points_file, splat_file) if p]
    said: list[str] = []  # (told once all are written, under their own names)
    with all_or_none(targets) as pending:  # a failed export leaves none of its files, nor half of them
        renamed = {str(tmp): str(t) for tmp, t in zip(pending, targets, strict=True)}
        mesh_file, points_file, splat_file = (
            str(pending[targets.index(p)]) if p else None for p in (mesh_file, points_file, splat_file)
        )
        if splat_file:
            said.append(stage.export_splat(opened, splat_file, options.background_dome))
        if mesh_file:
            said.append(
                stage.export_mesh(
                    opened,
                    mesh_file,
                    resolution=options.resolution,
                    threshold=options.threshold,
                    box_scale=options.box_scale,
                    table_cut=options.table_cut,
                    color_views=options.color_views,
                    color_dirs=options.color_dirs,
                    data=data,
                    allow_outside=allow_outside_paths,
                )
            )
        if points_file:
            radius = opened.info.bounds.radius * options.box_scale
            said.append(
                stage.export_points(
                    opened,
                    points_file,
                    every=options.every,
                    stride=options.stride,
                    acc_min=options.acc_min,
                    crop_radius=radius if options.crop else None,
                    data=data,
                    allow_outside=allow_outside_paths,
                )
            )
    for text in said:
        for tmp, target in renamed.items():
            text = text.replace(tmp, target)
        say(text)
    written = tuple(Path(p) for p in targets)
    return ExportResult(written, opened.step)


@dataclass(frozen=True)
class CaptureResult:
    """What :func:`capture` made in its ``out`` folder."""

    out: Path
    dataset_path: Path  # the posed dataset's folder (OUT/dataset)
    camera_path: Path | None  # the camera file the photos were posed with (None: EXIF or SfM's own)
    run_dir: Path | None  # the NeRF's run (None: not trained)
    mesh: Path | None  # the NeRF's mesh (None: not made)
    splat_run: Path | None  # the splat's run (None: not trained)
    splat_files: tuple[Path, ...]  # splat.ply, splat.splat and the object alone, splat_object.ply
    psnr: dict[str, float]  # held-out PSNR (dB) of each model scored: "NeRF", "splat"


@_checked
def capture(
    photos: str | Path,
    out: str | Path,
    *,
    tag_size: float | None = CaptureOptions.tag_size,
    calib: str | Path | None = CaptureOptions.calib,
    camera: str | Path | None = CaptureOptions.camera,
    sheet_tag_size: float | None = CaptureOptions.sheet_tag_size,
    dictionary: str | None = CaptureOptions.dictionary,
    method: PoseMethod = CaptureOptions.method,
    clip_frames: int = CaptureOptions.clip_frames,
    model: CaptureModel = CaptureOptions.model,
    max_side: int | None = CaptureOptions.max_side,
    minutes: float = CaptureOptions.minutes,
    steps: int | None = CaptureOptions.steps,
    frames: int | None = CaptureOptions.frames,
    mesh: bool = CaptureOptions.mesh,
    device: str = CaptureOptions.device,
    force: bool = False,
    verbose: bool = False,
    quiet: bool = False,
) -> CaptureResult:
    """A phone video or photos of an object to a NeRF and/or a Gaussian splat in one go
    (``nerfkit capture``): frames, calibration, poses, training, evaluation, videos and files,
    each kept for the next call with the same inputs. It prints what each stage prints, under
    ``[k/N]`` headings, and a summary (``quiet``: nothing; a stage's failure is the error raised).
    The defaults and checks of its options (``tag_size`` to ``device``) are those of
    :class:`~nerfkit.commands.options.CaptureOptions`, as the command's are.

    Args:
        photos: a folder of photos of the object, or a video filmed slowly around it.
        out: the folder for everything the capture makes.
        tag_size: side of the tag's black square beside the object in metres (None: no tag,
            structure-from-motion poses and the table is found in its points).
        calib: folder of photos of the printed tag sheet to calibrate the camera from.
        camera: a camera file from :func:`calibrate` (not with ``calib``).
        sheet_tag_size: side of the sheet's tags (None: ``tag_size``).
        dictionary: ArUco dictionary of the tags (None: the camera file's, else DICT_4X4_50).
        method: how the photos are posed ("auto", "tags", "colmap"; see ``nerfkit capture --help``).
        clip_frames: a video: frames kept from it, at most.
        model: "fast" (the NeRF, with its videos and mesh), "splat" or "both".
        max_side: the dataset's photos' longer side in pixels (0: keep; None: :func:`pose`'s).
        minutes: training time of each model (unless ``steps``).
        steps: train this many steps instead of ``minutes``.
        frames: frames of the orbit videos (None: :func:`render`'s).
        mesh: make the NeRF's mesh.
        device: "auto", "cpu", "cuda" or "cuda:N".
        force: redo every stage, replacing the results of an earlier capture in ``out``.
        verbose: a stage's error comes with its traceback.
        quiet: print nothing (what the stages print is dropped).
    """
    import io
    import json

    from ..config import output_path
    from .stages import capture as stage

    paths = {"calib": str(calib) if calib is not None else None, "camera": str(camera) if camera is not None else None}
    given = {
        **{"tag_size": tag_size, **paths, "sheet_tag_size": sheet_tag_size, "dictionary": dictionary},
        **{"method": method, "clip_frames": clip_frames, "model": model, "max_side": max_side},
        **{"minutes": minutes, "steps": steps, "frames": frames, "mesh": mesh, "device": device},
    }
    o = _options(CaptureOptions, given)
    options = stage.CaptureArgs(
        photos=str(photos),
        out=_check("--out", out, output_path),
        calib=o.calib,
        camera=o.camera,
        tag_size=o.tag_size,
        sheet_tag_size=o.sheet_tag_size,
        dict=o.dictionary,
        method=o.method,
        clip_frames=o.clip_frames,
        model=o.model,
        max_side=o.max_side,
        minutes=o.minutes,
        steps=o.steps,
        frames=o.frames,
        no_mesh=not o.mesh,
        device=o.device,
        force=force,
        verbose=verbose,
    )
    calls = stage.Calls(calibrate, pose, train, resume, evaluate, render, export)
    if quiet:
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            made = stage.run_capture(options, calls)
    else:
        made = stage.run_capture(options, calls)
    splat = made.splat or {}
    scored = [("NeRF", made.run_dir, made.evaluated), ("splat", splat.get("run_dir"), splat.get("evaluated"))]
    psnr = {
        name: float(json.loads((run / "eval_val.json").read_text())["psnr"]) for name, run, ok in scored if run and ok
    }
    return CaptureResult(
        made.out,
        made.dataset,
        made.camera,
        made.run_dir,
        made.mesh,
        splat.get("run_dir"),
        tuple(splat.get("files") or ()),
        psnr,
    )


__all__ = [
    "CalibrationResult",
    "CaptureModel",
    "CaptureOptions",
    "CaptureResult",
    "EvalOptions",
    "EvaluationResult",
    "ExportOptions",
    "ExportResult",
    "Matcher",
    "PoseMethod",
    "PoseResult",
    "RenderOptions",
    "RenderResult",
    "Split",
    "TrainResult",
    "VideoPath",
    "calibrate",
    "capture",
    "evaluate",
    "export",
    "pose",
    "render",
    "resume",
    "train",
    "train_settings",
]
