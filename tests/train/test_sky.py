"""The sky rule (tsplus_wgpu/train/sky.py): which pixels of a photo are sky, and which triangles
of a mesh stand in front of it."""

import numpy as np
import pytest

from tsplus_wgpu.train.sky import SKY_SHARE, sky_mask, sky_triangles, upper_border
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
    # red over blue, dark blue, white (a white wall, a synthetic scene's background) or green: not taken
    for colour in ([0.9, 0.6, 0.4], [0.1, 0.15, 0.3], [1.0, 1.0, 1.0], [0.5, 0.8, 0.75]):
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
    side[:, :20] = [0.45, 0.62, 0.9]
    m = sky_mask(side, _camera(roll=3), UP)
    assert m[:, :18].all() and not m[:, 21:].any()
    assert not sky_mask(side, _camera(roll=1), UP).any()     # the left is down: no sky there
    assert sky_mask(side)[:, :18].all()                      # no camera: the top row, which it reaches
    assert upper_border(level, None) == "top" and upper_border(level, [0.0, 0.0, 1.0]) == "top"


@pytest.fixture(scope="module")
def mesh_renderer(renderer):
    from tsplus_wgpu.render.mesh_renderer import MeshRenderer
    return MeshRenderer(renderer.ctx)


def _quad(x0, x1, y0, y1, z):
    p = np.array([[x0, y0, z], [x1, y0, z], [x0, y1, z], [x1, y1, z]], np.float64)
    return p, np.array([[0, 1, 2], [1, 3, 2]])


@pytest.mark.parametrize("scale, shift", [(1.0, (0.0, 0.0, 0.0)), (1000.0, (3.0e4, -2.0e4, 5.0e3))])
def test_triangles_mostly_in_front_of_the_sky(mesh_renderer, scale, shift):
    """Quads seen by two level cameras: one across the top of the photos (rows -6 to 18: the sky
    there), one across the bottom (the houses), one in front of them straddling the sky's edge
    (rows 16 to 30: under a third of its pixels in the sky). Only the first is in front of the sky; the same in a world scaled by 1000
    and shifted."""
    parts = [_quad(-8, 8, -3.0, -0.6, 5.0), _quad(-8, 8, 0.5, 3.0, 5.0), _quad(-1, 1, -0.7, 0.6, 4.5)]
    pos = np.concatenate([p for p, _ in parts])
    tri = np.concatenate([t + 4 * k for k, (_, t) in enumerate(parts)])
    cams = [_camera(scale=scale, shift=scale * np.array([x, 0.0, 0.0]) + shift) for x in (0.0, 0.3)]
    photos = [_street(rows_sky=20, seed=k) for k in range(2)]
    found = sky_triangles(mesh_renderer, scale * pos + shift, tri, cams, photos, 1e-3 * scale, up=UP)
    np.testing.assert_array_equal(found, [True, True, False, False, False, False])
    # without the up the rule is the same here (the sky is at the top)
    np.testing.assert_array_equal(sky_triangles(mesh_renderer, scale * pos + shift, tri, cams, photos,
                                                1e-3 * scale), found)
    # with no sky in the photos nothing is found; the views are counted
    ticks = []
    none = sky_triangles(mesh_renderer, scale * pos + shift, tri, cams, [_street(rows_sky=0)] * 2, 1e-3 * scale,
                         up=UP, tick=lambda: ticks.append(1))
    assert not none.any() and len(ticks) == 2
    assert sky_triangles(mesh_renderer, pos, np.zeros((0, 3), np.int64), cams[:1], photos[:1], 1e-3).shape == (0,)
    assert 0 < SKY_SHARE < 1


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
        asked.append((len(tri), up is not None))
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
    assert len(asked) == 1 and asked[0][1]                    # only with it on, with the scene's up
    (n_off, info_off, surface), (n_on, info_on, _) = out[False], out[True]
    assert info_off["sky"] == 0 and 0 < info_on["sky"] <= surface
    # every surface triangle gone, but the shards by size and error the shard check put back
    assert info_on["shards"] + info_on["shards_kept"] == surface and n_on < n_off
    assert info_on["sky"] + info_on["shards_checked"] <= surface    # the check never sees the sky's
