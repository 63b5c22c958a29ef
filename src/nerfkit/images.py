"""Reading the images people actually have.

JPEG/PNG/TIFF/WebP (and HEIC when pillow-heif is installed), greyscale, palette, RGBA
(composited on a background), 16-bit, EXIF-rotated phone photos (returned upright).
Every failure is a :class:`NerfkitError` naming the file.
"""

from __future__ import annotations

import contextlib
import os
import warnings
from collections import Counter
from pathlib import Path

import numpy as np

from .errors import fail
from .io.atomic import atomic_path
from .io.paths import file_sha1, files_inside, path_kind, refuse_special_file

IMAGE_SUFFIXES = {".jpg", ".jpeg", ".png", ".tif", ".tiff", ".webp", ".bmp", ".heic", ".heif"}
# the clips `nerfkit capture` and `nerfkit frames` take (ffmpeg reads them)
VIDEO_SUFFIXES = (".mp4", ".mov", ".m4v", ".mkv", ".avi", ".webm", ".3gp")
# PIL refuses larger images as a "decompression bomb"; phone photos are ~12-50 MP.
MAX_IMAGE_PIXELS = 250_000_000


def to_uint8(image: np.ndarray) -> np.ndarray:
    """Float image in [0, 1] -> uint8, rounded; a non-finite value (a diverged render) is
    black (NaN, -inf) or white (+inf) instead of whatever casting NaN gives."""
    image = np.nan_to_num(np.asarray(image), nan=0.0, posinf=1.0, neginf=0.0)
    return (np.clip(image, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


# cv2.remap takes maps shorter than 32767
REMAP_CHUNK = 30000


def sample_bilinear(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """(n, C) ``image`` (H, W, C) float32 at pixels ``uv`` (n, 2), pixel centres at +0.5
    (nerfkit's convention; OpenCV's are at integers), bilinear; outside the frame, the
    nearest border pixel's."""
    import cv2

    maps = (np.asarray(uv, np.float64) - 0.5).astype(np.float32)
    out = np.empty((len(maps), image.shape[2]), np.float32)
    for i in range(0, len(maps), REMAP_CHUNK):
        part = maps[i : i + REMAP_CHUNK]
        out[i : i + REMAP_CHUNK] = cv2.remap(
            image, part[:, :1].copy(), part[:, 1:].copy(), cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE
        ).reshape(len(part), -1)
    return out


def _open(path: Path):
    from PIL import Image, UnidentifiedImageError

    Image.MAX_IMAGE_PIXELS = MAX_IMAGE_PIXELS
    if path.suffix.lower() in {".heic", ".heif"}:
        try:
            import pillow_heif

            pillow_heif.register_heif_opener()
        except ImportError:
            raise fail(
                path, "HEIC photos need pillow-heif", "pip install pillow-heif, or export the photos as JPEG"
            ) from None
    kind = path_kind(path)
    if kind is None:
        raise fail(path, "no such file", "Check the path")
    if kind == "dir":
        raise fail(path, "is a folder, expected an image file")
    refuse_special_file(path, kind)
    try:
        with warnings.catch_warnings():  # nerfkit says it itself, in one line, just below
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            img = Image.open(path)
        if img.width * img.height > MAX_IMAGE_PIXELS:  # PIL only warns below twice its limit
            raise fail(
                path,
                f"image is {img.width}x{img.height} ({img.width * img.height / 1e6:.0f} megapixels), "
                f"more than nerfkit reads ({MAX_IMAGE_PIXELS / 1e6:.0f} megapixels)",
                "Downscale it first",
            )
        img.load()
    except UnidentifiedImageError:
        with open(path, "rb") as f:
            if f.read(4) in (b"II*\x00", b"MM\x00*"):  # a TIFF, of samples Pillow does not read
                raise fail(
                    path,
                    "a TIFF whose samples nerfkit cannot read (floating-point, or of an unusual layout)",
                    "Save it as an 8- or 16-bit RGB TIFF or PNG",
                ) from None
        raise fail(path, "not an image nerfkit can read", "Use JPEG, PNG, TIFF, WebP or HEIC") from None
    except Image.DecompressionBombError as e:
        raise fail(path, f"image is too large ({e})") from None
    except (OSError, SyntaxError, ValueError) as e:
        raise fail(path, f"cannot decode image ({e})", "The file may be truncated or corrupt") from None
    if img.width == 0 or img.height == 0:
        raise fail(path, "image is empty (0 pixels)")
    return img


def exif_focal_35mm(path: str | Path) -> float | None:
    """EXIF ``FocalLengthIn35mmFilm`` in mm, or None when the photo doesn't say."""
    try:
        img = _open(Path(path))
        exif = img.getexif()
        value = exif.get_ifd(0x8769).get(0xA405) or exif.get(0xA405)
        return float(value) if value else None
    except Exception:  # noqa: BLE001 - EXIF is optional metadata
        return None


# EXIF Orientation -> clockwise quarter turns that make the stored pixels upright (the
# mirrored orientations 2, 4, 5 and 7 are not turns)
QUARTER_TURNS = {1: 0, 6: 1, 3: 2, 8: 3}


def held_as(width: int, height: int) -> str:
    """How a photo of this size was held, for messages: ``"portrait 3024x4032"``."""
    return f"{'portrait' if height > width else 'landscape'} {width}x{height}"


def common_size(sizes) -> tuple[int, int] | None:
    """The (width, height) most of ``sizes`` share; a tie goes to the larger (more pixels,
    then wider), so the choice never depends on the photos' order. None when empty."""
    counts = Counter(tuple(s) for s in sizes)
    return max(counts, key=lambda s: (counts[s], s[0] * s[1], s[0])) if counts else None


def common_frame(orientations, extra_turns=None) -> int | None:
    """The frame most photos share: the most common clockwise quarter turns from the
    sensor's pixels (the photos as stored) to upright, from their EXIF ``orientations``
    (plus ``extra_turns`` already given to each). None when no orientation is a turn."""
    extra = extra_turns if extra_turns is not None else [0] * len(orientations)
    held = Counter((QUARTER_TURNS[o] + t) % 4 for o, t in zip(orientations, extra) if o in QUARTER_TURNS)
    return held.most_common(1)[0][0] if held else None


def turns_into_frame(orientation: int, frame: int | None) -> int | None:
    """Clockwise quarter turns that take a photo held the other way (upright size the
    frame's transposed; EXIF ``orientation``) from upright into ``frame`` (turns from the
    sensor, :func:`common_frame`): its stored pixels are the sensor's, as the others'.
    None when that is not so or EXIF cannot tell (no frame, a photo rotated in an editor)."""
    own = QUARTER_TURNS.get(orientation)
    if frame is None or own is None or not (frame - own) % 2:
        return None
    return (frame - own) % 4


def orientation_tag(img) -> int:
    """The EXIF Orientation tag of an opened PIL image: 1 (stored upright) when it has
    none, or when its EXIF is unreadable or out of range. HEIF photos (pillow-heif) are
    decoded upright already, their tag reset to 1: the original tag is what they say."""
    try:
        value = int(img.info.get("original_orientation") or img.getexif().get(0x0112, 1) or 1)
    except Exception:  # noqa: BLE001 - a broken EXIF block: treat as upright, as load_image does
        return 1
    return value if 1 <= value <= 8 else 1


def upright_size(img, orientation: int) -> tuple[int, int]:
    """(width, height) of an opened PIL image once turned upright by its EXIF
    ``orientation`` (:func:`orientation_tag`); HEIF photos are decoded upright already."""
    w, h = img.size
    if orientation in (5, 6, 7, 8) and "original_orientation" not in img.info:  # stored rotated by 90 degrees
        return h, w
    return w, h


def _open_upright(path: Path):
    return _upright(_open(path))


def _upright(img):
    """An opened PIL image turned by its EXIF orientation."""
    from PIL import ImageOps

    with contextlib.suppress(Exception):  # a broken EXIF block should not stop us
        img = ImageOps.exif_transpose(img)
    return img


def _over(rgba: np.ndarray, background) -> np.ndarray:
    """(H, W, 3) float32 RGB of float (H, W, 3 or 4) ``rgba`` in [0, 1], composited over ``background``."""
    if rgba.shape[-1] == 3:
        return np.ascontiguousarray(rgba, dtype=np.float32)
    alpha = rgba[..., 3:4]
    rgb = rgba[..., :3] * alpha + np.asarray(background, np.float32) * (1.0 - alpha)
    return np.ascontiguousarray(rgb, dtype=np.float32)


def _has_alpha(img) -> bool:
    return img.mode in ("RGBA", "LA", "PA") or (img.mode == "P" and "transparency" in img.info)


def load_image(path: str | Path, background: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> np.ndarray:
    """Load an image upright as float32 RGB in [0, 1], shape (H, W, 3).

    EXIF orientation is applied; greyscale is replicated to RGB; transparency is
    composited over ``background``; 16-bit images keep their precision (colour ones, which
    Pillow reads as 8 bits, through OpenCV when it is installed).
    """
    img = _open(Path(path))
    deep = _colour_16bit(Path(path), img)
    return _over(deep, background) if deep is not None else _to_float(_upright(img), background, path)


def _colour_16bit(path: Path, img) -> np.ndarray | None:
    """(H, W, 3 or 4) float32 RGB(A) in [0, 1] of a 16-bit colour PNG or TIFF stored upright
    (EXIF orientation 1), read by OpenCV; None for anything else (or without OpenCV)."""
    if img.mode not in ("RGB", "RGBA") or path.suffix.lower() not in (".png", ".tif", ".tiff"):
        return None
    if orientation_tag(img) != 1:
        return None
    try:
        import cv2
    except ImportError:
        return None
    arr = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if arr is None or arr.dtype != np.uint16 or arr.ndim != 3 or arr.shape[-1] not in (3, 4):
        return None
    arr = cv2.cvtColor(arr, cv2.COLOR_BGRA2RGBA if arr.shape[-1] == 4 else cv2.COLOR_BGR2RGB)
    return arr.astype(np.float32) / 65535.0


def _to_float(img, background, path) -> np.ndarray:
    mode = img.mode
    if mode in ("I;16", "I;16B", "I;16L", "I"):
        arr = np.asarray(img, dtype=np.float32)
        scale = 65535.0 if arr.max() > 255 or mode.startswith("I;16") else 255.0
        rgb = np.repeat((arr / scale)[..., None], 3, axis=2)
        return np.clip(rgb, 0.0, 1.0).astype(np.float32)
    if mode == "F":
        arr = np.asarray(img, dtype=np.float32)
        finite = arr[np.isfinite(arr)]
        if finite.size and (finite.min() < 0.0 or finite.max() > 1.0):  # clipped, it would be another picture
            raise fail(
                path,
                f"float pixels span [{finite.min():.4g}, {finite.max():.4g}], expected [0, 1]",
                "Save it with floats scaled to 0-1 (divide 0-255 values by 255), or as an 8- or 16-bit image",
            )
        arr = np.nan_to_num(arr, nan=0.0, posinf=1.0, neginf=0.0)  # a diverged render's NaN black, inf white
        return np.repeat(arr[..., None], 3, axis=2)
    has_alpha = _has_alpha(img)
    img = img.convert("RGBA" if has_alpha else "RGB")
    arr = np.asarray(img, dtype=np.float32)
    arr /= 255.0
    return _over(arr, background)


def load_image_uint8(
    path: str | Path, background: tuple[float, float, float] = (0.0, 0.0, 0.0), upright: bool = True
) -> np.ndarray:
    """Like :func:`load_image` but (H, W, 3) uint8, for OpenCV and for datasets. ``upright``:
    turned by its EXIF orientation (False: the pixels as stored, as COLMAP reads them).

    8-bit photos without transparency (nearly every phone photo) go straight to uint8:
    no float32 copy of a 12-MP image (~150 MB each) is made.
    """
    img = _open_upright(Path(path)) if upright else _open(Path(path))
    if img.mode not in ("I;16", "I;16B", "I;16L", "I", "F") and not _has_alpha(img):
        return np.array(img if img.mode == "RGB" else img.convert("RGB"), dtype=np.uint8)
    rgb = _to_float(img, background, path)
    rgb *= 255.0
    rgb += 0.5
    return rgb.astype(np.uint8)


def image_files(folder: str | Path) -> list[Path]:
    """The image files in a folder (not recursive), sorted by name. Hidden files are not
    photos: macOS leaves ``._IMG_0001.JPG`` (its metadata) beside each photo copied to a
    foreign disk."""
    return sorted(
        p
        for p in Path(folder).iterdir()
        if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES and not p.name.startswith(".")
    )


def video_names(folder: str | Path) -> list[str]:
    """The names of the videos (:data:`VIDEO_SUFFIXES`) in ``folder``, sorted."""
    return sorted(p.name for p in Path(folder).iterdir() if p.suffix.lower() in VIDEO_SUFFIXES)


def copies(paths: list[Path]) -> dict[str, str]:
    """Each photo of ``paths`` whose bytes are those of an earlier one -> that one's name
    ("IMG_1 (1).jpg" -> "IMG_1.jpg"): a copy adds no view, and one in the held-out photos
    would score a view trained on. Files that cannot be read are left to the reader's error."""
    first: dict[str, str] = {}
    out = {}
    for p in paths:
        try:
            key = file_sha1(p)
        except OSError:
            continue
        if key in first and first[key] != p.name:
            out[p.name] = first[key]
        else:
            first[key] = p.name
    return out


def copy_reason(original: str) -> str:
    """Why a copy of ``original`` (:func:`copies`) is left out."""
    return f"a copy of {original} (the same bytes): it adds no view"


def list_images(folder: str | Path, allow_outside: bool = False) -> list[Path]:
    """:func:`image_files` of a folder, for the commands that read them (``poses``,
    ``calibrate``, ``capture``); a clear error when it is no folder or holds none, and for a
    photo that is a symlink to a file outside the folder (:func:`~nerfkit.io.paths.files_inside`;
    ``allow_outside``: read it)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise fail(folder, "no such folder" if not folder.exists() else "is not a folder")
    files = image_files(folder)
    if not files:
        clips = video_names(folder)
        if clips:
            raise fail(
                folder,
                f"holds no images, but a video ({', '.join(clips[:3])})",
                f"Pass the video itself to nerfkit capture ({folder / clips[0]}), or write its frames as photos "
                "with nerfkit frames",
            )
        raise fail(folder, "holds no images", f"Expected files ending in {', '.join(sorted(IMAGE_SUFFIXES))}")
    return files_inside(
        folder,
        files,
        allow_outside,
        "nerfkit reads only the photos inside the folder it is given: copy the photo into the "
        "folder instead of linking to it",
    )


def write_image(path: str | os.PathLike, image: np.ndarray) -> None:
    """Write an image (float in [0, 1] or uint8, (H, W[, C])) as PNG/JPEG atomically; floats
    go through :func:`to_uint8`."""
    import imageio.v3 as iio

    if image.dtype != np.uint8:
        image = to_uint8(image)
    with atomic_path(path) as tmp:
        iio.imwrite(tmp, image, extension=Path(path).suffix)
