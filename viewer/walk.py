"""First-person walking through the mesh (``tsplus view --walk``): gravity, ground contact
and collision against the triangles, as plain math that runs without a window.

:class:`WalkController` is the body: a stack of spheres from knee to head height (collision
with walls and ceilings through :meth:`MeshCollider.closest_points`) and a ray down from
above the knees for the ground (:meth:`MeshCollider.raycast`: embree through trimesh when
installed). Steps lower than ``step_height`` are climbed. Every :meth:`step` is cut into
substeps in which the body moves at most half a sphere radius, so it cannot pass through
thin walls or floors however fast it falls. Falling out of the world puts it back at the start.

:class:`WalkInput` maps rendercanvas events to it: W A S D move, mouse drag (or the arrow
keys) looks around, Space jumps, Shift runs; everything else goes on to the viewer.

Lengths scale with the eye height (default: the starting camera's height above the ground
below it, else 1.6): the same walk works in metres or in a COLMAP scene's arbitrary units.

A trained mesh has no ground right under its cameras (no photo sees straight down), so a walk
started from a photo's viewpoint would fall through it. :func:`start_walk` finds the scene's
ground from its cameras (:func:`tsplus_wgpu.find_placement`, what ``tsplus export --origin
ground`` stands the mesh on): the eye starts at the camera that height above it, and the ground
is also a ``floor`` under the whole mesh, stood on wherever the mesh has a hole.
"""

from __future__ import annotations

import math

import numpy as np

from tsplus_wgpu import Camera, MeshCollider, PlacementError, estimate_up, find_placement

def _unit(v):
    v = np.asarray(v, np.float64)
    return v / max(float(np.linalg.norm(v)), 1e-300)


def scene_up(cameras, default=None):
    """World up from the scene's cameras (:func:`tsplus_wgpu.estimate_up`),
    snapped to a coordinate axis when within 10 degrees of one; ``default`` (+z) without cameras."""
    est = estimate_up(cameras) if cameras else None
    if est is None:
        return _unit(default) if default is not None else np.array([0.0, 0.0, 1.0])
    u = est.up
    k = int(np.argmax(np.abs(u)))
    if abs(u[k]) > math.cos(math.radians(10.0)):
        u = np.zeros(3)
        u[k] = 1.0 if est.up[k] > 0 else -1.0
    return u


class WalkController:
    """A walking body in a triangle mesh.

    Args:
        collider: :class:`MeshCollider` (or anything it takes).
        feet: starting position of the feet [3].
        forward: initial view direction [3] (its part along ``up`` becomes the pitch).
        up: world up [3] (gravity pulls along -up).
        eye_height: eye above the feet (scene units); sets every other length:
            radius 0.2x, step 0.25x, head 1.1x, walk speed 0.9x per second, run 2.5x, jump 0.35x,
            gravity 9.81 / 1.6 x per second^2.
        floor: the height (along ``up``) of a ground plane under the whole mesh, stood on where the
            mesh has no ground (None: only the mesh).
    """

    LOOK_RAD_PER_PX = 0.003
    TURN_RAD_PER_S = 1.8
    MAX_PITCH = math.radians(85.0)

    def __init__(self, collider, feet, forward=(1.0, 0.0, 0.0), up=(0.0, 0.0, 1.0), eye_height=1.6, floor=None):
        self.collider = collider if isinstance(collider, MeshCollider) else MeshCollider(collider)
        self.up = _unit(up)
        self.floor = None if floor is None else float(floor)
        self.eye_height = float(eye_height)
        if not self.eye_height > 0:
            raise ValueError(f"eye_height: expected > 0, got {eye_height}")
        e = self.eye_height
        self.radius = 0.2 * e
        self.step_height = 0.25 * e
        self.head = 1.1 * e
        self.walk_speed = 0.9 * e
        self.run_speed = 2.5 * e
        self.jump_height = 0.35 * e
        self.gravity = 9.81 / 1.6 * e
        f = np.asarray(forward, np.float64)
        fh = f - np.dot(f, self.up) * self.up
        if np.linalg.norm(fh) < 1e-9:      # looking straight up or down: any horizontal heading
            fh = np.cross(self.up, [1.0, 0.0, 0.0] if abs(self.up[0]) < 0.9 else [0.0, 1.0, 0.0])
        self.heading = _unit(fh)
        self.pitch = float(np.clip(math.asin(np.clip(np.dot(_unit(f), self.up), -1, 1)), -self.MAX_PITCH,
                                   self.MAX_PITCH))
        self.feet = np.asarray(feet, np.float64).reshape(3).copy()
        self.velocity = np.zeros(3)
        self.on_ground = False
        self.start = (self.feet.copy(), self.heading.copy(), self.pitch)
        lo, hi = self.collider.bounds
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        self._floor_limit = float((corners @ self.up).min()) - 2.0 * self.head   # below: out of the world
        # heights of the body spheres' centres: from the knees (above a climbable step) to the head
        top = self.head - self.radius
        bottom = self.step_height + self.radius
        n = max(1, int(math.ceil((top - bottom) / self.radius)) + 1)
        self.sphere_heights = np.linspace(bottom, max(top, bottom), n)

    @classmethod
    def from_camera(cls, collider, camera: Camera, up, eye_height=None, ground=None):
        """Stand below ``camera``, looking where it looks. Without ``eye_height``, the eye stays at
        the camera: the feet go on the scene's ``ground`` (a height along ``up``, also the walk's
        floor) when it is below the camera, else on the first surface below its centre (at most
        the mesh's height below it; else the eye height is 1.6 units, or a quarter of the mesh's
        height when that is smaller)."""
        col = collider if isinstance(collider, MeshCollider) else MeshCollider(collider)
        up = _unit(up)
        center = camera.center
        above = None if ground is None else float(center @ up) - float(ground)
        if above is not None and above > 1e-9:
            return cls(col, center - up * above, camera.R[2], up, above if eye_height is None else eye_height,
                       floor=ground)
        if eye_height is None:
            lo, hi = col.bounds
            tall = float(np.abs(hi - lo) @ np.abs(up))
            dist, _, _ = col.raycast(center[None], -up[None], tall)
            eye_height = float(dist[0]) if np.isfinite(dist[0]) and dist[0] > 1e-6 else min(1.6, 0.25 * tall)
        walker = cls(col, center - up * eye_height, camera.R[2], up, eye_height)
        return walker

    # ------------------------------------------------------------------ derived
    @property
    def eye(self):
        return self.feet + self.up * self.eye_height

    @property
    def forward(self):
        return math.cos(self.pitch) * self.heading + math.sin(self.pitch) * self.up

    @property
    def right(self):
        return _unit(np.cross(self.heading, self.up))

    def world_to_camera(self):
        z = _unit(self.forward)
        x = _unit(np.cross(z, self.up))
        y = np.cross(z, x)
        m = np.eye(4)
        m[:3, :3] = np.stack([x, y, z])
        m[:3, 3] = -m[:3, :3] @ self.eye
        return m

    def camera(self, width, height, intrinsics=None) -> Camera:
        """The eye's :class:`Camera`; ``intrinsics`` = (w0, h0, fx, fy, cx, cy) of a reference image,
        scaled to ``width`` (default: a 68-degree horizontal field of view)."""
        if intrinsics is None:
            f = 0.5 * width / math.tan(math.radians(34.0))
            return Camera(width, height, f, f, width / 2, height / 2, self.world_to_camera())
        w0, h0, fx, fy, cx, cy = intrinsics
        s = width / w0
        return Camera(width, height, fx * s, fy * s, cx * width / w0, cy * height / h0, self.world_to_camera())

    # ------------------------------------------------------------------ control
    def look(self, dx, dy):
        """Turn by a mouse move of (dx, dy) pixels: right turns right, down looks down."""
        self.turn(-dx * self.LOOK_RAD_PER_PX, -dy * self.LOOK_RAD_PER_PX)

    def turn(self, yaw, pitch):
        """Yaw (radians, positive = left, about up) and pitch (positive = up, clamped to 85 degrees)."""
        c, s = math.cos(yaw), math.sin(yaw)
        h = self.heading
        self.heading = _unit(c * h + s * np.cross(self.up, h))
        self.pitch = float(np.clip(self.pitch + pitch, -self.MAX_PITCH, self.MAX_PITCH))

    def reset(self):
        feet, heading, pitch = self.start
        self.feet, self.heading, self.pitch = feet.copy(), heading.copy(), pitch
        self.velocity = np.zeros(3)
        self.on_ground = False

    def step(self, dt, forward=0.0, right=0.0, jump=False, run=False):
        """Advance ``dt`` seconds with the walking intent ``forward`` / ``right`` in [-1, 1]
        (along the heading and to its right), ``jump`` (only from the ground), ``run``."""
        dt = float(min(max(dt, 0.0), 0.25))
        if dt == 0.0:
            return
        wish = forward * self.heading + right * self.right
        n = np.linalg.norm(wish)
        wish = wish / n if n > 1 else wish
        speed = self.run_speed if run else self.walk_speed
        vert = float(np.dot(self.velocity, self.up))
        if jump and self.on_ground:
            vert = math.sqrt(2.0 * self.gravity * self.jump_height)
            self.on_ground = False
        self.velocity = wish * speed + vert * self.up
        fall = abs(vert) + self.gravity * dt
        moves = max(1, int(math.ceil((speed + fall) * dt / (0.5 * self.radius))))
        h = dt / moves
        for _ in range(moves):
            self._substep(h)
        if float(np.dot(self.feet, self.up)) < self._floor_limit:   # fell out of the world
            self.reset()

    def _substep(self, h):
        up = self.up
        if not self.on_ground:
            self.velocity -= self.gravity * h * up
        self.feet = self.feet + self.velocity * h
        # walls and ceilings: push every body sphere out of the mesh
        for _ in range(3):
            centers = self.feet[None, :] + self.sphere_heights[:, None] * up[None, :]
            cp, dist, _, _ = self.collider.closest_points(centers, self.radius)
            hit = dist < self.radius
            if not np.any(hit):
                break
            k = int(np.argmin(np.where(hit, dist - self.radius, np.inf)))
            n = centers[k] - cp[k]
            d = float(np.linalg.norm(n))
            if d < 1e-12:
                break
            n /= d
            nu = float(np.dot(n, up))
            push = self.radius - d
            if nu > 0.7:          # a walkable surface under the knees: the ground ray handles it
                break
            if nu >= -0.5:        # a wall or an edge: pushed back horizontally, never lifted
                nh = n - nu * up
                norm = float(np.linalg.norm(nh))
                if norm < 1e-6:
                    break
                n = nh / norm
                push = min(push / max(norm, 0.3), self.radius)
            self.feet = self.feet + n * push   # (a ceiling pushes down)
            vn = float(np.dot(self.velocity, n))
            if vn < 0:
                self.velocity = self.velocity - vn * n
        # the ground: a ray down from above the knees, long enough to catch any substep's fall
        reach = self.step_height + self.radius
        vert = float(np.dot(self.velocity, up))
        snap = 0.05 * self.eye_height if self.on_ground else 0.0
        origin = self.feet + up * reach
        dist, _, nrm = self.collider.raycast(origin[None], -up[None], reach + snap)
        ground = np.isfinite(dist[0]) and float(np.dot(nrm[0], up)) > 0.5 and vert <= 1e-9
        if ground:
            self.feet = origin - up * float(dist[0])
            self.velocity = self.velocity - vert * up
            self.on_ground = True
        elif self.floor is not None and vert <= 1e-9 and self.floor - float(np.dot(self.feet, up)) >= -snap:
            self.feet = self.feet + up * (self.floor - float(np.dot(self.feet, up)))   # the floor under the holes
            self.velocity = self.velocity - vert * up
            self.on_ground = True
        else:
            self.on_ground = False


class WalkInput:
    """rendercanvas events -> :class:`WalkController` (no window needed to test it)."""

    MOVE = {"w": (1, 0), "s": (-1, 0), "d": (0, 1), "a": (0, -1)}
    TURN = {"arrowleft": (1, 0), "arrowright": (-1, 0), "arrowup": (0, 1), "arrowdown": (0, -1)}

    def __init__(self, walker: WalkController):
        self.walker = walker
        self.held = set()
        self.jump = False
        self._drag = None

    def handle(self, event):
        """Feed one event; returns True when walking used it (the viewer ignores it then)."""
        et = event.get("event_type")
        if et in ("key_down", "key_up"):
            key = str(event.get("key", "")).lower()
            if key in ("space", " "):
                key = " "
            if key in self.MOVE or key in self.TURN or key in (" ", "shift"):
                if et == "key_down":
                    self.held.add(key)
                    if key == " ":
                        self.jump = True
                else:
                    self.held.discard(key)
                return True
            if key == "r" and et == "key_down":
                self.walker.reset()
                return True
            return False
        if et == "pointer_down":
            self._drag = (event["x"], event["y"])
            return True
        if et == "pointer_up":
            self._drag = None
            return True
        if et == "pointer_move":
            if self._drag is not None:
                x0, y0 = self._drag
                self.walker.look(event["x"] - x0, event["y"] - y0)
                self._drag = (event["x"], event["y"])
            return True
        return et == "wheel"

    def update(self, dt):
        """Apply the held keys for ``dt`` seconds and step the walker."""
        f = sum(self.MOVE[k][0] for k in self.held if k in self.MOVE)
        r = sum(self.MOVE[k][1] for k in self.held if k in self.MOVE)
        yaw = sum(self.TURN[k][0] for k in self.held if k in self.TURN)
        pitch = sum(self.TURN[k][1] for k in self.held if k in self.TURN)
        if yaw or pitch:
            a = self.walker.TURN_RAD_PER_S * dt
            self.walker.turn(yaw * a, pitch * a)
        self.walker.step(dt, f, r, jump=self.jump, run="shift" in self.held)
        self.jump = False


def scene_ground(model, cameras, up):
    """The height (along ``up``) of the ground the scene's ``cameras`` stand over in ``model``'s
    mesh (:func:`tsplus_wgpu.find_placement`), or None: no cameras, or nothing looks like ground."""
    if not cameras or model is None or not hasattr(model, "positions"):
        return None
    try:
        return find_placement(model.positions, model.triangles, [c.center for c in cameras],
                              [c.R[2] for c in cameras], up).ground
    except PlacementError:
        return None


def start_walk(source, camera: Camera, cameras=None, collider=None, up=None):
    """A :class:`WalkInput` around a walker standing below ``camera`` in ``source``'s mesh
    (a viewer source with a ``model``), up from the scene's ``cameras`` (without them ``up``,
    else +z), on the ground those cameras stand over (:func:`scene_ground`) where one is found."""
    model = getattr(source, "model", None)
    if collider is None:
        if model is None or not hasattr(model, "positions"):
            raise ValueError("--walk: needs a mesh (a run folder, PLY, GLB or OBJ), not a live trainer")
        collider = MeshCollider(model)
    u = scene_up(cameras, up)
    return WalkInput(WalkController.from_camera(collider, camera, u, ground=scene_ground(model, cameras, u)))
