"""A live viewer of a trained (or training) run in the browser, with viser (``nerfkit view RUN``).

It sits with the commands, above training and rendering (it loads runs and renders them);
:mod:`nerfkit.viz` below holds the figures and the dataset viewer it draws with.

``serve_run(RUN)`` shows the training cameras (frustums with thumbnails) and renders the
NeRF from the browser's camera: a small preview as soon as the camera moves, refined
step by step up to ``max_side`` pixels once it stops. An RGB / depth toggle, a
resolution slider and an "Object alone" switch (a capture's object without its table and
room, on white) sit in the side panel. With ``watch=True`` the newest checkpoint is
re-loaded whenever training writes a new one (so it can attach to a run in progress).

It listens on 127.0.0.1 unless another ``host`` is passed explicitly (the viewer has no
authentication: anyone who can reach the port sees the scene).
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from ..errors import NerfkitError
from ..images import to_uint8

if TYPE_CHECKING:
    from ..models.base import NerfModel
    from ..train.checkpoint import RunInfo

PREVIEW_SIDE = 64
SETTLE_SECONDS = 0.25


# --------------------------------------------------------------------------- camera maths (pure)


def quat_to_matrix(wxyz) -> np.ndarray:
    """Rotation matrix (3, 3) of a unit quaternion (w, x, y, z)."""
    from viser import transforms as vtf

    return np.asarray(vtf.SO3(np.asarray(wxyz, np.float64)).as_matrix())


def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of a rotation matrix (3, 3)."""
    from viser import transforms as vtf

    return np.asarray(vtf.SO3.from_matrix(np.asarray(R, np.float64)).wxyz)


def viewer_camera(wxyz, position, fov: float, aspect: float, long_side: int) -> tuple[np.ndarray, np.ndarray, int, int]:
    """nerfkit camera of a viser camera (OpenCV axes, ``P_world = R p_cam + t``).

    Args:
        wxyz, position: the camera's rotation (quaternion) and centre in the world.
        fov: vertical field of view (radians); aspect: width / height.
        long_side: pixels of the longer image side.
    Returns:
        (K (3, 3) float32, c2w (4, 4) float32, width, height); square pixels, principal
        point at the image centre.
    """
    if aspect >= 1:
        w, h = long_side, max(1, round(long_side / aspect))
    else:
        w, h = max(1, round(long_side * aspect)), long_side
    fy = 0.5 * h / np.tan(0.5 * fov)
    K = np.array([[fy, 0, w / 2], [0, fy, h / 2], [0, 0, 1]], np.float32)
    c2w = np.eye(4, dtype=np.float32)
    c2w[:3, :3] = quat_to_matrix(wxyz)
    c2w[:3, 3] = np.asarray(position, np.float64)
    return K, c2w, w, h


def box_depth_range(box, c2w: np.ndarray, near: float, far: float) -> tuple[float, float]:
    """The depths a box ``(lo (3,), hi (3,))`` spans seen from camera ``c2w``: from its
    nearest point (no nearer than ``near``) to its farthest corner; ``(near, far)``
    without a box."""
    from ..scene_extent import box_corners

    if box is None:
        return near, far
    lo, hi = (np.asarray(v, np.float64) for v in box)
    eye = np.asarray(c2w, np.float64)[:3, 3]
    nearest = max(near, float(np.linalg.norm(np.maximum(np.maximum(lo - eye, eye - hi), 0.0))))
    return nearest, max(float(np.linalg.norm(box_corners(box) - eye, axis=1).max()), nearest + 1e-6)


def refinement_sides(preview: int, max_side: int) -> list[int]:
    """Long sides rendered one after another while the camera rests: preview, 2x, ..., max."""
    sides = [max(8, min(preview, max_side))]
    while sides[-1] < max_side:
        sides.append(min(2 * sides[-1], max_side))
    return sides


# --------------------------------------------------------------------------- model + checkpoints


@dataclass
class LoadedRun:
    """What the viewer draws: the model, the run info, its step, and the checkpoint file."""

    model: NerfModel
    info: RunInfo
    step: int
    checkpoint: Path | None


def newest_checkpoint(run_dir: Path) -> tuple[Path, float] | None:
    """(path, mtime) of the newest checkpoint file of a run (or its final ``model.pt``), or None."""
    found = []
    for group in (sorted((run_dir / "checkpoints").glob("step_*.pt"), reverse=True), [run_dir / "model.pt"]):
        for p in group:
            try:
                found.append((p, p.stat().st_mtime))
                break
            except FileNotFoundError:  # pruned while we looked
                continue
    return max(found, key=lambda f: f[1], default=None)


class RunWatcher:
    """Loads a run and re-loads it when a newer checkpoint appears.

    ``loader(run_dir) -> (model, info, step)`` (default: ``train.checkpoint.load_run``).
    """

    def __init__(self, run_dir: str | Path, loader: Callable, device: str | torch.device = "cpu"):
        self.run_dir = Path(run_dir)
        self.loader = loader
        self.device = device
        self.current: LoadedRun | None = None
        self._seen: tuple[Path, float] | None = None
        self.status = "waiting for the first checkpoint"

    def poll(self) -> bool:
        """Load the run if its newest checkpoint changed; True when a new model was loaded."""
        newest = newest_checkpoint(self.run_dir)
        if newest is None or newest == self._seen:
            return False
        try:
            model, info, step = self.loader(self.run_dir)
        except NerfkitError as e:  # e.g. a checkpoint half-written by another filesystem
            self.status = f"could not load: {e}"
            return False
        self._seen = newest
        self.current = LoadedRun(model, info, int(step), newest[0])
        self.status = f"step {step}"
        return True


# --------------------------------------------------------------------------- rendering


@torch.no_grad()
def render_camera(
    model,
    K: np.ndarray,
    c2w: np.ndarray,
    w: int,
    h: int,
    background: torch.Tensor,
    chunk: int = 4096,
    abort: Callable[[], bool] | None = None,
):
    """The view of a camera (:class:`~nerfkit.output.images.RenderedView`), or None if aborted;
    in the precision the run was loaded for (the model's ``autocast_dtype``, as ``render`` and
    ``eval`` draw it)."""
    from ..output.images import render_image

    dtype = getattr(model, "autocast_dtype", None)
    return render_image(model, K, c2w, w, h, background, chunk, autocast_dtype=dtype, abort=abort)


@dataclass
class _ClientState:
    key: tuple = ()
    level: int = 0
    changed_at: float = 0.0
    extra: dict = field(default_factory=dict)


class LiveViewer:
    """The viser server, its panel, and the render loop (see the module docstring)."""

    def __init__(
        self,
        watcher: RunWatcher,
        scene=None,
        host: str = "127.0.0.1",
        port: int = 8080,
        max_side: int = 256,
        preview: int = PREVIEW_SIDE,
        chunk: int = 4096,
        watch: bool = True,
    ):
        from ..viz.viewer import listening_port, require_viser

        viser = require_viser()
        self.watcher = watcher
        self.scene = scene
        self.max_side = max_side
        self.preview = preview
        self.chunk = chunk
        self.watch = watch
        self.server = viser.ViserServer(host=host, port=listening_port(host, port), verbose=False)
        self._states: dict[int, _ClientState] = {}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        gui = self.server.gui
        self.mode = gui.add_dropdown("Show", ("RGB", "Depth"), initial_value="RGB")
        self.res = gui.add_slider("Max resolution", min=32, max=1024, step=32, initial_value=max_side)
        self.alone = gui.add_checkbox(
            "Object alone",
            initial_value=False,
            hint="a capture's object without its table, floor and room, on white "
            "(a run that is not a capture has nothing to leave out: it is only put on white)",
        )
        self._alone: tuple[LoadedRun, object] | None = None  # (the run, its isolated copy)
        self.follow = gui.add_checkbox("Follow training", initial_value=watch)
        self.status = gui.add_markdown("loading...")
        self.frustums = gui.add_checkbox("Training cameras", initial_value=True)
        self.frustums.on_update(lambda _: self._set_frustums_visible(self.frustums.value))
        self.mode.on_update(lambda _: self._splats_visible())
        self.alone.on_update(lambda _: self._splats_visible())
        self._frustum_handles: list = []
        self.splats = None  # viser's own Gaussian-splat node, for splat runs
        if scene is not None:
            up = np.asarray(scene.up, np.float64)
            self.server.scene.set_up_direction((float(up[0]), float(up[1]), float(up[2])))
            self._add_training_cameras(scene)
        self.server.on_client_connect(self._on_connect)

    # -- scene

    def _show_splats(self) -> None:
        """A splat run's Gaussians, drawn by viser itself (replaced at each new checkpoint)."""
        run = self.watcher.current
        if run is None or not hasattr(run.model, "n_gaussians"):
            return
        from ..viz.splats import add_splats

        self.splats = add_splats(self.server, run.model)
        self._splats_visible()

    def _splats_visible(self) -> None:
        """viser draws its Gaussians over the rendered background: shown in colour only, as
        the depth or the object alone would be drawn under them unseen."""
        if self.splats is not None:
            self.splats.visible = self.mode.value == "RGB" and not self.alone.value

    def _add_training_cameras(self, scene) -> None:
        v = scene.train
        if len(v) == 0:
            return
        spread = float(np.mean(np.linalg.norm(v.c2w[:, :3, 3] - scene.center, axis=1)))
        step = max(1, len(v) // 100)  # at most ~100 frustums
        for i in range(0, len(v), step):
            fy = float(v.K[i, 1, 1])
            thumb = None
            if v.images is not None:
                s = max(1, max(v.width, v.height) // 64)
                thumb = v.images[i, ::s, ::s]
            name = v.names[i] if v.names else f"{i:04d}"
            self._frustum_handles.append(
                self.server.scene.add_camera_frustum(
                    f"/train/{i:04d}_{Path(name).stem}",
                    fov=float(2 * np.arctan(0.5 * v.height / fy)),
                    aspect=v.width / v.height,
                    scale=0.08 * spread,
                    image=thumb,
                    format="jpeg",
                    wxyz=matrix_to_quat(v.c2w[i, :3, :3]),
                    position=v.c2w[i, :3, 3].astype(np.float64),
                    color=(40, 120, 220),
                )
            )

    def _set_frustums_visible(self, visible: bool) -> None:
        for h in self._frustum_handles:
            h.visible = visible

    def _on_connect(self, client) -> None:
        if self.scene is not None and len(self.scene.train):
            c2w = self.scene.train.c2w[0]
            client.camera.position = c2w[:3, 3].astype(np.float64)
            client.camera.look_at = np.asarray(self.scene.center, np.float64)
            client.camera.up_direction = np.asarray(self.scene.up, np.float64)

    # -- render loop

    def _camera_key(self, client) -> tuple:
        cam = client.camera
        return (
            tuple(np.round(cam.wxyz, 5)),
            tuple(np.round(cam.position, 5)),
            round(float(cam.fov), 5),
            round(float(cam.aspect), 4),
            self.mode.value,
            int(self.res.value),
            bool(self.alone.value),
            None if self.watcher.current is None else self.watcher.current.step,
        )

    def _object_alone(self, run: LoadedRun):
        """The run's model with only its object (:func:`~nerfkit.surroundings.object_alone`),
        made once per loaded checkpoint."""
        from ..surroundings import object_alone

        if self._alone is None or self._alone[0] is not run:
            self._alone = (run, object_alone(run.model).model)
        return self._alone[1]

    def render_for(
        self,
        wxyz,
        position,
        fov: float,
        aspect: float,
        side: int,
        mode: str,
        abort: Callable[[], bool] | None = None,
        alone: bool = False,
    ) -> np.ndarray | None:
        """The image (H, W, 3) uint8 the viewer shows for a camera, or None (aborted / no
        model); ``alone``: the object alone, on white."""
        run = self.watcher.current
        if run is None:
            return None
        from ..train.config import parse_background

        K, c2w, w, h = viewer_camera(wxyz, position, fov, aspect, side)
        device = next(iter(run.model.parameters()), torch.zeros(0)).device
        bg = torch.tensor(
            parse_background("white" if alone else run.info.train.background), dtype=torch.float32, device=device
        )
        with self._lock:
            model = self._object_alone(run) if alone else run.model
            out = render_camera(model, K, c2w, w, h, bg, self.chunk, abort)
        if out is None:
            return None
        if mode == "Depth":
            b = run.info.bounds
            near, far = (b.near, b.far) if not alone else box_depth_range(model.density_box(), c2w, b.near, b.far)
            return to_uint8(out.depth_colours(near, far))
        return to_uint8(out.rgb)

    def step(self) -> None:
        """One pass of the loop: poll checkpoints, then refine every client's image once."""
        if self.follow.value or self.watcher.current is None:
            if self.watcher.poll():
                with self._lock:
                    self._alone = None  # (the earlier checkpoint's copy: not kept in memory)
                self.status.content = f"**{self.watcher.run_dir.name}**: {self.watcher.status}"
                self._show_splats()
            elif self.watcher.current is None:
                self.status.content = self.watcher.status
        sides = refinement_sides(self.preview, int(self.res.value))
        now = time.monotonic()
        for cid, client in list(self.server.get_clients().items()):
            st = self._states.setdefault(cid, _ClientState())
            try:
                key = self._camera_key(client)
            except AssertionError:  # the client has not sent its camera yet
                continue
            if key != st.key:
                st.key, st.level, st.changed_at = key, 0, now
            if st.level >= len(sides) or (st.level > 0 and now - st.changed_at < SETTLE_SECONDS):
                continue
            cam = client.camera

            def moved(c=client, k=key) -> bool:
                return self._camera_key(c) != k

            img = self.render_for(
                cam.wxyz,
                cam.position,
                cam.fov,
                cam.aspect,
                sides[st.level],
                self.mode.value,
                abort=moved,
                alone=self.alone.value,
            )
            if img is not None:
                client.scene.set_background_image(img, format="jpeg", jpeg_quality=90)
                st.level += 1
        for cid in set(self._states) - set(self.server.get_clients()):
            del self._states[cid]

    def serve_forever(self, poll_seconds: float = 0.05) -> None:
        try:
            while not self._stop.is_set():
                self.step()
                time.sleep(poll_seconds)
        finally:
            self.server.stop()

    def stop(self) -> None:
        self._stop.set()


def serve_run(
    run_dir: str | Path,
    host: str = "127.0.0.1",
    port: int = 8080,
    device: str = "auto",
    data: str | None = None,
    max_side: int = 256,
    watch: bool = True,
    chunk: int = 4096,
    allow_outside_paths: bool = False,
    quiet: bool = False,
) -> None:
    """Serve a live viewer of ``run_dir`` until interrupted (Ctrl-C).

    Args:
        host: interface to listen on; anything but 127.0.0.1/localhost exposes the scene
            to the network (the ``view`` command should only pass it on an explicit flag).
        data: dataset for the training cameras (default: the run's own).
        max_side: longest side of the fully refined image (pixels).
        watch: re-load the newest checkpoint while training writes new ones.
        allow_outside_paths: read dataset images outside the dataset's folder.
        quiet: print neither the address nor notes (the warning of a viewer open to the
            network still goes to stderr).
    """
    from ..precision import resolve_device, resolve_precision
    from ..train.checkpoint import load_run, read_run
    from ._common import scene_for_run

    run_dir = Path(run_dir)
    info = read_run(run_dir)  # fails early, with one line, when RUN is not a run folder
    dev = resolve_device(device)
    scene = None
    try:
        scene = scene_for_run(info, data, allow_outside=allow_outside_paths)
    except NerfkitError as e:
        if not quiet:
            print(f"note: training cameras not shown ({e})", file=sys.stderr)

    def load(d: Path) -> tuple:
        model, loaded, step = load_run(d, dev)
        model.set_precision(resolve_precision(loaded.train.precision, dev))  # as render and eval draw it
        return model, loaded, step

    watcher = RunWatcher(run_dir, load, dev)
    viewer = LiveViewer(watcher, scene, host, port, max_side, chunk=chunk, watch=watch)
    port = viewer.server.get_port()  # the first free port from the one asked for
    from ..viz.viewer import LOCAL_HOSTS, viewer_url

    if host not in LOCAL_HOSTS:
        print(f"warning: listening on {host}: anyone who can reach port {port} can see this scene", file=sys.stderr)
    if not quiet:
        print(f"nerfkit viewer of {run_dir} at {viewer_url(host, port)} (Ctrl-C to stop)", flush=True)
    viewer.serve_forever()
