"""The far-field test (tsplus_wgpu/train/far_field.py): a textured sky far away, a textured
ground plane near the cameras, and a shard in front of the sky that no photo shows. The photos
are the mesh renderer's own drawings of the scene without the shard."""

import numpy as np
import pytest

from tsplus_wgpu.train.far_field import (FAR_SHARE, FAR_VOTES, far_occluders, far_pixels, nearest_views,
                                         occluder_mask, pixel_rays, project)
from tsplus_wgpu.types import Camera

W, H, F = 64, 48, 60.0
SKY_Z = 2000.0        # parallax between the cameras under 0.04 px: at infinity for the test
GROUND_Z = 4.0        # 3.75 px a camera step
SHARD_Z = 1.5         # 10 px a camera step
STEP = 0.25


def _sky(tx, ty):
    """Colour of the sky along direction (tx, ty) = (x / z, y / z): two waves of unrelated periods."""
    a, b = 19.0 * tx + 7.0 * ty, 11.0 * ty - 5.0 * tx
    return np.stack([0.5 + 0.2 * np.sin(a), 0.5 + 0.2 * np.sin(b + 1.0), 0.6 + 0.15 * np.sin(a + b)], -1)


def _ground(x, y):
    a, b = 2.6 * x + 0.7 * y, 3.1 * y - 1.3 * x
    return np.stack([0.45 + 0.25 * np.sin(a), 0.4 + 0.2 * np.cos(b), 0.35 + 0.2 * np.sin(a - b)], -1)


def _grid(x0, x1, y0, y1, z, n, m):
    xs, ys = np.meshgrid(np.linspace(x0, x1, n + 1), np.linspace(y0, y1, m + 1))
    pos = np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, z)], 1)
    k = np.arange((n + 1) * (m + 1)).reshape(m + 1, n + 1)
    a, b, c, d = k[:-1, :-1].ravel(), k[:-1, 1:].ravel(), k[1:, :-1].ravel(), k[1:, 1:].ravel()
    return pos, np.concatenate([np.stack([a, b, c], 1), np.stack([b, d, c], 1)])


def _camera(x, scale=1.0, shift=(0.0, 0.0, 0.0)):
    m = np.eye(4)
    m[:3, 3] = -(scale * np.array([x, 0.0, 0.0]) + shift)
    return Camera(W, H, F, F, W / 2, H / 2, m)


def _scene(scale=1.0, shift=(0.0, 0.0, 0.0)):
    """``(cameras, positions, triangles, colours, shard's triangle index)``: the sky and the
    ground, then one shard in front of the sky from the middle camera; the world scaled by
    ``scale`` and shifted by ``shift``."""
    sky_p, sky_t = _grid(-1600, 1900, -1500, 300, SKY_Z, 48, 24)
    ground_p, ground_t = _grid(-3.0, 4.5, 0.0, 2.0, GROUND_Z, 60, 16)
    pos = np.concatenate([sky_p, ground_p])
    tri = np.concatenate([sky_t, ground_t + len(sky_p)])
    col = np.concatenate([_sky(sky_p[:, 0] / SKY_Z, sky_p[:, 1] / SKY_Z), _ground(ground_p[:, 0], ground_p[:, 1])])
    mid = 2 * STEP
    shard = np.array([[mid - 0.2 * SHARD_Z, -0.35 * SHARD_Z, SHARD_Z], [mid + 0.2 * SHARD_Z, -0.35 * SHARD_Z, SHARD_Z],
                      [mid, -0.1 * SHARD_Z, SHARD_Z]])
    pos = np.concatenate([pos, shard])
    tri = np.concatenate([tri, [[len(pos) - 3, len(pos) - 2, len(pos) - 1]]])
    col = np.concatenate([col, np.full((3, 3), 0.9)])
    cams = [_camera(k * STEP, scale, shift) for k in range(6)]
    return cams, scale * pos + shift, tri, col, len(tri) - 1


@pytest.fixture(scope="module")
def mesh_renderer(renderer):
    from tsplus_wgpu.render.mesh_renderer import MeshRenderer
    return MeshRenderer(renderer.ctx)


def _photos(mr, cams, pos, tri, col):
    """The photos: the scene without its shard (the last triangle), drawn at 2x2 samples."""
    return [mr.render((pos, tri[:-1], col), c, supersample=2, near=1e-3).image for c in cams]


def test_rays_and_projection_agree():
    cam = _camera(0.3)
    rays = pixel_rays(cam)
    u, v, z = project(cam, cam.center + 2.5 * rays)
    gu, gv = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    np.testing.assert_allclose(u, gu, atol=1e-9)
    np.testing.assert_allclose(v, gv, atol=1e-9)
    np.testing.assert_allclose(z, 2.5, atol=1e-12)


def test_pixels_of_the_sky_behind_a_shard_are_far_and_the_ground_near(mesh_renderer):
    """In the middle view: where the shard hides the sky, the neighbours vote far; the ground,
    drawn at its own depth, votes near; the sky drawn at its own depth decides nothing (the two
    hypotheses are the same point there)."""
    cams, pos, tri, col, _ = _scene()
    photos = _photos(mesh_renderer, cams, pos, tri, col)
    a = 2
    depth_true = mesh_renderer.render((pos, tri[:-1], col), cams[a], near=1e-3).depth
    depth_shard = mesh_renderer.render((pos, tri, col), cams[a], near=1e-3).depth
    shard = depth_shard < 0.5 * depth_true
    ground = (depth_true > 0) & (depth_true < 10)
    sky = depth_true > 1000
    assert shard.sum() > 100 and ground.sum() > 500
    nb = [(cams[b], photos[b]) for b in nearest_views([c.center for c in cams])[a]]
    far, near = far_pixels(cams[a], photos[a], depth_shard, nb, 1e-3)
    assert far[shard].mean() > 0.6, far[shard].mean()
    assert not far[ground].any()
    assert near[ground].mean() > 0.6, near[ground].mean()
    assert not (far | near)[sky & ~shard].any()
    # the same view with the sky's own depth everywhere: nothing far
    far_true, _ = far_pixels(cams[a], photos[a], depth_true, nb, 1e-3)
    assert not far_true.any()


def test_the_shard_alone_is_found_in_any_world_units(mesh_renderer):
    """far_occluders names the shard and nothing else, and the same with the world scaled by
    1000 and shifted (it compares pixels and colours only)."""
    found = []
    for scale, shift in ((1.0, (0.0, 0.0, 0.0)), (1000.0, (5e3, -2e3, 7e2))):
        cams, pos, tri, col, k = _scene(scale, shift)
        photos = _photos(mesh_renderer, cams, pos, tri, col)
        mask = far_occluders(mesh_renderer, pos, tri, cams, photos, 1e-3 * scale)
        assert np.flatnonzero(mask).tolist() == [k]
        found.append(mask)
    np.testing.assert_array_equal(found[0], found[1])


def test_occluder_mask_needs_votes_a_majority_and_a_share():
    far = np.array([FAR_VOTES, FAR_VOTES - 1, 10, 10, 10])
    near = np.array([0, 0, 5, 4, 0])
    drawn = np.array([FAR_VOTES, 10, 20, 20, int(10 / FAR_SHARE) + 1])
    np.testing.assert_array_equal(occluder_mask(far, near, drawn), [True, False, False, True, False])


def test_nearest_views():
    c = np.array([[0.0, 0, 0], [1, 0, 0], [3, 0, 0], [3.5, 0, 0]])
    np.testing.assert_array_equal(nearest_views(c, 2), [[1, 2], [0, 2], [3, 1], [2, 1]])
    assert nearest_views(c[:1]).shape == (1, 0)


def test_unrelated_neighbours_say_nothing_is_far(mesh_renderer):
    """Neighbours that show other content (here the photos shifted by 17 px) miss under both
    hypotheses: the lesser miss is not a match, so (almost) no pixel is far (without the match
    test, 502 of 3,072 were)."""
    cams, pos, tri, col, _ = _scene()
    photos = _photos(mesh_renderer, cams, pos, tri, col)
    a = 2
    depth = mesh_renderer.render((pos, tri, col), cams[a], near=1e-3).depth
    nb = [(cams[b], np.roll(photos[b], 17, axis=1)) for b in nearest_views([c.center for c in cams])[a]]
    far, near = far_pixels(cams[a], photos[a], depth, nb, 1e-3)
    assert far.mean() < 0.01 and near.sum() > 100, (far.sum(), near.sum())


def test_the_end_of_training_removes_what_the_test_names(renderer, monkeypatch):
    """The wiring in final_mesh: with --remove-far on, the surface triangles far_occluders names
    leave the exported mesh (counted apart from the shards), also those the size rule names, and
    the shard check puts none back (nor checks them); the shell's never; off, it is not asked."""
    import tsplus_wgpu.train.final as final
    from tsplus_wgpu.data.procedural import load_procedural
    from tsplus_wgpu.train.shell import SURFACE
    from tsplus_wgpu.train.trainer import TrainConfig, Trainer
    tiny = load_procedural("tiny")
    asked = []

    def every_triangle(mr, pos, tri, cams, imgs, near, tick=None):
        asked.append(len(tri))
        return np.ones(len(tri), bool)

    monkeypatch.setattr(final, "far_occluders", every_triangle)
    # the shard check on: the far field's triangles have evidence of their own and are never checked
    cfg = dict(iterations=2, quick=True, topology=False, log_every=0, mesh_colors="dc", color_detail=False,
               shard_check=True, remove_sky=False)
    out = {}
    for on in (False, True):
        t = Trainer(tiny, TrainConfig(**cfg, remove_far=on), renderer=renderer)
        t.train(progress=False, checkpoint_at_end=False)
        pos, tri, _ = t.final_mesh()
        out[on] = (len(tri), dict(t.final_info), int((np.asarray(t.groups) == SURFACE).sum()))
    assert len(asked) == 1                                   # only with it on
    (n_off, info_off, surface), (n_on, info_on, _) = out[False], out[True]
    assert info_off["far"] == 0 and 0 < info_on["far"] <= surface
    assert info_on["shards"] == surface and n_on < n_off     # every surface triangle gone, as a shard or as far
    assert info_on["shards_checked"] == 0 and info_on["shards_kept"] == 0
    assert info_on["shards"] - info_on["far"] - info_on["floaters"] > 0    # the size rule named some of them too


def test_a_single_view_finds_nothing_and_still_counts_its_view(mesh_renderer):
    cams, pos, tri, col, _ = _scene()
    photos = _photos(mesh_renderer, cams, pos, tri, col)
    ticks = []
    mask = far_occluders(mesh_renderer, pos, tri, cams[:1], photos[:1], 1e-3, tick=lambda: ticks.append(1))
    assert not mask.any() and len(ticks) == 1
