"""A splat model's learned background carried into its splat file as a dome of Gaussians:
the exported PLY, read back without nerfkit's reader and drawn over black, renders what the
model renders over its learned background."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from nerfkit.capture.dome import DOME_GAUSSIANS, DOME_SCALE, background_dome, dome_radius, fibonacci_sphere
from nerfkit.capture.splats import object_box, write_object_splat
from nerfkit.commands.stages.export import export_splat
from nerfkit.kernels.splat_reference import quat_to_rotmat
from nerfkit.models.base import SceneBounds
from nerfkit.models.splat import SplatConfig, SplatModel
from nerfkit.splat_files import Gaussians
from nerfkit.train.metrics import psnr

W, H = 64, 48
K = np.array([[0.9 * W, 0, W / 2], [0, 0.9 * W, H / 2], [0, 0, 1]])
BOUNDS = SceneBounds(
    near=1.0, far=5.0, center=np.zeros(3), radius=1.0, up=np.array([0, 0, 1.0]), camera_radius=3.0,
    object_box=(np.array([-0.6, -0.6, -0.6]), np.array([0.6, 0.6, 0.6])),
)  # fmt: skip


def look_at(eye, target) -> np.ndarray:
    """(4, 4) camera-to-world (OpenCV axes) at ``eye`` looking at ``target``, z up."""
    eye = np.asarray(eye, float)
    f = np.asarray(target, float) - eye
    f /= np.linalg.norm(f)
    r = np.cross(f, [0, 0, 1.0])
    r /= np.linalg.norm(r)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = r, np.cross(f, r), f, eye
    return c2w


# on the cameras' sphere looking at the centre; off it, looking past the centre; from above, askew
POSES = [
    look_at((3, 0, 0.5), (0, 0, 0)),
    look_at((1.5, -2.5, 1.0), (0.5, 0.3, 0.2)),
    look_at((0, 0.3, 2.9), (0.6, 0.1, 0)),
]


def captured_model(learn_background: bool = True) -> SplatModel:
    """Twenty Gaussians in the object's box, in front of a background with every SH degree."""
    m = SplatModel(SplatConfig(learn_background=learn_background, init_points=20, kernels="torch"), BOUNDS)
    g = torch.Generator().manual_seed(1)
    with torch.no_grad():
        m.means.mul_(0.5)
        m.log_scales.fill_(math.log(0.15))
        m.opacity_logits.fill_(2.0)
        m.sh_dc.copy_(torch.randn(m.sh_dc.shape, generator=g))
        if m.bg_coef is not None:
            amplitude = torch.tensor([0.5] + [0.8] * 3 + [0.5] * 5 + [0.3] * 7)
            m.bg_coef.copy_(torch.randn(3, 16, generator=g) * amplitude)
    m.active_degree = 3
    return m.eval()


def read_ply(path) -> Gaussians:
    """A 3DGS PLY read with plyfile alone (INRIA's layout: f_rest channel-major)."""
    from plyfile import PlyData

    v = PlyData.read(str(path))["vertex"]

    def cols(*names):
        return np.stack([np.asarray(v[k], np.float32) for k in names], 1)

    n = len(v.data)
    n_rest = len([p for p in v.properties if p.name.startswith("f_rest_")]) // 3
    rest = cols(*[f"f_rest_{i}" for i in range(3 * n_rest)]).reshape(n, 3, n_rest).transpose(0, 2, 1)
    return Gaussians(
        cols("x", "y", "z"),
        cols("scale_0", "scale_1", "scale_2"),
        cols("rot_0", "rot_1", "rot_2", "rot_3"),
        np.asarray(v["opacity"], np.float32),
        cols("f_dc_0", "f_dc_1", "f_dc_2").reshape(n, 1, 3),
        np.ascontiguousarray(rest),
    )


def over_black(g: Gaussians, c2w: np.ndarray) -> np.ndarray:
    """``g`` drawn by the plain-torch reference rasterizer over black, by a model with no
    learned background."""
    plain = SplatModel(SplatConfig(learn_background=False, init_points=1, kernels="torch"), BOUNDS)
    plain.set_gaussians(g)
    plain.active_degree = 3
    with torch.no_grad():
        return plain.eval().render_view(K, c2w, W, H, torch.zeros(3)).rgb.numpy()


def own_render(m: SplatModel, c2w: np.ndarray) -> np.ndarray:
    with torch.no_grad():
        return m.render_view(K, c2w, W, H, torch.ones(3)).rgb.numpy()


def export(m: SplatModel, path, dome: bool = True) -> str:
    return export_splat(SimpleNamespace(model=m, info=SimpleNamespace(bounds=BOUNDS), step=7), str(path), dome)


def test_the_exported_ply_renders_the_learned_background_over_black(tmp_path):
    m = captured_model()
    line = export(m, tmp_path / "splat.ply")
    assert f"and {DOME_GAUSSIANS} of the learned background's dome" in line
    g = read_ply(tmp_path / "splat.ply")
    assert len(g) == m.n_gaussians + DOME_GAUSSIANS
    export(m, tmp_path / "bare.ply", dome=False)
    bare = read_ply(tmp_path / "bare.ply")
    assert len(bare) == m.n_gaussians
    for c2w in POSES:
        own = own_render(m, c2w)
        # measured 37.9 to 44.8 dB at these poses (the dome's discs blend neighbouring
        # directions and leave about 1% uncovered); without the dome the background is black
        assert psnr(over_black(g, c2w), own) > 36
        assert psnr(over_black(bare, c2w), own) < 20


def test_the_dome_is_a_closed_far_shell_of_flat_gaussians_facing_the_centre():
    r = dome_radius(BOUNDS.radius, BOUNDS.far, BOUNDS.camera_radius)
    assert r == DOME_SCALE * 5.0  # the far bound is the farthest of the three
    coef = np.zeros((3, 16))
    coef[:, 3] = [2.0, 0.0, -2.0]  # red above, blue below
    d = background_dome(np.array([1.0, 2.0, 3.0]), r, coef, n=500)
    radial = d.means - [1.0, 2.0, 3.0]
    dist = np.linalg.norm(radial, axis=1)
    np.testing.assert_allclose(dist, r, rtol=1e-5)
    # each disc's thin axis (its local z) points along the radius
    normals = quat_to_rotmat(torch.as_tensor(d.quats))[:, :, 2].numpy()
    np.testing.assert_allclose(np.abs(np.sum(normals * radial / dist[:, None], 1)), 1, atol=1e-5)
    s = np.exp(d.log_scales)
    assert np.all(s[:, 2] < 0.05 * s[:, 0]) and np.allclose(s[:, 0], s[:, 1])
    # colour (DC only): the background's in each one's direction
    rgb = 0.5 + 0.28209479177387814 * d.sh_dc[:, 0]
    z = radial[:, 2] / dist
    np.testing.assert_allclose(rgb[:, 0], 1 / (1 + np.exp(-2 * z)), atol=1e-5)
    np.testing.assert_allclose(rgb[:, 2], 1 / (1 + np.exp(2 * z)), atol=1e-5)
    assert not d.sh_rest.any()
    # the centres cover the sphere: every direction is within a spacing of one
    probe = fibonacci_sphere(2000) @ np.diag([1, -1, 1])
    nearest = np.arccos(np.clip((probe @ (radial / dist[:, None]).T).max(1), -1, 1))
    assert nearest.max() < math.sqrt(4 * math.pi / 500)


@pytest.mark.parametrize("learned", [True, False])
def test_the_object_crop_and_dot_splat(tmp_path, learned):
    """The object alone has no dome Gaussian; the .splat carries the dome too; a model without
    a learned background gets none."""
    m = captured_model(learned)
    export(m, tmp_path / "splat.ply")
    export(m, tmp_path / "splat.splat")
    dome = DOME_GAUSSIANS if learned else 0
    assert (tmp_path / "splat.splat").stat().st_size == 32 * (m.n_gaussians + dome)
    lo, hi, _ = object_box(BOUNDS)
    kept, total = write_object_splat(tmp_path / "splat.ply", tmp_path / "alone.ply", (lo, hi))
    assert total == m.n_gaussians + dome
    alone = read_ply(tmp_path / "alone.ply")
    # the object's Gaussians only, none of the dome's (which ones a box keeps, exactly: the
    # crop's own test in test_capture_video)
    model_means = set(map(tuple, m.means.detach().numpy().tolist()))
    assert kept == len(alone) > 0 and set(map(tuple, alone.means.tolist())) <= model_means
