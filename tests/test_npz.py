"""The course npz loader: round trips, and one clear error per kind of broken file."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
import torch

from nerfkit.data.npz import load_npz, save_npz
from nerfkit.data.rays import RaysData, take_rows
from nerfkit.errors import NerfkitError


def course_arrays(n=4, size=8):
    rng = np.random.default_rng(0)
    c2w = np.tile(np.eye(4, dtype=np.float32), (n, 1, 1))
    c2w[:, :3, 3] = rng.normal(size=(n, 3)) + [0, 0, 4]
    return {
        "images_train": rng.integers(0, 255, (n, size, size, 3), dtype=np.uint8),
        "c2ws_train": c2w,
        "images_val": rng.integers(0, 255, (2, size, size, 3), dtype=np.uint8),
        "c2ws_val": c2w[:2],
        "c2ws_test": c2w[:3],
        "focal": np.float32(10.0),
    }


def write(tmp_path, **arrays):
    path = tmp_path / "scene.npz"
    np.savez(path, **arrays)
    return path


def ring_of_cameras(target, distance: float, n: int = 4) -> np.ndarray:
    """(n, 4, 4) float32 camera-to-world (OpenCV axes: z forward, y down) on a level ring of
    radius ``distance`` around ``target``, each looking at it."""
    c2w = np.tile(np.eye(4, dtype=np.float32), (n, 1, 1))
    for i, a in enumerate(np.linspace(0, 2 * np.pi, n, endpoint=False)):
        c, s = np.cos(a), np.sin(a)
        c2w[i, :3, 0], c2w[i, :3, 1], c2w[i, :3, 2] = (-s, c, 0), (0, 0, -1), (-c, -s, 0)
        c2w[i, :3, 3] = np.asarray(target) + distance * np.array([c, s, 0])
    return c2w


def test_course_layout_loads_with_focal_meaning_centered_principal_point(tmp_path):
    # no near/far stored: the cameras, 4 from the point they look at, give 0.5 x 4 and 1.5 x 4
    target = np.array([1.0, -2.0, 0.5])
    scene = load_npz(write(tmp_path, **{**course_arrays(), "c2ws_train": ring_of_cameras(target, 4.0)}))
    assert len(scene.train) == 4 and len(scene.val) == 2 and len(scene.test) == 3
    assert not scene.test.has_images
    assert np.allclose(scene.train.K[0], [[10, 0, 4], [0, 10, 4], [0, 0, 1]])
    np.testing.assert_allclose(scene.center, target, atol=1e-5)
    assert (scene.near, scene.far) == pytest.approx((2.0, 6.0), rel=1e-5)


def test_round_trip_keeps_cameras_images_names(tmp_path, sphere):
    save_npz(sphere, tmp_path / "s.npz")
    back = load_npz(tmp_path / "s.npz")
    for split in ("train", "val", "test"):
        a, b = sphere.splits[split], back.splits[split]
        assert np.allclose(a.c2w, b.c2w) and np.allclose(a.K, b.K) and a.names == b.names
    assert np.array_equal(sphere.train.images, back.train.images)
    assert (back.near, back.far) == (sphere.near, sphere.far)


def test_rays_data_uv_indexes_the_sampled_pixels(sphere):
    rays = RaysData(sphere.train, seed=0)
    batch = rays.sample(500)
    images = torch.from_numpy(sphere.train.images)
    pixels = images[batch.image_index, batch.uv[:, 1], batch.uv[:, 0]].float() / 255
    assert torch.equal(pixels, batch.rgb)
    # ray directions go through the pixel centres (uv + 0.5)
    i, (u, v) = int(batch.image_index[0]), batch.uv[0].tolist()
    K, c2w = sphere.train.K[i], sphere.train.c2w[i]
    d_cam = c2w[:3, :3].T @ batch.rays.directions[0].numpy()
    assert np.allclose(K @ (d_cam / d_cam[2]), [u + 0.5, v + 0.5, 1], atol=1e-3)
    per_image = rays.sample_from_images(64, 4)
    assert len(torch.unique(per_image.image_index)) == 4
    uneven = rays.sample_from_images(10, 3)  # as many rays as asked: 4, 3 and 3
    assert sorted(torch.unique(uneven.image_index, return_counts=True)[1].tolist()) == [3, 3, 4]
    assert len(rays.sample_from_images(7, 10 * rays.n_images).image_index) == 7  # more images asked than there are
    with pytest.raises(ValueError, match="at least one image"):
        rays.sample_from_images(7, 0)


def test_a_batch_holds_exactly_what_torch_indexing_of_the_stored_rays_gives(sphere):
    """The batch gathers through numpy on the CPU (take_rows); torch's own indexing is the reference."""
    rays = RaysData(sphere.train, seed=3)
    batch = rays.sample(777)
    img, uv = batch.image_index, batch.uv
    pix = uv[:, 1] * rays.width + uv[:, 0]
    assert torch.equal(batch.rays.origins, rays.c2w[img, :3, 3])
    assert torch.equal(batch.rays.directions, rays.directions[img, pix])
    assert torch.equal(batch.rgb, rays.images[img, uv[:, 1], uv[:, 0]].float() / 255.0)
    assert torch.equal(uv, rays.pixel_uv[pix])


@pytest.mark.parametrize("dtype", [torch.uint8, torch.int64, torch.float32, torch.float64])
def test_take_rows_equals_torch_indexing(dtype):
    table = (torch.arange(5 * 2 * 3) * 7 % 11).to(dtype).reshape(5, 2, 3)
    index = torch.tensor([4, 0, 0, 2, 4])
    for t in (table, table[:, 1, :], table[:, :, 2]):  # strided views too
        got = take_rows(t, index)
        assert torch.equal(got, t[index]) and got.dtype == t.dtype and got.is_contiguous()
    assert take_rows(table, index[:0]).shape == (0, 2, 3)


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda a: a.pop("c2ws_train"), "missing key 'c2ws_train'"),
        (lambda a: a.pop("focal"), "missing 'focal'"),
        (lambda a: a.update(c2ws_train=a["c2ws_train"][:3]), "has 4 images but 'c2ws_train' has 3 poses"),
        (lambda a: a.update(images_train=a["images_train"][..., :2]), "expected (N, H, W, 3)"),
        (lambda a: a.update(images_train=a["images_train"].astype(np.float32)), "expected [0, 1]"),
        (lambda a: a.update(images_train=a["images_train"].astype(np.int64)), "dtype int64"),
        (lambda a: a.update(focal=np.float32(-3)), "must be positive"),
        (lambda a: a.update(focal=np.float32(np.nan)), "'focal' is nan"),
        (lambda a: a["c2ws_train"].__setitem__((1, 0, 0), np.inf), "'c2ws_train'[1] has NaN or inf"),
        (lambda a: a["c2ws_train"].__setitem__((2, slice(0, 3), 0), 2.0), "'c2ws_train'[2] rotation is not rigid"),
        (lambda a: a["c2ws_train"].__setitem__((0, 3, 0), 1.0), "last row"),
        (lambda a: a.update(near=np.float32(5), far=np.float32(2)), "need 0 <= near < far"),
        (lambda a: a.update(near=np.float32(1)), "only one of 'near' and 'far'"),
        (lambda a: a.update(images_val=a["images_val"][:, :4]), "images are 8x4"),
        (lambda a: a.pop("c2ws_val"), "'images_val' is present but 'c2ws_val' is missing"),
        (lambda a: a.update(images_train=np.zeros((0, 8, 8, 3), np.uint8), c2ws_train=np.zeros((0, 4, 4))), "is empty"),
        (lambda a: a.update(K=np.array([[0.0, 0, 4], [0, 10, 4], [0, 0, 1]])), "zero or negative focal"),
        # K of the 4x larger images the 8x8 ones were downscaled from
        (lambda a: a.update(K=np.array([[40.0, 0, 16], [0, 40, 16], [0, 0, 1]])), "far outside the 8x8 image"),
        (lambda a: a.update(tags=np.zeros((2, 3, 3))), "'tags' must be (n, 4, 3) numbers"),
        (lambda a: a.update(tags=np.full((1, 4, 3), np.nan)), "'tags' holds non-finite"),
    ],
)
def test_broken_files_give_one_clear_error(tmp_path, mutate, message):
    arrays = course_arrays()
    mutate(arrays)
    path = write(tmp_path, **arrays)
    with pytest.raises(NerfkitError) as err:
        load_npz(path)
    assert message in str(err.value)
    assert str(path) in str(err.value)
    assert "\n" not in str(err.value)


def test_pickled_object_array_is_refused_without_running_it(tmp_path):
    class Boom:
        def __reduce__(self):
            return (exec, (f"open('{(tmp_path / 'pwned').as_posix()}', 'w').write('pwned')",))

    arrays = course_arrays()
    arrays["evil"] = np.array([Boom()], dtype=object)
    path = tmp_path / "evil.npz"
    np.savez(path, **arrays)
    with pytest.raises(NerfkitError, match="object array"):
        load_npz(path)
    assert not (tmp_path / "pwned").exists()
    pickle.loads(pickle.dumps(Boom()))  # the control: unpickled, the payload does run
    assert (tmp_path / "pwned").read_text() == "pwned"


@pytest.mark.parametrize("content", [b"", b"not a zip file at all", b"PK\x03\x04garbage"])
def test_non_npz_files_are_refused(tmp_path, content):
    path = tmp_path / "bad.npz"
    path.write_bytes(content)
    with pytest.raises(NerfkitError, match="not a valid .npz|cannot read|holds no arrays"):
        load_npz(path)


def test_truncated_npz_is_refused(tmp_path):
    path = write(tmp_path, **course_arrays(size=64))
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(NerfkitError, match=r"scene\.npz: not a valid \.npz file \(File is not a zip file\)"):
        load_npz(path)


def test_header_declaring_a_huge_array_is_refused_before_allocating(tmp_path):
    import zipfile

    path = write(tmp_path, **course_arrays())
    with zipfile.ZipFile(path) as zf:
        members = {n: zf.read(n) for n in zf.namelist()}
    raw = members["images_train.npy"]
    header_end = raw.index(b"\n") + 1  # the real header ends at the first newline
    d = "{'descr': '|u1', 'fortran_order': False, 'shape': (400000, 8000, 8000, 3), }"
    prefix = np.lib.format.magic(1, 0)
    d += " " * (63 - (len(prefix) + 2 + len(d)) % 64) + "\n"
    fake = prefix + len(d).to_bytes(2, "little") + d.encode() + raw[header_end:]
    members["images_train.npy"] = fake
    with zipfile.ZipFile(path, "w") as zf:
        for n, b in members.items():
            zf.writestr(n, b)
    with pytest.raises(NerfkitError, match="declares shape"):
        load_npz(path)


def test_a_centre_no_ray_reaches_is_refused_and_one_within_reach_is_kept(tmp_path):
    from dataclasses import replace

    from nerfkit.data.synthetic import sphere_scene

    scene = sphere_scene(n_train=3, n_val=1, size=8)  # cameras 4 from the origin, near 2, far 6
    for center, ok in (([1000.0, 0, 0], False), ([10.1, 0, 0], False), ([9.0, 0, 0], True), ([0.0, 0, 0], True)):
        save_npz(replace(scene, center=np.array(center, np.float32)), tmp_path / "s.npz")
        if ok:
            np.testing.assert_allclose(load_npz(tmp_path / "s.npz").center, center)
        else:
            with pytest.raises(NerfkitError, match=r"s\.npz: 'center' .* no ray reaches the object"):
                load_npz(tmp_path / "s.npz")


def test_a_scene_reaching_past_float32_training_is_refused(tmp_path):
    from dataclasses import replace

    from nerfkit.data.synthetic import sphere_scene

    scene = sphere_scene(n_train=3, n_val=1, size=8)  # cameras 4 from the origin
    far = replace(scene, train=replace(scene.train, c2w=scene.train.c2w * np.float32(1)))
    far.train.c2w[:, :3, 3] *= 1e7  # 4e7 units out: a grid over it divided by zero
    save_npz(replace(far, near=2e7, far=6e7, center=np.zeros(3, np.float32)), tmp_path / "far.npz")
    with pytest.raises(NerfkitError, match=r"far\.npz: its cameras or depth range reach 6e\+07 units"):
        load_npz(tmp_path / "far.npz")
