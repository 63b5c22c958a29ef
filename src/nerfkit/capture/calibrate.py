"""Camera calibration from photos of ArUco tags (``cv2.calibrateCamera``).

Three kinds of targets:

* a known layout (a layout file or an OpenCV GridBoard/ChArUco board): one view per photo
  with every visible tag's corners at their printed sheet positions (a sheet of several
  tags also gets the paper's heights, as below);
* several tags with an unknown layout: the layout is *estimated*. Each tag first serves as
  its own planar target for a rough calibration; relative tag poses (IPPE) give a first
  layout (the tags share the sheet plane); then calibration and layout are refined in
  turn: calibrate with the layout, back-project every tag corner onto the sheet plane of
  each photo, fit each tag's square to the averaged points, and repeat. Printed paper is
  not flat (ink cockles it; it lies on the table in gentle waves), so then each corner's
  height above the sheet's plane is triangulated from every photo that sees it, in turns
  with calibration (:func:`refine_heights`): a printed sheet's corners can lie a millimetre
  or more off its plane, and fitting their heights lowers the held-out reprojection error
  (benchmarks/capture_real.py; figures in BENCHMARKS.md). Different tags never share
  3D corners (that mistake silently ruins a calibration);
* ``per_tag=True`` (or a single tag): every tag in every photo is its own planar view.

The layout is estimated with a k1-only model and then frozen, so it cannot absorb the
camera chosen afterwards (nor the reverse). The camera is chosen whole by k-fold
cross-validation over photos (:func:`select_camera`): every combination of a distortion
model (none, k1, k1k2, k1k2p1p2, k1k2p1p2k3), the principal point (centred or fitted) and
the aspect (square pixels or fx, fy fitted) is fitted and cross-validated on its own, so no
parameter is kept from a camera that was then rejected. A camera is eligible when it passes
:func:`~.distortion.distortion_check` and its folds agree at the frame's edges within what
is at stake there (:func:`edge_limit`: twice the larger of its own held-out error and the
simpler model's held-out error at the photos' edges), and its K is a lens's
(:func:`~.camera.implausible`: a fitted principal point within 15% of the frame of the
centre, fitted pixels within 10% of square). From the best eligible camera the
choice is simplified (a simpler model, a centred principal point, square pixels: what
phone cameras have) while the simpler camera holds out within a small margin of the best.

Photos whose RMS error is far above the median are dropped and the camera recalibrated.
Because a low RMS does not prove a good calibration, :func:`sanity_checks` compares the
result with what phone cameras are like (square pixels, centred principal point, the EXIF
focal length) and warns when they disagree.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from typing import Protocol

import numpy as np

from ..config import flag_of, option
from ..errors import NerfkitError, fail
from .aruco import Layout, quad_sides, square_corners
from .camera import FILM_DIAGONAL_MM, exif_fx, image_centre, implausible
from .distortion import distortion_check, fold_spread, frame_displacement, heldout_errors
from .photos import PhotoRecord, frame_turns

# Per-tag calibration: at most this many tag views (cost grows as views^3).
MAX_TAG_VIEWS = 150
DIST_MODELS = ("k1k2p1p2k3", "k1k2p1p2", "k1k2", "k1", "none")
SIMPLEST_FIRST = tuple(reversed(DIST_MODELS))
# Coefficients each model fits.
DIST_PARAMS = {"none": 0, "k1": 1, "k1k2": 2, "k1k2p1p2": 4, "k1k2p1p2k3": 5}
# The photos' edges: this outermost share of the tag corners (by distance from the image
# centre), where a simpler model's held-out error is what a less stable one would correct.
EDGE_SHARE = 0.1
# A model is unstable at the frame's edges when its folds disagree there by more than this
# many times the error at stake: its own held-out error, or the simpler model's at the edges.
EDGE_FACTOR = 2.0
# The layout is estimated with this model, then frozen while the distortion model is chosen.
LAYOUT_MODEL = "k1"
# What phone cameras are like, kept unless freeing it holds out clearly better:
# config field -> (the constrained value, the free value).
CONSTRAINTS = {"principal_point": ("centre", "free"), "aspect": ("square", "free")}


@dataclass
class CalibrateConfig:
    """Calibration options (each becomes a ``nerfkit calibrate`` flag)."""

    dist_model: str = option(
        "auto",
        "distortion coefficients to estimate; auto: chosen by cross-validation over "
        "photos (the simplest model that generalises and stays plausible out to the image "
        "corners)",
        choices=["auto", *DIST_MODELS],
    )
    folds: int = option(5, "cross-validation folds over photos for the auto choices", min=2)
    select_tolerance: float = option(
        0.05,
        "the auto choices keep a simpler camera (a simpler distortion model, "
        "a centred principal point, square pixels) when its held-out error is within "
        "this fraction of the best camera's; a simpler distortion model also within "
        "this many pixels",
        min=0,
    )
    principal_point: str = option(
        "auto",
        "centre: keep the principal point at the image centre (phone lenses are "
        "nearly centred); free: fit it; auto: chosen with the distortion model and the "
        "aspect, centred unless fitting it lowers the held-out error by more than the "
        "fraction --select-tolerance and keeps it within 15% of the frame of the centre",
        choices=["auto", *CONSTRAINTS["principal_point"]],
    )
    aspect: str = option(
        "auto",
        "square: fx = fy (phone pixels are square); free: fit both; auto: chosen with the "
        "distortion model and the principal point, square unless fitting both lowers the held-out "
        "error by more than the fraction --select-tolerance and keeps fx / fy within 10% of 1",
        choices=["auto", *CONSTRAINTS["aspect"]],
    )
    outlier_factor: float = option(
        3.0, "drop photos whose reprojection error exceeds this many times the median, then recalibrate", above=0
    )
    per_tag: bool = option(False, "treat each tag as its own planar target instead of estimating the sheet layout")
    min_photos: int = option(5, "refuse to calibrate from fewer usable photos", min=3)


class PosedViews(Protocol):
    """What :func:`corner_rays` reads of a fit: the camera and each named view's pose
    (sheet -> camera). A :class:`Fit` is one; so are photos posed on a known camera."""

    K: np.ndarray
    dist: np.ndarray
    keys: list[str]
    rvecs: list[np.ndarray]
    tvecs: list[np.ndarray]


@dataclass
class Fit:
    """One calibrateCamera result over named views.

    Attributes:
        K: (3, 3), dist: (5,), rms: overall RMS (px).
        keys: names of the views used; rvecs/tvecs: their poses (sheet -> camera).
        errors: view name -> RMS error (px), for the views used.
        dropped: view name -> reason, for views rejected as outliers.
        std: standard deviations of fx, fy, cx, cy (px).
    """

    K: np.ndarray
    dist: np.ndarray
    rms: float
    keys: list[str]
    rvecs: list[np.ndarray]
    tvecs: list[np.ndarray]
    errors: dict[str, float]
    dropped: dict[str, str] = field(default_factory=dict)
    std: np.ndarray = field(default_factory=lambda: np.zeros(4))
    rounds: list[str] = field(default_factory=list)


def calib_flags(cfg: CalibrateConfig, model: str | None = None) -> int:
    """cv2.CALIB_* flags of a distortion model (default: the config's; "auto" is not a model).
    The principal point and the aspect ratio are fixed only when the config says "centre"
    and "square" (with a guess K0, at :func:`constrained_guess`'s values)."""
    import cv2

    flags = 0
    model = model or cfg.dist_model
    if model not in DIST_MODELS:
        raise ValueError(f"not a distortion model: {model!r}")
    if model != "k1k2p1p2k3":
        flags |= cv2.CALIB_FIX_K3
    if model in ("k1k2", "k1", "none"):
        flags |= cv2.CALIB_ZERO_TANGENT_DIST
    if model in ("k1", "none"):
        flags |= cv2.CALIB_FIX_K2
    if model == "none":
        flags |= cv2.CALIB_FIX_K1
    if cfg.aspect == "square":
        flags |= cv2.CALIB_FIX_ASPECT_RATIO
    if cfg.principal_point == "centre":
        flags |= cv2.CALIB_FIX_PRINCIPAL_POINT
    return flags


def constrained_guess(K0: np.ndarray | None, size: tuple[int, int], cfg: CalibrateConfig) -> np.ndarray | None:
    """An initial K (3, 3) as the config's constraints want it: the principal point at
    :func:`~.camera.image_centre` for "centre"; fy = fx for "square". None stays None."""
    if K0 is None:
        return None
    K0 = K0.copy()
    if cfg.principal_point == "centre":
        K0[0, 2], K0[1, 2] = image_centre(*size)
    if cfg.aspect == "square":
        K0[1, 1] = K0[0, 0]
    return K0


def fit_views(
    views: list[tuple[str, np.ndarray, np.ndarray]],
    size: tuple[int, int],
    flags: int,
    outlier_factor: float = 3.0,
    K0: np.ndarray | None = None,
    min_views: int = 3,
    floor_px: float = 0.5,
    max_rounds: int = 5,
    lean: bool = False,
) -> Fit:
    """calibrateCamera on named views, dropping outlier views and recalibrating.

    Args:
        views: ``(name, obj (n, 3), img (n, 2))`` with n >= 4 per view.
        size: (width, height).
        flags: cv2.CALIB_* flags; K0 (3, 3) turns on CALIB_USE_INTRINSIC_GUESS.
        outlier_factor: a view is an outlier when its RMS exceeds
            ``max(outlier_factor * median, median + floor_px)``.
        lean: plain calibrateCamera (the same camera, about 3x faster): no per-view errors
            (``errors`` stays empty), no standard deviations, no outlier rounds.
    """
    import cv2

    views = list(views)
    dropped: dict[str, str] = {}
    rounds: list[str] = []
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-10)
    for _ in range(max_rounds + 1):
        if len(views) < min_views:
            raise fail(
                "calibration",
                f"only {len(views)} usable views (need at least {min_views})",
                "Take more photos of the tag sheet from different angles",
            )
        objs = [v[1].astype(np.float32) for v in views]
        imgs = [v[2].astype(np.float32).reshape(-1, 1, 2) for v in views]
        f = flags
        if K0 is not None:
            f |= cv2.CALIB_USE_INTRINSIC_GUESS
            K_init = K0.copy()
        else:
            K_init = np.eye(3)
        if f & cv2.CALIB_FIX_ASPECT_RATIO and K0 is None:
            K_init = np.eye(3)  # aspect ratio fx/fy = 1 is then kept
        try:
            if lean:
                rms, K, dist, rvecs, tvecs = cv2.calibrateCamera(
                    objs, imgs, size, K_init, np.zeros(5), flags=f, criteria=crit
                )
                return Fit(
                    K,
                    dist.ravel()[:5].astype(np.float64),
                    float(rms),
                    [v[0] for v in views],
                    list(rvecs),
                    list(tvecs),
                    {},
                )
            rms, K, dist, rvecs, tvecs, std_i, _, per_view = cv2.calibrateCameraExtended(
                objs, imgs, size, K_init, np.zeros(5), flags=f, criteria=crit
            )
        except cv2.error as e:
            raise fail(
                "calibration",
                f"OpenCV could not calibrate ({str(e).strip().splitlines()[-1]})",
                "Take photos from more varied angles (tilted 20-60 degrees, not only head-on)",
            ) from None
        errs = per_view.ravel()
        med = float(np.median(errs))
        thr = max(outlier_factor * med, med + floor_px)
        bad = errs > thr
        if not bad.any() or outlier_factor <= 0:
            break
        for i in np.flatnonzero(bad):
            dropped[views[i][0]] = (
                f"outlier: reprojection error {errs[i]:.2f} px > {thr:.2f} px "
                f"({outlier_factor:g} x median {med:.2f} px)"
            )
        rounds.append(
            f"rms {rms:.3f} px with {len(views)} views; dropped {int(bad.sum())} outlier(s) "
            f"above {thr:.2f} px and recalibrated"
        )
        views = [v for v, b in zip(views, bad) if not b]
    std = np.asarray(std_i, np.float64).ravel()[:4].copy()
    if f & cv2.CALIB_FIX_ASPECT_RATIO:  # OpenCV fits fy and derives fx from it (reporting 0 for fx)
        std[0] = std[1] * K[0, 0] / K[1, 1]
    return Fit(
        K,
        dist.ravel()[:5].astype(np.float64),
        float(rms),
        [v[0] for v in views],
        list(rvecs),
        list(tvecs),
        {v[0]: float(e) for v, e in zip(views, errs)},
        dropped,
        std,
        rounds,
    )


# ---------------------------------------------------------------- distortion model choice


def photo_folds(views: list, n_folds: int, photo_of=lambda key: key) -> list[list[int]]:
    """Indices of ``views`` split into at most ``n_folds`` folds by photo (all views of a
    photo in the same fold; photos dealt round-robin in name order)."""
    photos = sorted({photo_of(v[0]) for v in views})
    k = max(1, min(n_folds, len(photos)))
    fold_of = {p: i % k for i, p in enumerate(photos)}
    return [[j for j, v in enumerate(views) if fold_of[photo_of(v[0])] == f] for f in range(k)]


def edge_radius(views: list, size: tuple[int, int], share: float | None = None) -> float:
    """Distance (px) from the image centre beyond which lie the outermost ``share`` (default
    :data:`EDGE_SHARE`) of the views' image points: the frame's edges as the photos show them."""
    share = EDGE_SHARE if share is None else share
    pts = np.concatenate([np.asarray(v[2], np.float64).reshape(-1, 2) for v in views])
    return float(np.quantile(np.hypot(*(pts - image_centre(*size)).T), 1.0 - share))


@dataclass
class Validation:
    """What k-fold cross-validation over photos says of one camera.

    Attributes:
        heldout: RMS (px) of every held-out point.
        edge: RMS (px) of the held-out points at the photos' edges (beyond :func:`edge_radius`).
        spread: spread (px) of the frame's undistortion across folds (:func:`~.distortion.fold_spread`).
    """

    heldout: float
    edge: float
    spread: float


def validate(
    views: list,
    size: tuple[int, int],
    flags: int,
    folds: list[list[int]],
    K0: np.ndarray | None = None,
    edge_px: float = float("inf"),
) -> Validation:
    """Cross-validate one camera (``flags``): each fold calibrates on the other folds' views;
    every held-out view is then posed with solvePnP using that fold's intrinsics and its
    points reprojected. Points farther than ``edge_px`` from the image centre make the
    edge error (nan when there are none)."""
    sq, edge, disps = [], [], []
    centre = image_centre(*size)
    for test in folds:
        held = set(test)
        try:
            fit = fit_views([v for j, v in enumerate(views) if j not in held], size, flags, 0, K0, lean=True)
        except NerfkitError:
            return Validation(float("inf"), float("inf"), float("inf"))
        tested = [views[j] for j in test]
        e = heldout_errors(tested, fit.K, fit.dist)
        r = np.concatenate([np.hypot(*(np.asarray(v[2], np.float64).reshape(-1, 2) - centre).T) for v in tested])
        sq.append(e)
        edge.append(e[r >= edge_px])
        disps.append(frame_displacement(fit.K, fit.dist, size))
    at_edge = np.concatenate(edge)
    return Validation(
        float(np.sqrt(np.mean(np.concatenate(sq)))),
        float(np.sqrt(np.mean(at_edge))) if len(at_edge) else float("nan"),
        fold_spread(disps),
    )


@dataclass(frozen=True)
class Candidate:
    """One whole camera that :func:`select_camera` tries: a distortion model, the principal
    point ("centre" or "free") and the pixels' aspect ("square" or "free")."""

    model: str
    principal_point: str
    aspect: str

    @property
    def name(self) -> str:
        return f"{self.model}/{self.principal_point}/{self.aspect}"

    @property
    def params(self) -> int:
        """How many parameters it fits beyond a centred, square camera's focal length."""
        return DIST_PARAMS[self.model] + 2 * (self.principal_point == "free") + (self.aspect == "free")

    def config(self, cfg: CalibrateConfig) -> CalibrateConfig:
        return replace(cfg, dist_model=self.model, principal_point=self.principal_point, aspect=self.aspect)


def candidates(cfg: CalibrateConfig) -> list[Candidate]:
    """Every camera ``cfg`` leaves open ("auto": all values), simplest distortion model first
    within each principal point and aspect."""
    models = SIMPLEST_FIRST if cfg.dist_model == "auto" else (cfg.dist_model,)
    pps = CONSTRAINTS["principal_point"] if cfg.principal_point == "auto" else (cfg.principal_point,)
    aspects = CONSTRAINTS["aspect"] if cfg.aspect == "auto" else (cfg.aspect,)
    return [Candidate(m, p, a) for p in pps for a in aspects for m in models]


def edge_limit(held: float, reference: dict | None) -> float:
    """How far (px) a camera's undistortion at the frame's edges may vary across folds:
    :data:`EDGE_FACTOR` times the larger of its own held-out error and the held-out error at
    the photos' edges of ``reference`` (the simpler model it would replace: what that one
    gets wrong there, which a disagreement of the same size does not outweigh); at least
    1 px."""
    ref = reference["edge_heldout_rms"] if reference else None
    return max(1.0, EDGE_FACTOR * held, EDGE_FACTOR * ref if ref is not None and np.isfinite(ref) else 0.0)


def _rounded(x: float, nd: int = 4) -> float | None:
    return round(float(x), nd) if np.isfinite(x) else None


def _try_camera(
    cand: Candidate,
    views: list,
    size: tuple[int, int],
    cfg: CalibrateConfig,
    folds: list[list[int]],
    K0: np.ndarray | None,
    edge_px: float,
    reference: dict | None,
) -> dict:
    """The record of one candidate camera: fitted on all ``views`` and cross-validated on its
    own, checked over the frame (:func:`~.distortion.distortion_check`) and for stability at
    the frame's edges against ``reference`` (:func:`edge_limit`)."""
    c = cand.config(cfg)
    flags, K0c = calib_flags(c), constrained_guess(K0, size, c)
    row: dict = {
        "name": cand.name,
        "dist_model": cand.model,
        "principal_point": cand.principal_point,
        "aspect": cand.aspect,
        "params": cand.params,
    }
    try:
        full = fit_views(views, size, flags, 0, K0c, lean=True)
    except NerfkitError as e:
        return {
            **row,
            "heldout_rms": None,
            "edge_heldout_rms": None,
            "eligible": False,
            "rejected": f"calibration failed ({e})",
            "check": {"ok": False, "reason": "calibration failed"},
        }
    v = validate(views, size, flags, folds, K0c, edge_px)
    check = distortion_check(full.K, full.dist, size)
    limit = edge_limit(v.heldout, reference) if cand.model != "none" else float("inf")
    rejected = "" if check["ok"] else check["reason"]
    if not np.isfinite(v.heldout):
        rejected = "could not be cross-validated"
    elif not rejected and not v.spread <= limit:
        what = (
            f"the larger of its held-out error and {reference['dist_model']}'s held-out error at the photos' edges"
            if reference
            else "its held-out error"
        )
        rejected = (
            f"unstable at the frame's edges: undistortion there varies by {v.spread:.1f} px across folds "
            f"(> {limit:.1f} px: {EDGE_FACTOR:g} x {what}, at least 1 px)"
        )
    K = full.K
    if not rejected:  # (a choice given with --principal-point or --aspect is the user's)
        rejected = implausible(K, size, cfg.principal_point == "auto", cfg.aspect == "auto")
    return {
        **row,
        "heldout_rms": _rounded(v.heldout),
        "edge_heldout_rms": _rounded(v.edge),
        "fit_rms": round(full.rms, 4),
        "frame_spread_px": _rounded(v.spread, 3),
        "edge_limit_px": _rounded(limit, 3),
        "edge_reference": reference["name"] if reference and cand.model != "none" else None,
        "check": check,
        "eligible": not rejected,
        "rejected": rejected or None,
        "fx": round(float(K[0, 0]), 3),
        "fy": round(float(K[1, 1]), 3),
        "cx": round(float(K[0, 2]), 3),
        "cy": round(float(K[1, 2]), 3),
        "dist": [round(float(d), 6) for d in full.dist],
    }


def margin(c: Candidate, d: Candidate, best_err: float, tol: float) -> float:
    """How much worse (px) than the best camera (held-out error ``best_err``) the camera
    ``d``, ``c`` made simpler, may hold out and still be preferred: ``tol x best_err``, or
    ``tol`` px when larger and the step simplifies the distortion model (below a few
    hundredths of a pixel distortion terms fit noise, while a principal point or aspect the
    photos hold is measured by the fraction alone: on exact synthetic corners a principal
    point 5 px off holds out at 0.044 px fitted and 0.061 centred)."""
    m = tol * best_err
    return max(m, tol) if DIST_PARAMS[d.model] < DIST_PARAMS[c.model] else m


def simpler_by_one(c: Candidate, d: Candidate) -> bool:
    """``d`` is ``c`` with one choice simpler: a simpler distortion model, the principal point
    centred, or the pixels square (the rest the same)."""
    same = [c.model == d.model, c.principal_point == d.principal_point, c.aspect == d.aspect]
    if sum(same) != 2:
        return False
    return (
        DIST_PARAMS[d.model] < DIST_PARAMS[c.model]
        if not same[0]
        else d.principal_point == CONSTRAINTS["principal_point"][0]
        if not same[1]
        else d.aspect == CONSTRAINTS["aspect"][0]
    )


def simplest(best: Candidate, held: dict, tol: float) -> tuple[Candidate, list[Candidate], float]:
    """From ``best`` (lowest held-out error among ``held``'s cameras, the eligible ones),
    simplify one choice at a time while the simpler camera holds out within :func:`margin`
    of ``best`` (the fewest parameters first). Returns the camera reached, the ones passed
    through and the margin of the last step."""
    at, last = best, 0.0
    path: list[Candidate] = []
    while True:
        steps = [d for d in held if simpler_by_one(at, d) and held[d] <= held[best] + margin(at, d, held[best], tol)]
        if not steps:
            return at, path, last
        path.append(at)
        nxt = min(steps, key=lambda d: (d.params, held[d]))
        at, last = nxt, margin(at, nxt, held[best], tol)


def select_camera(
    views: list, size: tuple[int, int], cfg: CalibrateConfig, photo_of=lambda key: key, K0: np.ndarray | None = None
) -> tuple[Candidate, dict]:
    """Choose the whole camera (distortion model, principal point, aspect) by k-fold
    cross-validation over photos, among the :func:`candidates` the config leaves open.

    Each candidate is a full combination fitted and cross-validated on its own, so no
    parameter is ever kept from a camera that was then rejected. A candidate is eligible when
    its fit passes :func:`~.distortion.distortion_check` and its undistortion at the frame's
    edges agrees across folds within :func:`edge_limit` of the simpler eligible model of the
    same principal point and aspect ("none" always is), and its K is a lens's
    (:func:`~.camera.implausible`, for the choices left to auto). From the eligible camera with the
    lowest held-out error, the choice is simplified one choice at a time while the simpler
    camera holds out within :func:`margin` of that best one (:func:`simplest`). A model
    given with --dist-model is never replaced, even when it fails the checks.

    Returns:
        (the camera, selection): ``candidates`` holds every camera tried (held-out error,
        edge error and spread, verdict), ``camera`` the chosen one's name; ``models``,
        ``principal_point`` and ``aspect`` compare each choice with the others left as chosen.
    """
    folds = photo_folds(views, cfg.folds, photo_of)
    edge_px = edge_radius(views, size)
    rows: dict[Candidate, dict] = {}
    for cand in candidates(cfg):
        simpler = [
            r
            for c, r in rows.items()
            if (c.principal_point, c.aspect) == (cand.principal_point, cand.aspect) and r["eligible"]
        ]
        rows[cand] = _try_camera(cand, views, size, cfg, folds, K0, edge_px, simpler[-1] if simpler else None)
    given = cfg.dist_model != "auto"
    pool = [c for c, r in rows.items() if r["eligible"]] or (
        [c for c, r in rows.items() if r["heldout_rms"] is not None] if given else []
    )
    if not pool:
        raise fail(
            "calibration",
            "no camera model could be cross-validated on these photos",
            "Take more photos of the tag sheet from varied angles (tilted 20-60 degrees)",
        )
    held = {c: rows[c]["heldout_rms"] for c in pool}
    best = min(pool, key=lambda c: (held[c], c.params))
    chosen, steps, within = simplest(best, held, cfg.select_tolerance)
    for c, r in rows.items():
        r["chosen"] = c == chosen
        if r["eligible"]:
            r["verdict"] = (
                "chosen"
                if c == chosen
                else f"the best; simplified to {chosen.name}"
                if c == best
                else "within the margin of the best; simplified further"
                if c in steps
                else f"eligible; {held[c] - held[best]:.3f} px above the best ({best.name})"
            )
    passing = "passing the checks" if rows[best]["eligible"] else "tried (none passes the checks)"
    why = (
        f"{chosen.name}: lowest held-out error among the cameras {passing} ({held[best]:.3f} px)"
        if chosen == best
        else f"{chosen.name}: the simplest camera {passing} with held-out error {held[chosen]:.3f} px, "
        f"within {within:.3f} px of the best ({best.name}, "
        f"{held[best]:.3f} px)"
    )
    method = f"{len(folds)}-fold cross-validation over photos"
    selection: dict = {
        "method": "given with --dist-model" if given else method,
        "tolerance": cfg.select_tolerance,
        "chosen": chosen.model,
        "why": "given with --dist-model" if given else why,
        "camera": chosen.name,
        "camera_why": why,
        "edge_radius_px": round(edge_px, 2),
        "candidates": list(rows.values()),
    }
    # The chosen camera against each change of one of its choices.
    selection["models"] = {
        c.model: rows[c] for c in rows if (c.principal_point, c.aspect) == (chosen.principal_point, chosen.aspect)
    }

    def fmt(e: float | None) -> str:
        return "-" if e is None else f"{e:.3f} px"

    for name, values in CONSTRAINTS.items():
        if getattr(cfg, name) != "auto":
            selection[name] = {"chosen": getattr(cfg, name), "why": f"given with {flag_of(name)}"}
            continue
        errs = {value: rows[replace(chosen, **{name: value})]["heldout_rms"] for value in values}
        value = getattr(chosen, name)
        other = next(v for v in values if v != value)
        selection[name] = {
            "method": method,
            "model": chosen.model,
            "chosen": value,
            "heldout_rms": errs,
            "why": f"held out at {fmt(errs[value])} against {fmt(errs[other])} {other}, "
            f"as part of the camera {chosen.name}",
        }
    return chosen, selection


# ---------------------------------------------------------------- layout estimation


def tag_views(
    records: list[PhotoRecord], tag_size: float, max_views: int = 0
) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """Every tag of every photo as its own planar view named ``"<photo>#<id>"``.

    Each view holds one tag's 4 corners, so no two tags ever share 3D points. With
    ``max_views`` > 0, keep at most that many: each photo's largest tag first, then each
    photo's second largest, and so on (calibrateCamera's cost grows with the cube of the
    number of views)."""
    sq = square_corners(tag_size)
    ranked: list[tuple[int, float, tuple]] = []
    for r in records:
        det = r.detected
        ids = list(det.ids)
        sides = quad_sides(det.corners)
        order = [i for i in np.argsort(-sides) if ids.count(ids[i]) == 1]
        for rank, i in enumerate(order):
            ranked.append((rank, -float(sides[i]), (f"{r.name}#{int(ids[i])}", sq, det.corners[i])))
    if max_views > 0 and len(ranked) > max_views:
        ranked = sorted(ranked, key=lambda t: t[:2])[:max_views]
    return [v for *_, v in ranked]


def tag_pose(corners: np.ndarray, K: np.ndarray, dist: np.ndarray, tag_size: float) -> np.ndarray | None:
    """(4, 4) tag-to-camera transform of one detected tag (IPPE_SQUARE, lower-error solution)."""
    import cv2

    ok, rvecs, tvecs, errs = cv2.solvePnPGeneric(
        square_corners(tag_size), corners.reshape(-1, 1, 2), K, dist, flags=cv2.SOLVEPNP_IPPE_SQUARE
    )
    if not ok:
        return None
    best = int(np.argmin(np.ravel(errs)))
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(rvecs[best])[0]
    T[:3, 3] = np.ravel(tvecs[best])
    return T


def _square_at(x: float, y: float, yaw: float, tag_size: float) -> np.ndarray:
    Rz = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    return square_corners(tag_size) @ Rz.T + np.array([x, y, 0.0])


def fit_square_2d(points: np.ndarray, tag_size: float) -> np.ndarray:
    """Corners (4, 3) in z = 0 of the square of side ``tag_size`` (rotated and shifted in
    the plane) closest in least squares to (4, 2+) ``points`` (OpenCV corner order)."""
    src = square_corners(tag_size)[:, :2]
    dst = np.asarray(points, np.float64)[:, :2]
    a, b = src - src.mean(0), dst - dst.mean(0)
    yaw = np.arctan2(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]), np.sum(a * b))
    c = dst.mean(0)
    return _square_at(c[0], c[1], yaw, tag_size)


def initial_layout(records: list[PhotoRecord], K: np.ndarray, dist: np.ndarray, tag_size: float) -> tuple[Layout, int]:
    """A first layout from relative tag poses (median over photos), all tags in the plane of
    the reference tag (the most often seen). Tags never seen together with the tags already
    placed are left out. Returns the layout and the reference id."""
    counts: dict[int, int] = {}
    poses: list[dict[int, np.ndarray]] = []
    for r in records:
        ids = list(r.detected.ids)
        p = {}
        for i, t in enumerate(ids):
            if ids.count(t) == 1:
                T = tag_pose(r.detected.corners[i], K, dist, tag_size)
                if T is not None:
                    p[int(t)] = T
                    counts[int(t)] = counts.get(int(t), 0) + 1
        poses.append(p)
    ref = min(counts, key=lambda t: (-counts[t], t))
    placed = {ref: (0.0, 0.0, 0.0)}  # id -> (x, y, yaw) in the reference tag's frame
    changed = True
    while changed:  # grow from placed tags to tags seen together with them
        changed = False
        for tag in sorted(counts):
            if tag in placed:
                continue
            xs, ys, yaws = [], [], []
            for p in poses:
                if tag not in p:
                    continue
                for anchor, (ax, ay, ayaw) in placed.items():
                    if anchor in p:
                        rel = np.linalg.inv(p[anchor]) @ p[tag]  # tag -> anchor frame
                        yaw = np.arctan2(rel[1, 0], rel[0, 0]) + ayaw
                        c, s = np.cos(ayaw), np.sin(ayaw)
                        xs.append(ax + c * rel[0, 3] - s * rel[1, 3])
                        ys.append(ay + s * rel[0, 3] + c * rel[1, 3])
                        yaws.append(yaw)
                        break
            if xs:
                yaw = float(np.angle(np.median(np.cos(yaws)) + 1j * np.median(np.sin(yaws))))
                placed[tag] = (float(np.median(xs)), float(np.median(ys)), yaw)
                changed = True
    tags = {t: _square_at(x, y, yaw, tag_size) for t, (x, y, yaw) in placed.items()}
    return Layout(tags, source="estimated"), ref


# A corner's height is triangulated from at least this many photos (else it stays on the plane).
HEIGHT_MIN_VIEWS = 3
# Heights above this share of the tag side mean something else is wrong (a tag that moved
# between photos, a wrong --tag-size): the layout then stays flat.
MAX_HEIGHT_OF_SIDE = 0.1
HEIGHT_ROUNDS = 4
# Heights within this share of the tag side are reported as a flat sheet (0.2 mm for 5 cm tags).
FLAT_WITHIN = 0.004


def refine_heights(records: dict[str, PhotoRecord], fit: PosedViews, layout: Layout) -> Layout:
    """``layout`` with each corner's height (z) triangulated: the point nearest to the rays of
    every calibrated photo that sees that corner (``fit``'s poses and camera), at least
    :data:`HEIGHT_MIN_VIEWS` of them (else height 0). A corner keeps its place on the
    printed sheet (x, y); the heights' best-fit plane is then taken out, so z = 0 stays the
    sheet's own plane and the frame does not move."""
    rays: dict[tuple[int, int], list[tuple[np.ndarray, np.ndarray]]] = {}
    for tag, origin, d in corner_rays(records, fit, layout.tags):
        for k in range(4):
            rays.setdefault((tag, k), []).append((origin, d[k]))
    tags = {t: np.array(c, np.float64, copy=True) for t, c in layout.tags.items()}
    for (tag, k), seen in rays.items():
        if len(seen) < HEIGHT_MIN_VIEWS:
            continue
        A, b = np.zeros((3, 3)), np.zeros(3)
        for o, d in seen:  # least squares: sum over rays of |(I - d d^T)(X - o)|^2
            P = np.eye(3) - np.outer(d, d)
            A += P
            b += P @ o
        tags[tag][k, 2] = np.linalg.solve(A, b)[2]
    pts = np.concatenate(list(tags.values()))
    plane = np.linalg.lstsq(np.column_stack([pts[:, :2], np.ones(len(pts))]), pts[:, 2], rcond=None)[0]
    for t in tags:
        tags[t][:, 2] -= tags[t][:, :2] @ plane[:2] + plane[2]
    return replace(layout, tags=tags)


def layout_change(new: Layout, old: Layout) -> float:
    """How far any corner of ``old``'s tags moved in ``new`` (world units, the largest
    coordinate change)."""
    return max(float(np.abs(new.tags[t] - old.tags[t]).max()) for t in old.tags)


def corner_rays(records: dict[str, PhotoRecord], fit: PosedViews, tags) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
    """Per photo of ``fit`` and per tag of ``tags`` it shows once: ``(tag, origin (3,),
    directions (4, 3))``, the camera centre and the unit rays through the tag's corners,
    in the sheet's frame (``fit``'s poses and camera)."""
    import cv2

    for key, rvec, tvec in zip(fit.keys, fit.rvecs, fit.tvecs):
        det = records[key].detected
        R = cv2.Rodrigues(rvec)[0]
        origin = -R.T @ np.ravel(tvec)  # camera centre in the sheet frame
        ids = [int(i) for i in det.ids]
        for i, tag in enumerate(ids):
            if tag not in tags or ids.count(tag) != 1:
                continue
            xy = cv2.undistortPoints(
                det.corners[i].reshape(-1, 1, 2),
                fit.K,
                fit.dist,
                criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 1e-10),
            ).reshape(-1, 2)
            d = (R.T @ np.column_stack([xy, np.ones(4)]).T).T
            yield tag, origin, d / np.linalg.norm(d, axis=1, keepdims=True)


def refine_layout(
    records: dict[str, PhotoRecord], fit: PosedViews, layout: Layout, ref: int, tag_size: float
) -> Layout:
    """Re-estimate every tag but ``ref``: back-project its corners onto the sheet plane of
    each calibrated photo, average, and fit a square of side ``tag_size``."""
    acc: dict[int, list[np.ndarray]] = {t: [] for t in layout.tags if t != ref}
    for tag, origin, d in corner_rays(records, fit, acc):
        if np.any(np.abs(d[:, 2]) < 1e-9):
            continue
        s = -origin[2] / d[:, 2]
        if np.any(s <= 0):
            continue
        acc[tag].append(origin + s[:, None] * d)
    tags = {ref: layout.tags[ref]}
    for tag, pts in acc.items():
        tags[tag] = fit_square_2d(np.mean(pts, axis=0), tag_size) if pts else layout.tags[tag]
    return Layout(tags, source="estimated")


# ---------------------------------------------------------------- the whole calibration


@dataclass
class Calibration:
    """What ``nerfkit calibrate`` found.

    Attributes:
        K, dist, rms, width, height: the camera.
        target: "layout file", "estimated layout" or "per-tag".
        layout: the layout used or estimated (None in per-tag mode).
        std: standard deviations of fx, fy, cx, cy.
        notes: human-readable lines about what happened (outlier rounds, layout fit).
        sanity: from :func:`sanity_checks`.
        dist_model: the distortion model used; selection: how the camera was chosen
            (:func:`select_camera`).
    """

    K: np.ndarray
    dist: np.ndarray
    rms: float
    width: int
    height: int
    target: str
    layout: Layout | None
    std: np.ndarray
    notes: list[str]
    sanity: dict
    dist_model: str = ""
    selection: dict = field(default_factory=dict)


def _views_for_layout(records: list[PhotoRecord], layout: Layout, min_points: int) -> list:
    views = []
    for r in records:
        obj, img, used = layout.match(r.detected)
        if len(obj) >= min_points:
            views.append((r.name, obj, img))
        else:
            got = [int(i) for i in r.detected.ids]
            r.skip("no tag of the layout found" if not got else f"too few layout points ({len(obj)}; tags seen: {got})")
    return views


def _layout_sheet_views(records: list[PhotoRecord], layout: Layout) -> list:
    return [(r.name, *layout.match(r.detected)[:2]) for r in records if len(layout.match(r.detected)[0]) >= 4]


# A tag whose side in the photos differs from the other tags' (in the same photos) by more
# than this factor in the median is of another size: perspective across a sheet stays within it.
ODD_SIZE = 1.4


def odd_sized_tags(detections: list) -> dict[int, float]:
    """Tag id -> its median side over the median side of the other tags in the same photo,
    for the tags beyond :data:`ODD_SIZE` either way, from the photos showing three tags or more
    (with two, which one is odd is unknown)."""
    ratios: dict[int, list[float]] = {}
    for det in detections:
        ids = [int(i) for i in det.ids]
        if len(set(ids)) < 3 or len(set(ids)) != len(ids):
            continue
        sides = quad_sides(np.asarray(det.corners, np.float64))
        for k, t in enumerate(ids):
            ratios.setdefault(t, []).append(float(sides[k] / np.median(np.delete(sides, k))))
    medians = {t: float(np.median(r)) for t, r in ratios.items()}
    return {t: m for t, m in medians.items() if not 1 / ODD_SIZE < m < ODD_SIZE}


def estimate_layout(
    with_tags: list[PhotoRecord],
    by_name: dict,
    size: tuple[int, int],
    tag_size: float,
    cfg: CalibrateConfig,
    notes: list[str],
) -> tuple[Layout, np.ndarray]:
    """The sheet layout from photos showing several tags: a first layout from relative tag
    poses, then rounds of calibrate (with :data:`LAYOUT_MODEL`) + re-fit of the tags on the
    plane, then rounds of calibrate + the corners' heights (:func:`refine_heights`). The
    result is frozen: the distortion model is chosen afterwards on this layout. Returns the
    layout and the last round's camera matrix (a non-flat layout's calibration starts
    from it)."""
    import cv2

    # Rough intrinsics from per-tag views (square pixels, centred principal point: robust).
    rough_flags = (
        cv2.CALIB_FIX_ASPECT_RATIO
        | cv2.CALIB_FIX_PRINCIPAL_POINT
        | cv2.CALIB_ZERO_TANGENT_DIST
        | cv2.CALIB_FIX_K3
        | cv2.CALIB_FIX_K2
    )
    rough = fit_views(tag_views(with_tags, tag_size, max_views=60), size, rough_flags, cfg.outlier_factor)
    layout, ref = initial_layout(with_tags, rough.K, rough.dist, tag_size)
    flags = calib_flags(cfg, LAYOUT_MODEL)
    fit = None
    change = float("nan")
    for it in range(10):  # noqa: B007 (`it` counts the rounds run, after the loop)
        fit = fit_views(
            _layout_sheet_views(with_tags, layout), size, flags, cfg.outlier_factor, None if fit is None else fit.K
        )
        new = refine_layout(by_name, fit, layout, ref, tag_size)
        change = layout_change(new, layout)
        layout = new
        if change < 5e-4 * tag_size:  # 0.03 mm for 6 cm tags
            break
    notes.append(
        f"estimated the layout of {len(layout.tags)} tags (reference tag {ref}) in {it + 1} "
        f"rounds of calibrate ({LAYOUT_MODEL} distortion) + re-fit; last change {change * 1000:.3f} mm"
    )
    assert fit is not None  # the loop above runs at least once
    layout, K = measure_heights(with_tags, by_name, fit, layout, size, cfg, notes)
    notes.append("then froze the layout to choose the distortion model")
    missing = sorted({int(i) for r in with_tags for i in r.detected.ids} - set(layout.tags))
    if missing:
        notes.append(f"tags {missing} were never seen together with the others and were ignored")
    return layout, K


def measure_heights(
    with_tags: list[PhotoRecord],
    by_name: dict,
    fit: Fit,
    layout: Layout,
    size: tuple[int, int],
    cfg: CalibrateConfig,
    notes: list[str],
) -> tuple[Layout, np.ndarray]:
    """``layout`` with its corners' heights, from :data:`HEIGHT_ROUNDS` rounds of
    :func:`refine_heights` and calibrate (:data:`LAYOUT_MODEL`), starting from ``fit`` (the
    flat layout's); the flat layout when the heights come out larger than a sheet bends.
    Returns the layout and the camera matrix its calibration starts from."""
    flags = calib_flags(cfg, LAYOUT_MODEL)
    flat, flat_fit = layout, fit
    for _ in range(HEIGHT_ROUNDS):
        layout = refine_heights(by_name, fit, layout)
        fit = fit_views(_layout_sheet_views(with_tags, layout), size, flags, cfg.outlier_factor, fit.K)
    height = layout.max_height()
    if height > MAX_HEIGHT_OF_SIDE * flat.tag_size:
        notes.append(
            f"the tags' corners came out up to {height * 1000:.1f} mm off the sheet's plane, more than a "
            f"paper sheet bends: kept the sheet flat (a tag moved between photos, or the tag size is wrong?)"
        )
        return flat, flat_fit.K
    if HEIGHT_ROUNDS:
        how = "lies flat" if height < FLAT_WITHIN * flat.tag_size else "is not quite flat"
        notes.append(
            f"the sheet {how}: its tags' corners lie up to {height * 1000:.2f} mm off its plane "
            f"(RMS {flat_fit.rms:.3f} px flat, {fit.rms:.3f} px with the heights)"
        )
    return layout, fit.K


# photos whose tags' corners all lie within this share of the image diagonal of another's show
# the same view (copies, a burst from a tripod) and tell the calibration nothing new
SAME_VIEW = 0.005
# Zhang's calibration needs at least three views of a plane for a camera's intrinsics
MIN_VIEWS = 3


def distinct_views(detections: list, tol: float) -> int:
    """How many of ``detections`` (``ids`` (n,), ``corners`` (n, 4, 2)) show their tags from a
    different place than every one before: a photo is another's view again when they share a
    tag and every shared tag's corners lie within ``tol`` pixels of each other's."""
    kept: list[dict[int, np.ndarray]] = []
    for det in detections:
        tags = {int(i): np.asarray(c, np.float64) for i, c in zip(det.ids, det.corners)}
        seen = any(
            (shared := tags.keys() & old.keys()) and all(np.abs(tags[i] - old[i]).max() <= tol for i in shared)
            for old in kept
        )
        if not seen:
            kept.append(tags)
    return len(kept)


def calibrate_records(
    records: list[PhotoRecord],
    size: tuple[int, int] | None,
    tag_size: float,
    layout: Layout | None,
    cfg: CalibrateConfig,
    dictionary: str = "",
) -> Calibration:
    """Calibrate from detected photos of one size; marks each record used/skipped with a reason.

    Args:
        records: readable photos of size ``size`` (others should be skipped beforehand).
        tag_size: tag side in metres (scales the estimated layout; intrinsics don't depend on it).
        layout: known sheet layout, or None.
    """
    notes: list[str] = []
    with_tags = []
    for r in records:
        ch = r.detected.charuco_ids
        n = len(r.detected.ids) if layout is None or layout.charuco is None else (0 if ch is None else len(ch))
        if n == 0:
            r.skip("no tags found" if layout is None or layout.charuco is None else "no ChArUco corners found")
        else:
            with_tags.append(r)

    def enough(photos: list[PhotoRecord], what: str) -> None:
        if len(photos) < cfg.min_photos:
            raise fail(
                "calibration",
                f"only {len(photos)} {what} (need at least {cfg.min_photos})",
                "Take 20-50 sharp photos of the tag sheet from varied angles and distances",
            )

    enough(with_tags, "photos with tags found")  # (before the fit, which counts tag views, not photos)
    assert size is not None  # None only with no photos (group_by_size), refused just above
    places = distinct_views([r.detected for r in with_tags], SAME_VIEW * float(np.hypot(*size)))
    if places < MIN_VIEWS:
        raise fail(
            "calibration",
            f"the {len(with_tags)} photos with tags show them from {places} place{'s' * (places != 1)} "
            f"(their corners within {SAME_VIEW * 100:g}% of the diagonal of each other): a lens cannot be "
            f"measured from fewer than {MIN_VIEWS} different views",
            "Take 20-50 sharp photos of the tag sheet, moving the phone between them: varied angles and distances",
        )
    by_name = {r.name: r for r in with_tags}
    ids_together = any(len(set(int(i) for i in r.detected.ids)) > 1 for r in with_tags)

    K0 = None
    per_tag = layout is None and (cfg.per_tag or not ids_together)

    def photo_of(key: str) -> str:  # views may be per tag ("<photo>#<id>")
        return key.rsplit("#", 1)[0] if per_tag else key

    if layout is not None:
        target = f"layout ({layout.source})"
        views = _views_for_layout(with_tags, layout, 6 if layout.charuco is not None else 4)
        if layout.charuco is None and len(layout.tags) > 1 and layout.is_planar():  # the paper's heights
            fit = fit_views(views, size, calib_flags(cfg, LAYOUT_MODEL), cfg.outlier_factor)
            layout, K_layout = measure_heights(with_tags, by_name, fit, layout, size, cfg, notes)
            if not layout.is_planar():
                views, K0 = _layout_sheet_views(with_tags, layout), K_layout
        elif not layout.is_planar():  # calibrateCamera can only initialise from planar targets
            fx0 = 1.2 * max(size)
            cx, cy = image_centre(*size)
            K0 = np.array([[fx0, 0, cx], [0, fx0, cy], [0, 0, 1]])
            notes.append("non-planar layout: started from fx = 1.2 x image width")
    elif per_tag:
        target = "per-tag"
        views = tag_views(with_tags, tag_size, max_views=MAX_TAG_VIEWS)
        notes.append(
            f"each tag is its own planar target ({len(views)} tag views"
            + (f", the largest {MAX_TAG_VIEWS}" if len(views) == MAX_TAG_VIEWS else "")
            + ")"
            + ("" if ids_together else ": no photo shows two different tags")
        )
        layout = None
    else:
        target = "estimated layout"
        odd = odd_sized_tags([r.detected for r in with_tags])
        if odd:
            for r in with_tags:
                r.detection = r.detected.without(odd)
            notes.append(
                "left out of the sheet: "
                + ", ".join(f"tag {t} (it looks {k:.1f} times the size of the others)" for t, k in sorted(odd.items()))
                + ": a tag of another size (the object's?) cannot share the sheet's --tag-size"
            )
        layout, K_layout = estimate_layout(with_tags, by_name, size, tag_size, cfg, notes)
        views = _layout_sheet_views(with_tags, layout)
        if not layout.is_planar():  # calibrateCamera can only initialise from planar targets
            K0 = K_layout
    K0 = constrained_guess(K0, size, cfg)
    kept, chosen_fit = views, None
    if "auto" in (cfg.dist_model, cfg.principal_point, cfg.aspect):
        # Outliers first (with the layout model), so they do not sway the choices.
        pre = fit_views(views, size, calib_flags(cfg, LAYOUT_MODEL), cfg.outlier_factor, K0)
        kept = [v for v in views if v[0] in set(pre.keys)]
    else:  # nothing to choose: cross-validated on the views the camera keeps
        chosen_fit = fit_views(views, size, calib_flags(cfg), cfg.outlier_factor, K0)
        kept = [v for v in views if v[0] in set(chosen_fit.keys)]
    camera, selection = select_camera(kept, size, cfg, photo_of, K0)
    cfg, model = camera.config(cfg), camera.model
    fit = chosen_fit or fit_views(views, size, calib_flags(cfg), cfg.outlier_factor, constrained_guess(K0, size, cfg))
    choices = {name: selection[name] for name in CONSTRAINTS}
    if layout is not None and target == "estimated layout":
        for r in with_tags:
            if not any(int(i) in layout.tags for i in r.detected.ids):
                r.skip("none of its tags belong to the estimated layout")
    notes.extend(fit.rounds)

    # Per-photo outcome (views may be per tag: a photo is used when any of its views is).
    per_photo: dict[str, list[float]] = {}
    for key, err in fit.errors.items():
        per_photo.setdefault(photo_of(key), []).append(err)
    for r in with_tags:
        if r.reason:
            continue
        if r.name in per_photo:
            r.used = True
            r.error_px = float(np.sqrt(np.mean(np.square(per_photo[r.name]))))
            n_drop = sum(1 for k in fit.dropped if photo_of(k) == r.name)
            if n_drop:
                r.info["tag_views_dropped"] = n_drop
        else:
            reasons = [v for k, v in fit.dropped.items() if photo_of(k) == r.name]
            r.skip(reasons[0] if reasons else "its tags were not among the tag views used")
    used = [r for r in with_tags if r.used]
    enough(used, "usable photos")
    coverage = corner_coverage(used, size)
    f35 = [r.exif_f35 for r in used if r.exif_f35]
    sanity = sanity_checks(fit.K, fit.dist, size, fit.rms, fit.std, f35, coverage, len(used), choices)
    check = selection["models"][model]["check"]
    if not check["ok"]:
        sanity["warnings"].append(
            f"the {model} distortion model is implausible over the frame ({check['reason']}); use --dist-model auto"
        )
    return Calibration(
        fit.K, fit.dist, fit.rms, size[0], size[1], target, layout, fit.std, notes, sanity, model, selection
    )


def constraint_advice(choices: dict | None, name: str, more_photos: str) -> str:
    """What to do about a camera that breaks one of :data:`CONSTRAINTS`, by how it came free:
    given free (try auto), or freed by the photos' held-out error (they want it: cropped or
    edited photos do that; keep it unless the photos are straight from the phone)."""
    kept = CONSTRAINTS[name][0]
    flag = flag_of(name)
    held = (choices or {}).get(name, {}).get("heldout_rms")
    if held and held.get(kept) is not None and held.get("free") is not None:
        return (
            f"The photos hold it there ({held['free']:.3f} px held out against {held[kept]:.3f} px with {flag} "
            f"{kept}): cropped or edited photos do that. If they come straight from the phone, "
            f"{more_photos[0].lower() + more_photos[1:]}, or re-run with {flag} {kept}"
        )
    return f"{more_photos}, or re-run with {flag} {kept}" + (" (or auto)" if choices else "")


def corner_coverage(records: list[PhotoRecord], size: tuple[int, int], cells: int = 3) -> float:
    """Fraction of a cells x cells grid over the image that holds at least one used corner."""
    hit = np.zeros((cells, cells), bool)
    for r in records:
        pts = r.detected.corners.reshape(-1, 2)
        if r.detected.charuco_corners is not None:
            pts = np.concatenate([pts, r.detected.charuco_corners])
        ix = np.clip((pts[:, 0] / size[0] * cells).astype(int), 0, cells - 1)
        iy = np.clip((pts[:, 1] / size[1] * cells).astype(int), 0, cells - 1)
        hit[iy, ix] = True
    return float(hit.mean())


def sanity_checks(
    K: np.ndarray,
    dist: np.ndarray,
    size: tuple[int, int],
    rms: float,
    std: np.ndarray,
    exif_f35: list[float],
    coverage: float,
    n_photos: int,
    choices: dict | None = None,
) -> dict:
    """Plausibility of a phone calibration; ``warnings`` lists each failed check in words.

    Checks: fx/fy (phone pixels are square), principal point offset from the image centre,
    agreement with the EXIF 35 mm-equivalent focal length, RMS, parameter uncertainty,
    coverage of the image by tag corners, number of photos. ``choices`` (name -> record, as
    :func:`select_camera` records) says how each of :data:`CONSTRAINTS` was decided, so
    the advice fits: a constraint the photos freed by held-out error is not simply undone.
    """
    w, h = size
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    diag = float(np.hypot(w, h))
    dx, dy = np.subtract((cx, cy), image_centre(w, h))
    out: dict = {
        "fx_fy_ratio": round(float(fx / fy), 5),
        "principal_point_offset_px": [round(float(dx), 2), round(float(dy), 2)],
        "principal_point_offset_of_diagonal": round(float(np.hypot(dx, dy) / diag), 5),
        "std_fx_fy_cx_cy": [round(float(s), 3) for s in std],
        "corner_coverage": round(coverage, 3),
        "photos_used": n_photos,
    }
    warnings: list[str] = []
    if abs(fx / fy - 1) > 0.015:
        warnings.append(
            f"fx and fy differ by {abs(fx / fy - 1) * 100:.1f}% (fx={fx:.1f}, fy={fy:.1f}); phone pixels "
            "are square. "
            + constraint_advice(
                choices, "aspect", "The calibration is probably poorly constrained: take more tilted photos"
            )
        )
    if np.hypot(dx, dy) > 0.02 * diag:
        warnings.append(
            f"principal point is {np.hypot(dx, dy):.0f} px ({np.hypot(dx, dy) / diag * 100:.1f}% of the "
            f"diagonal) from the image centre (dx={dx:.0f}, dy={dy:.0f}); phone lenses are nearly centred. "
            + constraint_advice(
                choices, "principal_point", "Take photos with the tags near the image edges and corners"
            )
        )
    if exif_f35:
        f35 = float(np.median(exif_f35))
        efx = exif_fx(f35, w, h)
        out["exif_focal_35mm"] = f35
        out["exif_fx"] = round(efx, 2)
        out["fx_over_exif_fx"] = round(float(fx / efx), 4)
        if abs(fx / efx - 1) > 0.07:
            warnings.append(
                f"fx={fx:.0f} px disagrees with the EXIF focal length ({f35:g} mm in 35 mm terms -> "
                f"{efx:.0f} px, {(fx / efx - 1) * 100:+.0f}%). Check the photos come from one lens and "
                "were not cropped or zoomed"
            )
    else:
        out["exif_focal_35mm"] = None
    if rms > 1.0:
        warnings.append(
            f"RMS reprojection error {rms:.2f} px is high (expect well under 1 px): blurred photos, "
            "a bent sheet or a wrong layout"
        )
    if std[0] > 0.01 * fx or std[1] > 0.01 * fy:
        warnings.append(f"focal length is uncertain (+/-{std[0]:.1f} px); add photos from more varied angles")
    if coverage < 0.67:
        warnings.append(
            f"tag corners cover only {coverage * 100:.0f}% of a 3x3 grid over the image; lens distortion "
            "near the edges is extrapolated. Add photos with the tags near the edges and corners"
        )
    if n_photos < 10:
        warnings.append(f"only {n_photos} photos used; 20-50 give a steadier calibration")
    out["warnings"] = warnings
    out["film_diagonal_mm"] = FILM_DIAGONAL_MM
    return out


def calibration_json(
    cal: Calibration, records: list[PhotoRecord], dictionary: str, tag_size: float | None, photos_dir: str
) -> dict:
    """The camera file's content."""
    K = cal.K
    return {
        "format": "nerfkit-camera",
        "version": 1,
        "pixel_convention": "opencv: pixel centres at integer coordinates "
        "(nerfkit and nerfstudio use cx + 0.5, cy + 0.5)",
        "width": cal.width,
        "height": cal.height,
        "sensor_turns": frame_turns([r for r in records if r.used]),
        "K": np.round(K, 6).tolist(),
        "fx": round(float(K[0, 0]), 4),
        "fy": round(float(K[1, 1]), 4),
        "cx": round(float(K[0, 2]), 4),
        "cy": round(float(K[1, 2]), 4),
        "dist": [round(float(d), 8) for d in cal.dist],
        "dist_names": ["k1", "k2", "p1", "p2", "k3"],
        "rms": round(float(cal.rms), 5),
        "dist_model": cal.dist_model,
        "heldout_rms": cal.selection.get("models", {}).get(cal.dist_model, {}).get("heldout_rms"),
        "model_selection": cal.selection,
        "target": cal.target,
        "dictionary": dictionary,
        "tag_size": tag_size,
        # the printed sheet (what `poses` takes); the heights were the paper's while calibrating
        "layout": None if cal.layout is None else cal.layout.flattened().to_json(),
        "sheet_heights_m": None if cal.layout is None else cal.layout.heights_json(),
        "sanity": cal.sanity,
        "notes": cal.notes,
        "photos_dir": photos_dir,
        "photos_used": sum(r.used for r in records),
        "photos_skipped": sum(not r.used for r in records),
        "images": [r.summary() for r in records],
    }
