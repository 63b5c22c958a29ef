"""The convert stage in small steps: the output's format and files, the input read as asked,
its depth range set, the dataset written in another format, and the line that says so."""

from __future__ import annotations

import argparse
import re
from typing import Any

# what a dataset file holds a depth bound in (float32): the largest finite value, and the
# smallest positive one it keeps at full precision (a smaller one is rounded, or becomes 0)
FLOAT32_MAX = 3.4028234663852886e38
FLOAT32_TINY = 1.1754943508222875e-38


def depth_bound(parse):
    """``parse`` (an argparse ``type``), also refusing a depth a dataset file cannot hold as
    float32: ``--far 1e308`` would be written as inf, ``--near 1e-320`` as 0."""

    def checked(text: str) -> float:
        value = parse(text)
        if value > FLOAT32_MAX:
            raise argparse.ArgumentTypeError(f"{text} is larger than a dataset file holds (float32: at most 3.4e38)")
        if 0 < value < FLOAT32_TINY:
            raise argparse.ArgumentTypeError(
                f"{text} is smaller than a dataset file holds (float32: 0 or at least 1.2e-38)"
            )
        return value

    checked.__name__ = "float"  # argparse names the type in its messages
    return checked


# names that --to takes for a file of another kind, not a folder (`--to out.ply`)
FILE_SUFFIXES = {
    ".ply",
    ".json",
    ".obj",
    ".glb",
    ".splat",
    ".zip",
    ".tar",
    ".gz",
    ".mp4",
    ".gif",
    ".png",
    ".jpg",
    ".jpeg",
    ".txt",
    ".pt",
    ".pth",
    ".bin",
    ".db",
}


def output_format(out: str, fmt: str) -> str:
    """The format ``fmt`` writes ``out`` in: "auto" is npz for a name ending in .npz, else transforms."""
    if fmt != "auto":
        return fmt
    return "npz" if out.lower().endswith(".npz") else "transforms"


def check_output(out, fmt: str, near: float | None, far: float | None) -> None:
    """Refuse an output ``out`` that ``fmt`` cannot write (an npz not named .npz, a folder named as a
    file) and a depth range for a COLMAP model, which keeps none."""
    from pathlib import Path

    from ...errors import fail

    out = Path(out)
    if fmt == "npz" and out.suffix.lower() != ".npz":
        raise fail(out, "an npz output must end in .npz")
    if fmt != "npz" and out.suffix.lower() == ".npz":
        raise fail(out, f"--format {fmt} writes a folder, not an .npz file")
    if fmt != "npz" and out.suffix.lower() in FILE_SUFFIXES:
        raise fail(
            out,
            f"looks like a {out.suffix} file, but convert writes a .npz file or a folder "
            f"({'COLMAP project' if fmt == 'colmap' else 'transforms.json and images/'})",
            "End --to in .npz, or give a folder name",
        )
    if fmt == "colmap" and (near is not None or far is not None):
        raise fail("--near/--far", "a COLMAP model keeps no depth range", "Write an npz or transforms.json instead")


def read_input(
    src, background, size: int | None, downscale: float | None, images: str | None, allow_outside: bool
) -> tuple[Any, str]:
    """(the dataset at ``src``, its format), its images resampled as asked and transparent pixels
    on ``background`` (RGB in [0, 1]); ``images``: the photo folder of a COLMAP model."""
    from ...data.load import detect_format, load_scene
    from ...errors import fail

    src_fmt = detect_format(src)
    if images and src_fmt == "colmap":
        from ...data.colmap import load_colmap

        scene = load_colmap(
            src, images=images, background=background, size=size, downscale=downscale, allow_outside=allow_outside
        )
        return scene, src_fmt
    if images:
        raise fail("--images", f"only applies to COLMAP inputs; {src} is {src_fmt}")
    return load_scene(src, background=background, size=size, downscale=downscale, allow_outside=allow_outside), src_fmt


def set_depth_range(scene, near: float | None, far: float | None) -> None:
    """Set the ends of ``scene``'s depth range that are given, as a dataset file can hold them."""
    if near is None and far is None:
        return
    import numpy as np

    from ...data.validate import check_near_far
    from ...errors import fail

    scene.near, scene.far = check_near_far(
        scene.near if near is None else near, scene.far if far is None else far, "--near/--far"
    )
    if not np.float32(scene.near) < np.float32(scene.far):  # as the file holds them
        raise fail(
            "--near/--far",
            f"near={scene.near:g} and far={scene.far:g} are one number in a dataset file (float32)",
            "Give a wider depth range",
        )


def convert_report(src, src_fmt: str, out, fmt: str, scene, written: list) -> str:
    """What was read and written; for a COLMAP model, what it does not keep."""
    n = {k: len(v) for k, v in scene.splits.items()}
    lines = [
        f"{src} ({src_fmt}) -> {out} ({fmt}): {n['train']} train, {n['val']} val, {n['test']} test views, "
        f"{scene.train.width}x{scene.train.height}, fx={scene.train.K[0, 0, 0]:.2f}, "
        f"near={scene.near:.3g}, far={scene.far:.3g}",
        *(f"  {p}" for p in written),
    ]
    if fmt == "colmap":
        kept = sum(len(v) for v in scene.splits.values() if v.images is not None) or sum(n.values())
        dropped = " (pose-only views left out)" if kept < sum(n.values()) else ""
        lines.append(
            f"note: a COLMAP model keeps no splits: it holds {kept} views as one set{dropped}, "
            "and reading it back holds out nerfkit's own val views"
        )
        if scene.capture or scene.table is not None or scene.tags is not None:
            lines.append(
                "note: nor does it keep that these are real photos of an object on a tag's table (the table "
                "plane, the printed tags, the depth range): read back, it trains as a plain scene. Keep the "
                "npz or transforms.json for nerfkit's capture settings"
            )
    return "\n".join(lines)


def output_targets(out, fmt: str) -> list:
    """What ``write_scene_as`` writes: the npz, or the files and folders it puts into ``out``."""
    from pathlib import Path

    out = Path(out)
    if fmt == "npz":
        return [out]
    if fmt == "colmap":
        return [out / "sparse", out / "images"]
    try:
        from ...data.nerfstudio import POINTS_FILE
    except ImportError:  # (write_scene_as says so)
        return [out / "transforms.json", out / "images"]
    return [out / "transforms.json", out / "images", out / POINTS_FILE]


def write_scene_as(scene, out, fmt: str, text: bool = False) -> list:
    """Write ``scene`` to ``out`` in ``fmt`` ('npz', 'transforms' or 'colmap'); the paths written."""
    from pathlib import Path

    from ...errors import fail

    out = Path(out)
    if fmt == "npz":
        from ...data.npz import save_npz

        save_npz(scene, out)
        return [out]
    if fmt == "colmap":
        return write_colmap_project(scene, out, text)
    try:
        from ...data.nerfstudio import write_transforms_json
    except ImportError:
        raise fail(
            out,
            "transforms.json output needs nerfkit.data.nerfstudio, which this build lacks",
            "Convert to .npz instead",
        ) from None
    write_transforms_json(scene, out)
    return [out / "transforms.json"]


# the files of a COLMAP model folder (pycolmap writes these, as text or binary)
MODEL_FILE_NAMES = [f"{n}.{ext}" for n in ("cameras", "images", "points3D", "rigs", "frames") for ext in ("bin", "txt")]


def model_images(model_dir) -> list[str]:
    """The image names an earlier COLMAP model at ``model_dir`` holds; none when there is
    none or it cannot be read."""
    from ...data.colmap import is_model_dir, read_model
    from ...errors import NerfkitError

    if not is_model_dir(model_dir):
        return []
    try:
        return [img.name for img in read_model(model_dir).images.values()]
    except (NerfkitError, OSError, ValueError, RuntimeError):
        return []


def write_colmap_project(scene, out, text: bool = False) -> list:
    """A COLMAP project: ``sparse/0`` (PINHOLE cameras) and ``images/`` (PNG).

    COLMAP has no splits and no pose-only views: when any split has images, only the
    views with images are written (a test split of render poses is left out).
    """
    from dataclasses import replace
    from pathlib import Path

    from ...data.colmap import write_colmap_model
    from ...errors import fail
    from ...images import IMAGE_SUFFIXES, write_image
    from ...io.atomic import refuse_foreign_files, replacing_folder
    from ...io.paths import distinct_names, refuse_links

    out = Path(out)
    written, splits = [], {}
    seen: set[str] = set()
    sizes = {(v.width, v.height) for v in scene.splits.values() if len(v) and v.images is not None}
    if len(sizes) > 1:  # (nerfkit's reader, as a NeRF, takes one size)
        raise fail(
            out,
            f"the views' images are of {len(sizes)} sizes ({', '.join(f'{w}x{h}' for w, h in sorted(sizes))})",
            "Resample them to one size (nerfkit convert --size), or export to transforms.json",
        )
    named = [
        (split, v.names[i] if v.names else f"{split}_{i:04d}")
        for split, v in scene.splits.items()
        for i in range(len(v))
    ]
    # (Blender's train/r_0 and val/r_0 would both be r_0; images.txt splits its lines at spaces)
    flat = iter(distinct_names([(split, re.sub(r"\s+", "_", name)) for split, name in named]))
    for split, v in scene.splits.items():
        names = [next(flat) for _ in range(len(v))]
        names = [n if Path(n).suffix.lower() in IMAGE_SUFFIXES else n + ".png" for n in names]
        if v.images is not None:
            names = [str(Path(n).with_suffix(".png")) for n in names]  # pixels are written as PNG
            if len(set(names)) < len(names) or seen & set(names):
                raise fail(
                    out, "two views would both be written as the same image file", "Give the views distinct names"
                )
            seen |= set(names)
        splits[split] = replace(v, names=names)
    with_images = tuple(k for k, v in scene.splits.items() if v.images is not None and len(v))
    keep = with_images or tuple(scene.splits)
    # both written afresh: an earlier conversion's extra images or text model do not stay; files
    # no earlier conversion wrote there are the user's, and refused
    refuse_links(out, ["sparse"])  # (sparse/0 as a link is replaced as a link)
    refuse_foreign_files(out / "images", model_images(out / "sparse" / "0"), "--to")
    refuse_foreign_files(out / "sparse" / "0", MODEL_FILE_NAMES, "--to")
    with replacing_folder(out / "images") as images, replacing_folder(out / "sparse" / "0") as model:
        for split in with_images:
            for name, im in zip(splits[split].names, scene.splits[split].images):
                write_image(images / name, im)
        written.append(write_colmap_model(replace(scene, **splits), model, text=text, splits=keep))
    if with_images:
        written.append(out / "images")
    return written
