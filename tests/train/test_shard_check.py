"""The end of training's shard check (tsplus_wgpu.train.final.worse_without): of the triangles
removed as shards, those whose pixels the training views draw worse without them come back."""

from types import SimpleNamespace

import numpy as np

from tsplus_wgpu.render.mesh_fit import id_mesh, triangle_ids


def _tri(centre, a, b, size):
    return np.stack([centre + size * a, centre - size * a + 0.8 * size * b, centre - 0.8 * size * b])


def test_a_removed_triangle_comes_back_only_where_it_drew_the_views_better(renderer):
    """A far green wall; the photos show a red triangle in front of it. The exported mesh holds
    the wall, that red triangle (right: a near surface) and a magenta one the photos do not show
    (a shard). Both are removed; without them the wall draws the shard's pixels better and the
    red one's worse, so the red one (and only it) comes back, and nothing that was not removed."""
    from tsplus_wgpu import MeshRenderer
    from tsplus_wgpu.data.procedural import load_procedural
    from tsplus_wgpu.train.final import worse_without
    tiny = load_procedural("tiny")
    views = list(tiny.train_indices[:2])
    cam = tiny.cameras[views[0]]
    c = cam.center
    d = np.linalg.norm(c)
    f = -c / d
    a = np.cross(f, [0.0, 0.0, 1.0])
    a /= np.linalg.norm(a)
    b = np.cross(f, a)
    wall_c = c + 1.5 * d * f
    wall = np.stack([wall_c + 3 * d * (-a - b), wall_c + 3 * d * (a - b), wall_c + 3 * d * (a + b), wall_c + 3 * d * (-a + b)])
    red = _tri(c + 0.7 * d * f + 0.12 * d * a, a, b, 0.1 * d)
    magenta = _tri(c + 0.5 * d * f - 0.1 * d * a, a, b, 0.07 * d)
    pos = np.concatenate([wall, red, magenta])
    tris = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [7, 8, 9]])
    col = np.concatenate([np.tile([0.1, 0.7, 0.2], (4, 1)), np.tile([0.9, 0.1, 0.1], (3, 1)),
                          np.tile([1.0, 0.0, 1.0], (3, 1))])
    mr = MeshRenderer(renderer.ctx)
    near = tiny.frame().near_world()
    truth = (pos, tris[:3], col)
    images = {v: np.asarray(mr.render(truth, tiny.cameras[v], near=near).image, np.float64) for v in views}
    ids_mesh, up = id_mesh(mr, pos, tris), mr.upload((pos, tris, col))
    drawn = []
    for v in views:
        ids = triangle_ids(mr, pos, tris, tiny.cameras[v], near, ids_mesh)
        r = np.mean((np.asarray(mr.render(up, tiny.cameras[v], near=near).image, np.float64) - images[v]) ** 2, -1)
        drawn.append((ids.astype(np.int32), r.astype(np.float32)))
    assert {2, 3} <= set(np.unique(drawn[0][0]))            # both drawn by the first view
    # the trainer's triangles 10..13 exported as 0..3 (source); 12 (red) and 13 (magenta) removed
    source = np.array([10, 11, 12, 13])
    removed = np.zeros(20, bool)
    removed[[12, 13, 5]] = True                             # 5: removed, not exported here
    t = SimpleNamespace(train_views=views, scene=SimpleNamespace(cameras=tiny.cameras, images=images),
                        config=SimpleNamespace(near=near), m=20, mesh_renderer=mr)
    mesh = (pos, pos, tris, col, source)
    out = (pos, pos, tris[:2], col, source[:2])
    back = worse_without(t, mesh, out, drawn, removed)
    assert np.flatnonzero(back).tolist() == [12]
    # a removal that changes nothing (the same mesh both ways) puts nothing back
    assert not worse_without(t, mesh, mesh, drawn, removed).any()
