"""The viewer window: :class:`Viewer` shows a source (:mod:`.frames`) in a rendercanvas canvas
(a glfw window, or an offscreen canvas for headless images) with orbit / fly / walk controls,
the HUD, screenshots and a hook that draws between training steps. Built only on the public API
of ``tsplus_wgpu``.
"""

from __future__ import annotations

import math
import os
import sys
import time

import numpy as np
import wgpu

from tsplus_wgpu import Camera, TriangleModel, estimate_up

from .controls import InputController, OrbitCamera
from .frames import FrameRenderer

NO_DISPLAY_HINT = ("use `tsplus view RUN --screenshot out.png --camera N` for images without a display "
                   "(or run under xvfb-run)")


def display_problem():
    """Why no window can open here (a short phrase), or None when a display is set."""
    if sys.platform.startswith(("linux", "freebsd", "openbsd")) and not (
            os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        return "no display (DISPLAY and WAYLAND_DISPLAY are not set)"
    return None


class NoDisplayError(RuntimeError):
    """No window can be opened: no display, or glfw could not start."""


# ---------------------------------------------------------------------------- the viewer
class Viewer:
    """A window (or offscreen canvas) showing ``source`` with orbit / fly controls.

    Args:
        source: a :class:`ModelSource` or :class:`TrainerSource`.
        cameras: the scene's cameras (snap targets), or None.
        size: (width, height) of the canvas; default: the first camera's (at most 1280 wide).
        offscreen: True for an offscreen canvas (no window; :meth:`frame` returns the image).
        background: RGB where nothing is drawn.
        hud: show the HUD text.
        max_fps: frame-rate cap of :meth:`run` and of the live hook.
        screenshot_dir: folder of the screenshot key's PNGs.
        near: near plane, in the units of the source's positions and the cameras (``tsplus view``:
            the scene's ``WorldFrame.near_world()``; the live viewer: the trainer's ``config.near``,
            as it draws the trainer's frame-unit buffers with ``trainer.scene.cameras``).
    """

    def __init__(self, source, cameras=None, size=None, offscreen=False, background=(0, 0, 0), hud=True,
                 max_fps=30.0, screenshot_dir=".", title="tsplus view", camera_index=None, walk=False, near=0.01,
                 up=None):
        self.source = source
        self.up = None if up is None else np.asarray(up, np.float64)   # without cameras: the file's up (default +z)
        self.near = float(near)
        self.cameras = list(cameras or [])
        self.renderer = source.renderer
        self.frames = FrameRenderer(self.renderer, background=background)
        self.offscreen = offscreen
        self.hud = hud
        self.max_fps = float(max_fps)
        self.mode = "mesh"
        self.wire = False
        self.screenshot_dir = screenshot_dir
        self.camera_index = None
        if size is None:
            if self.cameras:
                c = self.cameras[0 if camera_index is None else camera_index]
                s = min(1.0, 1280 / c.width)
                size = (max(1, round(c.width * s)), max(1, round(c.height * s)))
            else:
                size = (960, 720)
        self.size = tuple(int(v) for v in size)
        self._home = self._initial_camera()
        self.controller = InputController(self._home)
        if camera_index is not None:
            self.snap(camera_index)
        self._frame_times = []
        self.frames_drawn = 0             # frames drawn since the start (benchmarks, tests)
        self._last_frame = None
        self._capture = None
        self._hud_lines, self._hud_time = None, -math.inf
        self.last_image = None
        self.closed = False
        self._open_canvas(title)
        self.walking = None        # walk.WalkInput while walking (--walk)
        if walk:
            self.start_walk()

    def start_walk(self):
        """Walk from the current view: gravity and collision against the mesh (viewer/walk.py)."""
        from .walk import start_walk
        self.walking = start_walk(self.source, self.controller.camera.camera(*self.size), self.cameras, up=self.up)

    # ------------------------------------------------------------------ setup
    def _initial_camera(self):
        pos = getattr(self.source, "model", None)
        if self.cameras:
            cam = self.cameras[0]
            return OrbitCamera.from_camera(cam, distance=self._focus_distance(cam), up=self._scene_up())
        if isinstance(pos, TriangleModel) and pos.num_vertices:
            lo, hi = pos.positions.min(0), pos.positions.max(0)
        else:
            lo, hi = -np.ones(3), np.ones(3)
        w, h = self.size
        return OrbitCamera.look_at_bounds(lo, hi, w, h, up=(0.0, 0.0, 1.0) if self.up is None else self.up)

    def _scene_up(self):
        """The scene's up from its cameras (:func:`tsplus_wgpu.estimate_up`)."""
        up = estimate_up(self.cameras)
        return up.up if up is not None else np.array([0.0, -1.0, 0.0])

    def _focus_distance(self, cam):
        """Distance along the optical axis to the scene's cameras' centroid look point (a
        sensible orbit radius); 1 without better information."""
        centers = np.array([c.center for c in self.cameras])
        mid = centers.mean(0)
        d = float(np.dot(mid - cam.center, cam.R[2]))
        spread = float(np.linalg.norm(centers - mid, axis=1).mean())
        return d if d > 1e-3 else max(spread, 1.0)

    def _open_canvas(self, title):
        w, h = self.size
        dev = self.renderer.ctx.device
        if self.offscreen:
            from rendercanvas.offscreen import RenderCanvas
            self.canvas = RenderCanvas(size=(w, h), pixel_ratio=1.0, format="rgba-u8")
            self.context = self.canvas.get_wgpu_context()
            self.format = wgpu.TextureFormat.rgba8unorm
            self.context.configure(device=dev, format=self.format, usage=wgpu.TextureUsage.RENDER_ATTACHMENT
                                   | wgpu.TextureUsage.COPY_SRC)
        else:
            why = display_problem()
            if why:
                raise NoDisplayError(why)
            try:
                from rendercanvas.glfw import RenderCanvas
                self.canvas = RenderCanvas(size=(w, h), title=title, update_mode="manual")
            except Exception as exc:   # glfw missing, or it cannot reach the display
                raise NoDisplayError(f"the window could not open ({type(exc).__name__}: {exc})") from None
            self.context = self.canvas.get_wgpu_context()
            # a plain (not sRGB) 8-bit format: colours reach the screen as the mesh renderer computes them
            preferred = self.context.get_preferred_format(self.renderer.ctx.adapter)
            for fmt in ("bgra8unorm", "rgba8unorm", str(preferred).replace("-srgb", ""), preferred):
                try:
                    self.context.configure(device=dev, format=fmt, alpha_mode="opaque",
                                           usage=wgpu.TextureUsage.RENDER_ATTACHMENT | wgpu.TextureUsage.COPY_SRC)
                    self.format = fmt
                    break
                except Exception as exc:   # not supported by this surface: try the next
                    err = exc
            else:
                raise NoDisplayError(f"the window's surface takes none of the usual formats ({err})")
            self.canvas.add_event_handler(self._on_event, "pointer_down", "pointer_up", "pointer_move", "wheel",
                                          "key_down", "key_up", "close")
        self.canvas.request_draw(self._draw)

    def _on_event(self, event):
        if event.get("event_type") == "close":
            self.closed = True
            return
        if self.walking is not None and self.walking.handle(event):
            return
        self.controller.handle(event)

    # ------------------------------------------------------------------ actions
    def snap(self, index):
        """Put the view on scene camera ``index`` (modulo their number)."""
        if not self.cameras:
            return
        self.camera_index = int(index) % len(self.cameras)
        cam = self.cameras[self.camera_index]
        self.controller.camera = OrbitCamera.from_camera(cam, distance=self._focus_distance(cam),
                                                         up=self._scene_up())
        if getattr(self, "walking", None) is not None:
            self.start_walk()

    def _apply(self, actions):
        for a in actions:
            if a == "next_camera":
                self.snap(0 if self.camera_index is None else self.camera_index + 1)
            elif a == "previous_camera":
                self.snap(-1 if self.camera_index is None else self.camera_index - 1)
            elif a == "toggle_wireframe":
                self.wire = not self.wire
            elif a == "toggle_splat":
                self.mode = "mesh" if self.mode == "splat" else "splat"
            elif a == "toggle_hud":
                self.hud = not self.hud
            elif a == "reset":
                self.camera_index = None
                self.controller.camera = self._initial_camera()
            elif a == "screenshot":
                path = os.path.join(self.screenshot_dir, time.strftime("tsplus_%Y%m%d_%H%M%S.png"))
                self._capture = path
            elif a == "close":
                self.close()

    def current_camera(self) -> Camera:
        if getattr(self, "walking", None) is not None:
            return self.walking.walker.camera(*self.size, self.controller.camera.intrinsics)
        return self.controller.camera.camera(*self.size)

    def fps(self):
        """Frames per second over the last (up to) 30 frames."""
        t = self._frame_times[-31:]
        return (len(t) - 1) / (t[-1] - t[0]) if len(t) > 1 and t[-1] > t[0] else 0.0

    def hud_lines(self):
        s = self.source.stats or {}
        it, loss, ps = s.get("iteration"), s.get("loss"), s.get("psnr")
        mode = "WIRE" if self.wire else self.mode.upper()
        if self.mode == "splat" and not self.source.has_splat:
            mode += " (NO SPLAT DATA)"
        cam = f"CAM {self.camera_index}/{len(self.cameras)}" if self.camera_index is not None else "FREE"
        return [f"ITER {it if it is not None else '-'}  LOSS {'-' if loss is None else f'{loss:.4f}'}  "
                f"PSNR {'-' if ps is None else f'{ps:.2f}'}",
                f"VERTS {self.source.num_vertices}  TRIS {self.source.num_triangles}",
                f"FPS {self.fps():.1f}  {mode}  {cam}{'  FLY' if self.controller.fly_mode else ''}"
                + ("" if self.walking is None else f"  WALK{'' if self.walking.walker.on_ground else ' (AIR)'}")]

    # ------------------------------------------------------------------ drawing
    def _draw(self):
        tex = self.context.get_current_texture()
        w, h = tex.width, tex.height
        if (w, h) != self.size:
            self.size = (w, h)
        self.source.refresh()
        lines = self.hud_lines() if self.hud else None
        now = time.perf_counter()
        if lines != self._hud_lines and (not lines or not self._hud_lines or now - self._hud_time >= 0.25):
            self.frames.set_hud(lines)      # text upload at most 4 times a second
            self._hud_lines, self._hud_time = lines, now
        cam = self.current_camera()
        enc = self.renderer.ctx.device.create_command_encoder()
        mode = "wire" if self.wire else self.mode
        self.frames.record(enc, tex.create_view(), self.format, cam, self.source, mode, self.near)
        readback = None
        if self._capture is not None and not self.offscreen:
            row = (4 * w + 255) // 256 * 256
            readback = self.renderer.ctx.device.create_buffer(size=row * h, usage=wgpu.BufferUsage.COPY_DST
                                                              | wgpu.BufferUsage.MAP_READ)
            enc.copy_texture_to_buffer({"texture": tex, "mip_level": 0, "origin": (0, 0, 0)},
                                       {"buffer": readback, "offset": 0, "bytes_per_row": row, "rows_per_image": h},
                                       (w, h, 1))
        self.renderer.ctx.queue.submit([enc.finish()])
        if readback is not None:
            readback.map_sync(wgpu.MapMode.READ)
            raw = np.frombuffer(readback.read_mapped(), np.uint8).copy()
            readback.unmap()
            img = raw.reshape(h, -1)[:, :4 * w].reshape(h, w, 4)
            if str(self.format).startswith("bgra"):
                img = img[..., [2, 1, 0, 3]]
            self._store_capture(img)

    def _store_capture(self, img):
        self.last_image = np.ascontiguousarray(img[..., :3])
        path, self._capture = self._capture, None
        if isinstance(path, str):
            import imageio.v3 as iio
            iio.imwrite(path, self.last_image)
            print(f"tsplus view: saved {path}", flush=True)

    def process_events(self):
        """Pull the window's events into the controller (no-op offscreen)."""
        if self.offscreen or self.closed:
            return
        try:
            self.canvas._process_events()
        except AttributeError:   # pragma: no cover (rendercanvas without it)
            import glfw
            glfw.poll_events()
        if self.canvas.get_closed():
            self.closed = True

    def frame(self, capture=False):
        """Process events, apply held keys and actions, draw one frame. Returns the frame as
        uint8 [H, W, 3] when ``capture`` (or offscreen), else None."""
        now = time.perf_counter()
        self.process_events()
        if self.closed:
            return None
        dt = 0.0 if self._last_frame is None else min(now - self._last_frame, 0.25)
        self._last_frame = now
        (self.walking.update if self.walking is not None else self.controller.update)(dt)
        self._apply(self.controller.take_actions())
        if self.closed:
            return None
        if capture and self._capture is None:
            self._capture = True
        if self.offscreen:
            img = self.canvas.draw()
            self._frame_times.append(time.perf_counter())
            self.frames_drawn += 1
            img = np.asarray(img)
            if self._capture is not None:
                self._store_capture(img)
            return np.ascontiguousarray(img[..., :3])
        self.canvas.force_draw()
        self._frame_times.append(time.perf_counter())
        self.frames_drawn += 1
        del self._frame_times[:-64]
        if capture:
            return self.last_image
        return None

    def run(self):
        """The interactive loop (until the window closes), at most ``max_fps`` frames/s."""
        period = 1.0 / self.max_fps if self.max_fps > 0 else 0.0
        while not self.closed:
            t = time.perf_counter()
            self.frame()
            rest = period - (time.perf_counter() - t)
            if rest > 0:
                time.sleep(rest)

    def close(self):
        if not self.closed:
            self.closed = True
            try:
                self.canvas.close()
                if not self.offscreen:
                    self.canvas._process_events()
            except Exception:
                pass

    # ------------------------------------------------------------------ live training
    def training_hook(self, stop_on_close=False):
        """A ``Trainer.step_hooks`` entry: draws at most ``max_fps`` frames/s between steps;
        when the window closes training goes on (or stops, as Ctrl-C, with ``stop_on_close``)."""
        period = 1.0 / self.max_fps if self.max_fps > 0 else 0.0
        state = {"last": -math.inf, "done": False}

        def hook(trainer, stats):
            if state["done"]:
                return None
            now = time.perf_counter()
            if now - state["last"] < period:
                return None
            state["last"] = now
            self.frame()
            if self.closed:
                state["done"] = True
                if stop_on_close:
                    print("tsplus: viewer closed; stopping training (--view-close stop)", flush=True)
                    return False
                print("tsplus: viewer closed; training continues", flush=True)
            return None
        return hook
