"""Camera controls of the viewer as plain math (no window): orbit, pan, zoom, fly, mouse
look and snapping to the scene's cameras, plus :class:`InputController`, which maps
rendercanvas events (dicts) to those operations so the mapping can be tested without a window.

Conventions are the library's (COLMAP / OpenCV): camera x right, y down, z forward;
``Camera.world_to_camera`` maps world points to camera space.
"""

from __future__ import annotations

import math

import numpy as np

from tsplus_wgpu import Camera


def _rotation(axis, angle):
    """Rotation matrix [3, 3] by ``angle`` (radians) about the unit ``axis`` (Rodrigues)."""
    a = np.asarray(axis, np.float64)
    a = a / max(np.linalg.norm(a), 1e-300)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * (k @ k)


class OrbitCamera:
    """A pinhole camera pose with an orbit target.

    State: ``rotation`` (camera-to-world, columns = camera x, y, z axes in world space),
    ``target`` (orbit centre, on the camera's optical axis), ``distance`` (centre to target),
    ``up`` (world up used for yaw), and intrinsics relative to a reference image size.
    """

    ORBIT_RAD_PER_PX = 0.005
    LOOK_RAD_PER_PX = 0.003
    ZOOM_PER_STEP = 0.9

    def __init__(self, rotation, target, distance, up=(0.0, -1.0, 0.0), intrinsics=None):
        self.rotation = np.asarray(rotation, np.float64).copy()
        self.target = np.asarray(target, np.float64).copy()
        self.distance = float(distance)
        up = np.asarray(up, np.float64)
        self.up = up / max(np.linalg.norm(up), 1e-300)
        #: (width, height, fx, fy, cx, cy) of the reference image; scaled to the window's size
        self.intrinsics = intrinsics

    # ----------------------------------------------------------------- construction
    @classmethod
    def from_camera(cls, camera: Camera, distance=None, up=None):
        """The pose and intrinsics of ``camera``; the target lies ``distance`` ahead."""
        r_wc = camera.R.T                 # camera-to-world rotation
        center = camera.center
        d = 1.0 if distance is None else float(distance)
        up = -r_wc[:, 1] if up is None else up
        return cls(r_wc, center + d * r_wc[:, 2], d, up,
                   (camera.width, camera.height, camera.fx, camera.fy, camera.cx, camera.cy))

    @classmethod
    def look_at_bounds(cls, lo, hi, width=960, height=720, fov_deg=50.0, up=(0.0, 0.0, 1.0)):
        """A camera looking at the centre of the box [lo, hi] from far enough to see it all."""
        lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
        center = 0.5 * (lo + hi)
        radius = max(0.5 * float(np.linalg.norm(hi - lo)), 1e-6)
        f = 0.5 * height / math.tan(math.radians(fov_deg) / 2)
        dist = radius / math.sin(math.radians(fov_deg) / 2) * 1.05
        up = np.asarray(up, np.float64)
        side = np.array([1.0, 1.0, 1.0]) - up * float(up @ np.ones(3))   # a diagonal across the ground
        side = side * (math.sqrt(2.0) / max(float(np.linalg.norm(side)), 1e-12))
        fwd = side - 0.6 * up if abs(up[2]) < 1.0 else np.array([1.0, 1.0, -0.6 * up[2]])
        fwd /= np.linalg.norm(fwd)
        x = np.cross(-up, fwd)             # image x level, image y (down) against up
        if np.linalg.norm(x) < 1e-6:
            x = np.cross(fwd, [1.0, 0.0, 0.0])
        x /= np.linalg.norm(x)
        y = np.cross(fwd, x)
        rot = np.stack([x, y, fwd], 1)
        return cls(rot, center, dist, up, (width, height, f, f, width / 2, height / 2))

    # ----------------------------------------------------------------- derived
    @property
    def center(self):
        return self.target - self.distance * self.rotation[:, 2]

    @property
    def world_to_camera(self):
        m = np.eye(4)
        m[:3, :3] = self.rotation.T
        m[:3, 3] = -self.rotation.T @ self.center
        return m

    def camera(self, width, height) -> Camera:
        """A :class:`Camera` of this pose for a ``width`` x ``height`` image (the reference
        intrinsics scaled by the width ratio, the principal point kept at the same fraction)."""
        w0, h0, fx, fy, cx, cy = self.intrinsics or (width, height, 0.8 * width, 0.8 * width, width / 2, height / 2)
        if (w0, h0) == (width, height):
            return Camera(width, height, fx, fy, cx, cy, self.world_to_camera)
        s = width / w0
        return Camera(width, height, fx * s, fy * s, cx * width / w0, cy * height / h0, self.world_to_camera)

    def _reorthonormalise(self):
        u, _, vt = np.linalg.svd(self.rotation)
        self.rotation = u @ vt

    # ----------------------------------------------------------------- operations
    def orbit(self, dx, dy):
        """Drag by (dx, dy) pixels: yaw about ``up`` and pitch about the camera's x axis,
        both about the target (the target stays put, the distance too)."""
        yaw = _rotation(self.up, -dx * self.ORBIT_RAD_PER_PX)
        pitch = _rotation(self.rotation[:, 0], dy * self.ORBIT_RAD_PER_PX)
        self.rotation = yaw @ pitch @ self.rotation
        self._reorthonormalise()

    def look(self, dx, dy):
        """Mouse look (fly mode): rotate about the camera centre (the centre stays put)."""
        c = self.center
        yaw = _rotation(self.up, -dx * self.LOOK_RAD_PER_PX)
        pitch = _rotation(self.rotation[:, 0], dy * self.LOOK_RAD_PER_PX)
        self.rotation = yaw @ pitch @ self.rotation
        self._reorthonormalise()
        self.target = c + self.distance * self.rotation[:, 2]

    def pan(self, dx, dy, focal_px=None):
        """Drag by (dx, dy) pixels: move centre and target in the image plane so the point
        at the target's depth follows the cursor."""
        f = focal_px or (self.intrinsics[2] if self.intrinsics else 500.0)
        scale = self.distance / f
        self.target = self.target - scale * (dx * self.rotation[:, 0] + dy * self.rotation[:, 1])

    def zoom(self, steps):
        """Scroll ``steps`` (positive = closer): the distance to the target shrinks by 0.9 per step."""
        self.distance = max(self.distance * self.ZOOM_PER_STEP ** float(steps), 1e-6)

    def fly(self, forward, right, up, amount):
        """Move centre and target by ``amount`` scene units along the camera's axes
        (forward = +z, right = +x, up = -y)."""
        v = forward * self.rotation[:, 2] + right * self.rotation[:, 0] - up * self.rotation[:, 1]
        n = np.linalg.norm(v)
        if n > 0:
            self.target = self.target + v / n * amount


class InputController:
    """rendercanvas events -> :class:`OrbitCamera` operations and viewer actions.

    Mouse: left drag orbits (look in fly mode), right or middle drag (or shift + left) pans,
    the wheel zooms. Keys: W A S D (Q E down / up) fly while held; F toggles fly mode (mouse
    look); N / B or ] / [ snap to the next / previous scene camera; X toggles wireframe;
    T the soft splatting render vs the opaque mesh; K or F12 saves a screenshot; H the HUD;
    R resets the view; Escape closes the window.
    """

    ACTIONS = {"n": "next_camera", "]": "next_camera", "b": "previous_camera", "[": "previous_camera",
               "x": "toggle_wireframe", "t": "toggle_splat", "k": "screenshot", "f12": "screenshot",
               "h": "toggle_hud", "r": "reset", "f": "toggle_fly", "escape": "close"}
    FLY_KEYS = {"w": (1, 0, 0), "s": (-1, 0, 0), "d": (0, 1, 0), "a": (0, -1, 0), "e": (0, 0, 1), "q": (0, 0, -1)}

    def __init__(self, camera: OrbitCamera, fly_speed=None):
        self.camera = camera
        self.fly_mode = False
        self.held = set()
        self._drag = None          # (button, x, y, shift)
        self.actions = []          # actions triggered since the last take_actions()
        self.fly_speed = fly_speed  # scene units per second (default: the orbit distance per second)

    def handle(self, event):
        """Feed one rendercanvas event dict."""
        et = event.get("event_type")
        if et == "pointer_down":
            mods = event.get("modifiers", ()) or ()
            self._drag = (event.get("button", 1), event["x"], event["y"], "Shift" in mods)
        elif et == "pointer_up":
            self._drag = None
        elif et == "pointer_move" and self._drag is not None:
            button, x0, y0, shift = self._drag
            dx, dy = event["x"] - x0, event["y"] - y0
            self._drag = (button, event["x"], event["y"], shift)
            if button == 1 and not shift:
                (self.camera.look if self.fly_mode else self.camera.orbit)(dx, dy)
            else:
                self.camera.pan(dx, dy)
        elif et == "wheel":
            self.camera.zoom(-float(event.get("dy", 0.0)) / 100.0)
        elif et == "key_down":
            key = str(event.get("key", "")).lower()
            if key in self.FLY_KEYS:
                self.held.add(key)
            elif key in self.ACTIONS:
                action = self.ACTIONS[key]
                if action == "toggle_fly":
                    self.fly_mode = not self.fly_mode
                self.actions.append(action)
        elif et == "key_up":
            self.held.discard(str(event.get("key", "")).lower())

    def update(self, dt):
        """Apply the held fly keys for ``dt`` seconds."""
        if not self.held:
            return
        f = r = u = 0
        for key in self.held:
            a, b, c = self.FLY_KEYS[key]
            f, r, u = f + a, r + b, u + c
        speed = self.fly_speed if self.fly_speed is not None else max(self.camera.distance, 1e-3)
        self.camera.fly(f, r, u, speed * dt)

    def take_actions(self):
        out, self.actions = self.actions, []
        return out
