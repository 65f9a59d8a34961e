"""The training loop of Triangle Splatting+ on the device: :class:`Trainer`.

Every step stays on the device: ``train_activate`` (opacity from logits with the scheduled
floor, re-inverting the logits when it moves; SH to the renderer's layout) -> forward at the
scheduled sigma -> :class:`~.losses.ImageLoss` (0.8 L1 + 0.2 D-SSIM) -> ``pack_v_out`` ->
backward (gradients into reused device buffers, no readback) -> early opacity loss
(``opacity_reg_count`` + ``opacity_reg_scale``, while it < 5000 scaled) -> ``train_grads`` (chain rule of the
opacity activation, SH bands above the scheduled degree masked) -> Adam per parameter group
(positions, SH DC, SH rest, opacity logits) with the scheduled learning rates, the positions'
scaled per vertex by depth (:mod:`.optimizer`).

Host round trips: the renderer's size readbacks (pair counts, tile ranges); the trainer reads
back only at its logging interval and for checkpoints.

Determinism: the view of iteration ``it`` is ``perm_e[(it - 1) % V]``, ``perm_e`` drawn by
``numpy.random.default_rng([seed, e])`` with ``e = (it - 1) // V``: a pure function of (seed,
iteration). Every kernel sums in a fixed order, so a seed on one adapter gives bit-identical
parameters, and a resumed run equals the uninterrupted one bit for bit.

Beyond the step:

* The initial mesh (no ``model`` given, :func:`~.initial.initial_model`): the Delaunay faces of
  the scene's points, carved along the training cameras' lines of sight (``config.carve``) and
  without the long ones (``config.init_max_edge``), plus the background shell (:mod:`.shell`,
  ``config.shell``) whose triangles the prunes leave alone (``self.groups``).
* Topology (prune, densify, the densification stop, :func:`~.strategy.vertex_cap`) is
  :class:`~.strategy.TopologyStrategy`; each topology step is one host round trip
  (:meth:`Trainer.apply_topology`: read the :class:`~.state.VertexState`, map it through the pure
  :mod:`.strategy.ops`, re-create the device buffers in :meth:`Trainer.set_state`).
* Anti-aliasing (method.md): iteration ``it`` renders with the exact s-times camera
  (``s = Schedule.supersample(it)``: 2 from 20000, 4 from 25000, scaled with ``quick``; halved
  until it fits the binding limit, :meth:`Trainer.fit_supersample`), area-downsamples on the
  device and sends the gradient back through the transpose; held-out views are evaluated at
  s = 4. At s > 1 the per-triangle max weight ``alpha T`` is the maximum over sub-pixel samples:
  the same point-sampled function sampled more densely, so thresholds are not rescaled; the size
  prune measures at the training resolution.
* The optional normal loss (``config.normals``, :mod:`.normals`): for it > 5000 (scaled) on views
  with a map, a second forward/backward of the model's blended normals adds its gradients (both
  paths) into the same buffers before Adam.

World units (:mod:`tsplus_wgpu.data.frame`): ``self.scene``, device buffers and :meth:`Trainer.render`
are in the normalised frame; ``current_model``, ``final_mesh`` and checkpoints in world units.
"""

from __future__ import annotations

import time

import numpy as np

from ..data.frame import WorldFrame
from ..io.metrics import psnr, ssim  # noqa: F401  (re-exported: train.trainer.psnr/ssim)
from ..kernels.loss import DownsampleArea, DownsampleAreaT, PackVOut, supersampled_camera
from ..kernels.optim import OpacityRegGradient, TrainActivate, TrainGrads
from ..render.device_model import DeviceModel, corner_order, corner_spans
from ..types import TriangleModel
from .checkpoint import CheckpointError, read_checkpoint, resume_config, write_checkpoint
from .config import TrainConfig
from .init import SH_C0
from .final import final_mesh
from .initial import initial_model
from .losses import ImageLoss
from .memory import check_fits
from .loop import TrainLoop
from .normals import NormalLoss, loss_from_render, normal_priors
from .optimizer import ParamOptimizer
from .schedules import SUPERSAMPLE_EVAL, logit_from_opacity
from .state import PARAMS, VertexState
from .strategy import TopologyStrategy, vertex_cap


class Trainer:
    """Trains a triangle model on a :class:`~tsplus_wgpu.data.Scene`.

    Args:
        scene: the scene (cameras, images, points, train/test split).
        config: a :class:`TrainConfig`.
        renderer: a :class:`~tsplus_wgpu.Renderer` (default: a new one on the best adapter).
        model: an initial :class:`TriangleModel` in world units (default: :func:`~.initial.initial_model`
            of the scene's points and colours).
        normals: normal priors for the normal loss: a :class:`~tsplus_wgpu.data.normals.NormalMaps`
            or a list with one ``(prior [H, W, 3], valid [H, W])`` or None per view (default: read
            from ``config.normals`` when set, else no normal loss).
        frame: the :class:`~tsplus_wgpu.data.frame.WorldFrame` to train in (default: ``scene.frame()``).
        groups: ``[M]`` triangle groups of ``model`` (:mod:`.shell`; default: all ordinary). Without
            ``model``: the points' mesh without long faces, plus the shell (module docstring).
    """

    def __init__(self, scene, config: TrainConfig, renderer=None, model: TriangleModel | None = None,
                 normals=None, frame: WorldFrame | None = None, groups=None):
        from ..render.renderer import Renderer
        if not scene.train_indices:
            raise ValueError("scene: it has no training views")
        self.world_scene, self.frame = scene, scene.frame() if frame is None else frame
        self.scene = scene = scene.in_frame(self.frame)     # what every render, loss and edit uses
        self.config = config
        self.sched = config.schedule(views=len(scene.train_indices))
        self.renderer = renderer if renderer is not None else Renderer()
        self.ctx = c = self.renderer.ctx
        self.init_info = None      # the points mesh's InitInfo (carved / long faces), when built here
        if model is None:
            model, groups, self.init_info = initial_model(scene, config)
        else:
            model = self.frame.model_to_frame(model)
        self.train_views = list(scene.train_indices)
        self.iteration = 0
        self.elapsed = 0.0         # seconds of training, summed over sessions
        self.loss_image = ImageLoss(c, self.renderer.scratch)
        self.activate = TrainActivate(c)
        self.grads = TrainGrads(c)
        self.pack = PackVOut(c)
        self.down = DownsampleArea(c)
        self.down_t = DownsampleAreaT(c)
        self.optimizer = ParamOptimizer(c, [scene.cameras[i].center for i in self.train_views], config.position_lr_depth)
        self.reg = OpacityRegGradient(c, self.renderer.scratch)
        self._targets = {}
        #: per view (prior, valid) or None: the normal loss's priors (None: no normal loss)
        self.normal_maps = normal_priors(scene, config, normals)
        self.normal_loss = NormalLoss(self.renderer) if self.normal_maps is not None else None
        self._normal_targets = {}
        #: callables ``hook(trainer, stats)`` run after every step (the live viewer); one that
        #: returns False stops training as Ctrl-C does (checkpoint, KeyboardInterrupt)
        self.step_hooks = []
        self.last_stats = None
        cams = [scene.cameras[i] for i in self.train_views]
        check_fits(c, model.num_vertices, model.num_triangles, config.sh_degree, cams)   # before the model's buffers
        cap = vertex_cap(config, cams, c.limits)
        self.topology = TopologyStrategy(self.sched, seed=config.seed, max_vertices=cap,
                                         stop_rel=config.densify_stop_rel, stop_windows=config.densify_stop_windows,
                                         enabled=config.topology, near=config.near)
        #: the :class:`~.profile.StepProfiler` of profiled steps (created on the first one)
        self.profiler = None
        self.set_state(VertexState.from_model(model.positions, model.triangles, model.sh,
                                              logit_from_opacity(model.opacity, self.sched.opacity_floor(0)),
                                              groups=groups))

    # ------------------------------------------------------------------ device state
    def set_state(self, state: VertexState):
        """Replace the model under training (parameters, Adam moments, triangles, the
        topology's max weights) with ``state``, re-creating every device buffer (init, resume,
        topology edits)."""
        c = self.ctx
        n, m, k = state.n, state.m, state.k
        self.n, self.m, self.k = n, m, k
        self.triangles_host = np.asarray(state.triangles, np.int64)
        #: per-triangle groups (None: all ordinary; :mod:`.shell`), host only: the prunes read them
        self.groups = None if state.groups is None else np.asarray(state.groups, np.int8)
        # positions, triangles and the SH double as vertex / index buffers: the live viewer
        # (tsplus train --view) draws them as they are, no copy. The SH parameters are in the
        # renderer's [N, K, 3] layout: the renderer reads them, and their gradient is the
        # renderer's v_sh. They, their moments and v_sh may be larger than one storage binding
        # (bound a range of vertices at a time: gpu/chunks.py).
        import wgpu
        rw = wgpu.BufferUsage.STORAGE | wgpu.BufferUsage.COPY_SRC | wgpu.BufferUsage.COPY_DST
        usage = dict(positions=rw | wgpu.BufferUsage.VERTEX, sh=rw | wgpu.BufferUsage.VERTEX, logits=None)
        self.params, self.moments = {}, {}
        for key in PARAMS:
            param, m1, m2 = state.flat(key)
            big = key == "sh"
            self.params[key] = c.upload(param, key, usage=usage[key], chunked=big)
            self.moments[key] = (c.upload(m1, f"exp_avg_{key}", chunked=big),
                                 c.upload(m2, f"exp_avg_sq_{key}", chunked=big))
        self.sizes = dict(positions=3 * n, sh=3 * n * k, logits=n)
        tris = c.upload(self.triangles_host.astype(np.uint32), "triangles", usage=rw | wgpu.BufferUsage.INDEX)
        render = dict(positions=self.params["positions"], triangles=tris, sh=self.params["sh"],
                      opacity=c.buffer(4 * n, "render_opacity"))
        self.model = DeviceModel(c, render, n, m, k)
        self.gbuf = dict(v_positions=c.buffer(12 * n, "v_positions"), v_sh=c.buffer(12 * n * k, "v_sh", chunked=True),
                         v_opacity=c.buffer(4 * n, "v_opacity"))
        self.pgrad = dict(positions=self.gbuf["v_positions"], sh=self.gbuf["v_sh"], logits=c.buffer(4 * n, "v_logits"))
        self.reg_out = c.buffer(16 * n, "opacity_reg_vertex")
        self.model.corner_order = corner_order(c, self.triangles_host)   # the backward's gather: no sort per step
        self.model.corner_spans = corner_spans(c, self.triangles_host, n)   # ... and one invocation per vertex
        if self.normal_loss is not None:
            self.normal_loss.set_topology(self.triangles_host, n)
        self.topology.attach(c, m, state.max_weight)
        self._activate(self.sched.opacity_floor(self.iteration))

    def _activate(self, floor, floor_old=None):
        enc = self.ctx.device.create_command_encoder()
        self.activate(enc, self.params["logits"], self.model.buffers["opacity"], self.n, floor, floor_old)
        self.ctx.queue.submit([enc.finish()])

    def _target(self, view):
        buf = self._targets.get(view)
        if buf is None:
            img = np.ascontiguousarray(self.scene.images[view], np.float32)
            buf = self._targets[view] = self.ctx.upload(img, f"target_{view}")
        return buf

    def normal_weight(self, it, view):
        """The normal loss's weight at iteration ``it`` for ``view`` (0: not applied)."""
        if self.normal_maps is None or self.normal_maps[view] is None:
            return 0.0
        return self.sched.normal_loss_weight(it)

    def _normal_step(self, it, view, camera):
        """The normal loss of this step (:class:`.normals.NormalLoss`): its gradient added into
        ``gbuf`` (after the photometric backward, before train_grads / Adam). Returns the
        normal render's forward result, or None when the loss does not apply."""
        w = self.normal_weight(it, view)
        if w <= 0:
            return None
        tgt = self._normal_targets.get(view)
        if tgt is None:
            tgt = self._normal_targets[view] = self.normal_loss.target(*self.normal_maps[view],
                                                                      label=f"normal_target_{view}")[0]
        return self.normal_loss.run(camera, self.sched.sigma(it), self.config.near, self.params["positions"],
                                    self.model.buffers["triangles"], self.model.buffers["opacity"], tgt,
                                    self.gbuf["v_positions"], self.gbuf["v_opacity"], w)

    def fit_supersample(self, camera, s):
        """The largest of s, s/2, ..., 1 whose sub-pixel image (and the backward's vec4 input,
        16 bytes per sub-pixel) fits the device's storage-binding and buffer limits."""
        lim = self.ctx.limits
        cap = min(int(lim["max-storage-buffer-binding-size"]), int(lim["max-buffer-size"]))
        s = max(1, int(s))
        while s > 1 and 16 * camera.width * camera.height * s * s > cap:
            s //= 2
        return s

    def render_supersampled(self, model, camera, sigma, s, enc=None, profiler=None, reuse=False):
        """Forward with the s-times camera and, for s > 1, area-downsample on the device.
        Returns ``(forward result, image buffer [H * W * 3] at the camera's resolution)``.
        ``profiler``: a :class:`~.profile.StepProfiler` that gets the forward's stage times.
        ``reuse``: the forward's (and then the backward's) buffers are the renderer's scratch,
        overwritten by the next such call (:meth:`step`)."""
        s = self.fit_supersample(camera, s)
        res = self.renderer.forward(model, supersampled_camera(camera, s), sigma, self.config.background,
                                    self.config.near, profile=profiler is not None, reuse=reuse)
        if profiler is not None:
            profiler.add_kernels(res.timings)
        if s == 1:
            return res, res.buffers["image"], 1
        h, w = camera.height, camera.width
        out = self.renderer.scratch.get("train_image_down", 12 * h * w)
        own = enc is None
        enc = self.ctx.device.create_command_encoder() if own else enc
        self.down(enc, res.buffers["image"], out, w, h, s, profiler=profiler.profiler("loss") if profiler else None)
        if own:
            self.ctx.queue.submit([enc.finish()])
        return res, out, s

    def view_of(self, it):
        """Training view (index into the scene) of 1-based iteration ``it``."""
        v = len(self.train_views)
        epoch, pos = divmod(int(it) - 1, v)
        perm = np.random.default_rng([int(self.config.seed), epoch]).permutation(v)
        return self.train_views[int(perm[pos])]

    # ------------------------------------------------------------------ one step
    def step(self, read_stats=False, profile=False):
        """One optimisation step (iteration ``self.iteration + 1``). With ``read_stats`` the
        loss and the training-view PSNR are read back (a host round trip) and returned. With
        ``profile`` the step's per-stage times (ms; :mod:`.profile`) go to ``self.step_times``
        (timestamp queries where supported, else per-stage submits timed on the host)."""
        c, s = self.ctx, self.sched
        it = self.iteration + 1
        sp = self._step_profiler() if profile else None
        lp, op, tp = (sp.profiler("loss"), sp.profiler("optimizer"), sp.profiler("topology")) if sp else (None,) * 3
        self.topology.pre_step(self, it)
        floor = s.opacity_floor(it)
        if s.opacity_floor_changes(it):
            self._activate(floor, s.opacity_floor(it - 1))
        view = self.view_of(it)
        cam = self.scene.cameras[view]
        h, w = cam.height, cam.width
        enc = c.device.create_command_encoder()
        res, image, ss = self.render_supersampled(self.model, cam, s.sigma(it), s.supersample(it), enc, sp,
                                                  reuse=c.host_caching)
        scr = self.renderer.scratch
        v_img = scr.get("train_v_image", 12 * h * w)
        v_out = scr.get("train_v_out", 16 * h * w * ss * ss)
        loss_buf = scr.get("train_loss", 16)
        self.loss_image.record(enc, image, self._target(view), v_img, loss_buf, w, h, profiler=lp)
        if ss == 1:
            self.pack(enc, v_img, v_out, h * w, profiler=lp)
        else:
            self.down_t(enc, v_img, v_out, w, h, ss, profiler=lp)
        c.queue.submit([enc.finish()])
        if sp is None:
            self.renderer.backward(res, v_out, read=False, out=self.gbuf)
        else:
            from ..render.backward import backward
            sp.mark("loss")
            sp.add_kernels(backward(self.renderer, res, v_out, profile=True, read=False, out=self.gbuf))
        nres = self._normal_step(it, view, cam)      # adds its gradient into gbuf (normal loss, optional)
        enc = c.device.create_command_encoder()
        reg_w = s.opacity_reg_weight(it) if self.config.opacity_reg else 0.0
        if reg_w > 0:
            self.reg.record(enc, self.model.buffers["triangles"], self.model.buffers["opacity"], self.reg_out, reg_w,
                            self.n, self.m, profiler=op)
        active_k = min(self.k, (s.sh_degree(it) + 1) ** 2)
        self.grads(enc, self.params["logits"], self.gbuf["v_sh"], self.gbuf["v_opacity"], self.reg_out,
                   self.pgrad["logits"], self.n, self.k, active_k, floor, reg_w > 0, profiler=op)
        self.optimizer.record(enc, self, it, op)
        self.activate(enc, self.params["logits"], self.model.buffers["opacity"], self.n, floor, profiler=op)
        if sp is not None:        # the topology's per-step work in a submit of its own
            c.queue.submit([enc.finish()])
            sp.mark("optimizer")
            enc = c.device.create_command_encoder()
        edit = self.topology.post_step(self, it, res, view, loss_buf, enc, profiler=tp)
        c.queue.submit([enc.finish()])
        if sp is not None:
            sp.mark("topology")
        self.iteration = it
        stats = None
        if read_stats:
            loss = c.read(loss_buf, np.float32, 4)
            img = c.read(image, np.float32, 3 * h * w).reshape(h, w, 3)
            stats = dict(loss=float(loss[0]), l1=float(loss[1]), ssim=float(loss[2]),
                         psnr=psnr(img, self.scene.images[view]), view=int(view), supersample=int(ss))
            if nres is not None:   # mean(1 - <N, P>) over the view's usable pixels, before the weight
                stats["normal_loss"] = loss_from_render(nres.image, nres.transmittance, *self.normal_maps[view])
                stats["normal_weight"] = self.normal_weight(it, view)
        if edit:
            t_edit = time.perf_counter()
            self.apply_topology(it)
            if sp is not None:
                sp.host("topology", time.perf_counter() - t_edit)
        if sp is not None:
            self.step_times = sp.finish()
        return stats

    def _step_profiler(self):
        if self.profiler is None:
            from .profile import StepProfiler
            self.profiler = StepProfiler(self.ctx)
        self.profiler.begin()
        return self.profiler

    @property
    def profile_method(self):
        """How profiled steps are timed: ``"timestamp queries"`` or host timing."""
        from .profile import StepProfiler
        return self.profiler.method if self.profiler is not None else StepProfiler.describe(
            bool(self.ctx.features.timestamps))

    # ------------------------------------------------------------------ topology
    def is_topology_step(self, it):
        """Whether iteration ``it`` prunes or densifies."""
        return self.topology.is_edit_step(it)

    def read_state(self) -> VertexState:
        """The model under training as a host :class:`~.state.VertexState` (a readback) in the
        device's layout, not through the checkpoint's planar SH (2.3 s of 3.1 at 1M SH-3 vertices)."""
        shapes = dict(positions=(self.n, 3), sh=(self.n, self.k, 3), logits=(self.n,))
        arrays = {f"{pre}{key}": self.ctx.read(buf, np.float32, int(np.prod(shape))).reshape(shape)
                  for key, shape in shapes.items()
                  for pre, buf in zip(("", "exp_avg_", "exp_avg_sq_"), (self.params[key], *self.moments[key]))}
        return VertexState(triangles=self.triangles_host.astype(np.int64), max_weight=self.topology.max_weight(),
                           groups=self.groups, **arrays)

    def apply_topology(self, it):
        """The topology edit of iteration ``it`` (prune / densify, :class:`~.strategy.TopologyStrategy`):
        reads the state, lets the strategy map it to a new one and installs that. Returns the
        new state."""
        cams = [self.scene.cameras[i] for i in self.train_views]
        state = self.topology.edit(self.read_state(), it, self.train_views, cams)
        self.set_state(state)
        return state

    # ------------------------------------------------------------------ loop
    def train(self, out_dir=None, progress=True, until=None, log_every=None, callbacks=(), checkpoint_at_end=True):
        """Run to ``until`` (default: the configured iterations; calling again continues from
        where it stopped). Logs to ``out_dir/log.jsonl`` every ``log_every`` iterations
        (default: the config's); checkpoints every ``checkpoint_every`` iterations and at the
        end (unless ``checkpoint_at_end`` is False: ``tsplus train`` writes the mesh first);
        Ctrl-C (SIGINT), SIGTERM and SIGHUP finish the current step, write a checkpoint and raise
        :class:`~.loop.Interrupted` (a KeyboardInterrupt). ``callbacks``:
        :class:`~.callbacks.TrainCallback` objects asked before and told after every step.
        Returns ``self``."""
        return TrainLoop(self, out_dir, progress, until, log_every, callbacks, checkpoint_at_end).run()

    # ------------------------------------------------------------------ checkpoints
    def state_arrays(self):
        """Host copies of everything a bit-identical resume needs (device layout, frame units)."""
        c = self.ctx
        arrays = dict(
            positions=c.read(self.params["positions"], np.float32, 3 * self.n).reshape(self.n, 3),
            sh_planar=np.ascontiguousarray(   # the checkpoint's layout: planar [K, N, 3]
                c.read(self.params["sh"], np.float32, 3 * self.n * self.k).reshape(self.n, self.k, 3).transpose(1, 0, 2)),
            logits=c.read(self.params["logits"], np.float32, self.n),
            triangles=self.triangles_host.astype(np.int64),
        )
        for key, size in self.sizes.items():
            for mom, buf in zip(("exp_avg", "exp_avg_sq"), self.moments[key]):
                a = c.read(buf, np.float32, size)
                if key == "sh":   # planar in the checkpoint, as the SH
                    a = a.reshape(self.n, self.k, 3).transpose(1, 0, 2).ravel()
                arrays[f"{mom}_{key}"] = a
        return arrays

    def topology_arrays(self):
        """The topology's state (running max weight, L1 ring, triangle groups), for checkpoints."""
        out = dict(max_weight_acc=self.topology.max_weight(), l1_ring=self.topology.ring_values())
        if self.groups is not None:
            out["triangle_groups"] = self.groups
        return out

    def save_checkpoint(self, path):
        """Atomic (temp file + os.replace) checkpoint (:func:`~.checkpoint.write_checkpoint`)."""
        write_checkpoint(path, self)

    @classmethod
    def resume(cls, path, scene, config: TrainConfig | None = None, renderer=None, normals=None, loaded=None):
        """A trainer continuing from a checkpoint. ``config`` (optional) must agree with the
        checkpoint's on :attr:`TrainConfig.RESUME_KEYS`; other fields (logging) come from it.
        ``normals``: the normal priors when they were given to the trainer directly (else they
        are read again from the config's ``normals`` folder). ``loaded``: the checkpoint's
        ``(arrays, meta)`` when already read (:func:`~.checkpoint.read_checkpoint`). The run
        continues in the checkpoint's own frame (world positions map back exactly: :mod:`.checkpoint`)."""
        arrays, meta = read_checkpoint(path) if loaded is None else loaded
        config = resume_config(meta, config)
        frame = WorldFrame.from_json(meta["frame"])
        sh = arrays["sh_planar"].transpose(1, 0, 2)
        init = TriangleModel(arrays["positions"], arrays["triangles"], sh,
                             np.full(arrays["positions"].shape[0], 0.5))
        t = cls(scene, config, renderer=renderer, model=init, normals=normals, frame=frame)
        t.iteration = int(meta["iteration"])
        t.elapsed = float(meta.get("elapsed", 0.0))
        flat = dict(arrays, positions=arrays.get("positions_frame",         # exact at any offset (checkpoint.py)
                                                 frame.to_frame(arrays["positions"]).astype(np.float32)))
        t.set_state(VertexState.from_flat(flat, arrays.get("max_weight_acc"), arrays.get("triangle_groups")))
        ring = arrays.get("l1_ring")
        if ring is not None and ring.shape != (t.topology.ring_size,):
            raise CheckpointError(f"--resume: {path}: array 'l1_ring' has shape {ring.shape}, expected "
                                  f"({t.topology.ring_size},); the checkpoint is corrupt")
        t.topology.load_state(meta.get("topology", {}), ring)
        return t

    # ------------------------------------------------------------------ results
    def current_model(self) -> TriangleModel:
        """The model as trained (activated opacity, full SH), read back, in world units."""
        return self.frame.model_to_world(self.model.to_model())

    def render(self, model, camera, sigma=None, supersample=1):
        """``model`` seen by ``camera`` at ``sigma`` (default: the current one), rendered at
        ``supersample`` x resolution (reduced to fit the device) and area-downsampled on the
        device. Both in frame units (``self.model``, ``self.scene.cameras``). Returns ``[H, W, 3]`` float32."""
        sigma = self.sched.sigma(self.iteration) if sigma is None else sigma
        res, image, s = self.render_supersampled(model, camera, sigma, supersample)
        if s == 1:
            return res.image
        return self.ctx.read(image, np.float32, 3 * camera.height * camera.width).reshape(camera.height,
                                                                                          camera.width, 3)

    def positions_frame(self) -> np.ndarray:
        """``[N, 3]`` float32: the vertex positions as trained, in the trainer's frame (read back)."""
        return self.ctx.read(self.params["positions"], np.float32, 3 * self.n).reshape(self.n, 3)

    @property
    def mesh_renderer(self):
        """A :class:`~tsplus_wgpu.MeshRenderer` on the trainer's device, made on first use."""
        if getattr(self, "_mesh_renderer", None) is None:
            from ..render.mesh_renderer import MeshRenderer
            self._mesh_renderer = MeshRenderer(self.ctx)
        return self._mesh_renderer

    def final_mesh(self, progress=None):
        """The exported mesh: ``(positions [V, 3] in world units, triangles [F, 3], colors [V, 3]
        in [0, 1])`` after the end-of-training cleanup, colours fitted to the training photos or
        from SH DC (:func:`.final.final_mesh`; ``progress``: a tqdm-like bar of the views drawn)."""
        return final_mesh(self, progress)

    @staticmethod
    def mesh_model(positions, triangles, colors):
        """The exported mesh as an opaque, vertex-coloured model for evaluation."""
        sh = ((np.asarray(colors, np.float64) - 0.5) / SH_C0)[:, None, :]
        return TriangleModel(positions, triangles, sh, np.ones(len(positions)))

    def evaluate(self, model=None, sigma=None, views=None, supersample=SUPERSAMPLE_EVAL):
        """Mean PSNR / SSIM over ``views`` (default: the held-out ones, else the training ones)
        of ``model`` (default: the trained model at the current sigma), rendered at
        ``supersample`` x resolution (method.md's evaluation: 4; less where the image would not
        fit the device) and area-downsampled. ``model``: a :class:`TriangleModel` in world units, or a
        :class:`DeviceModel` in the trainer's frame (``self.model``). Returns (psnr, ssim, images)."""
        views = list(self.scene.test_indices or self.train_views) if views is None else list(views)
        model = self.model if model is None else model
        if isinstance(model, TriangleModel):    # uploaded once for every view
            model = DeviceModel.from_model(self.renderer, self.frame.model_to_frame(model))
        ps, ss, imgs = [], [], []
        for v in views:
            img = self.render(model, self.scene.cameras[v], sigma, supersample)
            ps.append(psnr(img, self.scene.images[v]))
            ss.append(ssim(img, self.scene.images[v]))
            imgs.append(img)
        return float(np.mean(ps)), float(np.mean(ss)), imgs
