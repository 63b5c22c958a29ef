"""What a run shows its user: depth colours and image grids (contact sheets)."""

import numpy as np
import pytest


def test_depth_colours_near_warm_far_cool_and_what_rays_do_not_meet():
    from matplotlib import colormaps

    from nerfkit.output.images import RenderedView
    from nerfkit.viz.video import colorize_depth

    warm, cool = (np.array(colormaps["turbo"](x)[:3]) for x in (1.0, 0.0))
    depth = np.array([[2.0, 6.0, 4.0, 9.0]])
    acc = np.array([[1.0, 1.0, 0.0, 0.5]])
    img = colorize_depth(depth, acc, 2.0, 6.0)
    np.testing.assert_allclose(img[0, 0], warm, atol=1e-6)
    np.testing.assert_allclose(img[0, 1], cool, atol=1e-6)
    assert (img[0, 2] == 0).all()  # met nothing: empty, black
    np.testing.assert_allclose(img[0, 3], 0.5 * cool, atol=1e-6)  # beyond far: clipped, half met
    # a scene closed by its surroundings: what the rays do not meet is infinitely far
    closed = colorize_depth(depth, acc, 2.0, 6.0, unmet_is_far=True)
    np.testing.assert_allclose(closed[0, 2], cool, atol=1e-6)
    np.testing.assert_allclose(closed[0, 3], cool, atol=1e-6)
    np.testing.assert_allclose(closed[0, :2], img[0, :2])
    # a rendered view colours the depth of everything when the model drew surfaces behind its volume
    view = RenderedView(np.zeros((1, 4, 3)), depth, acc)
    np.testing.assert_allclose(view.depth_colours(2.0, 6.0), img)
    view.scene_depth, view.scene_acc = np.full((1, 4), 2.0), np.ones((1, 4))
    np.testing.assert_allclose(view.depth_colours(2.0, 6.0), np.broadcast_to(warm, (1, 4, 3)), atol=1e-6)


def test_depth_scale_bar_is_the_depth_colours_from_near_to_far():
    from nerfkit.images import to_uint8
    from nerfkit.viz.video import colorize_depth, depth_label, depth_scale

    near, far, width = 0.2, 0.6, 320
    strip = depth_scale(width, near, far, metres=True)
    assert strip.shape[1:] == (width, 3) and strip.shape[0] >= 24
    # column x of the bar is the colour of depth near + (far - near) x / (width - 1)
    depths = near + (far - near) * np.linspace(0.0, 1.0, width)[None]
    expected = to_uint8(colorize_depth(depths, np.ones_like(depths), near, far))[0]
    assert np.abs(strip[2].astype(int) - expected).max() <= 1
    # the labels sit below the bar, at both ends
    text = strip[strip.shape[0] // 2 + 2 :]
    assert text[:, : width // 4].max() > 128 and text[:, -width // 4 :].max() > 128
    # a narrow frame: the two labels never run into each other (a dark gap between them)
    for narrow in (100, 60, 45):
        strip = depth_scale(narrow, 2.02, 6.05, metres=False)
        columns = np.flatnonzero((strip[strip.shape[0] // 2 + 2 :] > 64).any(axis=(0, 2)))
        assert np.diff(columns).max() > 5, narrow  # a gap wider than between two letters
    assert [depth_label(v, True) for v in (0.214, 0.05, 2.5)] == ["21 cm", "5.0 cm", "2.50 m"]
    assert depth_label(3.14159, False) == "3.14"


def test_image_grid_tiles_follow_the_photos_shape_and_the_contact_sheet_their_size(tmp_path):
    """Landscape photos get landscape tiles (not letterboxed in squares), and the contact
    sheet shows each photo about as many pixels wide as it has, up to 640."""
    import imageio.v3 as iio

    from nerfkit.commands.eval import write_contact_sheet
    from nerfkit.viz.plots import GRID_DPI, image_grid, native_tile_inches

    wide, square = np.zeros((300, 400, 3)), np.zeros((400, 400, 3))
    image_grid(tmp_path / "wide.png", [wide, wide], ["a", "b"], tile_inches=4.0)
    image_grid(tmp_path / "square.png", [square, square], ["a", "b"], tile_inches=4.0)
    (hw, ww), (hs, ws) = (iio.imread(tmp_path / f"{n}.png").shape[:2] for n in ("wide", "square"))
    assert ww == ws and hs - hw == round(GRID_DPI * 4.0 * 0.25)  # a quarter of a tile less per row
    assert native_tile_inches(np.zeros((384, 512, 3))) * GRID_DPI == pytest.approx(512)
    assert native_tile_inches(np.zeros((3000, 4000, 3))) * GRID_DPI == pytest.approx(640)
    assert native_tile_inches(np.zeros((6, 8, 3))) * GRID_DPI == pytest.approx(240)  # room for the titles
    # no title overprints a tile: every tile of a 2-row grid stays a whole red rectangle
    from scipy import ndimage

    red = np.zeros((384, 512, 3))
    red[..., 0] = 1.0
    image_grid(tmp_path / "rows.png", [red] * 8, [f"step {k}" for k in range(8)], ncols=5, suptitle="progress")
    png = iio.imread(tmp_path / "rows.png")[..., :3].astype(int)
    tiles, n = ndimage.label((png[..., 0] > 200) & (png[..., 1] < 60) & (png[..., 2] < 60))
    assert n == 8
    for box in ndimage.find_objects(tiles):
        assert (tiles[box] > 0).all()  # a full rectangle: no text over it
    photo = np.full((240, 320, 3), 0.5)
    write_contact_sheet(
        tmp_path / "sheet.png", [(photo, photo, None, {"name": "a.jpg", "index": 0, "psnr": 20.0})], "val"
    )
    assert 2 * 320 <= iio.imread(tmp_path / "sheet.png").shape[1] <= 2 * 320 + 40


def test_an_object_video_is_framed_on_the_object_with_its_own_depth_range():
    """The unit sphere seen small and off-centre from cameras 6 away: after framing it
    fills 80% of every frame's height, centred, and the depth range is the sphere's."""
    import torch

    from nerfkit.cameras import look_at
    from nerfkit.data.scene import Views
    from nerfkit.models.base import RenderOutput, SceneBounds
    from nerfkit.output.images import frame_object, render_image
    from test_export import SphereModel

    model = SphereModel(SceneBounds(1.0, 20.0, np.zeros(3, np.float32), 1.0, np.array([0, 0, 1], np.float32)))
    w, h, f = 160, 120, 150.0
    K = np.array([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1]], np.float32)
    az = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    eyes = 6.0 * np.stack([np.cos(az), np.sin(az), np.full_like(az, 0.3)], 1)
    # each camera looks 1.2 to the side of the sphere, so it sits off-centre in every view
    c2w = np.stack([look_at(e, np.array([0.0, 0.0, 1.2]), np.array([0.0, 0.0, 1.0])) for e in eyes]).astype(np.float32)
    views = Views(c2w, np.repeat(K[None], len(az), 0), w, h)
    framing = frame_object(model, views, torch.zeros(3))
    for i in (0, 3, 6):
        view = render_image(model, framing.views.K[i], c2w[i], w, h, torch.zeros(3))
        rows, cols = np.nonzero(view.acc > 0.5)
        assert abs((rows.min() + rows.max() + 1) / 2 - h / 2) < 3 and abs((cols.min() + cols.max() + 1) / 2 - w / 2) < 3
        assert abs((rows.max() + 1 - rows.min()) / h - 0.8) < 0.05
    assert framing.zoom > 1.5
    # seen through a long lens the sphere overflows every frame: framing zooms out until it fits
    close = Views(c2w, np.repeat(np.diag([2 * f, 2 * f, 1.0]).astype(np.float32)[None], len(az), 0), w, h)
    close.K[:, :2, 2] = [w / 2, h / 2]
    framing = frame_object(model, close, torch.zeros(3))
    assert framing.zoom < 1
    rows, cols = np.nonzero(render_image(model, framing.views.K[0], c2w[0], w, h, torch.zeros(3)).acc > 0.5)
    assert rows.min() > 0 and cols.min() > 0 and rows.max() < h - 1 and cols.max() < w - 1
    # the distance along rays to the sphere's near side: from d - 1 (its front) to sqrt(d^2 - 1) (its rim)
    d = float(np.linalg.norm(eyes[0]))
    assert (d - 1.1 < framing.near).all() and (framing.near < d - 1.0).all()
    np.testing.assert_allclose(framing.far, np.sqrt(d * d - 1), atol=0.1)
    # cameras 4.5 to 9 away: with the point they look at, each frame's range follows its camera,
    # so the sphere's relief spans the same colours in every frame
    far_eyes = eyes * np.linspace(0.75, 1.5, len(az))[:, None]
    c2w_far = np.stack([look_at(e, np.zeros(3), np.array([0.0, 0.0, 1.0])) for e in far_eyes]).astype(np.float32)
    framing = frame_object(model, Views(c2w_far, views.K, w, h), torch.zeros(3), n_probe=8, aim=np.zeros(3))
    d = np.linalg.norm(far_eyes, axis=1)
    assert ((d - 1.1 < framing.near) & (framing.near < d - 1.0)).all()  # the front, 1 nearer than the centre
    np.testing.assert_allclose(framing.far - d, framing.far[0] - d[0], atol=1e-4)  # one range about each centre
    assert -0.35 < framing.far[0] - d[0] < 0.0  # the rim, a little nearer than the centre

    class Empty(SphereModel):
        def render_rays(self, rays, background, perturb):
            n = len(rays)
            return RenderOutput(background.expand(n, 3), torch.zeros(n), torch.zeros(n))

    assert frame_object(Empty(model.bounds), views, torch.zeros(3), width=40) is None  # nothing to frame
