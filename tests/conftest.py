"""Shared fixtures: tiny generated scenes (tests never read ../shared)."""

from __future__ import annotations

import os

import pytest

from nerfkit.data.npz import save_npz
from nerfkit.data.synthetic import sphere_scene

if os.environ.get("PYTEST_XDIST_WORKER"):  # `make test` runs one worker per core: one thread each
    import torch

    torch.set_num_threads(1)


def tiny_vanilla(samples: int = 8, width: int = 16, **more) -> list[str]:
    """`nerfkit train` flags of a tiny course NeRF (2 layers, one eval view) for tests that only
    need a run; ``more`` adds flags (``batch_rays=64`` -> ``--batch-rays 64``)."""
    flags = ["--model", "vanilla", "--n-samples", str(samples), "--width", str(width), "--depth", "2"]
    for name, value in more.items():
        flags += ["--" + name.replace("_", "-"), str(value)]
    return [*flags, "--eval-views", "1"]


def tiny_vanilla_configs(out, steps: int, data: str = "x", batch_rays: int = 16, **train):
    """``(TrainConfig, VanillaConfig)`` of a tiny course NeRF run into ``out`` (4 samples, 8 wide,
    2 layers, one eval view, no timed checkpoints) for tests that drive the trainer in-process;
    ``train`` sets more TrainConfig fields."""
    from nerfkit.models.vanilla import VanillaConfig
    from nerfkit.train.config import TrainConfig

    cfg = TrainConfig(
        data=data,
        model="vanilla",
        out=str(out),
        steps=steps,
        batch_rays=batch_rays,
        lr=1e-3,
        eval_views=1,
        checkpoint_seconds=1e9,
        **train,
    )
    return cfg, VanillaConfig(n_samples=4, width=8, depth=2)


@pytest.fixture(scope="session")
def sphere():
    """20 training and 2 validation 32x32 views of a textured sphere."""
    return sphere_scene(n_train=20, n_val=2, size=32)


@pytest.fixture(scope="session")
def sphere_npz(tmp_path_factory, sphere):
    path = tmp_path_factory.mktemp("data") / "sphere.npz"
    save_npz(sphere, path)
    return path


def train_loop(model, scene, steps: int, batch: int = 1024, lr: float = 0.3, seed: int = 0, background=(0.0, 0.0, 0.0)):
    """The trainer's protocol, minimal: the model's schedules, the optimizer built from its
    parameter groups (a job that replaces parameters swaps them into it), each batch's pixels
    told to the model before its loss, a constant lr. Returns the optimizer."""
    import torch

    from nerfkit.data.rays import RaysData
    from nerfkit.models.base import StepState, run_schedules
    from nerfkit.train.optim import build_optimizer

    torch.manual_seed(seed)
    rays = RaysData(scene.train, "cpu", seed=seed)
    bg = torch.tensor(background)
    opt = build_optimizer(model, lr)
    schedules = model.schedules()
    shape = (rays.n_images, rays.width, rays.height)
    for step in range(steps):
        run_schedules(schedules, StepState(step, step / steps, opt), phase="before_step")
        batch_ = rays.sample(batch)
        out = model.render_rays(batch_.rays, bg, perturb=True)
        model.see_batch(step / steps, batch_.image_index, batch_.uv, shape)
        loss = model.loss(out, batch_.rgb)
        opt.zero_grad()
        loss.backward()
        after = StepState(step, step / steps, opt, batch_.rays, out)
        run_schedules(schedules, after, phase="gradients")
        opt.step()
        run_schedules(schedules, after, phase="after_step")
    return opt


def draw_dots(width: int, height: int, uv, sigma: float = 0.8):
    """(height, width, 3) float image in [0, 1] of smooth dots centred at the pixel positions
    ``uv`` (n, 2) (pixel centres at +0.5): each dot's centroid is its position."""
    import numpy as np

    img = np.zeros((height, width, 3))
    rows, cols = np.mgrid[0:height, 0:width] + 0.5
    for u, v in uv:
        img += np.exp(-((cols - u) ** 2 + (rows - v) ** 2) / (2 * sigma**2))[..., None]
    return np.clip(img, 0, 1)


def dot_centroid_errors(image, expected_uv, margin: int = 4) -> list[float]:
    """Pixel distance from each expected dot position (n, 2) to the brightness centroid of
    ``image`` (H, W, 3) within 3 px of it; dots within ``margin`` px of the border are left out."""
    import numpy as np

    out = np.asarray(image, np.float64).mean(-1)
    rows, cols = np.mgrid[0 : out.shape[0], 0 : out.shape[1]] + 0.5
    errs = []
    for u, v in expected_uv:
        if u < margin or v < margin or u > out.shape[1] - margin or v > out.shape[0] - margin:
            continue
        wgt = out * ((np.abs(cols - u) < 3) & (np.abs(rows - v) < 3))
        errs.append(float(np.hypot((wgt * cols).sum() / wgt.sum() - u, (wgt * rows).sum() / wgt.sum() - v)))
    return errs


def write_mp4(path, frames, fps: int = 10, macro_block_size: int = 8) -> None:
    """Write ``frames`` (list of (H, W, 3) uint8) as an H.264 MP4 at ``fps``, nearly lossless."""
    import imageio_ffmpeg
    import numpy as np

    h, w = frames[0].shape[:2]
    writer = imageio_ffmpeg.write_frames(
        str(path),
        (w, h),
        fps=fps,
        codec="libx264",
        pix_fmt_out="yuv420p",
        macro_block_size=macro_block_size,
        output_params=["-crf", "16"],
        ffmpeg_log_level="error",
    )
    writer.send(None)
    for f in frames:
        writer.send(np.ascontiguousarray(f))
    writer.close()


def sigint_as_a_terminal_gives_it() -> None:
    """A child's ``preexec_fn``: SIGINT handled by default, as a terminal's Ctrl-C finds it,
    even when the test run itself was started with SIGINT ignored (a background job)."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_DFL)


def fibonacci_sphere(n: int) -> torch.Tensor:
    """n nearly uniform unit directions (equal-area rows of a golden-angle spiral), float64."""
    import math

    import torch

    i = torch.arange(n, dtype=torch.float64) + 0.5
    z = 1 - 2 * i / n
    phi = math.pi * (1 + 5**0.5) * i
    r = torch.sqrt(1 - z * z)
    return torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], -1)
