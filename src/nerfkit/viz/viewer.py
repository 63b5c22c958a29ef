"""Interactive dataset viewer in the browser (viser).

Shows every camera as a frustum textured with its image, the world axes, the tag plane
(the world's z = 0, perpendicular to the scene's up), the scene centre, and on request
training rays with their stratified samples (the course's visual sanity check).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..cameras import axes_across
from ..data.scene import Scene
from .scene_plot import SPLIT_COLORS, printed_tags, sample_rays, scene_scale

# the addresses that only this machine reaches (any other --host is warned about)
LOCAL_HOSTS = ("127.0.0.1", "localhost", "::1")


def viewer_url(address: str, port: int) -> str:
    """The address to open in a browser for a viewer listening on ``address`` (an IPv6 one
    in brackets; this machine's names as 127.0.0.1)."""
    shown = "127.0.0.1" if address in ("127.0.0.1", "localhost") else f"[{address}]" if ":" in address else address
    return f"http://{shown}:{port}"


def _wxyz(R: np.ndarray) -> np.ndarray:
    import viser.transforms as vtf

    return vtf.SO3.from_matrix(np.asarray(R, np.float64)).wxyz


def _thumbnail(image: np.ndarray, max_side: int) -> np.ndarray:
    """(h, w, 3) uint8 ``image`` shrunk (Pillow, box filter) to at most ``max_side`` a side."""
    from PIL import Image

    s = max_side / max(image.shape[:2])
    if s >= 1:
        return image
    size = (max(1, round(image.shape[1] * s)), max(1, round(image.shape[0] * s)))
    return np.asarray(Image.fromarray(image).resize(size, Image.Resampling.BOX))


def require_viser():
    """The viser module, or a NerfkitError saying how to install it."""
    from ..errors import fail

    try:
        import viser
    except ImportError:
        raise fail("nerfkit view", "the browser viewer needs viser", "pip install 'nerfkit[viewer]'") from None
    return viser


def listening_port(host: str = "127.0.0.1", port: int = 8080, tries: int = 100) -> int:
    """The first port from ``port`` on that ``host`` can listen on (viser moves to the next
    free one too, but from its own thread, where a host this machine cannot listen on left the
    caller waiting). Refuses an empty host, a name that does not resolve, an address that
    is not this machine's, and no free port among ``tries``."""
    import errno
    import socket

    from ..errors import fail

    if not host.strip():
        raise fail(
            "--host", "is empty", "Give an address, e.g. 127.0.0.1 (this machine only) or 0.0.0.0 (every network)"
        )
    try:
        family, kind, proto, _, address = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
    except (socket.gaierror, UnicodeError) as e:
        raise fail(
            "--host", f"'{host}' does not resolve to an address ({e})", "Give an address such as 127.0.0.1"
        ) from None
    last = port
    for last in range(port, min(port + tries, 65536)):
        with socket.socket(family, kind, proto) as sock:
            try:
                sock.bind((address[0], last, *address[2:]))
                return last
            except OSError as e:
                if e.errno != errno.EADDRINUSE:
                    raise fail(
                        "--host",
                        f"cannot listen on {host} ({e.strerror or e})",
                        "Give an address this machine has, e.g. 127.0.0.1",
                    ) from None
    raise fail("--port", f"ports {port} to {last} on {host} are all taken", "Pick another --port")


def populate(
    server,
    scene: Scene,
    n_rays: int = 0,
    n_samples: int = 64,
    tag_size: float | None = None,
    image_max_side: int = 256,
    seed: int = 0,
    rays_from: int | None = None,
) -> dict:
    """Add the scene to a viser server; returns the handles by kind (for updates and tests)."""
    up = np.asarray(scene.up, np.float64)
    server.scene.set_up_direction(tuple(float(u) for u in up))
    scale = scene_scale(scene)
    handles: dict = {"frustums": [], "rays": None, "samples": None, "points": None}
    handles["axes"] = server.scene.add_frame(
        "/world",
        axes_length=1.5 * tag_size if tag_size else 0.25 * scale,
        axes_radius=0.02 * (1.5 * tag_size if tag_size else 0.25 * scale),
    )
    a, b = axes_across(up)
    R_plane = np.column_stack([a, b, up / np.linalg.norm(up)])
    handles["plane"] = server.scene.add_grid(
        "/tag_plane",
        width=scale,
        height=scale,
        cell_size=scale / 10,
        section_size=scale / 2,
        plane="xy",
        wxyz=_wxyz(R_plane),
        plane_color=(200, 200, 200),
        plane_opacity=0.25,
    )
    tags = printed_tags(scene, tag_size)
    if tags is not None:  # the printed tags, a hair above the plane
        verts = (tags + up * 1e-4).reshape(-1, 3)
        faces = (np.array([[0, 1, 2], [0, 2, 3]]) + 4 * np.arange(len(tags))[:, None, None]).reshape(-1, 3)
        handles["tag"] = server.scene.add_mesh_simple(
            "/tag", verts.astype(np.float32), faces.astype(np.uint32), color=(20, 20, 20), side="double"
        )
    handles["center"] = server.scene.add_icosphere(
        "/center", radius=0.01 * scale, color=(220, 0, 220), position=tuple(float(c) for c in scene.center)
    )
    if scene.points is not None and len(scene.points):  # the dataset's sparse points, in their colours
        handles["points"] = server.scene.add_point_cloud(
            "/sparse_points", scene.points.astype(np.float32), colors=scene.point_colors, point_size=0.004 * scale
        )
    for split, v in scene.splits.items():
        color = tuple(int(255 * c) for c in SPLIT_COLORS.get(split, (0, 0, 0)))
        for i in range(len(v)):
            c2w = v.c2w[i].astype(np.float64)
            K = v.K[i]
            img = None if v.images is None else _thumbnail(v.images[i], image_max_side)
            name = f"{i:04d}" + (f"_{Path(v.names[i]).stem}" if v.names is not None else "")
            h = server.scene.add_camera_frustum(
                f"/cameras/{split}/{name}",  # the index first: two folders' frame.jpg are two cameras
                fov=float(2 * np.arctan2(v.height / 2, K[1, 1])),
                aspect=v.width / v.height,
                scale=0.1 * scale,
                thickness=0.004 * scale,
                color=color,
                image=img,
                wxyz=_wxyz(c2w[:3, :3]),
                position=tuple(c2w[:3, 3]),
            )
            handles["frustums"].append(h)
    set_rays(server, scene, handles, n_rays, n_samples, seed, rays_from)
    return handles


def set_rays(
    server, scene: Scene, handles: dict, n_rays: int, n_samples: int, seed: int = 0, rays_from: int | None = None
) -> None:
    """Replace the shown rays and samples with ``n_rays`` new ones (0 removes them), of
    training view ``rays_from`` only when given."""
    for key in ("rays", "samples"):
        if handles.get(key) is not None:
            handles[key].remove()
            handles[key] = None
    if n_rays <= 0 or len(scene.train) == 0:
        return
    rs = sample_rays(scene.train, scene.near, scene.far, n_rays, n_samples, seed, rays_from)
    rng = np.random.default_rng(seed)
    cols = rng.integers(60, 255, (n_rays, 3)).astype(np.uint8)
    scale = scene_scale(scene)
    handles["rays"] = server.scene.add_line_segments(
        "/rays/lines", rs.segments.astype(np.float32), np.repeat(cols[:, None], 2, axis=1), thickness=0.002 * scale
    )
    handles["samples"] = server.scene.add_point_cloud(
        "/rays/samples",
        rs.points.reshape(-1, 3).astype(np.float32),
        np.repeat(cols, rs.points.shape[1], axis=0),
        point_size=0.006 * scale,
        precision="float32",
    )


def serve_dataset(
    scene: Scene,
    host: str = "127.0.0.1",
    port: int = 8080,
    n_rays: int = 0,
    n_samples: int = 64,
    tag_size: float | None = None,
    block: bool = True,
    rays_from: int | None = None,
):
    """Start a viser server showing ``scene``; with ``block`` wait until Ctrl-C, then stop.

    Returns ``(server, handles)`` (after stopping, when blocking). The server listens on the
    first free port from ``port`` (:func:`listening_port`): ``server.get_port()`` tells which.
    """
    viser = require_viser()
    server = viser.ViserServer(host=host, port=listening_port(host, port), verbose=False)
    try:
        handles = populate(server, scene, n_rays, n_samples, tag_size, rays_from=rays_from)
        with server.gui.add_folder("rays"):  # the sliders reach the counts given, however many
            n_in = server.gui.add_slider("rays", min=0, max=max(1000, int(n_rays)), step=1, initial_value=int(n_rays))
            s_in = server.gui.add_slider(
                "samples per ray",
                min=min(2, int(n_samples)),
                max=max(128, int(n_samples)),
                step=1,
                initial_value=int(n_samples),
            )
            again = server.gui.add_button("new random rays")
    except BaseException:
        server.stop()
        raise
    state = {"seed": 0}

    def refresh(_=None) -> None:
        set_rays(server, scene, handles, int(n_in.value), int(s_in.value), state["seed"], rays_from)

    def reseed(_=None) -> None:
        state["seed"] += 1
        refresh()

    n_in.on_update(refresh)
    s_in.on_update(refresh)
    again.on_click(reseed)
    handles["gui"] = {"rays": n_in, "samples": s_in, "resample": again}
    if block:
        wait_until_interrupted(server)
    return server, handles


def wait_until_interrupted(server) -> None:
    """Keep serving until Ctrl-C, then stop the server."""
    import time

    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()
