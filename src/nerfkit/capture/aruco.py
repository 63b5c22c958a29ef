"""ArUco tags: dictionaries, tag sheets (layouts and OpenCV boards) and detection.

Conventions
-----------
* Pixels are OpenCV's: the centre of pixel (col, row) is at (col, row).
* A tag's own frame: origin at its centre, +x to the right of the printed tag, +y up the
  printed tag, +z out of the paper toward the viewer. Its corners, in the order OpenCV
  detects them (top-left, top-right, bottom-right, bottom-left of the printed tag), are
  ``(-s/2, s/2, 0), (s/2, s/2, 0), (s/2, -s/2, 0), (-s/2, -s/2, 0)``: the order
  ``cv2.SOLVEPNP_IPPE_SQUARE`` expects.
* A :class:`Layout` gives the corners of every tag of a sheet in one sheet frame with the
  same axes (tags printed on one sheet lie in ``z = 0`` and face ``+z``).

Layout files (JSON, metres) take one of these forms::

    {"tag_size": 0.06, "tags": {"0": {"center": [0, 0], "rotation_deg": 0}, "1": ...}}
    {"tags": {"0": [[x, y, z], [x, y, z], [x, y, z], [x, y, z]], ...}}      # corners, order above
    {"board": "grid", "markers_x": 2, "markers_y": 3, "marker_length": 0.06,
     "marker_separation": 0.02, "first_id": 0}                              # cv2.aruco.GridBoard
    {"board": "charuco", "squares_x": 5, "squares_y": 7, "square_length": 0.04,
     "marker_length": 0.03, "legacy": false}                                # cv2.aruco.CharucoBoard

Boards are centred on the board's centre. A camera file written by ``nerfkit calibrate``
is also a layout file (its ``"layout"`` entry, e.g. the layout it estimated).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..data.validate import check_count, check_number, check_numbers, short_repr
from ..errors import advice, fail

# Dictionaries tried when no tag is found, to suggest the right --dict. The _1000
# dictionaries contain the _50/_100/_250 ones as prefixes, so they find any id of
# their family (:func:`smallest_dictionary_for` then names the smallest holding it).
SEARCH_DICTIONARIES = [
    "DICT_4X4_1000",
    "DICT_5X5_1000",
    "DICT_6X6_1000",
    "DICT_7X7_1000",
    "DICT_ARUCO_ORIGINAL",
    "DICT_APRILTAG_36h11",
    "DICT_APRILTAG_25h9",
    "DICT_APRILTAG_16h5",
    "DICT_ARUCO_MIP_36h12",
]


# Boards with more markers (or squares) than this per side are refused.
MAX_BOARD_SIDE = 100
POSITIVE_LENGTH = "a positive length in metres"


def dictionary_names() -> list[str]:
    """Every predefined dictionary name OpenCV knows (e.g. ``DICT_4X4_50``)."""
    import cv2

    return sorted(n for n in dir(cv2.aruco) if n.startswith("DICT_"))


def dictionary_key(name: str) -> str:
    """``name`` as OpenCV spells it, upper-cased: "4x4_50" -> "DICT_4X4_50"."""
    key = name.strip().upper() if isinstance(name, str) else ""
    return key if key.startswith("DICT_") else "DICT_" + key


def get_dictionary(name: str, where: str = "--dict"):
    """The ``cv2.aruco.Dictionary`` called ``name`` (case-insensitive), or a NerfkitError."""
    import cv2

    key = dictionary_key(name)
    match = [n for n in dictionary_names() if n.upper() == key]
    if not match:
        raise fail(
            where,
            f"unknown ArUco dictionary {short_repr(name)}",
            "Use one of DICT_4X4_50, DICT_5X5_100, DICT_6X6_250, DICT_APRILTAG_36h11, ...",
        )
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, match[0]))


def smallest_dictionary_for(family: str, max_id: int) -> str:
    """``DICT_4X4_1000`` and max id 57 -> ``DICT_4X4_100``: the smallest size holding the id."""
    if not family.endswith("_1000"):
        return family
    base = family[: -len("1000")]
    for n in (50, 100, 250, 1000):
        if max_id < n:
            return f"{base}{n}"
    return family


def square_corners(size: float) -> np.ndarray:
    """(4, 3) corners of one tag of side ``size`` in its own frame, OpenCV corner order."""
    h = size / 2.0
    return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])


def quad_sides(corners) -> np.ndarray:
    """(...) the mean side of each quad of ``corners`` (..., 4, k), in their units (a tag's
    side in pixels or metres)."""
    c = np.asarray(corners)
    return np.linalg.norm(c - np.roll(c, -1, axis=-2), axis=-1).mean(-1)


def tag_pose_in_layout(corners: np.ndarray) -> np.ndarray:
    """(4, 4) transform from a tag's own frame to the layout frame, fitted (Kabsch) to its
    (4, 3) layout corners."""
    size = float(quad_sides(corners))
    src = square_corners(size)
    mu_s, mu_d = src.mean(0), corners.mean(0)
    U, _, Vt = np.linalg.svd((corners - mu_d).T @ (src - mu_s))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, mu_d - R @ mu_s
    return T


@dataclass
class Layout:
    """Where the tags of a sheet are, in the sheet's frame (metres).

    Attributes:
        tags: tag id -> (4, 3) corners in OpenCV corner order.
        charuco: for ChArUco boards, the cv2.aruco.CharucoBoard (then calibration and poses
            use its chessboard corners, far more precise than tag corners).
        charuco_corners: (M, 3) chessboard corners in the sheet frame (ChArUco only).
        spec: the JSON the layout came from (for writing it back).
        source: a description for messages.
    """

    tags: dict[int, np.ndarray]
    charuco: Any = None
    charuco_corners: np.ndarray | None = None
    spec: dict = field(default_factory=dict)
    source: str = ""

    @property
    def ids(self) -> list[int]:
        return sorted(self.tags)

    def corners(self) -> np.ndarray:
        """(n, 4, 3) float32 corners of every tag, by id: where the printed squares lie."""
        return np.stack([self.tags[i] for i in self.ids]).astype(np.float32)

    @property
    def tag_size(self) -> float:
        """Mean side length of the tags."""
        return float(np.mean([quad_sides(c) for c in self.tags.values()]))

    def max_height(self) -> float:
        """The largest distance of a corner from the plane z = 0."""
        return float(np.abs(np.concatenate(list(self.tags.values()))[:, 2]).max())

    def is_planar(self, tol: float = 1e-9) -> bool:
        """True when every corner lies in z = 0 (what calibrateCamera's initialisation needs)."""
        return self.max_height() <= tol

    def flattened(self) -> Layout:
        """The same tags with every corner on the plane z = 0 (an estimated layout's heights
        describe how the paper lay while it was photographed, not the printed sheet)."""
        return replace(self, tags={t: np.column_stack([c[:, :2], np.zeros(len(c))]) for t, c in self.tags.items()})

    def scaled(self, factor: float) -> Layout:
        """The same sheet ``factor`` times larger (its corners written out: the spec's sizes no longer hold)."""
        return replace(self, tags={t: c * factor for t, c in self.tags.items()}, spec={})

    def heights_json(self) -> dict | None:
        """Each tag's corners' heights (metres) by id, for a report beside the flattened
        layout; None for a flat layout."""
        if self.is_planar():
            return None
        return {str(t): np.round(c[:, 2], 7).tolist() for t, c in sorted(self.tags.items())}

    @staticmethod
    def single(tag_id: int, size: float) -> Layout:
        """One tag whose frame is the sheet frame."""
        return Layout(
            {int(tag_id): square_corners(size)},
            spec={"tag_size": size, "tags": {str(tag_id): {"center": [0, 0], "rotation_deg": 0}}},
            source=f"tag {tag_id}",
        )

    def match(self, det: Detection) -> tuple[np.ndarray, np.ndarray, list[int]]:
        """Object and image points of a detection's tags (or ChArUco corners) in this layout.

        Returns:
            ``(obj, img, ids)``: (n, 3) float32 sheet points, (n, 2) float32 pixels, and the
            tag ids used (charuco corner ids for ChArUco boards).
        """
        if self.charuco is not None:
            if det.charuco_ids is None or len(det.charuco_ids) == 0:
                return np.zeros((0, 3), np.float32), np.zeros((0, 2), np.float32), []
            assert self.charuco_corners is not None and det.charuco_corners is not None  # set with charuco
            obj = self.charuco_corners[det.charuco_ids]
            return obj.astype(np.float32), det.charuco_corners.astype(np.float32), [int(i) for i in det.charuco_ids]
        objs, imgs, used = [], [], []
        for i, tag_id in enumerate(det.ids):
            tag_id = int(tag_id)
            if tag_id in self.tags and list(det.ids).count(tag_id) == 1:
                objs.append(self.tags[tag_id])
                imgs.append(det.corners[i])
                used.append(tag_id)
        if not used:
            return np.zeros((0, 3), np.float32), np.zeros((0, 2), np.float32), []
        return (np.concatenate(objs).astype(np.float32), np.concatenate(imgs).astype(np.float32), used)

    def to_json(self) -> dict:
        """The layout as a layout-file dict (explicit corners for estimated layouts)."""
        if self.spec:
            return dict(self.spec)
        return {"tags": {str(k): np.round(v, 7).tolist() for k, v in sorted(self.tags.items())}}


def _board_to_layout_axes(points: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """OpenCV board frame (x right, y down the print, z into it) -> ours (y up, z out), centred."""
    p = np.asarray(points, np.float64).reshape(-1, 3) - centre
    return p * np.array([1.0, -1.0, -1.0])


def layout_from_json(spec: dict, where: str, dictionary: str, tag_size: float | None = None) -> Layout:
    """Build a :class:`Layout` from a layout-file dict (see the module docstring)."""
    if not isinstance(spec, dict):
        raise fail(where, "a layout must be a JSON object")
    if "layout" in spec:  # a camera file
        if not isinstance(spec["layout"], dict):
            raise fail(
                where,
                "this camera file holds no layout (it was calibrated with each tag on its own)",
                "Pass a layout file, or calibrate again without --per-tag",
            )
        return layout_from_json(spec["layout"], where, dictionary, tag_size)
    if spec.get("board") is not None:
        layout = _board_layout(spec, where, dictionary)
    else:
        layout = Layout(_tags_from_spec(spec, where, tag_size), spec=dict(spec), source=where)
    for tag_id, corners in layout.tags.items():
        _check_square(tag_id, corners, where)
    return layout


def _check_square(tag_id: int, corners: np.ndarray, where: str) -> None:
    sides = np.linalg.norm(corners - np.roll(corners, -1, axis=0), axis=1)
    if not sides.min() > 0 or sides.max() / sides.min() > 1.05:
        raise fail(
            where,
            f"tag {tag_id}'s corners are not a square (sides {np.round(sides, 4).tolist()})",
            "List corners in OpenCV order: top-left, top-right, bottom-right, bottom-left",
        )


def _tags_from_spec(spec: dict, where: str, tag_size: float | None) -> dict[int, np.ndarray]:
    """Tag id -> (4, 3) corners of a ``{"tags": ...}`` layout."""
    tags_spec = spec.get("tags")
    if not isinstance(tags_spec, dict) or not tags_spec:
        raise fail(where, 'a layout needs a non-empty "tags" object (tag id -> corners or centre) or a "board"')
    if "tag_size" in spec:
        check_number(spec["tag_size"], where, "tag_size", 0.0, expected=POSITIVE_LENGTH)
    default_size = spec.get("tag_size", tag_size)
    tags: dict[int, np.ndarray] = {}
    for key, value in tags_spec.items():
        try:
            tag_id = int(key)
        except ValueError:
            raise fail(where, f"tag id {short_repr(key)} is not an integer") from None
        if tag_id < 0 or tag_id in tags:
            raise fail(where, f"tag id {short_repr(key)} is negative or given twice")
        tags[tag_id] = _tag_corners(key, value, default_size, where)
    return tags


def _tag_corners(key: str, value, default_size, where: str) -> np.ndarray:
    """(4, 3) corners of one tag: ``{"center", "size", "rotation_deg"}`` or 4 corners [x, y, z]."""
    if not isinstance(value, dict):
        corners = check_numbers(value, where, f"tags.{key}")
        if corners.shape != (4, 3):
            raise fail(where, f"tag {key} must have 4 corners [x, y, z], got shape {corners.shape}")
        return corners
    size = value.get("size", default_size)
    if size is None or "center" not in value:
        raise fail(where, f'tag {key} needs "center" and a size ("size", top-level "tag_size" or --tag-size)')
    size = check_number(size, where, f"tags.{key}.size", 0.0, expected=POSITIVE_LENGTH)
    c = check_numbers(value["center"], where, f"tags.{key}.center").ravel()
    if c.size not in (2, 3):
        raise fail(where, f"'tags.{key}.center' must be 2 or 3 numbers, got {c.size}")
    a = np.deg2rad(check_number(value.get("rotation_deg", 0.0), where, f"tags.{key}.rotation_deg"))
    Rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    return square_corners(size) @ Rz.T + np.append(c[:2], c[2] if c.size == 3 else 0.0)


def _board_layout(spec: dict, where: str, dictionary: str) -> Layout:
    """The layout of an OpenCV GridBoard or CharucoBoard description."""
    import cv2

    board = spec["board"]
    if board not in ("grid", "charuco"):
        raise fail(where, f"unknown board type {short_repr(board)}", 'Use "grid" or "charuco"')
    d = get_dictionary(spec.get("dictionary", dictionary), where)
    try:
        b, centre = _grid_board(spec, where, d) if board == "grid" else _charuco_board(spec, where, d)
        obj = np.asarray(b.getObjPoints(), np.float64)  # (n, 4, 3)
        ids = b.getIds().ravel()
        chessboard = b.getChessboardCorners() if board == "charuco" else None
    except KeyError as e:
        raise fail(where, f"board '{board}' is missing the key {e}") from None
    except (cv2.error, SystemError, ValueError, TypeError, OverflowError, AttributeError, MemoryError) as e:
        raise fail(where, f"invalid board description ({type(e).__name__}: {short_repr(str(e))})") from None
    if centre is None:
        pts = obj.reshape(-1, 3)
        centre = (pts.min(0) + pts.max(0)) / 2.0
    tags = {int(i): _board_to_layout_axes(c, centre) for i, c in zip(ids, obj)}
    layout = Layout(tags, spec=dict(spec), source=f"{where} ({board} board)")
    if board == "charuco":
        assert chessboard is not None
        layout.charuco = b
        layout.charuco_corners = _board_to_layout_axes(chessboard, centre)
    return layout


def _grid_board(spec: dict, where: str, d):
    """(cv2.aruco.GridBoard, None): markers_x x markers_y tags, ids from first_id."""
    import cv2

    nx = check_count(spec["markers_x"], where, "markers_x", 1, MAX_BOARD_SIDE)
    ny = check_count(spec["markers_y"], where, "markers_y", 1, MAX_BOARD_SIDE)
    length = check_number(spec["marker_length"], where, "marker_length", 0.0, expected=POSITIVE_LENGTH)
    gap = check_number(spec["marker_separation"], where, "marker_separation", 0.0, expected=POSITIVE_LENGTH)
    first = check_count(spec.get("first_id", 0), where, "first_id", 0, len(d.bytesList))
    _check_ids_fit(first, nx * ny, d, where)
    return cv2.aruco.GridBoard((nx, ny), length, gap, d, np.arange(first, first + nx * ny)), None


def _charuco_board(spec: dict, where: str, d):
    """(cv2.aruco.CharucoBoard, its centre): squares_x x squares_y squares, a tag in every other one."""
    import cv2

    sx = check_count(spec["squares_x"], where, "squares_x", 2, MAX_BOARD_SIDE)
    sy = check_count(spec["squares_y"], where, "squares_y", 2, MAX_BOARD_SIDE)
    square = check_number(spec["square_length"], where, "square_length", 0.0, expected=POSITIVE_LENGTH)
    marker = check_number(
        spec["marker_length"],
        where,
        "marker_length",
        0.0,
        square,
        f"a positive length in metres, smaller than square_length {square:g}",
    )
    legacy = spec.get("legacy", False)
    if not isinstance(legacy, bool):
        raise fail(where, f"'legacy' is {short_repr(legacy)}, expected true or false")
    _check_ids_fit(0, sx * sy // 2, d, where)
    b = cv2.aruco.CharucoBoard((sx, sy), square, marker, d)
    b.setLegacyPattern(legacy)
    return b, np.array([sx * square / 2, sy * square / 2, 0.0])


def _check_ids_fit(first: int, count: int, d, where: str) -> None:
    """The board's tag ids first .. first + count - 1 must exist in the dictionary ``d``."""
    size = len(d.bytesList)
    if first + count > size:
        raise fail(
            where,
            f"the board needs tag ids {first} to {first + count - 1}, but its dictionary holds ids 0 to {size - 1}",
            "Use a smaller board, a lower first_id or a larger dictionary",
        )


def load_layout(path: str | Path, dictionary: str, tag_size: float | None = None) -> Layout:
    """Read a layout file (or a camera file holding a layout)."""
    path = Path(path)
    from ..config import load_json

    spec = load_json(path, "no such layout file", "Check the --layout path")
    with advice("Fix the layout file; its forms are described at the top of nerfkit/capture/aruco.py"):
        return layout_from_json(spec, str(path), dictionary, tag_size)


@dataclass
class Detection:
    """Tags found in one upright photo (OpenCV pixel coordinates, full resolution).

    Attributes:
        width, height: image size in pixels.
        ids: (n,) tag ids.
        corners: (n, 4, 2) tag corners, OpenCV corner order.
        sharpness: variance of the Laplacian of a ~1000 px copy (low = blurred).
        charuco_ids, charuco_corners: (m,) and (m, 2) ChArUco chessboard corners, or None.
    """

    width: int
    height: int
    ids: np.ndarray
    corners: np.ndarray
    sharpness: float = 0.0
    charuco_ids: np.ndarray | None = None
    charuco_corners: np.ndarray | None = None

    def to_json(self) -> dict:
        # Corners unrounded (float64 round-trips exactly through JSON): a cached re-run gives the same calibration.
        d = {
            "width": self.width,
            "height": self.height,
            "ids": [int(i) for i in self.ids],
            "corners": np.asarray(self.corners, np.float64).tolist(),
            "sharpness": float(self.sharpness),
        }
        if self.charuco_ids is not None:
            d["charuco_ids"] = [int(i) for i in self.charuco_ids]
            d["charuco_corners"] = np.asarray(self.charuco_corners, np.float64).tolist()
        return d

    def turned(self, quarter_turns: int) -> Detection:
        """The same detection in the photo turned clockwise by ``quarter_turns`` x 90
        degrees (a W x H photo turned once is H x W; a pixel (x, y) moves to (H - 1 - y, x)).
        Each corner keeps its place in the tag's corner order."""
        det = self
        for _ in range(quarter_turns % 4):

            def turn(p, h=det.height):
                p = np.asarray(p, np.float64)
                return np.stack([h - 1 - p[..., 1], p[..., 0]], axis=-1)

            det = Detection(
                det.height,
                det.width,
                det.ids,
                turn(det.corners),
                det.sharpness,
                det.charuco_ids,
                None if det.charuco_corners is None else turn(det.charuco_corners),
            )
        return det

    def without(self, tags) -> Detection:
        """The same detection without the tags of ids ``tags``."""
        keep = ~np.isin(self.ids, list(tags))
        return replace(self, ids=self.ids[keep], corners=self.corners[keep])

    def resized(self, width: int, height: int) -> Detection:
        """The same detection in the photo resized to ``width`` x ``height`` (pixel centres at
        integers: a pixel x moves to (x + 0.5) s - 0.5)."""
        s = np.array([width / self.width, height / self.height])

        def scale(p):
            return (np.asarray(p, np.float64) + 0.5) * s - 0.5

        charuco = None if self.charuco_corners is None else scale(self.charuco_corners)
        return Detection(width, height, self.ids, scale(self.corners), self.sharpness, self.charuco_ids, charuco)

    @staticmethod
    def from_json(d: dict) -> Detection:
        ids = np.asarray(d["ids"], np.int64).reshape(-1)
        corners = np.asarray(d["corners"], np.float64).reshape(-1, 4, 2)
        if corners.shape[0] != ids.shape[0]:
            raise ValueError("ids and corners differ in length")
        det = Detection(int(d["width"]), int(d["height"]), ids, corners, float(d.get("sharpness", 0.0)))
        if "charuco_ids" in d:
            det.charuco_ids = np.asarray(d["charuco_ids"], np.int64).reshape(-1)
            det.charuco_corners = np.asarray(d["charuco_corners"], np.float64).reshape(-1, 2)
        return det


def make_detector(dictionary: str, board: Layout | None = None):
    """An ArUco (or ChArUco) detector refining corners to sub-pixel at detection scale."""
    import cv2

    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    if board is not None and board.charuco is not None:
        return cv2.aruco.CharucoDetector(board.charuco, cv2.aruco.CharucoParameters(), params)
    return cv2.aruco.ArucoDetector(get_dictionary(dictionary), params)


def to_gray(image: np.ndarray) -> np.ndarray:
    """(H, W) uint8 luminance of an (H, W, 3) RGB or (H, W) image."""
    import cv2

    return image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)


def reduced(gray: np.ndarray, side: int) -> np.ndarray:
    """``gray``, or a copy shrunk to ``side`` pixels on its long side when it is larger."""
    import cv2

    s = min(1.0, side / max(gray.shape))
    return cv2.resize(gray, None, fx=s, fy=s, interpolation=cv2.INTER_AREA) if s < 1 else gray


def sharpness(gray: np.ndarray) -> float:
    """Variance of the Laplacian on a copy at most 1000 px wide: comparable across sizes."""
    import cv2

    return float(cv2.Laplacian(reduced(gray, 1000), cv2.CV_64F).var())


def _refine(gray: np.ndarray, pts: np.ndarray, win: int, max_shift: float) -> np.ndarray:
    """cornerSubPix at full resolution; points that move more than ``max_shift`` keep their
    input position (the refinement latched onto something else)."""
    import cv2

    h, w = gray.shape
    p = pts.reshape(-1, 1, 2).astype(np.float32).copy()
    inside = (p[:, 0, 0] > win + 1) & (p[:, 0, 0] < w - win - 2) & (p[:, 0, 1] > win + 1) & (p[:, 0, 1] < h - win - 2)
    if not inside.any():
        return pts
    q = p[inside].copy()
    cv2.cornerSubPix(gray, q, (win, win), (-1, -1), (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-3))
    moved = np.linalg.norm(q - p[inside], axis=2)[:, 0]
    q[moved > max_shift] = p[inside][moved > max_shift]
    p[inside] = q
    return p.reshape(pts.shape).astype(np.float64)


def _edge_points(
    gray: np.ndarray,
    p: np.ndarray,
    q: np.ndarray,
    outward: np.ndarray,
    reach: float,
    frac: tuple[float, float] = (0.15, 0.85),
) -> np.ndarray:
    """Sub-pixel points (k, 2) on the straight edge from ``p`` to ``q`` of a dark tag on white
    paper: along each of up to 60 normals, where the intensity crosses halfway between the
    dark inside and the bright outside (unbiased by symmetric blur)."""
    import cv2

    length = float(np.linalg.norm(q - p))
    t = (q - p) / length
    m = int(np.clip(length, 6, 60))
    base = p[None] + np.linspace(*frac, m)[:, None] * length * t[None]  # (m, 2)
    offs = np.arange(-reach, reach + 1e-9, 0.25)
    pts = base[:, None, :] + offs[None, :, None] * outward[None, None, :]  # (m, o, 2)
    prof = cv2.remap(
        gray,
        pts[..., 0].astype(np.float32),
        pts[..., 1].astype(np.float32),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    )
    q4 = max(1, len(offs) // 4)
    lo, hi = prof[:, :q4].mean(1), prof[:, -q4:].mean(1)
    out = []
    for i in np.flatnonzero(hi - lo > 10):
        pr, mid = prof[i], (lo[i] + hi[i]) / 2
        j = np.flatnonzero((pr[:-1] < mid) & (pr[1:] >= mid))
        if len(j) != 1:  # noise or a neighbouring edge: skip this normal
            continue
        j = j[0]
        f = (mid - pr[j]) / (pr[j + 1] - pr[j])
        out.append(base[i] + (offs[j] + f * 0.25) * outward)
    return np.asarray(out, np.float64).reshape(-1, 2)


def _fit_edge_line(pts: np.ndarray, length: float, min_keep: float = 0.5) -> tuple[np.ndarray, np.ndarray] | None:
    """(point, direction) of the straight line through edge points (k, 2), ordered along
    the edge, refitted without outliers; None when the edge is not straight enough to trust
    (fewer than ``min_keep`` of the points agree, they span less than a quarter of the edge, or
    they scatter more than 0.2 px + 0.2% of the edge length).

    An object over one end of the edge bends that part: the fit starts from the whole edge
    and from each end's 60%, and keeps the start most points agree with.
    """
    import cv2

    if len(pts) < 6:
        return None
    k = len(pts)
    enough, end = max(6, min_keep * k), max(6, int(0.6 * k))
    best = None
    for start in (slice(None), slice(0, end), slice(k - end, k)):
        keep = np.zeros(k, bool)
        keep[start] = True
        for _ in range(4):
            vx, vy, lx, ly = cv2.fitLine(pts[keep].astype(np.float32), cv2.DIST_L2, 0, 0.01, 0.01).ravel()
            r = (pts[:, 0] - lx) * vy - (pts[:, 1] - ly) * vx  # signed distance to the line
            sigma = 1.4826 * np.median(np.abs(r[keep]))
            new = np.abs(r) < max(0.25, 3.0 * sigma)
            if new.sum() < enough or np.array_equal(new, keep):
                break
            keep = new
        if new.sum() < enough or (best is not None and keep.sum() <= best[0]):
            continue
        along = pts[keep] @ np.array([vx, vy])
        if np.sqrt(np.mean(r[keep] ** 2)) > 0.2 + 0.002 * length or np.ptp(along) < 0.25 * length:
            continue
        best = (int(keep.sum()), np.array([lx, ly], np.float64), np.array([vx, vy], np.float64))
    return None if best is None else (best[1], best[2])


# How far (in modules, the tag's cells) the edge lines may move a detector's corner. An object
# over a corner bends the detector's outline toward it by up to a module;
# the lines, fitted to the visible part of each edge, put the corner back.
MAX_CORNER_MOVE = 1.5


def refine_corners_by_edges(
    gray: np.ndarray, corners: np.ndarray, marker_bits: int = 4, passes: int = 2
) -> np.ndarray | None:
    """Refine a tag's 4 corners (4, 2) by fitting lines to its 4 outer edges and intersecting
    them; None when an edge cannot be measured.

    Halves the corner error of cornerSubPix on our synthetic photos (0.19 -> 0.08 px RMS)
    and removes its inward bias at blurred corners. Each line needs only part of its edge
    (:func:`_fit_edge_line`), so a corner under the object is found where the visible
    edges meet, and a photo whose tag the object partly hides is still posed by it
    (benchmarks/capture_real.py counts the photos posed).
    """
    c = np.asarray(corners, np.float64).copy()
    side = float(quad_sides(c))
    reach = max(1.5, 0.45 * side / (marker_bits + 2))  # stay inside the black border
    x0, y0 = np.floor(c.min(0) - reach - 3).astype(int)
    x1, y1 = np.ceil(c.max(0) + reach + 3).astype(int)
    h, w = gray.shape
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, w - 1), min(y1, h - 1)
    if x1 - x0 < 4 or y1 - y0 < 4:
        return None
    crop = gray[y0 : y1 + 1, x0 : x1 + 1].astype(np.float32)
    c -= (x0, y0)
    start = c.copy()
    for _ in range(passes):
        lines = []
        centre = c.mean(0)
        for k in range(4):
            p, q = c[k], c[(k + 1) % 4]
            t = (q - p) / np.linalg.norm(q - p)
            n = np.array([t[1], -t[0]])
            if np.dot((p + q) / 2 - centre, n) < 0:
                n = -n
            pts = _edge_points(crop, p, q, n, reach)
            line = _fit_edge_line(pts, float(np.linalg.norm(q - p)))
            if line is None:
                return None
            lines.append(line)
        new = np.zeros((4, 2))
        for k in range(4):  # corner k joins edge k-1 (into it) and edge k (out of it)
            (p1, d1), (p2, d2) = lines[(k - 1) % 4], lines[k]
            M = np.column_stack([d1, -d2])
            if abs(np.linalg.det(M)) < 1e-6:
                return None
            new[k] = p1 + np.linalg.solve(M, p2 - p1)[0] * d1
        c = new
    if np.abs(c - start).max() > max(2.0, MAX_CORNER_MOVE * side / (marker_bits + 2)):
        return None  # the lines latched onto something else
    return c + (x0, y0)


def careful_detector(dictionary: str):
    """A slower, more permissive ArUco detector for a second pass on photos where
    :func:`make_detector` found nothing: finer adaptive-threshold steps, smaller and less
    square-looking candidates accepted (blur, steep angles, small tags). Its extra finds
    can include false ids: callers keep only ids the capture is known to hold."""
    import cv2

    p = cv2.aruco.DetectorParameters()
    p.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    p.adaptiveThreshWinSizeMin, p.adaptiveThreshWinSizeMax, p.adaptiveThreshWinSizeStep = 3, 63, 4
    p.minMarkerPerimeterRate = 0.01
    p.polygonalApproxAccuracyRate = 0.06
    p.perspectiveRemovePixelPerCell = 8
    p.perspectiveRemoveIgnoredMarginPerCell = 0.2
    p.minCornerDistanceRate = 0.02
    p.minDistanceToBorder = 1
    return cv2.aruco.ArucoDetector(get_dictionary(dictionary), p)


def detect_careful(image: np.ndarray, dictionary: str, detect_side: int = 2000, marker_bits: int = 4) -> Detection:
    """Second detection pass: :func:`careful_detector` at the first pass's scale, at full
    resolution, and upscaled 2x (3x) for small photos, each also on a contrast-equalised
    (CLAHE) copy; the first of these that finds a tag wins. Corners are refined on the
    original full-resolution image as in :func:`detect`."""
    import cv2

    gray = to_gray(image)
    long_side = max(gray.shape)
    sides = [min(detect_side, long_side), long_side] + [k * long_side for k in (2, 3) if k * long_side <= 1500]
    clahe = cv2.createCLAHE(2.0, (8, 8))
    det = careful_detector(dictionary)
    found = None
    for side in dict.fromkeys(sides):
        for prepare in (None, clahe.apply):
            found = detect(gray, det, side, marker_bits, upscale=True, prepare=prepare)
            if len(found.ids):
                return found
    assert found is not None  # sides holds at least one size
    return found


def detect(
    image: np.ndarray, detector, detect_side: int = 2000, marker_bits: int = 4, upscale: bool = False, prepare=None
) -> Detection:
    """Find tags in an upright photo: detect on a copy at most ``detect_side`` pixels on its
    long side, then refine every corner on the full-resolution image, by fitting lines to
    the tag's edges (:func:`refine_corners_by_edges`), else with cornerSubPix.

    Args:
        image: (H, W, 3) RGB or (H, W) uint8.
        detector: from :func:`make_detector`.
        marker_bits: the dictionary's marker size (4 for 4x4), to size the refinement window.
        upscale: also enlarge photos smaller than ``detect_side`` (second pass).
        prepare: optional function applied to the detection copy (e.g. contrast equalisation).

    Returns:
        a :class:`Detection` in full-resolution OpenCV pixel coordinates.
    """
    import cv2

    gray = to_gray(image)
    h, w = gray.shape
    s = detect_side / max(h, w) if upscale else min(1.0, detect_side / max(h, w))
    small = (
        gray
        if s == 1
        else cv2.resize(
            gray,
            (max(1, round(w * s)), max(1, round(h * s))),
            interpolation=cv2.INTER_AREA if s < 1 else cv2.INTER_CUBIC,
        )
    )
    if prepare is not None:
        small = prepare(small)
    sx, sy = small.shape[1] / w, small.shape[0] / h

    def up(p: np.ndarray) -> np.ndarray:  # small-image pixel -> full-image pixel (OpenCV centres)
        return (p + 0.5) / np.array([sx, sy]) - 0.5

    charuco_ids = charuco_corners = None
    if isinstance(detector, cv2.aruco.CharucoDetector):
        ch_corners, ch_ids, corners, ids = detector.detectBoard(small)
        if ch_ids is not None and len(ch_ids):
            charuco_ids = ch_ids.ravel().astype(np.int64)
            charuco_corners = up(ch_corners.reshape(-1, 2).astype(np.float64))
            if s < 1:
                sq = detector.getBoard().getSquareLength() / detector.getBoard().getMarkerLength()
                side_px = _median_side(corners, sx) if corners else 40.0 / sx
                win = int(np.clip(0.25 * side_px * sq, 2, 30))
                charuco_corners = _refine(gray, charuco_corners, win, max_shift=2.0 / s)
    else:
        corners, ids, _ = detector.detectMarkers(small)
    if ids is None or len(ids) == 0:
        return Detection(
            w, h, np.zeros(0, np.int64), np.zeros((0, 4, 2)), sharpness(gray), charuco_ids, charuco_corners
        )
    ids = ids.ravel().astype(np.int64)
    quads = up(np.asarray(corners, np.float64).reshape(-1, 4, 2))
    for i in range(len(ids)):
        refined = refine_corners_by_edges(gray, quads[i], marker_bits)
        if refined is not None:
            quads[i] = refined
        elif s != 1:  # the detector refined at its scale only
            side = float(quad_sides(quads[i]))
            module = side / (marker_bits + 2)
            win = int(np.clip(round(0.4 * module), 2, 30))
            quads[i] = _refine(gray, quads[i], win, max_shift=min(0.5 * module, 2.0 / s))
    return Detection(w, h, ids, quads, sharpness(gray), charuco_ids, charuco_corners)


def _median_side(corners, scale: float) -> float:
    c = np.asarray(corners, np.float64).reshape(-1, 4, 2)
    return float(np.median(np.linalg.norm(c - np.roll(c, -1, axis=1), axis=2))) / scale


def marker_bits(dictionary: str) -> int:
    return int(get_dictionary(dictionary).markerSize)


def search_detector(name: str):
    """A plain ArUco detector for :class:`DictionarySearch` (no corner refinement: ids only)."""
    import cv2

    return cv2.aruco.ArucoDetector(get_dictionary(name), cv2.aruco.DetectorParameters())


@dataclass
class DictionaryFind:
    """What one dictionary family of :data:`SEARCH_DICTIONARIES` finds in some photos.

    Attributes:
        name: the smallest dictionary of the family holding every id of ``ids`` (the --dict to pass).
        ids: the ids seen in at least half as many photos as the most seen one.
        shown_in: the indices (in the order searched) of the photos showing one of ``ids``.
        searched: how many photos were searched.
        misreads: ids seen in fewer photos (a large dictionary reads some in textures).
    """

    name: str
    ids: list[int]
    shown_in: list[int]
    searched: int
    misreads: list[int]

    @property
    def photos(self) -> int:
        """How many of the photos searched show one of ``ids``."""
        return len(self.shown_in)

    @property
    def in_most(self) -> bool:
        """Whether at least half of the photos searched show it and, of more than one, two:
        tags, not a pattern misread as one (a large dictionary's misreads are in one photo or two
        of thirty)."""
        return 2 * self.photos >= self.searched and self.photos >= min(2, self.searched)


class DictionarySearch:
    """Which tags the dictionaries of :data:`SEARCH_DICTIONARIES` (but ``skip``) find, one photo at a time."""

    def __init__(self, skip: str = "", detect_side: int = 1600):
        self.detect_side = detect_side
        names = [n for n in SEARCH_DICTIONARIES if n.upper() != dictionary_key(skip)]
        self.detectors = {n: search_detector(n) for n in names}
        self.seen: dict[str, list[set[int]]] = {n: [] for n in names}  # the ids of each photo searched
        self.names: list[str] = []  # the photos searched, in order

    @property
    def photos(self) -> int:
        """How many photos were searched."""
        return len(self.names)

    def add(self, image: np.ndarray, name: str = "") -> None:
        """Search one (H, W, 3) RGB or (H, W) photo called ``name``, on a copy at most ``detect_side`` wide."""
        small = reduced(to_gray(image), self.detect_side)
        for family, det in self.detectors.items():
            _, got, _ = det.detectMarkers(small)
            self.seen[family].append(set() if got is None else {int(i) for i in got.ravel()})
        self.names.append(name)

    def finds(self) -> list[DictionaryFind]:
        """The families that found tags, those seen in the most photos first."""
        found = [f for f in (_find(family, per_photo) for family, per_photo in self.seen.items()) if f]
        return sorted(found, key=lambda f: (-f.photos, -len(f.ids)))


def _find(family: str, per_photo: list[set[int]]) -> DictionaryFind | None:
    """``family``'s find in photos showing ``per_photo`` ids, or None when it found none."""
    counts = Counter(i for ids in per_photo for i in ids)
    if not counts:
        return None
    top = max(counts.values())
    ids = sorted(i for i, n in counts.items() if 2 * n >= top)
    shown_in = [k for k, seen in enumerate(per_photo) if seen & set(ids)]
    misreads = sorted(set(counts) - set(ids))
    return DictionaryFind(smallest_dictionary_for(family, max(ids)), ids, shown_in, len(per_photo), misreads)
