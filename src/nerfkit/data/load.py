"""Load any supported dataset into a :class:`Scene`, choosing the reader by path.

Supported (file or folder):

* the course npz (``*.npz``, or a folder holding exactly one ``.npz``);
* Blender-style synthetic scenes (a folder with ``transforms_train.json``, or that file);
* nerfstudio / instant-ngp ``transforms.json`` (the file, or a folder holding it);
* LLFF forward-facing scenes (a folder with ``poses_bounds.npy`` and ``images/``, or that
  file; it wins over a COLMAP model in the same folder, as the papers use its poses);
* COLMAP models (a folder with ``cameras``/``images``/``points3D`` ``.bin`` or ``.txt``,
  or a project folder with ``sparse/0`` and ``images/``), without re-running SfM.

The resampling every format shares (:func:`resample_scene`) lives in :mod:`.resample`.
"""

from __future__ import annotations

from pathlib import Path

from ..errors import NerfkitError, fail
from ..io.paths import dataset_folder, is_within, path_kind, refuse_special_file
from .npz import load_npz
from .resample import resample_scene
from .scene import Scene
from .validate import check_scene

FORMATS = (
    "a course .npz, a Blender folder (transforms_train.json), a transforms.json, an LLFF folder "
    "(poses_bounds.npy), or a COLMAP model folder"
)


def detect_format(path: str | Path) -> str:
    """'npz', 'blender', 'transforms', 'llff' or 'colmap' for a dataset path; NerfkitError otherwise."""
    from .blender import blender_folder
    from .colmap import find_colmap_model
    from .llff import llff_folder

    path = Path(path)
    kind = path_kind(path)
    refuse_special_file(path, kind)
    if kind is None:
        raise fail(path, "no such file or folder", "Check the path")
    if kind != "dir":
        if path.name == "poses.json" and (path.parent / "dataset.npz").is_file():
            raise fail(
                path, "is the record of the photos' poses, not the dataset", f"Give {path.parent / 'dataset.npz'}"
            )
        if path.suffix.lower() == ".npz":
            return "npz"
        if blender_folder(path) is not None:
            return "blender"
        if path.suffix.lower() == ".json":
            return "transforms"
        if llff_folder(path) is not None:
            return "llff"
        if path.suffix.lower() in (".bin", ".txt") and find_colmap_model(path.parent) is not None:
            return "colmap"
        raise fail(path, "unrecognised dataset file", f"Expected {FORMATS}")
    npzs = sorted(path.glob("*.npz"))
    if len(npzs) == 1:
        return "npz"
    if len(npzs) > 1:
        raise fail(
            path, f"holds {len(npzs)} .npz files ({', '.join(p.name for p in npzs[:4])})", "Pass the one you mean"
        )
    if blender_folder(path) is not None:
        return "blender"
    if (path / "transforms.json").is_file():
        return "transforms"
    if llff_folder(path) is not None:
        return "llff"
    if find_colmap_model(path) is not None:
        return "colmap"
    raise fail(path, "folder holds no dataset nerfkit recognises", _folder_hint(path) or f"Expected {FORMATS}")


def is_run_folder(path: Path) -> bool:
    """Whether ``path`` is a trained run's folder (its config.json, and checkpoints or model.pt)."""
    return (
        path.is_dir()
        and (path / "config.json").is_file()
        and ((path / "checkpoints").is_dir() or (path / "model.pt").is_file())
    )


def is_run_in_training(path: Path) -> bool:
    """Whether ``path`` is a run's folder that a process is training now, its first checkpoint
    perhaps not yet written."""
    from ..io.lock import is_locked

    return path.is_dir() and _run_config(path) is not None and is_locked(path)


def _run_config(path: Path) -> dict | None:
    """The ``train`` settings of the run config ``path/config.json``, or None (no such file, or not a run's)."""
    import json

    try:
        train = json.loads((path / "config.json").read_text())["train"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return train if isinstance(train, dict) else None


def _folder_hint(path: Path) -> str | None:
    """What to give instead of a folder that holds no dataset: a capture's own dataset, a
    run's dataset, or how to make one from the photos it holds."""
    from ..images import image_files

    if (path / "dataset" / "dataset.npz").is_file():
        return f"This is a capture's folder: its dataset is {path / 'dataset'}"
    if is_run_folder(path):
        data = (_run_config(path) or {}).get("data")
        where = f" trained on {data}" if isinstance(data, str) and data else ""
        return (
            f"This is a trained run's folder{where}: pass that dataset, or continue the run with "
            f"`nerfkit train --resume {path}`"
        )
    if _run_config(path) is not None:
        return (
            "This is a run's folder whose training stopped before its first checkpoint, so it holds no model: "
            f"train it again with `nerfkit train --config {path / 'config.json'} --out NEW_RUN`"
        )
    if image_files(path):
        return (
            f"It holds photos without poses: make a dataset of them with `nerfkit poses {path} --out DATASET` "
            "(or the whole flow with `nerfkit capture`)"
        )
    return None


def dataset_inputs(path: str | Path) -> list[Path]:
    """What reading the dataset at ``path`` reads, for the guard that never writes an input
    (:func:`~nerfkit.io.paths.guard_outputs`): the path; the folder of a dataset named by one
    of its files (a ``transforms.json`` or ``poses_bounds.npy`` with images beside it); and a
    COLMAP model's photo folder (the project's ``images/``, found above the model)."""
    path = Path(path)
    out = [path]
    if path.is_file() and path.suffix.lower() != ".npz":
        out.append(path.parent)
    folder = dataset_folder(path)  # ds/ of ds/dataset.npz beside its images, as train refuses it too
    out += [folder] if folder is not None and folder not in out else []
    try:
        fmt = detect_format(path)
    except NerfkitError:
        return out
    if fmt == "colmap":
        from .colmap import find_image_dir

        images = find_image_dir(path if path.is_dir() else path.parent)
        out += [images] if images is not None else []
    if fmt in ("transforms", "blender"):  # the files its frames name, wherever they are (--allow-outside-paths)
        out += _named_files(path if path.is_file() else _transforms_file(path))
    return out


def _transforms_file(folder: Path) -> Path:
    """A dataset folder's transforms file: transforms.json, else Blender's transforms_train.json."""
    return folder / "transforms.json" if (folder / "transforms.json").is_file() else folder / "transforms_train.json"


def _named_files(transforms: Path) -> list[Path]:
    """The images and point file outside its folder that a transforms.json (and, for
    Blender, its sibling split files) names (read with ``--allow-outside-paths``), resolved;
    none when it cannot be read."""
    from .nerfstudio import named_paths

    files = [transforms, *(transforms.parent / f"transforms_{s}.json" for s in ("train", "val", "test"))]
    named = {(transforms.parent / n).resolve() for f in files for n in named_paths(f)}
    return sorted(p for p in named if not is_within(p, transforms.parent))


def load_scene(
    path: str | Path,
    background: tuple[float, float, float] = (0.0, 0.0, 0.0),
    size: int | None = None,
    downscale: float | None = None,
    allow_outside: bool = False,
    need: str = "train",
) -> Scene:
    """Read a dataset file or folder (any supported format) into a Scene.

    Args:
        background: RGB in [0, 1] under transparent pixels (RGBA formats; default black).
        size, downscale: optional resampling, see :func:`~.resample.output_size`.
        allow_outside: accept image paths outside the dataset folder (``--allow-outside-paths``).
        need: the split that must be present: ``train``, or the split an evaluation reads
            (a file of held-out views needs no training split).
    Raises NerfkitError naming the path when the format is unsupported or the data is bad.
    """
    path = Path(path)
    fmt = detect_format(path)
    if fmt == "npz":
        if path.is_dir():
            path = next(path.glob("*.npz"))
        scene = resample_scene(load_npz(path, need=need), size, downscale)
    elif fmt == "blender":
        from .blender import load_blender

        scene = load_blender(
            path, background=background, size=size, downscale=downscale, allow_outside=allow_outside, need=need
        )
    elif fmt == "llff":
        from .llff import load_llff

        scene = load_llff(path, size=size, downscale=downscale, allow_outside=allow_outside)
    elif fmt == "colmap":
        from .colmap import load_colmap

        scene = load_colmap(path, background=background, size=size, downscale=downscale, allow_outside=allow_outside)
    else:
        scene = resample_scene(_load_transforms(path, background, allow_outside, need), size, downscale)
    return check_scene(scene, scene.source or str(path), need=need)  # the same guarantees for every format


def _load_transforms(path: Path, background, allow_outside: bool, need: str) -> Scene:
    """nerfstudio / instant-ngp transforms.json through :mod:`nerfkit.data.nerfstudio`."""
    try:
        from .nerfstudio import load_transforms_json
    except ImportError:
        raise fail(
            path,
            "transforms.json support (nerfkit.data.nerfstudio) is not installed in this build",
            "Convert the dataset to a course .npz first",
        ) from None
    return load_transforms_json(path, background=background, allow_outside=allow_outside, need=need)
