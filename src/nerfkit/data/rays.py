"""Training ray batches drawn from a split's pixels."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from ..cameras import Rays, pixel_to_ray
from .scene import Views


def take_rows(table: Tensor, index: Tensor) -> Tensor:
    """``table[index]``: the rows (n, ...) of ``table`` at ``index`` (n,) int64.

    On the CPU through numpy, which gathers on the calling thread: torch's indexing wakes
    its thread pool for each gather, and on busy cores each wake-up waited about 10 ms (four
    such gathers a step were a fifth of a training step of the ``fast`` model, 2 loaded
    cores; ``benchmarks/step_profile.py``).
    """
    if table.device.type != "cpu" or index.device.type != "cpu":
        return table[index]
    return torch.from_numpy(np.ascontiguousarray(table.numpy()[index.numpy()]))


@dataclass
class RayBatch:
    """Rays with their ground-truth pixels.

    Attributes:
        rays: n_rays rays.
        rgb: (n_rays, 3) float32 colours in [0, 1].
        image_index: (n_rays,) which view each ray comes from.
        uv: (n_rays, 2) integer pixel (column, row); the ray goes through ``uv + 0.5``.
    """

    rays: Rays
    rgb: Tensor
    image_index: Tensor
    uv: Tensor


class RaysData:
    """Every pixel ray of a split, precomputed, and random batches of them.

    Directions are precomputed for all pixels ((N*H*W, 3) float32); origins are looked
    up from the camera centres; pixels stay uint8 until a batch is drawn.
    """

    def __init__(self, views: Views, device: torch.device | str = "cpu", seed: int = 0):
        if not views.has_images:
            raise ValueError("RaysData needs a split with images")
        images = views.images
        assert images is not None  # has_images
        shape = (len(views), views.height, views.width, 3)
        if images.dtype != np.uint8 or images.shape != shape:
            raise ValueError(
                f"RaysData takes images of (N, H, W, 3) = {shape} uint8, got {images.shape} "
                f"{images.dtype} (floats in [0, 1]: (images * 255 + 0.5).astype(np.uint8))"
            )
        self.device = torch.device(device)
        self.n_images, self.height, self.width = len(views), views.height, views.width
        self.images = torch.from_numpy(np.ascontiguousarray(views.images)).to(self.device)  # (N, H, W, 3) uint8
        self.c2w = torch.from_numpy(views.c2w).float().to(self.device)
        self.K = torch.from_numpy(views.K).float().to(self.device)
        rows, cols = torch.meshgrid(torch.arange(self.height), torch.arange(self.width), indexing="ij")
        self.pixel_uv = torch.stack([cols, rows], -1).reshape(-1, 2).to(self.device)  # (H*W, 2) int
        uv = self.pixel_uv.float() + 0.5
        dirs = []
        for i in range(self.n_images):
            _, d = pixel_to_ray(self.K[i], self.c2w[i], uv)
            dirs.append(d)
        self.directions = torch.stack(dirs)  # (N, H*W, 3)
        self.generator = torch.Generator(device="cpu").manual_seed(seed)

    def __len__(self) -> int:
        return self.n_images * self.height * self.width

    def _batch(self, img: Tensor, pix: Tensor) -> RayBatch:
        img, pix = img.to(self.device), pix.to(self.device)
        flat = img * (self.height * self.width) + pix
        uv = take_rows(self.pixel_uv, pix)
        rgb = take_rows(self.images.reshape(-1, 3), flat).float() / 255.0
        rays = Rays(take_rows(self.c2w[:, :3, 3], img), take_rows(self.directions.reshape(-1, 3), flat))
        return RayBatch(rays, rgb, img, uv)

    def sample(self, n_rays: int) -> RayBatch:
        """``n_rays`` rays drawn uniformly from all pixels of all images."""
        flat = torch.randint(0, len(self), (n_rays,), generator=self.generator)
        hw = self.height * self.width
        return self._batch(flat // hw, flat % hw)

    def sample_from_images(self, n_rays: int, n_images: int) -> RayBatch:
        """``n_rays`` rays from ``m = min(n_images, all)`` random images: ``n_rays // m`` each,
        one more from the first ``n_rays % m``."""
        if n_images < 1:
            raise ValueError(f"sample_from_images needs at least one image, got n_images={n_images}")
        imgs = torch.randperm(self.n_images, generator=self.generator)[:n_images]
        per = torch.full((len(imgs),), n_rays // len(imgs), dtype=torch.long)
        per[: n_rays % len(imgs)] += 1
        img = imgs.repeat_interleave(per)
        pix = torch.randint(0, self.height * self.width, (img.numel(),), generator=self.generator)
        return self._batch(img, pix)

    def rng_state(self) -> Tensor:
        return self.generator.get_state()

    def set_rng_state(self, state: Tensor) -> None:
        self.generator.set_state(state)
