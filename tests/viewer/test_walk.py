"""Walk mode (viewer/walk.py, ``tsplus view --walk``) without a window: gravity, standing on
the ground, walls (thick and single-sheet) that cannot be walked through, steps, jumping,
the input mapping, and the viewer drawing from the walker's eye offscreen."""

import math

import numpy as np
import pytest
from scenes import merge_meshes as merge

from tsplus_wgpu import Camera, Renderer
from tsplus_wgpu.apps.physics import MeshCollider
from tsplus_wgpu.cli.view import load_viewer

v = load_viewer()
from tsplus_wgpu.viewer import walk as W  # noqa: E402  (loaded by load_viewer)

EYE = 1.6


def quad(p0, du, dv):
    p0, du, dv = (np.asarray(x, float) for x in (p0, du, dv))
    return np.array([p0, p0 + du, p0 + du + dv, p0 + dv]), np.array([[0, 1, 2], [0, 2, 3]])


def box(lo, hi):
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    c = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],
                  [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return c, f


@pytest.fixture(scope="module")
def course():
    """A 20 m floor; a single-sheet wall at x = 3; a thick wall at y = 3; a 0.3 m step at
    x in [-3, -2]; a 1 m block at x in [-6, -5]."""
    return MeshCollider(merge(
        quad((-10, -10, 0), (20, 0, 0), (0, 20, 0)),
        quad((3, -10, 0), (0, 20, 0), (0, 0, 3)),
        box((-10, 3, 0), (10, 3.5, 3)),
        box((-3, -10, 0), (-2, -4, 0.3)),
        box((-6, -10, 0), (-5, -4, 1.0)),
    ))


def walker(col, feet=(0, 0, 0), forward=(1, 0, 0)):
    return W.WalkController(col, feet, forward, (0, 0, 1), EYE)


def test_gravity_then_standing(course):
    w = walker(course, feet=(0, 0, 2.0))
    g = w.gravity
    assert abs(g - 9.81) < 1e-9                     # eye height 1.6: metres
    dt, t = 1 / 120, 0.0
    for _ in range(30):                             # 0.25 s of free fall
        w.step(dt)
        t += dt
    assert abs(w.feet[2] - (2.0 - 0.5 * g * t * t)) < g * t * dt       # semi-implicit Euler: O(dt)
    assert not w.on_ground
    for _ in range(240):
        w.step(dt)
    assert w.on_ground and abs(w.feet[2]) < 1e-12
    assert abs(w.eye[2] - EYE) < 1e-12
    np.testing.assert_allclose(w.feet[:2], [0, 0], atol=1e-12)


@pytest.mark.parametrize("forward,limit", [((1, 0, 0), 3.0), ((0, 1, 0), 3.0)])
@pytest.mark.parametrize("run,dt", [(False, 1 / 60), (True, 0.25)])
def test_cannot_walk_through_walls(course, forward, limit, run, dt):
    """Walking (or running with long frames) into the single-sheet wall at x = 3 or the thick
    one at y = 3 for 10 s stops a body radius in front of it."""
    w = walker(course, forward=forward)
    axis = int(np.argmax(forward))
    for _ in range(int(10 / dt)):
        w.step(dt, forward=1.0, run=run)
        assert w.feet[axis] <= limit - w.radius + 1e-9
    assert w.feet[axis] > limit - w.radius - 1e-6   # reached it
    assert w.on_ground and abs(w.feet[2]) < 1e-12


def test_slides_along_a_wall(course):
    w = walker(course, forward=(1, 1, 0))
    for _ in range(600):
        w.step(1 / 60, forward=1.0)
    # stopped by both walls, in the corner
    np.testing.assert_allclose(w.feet[:2], [3 - w.radius, 3 - w.radius], atol=1e-6)


def test_climbs_a_low_step_not_a_block(course):
    w = walker(course, feet=(0, -5, 0), forward=(-1, 0, 0))
    heights = []
    for _ in range(int(5 / (1 / 60))):
        w.step(1 / 60, forward=1.0)
        heights.append(w.feet[2])
    assert max(heights) == pytest.approx(0.3, abs=1e-9)      # went over the 0.3 m step
    # ... and stopped at the 1 m block
    assert abs(w.feet[0] - (-5 + w.radius)) < 1e-6 and abs(w.feet[2]) < 1e-12


def test_jump(course):
    w = walker(course)
    w.step(1 / 60)
    assert w.on_ground
    top = 0.0
    w.step(1 / 120, jump=True)
    for _ in range(200):
        w.step(1 / 120)
        top = max(top, w.feet[2])
    assert abs(top - w.jump_height) < 0.03 * w.jump_height
    assert w.on_ground and abs(w.feet[2]) < 1e-12
    # no jumping in mid-air
    w2 = walker(course, feet=(0, 0, 1.0))
    w2.step(1 / 60, jump=True)
    assert w2.velocity[2] < 0


def test_falling_out_of_the_world_resets():
    col = MeshCollider(quad((-1, -1, 0), (2, 0, 0), (0, 2, 0)))
    w = walker(col, feet=(0, 0, 0), forward=(1, 0, 0))
    for _ in range(600):
        w.step(1 / 60, forward=1.0)
        assert w.feet[2] > -10
    assert w.feet[0] < 1.5


def test_look_and_camera(course):
    w = walker(course)
    cam = w.camera(64, 48)
    np.testing.assert_allclose(cam.center, [0, 0, EYE], atol=1e-12)
    np.testing.assert_allclose(cam.R[2], [1, 0, 0], atol=1e-12)            # looks along +x
    np.testing.assert_allclose(cam.R[1], [0, 0, -1], atol=1e-12)           # image y points down
    w.look(100, 0)                                                          # mouse right: turn right
    assert w.heading[1] < 0
    w.look(0, 10_000)                                                       # far down: clamped
    assert math.degrees(w.pitch) == pytest.approx(-85.0)
    w.turn(0, math.radians(170))
    assert math.degrees(w.pitch) == pytest.approx(85.0)


def test_from_camera_and_scene_up(course):
    m = np.eye(4)
    m[:3, :3] = np.array([[0, -1, 0], [0, 0, -1], [1, 0, 0]], float)     # looks along +x, z up
    m[:3, 3] = -m[:3, :3] @ np.array([0.0, 0.0, 1.3])
    cam = Camera(64, 48, 50, 50, 32, 24, m)
    np.testing.assert_allclose(W.scene_up([cam]), [0, 0, 1])
    w = W.WalkController.from_camera(course, cam, [0, 0, 1])
    assert w.eye_height == pytest.approx(1.3)
    np.testing.assert_allclose(w.camera(64, 48).world_to_camera, m, atol=1e-12)


def test_walk_input_maps_keys_and_mouse(course):
    inp = W.WalkInput(walker(course))
    w = inp.walker
    assert inp.handle({"event_type": "key_down", "key": "w"})
    inp.update(0.2)
    assert w.feet[0] == pytest.approx(0.2 * w.walk_speed)
    assert inp.handle({"event_type": "key_down", "key": "Shift"})
    x = w.feet[0]
    inp.update(0.1)
    assert w.feet[0] - x == pytest.approx(0.1 * w.run_speed)
    inp.handle({"event_type": "key_up", "key": "w"})
    inp.handle({"event_type": "key_up", "key": "Shift"})
    assert inp.handle({"event_type": "key_down", "key": " "})
    inp.update(1 / 60)
    assert w.velocity[2] > 0 and not w.on_ground
    assert inp.handle({"event_type": "pointer_down", "x": 10, "y": 10, "button": 1})
    assert inp.handle({"event_type": "pointer_move", "x": 60, "y": 10})
    assert w.heading[1] < 0
    assert not inp.handle({"event_type": "key_down", "key": "x"})          # the viewer's keys pass through
    assert not inp.handle({"event_type": "key_down", "key": "Escape"})
    assert inp.handle({"event_type": "key_down", "key": "r"})               # back to the start
    np.testing.assert_allclose(w.feet, [0, 0, 0])


def test_viewer_walks_offscreen():
    """The viewer with walk=True draws from the walker's eye; W moves it, X still toggles wireframe."""
    from tsplus_wgpu.data import demo_model
    from tsplus_wgpu.data.procedural import make_cameras
    renderer = Renderer()
    model = demo_model(0)
    cams = make_cameras(8, 64, 48)
    viewer = v.Viewer(v.ModelSource(renderer, model), cams, offscreen=True, hud=False, camera_index=1, walk=True)
    assert viewer.walking is not None
    c0 = viewer.current_camera()
    np.testing.assert_allclose(c0.center, cams[1].center, atol=1e-9)       # eye at the scene camera
    img0 = viewer.frame()
    viewer._on_event({"event_type": "key_down", "key": "w"})
    for _ in range(5):
        viewer.walking.update(0.1)
    viewer._on_event({"event_type": "key_up", "key": "w"})
    c1 = viewer.current_camera()
    step = c1.center - c0.center
    assert np.linalg.norm(step) > 0.1 and abs(step[2]) < 1e-9                # walked, on the floor
    img1 = viewer.frame()
    assert np.abs(img1.astype(int) - img0.astype(int)).mean() > 1.0
    viewer._on_event({"event_type": "key_down", "key": "x"})
    viewer.frame()
    assert viewer.wire
    viewer._apply(["next_camera"])                                          # N: walk from the next camera
    np.testing.assert_allclose(viewer.current_camera().center, cams[2].center, atol=1e-9)
    assert "WALK" in viewer.hud_lines()[-1]
    viewer.close()
    # a live trainer has no mesh to collide with
    with pytest.raises(ValueError, match="walk"):
        W.start_walk(object(), c0)


def test_view_help_documents_walk_keys(capsys):
    from tsplus_wgpu.cli.main import main
    with pytest.raises(SystemExit):
        main(["view", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    for words in ("--walk", "W A S D walk", "Space jump", "Shift run", "arrow keys look"):
        assert words in text


def test_view_walk_screenshot_headless(tmp_path, capsys):
    """--screenshot --walk: the walker stands below camera 1 with its eye at the camera, so after
    a second on the ground the frame is the scene camera's own."""
    import imageio.v3 as iio
    from tsplus_wgpu.cli.main import main
    from tsplus_wgpu.data import demo_model
    from tsplus_wgpu.io.export import export
    export(demo_model(0), tmp_path / "m.ply")
    common = [str(tmp_path / "m.ply"), "--scene", "procedural:tiny", "--camera", "1"]
    assert main(["view", *common, "--walk", "--screenshot", str(tmp_path / "walk.png")]) == 0
    assert main(["view", *common, "--screenshot", str(tmp_path / "still.png")]) == 0
    a, b = iio.imread(tmp_path / "walk.png"), iio.imread(tmp_path / "still.png")
    assert a.shape == (48, 64, 3)
    assert np.abs(a.astype(int) - b.astype(int)).max() <= 1


def _orbit_capture():
    """What a capture reconstructs: a floor only where the photos saw it (within 2 m of the
    object in the middle), a box on it, and 12 cameras 3 m out and 1.5 m up, looking at the box:
    no mesh at all under any camera."""
    n = 16
    u = np.linspace(-2.0, 2.0, n + 1)
    x, y = np.meshgrid(u, u, indexing="ij")
    verts = np.stack([x, y, np.zeros_like(x)], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    a = (i * (n + 1) + j).ravel()
    faces = np.concatenate([np.stack([a, a + n + 1, a + 1], 1), np.stack([a + 1, a + n + 1, a + n + 2], 1)])
    model = merge((verts, faces), box((-0.3, -0.3, 0.0), (0.3, 0.3, 0.6)))
    cams = []
    for t in np.linspace(0, 2 * np.pi, 12, endpoint=False):
        c = np.array([3.0 * np.cos(t), 3.0 * np.sin(t), 1.5])
        fwd = np.array([0.0, 0.0, 0.4]) - c
        fwd /= np.linalg.norm(fwd)
        right = np.cross(fwd, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        m = np.eye(4)
        m[:3, :3] = np.stack([right, np.cross(fwd, right), fwd])
        m[:3, 3] = -m[:3, :3] @ c
        cams.append(Camera(64, 48, 50, 50, 32, 24, m))
    return model, cams


def test_a_walk_from_a_photo_stands_on_the_scene_ground_where_the_mesh_has_none():
    """Started from a photo's viewpoint, over no mesh at all (as under every camera of lund and
    office), the walker stands on the ground the cameras stand over, its eye at the camera, and
    walks onto the reconstructed floor without a step; with the mesh alone it fell through."""
    from tsplus_wgpu import TriangleModel
    (verts, faces), cams = _orbit_capture()
    model = TriangleModel(verts, faces, np.zeros((len(verts), 1, 3)), np.ones(len(verts)))

    class Source:
        pass
    src = Source()
    src.model = model
    assert W.scene_ground(model, cams, [0, 0, 1]) == pytest.approx(0.0, abs=1e-12)
    inp = W.start_walk(src, cams[0], cams)
    w = inp.walker
    assert w.floor == pytest.approx(0.0, abs=1e-12) and w.eye_height == pytest.approx(1.5)
    for _ in range(60):
        w.step(1 / 30)
    assert w.on_ground and w.feet[2] == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(w.eye, cams[0].center, atol=1e-9)          # the photo's own viewpoint
    for _ in range(45):                                                     # 1.5 s towards the box
        w.step(1 / 30, forward=1.0)
        assert w.feet[2] == pytest.approx(0.0, abs=1e-9)
    assert np.linalg.norm(w.feet[:2]) < 2.0                                 # on the reconstructed floor
    old = W.WalkController.from_camera(MeshCollider(model), cams[0], [0, 0, 1])   # the mesh alone: it falls
    stood = []                                                              # out of the world, again and again
    for _ in range(60):
        old.step(1 / 30)
        stood.append(old.on_ground)
    assert not any(stood) and old.floor is None
    assert W.scene_ground(model, [], [0, 0, 1]) is None                     # no cameras: the mesh alone
