"""Floaters at the training cameras (train/final.py, ``find_near_floaters``): a surface triangle
through a training camera's near plane, which the training never draws in that view."""

from dataclasses import replace

import numpy as np

MAGENTA = np.array([1.0, 0.0, 1.0])


def _with_floater(renderer, photo_shows_it):
    """A trainer on procedural:tiny whose model has one more surface triangle, magenta, through
    the near plane of its first training camera (two corners behind it, one in front), and the
    exported mesh ``_exported`` makes of it (SH DC colours, no fill). ``photo_shows_it``: that
    view's photo is replaced by what an engine draws there (the triangle clipped at the near
    plane), so the photo agrees with the triangle."""
    from tsplus_wgpu import MeshRenderer, TriangleModel
    from tsplus_wgpu.data.procedural import load_procedural
    from tsplus_wgpu.io.export import dc_colors
    from tsplus_wgpu.train.final import _exported
    from tsplus_wgpu.train.initial import initial_model
    from tsplus_wgpu.train.trainer import TrainConfig, Trainer
    from tsplus_wgpu.types import SH_C0
    tiny = load_procedural("tiny")
    cfg = TrainConfig(iterations=1, quick=True, topology=False, log_every=0, mesh_colors="dc", fill_holes=False,
                      color_detail=False)
    model, groups, _ = initial_model(tiny, cfg)
    view = tiny.train_indices[0]
    cam = tiny.cameras[view]
    c = cam.center
    d = np.linalg.norm(c)
    fwd = -c / d
    a = np.cross(fwd, [0.0, 0.0, 1.0])
    a /= np.linalg.norm(a)
    b = np.cross(fwd, a)
    floater = np.stack([c - 0.05 * d * fwd + 0.3 * d * a, c - 0.05 * d * fwd - 0.3 * d * a, c + 0.2 * d * fwd + 0.01 * d * b])
    n = model.num_vertices
    sh = np.concatenate([model.sh, np.zeros((3,) + model.sh.shape[1:])])
    sh[n:, 0] = (MAGENTA - 0.5) / SH_C0
    big = TriangleModel(np.concatenate([model.positions, floater]), np.concatenate([model.triangles, [[n, n + 1, n + 2]]]),
                        sh, np.concatenate([model.opacity, np.full(3, 0.99)]))
    big_groups = np.concatenate([groups, [0]]).astype(np.int8)
    near = tiny.frame().near_world()
    z = (floater @ cam.R.T + cam.t)[:, 2]
    assert z.min() < near < z.max()                        # through the near plane
    if photo_shows_it:
        engine = MeshRenderer(renderer.ctx).render((big.positions, big.triangles, dc_colors(big)), cam, near=near,
                                                   drop_near=False).image
        images = list(tiny.images)
        images[view] = np.asarray(engine, np.float32)
        tiny = replace(tiny, images=images)
    t = Trainer(tiny, cfg, renderer=renderer, model=big, groups=big_groups)
    return t, _exported(t, np.ones(t.m, bool)), big.num_triangles - 1


def test_a_floater_through_a_cameras_near_plane_is_found(renderer):
    """Drawn clipped (as an engine draws it), the magenta triangle covers much of the first
    training view, whose photo shows the scene there: a floater. No training view draws it
    (the splatting renderer drops triangles through the near plane), so its photo error never
    removed it. (A few long faces of the initial mesh through other cameras are floaters too.)"""
    from tsplus_wgpu.train.final import find_near_floaters
    t, mesh, k = _with_floater(renderer, photo_shows_it=False)
    out = find_near_floaters(t, *mesh)
    assert out.shape == (t.m,) and out[k]


def test_a_triangle_the_photo_shows_through_the_near_plane_is_kept(renderer):
    """The same triangle where the photo shows it (as the ground under a camera): drawing it
    clipped draws that view better than leaving it out, so it is no floater."""
    from tsplus_wgpu.train.final import find_near_floaters
    t, mesh, k = _with_floater(renderer, photo_shows_it=True)
    assert not find_near_floaters(t, *mesh)[k]


def test_final_mesh_removes_the_floater(renderer):
    """``--remove-shards on`` (the default) removes it at the end and counts it."""
    t, _, k = _with_floater(renderer, photo_shows_it=False)
    pos, tri, col = t.final_mesh()
    assert t.final_info["near_floaters"] >= 1 and t.final_info["shards"] >= t.final_info["near_floaters"]
    assert len(tri) <= t.m - 1
    assert not np.any(np.all(np.isclose(col, MAGENTA, atol=1e-3), axis=1))
