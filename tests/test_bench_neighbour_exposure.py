"""benchmarks/neighbour_exposure.py: the nearest training photos by direction, and the mean
of their colour corrections, which applied equals the mean of the corrected colours."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import torch

from nerfkit.cameras import look_at
from nerfkit.train.view_corrections import ExposureCorrection

_spec = importlib.util.spec_from_file_location(
    "neighbour_exposure", Path(__file__).resolve().parents[1] / "benchmarks" / "neighbour_exposure.py"
)
nx = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(nx)


def test_nearest_views_by_angle_from_the_centre():
    center = np.array([1.0, 2.0, 0.0])
    azimuths = np.radians([0, 40, 90, 170, 260])
    eyes = center + 3.0 * np.stack([np.cos(azimuths), np.sin(azimuths), np.full(5, 0.5)], 1)
    c2w = np.stack([look_at(e, center, np.array([0.0, 0, 1])) for e in eyes])
    dirs = nx.camera_directions(c2w, center)
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=1), 1.0)
    probe = np.array([np.cos(np.radians(80)), np.sin(np.radians(80)), 0.5])
    probe /= np.linalg.norm(probe)
    assert nx.nearest_views(dirs, probe, 3).tolist() == [2, 1, 0]  # 10, 40 and 80 degrees of azimuth away


def test_the_mean_correction_is_the_mean_of_the_corrected_colours():
    torch.manual_seed(0)
    ex = ExposureCorrection(5, mix=True)
    with torch.no_grad():
        for p in ex.parameters():
            p.normal_(0.0, 0.1)
        M, b = ex.matrices().numpy(), ex.centred()[1].numpy()
        rgb = torch.rand(100, 3)
        idx = np.array([4, 1])
        each = [ex(rgb, torch.full((100,), int(i), dtype=torch.long)).numpy() for i in idx]
    Mk, bk = nx.mean_correction(M, b, idx)
    np.testing.assert_allclose(rgb.numpy() @ Mk.T + bk, np.mean(each, 0), atol=1e-6)
    Mone, bone = nx.mean_correction(M, b, idx[:1])
    np.testing.assert_allclose(rgb.numpy() @ Mone.T + bone, each[0], atol=1e-6)
    # the Gaussian's correction half-way between photos 4 and 1 (others far off) is their mean too
    dirs = np.array([[0.0, 0, -1], [1.0, 0, 0], [0, 0, -1], [0, 0, -1], [0.0, 1, 0]])
    kernel = nx.DirectionalColour(dirs, M.astype(np.float64), b.astype(np.float64), np.zeros(3), np.radians(10.0))
    between = np.eye(4)
    between[:3, 3] = [1.0, 1.0, 0.0]
    Mw, bw = kernel.correction(between)
    np.testing.assert_allclose(rgb.numpy() @ Mw.T + bw, np.mean(each, 0), atol=1e-6)
