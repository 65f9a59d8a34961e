"""The exported triangles face the views that draw them (train/final.py ``facing_views``): their
winding is arbitrary after training, and an engine or an OBJ that culls back faces drops every
triangle seen from behind."""

from types import SimpleNamespace

import numpy as np
import pytest

from tsplus_wgpu import Camera, MeshRenderer
from tsplus_wgpu.render.mesh_fit import triangle_ids
from tsplus_wgpu.train.final import facing_views


def _looking_down(x, y, height=2.0):
    """A camera at (x, y, height) looking straight down (-z), image x along world +x."""
    m = np.eye(4)
    m[:3, :3] = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
    m[:3, 3] = -m[:3, :3] @ np.array([x, y, height])
    return Camera(48, 48, 40, 40, 24, 24, m)


@pytest.fixture(scope="module")
def mr(ctx):
    return MeshRenderer(ctx)


def test_every_drawn_triangle_faces_the_views_and_the_images_stay(mr):
    rng = np.random.default_rng(4)
    n = 12
    u = np.linspace(-1.0, 1.0, n + 1)
    x, y = np.meshgrid(u, u, indexing="ij")
    pos = np.stack([x, y, rng.normal(0.0, 0.01, x.shape)], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    a = (i * (n + 1) + j).ravel()
    tris = np.concatenate([np.stack([a, a + n + 1, a + 1], 1), np.stack([a + 1, a + n + 1, a + n + 2], 1)])
    flip = rng.random(len(tris)) < 0.5                              # arbitrary winding, as trained
    tris[flip] = tris[flip][:, [0, 2, 1]]
    far = np.array([[5.0, 5.0, 0.0], [6.0, 5.0, 0.0], [5.0, 6.0, 0.0]])   # no view draws it
    pos = np.concatenate([pos, far])
    tris = np.concatenate([tris, [[len(pos) - 3, len(pos) - 1, len(pos) - 2]]])   # facing down, away
    cams = [_looking_down(-0.3, 0.0), _looking_down(0.3, 0.2)]
    trainer = SimpleNamespace(mesh_renderer=mr, scene=SimpleNamespace(cameras=cams), train_views=[0, 1],
                              config=SimpleNamespace(near=0.01))
    out, info = facing_views(trainer, pos, tris)
    p = pos[out]
    normal = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    assert np.all(normal[:, 2] > 0)                                 # every one faces up, to the cameras
    assert sorted(map(tuple, np.sort(out, 1))) == sorted(map(tuple, np.sort(tris, 1)))   # the same triangles
    assert info["front_after"] == 1.0 and 0.3 < info["front_before"] < 0.7
    assert info["turned"] == int(flip.sum()) + 1 and info["triangles"] == len(tris)
    for cam in cams:                                                # nothing a renderer without culling sees
        np.testing.assert_array_equal(triangle_ids(mr, pos, out, cam, 0.01), triangle_ids(mr, pos, tris, cam, 0.01))


def test_a_sheet_seen_from_both_sides_faces_the_side_that_sees_more(mr):
    """A vertical sheet between two cameras: it turns to the one that draws more of its pixels."""
    pos = np.array([[0.0, -0.5, -0.5], [0.0, 0.5, -0.5], [0.0, 0.0, 0.5]])
    tris = np.array([[0, 1, 2]])                                    # its normal along +x
    near = Camera(48, 48, 40, 40, 24, 24, np.array([[0, -1, 0, 0], [0, 0, -1, 0], [1, 0, 0, 1.2], [0, 0, 0, 1.0]]))
    far = Camera(48, 48, 40, 40, 24, 24, np.array([[0, 1, 0, 0], [0, 0, -1, 0], [-1, 0, 0, 4.0], [0, 0, 0, 1.0]]))
    assert near.center[0] == pytest.approx(-1.2) and near.R[2][0] == 1.0        # at -x, looking at the sheet
    assert far.center[0] == pytest.approx(4.0) and far.R[2][0] == -1.0           # at +x, looking back at it
    trainer = SimpleNamespace(mesh_renderer=mr, scene=SimpleNamespace(cameras=[near, far]), train_views=[0, 1],
                              config=SimpleNamespace(near=0.01))
    out, info = facing_views(trainer, pos, tris)
    p = pos[out[0]]
    assert np.cross(p[1] - p[0], p[2] - p[0])[0] < 0               # towards the near camera, at -x
    assert info["turned"] == 1 and 0.0 < info["front_before"] < 0.5 and 0.5 < info["front_after"] < 1.0
