"""The optional normal loss (tsplus_wgpu.train.normals): the float64 twin of the whole gradient
against central finite differences, with a mutation check that fails when either path (the
blending weights, the 3D normal) is dropped; the WGSL chain against the twin; the normal
render's decoding; priors on disk; the procedural scene's ground-truth maps; training with
normals (resume bit-identical, lower normal error than without)."""

import numpy as np
import pytest
from scenes import f32_exact, look_at_camera, random_scene

from tsplus_wgpu import TriangleModel
from tsplus_wgpu import reference as ref
from tsplus_wgpu.train import normals as nl
import tsplus_wgpu.reference.normals as rn

W = H = 32
FD_TOL = 1e-5          # twin vs central differences (relative to the largest FD component)
WGSL_TOL = 1e-4        # WGSL chain vs twin (relative norm, float32)
MUTANT_MIN = 1e-2      # a gradient missing one path is at least this far off (measured: 0.1 .. 1)


def _scene_ok(model, cam, sigma):
    um = rn.normal_model(model, cam)
    r = ref.render(um, cam, sigma)
    proj = r.projection
    vis = proj.visible
    depths = np.sort(proj.depth[vis])
    if r.ambiguous.any() or vis.sum() < 6 or (r.n_contrib > 0).sum() < 300:
        return False
    if depths.size > 1 and np.diff(depths).min() < 1e-3:
        return False
    # window ratio of every contributing pixel well above 0 where the window is steep
    if sigma < 1:
        for t in np.nonzero(vis)[0]:
            x0, y0, x1, y1 = proj.rect[t]
            ys, xs = np.mgrid[y0:y1 + 1, x0:x1 + 1]
            d = np.stack([xs + 0.5 - proj.s[t, 0], ys + 0.5 - proj.s[t, 1]], -1)
            ratio = (1.0 + d @ proj.g[t].T).min(-1)
            if np.any((ratio > 0) & (ratio < 2e-3)):
                return False
    # no triangle seen nearly edge-on (its camera-facing sign must not flip under a small step)
    n, _, _, _ = rn.triangle_normals(model.positions, model.triangles, cam)
    c = model.positions[model.triangles].mean(1) @ cam.R.T + cam.t
    cosang = np.abs(np.einsum("mi,mi->m", n, c)) / np.linalg.norm(c, axis=1)
    return bool(cosang.min() > 0.05)


def _prior(seed, h=H, w=W):
    rng = np.random.default_rng(seed)
    raw = np.array([0.3, -0.2, -1.0]) + 0.5 * rng.normal(size=(h, w, 3))
    raw /= np.linalg.norm(raw, axis=2, keepdims=True)
    raw[:3] = 0.0                      # rows without a prior
    raw[5, 7] = np.nan
    return nl.prepare_prior(raw)


_SCENES = {}


def scenes_for(sigma, count=2):
    if sigma not in _SCENES:
        found, seed = [], 200
        while len(found) < count:
            seed += 1
            model, cam = f32_exact(*random_scene(seed, W, H, sheets=3, points_per_sheet=6, sh_k=1))
            if model.num_triangles <= 20 and _scene_ok(model, cam, sigma):
                found.append((seed, model, cam))
        _SCENES[sigma] = found
    return _SCENES[sigma]


def _with(model, positions=None, opacity=None):
    return TriangleModel(model.positions if positions is None else positions, model.triangles, model.sh,
                         model.opacity if opacity is None else opacity)


def _fd(model, cam, sigma, prior, valid, h=1e-6):
    def loss(**kw):
        return rn.normal_loss_value(_with(model, **kw), cam, sigma, prior, valid)
    fd_x = np.zeros(model.positions.size)
    for i in range(fd_x.size):
        vals = []
        for sgn in (1, -1):
            a = model.positions.copy().ravel()
            a[i] += sgn * h
            vals.append(loss(positions=a.reshape(-1, 3)))
        fd_x[i] = (vals[0] - vals[1]) / (2 * h)
    fd_o = np.zeros(model.num_vertices)
    for i in range(fd_o.size):
        vals = []
        for sgn in (1, -1):
            a = model.opacity.copy()
            a[i] += sgn * h
            vals.append(loss(opacity=a))
        fd_o[i] = (vals[0] - vals[1]) / (2 * h)
    return fd_x.reshape(-1, 3), fd_o


def _err(a, fd):
    return float(np.abs(np.asarray(a, np.float64) - fd).max() / np.abs(fd).max())


def _rel(a, b):
    return float(np.linalg.norm(np.asarray(a, np.float64) - b) / max(np.linalg.norm(b), 1e-300))


@pytest.mark.parametrize("sigma", [1.0, 0.3])
def test_twin_matches_finite_differences_and_needs_both_paths(sigma):
    for seed, model, cam in scenes_for(sigma):
        prior, valid = _prior(seed)
        loss, v_x, v_o = rn.normal_loss(model, cam, sigma, prior, valid)
        assert loss == pytest.approx(rn.normal_loss_value(model, cam, sigma, prior, valid), abs=1e-15)
        fd_x, fd_o = _fd(model, cam, sigma, prior, valid)
        assert np.abs(fd_x).max() > 0 and np.abs(fd_o).max() > 0
        e_x, e_o = _err(v_x, fd_x), _err(v_o, fd_o)
        print(f"sigma {sigma} seed {seed}: positions {e_x:.2e}, opacity {e_o:.2e}")
        assert e_x <= FD_TOL and e_o <= FD_TOL, (seed, e_x, e_o)
        # mutation check: without the blending-weight path, or without the 3D-normal path,
        # the positions' gradient is far off the finite differences
        for paths in (("alpha",), ("normal",)):
            _, m_x, _ = rn.normal_loss(model, cam, sigma, prior, valid, paths=paths)
            e = _err(m_x, fd_x)
            print(f"  only {paths[0]}: positions {e:.2e}")
            assert e > 100 * FD_TOL and e > MUTANT_MIN, (seed, paths, e)
        # the weight scales loss and gradient
        l2, x2, o2 = rn.normal_loss(model, cam, sigma, prior, valid, weight=0.05)
        assert l2 == pytest.approx(0.05 * loss) and np.allclose(x2, 0.05 * v_x) and np.allclose(o2, 0.05 * v_o)


@pytest.mark.parametrize("sigma", [1.0, 0.3])
def test_wgsl_chain_matches_twin(renderer, sigma):
    loss_kernel = nl.NormalLoss(renderer)
    for seed, model, cam in scenes_for(sigma):
        prior, valid = _prior(seed)
        loss, v_x, v_o = rn.normal_loss(model, cam, sigma, prior, valid, weight=0.05)
        d_loss, d_x, d_o = loss_kernel.gradients(model, cam, sigma, prior, valid, weight=0.05)
        e_x, e_o = _rel(d_x, v_x), _rel(d_o, v_o)
        print(f"sigma {sigma} seed {seed}: WGSL vs twin positions {e_x:.2e}, opacity {e_o:.2e}, "
              f"loss {abs(d_loss - loss):.1e}")
        assert e_x <= WGSL_TOL and e_o <= WGSL_TOL, (seed, e_x, e_o)
        assert d_loss == pytest.approx(loss, rel=1e-5)
        for paths in (("alpha",), ("normal",)):
            _, m_x, _ = rn.normal_loss(model, cam, sigma, prior, valid, weight=0.05, paths=paths)
            assert _rel(d_x, m_x) > MUTANT_MIN, (seed, paths)
        # deterministic: bit-identical on a second run
        again = loss_kernel.gradients(model, cam, sigma, prior, valid, weight=0.05)
        np.testing.assert_array_equal(again[1], d_x)
        np.testing.assert_array_equal(again[2], d_o)


def test_normal_render_decodes_the_facing_normal(renderer):
    """An opaque, sharp quad: N = 2 C - (1 - T) is its camera-facing unit normal (times the
    alpha cap 0.99) whatever the winding; off the quad N = 0; both on the device and the twin."""
    cam = look_at_camera(24, 24)
    pos = np.array([[-3, -3, 0], [3, -3, 0], [3, 3, 0], [-3, 3, 0]], float)
    pos[:, 2] = 0.3 * pos[:, 0]                      # the plane z = 0.3 x, seen from z = -4
    want_w = np.array([0.3, 0.0, -1.0]) / np.linalg.norm([0.3, 0.0, -1.0])   # its normal towards the camera
    want = cam.R @ want_w
    for tris in (np.array([[0, 1, 2], [0, 2, 3]]), np.array([[0, 2, 1], [0, 3, 2]])):
        model = TriangleModel(pos, tris, np.zeros((4, 1, 3)), np.ones(4))
        n_twin, t_twin = rn.normal_render(model, cam, 1e-4)
        centre = n_twin[8:16, 8:16].reshape(-1, 3)
        assert np.allclose(centre, 0.99 * want, atol=2e-3), centre[0]
        k = nl.NormalLoss(renderer)
        k.set_topology(tris, 4)
        from tsplus_wgpu import DeviceModel
        dm = DeviceModel.from_model(renderer, model)
        prior = np.broadcast_to(want.astype(np.float32), (24, 24, 3)).copy()
        tgt, _ = k.target(prior, np.ones((24, 24), bool))
        c = renderer.ctx
        res = k.run(cam, 1e-4, 0.01, dm.buffers["positions"], dm.buffers["triangles"], dm.buffers["opacity"], tgt,
                    c.buffer(48), c.buffer(16), 1.0)
        n_dev = 2.0 * res.image - (1.0 - res.transmittance)[..., None]
        sure = ~ref.render(rn.normal_model(model, cam), cam, 1e-4).ambiguous   # not on the diagonal
        assert sure.mean() > 0.9
        np.testing.assert_allclose(n_dev[sure], n_twin[sure], atol=1e-5)
    model = TriangleModel(pos * 0.1, np.array([[0, 1, 2]]), np.zeros((4, 1, 3)), np.ones(4))
    n_twin, _ = rn.normal_render(model, cam, 1e-4)
    assert np.all(n_twin[0, 0] == 0.0)               # nothing drawn: N = 0 (background 0)


def test_prepare_prior_and_error_metric():
    raw = np.zeros((2, 3, 3))
    raw[0, 0] = [0, 0, -2.0]          # too long: ignored
    raw[0, 1] = [0, 0, -1.2]          # normalised
    raw[0, 2] = [np.nan, 0, -1]
    raw[1, 0] = [0.6, 0, -0.8]
    raw[1, 1] = [0, 0, -0.4]          # too short: ignored
    prior, valid = nl.prepare_prior(raw, alpha=np.array([[1, 1, 1], [1, 1, 1]]))
    assert valid.tolist() == [[False, True, False], [True, False, False]]
    np.testing.assert_allclose(prior[0, 1], [0, 0, -1])
    assert np.all(prior[~valid] == 0)
    _, valid_a = nl.prepare_prior(raw, alpha=np.array([[1, 0, 1], [1, 1, 1]]))
    assert valid_a.sum() == 1
    err = nl.normal_error(np.broadcast_to([0.0, 0.0, -0.5], (2, 3, 3)), prior, valid)
    assert err["pixels"] == 2 and err["loss"] == pytest.approx(1 - (0.5 + 0.4) / 2)
    assert err["angle_deg"] == pytest.approx(np.degrees(np.arccos(0.8)) / 2)
    vi, vt, cnt = nl.normal_cotangents(prior, valid)
    assert cnt == 2 and np.allclose(vi[valid], -prior[valid]) and np.allclose(vt[0, 1], 0.5)


# ---------------------------------------------------------------------- priors on disk

@pytest.fixture(scope="module")
def tiny():
    from tsplus_wgpu.data import load_procedural
    return load_procedural("tiny")


@pytest.fixture(scope="module")
def tiny_maps(tiny):
    from tsplus_wgpu.data.procedural import normal_maps
    return normal_maps(tiny)


def test_ground_truth_maps_match_the_normal_render_of_the_ground_truth_mesh(renderer, tiny, tiny_maps):
    """The helper's maps and the loss's normal render agree on the convention: the opaque
    ground-truth mesh drawn through the normal render (sigma 1e-4) is within a few degrees of
    its own maps (the rest: the alpha cap 0.99 letting 1 % of the surface behind through, and
    pixels on silhouettes)."""
    from tsplus_wgpu.data import demo_model
    model = demo_model(0)
    k = nl.NormalLoss(renderer)
    for v in (0, 3):
        prior, valid = nl.prepare_prior(tiny_maps[v])
        assert valid.mean() > 0.99                     # a closed room: every pixel sees a surface
        assert np.allclose(np.linalg.norm(tiny_maps[v], axis=2)[valid], 1.0, atol=1e-6)
        assert prior[valid][:, 2].mean() < -0.3         # facing the camera: z < 0 on average
        loss, _, _ = k.gradients(model, tiny.cameras[v], 1e-4, prior, valid)
        n_twin, _ = rn.normal_render(model, tiny.cameras[v], 1e-4)
        err = nl.normal_error(n_twin, prior, valid)
        print(f"view {v}: GT mesh vs its maps: 1 - cos {err['loss']:.4f}, mean angle {err['angle_deg']:.2f} deg, "
              f"device loss {loss:.4f}")
        assert err["angle_deg"] < 3.0 and err["loss"] < 0.03
        assert loss == pytest.approx(err["loss"], abs=2e-3)
        # a wrong convention is far off: OpenGL axes (y, z negated)
        assert nl.normal_error(n_twin, prior * np.array([1, -1, -1], np.float32), valid)["angle_deg"] > 60


def test_normal_maps_on_disk_npy_png_missing_resized(tiny, tiny_maps, tmp_path):
    from tsplus_wgpu.data.normals import load_normal_maps, write_normal_maps
    train = tiny.train_indices
    for fmt in ("npy", "png"):
        folder = tmp_path / fmt
        paths = write_normal_maps(folder, tiny, tiny_maps, fmt)
        assert len(paths) == len(tiny.images) and not list(folder.glob(".*tmp*"))
        got = load_normal_maps(tiny, folder)
        assert got.count == len(train) and not got.missing and not got.warnings
        assert all(got.maps[v] is None for v in tiny.test_indices)
        for v in train:
            prior, valid = nl.prepare_prior(tiny_maps[v])
            np.testing.assert_array_equal(got.maps[v][1], valid)
            np.testing.assert_allclose(got.maps[v][0], prior, atol=1e-7 if fmt == "npy" else 1e-4)
    # a missing map: that view gets none, and the summary says so
    (tmp_path / "npy" / f"{tiny.image_names[train[0]].rsplit('.', 1)[0]}.npy").unlink()
    got = load_normal_maps(tiny, tmp_path / "npy")
    assert got.count == len(train) - 1 and got.missing == [tiny.image_names[train[0]]]
    assert f"{len(train) - 1} of {len(train)} training views" in got.summary(len(train))
    assert "1 without a map get no normal loss" in got.summary(len(train))
    # another size: area-resized with a warning; the wrong convention: a warning
    big = tmp_path / "big"
    big.mkdir()
    v = train[1]
    stem = tiny.image_names[v].rsplit(".", 1)[0]
    np.save(big / f"{stem}.npy", np.repeat(np.repeat(tiny_maps[v], 2, axis=0), 2, axis=1))
    np.save(big / f"{tiny.image_names[train[2]].rsplit('.', 1)[0]}.npy", -tiny_maps[train[2]])
    got = load_normal_maps(tiny, big)
    assert got.count == 2
    assert any("resized (area)" in w for w in got.warnings) and any("another convention" in w for w in got.warnings)
    prior, valid = nl.prepare_prior(tiny_maps[v])
    both = valid & got.maps[v][1]
    np.testing.assert_allclose(got.maps[v][0][both], prior[both], atol=1e-5)


@pytest.mark.parametrize("name,content,msg", [
    ("x.npy", "shape", "must have shape [H, W, 3]"),
    ("x.npy", "ints", "must hold floats"),
    ("x.npy", b"not numpy", "not a readable .npy"),
    ("x.png", b"\x89PNG garbage", "not a readable PNG"),
    ("x.png", "grey", "RGB or RGBA"),
    ("x.npy", "aspect", "different aspect ratio"),
])
def test_malformed_normal_maps_are_one_line_errors(tiny, tmp_path, name, content, msg):
    import cv2

    from tsplus_wgpu.data import SceneError
    from tsplus_wgpu.data.normals import load_normal_maps
    v = tiny.train_indices[0]
    path = tmp_path / (tiny.image_names[v].rsplit(".", 1)[0] + name[1:])
    if isinstance(content, bytes):
        path.write_bytes(content)
    elif content == "shape":
        np.save(path, np.zeros((48, 64), np.float32))
    elif content == "ints":
        np.save(path, np.zeros((48, 64, 3), np.int32))
    elif content == "grey":
        cv2.imwrite(str(path), np.zeros((48, 64), np.uint8))
    elif content == "aspect":
        np.save(path, np.zeros((48, 48, 3), np.float32))
    with pytest.raises(SceneError) as exc:
        load_normal_maps(tiny, tmp_path)
    text = str(exc.value)
    assert msg in text and str(path) in text and "\n" not in text


def test_inspect_writes_ground_truth_normals(tmp_path):
    import subprocess
    import sys
    r = subprocess.run([sys.executable, "-m", "tsplus_wgpu.cli", "inspect", "procedural:tiny", "--quiet",
                        "--write-normals", str(tmp_path / "n"), "--normals-format", "png"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "wrote 8 ground-truth normal maps (png)" in r.stdout
    assert len(list((tmp_path / "n").glob("view_*.png"))) == 8


# ---------------------------------------------------------------------- training

def _train_maps(scene, maps):
    return [nl.prepare_prior(maps[v]) if v in scene.train_indices else None for v in range(len(maps))]


def test_training_with_normals_resumes_bit_identically(renderer, tiny, tiny_maps, tmp_path):
    import json

    from tsplus_wgpu.train.trainer import TrainConfig, Trainer
    maps = _train_maps(tiny, tiny_maps)
    cfg = TrainConfig(iterations=24, quick=True, seed=3, log_every=5)     # topology on: the mesh changes
    full = Trainer(tiny, cfg, renderer=renderer, normals=maps).train(out_dir=tmp_path / "a", progress=False)
    Trainer(tiny, cfg, renderer=renderer, normals=maps).train(out_dir=tmp_path / "b", progress=False, until=11)
    resumed = Trainer.resume(tmp_path / "b" / "checkpoint.npz", tiny, renderer=renderer, normals=maps)
    resumed.train(progress=False)
    a, b = full.state_arrays(), resumed.state_arrays()
    assert a.keys() == b.keys()
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    plain = Trainer(tiny, cfg, renderer=renderer).train(progress=False).state_arrays()
    assert not np.array_equal(plain["positions"], a["positions"])          # the loss did something
    lines = [json.loads(x) for x in (tmp_path / "a" / "log.jsonl").read_text().splitlines()]
    log = {r["iteration"]: r for r in lines if "event" not in r}
    assert "normal_loss" not in log[1]                                     # it <= 5000 scaled (4)
    assert all(0 < log[i]["normal_loss"] < 2 and log[i]["normal_weight"] == 0.05 for i in (5, 10, 15, 20, 24))
    assert any(r.get("event") == "topology" for r in lines)


def test_cli_train_with_normals(tiny, tiny_maps, tmp_path):
    import json
    import subprocess
    import sys

    from tsplus_wgpu.data.normals import write_normal_maps
    write_normal_maps(tmp_path / "n", tiny, tiny_maps, "png")
    (tmp_path / "n" / "view_001.png").unlink()                            # a training view without a map

    def cli(*args):
        return subprocess.run([sys.executable, "-m", "tsplus_wgpu.cli", "train", "procedural:tiny", "--preset", "quick",
                               "--iterations", "12", "--no-progress", "--log-every", "6", *map(str, args)],
                              capture_output=True, text=True, timeout=300)
    r = cli("--out", tmp_path / "run", "--normals", tmp_path / "n")
    assert r.returncode == 0, r.stderr
    assert "normal maps: 6 of 7 training views" in r.stdout and "1 without a map" in r.stdout
    cfg = json.loads((tmp_path / "run" / "config.json").read_text())
    assert cfg["normals"] == str((tmp_path / "n").resolve())
    assert any("normal_loss" in json.loads(x) for x in (tmp_path / "run" / "log.jsonl").read_text().splitlines())
    # tsplus eval --normals: the mesh's normal error on the evaluated views that have a map
    r = subprocess.run([sys.executable, "-m", "tsplus_wgpu.cli", "eval", str(tmp_path / "run"), "procedural:tiny",
                        "--views", "train", "--normals", str(tmp_path / "n"), "--no-splat", "--write-images", "0"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "normal error vs" in r.stdout and "on 6 of 7 views" in r.stdout
    ev = json.loads((tmp_path / "run" / "eval" / "metrics.json").read_text())["normal_error"]
    assert ev["views"] == 6 and 0 < ev["loss"] < 2 and 0 < ev["angle_deg"] < 180
    # resume with other normals is refused; a malformed map is a one-line error naming it
    r = cli("--out", tmp_path / "run", "--resume", "--iterations", "12", "--normals", tmp_path)
    assert r.returncode == 2 and "normals" in r.stderr
    np.save(tmp_path / "n" / "view_002.npy", np.zeros((5, 5)))
    r = cli("--out", tmp_path / "run2", "--normals", tmp_path / "n")
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and "view_002.npy" in lines[0] and "[H, W, 3]" in lines[0], r.stderr


#: Measured on lavapipe (llvmpipe, LLVM 15; seed 0), topology on (the quick preset's default),
#: normal error mean(1 - <N, P>) of the exported opaque mesh (normal render at sigma 1e-4):
#:   150 iterations: training views 0.5585 without -> 0.5463 with the true normal maps (mean angle
#:   59.81 -> 58.88 deg), held-out view 0.5659 -> 0.5570;
#:   300: 0.3847 -> 0.3753 (42.03 -> 41.18 deg), held-out 0.4785 -> 0.4694.
#: Since the floor starts at the stretched hard prune (schedules.floor_start; iteration 41 instead
#: of 25 at 150 iterations), 150 iterations no longer lower the held-out view's error (0.4111 ->
#: 0.4205), so the test runs 300: training views 0.3828 -> 0.3646 (41.94 -> 40.25 deg), held-out
#: 0.4870 -> 0.3998 (49.47 -> 42.12 deg).
#: With topology off the effect is smaller (200 iterations: 0.3963 -> 0.3943 on the soft model):
#: at method.md's weight 0.05 the loss tilts triangles only through the positions (Adam lr <=
#: 0.0015 per step), and what it does to opacities is overridden by the floor's ramp to 0.9999,
#: except where pruning acts on it.
#: On an NVIDIA H100 (2026-11-27) the one held-out view went the other way: 0.3065 without,
#: 0.3133 with (training views 0.3167 -> 0.2914): float32 sums in the card's order part the
#: 300-step trajectories, and one view of a tiny scene is a coin toss. So the held-out error is
#: the mean over that view and NOVEL_VIEWS more on the cameras' loop (ground-truth maps of the
#: procedural mesh). llvmpipe, cpu layout: training views 0.2958 -> 0.2832, held-out and novel
#: 0.3064 -> 0.2946.
NORMAL_STEPS = 300
NORMAL_GAIN = 0.005
NOVEL_VIEWS = 12


def test_normal_loss_lowers_the_normal_error_of_a_short_run(renderer, tiny, tiny_maps):
    from tsplus_wgpu.train.trainer import TrainConfig, Trainer
    from tsplus_wgpu.data.procedural import make_cameras, render_normal_map
    maps = _train_maps(tiny, tiny_maps)
    k = nl.NormalLoss(renderer)
    # held out: the scene's held-out view and NOVEL_VIEWS more on the cameras' loop (one view alone
    # went either way with the float32 order of the adapter)
    g = tiny.gt_mesh
    novel = [(cam, render_normal_map((g.vertices, g.faces), cam))
             for cam in make_cameras(NOVEL_VIEWS, tiny.cameras[0].width, tiny.cameras[0].height, seed=11)]
    errs = {}
    for name, normals in (("without", None), ("with", maps)):
        # the surfaces' normals: the backdrop behind them (a far sphere, the same without and with the
        # loss in kind but not in amount) changes the held-out error more than the loss does
        # (fill_hidden on: 0.2642 without, 0.2746 with; off: 0.2825, 0.2771; training views equal)
        # no colour detail: its midpoints lie on the surfaces, so it changes no normal, only the time
        cfg = TrainConfig(iterations=NORMAL_STEPS, quick=True, topology=True, background=tiny.background, log_every=0,
                          fill_hidden=False, color_detail=False)
        t = Trainer(tiny, cfg, renderer=renderer, normals=normals)
        t.train(progress=False)
        mesh = Trainer.mesh_model(*t.final_mesh())
        held = [(tiny.cameras[v], tiny_maps[v]) for v in tiny.test_indices] + novel
        for split, views in (("train", [(tiny.cameras[v], tiny_maps[v]) for v in tiny.train_indices]),
                             ("held-out", held)):
            e = [nl.normal_error(nl.render_normals(renderer, mesh, cam, 1e-4, loss=k), *nl.prepare_prior(m))
                 for cam, m in views]
            errs[name, split] = {key: float(np.mean([x[key] for x in e])) for key in ("loss", "angle_deg")}
    for split in ("train", "held-out"):
        a, b = errs["without", split], errs["with", split]
        print(f"{split} views, mesh after {NORMAL_STEPS} quick iterations: normal error without normals "
              f"{a['loss']:.4f} ({a['angle_deg']:.2f} deg), with {b['loss']:.4f} ({b['angle_deg']:.2f} deg)")
    assert errs["with", "train"]["loss"] < errs["without", "train"]["loss"] - NORMAL_GAIN
    assert errs["with", "held-out"]["loss"] < errs["without", "held-out"]["loss"]
