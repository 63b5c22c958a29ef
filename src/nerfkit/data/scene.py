"""The one scene type every data format loads into.

A :class:`Scene` holds three splits of :class:`Views` (train, val, test) in nerfkit's
camera convention (OpenCV axes, see :mod:`nerfkit.cameras`), plus the depth range
(near/far) and the scene's centre and up direction used for orbit paths.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..cameras import axes_across, forward_facing, mean_camera, orbit_path, spiral_path
from ..ground import find_floor

# frames of a generated orbit or spiral: 4 s at 30 fps
ORBIT_FRAMES = 120

# how sharply an orbit follows the training cameras near each azimuth (von Mises
# concentration: weights fall to 1/e at about 30 degrees)
ORBIT_KAPPA = 4.0

# the camera paths a video can take (:meth:`Scene.video_kind`)
VIDEO_PATHS = ("test", "orbit", "spiral")


@dataclass
class Views:
    """The cameras (and images, when there are any) of one split.

    Attributes:
        c2w: (N, 4, 4) float32 camera-to-world, OpenCV axes.
        K: (N, 3, 3) float32 intrinsics, one per view.
        width, height: image size in pixels (the same for every view of a split).
        images: (N, H, W, 3) uint8, or None for pose-only splits (e.g. a render path).
        names: N strings tracing each view back to its photo, or None.
    """

    c2w: np.ndarray
    K: np.ndarray
    width: int
    height: int
    images: np.ndarray | None = None
    names: list[str] | None = None

    def __len__(self) -> int:
        return int(self.c2w.shape[0])

    @property
    def has_images(self) -> bool:
        return self.images is not None and len(self.images) > 0

    def subset(self, idx) -> Views:
        idx = np.asarray(idx)
        return replace(
            self,
            c2w=self.c2w[idx],
            K=self.K[idx],
            images=None if self.images is None else self.images[idx],
            names=None if self.names is None else [self.names[i] for i in np.atleast_1d(idx)],
        )

    @staticmethod
    def empty(width: int, height: int) -> Views:
        return Views(np.zeros((0, 4, 4), np.float32), np.zeros((0, 3, 3), np.float32), width, height)


@dataclass
class Scene:
    """A posed dataset.

    Attributes:
        train, val, test: the splits (val/test may be empty; test often has poses only).
        near, far: depth range of the object along rays, in scene units.
        center: (3,) point the cameras look at (orbit centre).
        up: (3,) unit world up direction (orbit axis).
        source: where the scene came from (for messages).
        capture: True for real photos (a room around the object, exposure changing between
            shots, poses from tags or SfM); training then picks its real-capture settings.
        table: (4,) plane ``(n, d)`` with ``n . x + d = 0`` on which the object stands, ``n``
            the unit normal toward the cameras, or None (e.g. the tag plane of a tag capture).
        points: (m, 3) float32 sparse 3D points on the scene's surfaces (from
            structure-from-motion or triangulation), or None; point_colors: (m, 3) uint8.
        point_views: (k, 2) int32 rows ``(point, train view)``: the train views that saw
            each point (its feature track), or None (not known).
        tags: (n, 4, 3) float32 corners of the printed tags lying on the table (a tag
            capture's, in world units), or None.
    """

    train: Views
    val: Views
    test: Views
    near: float
    far: float
    center: np.ndarray = field(default_factory=lambda: np.zeros(3, np.float32))
    up: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0], np.float32))
    source: str = ""
    capture: bool = False
    table: np.ndarray | None = None
    points: np.ndarray | None = None
    point_colors: np.ndarray | None = None
    tags: np.ndarray | None = None
    point_views: np.ndarray | None = None
    _floor: tuple = field(default=(), init=False, repr=False, compare=False)  # (floor(), once found)

    def floor(self):
        """The floor seen beyond the table's edge in the sparse points, as a
        :class:`~nerfkit.ground.GroundPlane` (:func:`~nerfkit.ground.find_floor`
        under the training cameras), or None (no table, no points, no such plane). Found
        once, the first time it is asked."""
        if not self._floor:
            plane = None
            if self.points is not None and self.table is not None and len(self.train):
                plane = find_floor(self.points, self.table, self.train.c2w[:, :3, 3], self.center)
            self._floor = (plane,)
        return self._floor[0]

    @property
    def splits(self) -> dict[str, Views]:
        return {"train": self.train, "val": self.val, "test": self.test}

    def split_with_images(self, besides: str) -> str | None:
        """The first split other than ``besides`` that has images, held-out ones first."""
        return next((s for s in ("val", "test", "train") if s != besides and self.splits[s].has_images), None)

    @property
    def has_video_path(self) -> bool:
        """True when the test split is a pose-only camera path (as in the course files); a
        captured dataset's test split holds held-out photos instead."""
        return len(self.test) > 0 and not self.test.has_images

    @property
    def forward_facing(self) -> bool:
        """Every training camera looks about the same way from about the same place (an
        LLFF-style scene; :func:`~nerfkit.cameras.forward_facing`)."""
        return len(self.train) > 0 and forward_facing(self.train.c2w, self.center)

    def video_kind(self, kind: str = "auto") -> str:
        """The camera path a video takes: ``kind`` itself ("test", "orbit" or "spiral"), or
        for "auto" the test split when it is a pose-only path, else a spiral for a
        forward-facing scene (the cameras never saw its far side), else an orbit."""
        if kind == "auto":
            return "test" if self.has_video_path else "spiral" if self.forward_facing else "orbit"
        if kind not in VIDEO_PATHS:
            raise ValueError(f"unknown camera path {kind!r}: expected auto or one of {', '.join(VIDEO_PATHS)}")
        return kind

    def render_path(self, n_frames: int = ORBIT_FRAMES, aim: np.ndarray | None = None, kind: str = "auto") -> Views:
        """Poses for a video along :meth:`video_kind`'s path; ``aim``: the point an orbit
        circles or a spiral focuses on (default ``center``)."""
        kind = self.video_kind(kind)
        if kind == "test":
            return self.test
        return self.spiral(n_frames, aim) if kind == "spiral" else self.orbit(n_frames, aim)

    def spiral(self, n_frames: int = ORBIT_FRAMES, aim: np.ndarray | None = None) -> Views:
        """LLFF's spiral (:func:`~nerfkit.cameras.spiral_path`) looking at the depth of
        ``aim`` (default ``center``), with the first training camera's intrinsics."""
        ref = mean_camera(self.train.c2w)
        focus = np.asarray(self.center if aim is None else aim, np.float64).reshape(3)
        depth = max(float((focus - ref[:3, 3]) @ ref[:3, 2]), 1e-3)
        c2w = spiral_path(self.train.c2w, depth, n_frames)
        return Views(c2w, np.repeat(self.train.K[:1], n_frames, axis=0), self.train.width, self.train.height)

    def orbit(self, n_frames: int = ORBIT_FRAMES, aim: np.ndarray | None = None) -> Views:
        """A loop of cameras about ``up`` looking at ``aim`` (default ``center``), with the
        first training camera's intrinsics. At each azimuth its height and distance from
        the axis are those of the training cameras near that azimuth (a weighted mean,
        weights ``exp(ORBIT_KAPPA (cos(angle between azimuths) - 1))``: about 30 degrees
        wide), so the video stays where the photos were taken: higher where they looked
        down more, and never far from them."""
        if len(self.train) == 0:
            raise ValueError("cannot make an orbit without training cameras")
        center = self.center if aim is None else np.asarray(aim, np.float64).reshape(3)
        offsets = self.train.c2w[:, :3, 3] - center
        heights = offsets @ self.up
        radial = offsets - np.outer(heights, self.up)
        a, b = axes_across(self.up)
        azimuths = np.arctan2(radial @ b, radial @ a)
        thetas = np.linspace(0.0, 2.0 * np.pi, n_frames, endpoint=False)
        w = np.exp(ORBIT_KAPPA * (np.cos(thetas[:, None] - azimuths[None]) - 1.0))  # (n_frames, n_cameras)
        w /= w.sum(1, keepdims=True)
        c2w = orbit_path(center, self.up, w @ np.linalg.norm(radial, axis=1), w @ heights, n_frames)
        K = np.repeat(self.train.K[:1], n_frames, axis=0)
        return Views(c2w, K, self.train.width, self.train.height)


def estimate_center(c2w: np.ndarray) -> np.ndarray:
    """The point nearest (least squares) to every camera's optical axis, (3,).

    Falls back to the mean camera position when the axes are (nearly) parallel.
    """
    origins = c2w[:, :3, 3].astype(np.float64)
    dirs = c2w[:, :3, 2].astype(np.float64)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    projectors = np.eye(3)[None] - dirs[:, :, None] * dirs[:, None, :]  # (N, 3, 3)
    A = projectors.sum(0)
    b = (projectors @ origins[:, :, None]).sum(0)[:, 0]
    if np.linalg.cond(A) > 1e6:
        return origins.mean(0).astype(np.float32)
    return np.linalg.solve(A, b).astype(np.float32)


def estimate_up(c2w: np.ndarray) -> np.ndarray:
    """World up (3,) as the mean of the cameras' up vectors (-y in OpenCV axes)."""
    up = -c2w[:, :3, 1].astype(np.float64).mean(0)
    n = np.linalg.norm(up)
    return (up / n).astype(np.float32) if n > 1e-6 else np.array([0.0, 0.0, 1.0], np.float32)


def estimate_near_far(c2w: np.ndarray, center: np.ndarray) -> tuple[float, float]:
    """Depth range from the cameras alone: 0.5x to 1.5x their mean distance to the centre.

    For the lego scene (cameras 4.03 from the origin) this gives 2.02 and 6.05 (the course
    uses 2 and 6).
    """
    dist = float(np.mean(np.linalg.norm(c2w[:, :3, 3] - center, axis=1)))
    return 0.5 * dist, 1.5 * dist


def point_views(seen_by: list | None, train_names: list[str] | None) -> np.ndarray | None:
    """``(k, 2)`` int32 rows ``(point, train view)``: which of the train views see each
    point, from ``seen_by`` (per point, the names of the photos that see it; None: not
    known). Photos outside the train split are left out, so held-out photos teach nothing."""
    if seen_by is None or not train_names:
        return None
    index = {n: i for i, n in enumerate(train_names)}
    rows = [(p, index[n]) for p, names in enumerate(seen_by) for n in names if n in index]
    return np.array(rows, np.int32).reshape(-1, 2)
