"""The tools around the pipeline from Python (:mod:`nerfkit.api`): tags, frames, convert,
dataset, fit_image and view.

As :mod:`~nerfkit.commands.pipeline`'s functions, each takes typed keyword arguments named as
the flags of its command (``object_tag_size=0`` for ``--object-tag-size 0``; ``--dict`` is
``dictionary``), checks them as the command line is checked (with the pipeline's helpers),
does the work, prints the report the command prints (unless ``quiet``) and returns a typed
result; the commands parse their command line into these calls. :func:`demo` is ``nerfkit
demo``: training, videos and scores on the bundled lego scene. Example::

    from nerfkit import api

    sheet = api.tags("tags.pdf", tag_size=0.04)
    clip = api.frames("clip.mp4", "frames/", frames=80)
    fit = api.fit_image("photo.jpg", out="runs/photo")
    lego = api.demo("runs/demo", minutes=1)
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, get_args

from .options import ConvertFormat, ConvertOptions, FramesOptions, Paper, Spread, TagsOptions, ViewOptions
from .pipeline import _check, _checked, _choice, _given, _options, _say, _settings

if TYPE_CHECKING:
    from ..capture.dataset import DatasetConfig
    from ..fit_image import FitImageConfig

# the choices of the commands' flags of the same names
PoseSource = Literal["auto", "tags", "sfm"]
DemoModel = Literal["fast", "vanilla"]

# the demo's training minutes when none are given: a few minutes on a 2-core CPU for each model
DEMO_MINUTES: dict[str, float] = {"fast": 3.0, "vanilla": 8.0}


@dataclass(frozen=True)
class TagsResult:
    """A PDF of tags written by :func:`tags`."""

    pdf_path: Path
    pages: int  # 2 with the tag beside the object, else 1
    sheet_ids: tuple[int, ...]  # the calibration sheet's tags (page 1)
    object_tag_id: int | None  # the tag beside the object (page 2; None: no such page)


@_checked
def tags(
    out: str | Path = "tags.pdf",
    *,
    paper: Paper = TagsOptions.paper,
    dictionary: str = TagsOptions.dictionary,
    tag_size: float = TagsOptions.tag_size,
    object_tag_size: float = TagsOptions.object_tag_size,
    force: bool = False,
    quiet: bool = False,
) -> TagsResult:
    """Write a PDF of ArUco tags to print at actual size (``nerfkit tags``): page 1 a calibration
    sheet, page 2 one larger tag to lay beside the object, each with a 100 mm ruler. The defaults
    and checks of its options (``paper`` to ``object_tag_size``) are those of
    :class:`~nerfkit.commands.options.TagsOptions`, as the command's are.

    Args:
        out: the PDF to write.
        paper: "a4" or "letter".
        dictionary: ArUco dictionary of the tags.
        tag_size: side of the sheet's tags' black squares in metres.
        object_tag_size: side of the tag beside the object in metres (0: no such page).
        force: replace an existing file.
        quiet: print no report.
    """
    from ..capture.aruco import get_dictionary
    from ..capture.sheet import tag_sheets
    from ..config import output_path
    from ..errors import fail
    from ..io.paths import guard_outputs
    from .stages import tags as stage

    given = {"paper": paper, "dictionary": dictionary, "tag_size": tag_size, "object_tag_size": object_tag_size}
    paper, dictionary, tag_size, object_tag_size = dataclasses.astuple(_options(TagsOptions, given))
    path = Path(_check("--out", out, output_path))
    if path.suffix.lower() != ".pdf":
        raise fail("--out", f"'{path}' should end in .pdf")
    d = get_dictionary(dictionary)
    sheet_mm, object_mm = 1000 * tag_size, 1000 * object_tag_size
    stage.check_sizes(paper, d.markerSize + 2, sheet_mm, object_mm)
    guard_outputs([path], [], force)
    pages = tag_sheets(paper, dictionary, sheet_mm, object_mm or None)
    stage.write_pdf(path, pages, d)
    _say(quiet)(stage.tags_report(path, paper, dictionary, pages, tag_size, object_tag_size))
    return TagsResult(path, len(pages), tuple(pages[0].ids), pages[1].ids[0] if len(pages) > 1 else None)


@dataclass(frozen=True)
class FramesResult:
    """The frames of a clip written by :func:`frames`."""

    out: Path
    files: tuple[Path, ...]  # the frames kept (JPEG, upright, full resolution), in clip order
    read: int  # frames decoded from the clip
    report_path: Path  # OUT/frames.json: each kept frame's time and sharpness, and why the others were dropped


@_checked
def frames(
    clip: str | Path,
    out: str | Path,
    *,
    frames: int = FramesOptions.frames,
    spread: Spread = FramesOptions.spread,
    force: bool = False,
    quiet: bool = False,
) -> FramesResult:
    """Choose sharp, evenly spread frames of a video filmed around an object and write them as
    JPEG, with frames.json (``nerfkit frames``). The defaults and ranges of ``frames`` and
    ``spread`` are those of :class:`~nerfkit.commands.options.FramesOptions`, as the command's are.

    Args:
        clip: the video file (MP4, MOV, M4V; H.264 or HEVC).
        out: folder for the frames (new, empty, or holding earlier frames).
        frames: frames to keep, at most.
        spread: spread the windows evenly in "time", or in camera "motion" (a pause takes no window).
        force: replace the frames an earlier call wrote in ``out``.
        quiet: print no progress or report.
    """
    from ..capture.video import REPORT_NAME, select_frames
    from ..config import output_path
    from .stages.frames import report_lines

    _options(FramesOptions, dict(frames=frames, spread=spread))
    folder = _check("--out", out, output_path)
    selection = select_frames(clip, folder, frames, force=force, spread=spread, progress=not quiet)
    _say(quiet)(report_lines(selection))
    return FramesResult(
        Path(selection.out_dir), tuple(selection.paths), selection.read, Path(selection.out_dir) / REPORT_NAME
    )


@dataclass(frozen=True)
class ConvertResult:
    """A dataset written by :func:`convert`."""

    out: Path  # the .npz file or the folder
    format: str  # what was written: "npz", "transforms" or "colmap"
    source_format: str  # what was read (nerfkit.data.load.detect_format)
    files: tuple[Path, ...]  # the npz, OUT/transforms.json (images/ beside it), or OUT/sparse/0 and OUT/images
    views: dict[str, int]  # views of each split ("train", "val", "test") of the dataset read
    width: int  # the training views' size in pixels, as written
    height: int


@_checked
def convert(
    src: str | Path,
    to: str | Path,
    *,
    format: ConvertFormat = ConvertOptions.format,  # noqa: A002 - the flag's name
    size: int | None = ConvertOptions.size,
    downscale: float | None = ConvertOptions.downscale,
    background: str = ConvertOptions.background,
    near: float | None = ConvertOptions.near,
    far: float | None = ConvertOptions.far,
    images: str | Path | None = None,
    text: bool = False,
    force: bool = False,
    allow_outside_paths: bool = False,
    quiet: bool = False,
) -> ConvertResult:
    """Convert a dataset to a course npz, a transforms.json folder or a COLMAP project
    (``nerfkit convert``), optionally resized or with another depth range. The defaults and
    checks of its options (``format`` to ``far``) are those of
    :class:`~nerfkit.commands.options.ConvertOptions`, as the command's are.

    Args:
        src: the dataset file or folder (npz, Blender, transforms.json, COLMAP, LLFF).
        to: the output: a .npz file or a folder.
        format: "npz", "transforms" (transforms.json and images/), "colmap" (sparse/0 and
            images/), or "auto" (npz for a name ending in .npz, else transforms).
        size: resample so the longest image side is this many pixels (K follows).
        downscale: divide the image size by this (K follows; not with ``size``).
        background: colour under transparent pixels of RGBA inputs (black, white, grey,
            "r,g,b" in [0, 1] or "#rrggbb").
        near: set the depth range's near end (world units).
        far: set the depth range's far end.
        images: photo folder of a COLMAP model (None: the project's images/).
        text: with format "colmap", write the text model instead of binary.
        force: replace an existing output (never an input).
        allow_outside_paths: read dataset images outside the dataset's folder.
        quiet: print no report (a note that ``text`` has no effect still goes to stderr).
    """
    import sys

    from ..config import output_path, parse_background
    from ..data.load import dataset_inputs
    from ..io.paths import guard_outputs
    from .stages import convert as stage

    given = {"format": format, "size": size, "downscale": downscale, "background": background, "near": near, "far": far}
    format, size, downscale, background, near, far = dataclasses.astuple(_options(ConvertOptions, given))
    images = _given("--images", images)
    target = _check("--to", to, output_path)
    out, fmt = Path(target), stage.output_format(target, format)
    stage.check_output(out, fmt, near, far)
    guard_outputs(stage.output_targets(out, fmt), [*dataset_inputs(src), images], force, "--to")
    scene, src_fmt = stage.read_input(src, parse_background(background), size, downscale, images, allow_outside_paths)
    stage.set_depth_range(scene, near, far)
    written = stage.write_scene_as(scene, out, fmt, text=text)
    _say(quiet)(stage.convert_report(src, src_fmt, out, fmt, scene, written))
    if text and fmt != "colmap":
        print("note: --text is for --format colmap's model; ignored", file=sys.stderr)
    views = {k: len(v) for k, v in scene.splits.items()}
    return ConvertResult(
        out, fmt, src_fmt, tuple(Path(p) for p in written), views, scene.train.width, scene.train.height
    )


@dataclass(frozen=True)
class DatasetResult:
    """A dataset (re)built by :func:`dataset`."""

    dataset_path: Path  # OUT/dataset.npz (OUT/transforms.json and OUT/images/ beside it)
    views: dict[str, int]  # views of each split: "train", "val", "test"
    pose_source: str  # the poses it was built from: "tags" (poses.json) or "sfm" (OUT/colmap)


@_checked
def dataset(
    poses: str | Path,
    *,
    out: str | Path | None = None,
    pose_source: PoseSource = "auto",
    jobs: int = 0,
    force: bool = False,
    allow_outside_paths: bool = False,
    settings: DatasetConfig | None = None,
    quiet: bool = False,
) -> DatasetResult:
    """Build (or rebuild) a dataset from the poses :func:`~nerfkit.commands.pipeline.pose` found
    (``nerfkit dataset``): undistort, resize and split the photos, and write dataset.npz,
    transforms.json and images/.

    Args:
        poses: the folder with poses.json from :func:`~nerfkit.commands.pipeline.pose` (or the file).
        out: folder to write (None: the same folder).
        pose_source: "tags" (poses.json), "sfm" (the structure-from-motion model the folder
            keeps), or "auto" (the ones its dataset was built from).
        jobs: photos processed in parallel (0: up to 4 cores).
        force: replace an existing dataset in ``out``.
        allow_outside_paths: read photos that lie outside the recorded photo folder.
        settings: the dataset options (size, splits, near/far, ...); None: the defaults.
        quiet: print no report.
    """
    from ..capture.dataset import NPZ_FILE, DatasetConfig, check_settings
    from ..capture.photos import default_jobs
    from ..config import number, output_path
    from .stages import dataset as stage

    _choice("--pose-source", pose_source, get_args(PoseSource))
    jobs = _check("--jobs", jobs, number(int, 0, 256))
    cfg = _settings(settings, DatasetConfig, "settings")
    check_settings(cfg)
    src = Path(poses)
    folder = src if src.is_dir() else src.parent
    target = Path(_check("--out", out, output_path)) if out is not None else folder
    workers = jobs or default_jobs()
    source = stage.recorded_pose_source(folder) if pose_source == "auto" else pose_source
    if source == "sfm":
        summary = stage.rebuild_from_sfm(folder, target, cfg, workers, force, allow_outside_paths, _say(quiet))
    else:
        summary = stage.rebuild_from_tags(str(poses), target, cfg, workers, force, allow_outside_paths)
    if not quiet:
        stage.report_dataset(summary, target)
    return DatasetResult(target / NPZ_FILE, dict(summary["views"]), source)


@dataclass(frozen=True)
class FitImageResult:
    """A fit of one image, or a sweep of fits, written by :func:`fit_image`."""

    out: Path  # the run folder (a sweep: the folder of its run folders, sweep.json and its figures)
    final_psnr: float | None  # one fit: PSNR (dB) of its final image on every pixel (None: a sweep)
    interrupted: bool  # one fit stopped by Ctrl-C: what it fitted is written, with the steps it did
    metrics: dict[str, Any] = field(default_factory=dict, compare=False)  # one fit: what OUT/metrics.json holds
    sweep: tuple[dict[str, Any], ...] = field(default=(), compare=False)  # a sweep: sweep.json's runs


@_checked
def fit_image(
    image: str | Path | None = None,
    *,
    out: str | Path | None = None,
    sweep: list[str] | tuple[str, ...] | None = None,
    quiet: bool = False,
    force: bool = False,
    settings: FitImageConfig | None = None,
) -> FitImageResult:
    """Fit a coordinate MLP (x, y) -> RGB to one image, writing its PSNR curve, progression figure,
    final image and metrics (``nerfkit fit-image``); with ``sweep``, one fit per combination.
    Ctrl-C during a sweep raises KeyboardInterrupt once the run it stopped is written.

    Args:
        image: the image file (None: the bundled astronaut photo).
        out: run folder (None: runs/fit-image/<image name>, with "-sweep" for a sweep).
        sweep: "KEY=V1,V2" items, one fit per combination (keys: L, width, depth, lr, batch, steps).
        quiet: print no progress bar and no report (the command's ``--quiet`` keeps the report).
        force: replace the results of an earlier fit in ``out``.
        settings: the model and training options (L, width, steps, ...); None: the defaults.
    """
    from .. import fit_image as fitting
    from ..config import output_path
    from ..io.paths import guard_outputs, refuse_links
    from .stages.fit_image import fit_report

    cfg = _settings(settings, fitting.FitImageConfig, "settings")
    combos = fitting.parse_sweep([str(item) for item in sweep]) if sweep is not None else None  # ([]: refused)
    stem = Path(image).stem if image else fitting.default_image_path().stem
    folder = Path("runs") / "fit-image" / (stem + ("-sweep" if combos else ""))
    folder = Path(_check("--out", out, output_path)) if out is not None else folder
    outputs = fitting.sweep_outputs(folder, combos) if combos else [folder / name for name in fitting.RUN_FILES]
    guard_outputs(outputs, [image], force)
    if combos:  # each combination's run folder is the sweep's own
        refuse_links(folder, [fitting.sweep_folder(folder, c).name for c in combos])
        entries = fitting.run_sweep(image, folder, cfg, combos, progress=not quiet)
        result = FitImageResult(folder, None, False, sweep=tuple(entries))
    else:
        fitted = fitting.run_fit(image, folder, cfg, progress=not quiet)
        result = FitImageResult(folder, fitted.final_psnr, fitted.interrupted, metrics=fitted.metrics())
    _say(quiet)(fit_report(result, cfg.eval_every))
    return result


@dataclass(frozen=True)
class ViewResult:
    """What :func:`view` drew, or where it serves."""

    png: Path | None  # the picture written (None: served)
    url: str | None  # where the viewer listens (None: a picture, or a viewer already stopped)
    server: Any = field(default=None, compare=False, repr=False)  # a dataset's viser server: server.stop() ends it


@_checked
def view(
    path: str | Path,
    *,
    rays: int | None = ViewOptions.rays,
    samples: int | None = ViewOptions.samples,
    rays_from: int | None = ViewOptions.rays_from,
    png: str | Path | None = None,
    host: str = ViewOptions.host,
    port: int = ViewOptions.port,
    force: bool = False,
    downscale: float | None = ViewOptions.downscale,
    allow_outside_paths: bool = False,
    block: bool = False,
    quiet: bool = False,
) -> ViewResult:
    """Show a dataset's cameras, rays and samples in the browser (viser) or draw them as a PNG
    (``nerfkit view``); a run folder opens the live viewer of the trained model. The defaults and
    ranges of its options (``rays``, ``samples``, ``rays_from``, ``host``, ``port``, ``downscale``)
    are those of :class:`~nerfkit.commands.options.ViewOptions`, as the command's are.

    Args:
        path: dataset file or folder (anything :func:`~nerfkit.commands.pipeline.train` reads), or a run folder.
        rays: training rays to draw with their samples (None: none; 100 with ``rays_from``).
        samples: samples per drawn ray (None: 64, as the course).
        rays_from: draw the rays of this training view only.
        png: write this static picture (matplotlib) instead of serving.
        host: address to listen on (127.0.0.1: this machine only).
        port: the first port to try (taken: the next free one; refused when 100 in a row are).
        force: replace an existing ``png``.
        downscale: divide the dataset's image size by this.
        allow_outside_paths: read dataset images outside the dataset's folder (a run's too).
        block: serve until Ctrl-C, then stop (False: return at once with the server, a dataset's
            only: a run's live viewer renders on the calling thread, so it needs ``block``).
        quiet: print no report (a warning that the viewer listens beyond this machine still is).
    """
    import sys

    from ..config import output_path
    from ..data.load import dataset_inputs, is_run_folder, is_run_in_training, load_scene
    from ..io.paths import guard_outputs
    from .stages import view as stage

    options = _options(
        ViewOptions, dict(rays=rays, samples=samples, rays_from=rays_from, host=host, port=port, downscale=downscale)
    )
    downscale = options.downscale  # (a float, as --downscale gives it)
    picture = Path(_check("--png", png, output_path)) if png is not None else None
    stage.check_png(picture)
    source, say = Path(path), _say(quiet)
    stage.refuse_run_file(source)
    if is_run_folder(source) or is_run_in_training(source):
        stage.serve_run(
            source,
            host,
            port,
            stage.RunOptions(rays, rays_from, samples, downscale, picture, force),
            block,
            allow_outside_paths,
            quiet,
        )
        return ViewResult(None, None)
    scene = load_scene(source, downscale=downscale, allow_outside=allow_outside_paths)
    if picture:  # (after the dataset is read: a file that is none is said to be none first)
        guard_outputs([picture], dataset_inputs(source), force, "--png")
    tag_size = stage.dataset_tag_size(source)
    stage.check_rays_from(scene, rays_from)
    n_rays = rays if rays is not None else 100 if rays_from is not None else 0  # the course: 100
    samples = 64 if samples is None else samples
    if picture:
        from ..viz.scene_plot import plot_scene

        plot_scene(scene, str(png), n_rays=n_rays, n_samples=samples, tag_size=tag_size, rays_from=rays_from)
        say(f"wrote {png}")
        return ViewResult(picture, None)
    from ..viz.viewer import LOCAL_HOSTS, serve_dataset, viewer_url, wait_until_interrupted

    server, _ = serve_dataset(
        scene, host, port, n_rays=n_rays, n_samples=samples, tag_size=tag_size, block=False, rays_from=rays_from
    )
    if host not in LOCAL_HOSTS:
        print(f"warning: listening on {host}: anyone who can reach this machine can see the dataset", file=sys.stderr)
    url = viewer_url(host, server.get_port())
    say(
        f"{len(scene.train)} train, {len(scene.val)} val, {len(scene.test)} test cameras; near {scene.near:.4g}, "
        f"far {scene.far:.4g}"
    )
    if not block:
        say(f"viewer at {url} (server.stop() to stop)")
        return ViewResult(None, url, server)
    say(f"viewer at {url} (Ctrl-C to stop)")
    wait_until_interrupted(server)
    return ViewResult(None, None)


@dataclass(frozen=True)
class DemoResult:
    """The demo's run (:func:`demo`): its folder, the figures of ``summary.json`` (model, steps,
    train_seconds, val_psnr, val_ssim, render_seconds_per_frame, total_seconds) and the files
    written, by what they are."""

    run_dir: Path
    summary: dict[str, Any]
    outputs: dict[str, Path]


def bundled_lego() -> Path:
    """The lego scene shipped with nerfkit (200x200, 100 training views; NeRF synthetic
    dataset, Mildenhall et al. 2020, CC BY 3.0)."""
    from importlib.resources import files

    return Path(str(files("nerfkit") / "assets" / "lego_200x200.npz"))


def fresh_folder(path: str | Path) -> Path:
    """``path``, or ``path-2``, ``path-3``, ...: the first that holds no run."""
    p, i = Path(path), 2
    while (p / "config.json").exists():
        p, i = Path(f"{path}-{i}"), i + 1
    return p


@_checked
def demo(
    out: str | Path = "runs/demo",
    *,
    model: DemoModel = "fast",
    minutes: float | None = None,
    device: str = "auto",
    seed: int = 0,
    quiet: bool = False,
) -> DemoResult:
    """The main job on the bundled lego scene (``nerfkit demo``): train ``model`` for
    ``minutes`` (None: :data:`DEMO_MINUTES`) into ``out`` (a fresh ``out-2``, ... when it holds a
    run), render the 60 test poses to an MP4, a GIF and a depth video (vanilla: every other
    pose), score the 10 val views as ``nerfkit eval`` does, and write ``summary.json``."""
    import time

    import torch

    from ..config import MAX_SEED, number
    from ..data.npz import load_npz
    from ..io.atomic import write_json
    from ..models import model_config_class
    from ..output.videos import render_videos
    from ..precision import resolve_device, resolve_precision
    from ..train.checkpoint import load_run
    from ..train.config import TrainConfig, parse_background
    from ..train.trainer import train
    from .pipeline import evaluate

    t_start = time.perf_counter()
    _choice("--model", model, tuple(DEMO_MINUTES))
    minutes = _check("--minutes", minutes, number(float, above=0))
    seed = _check("--seed", seed, number(int, 0, MAX_SEED))
    dev = resolve_device(device)  # a device that is not there: refused before anything is said or written
    say = _say(quiet)
    data = str(bundled_lego())
    scene = load_npz(data)
    run_dir = fresh_folder(out)
    if run_dir != Path(out):
        say(f"note: {out} holds a run already; this demo goes into {run_dir}")
    minutes = minutes if minutes is not None else DEMO_MINUTES[model]
    cfg = TrainConfig(data=data, model=model, out=str(run_dir), minutes=minutes, seed=seed, device=device)
    say(f"nerfkit demo: training '{model}' on lego for {minutes:g} min into {run_dir}")
    given = {"data", "model", "out", "minutes", "seed", "device"}  # the rest: the preset's
    result = train(scene, cfg, model_config_class(model)(), quiet=quiet, user_set=given)

    trained, info, _ = load_run(run_dir, dev)
    bg = torch.tensor(parse_background(info.train.background), device=dev)
    autocast = resolve_precision(info.train.precision, dev)
    views = scene.render_path()
    if model == "vanilla":  # the big MLP renders ~10 s per frame on a CPU: half the frames
        views = views.subset(range(0, len(views), 2))
    videos = render_videos(
        trained, views, run_dir / "videos", bg, scene.near, scene.far, 30, info.train.render_chunk, autocast
    )
    # scored as `nerfkit eval` scores it: eval_val.json and the photos beside the renders
    metrics = evaluate(run_dir, split="val", device=device, quiet=True).scores
    summary = {
        "model": model,
        "steps": result.step,
        "train_seconds": round(result.train_seconds, 1),
        "val_psnr": metrics["psnr"],
        "val_ssim": metrics["ssim"],
        "render_seconds_per_frame": round(videos.seconds_per_frame, 3),
        "total_seconds": round(time.perf_counter() - t_start, 1),
    }
    write_json(run_dir / "summary.json", summary)
    outputs = {
        "orbit video": videos.rgb_mp4,
        "orbit GIF": videos.rgb_gif,
        "depth video": videos.depth_mp4,
        "PSNR curve": run_dir / "plots" / "psnr.png",
        "loss curve": run_dir / "plots" / "loss.png",
        "progression": run_dir / "plots" / "progress.png",
        "metrics": run_dir / "metrics.csv",
        "evaluation": run_dir / "eval_val.json",
        "val views": run_dir / "eval_val.png",
    }
    return DemoResult(run_dir, summary, {k: Path(v) for k, v in outputs.items()})


__all__ = [
    "ConvertFormat",
    "ConvertOptions",
    "ConvertResult",
    "DEMO_MINUTES",
    "DatasetResult",
    "DemoModel",
    "DemoResult",
    "FitImageResult",
    "FramesOptions",
    "FramesResult",
    "Paper",
    "PoseSource",
    "Spread",
    "TagsOptions",
    "TagsResult",
    "ViewOptions",
    "ViewResult",
    "convert",
    "bundled_lego",
    "dataset",
    "demo",
    "fit_image",
    "frames",
    "tags",
    "view",
]
