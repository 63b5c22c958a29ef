"""The options of the commands (those on a trained run, and tools), one dataclass per command: each field is one
flag (:func:`~nerfkit.config.option`: its default, help and range), so the command's parser
(:func:`~nerfkit.config.add_dataclass_args`), its Python function in :mod:`nerfkit.api` (whose
keyword defaults are these fields') and its checks (:func:`~nerfkit.config.check_ranges`) all
read them from here. Plain Python (no NumPy): the command modules, which ``nerfkit --help``
imports, import :mod:`~nerfkit.commands.pipeline`, which imports this.

A field's ``needs`` metadata names the output it acts on (``export``: "--mesh", ...); given
without that output, the command says the option does nothing.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, get_args

from ..config import MAX_BATCH_RAYS, MIN_DOWNSCALE, MIN_RESAMPLED_SIDE, number, option, tag_side
from ..table_cut import TABLE_CUT
from .stages.convert import depth_bound
from .stages.tags import object_side

# the choices of `nerfkit render --path`, `nerfkit eval --split` and `nerfkit frames --spread`
VideoPath = Literal["auto", "test", "orbit", "spiral"]
Split = Literal["val", "test", "train"]
Spread = Literal["time", "motion"]
# the choices of `nerfkit tags --paper` and `nerfkit convert --format`
Paper = Literal["a4", "letter"]
ConvertFormat = Literal["auto", "npz", "transforms", "colmap"]
# the choices of `nerfkit poses --method` (and capture's) and of `nerfkit capture --model`
PoseMethod = Literal["auto", "tags", "colmap"]
CaptureModel = Literal["fast", "splat", "both"]


# the range of calibrate's and poses' --detect-size (the long side, in pixels, tags are
# detected on) and --jobs (photos processed at once), which they word each their own way
DETECT_SIZE = {"min": 64, "max": 100_000}
JOBS = {"min": 0, "max": 256}


@dataclass(frozen=True)
class CalibrateOptions:
    """The options of ``nerfkit calibrate`` (:func:`nerfkit.api.calibrate`) on how it reads the photos."""

    detect_size: int = option(
        2000,
        "detect tags on a copy this many pixels on the long side, then refine corners at full resolution",
        **DETECT_SIZE,
        metavar="DETECT_SIZE",
    )
    jobs: int = option(0, "photos processed in parallel", default_help="up to 4 cores", **JOBS, metavar="JOBS")


@dataclass(frozen=True)
class PosesOptions:
    """The options of ``nerfkit poses`` (:func:`nerfkit.api.pose`) on the camera and tag it poses
    with and how it reads the photos."""

    focal_px: float | None = option(
        None,
        "focal length in pixels to pose with instead of the photos' EXIF (no distortion, principal point "
        "at the centre); not with --camera or --method colmap",
        above=0,
        metavar="FOCAL_PX",
    )
    tag_id: int | None = option(
        None, "the tag that defines the world", default_help="the one seen most", min=0, metavar="TAG_ID"
    )
    sfm_max_size: int = option(
        1000, "longest side used for SfM features, px", min=64, max=100_000, metavar="SFM_MAX_SIZE"
    )
    detect_size: int = option(
        CalibrateOptions.detect_size, "tag detection size (long side, px)", **DETECT_SIZE, metavar="DETECT_SIZE"
    )
    jobs: int = option(
        CalibrateOptions.jobs,
        "photos processed in parallel, and structure-from-motion's threads",
        default_help="up to 4 cores, SfM on all; SfM on several threads differs a little from run to run, "
        "--jobs 1 repeats exactly",
        **JOBS,
        metavar="JOBS",
    )


@dataclass(frozen=True)
class RunDeviceOptions:
    """Where a command on a trained run (render, eval, export) renders it, and how many rays at once."""

    device: str = option("auto", "auto, cpu, cuda or cuda:N", metavar="DEVICE")
    chunk: int = option(
        0,
        "rays rendered at once; lower it if memory runs out",
        default_help="the run's render chunk",
        min=0,
        max=MAX_BATCH_RAYS,
        metavar="CHUNK",
    )


@dataclass(frozen=True)
class ExportOptions:
    """The options of ``nerfkit export`` (:func:`nerfkit.api.export`) beside its outputs and run."""

    background_dome: bool = option(
        True,
        "(splat runs with a learned background, as captures) leave out the dome of Gaussians "
        "that carries the background into the file",
        switch=True,
        needs="--splat",
    )
    resolution: int = option(
        256, "grid cells per side", min=8, max=1024, group="mesh", needs="--mesh", metavar="RESOLUTION"
    )
    threshold: float | None = option(
        None,
        "density of the surface",
        default_help="the density at which 1/256 of the meshed cube's width is 7% opaque, whatever the "
        "scene's units: lego's about 6, a 15-cm object's in metres about 120; printed; higher = tighter, "
        "fewer floaters",
        above=0,
        group="mesh",
        needs="--mesh",
        metavar="THRESHOLD",
    )
    box_scale: float = option(
        1.0,
        "scale the cube meshed, and the scene box points are cropped to",
        above=0,
        max=100,
        group="mesh",
        needs="--mesh or --points",
        metavar="BOX_SCALE",
    )
    table_cut: float = option(
        TABLE_CUT,
        "(captures) clear density within this fraction of the object's height above the table, where "
        "nothing rises out of that slab, and pieces apart from the object lower than three times that: "
        "the tags and sheet painted into density (0: clear only under the table)",
        min=0,
        max=1,
        group="mesh",
        needs="--mesh",
        metavar="TABLE_CUT",
    )
    # a mesh's vertices are coloured from this many of the training views, evenly spread
    # (nerfkit.export: how large they are rendered, and when a view sees a vertex)
    color_views: int = option(
        32,
        "training views rendered for the vertex colours (0: colour along the normals only, without the dataset)",
        min=0,
        max=10000,
        group="mesh",
        needs="--mesh",
        metavar="N",
    )
    color_dirs: int = option(
        1,
        "directions averaged per colour of a vertex no view sees (1 = along the normal)",
        min=1,
        max=64,
        group="mesh",
        needs="--mesh",
        metavar="N",
    )
    every: int = option(1, "use every N-th training view", min=1, group="points", needs="--points", metavar="EVERY")
    stride: int = option(
        1, "use every N-th pixel in each direction", min=1, max=4096, group="points", needs="--points", metavar="STRIDE"
    )
    acc_min: float = option(
        0.5,
        "keep pixels with opacity above this",
        min=0,
        max=0.999,
        group="points",
        needs="--points",
        metavar="ACC_MIN",
    )
    crop: bool = option(True, "keep points outside the scene box", switch=True, group="points", needs="--points")


@dataclass(frozen=True)
class RenderOptions:
    """The options of ``nerfkit render`` (:func:`nerfkit.api.render`) beside its run and output."""

    path: VideoPath = option(
        "auto",
        "camera path: the dataset's test poses, an orbit around the object, a spiral across a "
        "forward-facing capture's view, or auto (chosen as described above)",
        choices=get_args(VideoPath),
    )
    frames: int | None = option(
        None,
        "frames of a generated orbit or spiral; the test path has the dataset's own poses",
        default_help="120, 4 s at 30 fps",
        min=1,
        max=100_000,
        metavar="FRAMES",
    )
    fps: int = option(30, "frames per second", min=1, max=1000, metavar="FPS")
    object: bool = option(
        False,
        "render the object alone into object.mp4, object.gif and object_depth.mp4: a capture's "
        "table, floor and room left out, the table's paint and the specks apart from the object "
        "cleared from the density (as export --mesh does), on white, centred and framed whole (one zoom for the "
        "whole path: an object that already fills the frame is drawn smaller)",
        switch=True,
    )
    background: str | None = option(
        None,
        "override the run's background colour (with --object: white): black, white, grey, r,g,b in [0, 1] or #rrggbb",
        metavar="BACKGROUND",
    )


@dataclass(frozen=True)
class EvalOptions:
    """The options of ``nerfkit eval`` (:func:`nerfkit.api.evaluate`) beside its run."""

    split: Split = option("val", "which images", choices=get_args(Split))
    fit_views: int | None = option(
        None,
        "also score each view after fitting its pose to its photo with the scene frozen, for this "
        "many steps, and then each half of the photo with a gain and offset per channel solved on "
        "the other half (least squares; NeRF-W's protocol, both ways)",
        default_help="100 for runs trained with --capture, else 0: off; a model that renders whole views, "
        "such as splat, fits from whole renders",
        min=0,
        max=100_000,
        metavar="STEPS",
    )


# the range of the frames kept from a clip: frames' --frames, capture's --clip-frames
FRAMES_KEPT = {"min": 10, "max": 10_000}


@dataclass(frozen=True)
class FramesOptions:
    """The options of ``nerfkit frames`` (:func:`nerfkit.api.frames`) beside its clip and output."""

    # the frames kept from a clip by default, written here only (capture's --clip-frames reads it;
    # capture.video.select_frames, below the commands, takes the count from its callers)
    frames: int = option(120, "frames to keep, at most", **FRAMES_KEPT, metavar="N")
    spread: Spread = option(
        "time",
        "spread the windows evenly in time, or in camera motion measured between frames (a pause then takes no window)",
        choices=get_args(Spread),
    )


@dataclass(frozen=True)
class ViewOptions:
    """The options of ``nerfkit view`` (:func:`nerfkit.api.view`) beside its dataset and picture."""

    rays: int | None = option(
        None,
        "training rays to draw with their samples",
        default_help="none; 100 with --rays-from",
        min=0,
        max=100_000,
        metavar="RAYS",
    )
    samples: int | None = option(
        None, "samples per drawn ray", default_help="64, as the course", min=1, max=4096, metavar="SAMPLES"
    )
    rays_from: int | None = option(
        None,
        "draw the rays of training view N only (the course's check that u and v are not swapped: they "
        "fill that camera's frustum)",
        min=0,
        metavar="N",
    )
    downscale: float | None = option(
        None,
        "divide the dataset's image size by this (an LLFF scene's 4 or 8 reads its images_4 or images_8)",
        min=MIN_DOWNSCALE,
        metavar="DOWNSCALE",
    )
    port: int = option(8080, "first port to try (taken: the next free one)", min=1, max=65535, metavar="PORT")
    # the command's --host is its own flag, whose default (this one) a check of every command's
    # --host sees in the parser (tests/test_hostile_inputs.py)
    host: str = option("127.0.0.1", "address to listen on", cli=False)


@dataclass(frozen=True)
class TagsOptions:
    """The options of ``nerfkit tags`` (:func:`nerfkit.api.tags`) beside its output."""

    paper: Paper = option("a4", "paper size", choices=get_args(Paper))
    dictionary: str = option(
        "DICT_4X4_50", "ArUco dictionary", default_help="DICT_4X4_50, nerfkit's", flag="--dict", metavar="DICT"
    )
    tag_size: float = option(
        0.05, "side of the sheet's tags' black squares in metres", parse=tag_side, metavar="TAG_SIZE"
    )
    object_tag_size: float = option(
        0.1,
        "side of the tag beside the object in metres",
        default_help="0.1; 0: no such page",
        parse=object_side,
        metavar="OBJECT_TAG_SIZE",
    )


@dataclass(frozen=True)
class ConvertOptions:
    """The options of ``nerfkit convert`` (:func:`nerfkit.api.convert`) on what it writes, beside
    its input, output and a COLMAP model's photos."""

    format: ConvertFormat = option(
        "auto", "output format; auto: npz for *.npz, else transforms.json", choices=get_args(ConvertFormat)
    )
    size: int | None = option(
        None,
        "resample so the longest image side is PX pixels (K follows)",
        min=1,
        max=100_000,
        exclusive="size",
        metavar="PX",
    )
    downscale: float | None = option(
        None, "divide the image size by F (K follows)", min=MIN_DOWNSCALE, exclusive="size", metavar="F"
    )
    background: str = option(
        "black",
        "colour under transparent pixels of RGBA inputs: black, white, grey, r,g,b in [0, 1] or #rrggbb",
        metavar="BACKGROUND",
    )
    near: float | None = option(
        None,
        "set the depth range's near end (world units; e.g. the course's 2 for lego, where nerfkit's rule "
        "from the cameras gives 2.02)",
        parse=depth_bound(number(float, 0.0)),
        metavar="NEAR",
    )
    far: float | None = option(
        None,
        "set the depth range's far end (the course's 6 for lego)",
        parse=depth_bound(number(float, above=0)),
        metavar="FAR",
    )


@dataclass(frozen=True)
class CaptureOptions:
    """The options of ``nerfkit capture`` (:func:`nerfkit.api.capture`) beside its photos, output
    and --force."""

    tag_size: float | None = option(
        None,
        "side of the black square of the tag beside the object, in metres (e.g. 0.06): the tag then fixes scale and up",
        default_help="no tag; structure-from-motion poses, the table found in its points",
        parse=tag_side,
        metavar="TAG_SIZE",
    )
    calib: str | None = option(
        None,
        "folder of photos of the printed tag sheet, to calibrate the camera from (without it or --camera: "
        "the photos' EXIF focal length, no distortion)",
        exclusive="camera",
        metavar="CALIB_DIR",
    )
    camera: str | None = option(
        None,
        "a camera file from an earlier `nerfkit calibrate` of the same phone",
        exclusive="camera",
        exclusive_fix="Calibrate from the sheet's photos or give a camera file",
        metavar="CAMERA",
    )
    sheet_tag_size: float | None = option(
        None,
        "side of a tag's black square on the calibration sheet",
        default_help="--tag-size; needed with --calib when there is no --tag-size",
        parse=tag_side,
        metavar="SHEET_TAG_SIZE",
    )
    dictionary: str | None = option(
        None,
        "ArUco dictionary of the tags",
        default_help="the camera file's, else DICT_4X4_50",
        flag="--dict",
        metavar="DICT",
    )
    method: PoseMethod = option(
        "auto",
        "poses: auto (default): without --tag-size, structure-from-motion; with it, structure-from-motion "
        "poses in the tag's frame when they hold up; tags: the tag's poses only, as the course does; colmap: "
        "structure-from-motion alone (a tag, with --tag-size, fixes scale and up)",
        default_help="",  # (the help says it)
        choices=get_args(PoseMethod),
    )
    clip_frames: int = option(
        FramesOptions.frames,
        "a video: frames to keep from it, at most",
        default_help=f"{FramesOptions.frames}; see `nerfkit frames`",
        **FRAMES_KEPT,
        metavar="N",
    )
    model: CaptureModel = option(
        "both",
        "what to train: fast, the NeRF, with the videos and mesh; splat, 3D Gaussians written as "
        "OUT/splat.ply and OUT/splat.splat, and the object alone as OUT/splat_object.ply; both (the "
        "default: each trains for --minutes)",
        default_help="",  # (the help says it)
        choices=get_args(CaptureModel),
    )
    max_side: int | None = option(
        None,
        "the dataset's photos' longer side in pixels (0: keep their size; default: poses', 512)",
        min=MIN_RESAMPLED_SIDE,
        off=0,
        metavar="MAX_SIDE",
    )
    minutes: float = option(3.0, "training time of each model", above=0, exclusive="budget", metavar="MINUTES")
    steps: int | None = option(
        None, "train this many steps instead of --minutes", min=1, exclusive="budget", metavar="STEPS"
    )
    frames: int | None = option(
        None, "frames of the orbit", default_help="render's, 120", min=1, max=100_000, metavar="FRAMES"
    )
    mesh: bool = option(True, "skip the NeRF's mesh", switch=True)
    device: str = option(RunDeviceOptions.device, "auto, cpu, cuda or cuda:N", metavar="DEVICE")
