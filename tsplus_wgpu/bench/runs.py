"""``tsplus bench``: speed against error in one report (issue 8).

For every scene (default: the procedural scene and each scene folder in ``TSPLUS_DATA``) it
trains on the device and writes ``report.md``, ``report.json`` and PNG plots to ``--out``:

* **curves**: held-out PSNR / SSIM of the exported opaque mesh (drawn by the depth-tested
  :class:`~tsplus_wgpu.MeshRenderer`, 4x4 supersampled) and of the soft model as trained, against
  training wall time and iteration, for the quick preset with topology off (``--preset quick
  --topology off``: the trainer's advice for runs of a few hundred iterations; the preset's default is
  on) and a run ``--long-factor`` times longer (the same settings scaled to more iterations);
* **per-stage time per iteration** (:mod:`.train.profile`: projection, binning, sort, forward,
  loss, backward, gather, optimizer, topology) of the method's run (topology on), median and
  min-max over 1 in ``--profile-every`` iterations plus every topology step;
* the device's **peak FMA rate** (:func:`.measure.measure_peak_flops`) measured right before the
  **forward and backward blend kernels** run on the trained model, and their fraction of it;
* **vertices vs PSNR**: the densification plateau stop (``densify_stop_rel`` 0.01), no stop, and
  ``--max-vertices`` budgets (the initial vertex count plus a fraction of the growth the no-stop run
  reached: 0 = no densification; plateau stop off);
* the paper's **ablations** (Tables 2-3, :mod:`.train.ablations`) measured here: change against this
  run's baseline next to the paper's change;
* the **Poisson baseline** (:func:`.apps.evaluate.poisson_baseline`) on the same views.

Every run trains through :meth:`Trainer.train` (the training loop itself) with a
:class:`RunMonitor` callback that chooses the profiled steps and records what the report needs.
Every run is cached in ``OUT/cache`` under a key of its settings and adapter, so an interrupted
bench continues where it stopped (``fresh`` ignores the cache). Reports are rewritten atomically
after every scene; a scene that does not load is one line in the report.
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
import sys
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from ..io.atomic import write_text
from ..kernels.blend import kernel_layout
from ..train.callbacks import TrainCallback
from .measure import git_commit, measure_blend, peak_record, stats, timing_name
from .plans import curve_iterations, eval_views
from .report import (REPORT_VERSION, ablation_table, budget_table, headline_markdown, json_safe, one_line,
                     summarize_stages, write_report)

# the Poisson baseline's method, in its cache key: 2 = screened (point weight 0.1), normals oriented to
# the cameras that see each point, lowest-density 5 % of vertices trimmed (1: distance trim, nearest camera)
POISSON_VERSION = 2


class RunMonitor(TrainCallback):
    """A training callback for one bench run: profiles 1 in ``profile_every`` steps and every
    topology step (0: none), keeps the profiled steps' stage times and host seconds, the peak
    vertex count and the number of topology edits, and advances the progress ``bars``."""

    def __init__(self, profile_every=0, vertices=0, bars=()):
        self.profile_every = int(profile_every)
        self.rows = []               # per profiled step: iteration, topology_step, stage ms
        self.profiled_seconds = 0.0  # host time of the profiled steps
        self.peak_vertices = int(vertices)
        self.topology_edits = 0
        self.bars = [b for b in bars if b is not None]
        self._started = None
        self._topology_step = False

    def wants_profile(self, trainer, it):
        if self.profile_every <= 0:
            return False
        topo = bool(trainer.is_topology_step(it))
        if not (it % self.profile_every == 0 or topo):
            return False
        self._topology_step = topo
        self._started = time.perf_counter()
        return True

    def after_step(self, trainer, it, info):
        if info["profiled"] and self._started is not None:
            self.profiled_seconds += time.perf_counter() - self._started
            self.rows.append(dict(iteration=it, topology_step=self._topology_step, **info["step_times"]))
        self._started = None
        self.peak_vertices = max(self.peak_vertices, int(info["vertices"]))
        self.topology_edits += bool(info["topology"])
        for bar in self.bars:
            bar.update(1)


class Bench:
    """Runs and caches the measurements of one ``tsplus bench`` invocation."""

    def __init__(self, out, renderer, mesh_renderer, progress=True, fresh=False, log=print):
        self.out = Path(out)
        self.renderer = renderer
        self.ctx = renderer.ctx
        self.mr = mesh_renderer
        self.progress = progress
        self.fresh = fresh
        self.log = log
        self.peaks = []          # every peak FMA sample of this invocation
        self.overall = None      # the whole bench's progress bar (training iterations, with ETA)
        self.commit = git_commit()

    # ------------------------------------------------------------------ cache
    def cached(self, scene_name, run, key_obj, fn):
        """``fn()``'s record, from ``OUT/cache/<scene>/<run>-<key>.json`` when it is there (and
        not ``fresh``), else measured and written there."""
        key = hashlib.sha1(json.dumps(json_safe(dict(key_obj, adapter=self.ctx.name, v=REPORT_VERSION)),
                                      sort_keys=True).encode()).hexdigest()[:12]
        path = self.out / "cache" / scene_name / f"{run}-{key}.json"
        if path.is_file() and not self.fresh:
            try:
                rec = json.loads(path.read_text())
                rec["cached"] = True
                self.log(f"  {run}: from the cache ({path.name})")
                return rec
            except Exception:
                pass
        rec = fn()
        rec = json_safe(dict(rec, commit=self.commit, finished=time.strftime("%Y-%m-%d %H:%M:%S"),
                             loadavg=list(os.getloadavg())))
        path.parent.mkdir(parents=True, exist_ok=True)
        write_text(path, json.dumps(rec, indent=1) + "\n")
        rec["cached"] = False
        return rec

    # ------------------------------------------------------------------ measurements
    def peak(self, repeats):
        """A peak FMA sample, kept in :attr:`peaks`."""
        rec = peak_record(self.ctx, repeats)
        self.peaks.append(rec)
        return rec

    def evaluate_point(self, t, scene, views):
        """Held-out PSNR/SSIM of the exported opaque mesh (mesh renderer, 4x4) and of the soft
        model as trained (trainer renderer at the current sigma, 4x)."""
        from ..apps.evaluate import evaluate_mesh, mean_coverage
        from ..io.metrics import psnr, ssim
        from ..train.trainer import Trainer
        t0 = time.perf_counter()
        soft_psnr, soft_ssim, _ = t.evaluate(views=views)
        pos, tri, col = t.final_mesh()
        bg = tuple(float(x) for x in t.config.background)
        if len(tri):
            rows = evaluate_mesh(Trainer.mesh_model(pos, tri, col), scene, views, self.mr, supersample=4,
                                 background=bg)
            mp, ms = float(np.mean([r["psnr"] for r in rows])), float(np.mean([r["ssim"] for r in rows]))
            cov = mean_coverage(rows)
        else:       # nothing survived the final cleanup: the background alone
            imgs = [np.broadcast_to(np.asarray(bg, np.float32), scene.images[v].shape) for v in views]
            mp = float(np.mean([psnr(i, scene.images[v]) for i, v in zip(imgs, views)]))
            ms = float(np.mean([ssim(np.ascontiguousarray(i), scene.images[v]) for i, v in zip(imgs, views)]))
            cov = 0.0
        return dict(iteration=t.iteration, sigma=t.sched.sigma(t.iteration), model_vertices=t.n, model_triangles=t.m,
                    mesh_vertices=int(len(pos)), mesh_triangles=int(len(tri)), mesh_psnr=mp, mesh_ssim=ms,
                    mesh_coverage=cov, soft_psnr=soft_psnr, soft_ssim=soft_ssim, eval_seconds=time.perf_counter() - t0)

    def _run_bar(self, plan, label, iterations):
        if not self.progress:
            return None
        from tqdm import tqdm
        return tqdm(total=int(iterations), desc=f"{plan.name} {label}", unit="it", dynamic_ncols=True,
                    leave=False, file=sys.stderr, position=1 if self.overall is not None else 0)

    def _train_and_evaluate(self, t, scene, views, eval_at, mon, bar):
        """Train ``t`` to each iteration of ``eval_at`` in turn (through :meth:`Trainer.train`),
        evaluating at each; returns the points, the training seconds and the it/s of each
        segment's unprofiled steps."""
        points, segments = [], []
        train_s = 0.0
        for target in eval_at:
            if target > t.iteration:
                t.ctx.wait()
                t0, it0, p0, n0 = time.perf_counter(), t.iteration, mon.profiled_seconds, len(mon.rows)
                t.train(progress=False, until=target, log_every=0, callbacks=(mon,))
                t.ctx.wait()
                dt = time.perf_counter() - t0
                train_s += dt
                n_plain = (t.iteration - it0) - (len(mon.rows) - n0)
                if n_plain > 0:
                    segments.append(n_plain / max(dt - (mon.profiled_seconds - p0), 1e-9))
            pt = self.evaluate_point(t, scene, views)
            pt["train_seconds"] = train_s
            points.append(pt)
            if bar is not None:
                bar.set_postfix(mesh_psnr=f"{pt['mesh_psnr']:.2f}", tris=t.m)
        return points, train_s, segments

    def train_run(self, scene, plan, label, iterations, cfg_kwargs, eval_at=None, profile_every=0, blend=False):
        """One training run (quick preset scaled to ``iterations``) with evaluations at ``eval_at``
        (default: the end) and optional per-stage profiling / blend measurement."""
        from ..train.trainer import TrainConfig, Trainer
        views = eval_views(scene, plan.test_views)
        cfg = TrainConfig(iterations=int(iterations), quick=True, seed=0,
                          background=tuple(float(x) for x in scene.background), log_every=0, **cfg_kwargs)
        t_run = time.perf_counter()
        t = Trainer(scene, cfg, renderer=self.renderer)
        init = dict(vertices=t.n, triangles=t.m)
        eval_at = sorted(set(eval_at or []) | {int(iterations)})
        bar = self._run_bar(plan, label, iterations)
        mon = RunMonitor(profile_every, t.n, bars=(bar, self.overall))
        try:
            points, train_s, segments = self._train_and_evaluate(t, scene, views, eval_at, mon, bar)
        finally:
            if bar is not None:
                bar.close()
        prof_n, prof_s = len(mon.rows), mon.profiled_seconds
        plain_n = int(iterations) - prof_n
        rec = dict(label=label, run_seconds=time.perf_counter() - t_run, iterations=int(iterations),
                   config={k: v for k, v in asdict(cfg).items() if k != "extra"},
                   initial=init, points=points, final=points[-1], train_seconds=train_s,
                   its_per_s=plain_n / max(train_s - prof_s, 1e-9) if plain_n > 0 else int(iterations) / max(train_s, 1e-9),
                   its_per_s_segments=stats(segments), profiled_iterations=prof_n, peak_vertices=mon.peak_vertices,
                   densify_stopped=t.topology.densify_stopped, topology_events=mon.topology_edits,
                   eval_views=len(views))
        if mon.rows:
            rec["stages"] = summarize_stages(mon.rows, int(iterations), t.profile_method)
        if blend:
            rec["blend"] = measure_blend(self.renderer, t, plan.blend_repeats,
                                         lambda: self.peak(plan.peak_repeats))
            rec["run_seconds"] = time.perf_counter() - t_run
        return rec

    # ------------------------------------------------------------------ one scene
    def _load(self, plan, rec):
        """The plan's scene, its facts added to ``rec`` (None, with ``rec['status']``, when it does not load)."""
        from ..data import load_scene_arg
        from ..data.loader import load_scene
        t0 = time.perf_counter()
        try:   # a scene folder starts from the points `tsplus train` starts from (--points auto)
            scene = (load_scene_arg(plan.scene, plan.downscale) if str(plan.scene).startswith("procedural")
                     else load_scene(plan.scene, downscale=plan.downscale, points="most"))
            if not scene.train_indices:
                raise ValueError("no training views")
            if scene.points is None or len(scene.points) < 3:
                raise ValueError("no initial points")
        except Exception as exc:
            rec["status"] = f"error: scene did not load ({one_line(exc)})"
            self.log(f"{plan.name}: {rec['status']}")
            return None
        cam = scene.cameras[scene.train_indices[0]]
        views = eval_views(scene, plan.test_views)
        rec.update(status="ok", resolution=[cam.width, cam.height], train_views=len(scene.train_indices),
                   test_views=len(scene.test_indices), eval_views=len(views),
                   eval_note=("held-out views" if scene.test_indices else "training views (the scene has no held-out "
                                                                          "split)")
                   + (f", {len(views)} of {len(scene.test_indices)} evenly spaced" if scene.test_indices and
                      len(views) < len(scene.test_indices) else ""),
                   points=int(len(scene.points)), load_seconds=time.perf_counter() - t0)
        self.log(f"{plan.name}: {plan.scene} at {cam.width}x{cam.height} ({len(scene.train_indices)} training / "
                 f"{len(views)} evaluation views), {plan.iterations} iterations per run")
        return scene

    def _run(self, runs, plan, name, fn, key):
        """``runs[name]``: the cached or measured record of ``fn`` (an error record when it fails)."""
        base_key = dict(scene=plan.scene, downscale=plan.downscale, test_views=plan.test_views)
        try:
            runs[name] = self.cached(plan.name, name, dict(base_key, run=name, **key), fn)
            if runs[name].get("cached") and self.overall is not None:   # nothing left to do: out of the ETA
                self.overall.total = max(self.overall.n, self.overall.total - int(runs[name].get("iterations", 0)))
                self.overall.refresh()
        except KeyboardInterrupt:
            raise
        except Exception as exc:
            runs[name] = dict(error=one_line(exc))
            self.log(f"  {name}: failed ({runs[name]['error']})")
            return None
        r = runs[name]
        f = r["final"]
        self.log(f"  {name}: {r['iterations']} it in {r['train_seconds']:.1f}s ({r['its_per_s']:.2f} it/s); mesh "
                 f"{f['mesh_psnr']:.2f} dB / {f['mesh_ssim']:.3f}, soft {f['soft_psnr']:.2f} dB, "
                 f"{f['mesh_vertices']} vertices")
        return r

    def _curves(self, scene, plan, runs):
        """The quick preset with topology off (blend measured on it) and the longer run."""
        n, pts = int(plan.iterations), plan.eval_points
        self._run(runs, plan, "quick", lambda: self.train_run(scene, plan, "quick", n, dict(topology=False),
                                                              curve_iterations(n, pts), blend=True),
                  dict(iterations=n, topology=False, points=pts, blend=(plan.blend_repeats, plan.peak_repeats)))
        if plan.long and plan.long_factor > 1:
            nl = n * int(plan.long_factor)
            self._run(runs, plan, "long", lambda: self.train_run(scene, plan, "long", nl, dict(topology=False),
                                                                 curve_iterations(nl, pts)),
                      dict(iterations=nl, topology=False, points=pts))

    def _method_runs(self, scene, plan, runs):
        """The method with topology: the ablations (the baseline profiled per stage), then vertices
        vs PSNR: no stop and budgets V0 + f (peak - V0), plateau stop off. Densification starts
        long before the first prune, so a cap below V0 would only stop it; f = 0 is "none"."""
        from ..train.ablations import ABLATIONS
        n = int(plan.iterations)
        topo = dict(topology=True, quick_topology_epochs=float(plan.topology_epochs))
        for name in plan.ablations:
            over = ABLATIONS[name][2]
            prof = plan.profile_every if name == "baseline" else 0
            self._run(runs, plan, f"ablation-{name}", lambda over=over, name=name, prof=prof: self.train_run(
                scene, plan, f"ablation {name}", n, dict(topo, **over), profile_every=prof),
                dict(iterations=n, cfg=dict(topo, **over), profile=prof))
        if not plan.budget_runs:
            return
        cfg = dict(topo, densify_stop_rel=0.0)
        nostop = self._run(runs, plan, "densify-no-stop", lambda: self.train_run(scene, plan, "no stop", n, cfg),
                           dict(iterations=n, cfg=cfg))
        if nostop is None:
            return
        v0 = int(nostop["initial"]["vertices"])
        for f in plan.budgets:
            cap = max(3, int(round(v0 + f * max(0, nostop["peak_vertices"] - v0))))
            self._run(runs, plan, f"budget-{f:g}", lambda cap=cap: self.train_run(
                scene, plan, f"budget {cap}", n, dict(cfg, max_vertices=cap)),
                dict(iterations=n, cfg=dict(cfg, max_vertices=cap)))

    def _poisson(self, scene, plan, views, rec):
        """The classical baseline, cached like a run."""
        base_key = dict(scene=plan.scene, downscale=plan.downscale, test_views=plan.test_views)
        try:
            rec["poisson"] = self.cached(plan.name, "poisson", dict(base_key, run="poisson", depth=plan.poisson_depth,
                                                                        baseline=POISSON_VERSION),
                                         lambda: self.poisson(scene, views, plan.poisson_depth))
            p = rec["poisson"]
            self.log(f"  poisson: {p['psnr']:.2f} dB / {p['ssim']:.3f}, coverage {p.get('coverage', 0):.1%}, "
                     f"{p['vertices']} vertices")
        except KeyboardInterrupt:
            raise
        except Exception as exc:
            rec["poisson"] = dict(error=one_line(exc))

    def scene(self, plan):
        """Every measurement of one scene; a scene that does not load is a one-line record."""
        from ..train.ablations import ABLATIONS, PAPER_BASELINE
        rec = dict(name=plan.name, scene=plan.scene, downscale=plan.downscale, plan=asdict(plan),
                   loadavg_start=list(os.getloadavg()), started=time.strftime("%Y-%m-%d %H:%M:%S"))
        t0 = time.perf_counter()
        scene = self._load(plan, rec)
        if scene is None:
            return rec
        runs = rec["runs"] = {}
        self._curves(scene, plan, runs)
        self._method_runs(scene, plan, runs)
        if plan.poisson:
            self._poisson(scene, plan, eval_views(scene, plan.test_views), rec)
        rec["ablations"] = ablation_table(runs, plan.ablations, ABLATIONS, PAPER_BASELINE)
        rec["budgets"] = budget_table(runs)
        rec["seconds"] = time.perf_counter() - t0
        # what the runs took when they were measured (cached runs included), evaluations included
        rec["measured_seconds"] = sum(float(r.get("run_seconds") or 0.0) for r in runs.values()) + \
            float((rec.get("poisson") or {}).get("seconds") or 0.0)
        rec["loadavg_end"] = list(os.getloadavg())
        return rec

    def poisson(self, scene, views, depth):
        """The Poisson reconstruction of the scene's points, evaluated like the exported mesh."""
        from ..apps.evaluate import evaluate_mesh, mean_coverage, poisson_baseline
        t0 = time.perf_counter()
        model = poisson_baseline(scene, depth=depth)
        rows = evaluate_mesh(model, scene, views, self.mr, supersample=4,
                             background=tuple(float(x) for x in scene.background))
        return dict(depth=depth, psnr=float(np.mean([r["psnr"] for r in rows])),
                    ssim=float(np.mean([r["ssim"] for r in rows])), coverage=mean_coverage(rows),
                    vertices=model.num_vertices,
                    triangles=model.num_triangles, seconds=time.perf_counter() - t0, points=int(len(scene.points)))


# ---------------------------------------------------------------------------------------- invocation

def _start(out, adapter, progress, fresh, command, smoke, plans):
    """The renderers, the :class:`Bench` and the report's metadata of one invocation."""
    from ..gpu.context import GpuContext
    from ..render.mesh_renderer import MeshRenderer
    from ..render.renderer import Renderer
    renderer = Renderer(adapter)
    ctx = renderer.ctx
    # the mesh renderer gets a device of its own: on lavapipe (Mesa 22.3) a render pass on a device
    # leaves that device's later compute-pass timestamps near zero, which would void the stage times
    mr = MeshRenderer(GpuContext(adapter))
    bench = Bench(out, renderer, mr, progress=progress, fresh=fresh)
    meta = dict(adapter=ctx.name, is_cpu=bool(ctx.is_cpu), commit=git_commit(), date=time.strftime("%Y-%m-%d %H:%M:%S"),
                host=platform.node(), cpus=os.cpu_count(), python=platform.python_version(), command=command,
                timing=timing_name(ctx), layout=kernel_layout(ctx), loadavg_start=list(os.getloadavg()), smoke=bool(smoke),
                _peaks=bench.peaks)
    print(f"adapter: {ctx.name}; commit {meta['commit']}; scenes: {', '.join(p.name for p in plans)}", flush=True)
    return bench, meta


def run_bench(plans, out, adapter=None, progress=True, fresh=False, plots=True, command="tsplus bench", smoke=False):
    """Measure every plan (:class:`~.plans.ScenePlan`) and write the report to ``out`` after each
    scene. Returns 0, or 130 when interrupted (finished runs stay in the cache)."""
    t0 = time.perf_counter()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    bench, meta = _start(out, adapter, progress, fresh, command, smoke, plans)
    report = dict(version=REPORT_VERSION, meta=meta, scenes=[])
    bench.peak(plans[0].peak_repeats if plans else 5)
    print(f"peak FMA rate: {bench.peaks[-1]['flops_per_s'] / 1e9:.1f} GFLOP/s", flush=True)
    if progress:
        from tqdm import tqdm
        # smoothing 0: the rate over the whole bench, evaluations included, drives the ETA
        bench.overall = tqdm(total=sum(p.planned_iterations() for p in plans), desc="bench (all training runs)",
                             unit="it", dynamic_ncols=True, file=sys.stderr, position=0, smoothing=0)
        bench.log = bench.overall.write
    try:
        for plan in plans:
            report["scenes"].append(bench.scene(plan))
            meta.update(seconds=time.perf_counter() - t0, loadavg_end=list(os.getloadavg()),
                        cached_runs=sum(1 for s in report["scenes"] for r in s.get("runs", {}).values()
                                        if r.get("cached")))
            write_report(report, out, plots=plots)
    except KeyboardInterrupt:
        meta.update(seconds=time.perf_counter() - t0, loadavg_end=list(os.getloadavg()), interrupted=True)
        write_report(report, out, plots=plots)
        print(f"tsplus bench: interrupted; finished runs are cached in {out}/cache (run the same command to go on)",
              file=sys.stderr)
        return 130
    if bench.overall is not None:
        bench.overall.close()
    bench.peak(3)
    meta.update(seconds=time.perf_counter() - t0, loadavg_end=list(os.getloadavg()))
    data = write_report(report, out, plots=plots)
    print(headline_markdown(data))
    print(f"wrote {out}/report.md, report.json and plots in {meta['seconds'] / 60:.1f} min")
    return 0


__all__ = ["RunMonitor", "Bench", "run_bench"]
