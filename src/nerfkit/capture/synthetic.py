"""Synthetic phone captures with known answers, for tests and development checks.

Renders photos of ArUco tag sheets and of a textured object (a sphere, or a glossy drink
can) beside a tag, through a pinhole camera with OpenCV lens distortion, by casting a ray
through every (super-sampled) pixel: the pixel is undistorted with ``cv2.undistortPoints``,
its ray hit with the table plane ``z = 0`` (or a gently waved surface: :func:`cockle`;
textures sampled with ``cv2.remap``), the sphere and the can, whose label and top mirror a
room around them (:func:`surroundings`), so that they change colour with the view.
Tags come from ``cv2.aruco.generateImageMarker``.

World frame: the table is ``z = 0`` and ``+z`` points up toward the cameras; tag frames
follow :mod:`nerfkit.capture.aruco` (the single tag of an object capture *is* the world
frame). ``K`` is in OpenCV's pixel convention.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..cameras import look_at
from .aruco import Layout, get_dictionary

DEFAULT_SIZE = (640, 480)
DEFAULT_K = np.array([[540.0, 0.0, 323.7], [0.0, 540.0, 236.2], [0.0, 0.0, 1.0]])
DEFAULT_DIST = np.array([-0.15, 0.08, 0.0008, -0.0006, 0.0])


@dataclass
class Decal:
    """A textured rectangle lying on z = 0.

    Attributes:
        texture: (h, w, 3) uint8.
        x0, y1: world x of its left edge and y of its top edge (texture rows go toward -y).
        res: metres per texel.
    """

    texture: np.ndarray
    x0: float
    y1: float
    res: float


@dataclass
class Sphere:
    center: np.ndarray
    radius: float


@dataclass
class Cylinder:
    """A closed upright cylinder standing on z = 0: a drink can.

    Attributes:
        center: (2,) x, y of its axis; radius, height: metres.
        label: (h, w, 3) uint8 wrapped once around its side (columns: the angle about the
            axis from +x, rows: from the top down).
        gloss: the share of the mirrored surroundings in the label's colour; top_gloss: in
            the metal top's.
    """

    center: np.ndarray
    radius: float
    height: float
    label: np.ndarray
    gloss: float = 0.3
    top_gloss: float = 0.7


@dataclass
class SynthScene:
    decals: list[Decal]
    spheres: list[Sphere] = field(default_factory=list)
    cylinders: list[Cylinder] = field(default_factory=list)
    table: np.ndarray | None = None  # (n, n, 3) uint8 tiling texture
    table_res: float = 0.002
    height: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None  # z of the table and sheet at (x, y)


def cockle(amplitude: float, wavelength: float = 0.08, seed: int = 0) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """The waves of a printed sheet lying on a table: ``z = amplitude * sin(...) * sin(...)``
    over (x, y), crests ``wavelength`` metres apart, at random phases and a random angle."""
    rng = np.random.default_rng(seed)
    angle, px, py = rng.uniform(0, np.pi), rng.uniform(0, 2 * np.pi), rng.uniform(0, 2 * np.pi)
    c, s_ = np.cos(angle), np.sin(angle)
    k = 2 * np.pi / wavelength

    def z(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return amplitude * np.sin(k * (c * x + s_ * y) + px) * np.sin(k * (-s_ * x + c * y) + py)

    return z


def table_texture(seed: int = 0, n: int = 256) -> np.ndarray:
    """A smooth grey-beige noise texture that tiles (wrapped low-frequency noise)."""
    import cv2

    rng = np.random.default_rng(seed)
    noise = np.zeros((n, n), np.float32)
    for scale, amp in ((8, 1.0), (32, 0.5), (128, 0.25)):
        small = rng.standard_normal((scale, scale)).astype(np.float32)
        big = cv2.resize(np.pad(small, 1, mode="wrap"), None, fx=n / scale, fy=n / scale, interpolation=cv2.INTER_CUBIC)
        off = int(round(n / scale))
        noise += amp * big[off : off + n, off : off + n]
    noise = (noise - noise.mean()) / (noise.std() + 1e-6)
    base = np.array([150.0, 140.0, 125.0])
    return np.clip(base + 18.0 * noise[..., None], 0, 255).astype(np.uint8)


def tag_sheet(
    ids: list[int],
    tag_size: float = 0.06,
    cols: int = 2,
    gap: float = 0.02,
    margin: float = 0.02,
    dictionary: str = "DICT_4X4_50",
    texels_per_module: int = 16,
    center: tuple[float, float] = (0.0, 0.0),
) -> tuple[Decal, Layout]:
    """A white sheet with tags in a grid, and its true layout.

    Tags are placed at whole texels so their corners are exact. With one tag and the default
    centre, the tag's frame is the world frame.
    """
    import cv2

    d = get_dictionary(dictionary)
    side_px = (d.markerSize + 2) * texels_per_module
    res = tag_size / side_px
    gap_px, margin_px = int(round(gap / res)), int(round(margin / res))
    rows = (len(ids) + cols - 1) // cols
    ncols = min(cols, len(ids))
    w = 2 * margin_px + ncols * side_px + (ncols - 1) * gap_px
    h = 2 * margin_px + rows * side_px + (rows - 1) * gap_px
    tex = np.full((h, w, 3), 245, np.uint8)
    x0 = center[0] - w * res / 2.0
    y1 = center[1] + h * res / 2.0
    tags = {}
    for k, tag_id in enumerate(ids):
        r, c = divmod(k, cols)
        j0 = margin_px + c * (side_px + gap_px)
        i0 = margin_px + r * (side_px + gap_px)
        marker = cv2.aruco.generateImageMarker(d, int(tag_id), side_px, borderBits=1)
        tex[i0 : i0 + side_px, j0 : j0 + side_px] = np.where(marker[..., None] > 127, 245, 20)
        left, top = x0 + j0 * res, y1 - i0 * res
        tags[int(tag_id)] = np.array(
            [[left, top, 0], [left + tag_size, top, 0], [left + tag_size, top - tag_size, 0], [left, top - tag_size, 0]]
        )
    return Decal(tex, x0, y1, res), Layout(tags, source="synthetic")


def charuco_sheet(layout: Layout, res: float = 0.0002, margin_px: int = 50) -> Decal:
    """The printed ChArUco board of a ChArUco :class:`Layout` (``cv2.aruco.CharucoBoard.generateImage``),
    placed so its frame is the layout's (centred, y up)."""
    b = layout.charuco
    nx, ny = b.getChessboardSize()
    sq = b.getSquareLength()
    w, h = int(round(nx * sq / res)) + 2 * margin_px, int(round(ny * sq / res)) + 2 * margin_px
    img = b.generateImage((w, h), marginSize=margin_px, borderBits=1)
    tex = np.repeat(np.where(img > 127, 245, 20).astype(np.uint8)[..., None], 3, axis=2)
    return Decal(tex, -nx * sq / 2 - margin_px * res, ny * sq / 2 + margin_px * res, res)


def camera_rays(K: np.ndarray, dist: np.ndarray, width: int, height: int, supersample: int = 2) -> np.ndarray:
    """Unit-z ray directions (H*ss, W*ss, 3) in the camera frame for every sub-pixel sample
    of a distorted image (OpenCV pixel centres)."""
    import cv2

    ss = supersample
    u = (np.arange(width * ss) + 0.5) / ss - 0.5
    v = (np.arange(height * ss) + 0.5) / ss - 0.5
    uu, vv = np.meshgrid(u, v)
    pts = np.stack([uu, vv], -1).reshape(-1, 1, 2)
    xy = cv2.undistortPoints(pts, K, dist, criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 60, 1e-12))
    xy = xy.reshape(height * ss, width * ss, 2)
    return np.concatenate([xy, np.ones_like(xy[..., :1])], -1)


def _sphere_color(n: np.ndarray) -> np.ndarray:
    """Colourful checker in longitude/latitude on unit normals (..., 3) -> (..., 3) float."""
    lon = np.arctan2(n[..., 1], n[..., 0])
    lat = np.arcsin(np.clip(n[..., 2], -1, 1))
    palette = np.array(
        [[220, 60, 50], [240, 200, 60], [60, 160, 80], [50, 90, 200], [230, 230, 230], [120, 60, 160]], np.float64
    )
    idx = (np.floor(lon / np.pi * 6).astype(int) + 2 * np.floor(lat / np.pi * 6).astype(int)) % len(palette)
    return palette[idx]


def cylinder_hits(o: np.ndarray, d: np.ndarray, cyl: Cylinder) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where rays from ``o`` (3,) along ``d`` (m, 3) (any length) first meet ``cyl``: ray
    parameters ``s`` (m,) (inf: they miss it), unit outward normals (m, 3) there and whether
    the hit is on the top (m,)."""
    q = o[:2] - np.asarray(cyl.center, np.float64)
    a = d[:, 0] ** 2 + d[:, 1] ** 2
    b = 2 * (d[:, :2] @ q)
    c = q @ q - cyl.radius**2
    disc = b * b - 4 * a * c
    with np.errstate(divide="ignore", invalid="ignore"):
        side = (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a)
        top = (cyl.height - o[2]) / d[:, 2]
    z = o[2] + side * d[:, 2]
    side = np.where((disc > 0) & (a > 0) & (side > 0) & (z >= 0) & (z <= cyl.height), side, np.inf)
    xy = q + np.where(np.isfinite(top), top, 0.0)[:, None] * d[:, :2]
    top = np.where((d[:, 2] < 0) & (top > 0) & (np.sum(xy * xy, 1) <= cyl.radius**2), top, np.inf)
    on_top = top < side
    s = np.minimum(side, top)
    p = q + np.where(np.isfinite(s), s, 0.0)[:, None] * d[:, :2]
    normal = np.concatenate([p / cyl.radius, np.zeros((len(d), 1))], 1)
    normal[on_top] = (0.0, 0.0, 1.0)
    return s, normal, on_top


def reflect(d: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Unit directions (m, 3) of rays along ``d`` (m, 3) mirrored by unit normals ``n`` (m, 3)."""
    u = d / np.linalg.norm(d, axis=1, keepdims=True)
    return u - 2 * np.sum(u * n, 1, keepdims=True) * n


def surroundings(u: np.ndarray) -> np.ndarray:
    """The room a glossy object mirrors: colours (m, 3) in 0-255 far along unit directions
    ``u`` (m, 3): a ceiling brighter than the floor, a bright window and dark furniture
    around the horizon."""
    up = np.clip(u[:, 2], -1, 1)
    base = 110 + 90 * (up[:, None] + 1) / 2 * np.array([1.0, 1.0, 1.05])
    window = np.exp(-np.sum((u - np.array([0.55, 0.45, 0.70])) ** 2, 1) / 0.05)
    azimuth = np.arctan2(u[:, 1], u[:, 0])
    furniture = (np.abs(up) < 0.3) * (np.cos(3 * azimuth) > 0.6)
    return np.clip(base + 150 * window[:, None] - 70 * furniture[:, None], 0, 255)


def red_label(size: tuple[int, int], row: float, swing: float, half_width: float) -> np.ndarray:
    """A red label (h, w, 3) uint8 with a white wave twice around it: its middle ``row`` of
    the height down, swinging ``swing`` of the height up and down, ``half_width`` of the
    height to each side."""
    h, w = size
    img = np.empty((h, w, 3), np.uint8)
    img[:] = (200, 25, 35)
    rows, cols = np.mgrid[0:h, 0:w]
    wave = row * h + swing * h * np.sin(2 * np.pi * 2 * cols / w)
    img[np.abs(rows - wave) < half_width * h] = (240, 240, 235)
    return img


def can_label(seed: int = 0, size: tuple[int, int] = (128, 512)) -> np.ndarray:
    """A drink can's label (h, w, 3) uint8: red, a white wave around it and dark lettering."""
    rng = np.random.default_rng(seed)
    h, w = size
    img = red_label(size, 0.55, 0.12, 0.05)
    for _ in range(14):  # letters: dark blocks in a band
        x, bw = int(rng.integers(0, w - 20)), int(rng.integers(6, 16))
        y, bh = int(rng.integers(int(0.15 * h), int(0.35 * h))), int(rng.integers(10, 22))
        img[y : y + bh, x : x + bw] = (30, 20, 20)
    return img


def render(
    scene: SynthScene,
    rays_cam: np.ndarray,
    c2w: np.ndarray,
    supersample: int = 2,
    blur: float = 0.0,
    noise: float = 0.0,
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """Render one view.

    Args:
        rays_cam: from :func:`camera_rays` (fixes K, distortion, size and supersampling).
        c2w: (4, 4) camera-to-world, OpenCV axes.
        blur: Gaussian blur sigma in output pixels (camera shake / defocus).
        noise: Gaussian pixel noise sigma (0-255 scale).

    Returns:
        (H, W, 3) uint8 RGB.
    """
    import cv2

    Hs, Ws = rays_cam.shape[:2]
    R, o = c2w[:3, :3], c2w[:3, 3]
    d = rays_cam @ R.T  # (Hs, Ws, 3), not normalised: plane/sphere hits use the same scale
    with np.errstate(divide="ignore", invalid="ignore"):
        s_plane = np.where(d[..., 2] < 0, -o[2] / d[..., 2], np.inf)
    hit = np.isfinite(s_plane)
    X = o[0] + s_plane * d[..., 0]
    Y = o[1] + s_plane * d[..., 1]
    if scene.height is not None:  # the waved surface: the fixed point of "hit the plane at the height below"
        for _ in range(8):
            with np.errstate(invalid="ignore"):
                s_plane = np.where(
                    hit, (scene.height(np.where(hit, X, 0.0), np.where(hit, Y, 0.0)) - o[2]) / d[..., 2], np.inf
                )
            X = o[0] + s_plane * d[..., 0]
            Y = o[1] + s_plane * d[..., 1]
    Xs, Ys = np.where(hit, X, 0.0), np.where(hit, Y, 0.0)
    img = np.empty((Hs, Ws, 3), np.uint8)
    table = scene.table if scene.table is not None else table_texture()
    n = table.shape[0]
    mx = (Xs / scene.table_res) % n
    my = (-Ys / scene.table_res) % n
    img[:] = cv2.remap(
        table, mx.astype(np.float32), my.astype(np.float32), cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP
    )
    for dec in scene.decals:
        jx = ((Xs - dec.x0) / dec.res - 0.5).astype(np.float32)
        iy = ((dec.y1 - Ys) / dec.res - 0.5).astype(np.float32)
        cv2.remap(dec.texture, jx, iy, cv2.INTER_LINEAR, dst=img, borderMode=cv2.BORDER_TRANSPARENT)
    img[~hit] = (200, 210, 225)
    out: np.ndarray = img.astype(np.float64)
    depth = np.where(hit, s_plane, np.inf)
    light = np.array([0.3, -0.4, 0.87])
    for sp in scene.spheres:
        oc = o - sp.center
        a = np.sum(d * d, -1)
        b = 2 * (d @ oc)
        c = oc @ oc - sp.radius**2
        disc = b * b - 4 * a * c
        with np.errstate(invalid="ignore"):
            s = (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a)
        on = (disc > 0) & (s > 0) & (s < depth)
        if not on.any():
            continue
        p = o + s[on][:, None] * d[on]
        nrm = (p - sp.center) / sp.radius
        shade = 0.35 + 0.65 * np.clip(nrm @ light, 0, 1)
        out[on] = _sphere_color(nrm) * shade[:, None]
        depth = np.where(on, s, depth)
    for cyl in scene.cylinders:
        flat = d.reshape(-1, 3)
        s, nrm, on_top = (x.reshape(Hs, Ws, *x.shape[1:]) for x in cylinder_hits(o, flat, cyl))
        on = s < depth
        if not on.any():
            continue
        p = o + s[on][:, None] * d[on]
        n_on, top_on = nrm[on], on_top[on]
        shade = 0.35 + 0.65 * np.clip(n_on @ light, 0, 1)
        angle = np.arctan2(n_on[:, 1], n_on[:, 0]) % (2 * np.pi)
        lh, lw = cyl.label.shape[:2]
        col = np.clip((angle / (2 * np.pi) * lw).astype(int), 0, lw - 1)
        row = np.clip(((cyl.height - p[:, 2]) / cyl.height * lh).astype(int), 0, lh - 1)
        diffuse = np.where(top_on[:, None], 175.0, cyl.label[row, col].astype(np.float64)) * shade[:, None]
        gloss = np.where(top_on, cyl.top_gloss, cyl.gloss)[:, None]
        out[on] = (1 - gloss) * diffuse + gloss * surroundings(reflect(d[on], n_on))
        depth = np.where(on, s, depth)
    out = cv2.resize(out, (Ws // supersample, Hs // supersample), interpolation=cv2.INTER_AREA)
    if blur > 0:
        out = cv2.GaussianBlur(out, (0, 0), blur)
    if noise > 0:
        out = out + (rng or np.random.default_rng(0)).normal(0, noise, out.shape)
    return np.clip(out + 0.5, 0, 255).astype(np.uint8)


def _with_roll(c2w: np.ndarray, roll: float) -> np.ndarray:
    c, s = np.cos(roll), np.sin(roll)
    Rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    out = c2w.copy()
    out[:3, :3] = c2w[:3, :3] @ Rz
    return out


def sheet_views(
    n: int,
    K: np.ndarray,
    size: tuple[int, int],
    extent: float,
    rng: np.random.Generator,
    center: np.ndarray | None = None,
) -> np.ndarray:
    """(n, 4, 4) varied calibration viewpoints of a sheet of half-size ``extent`` metres:
    elevations 35-75 degrees, any azimuth and roll, the sheet filling 45-95% of the width."""
    center = np.zeros(3) if center is None else np.asarray(center, float)
    poses = []
    for _ in range(n):
        el = np.deg2rad(rng.uniform(35, 75))
        az = rng.uniform(0, 2 * np.pi)
        frac = rng.uniform(0.45, 0.95)
        dist = K[0, 0] * 2 * extent / (frac * size[0])
        target = center + np.append(rng.uniform(-0.5, 0.5, 2) * extent, 0.0)
        eye = target + dist * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        poses.append(_with_roll(look_at(eye, target, np.array([0.0, 0.0, 1.0])), rng.uniform(-np.pi, np.pi)))
    return np.stack(poses)


def orbit_views(
    n: int,
    target: np.ndarray,
    rng: np.random.Generator,
    distance=(0.3, 0.42),
    elevation_deg=(25, 60),
    roll_deg: float = 8.0,
) -> np.ndarray:
    """(n, 4, 4) cameras around ``target`` (evenly spread azimuths with jitter), looking at it."""
    poses = []
    for k in range(n):
        az = 2 * np.pi * (k + rng.uniform(-0.3, 0.3)) / n
        el = np.deg2rad(rng.uniform(*elevation_deg))
        dist = rng.uniform(*distance)
        eye = target + dist * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        aim = target + np.append(rng.normal(0, 0.01, 2), 0.0)
        poses.append(
            _with_roll(look_at(eye, aim, np.array([0.0, 0.0, 1.0])), np.deg2rad(rng.uniform(-roll_deg, roll_deg)))
        )
    return np.stack(poses)


@dataclass
class SyntheticCapture:
    """Rendered photos and the truth behind them.

    Attributes:
        images: N (H, W, 3) uint8 upright photos.
        c2w: (N, 4, 4) true camera-to-world (OpenCV axes, world = table/tag frame).
        names: N file names.
        K: (3, 3) OpenCV-convention intrinsics; dist: (5,) k1 k2 p1 p2 k3.
        layout: the true tag layout.
        scene: what was rendered.
    """

    images: list[np.ndarray]
    c2w: np.ndarray
    names: list[str]
    K: np.ndarray
    dist: np.ndarray
    width: int
    height: int
    layout: Layout
    scene: SynthScene

    def write(self, folder: str | Path, quality: int = 95, f35: float | None = None) -> list[Path]:
        """Write the photos (format from each name's suffix) into ``folder``; returns the paths."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        return [write_photo(folder / n, img, quality=quality, f35=f35) for n, img in zip(self.names, self.images)]


def write_photo(
    path: str | Path, upright: np.ndarray, orientation: int = 1, quality: int = 95, f35: float | None = None
) -> Path:
    """Write a photo whose *displayed* (EXIF-applied) image is ``upright``.

    ``orientation`` is the EXIF Orientation tag (1, 3, 6 or 8); the stored pixels are rotated
    so a viewer applying the tag shows ``upright``. ``f35`` adds FocalLengthIn35mmFilm.
    """
    from PIL import Image

    path = Path(path)
    stored = {1: upright, 3: np.rot90(upright, 2), 6: np.rot90(upright, 1), 8: np.rot90(upright, -1)}[orientation]
    img = Image.fromarray(np.ascontiguousarray(stored))
    exif = Image.Exif()
    if orientation != 1:
        exif[0x0112] = orientation
    if f35 is not None:
        exif.get_ifd(0x8769)[0xA405] = int(round(f35))
    kwargs: dict[str, Any] = {"exif": exif.tobytes()} if (orientation != 1 or f35 is not None) else {}
    if path.suffix.lower() in (".jpg", ".jpeg"):
        img.save(path, quality=quality, **kwargs)
    else:
        img.save(path, **kwargs)
    return path


def make_calibration_capture(
    n: int = 16,
    size: tuple[int, int] = DEFAULT_SIZE,
    K: np.ndarray = DEFAULT_K,
    dist: np.ndarray = DEFAULT_DIST,
    ids: tuple[int, ...] = (0, 1, 2, 3, 4, 5),
    tag_size: float = 0.05,
    cols: int = 2,
    gap: float = 0.025,
    seed: int = 0,
    supersample: int = 2,
    dictionary: str = "DICT_4X4_50",
    noise: float = 1.0,
    prefix: str = "calib",
    height=None,
) -> SyntheticCapture:
    """Photos of a sheet of tags (default: 6 tags, 2 columns, like the course's sheet);
    ``height``: the sheet's surface (:func:`cockle`), else flat."""
    rng = np.random.default_rng(seed)
    decal, layout = tag_sheet(list(ids), tag_size, cols, gap, dictionary=dictionary)
    scene = SynthScene([decal], table=table_texture(seed), height=height)
    extent = 0.5 * max(decal.texture.shape[:2]) * decal.res
    poses = sheet_views(n, np.asarray(K), size, extent, rng)
    rays = camera_rays(np.asarray(K), np.asarray(dist), size[0], size[1], supersample)
    images = [render(scene, rays, p, supersample, noise=noise, rng=rng) for p in poses]
    names = [f"{prefix}_{i:03d}.jpg" for i in range(n)]
    return SyntheticCapture(
        images, poses, names, np.asarray(K, float), np.asarray(dist, float), size[0], size[1], layout, scene
    )


def make_object_capture(
    n: int = 12,
    size: tuple[int, int] = DEFAULT_SIZE,
    K: np.ndarray = DEFAULT_K,
    dist: np.ndarray = DEFAULT_DIST,
    tag_id: int = 0,
    tag_size: float = 0.06,
    object_center: tuple[float, float, float] = (0.11, 0.03, 0.045),
    object_radius: float = 0.045,
    seed: int = 1,
    supersample: int = 2,
    dictionary: str = "DICT_4X4_50",
    noise: float = 1.0,
    distance=(0.32, 0.42),
    prefix: str = "obj",
    can: bool = False,
    table: np.ndarray | None = None,
    gloss: float = 1.0,
    label: np.ndarray | None = None,
) -> SyntheticCapture:
    """Photos of a textured sphere resting beside one tag (whose frame is the world frame),
    taken from a ring of viewpoints looking between the tag and the object. ``can``: a glossy
    drink can instead (:class:`Cylinder`, ``object_radius`` wide and ``2 object_center[2]``
    tall, its axis through the centre, its label's and top's gloss times ``gloss``: 0 matte;
    its ``label`` (h, w, 3) uint8, default :func:`can_label`); ``table``: the table's tiling
    texture (default: :func:`table_texture`)."""
    rng = np.random.default_rng(seed)
    decal, layout = tag_sheet([tag_id], tag_size, 1, 0.0, margin=0.012, dictionary=dictionary)
    center = np.asarray(object_center, float)
    table = table_texture(seed) if table is None else table
    if can:
        cyl = Cylinder(center[:2], object_radius, 2 * center[2], can_label(seed) if label is None else label)
        cyl.gloss, cyl.top_gloss = gloss * cyl.gloss, gloss * cyl.top_gloss
        scene = SynthScene([decal], cylinders=[cyl], table=table)
    else:
        scene = SynthScene([decal], [Sphere(center, object_radius)], table=table)
    target = np.array([center[0] * 0.6, center[1] * 0.6, center[2] * 0.5])
    poses = orbit_views(n, target, rng, distance)
    rays = camera_rays(np.asarray(K), np.asarray(dist), size[0], size[1], supersample)
    images = [render(scene, rays, p, supersample, noise=noise, rng=rng) for p in poses]
    names = [f"{prefix}_{i:03d}.jpg" for i in range(n)]
    return SyntheticCapture(
        images, poses, names, np.asarray(K, float), np.asarray(dist, float), size[0], size[1], layout, scene
    )


def project(K: np.ndarray, dist: np.ndarray, c2w: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Pixels (n, 2) (OpenCV convention) of world points (n, 3) seen by a camera."""
    import cv2

    w2c = np.linalg.inv(c2w)
    rvec = cv2.Rodrigues(w2c[:3, :3])[0]
    px, _ = cv2.projectPoints(np.asarray(points, np.float64).reshape(-1, 1, 3), rvec, w2c[:3, 3], K, dist)
    return px.reshape(-1, 2)


@functools.lru_cache(maxsize=8)
def cached_capture(kind: str, n: int, seed: int) -> SyntheticCapture:
    """A capture rendered once per process (tests share them; do not modify the result).

    ``kind`` is ``"sheet"`` (:func:`make_calibration_capture`) or ``"object"``
    (:func:`make_object_capture`)."""
    if kind == "sheet":
        return make_calibration_capture(n=n, seed=seed)
    if kind == "object":
        return make_object_capture(n=n, seed=seed)
    raise ValueError(f"unknown capture kind {kind!r}")
