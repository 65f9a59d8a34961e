"""The sky rule (tsplus_wgpu/train/sky.py): which pixels of a photo are sky, and which triangles
of a mesh stand in front of it."""

import numpy as np
import pytest

from tsplus_wgpu.train.sky import SKY_SIDE, sky_mask, sky_triangles, upper_border
from tsplus_wgpu.types import Camera

W, H, F = 64, 48, 50.0
UP = np.array([0.0, -1.0, 0.0])          # OpenCV: a level camera's image y points down the world's up


def _camera(roll=0, scale=1.0, shift=(0.0, 0.0, 0.0), pitch=0.0):
    """Looking down +z from ``scale * (0, 0, 0) + shift``; ``roll``: quarter turns about the view
    (a photo stored sideways); ``pitch`` (rad): tilted up (positive) or down."""
    c, s = np.cos(np.pi / 2 * roll), np.sin(np.pi / 2 * roll)
    rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    cp, sp = np.cos(pitch), np.sin(pitch)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cp, sp], [0.0, -sp, cp]])       # its view along (0, -sin, cos)
    m = np.eye(4)
    m[:3, :3] = rz @ rx
    m[:3, 3] = -m[:3, :3] @ np.asarray(shift, np.float64)
    return Camera(W, H, F, F, W / 2, H / 2, m)


def _stripes(shape, amplitude):
    """Vertical stripes two pixels wide, +-``amplitude``: the edges of bricks, leaves, branches."""
    x = np.arange(shape[1])
    return (amplitude * np.where((x // 2) % 2 == 0, 1.0, -1.0))[None, :, None] * np.ones(shape)


def _street(rows_sky=20, seed=0):
    """A photo: a clear sky (a smooth blue gradient) above ``rows_sky``, brick houses below."""
    rng = np.random.default_rng(seed)
    img = np.array([0.55, 0.45, 0.4]) + _stripes((H, W, 3), 0.12) + 0.1 * rng.random((H, W, 3))
    yy, xx = np.mgrid[0:rows_sky, 0:W]
    img[:rows_sky] = np.stack([0.45 + 0.002 * xx, 0.62 + 0.002 * yy, 0.9 + 0.0 * xx], -1)
    return img.astype(np.float32)


def test_a_clear_sky_reaching_the_top_is_sky_and_nothing_else():
    img = _street()
    m = sky_mask(img)
    assert m[:18].all()                               # the sky, but its last rows (the blur meets the houses)
    assert not m[21:].any()                           # the textured houses
    # a smooth blue patch among the houses reaches no border: a car, not the sky
    img[30:40, 20:40] = [0.2, 0.3, 0.8]
    assert not sky_mask(img)[30:40, 20:40].any()
    # reaching the top, it joins the sky
    img[0:40, 20:40] = [0.45, 0.62, 0.9]
    assert sky_mask(img)[30:38, 22:38].all()
    # the same sky with texture (a tree) is not sky
    noisy = _street()
    noisy[:20] += _stripes((20, W, 3), 0.2).astype(np.float32)
    assert not sky_mask(noisy)[:, 1:-1].any()       # (the frame's own columns see half an edge)
    # red over blue, dark or dull blue-grey, white (a white wall, a synthetic scene's background) or
    # green: not taken
    for colour in ([0.9, 0.6, 0.4], [0.1, 0.15, 0.3], [0.29, 0.29, 0.4], [1.0, 1.0, 1.0], [0.5, 0.8, 0.75]):
        other = _street()
        other[:20] = colour
        assert not sky_mask(other).any(), colour


def test_only_above_the_horizon_and_from_the_upper_border():
    """With a camera and the scene's up: pixels whose rays point down are never sky, and the sky
    must reach the border up points to (a photo stored sideways has it at a side)."""
    img = _street(rows_sky=40)                      # blue down to row 40, past the horizon (row 24)
    level = _camera()
    m = sky_mask(img, level, UP)
    assert m[:23].all() and not m[25:].any()
    # tilted up by 0.2 rad the horizon lies 10 px lower (F tan 0.2)
    up_tilt = sky_mask(img, _camera(pitch=0.2), UP)
    assert up_tilt[:33].all() and not up_tilt[35:].any()
    # upside down (up is the image's bottom): the blue at the top is below the horizon
    assert not sky_mask(img, _camera(roll=2), UP).any()
    # stored sideways (turned a quarter about the view): the sky is at a side of the photo
    assert [upper_border(_camera(roll=k), UP) for k in range(4)] == ["top", "right", "bottom", "left"]
    side = _street(rows_sky=0)
    side[5:, :20] = [0.45, 0.62, 0.9]                      # reaching the left border, not the top
    m = sky_mask(side, _camera(roll=3), UP)
    assert m[6:, :18].all() and not m[:, 21:].any() and not m[:4].any()
    assert not sky_mask(side, _camera(roll=1), UP).any()     # the left is down: no sky there
    assert not sky_mask(side).any()                          # no camera: the top row, which it does not reach
    # a view within 30 degrees of straight down (or up) has no sky: up is least sure there
    top = _street()
    assert sky_mask(top, _camera(pitch=-1.1), UP).sum() == 0 and sky_mask(top, _camera(pitch=1.1), UP).sum() == 0
    assert sky_mask(top, _camera(pitch=0.9), UP)[:18].all()
    assert upper_border(level, None) == "top" and upper_border(level, [0.0, 0.0, 1.0]) == "top"


def test_the_smoothness_is_judged_at_a_bounded_size_and_the_input_checked():
    """A blue sky with fine texture is not sky in a photo 4 times the working size either: its
    stripes are 8 px wide there, their middle pixels smooth, but 2 px wide at the working size."""
    big_h, big_w = 3 * SKY_SIDE, 4 * SKY_SIDE              # resized 4 times smaller to be judged
    x = np.arange(big_w)
    img = np.zeros((big_h, big_w, 3), np.float32)
    img[:] = [0.45, 0.62, 0.9]
    img += (0.2 * np.where((x // 8) % 2 == 0, 1.0, -1.0))[None, :, None].astype(np.float32)
    assert sky_mask(img).mean() < 0.05
    assert sky_mask(np.full((big_h, big_w, 3), [0.45, 0.62, 0.9], np.float32)).all()
    for bad in (np.zeros((8, 8), np.float32), np.zeros((8, 8, 4), np.float32), np.zeros((8, 8, 3), np.uint8)):
        with pytest.raises(ValueError, match="image"):
            sky_mask(bad)


@pytest.fixture(scope="module")
def mesh_renderer(renderer):
    from tsplus_wgpu.render.mesh_renderer import MeshRenderer
    return MeshRenderer(renderer.ctx)


def _quad(x0, x1, y0, y1, z):
    p = np.array([[x0, y0, z], [x1, y0, z], [x0, y1, z], [x1, y1, z]], np.float64)
    return p, np.array([[0, 1, 2], [1, 3, 2]])


@pytest.mark.parametrize("scale, shift", [(1.0, (0.0, 0.0, 0.0)), (1000.0, (3.0e4, -2.0e4, 5.0e3))])
def test_triangles_mostly_in_front_of_the_sky(mesh_renderer, scale, shift):
    """Quads at depth 5 seen by two level cameras (the sky is rows 0-19 of the photos): one
    across the sky (columns 0-21, rows -6 to 18), one across the houses (rows 29-54), one with
    most of its rows in the sky (rows 6-20: each of its triangles at least 64 % sky pixels) and
    one with a fifth (rows 14-41: its triangles under 40 %); and a triangle behind the cameras
    that no view draws. Only the first and the third are in front of the sky; the same in a world
    scaled by 1000 and shifted."""
    parts = [_quad(-8, -1, -3.0, -0.6, 5.0), _quad(-8, 8, 0.5, 3.0, 5.0), _quad(0.0, 1.2, -1.8, -0.3, 5.0),
             _quad(1.6, 2.8, -1.0, 1.8, 5.0)]
    pos = np.concatenate([p for p, _ in parts] + [[[-1.0, -1.0, -5.0], [1.0, -1.0, -5.0], [0.0, -2.0, -5.0]]])
    tri = np.concatenate([t + 4 * k for k, (_, t) in enumerate(parts)] + [[[16, 17, 18]]])
    cams = [_camera(scale=scale, shift=scale * np.array([x, 0.0, 0.0]) + shift) for x in (0.0, 0.3)]
    photos = [_street(rows_sky=20, seed=k) for k in range(2)]
    found = sky_triangles(mesh_renderer, scale * pos + shift, tri, cams, photos, 1e-3 * scale, up=UP)
    np.testing.assert_array_equal(found, [True, True, False, False, True, True, False, False, False])
    # without the up the rule is the same here (the sky is at the top)
    np.testing.assert_array_equal(sky_triangles(mesh_renderer, scale * pos + shift, tri, cams, photos,
                                                1e-3 * scale), found)
    # with no sky in the photos nothing is found; the views are counted
    ticks = []
    none = sky_triangles(mesh_renderer, scale * pos + shift, tri, cams, [_street(rows_sky=0)] * 2, 1e-3 * scale,
                         up=UP, tick=lambda: ticks.append(1))
    assert not none.any() and len(ticks) == 2
    assert sky_triangles(mesh_renderer, pos, np.zeros((0, 3), np.int64), cams[:1], photos[:1], 1e-3).shape == (0,)


def test_the_end_of_training_removes_the_sky_triangles(renderer, monkeypatch):
    """The wiring in final_mesh: with --remove-sky on, the surface triangles sky_triangles names
    leave the exported mesh, counted apart from the shards and not put back by the shard check;
    the shell's never; off, it is not asked."""
    import tsplus_wgpu.train.final as final
    from tsplus_wgpu.data.procedural import load_procedural
    from tsplus_wgpu.train.shell import SURFACE
    from tsplus_wgpu.train.trainer import TrainConfig, Trainer
    tiny = load_procedural("tiny")
    asked = []

    def every_triangle(mr, pos, tri, cams, imgs, near, up=None, tick=None):
        asked.append((len(tri), up, cams))
        return np.ones(len(tri), bool)

    monkeypatch.setattr(final, "sky_triangles", every_triangle)
    cfg = dict(iterations=2, quick=True, topology=False, log_every=0, mesh_colors="dc", color_detail=False,
               remove_far=False)
    out = {}
    for on in (False, True):
        t = Trainer(tiny, TrainConfig(**cfg, remove_sky=on), renderer=renderer)
        t.train(progress=False, checkpoint_at_end=False)
        pos, tri, _ = t.final_mesh()
        out[on] = (len(tri), dict(t.final_info), int((np.asarray(t.groups) == SURFACE).sum()))
    assert len(asked) == 1                                    # only with it on
    up, cams = asked[0][1], asked[0][2]                       # the scene's up: the cameras' own up, roughly
    assert np.mean([up @ -np.asarray(c.world_to_camera)[1, :3] > 0.5 for c in cams]) > 0.5
    (n_off, info_off, surface), (n_on, info_on, _) = out[False], out[True]
    assert info_off["sky"] == 0 and 0 < info_on["sky"] <= surface
    # every surface triangle gone, as a shard or in front of the sky, none checked or put back
    assert info_on["shards"] == surface and n_on < n_off
    assert info_on["shards_checked"] == 0 and info_on["shards_kept"] == 0
    # declared indoor, the scene has no sky: not asked
    t = Trainer(tiny, TrainConfig(**cfg, remove_sky=True, indoor=True), renderer=renderer)
    t.train(progress=False, checkpoint_at_end=False)
    t.final_mesh()
    assert len(asked) == 1 and t.final_info["sky"] == 0
