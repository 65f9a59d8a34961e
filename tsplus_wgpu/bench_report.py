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
* the device's **peak FMA rate** (:func:`.bench.measure_peak_flops`) measured right before the
  **forward and backward blend kernels** run on the trained model, and their fraction of it;
* **vertices vs PSNR**: the densification plateau stop (``densify_stop_rel`` 0.01), no stop, and
  ``--max-vertices`` budgets (the initial vertex count plus a fraction of the growth the no-stop run
  reached: 0 = no densification; plateau stop off);
* the paper's **ablations** (Tables 2-3, :mod:`.train.ablations`) measured here: change against this
  run's baseline next to the paper's change;
* the **Poisson baseline** (:func:`.evaluate.poisson_baseline`) on the same views.

Every run is cached in ``OUT/cache`` under a key of its settings and adapter, so an interrupted
bench continues where it stopped (``--fresh`` ignores the cache). Reports are rewritten
atomically after every scene; a scene that does not load is one line in the report.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import platform
import statistics
import sys
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

REPORT_VERSION = 1


# ---------------------------------------------------------------------------------------- plans

@dataclass
class ScenePlan:
    """What the bench runs on one scene (``tsplus bench --help`` lists the defaults)."""

    name: str
    scene: str
    downscale: int = 1
    iterations: int = 300            # the quick run and every ablation / budget run
    long_factor: int = 3             # the longer run: iterations x long_factor
    eval_points: int = 5             # evaluations along each curve, iteration 0 included
    test_views: int = 25             # at most this many held-out views, evenly spaced
    topology_epochs: float = 1.0     # quick_topology_epochs of the runs with topology on
    budgets: tuple = (0.0, 0.25, 0.5)  # --max-vertices = V0 + f (peak - V0) of the no-stop run (V0: initial)
    profile_every: int = 10
    blend_repeats: int = 5
    peak_repeats: int = 5
    poisson_depth: int = 8
    long: bool = True
    ablations: tuple = ()            # ablation names (default: all)
    budget_runs: bool = True
    poisson: bool = True
    minutes: float = 0.0             # the stated time of this plan on lavapipe (2 cores), for --help

    def planned_iterations(self):
        """Training iterations of every run of this plan (the overall progress bar's total)."""
        n = int(self.iterations)
        total = n + n * len(self.ablations)
        if self.long and self.long_factor > 1:
            total += n * int(self.long_factor)
        if self.budget_runs:
            total += n * (1 + len(self.budgets))
        return total


def data_dir():
    """``TSPLUS_DATA``, else ``shared/data`` beside the checkout, else ``../shared/data``."""
    env = os.environ.get("TSPLUS_DATA")
    if env:
        return Path(env)
    beside = Path(__file__).resolve().parent.parent.parent / "shared" / "data"
    return beside if beside.is_dir() else Path("../shared/data")


#: per-scene defaults (scene folder name -> plan); other folders get GENERIC with downscale 4
DEFAULT_PLANS = {
    "procedural": dict(scene="procedural:small", downscale=1, iterations=300, long_factor=3, minutes=12),
    "cup": dict(downscale=8, iterations=240, long_factor=2, minutes=14),
    "chair": dict(downscale=4, iterations=300, long_factor=3, minutes=5),
    "fox": dict(downscale=12, iterations=300, long_factor=2, minutes=8),
}
GENERIC = dict(downscale=4, iterations=300, long_factor=2, minutes=0)

SMOKE_PLAN = dict(name="procedural-tiny", scene="procedural:tiny", iterations=16, long_factor=2, eval_points=3,
                  test_views=2, topology_epochs=1.0, budgets=(0.5,), profile_every=4, blend_repeats=2,
                  peak_repeats=3, poisson_depth=6, ablations=("baseline", "no-hard-prune", "no-weight-prune",
                                                                "no-sigma-decay", "soft-opaque", "hard-free",
                                                                "soft-free"), minutes=1)


def default_scenes():
    """The procedural scene, then every scene folder in :func:`data_dir` (sorted)."""
    out = ["procedural"]
    d = data_dir()
    if d.is_dir():
        out += sorted(str(p) for p in d.iterdir() if p.is_dir() and not p.name.startswith("."))
    return out


def plan_for(spec, args=None):
    """A :class:`ScenePlan` for a scene argument (``procedural[:size]``, a folder, or the name of
    a folder in ``TSPLUS_DATA``), with the command line's overrides."""
    from .train.ablations import ABLATIONS
    smoke = bool(getattr(args, "smoke", False))
    if smoke and spec in ("procedural", "procedural:tiny"):
        plan = ScenePlan(**SMOKE_PLAN)
    elif spec.startswith("procedural"):
        kw = dict(DEFAULT_PLANS["procedural"])
        if ":" in spec:
            kw["scene"] = spec
        size = kw["scene"].split(":", 1)[1]
        plan = ScenePlan(name="procedural" if size == "small" else f"procedural-{size}", **kw)
    else:
        path = Path(spec)
        if not path.exists() and (data_dir() / spec).exists():
            path = data_dir() / spec
        kw = dict(DEFAULT_PLANS.get(path.name, GENERIC))
        plan = ScenePlan(name=path.name or str(path), scene=str(path), **kw)
    if not plan.ablations:
        plan = replace(plan, ablations=tuple(ABLATIONS))
    if args is not None:
        over = {}
        for key in ("iterations", "long_factor", "eval_points", "test_views", "profile_every", "topology_epochs"):
            val = getattr(args, key, None)
            if val is not None:
                over[key] = val
        if getattr(args, "downscale", None) is not None and not plan.scene.startswith("procedural"):
            over["downscale"] = args.downscale
        if getattr(args, "budgets", None) is not None:
            over["budgets"] = tuple(args.budgets)
        if getattr(args, "no_long", False):
            over["long"] = False
        if getattr(args, "no_ablations", False):
            over["ablations"] = ("baseline",)
        if getattr(args, "no_budgets", False):
            over["budget_runs"] = False
        if getattr(args, "no_poisson", False):
            over["poisson"] = False
        plan = replace(plan, **over)
    return plan


# ---------------------------------------------------------------------------------------- helpers

def _finite(x):
    return x is not None and isinstance(x, (int, float)) and math.isfinite(float(x))


def _stats(values):
    v = [float(x) for x in values if _finite(x)]
    if not v:
        return None
    return dict(median=statistics.median(v), min=min(v), max=max(v), n=len(v))


def atomic_write_text(path, text):
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    try:
        tmp.write_text(text)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def _clean(obj):
    """JSON-safe: numpy scalars to Python, non-finite floats to None."""
    if isinstance(obj, dict):
        return {str(k): _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.floating, float)):
        f = float(obj)
        return f if math.isfinite(f) else None
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj


def _one_line(exc):
    text = f"{type(exc).__name__}: {exc}".strip().splitlines()
    return text[0][:300] if text else type(exc).__name__


def eval_views(scene, k):
    views = list(scene.test_indices) or list(scene.train_indices)
    if k and len(views) > k:
        idx = np.unique(np.round(np.linspace(0, len(views) - 1, int(k))).astype(int))
        views = [views[i] for i in idx]
    return views


def curve_iterations(total, points):
    points = max(2, int(points))
    return sorted({int(round(total * i / (points - 1))) for i in range(points)})


# ---------------------------------------------------------------------------------------- one run

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
        from .bench import git_commit
        self.commit = git_commit()

    # ------------------------------------------------------------------ cache
    def _cached(self, scene_name, run, key_obj, fn):
        key = hashlib.sha1(json.dumps(_clean(dict(key_obj, adapter=self.ctx.name, v=REPORT_VERSION)),
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
        rec = _clean(dict(rec, commit=self.commit, finished=time.strftime("%Y-%m-%d %H:%M:%S"),
                          loadavg=list(os.getloadavg())))
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(path, json.dumps(rec, indent=1) + "\n")
        rec["cached"] = False
        return rec

    # ------------------------------------------------------------------ measurements
    def peak(self, repeats):
        from .bench import measure_peak_flops
        p = measure_peak_flops(self.ctx, repeats=repeats)
        s = [p["flops_per_s"] * p["seconds_median"] / t for t in p["seconds_all"]]
        rec = dict(flops_per_s=p["flops_per_s"], flops_per_s_min=min(s), flops_per_s_max=max(s),
                   repeats=len(s), at=time.strftime("%H:%M:%S"), loadavg=list(os.getloadavg()))
        self.peaks.append(rec)
        return rec

    def evaluate_point(self, t, scene, views):
        """Held-out PSNR/SSIM of the exported opaque mesh (mesh renderer, 4x4) and of the soft
        model as trained (trainer renderer at the current sigma, 4x)."""
        from .evaluate import evaluate_mesh
        from .train.trainer import Trainer, psnr, ssim
        t0 = time.perf_counter()
        soft_psnr, soft_ssim, _ = t.evaluate(views=views)
        pos, tri, col = t.final_mesh()
        bg = tuple(float(x) for x in t.config.background)
        if len(tri):
            rows = evaluate_mesh(Trainer.mesh_model(pos, tri, col), scene, views, self.mr, supersample=4,
                                 background=bg)
            mp, ms = float(np.mean([r["psnr"] for r in rows])), float(np.mean([r["ssim"] for r in rows]))
        else:       # nothing survived the final cleanup: the background alone
            imgs = [np.broadcast_to(np.asarray(bg, np.float32), scene.images[v].shape) for v in views]
            mp = float(np.mean([psnr(i, scene.images[v]) for i, v in zip(imgs, views)]))
            ms = float(np.mean([ssim(np.ascontiguousarray(i), scene.images[v]) for i, v in zip(imgs, views)]))
        return dict(iteration=t.iteration, sigma=t.sched.sigma(t.iteration), model_vertices=t.n, model_triangles=t.m,
                    mesh_vertices=int(len(pos)), mesh_triangles=int(len(tri)), mesh_psnr=mp, mesh_ssim=ms,
                    soft_psnr=soft_psnr, soft_ssim=soft_ssim, eval_seconds=time.perf_counter() - t0)

    def measure_blend(self, t, scene, repeats, peak_repeats):
        """The forward and backward blend kernels on the trained model (first training view, the
        run's final sigma), timed by timestamp queries (host timing otherwise), with the peak FMA
        rate measured just before: GFLOP/s of the algorithm's count and the fraction of peak."""
        from .backward import backward
        from .bench import blend_flops
        from .bench_backward import BACKWARD_BLEND_FLOPS
        r, c = self.renderer, self.ctx
        view = t.train_views[0]
        cam = scene.cameras[view]
        sigma = t.sched.sigma(t.iteration)
        bg, near = t.config.background, t.config.near
        vi = np.random.default_rng(1).normal(size=(cam.height, cam.width, 3)).astype(np.float32)
        res = r.forward(t.model, cam, sigma, bg, near)
        backward(r, res, vi)                                         # warm-up
        peak = self.peak(peak_repeats)
        f_ms, b_ms = [], []
        g = None
        f_wall, f_sum = [], []
        for _ in range(repeats):
            c.wait()
            ts = time.perf_counter()
            res = r.forward(t.model, cam, sigma, bg, near, profile=True)
            c.wait()
            f_wall.append((time.perf_counter() - ts) * 1e3)
            f_sum.append(sum(res.timings.values()))
            f_ms.append(res.timings.get("rasterize_forward", float("nan")))
            g = backward(r, res, vi, profile=True)
            b_ms.append(g.timings.get("rasterize_backward", float("nan")))
        fwork = res.work
        if "work" in getattr(g, "buffers", {}):
            w = c.read(g.buffers["work"], np.uint32, 3)
            bwork = dict(evaluations=int(w[0]), powered=int(w[1]), contributions=int(w[2]))
        else:
            bwork = dict(evaluations=0, powered=0, contributions=0)
        bflops = sum(BACKWARD_BLEND_FLOPS[k] * bwork[k] for k in BACKWARD_BLEND_FLOPS)
        out = dict(view=int(view), width=cam.width, height=cam.height, sigma=sigma, triangles=t.m, pairs=res.num_pairs,
                   timing="timestamp queries" if c.features.timestamps else "host timing", peak=peak,
                   forward_wall_ms=_stats(f_wall), forward_stages_sum_ms=_stats(f_sum),
                   # the stages' sum against the host's wall clock: timestamps that account for less than
                   # a tenth of it are not to be trusted (see run_bench: lavapipe after a render pass)
                   timestamps_plausible=bool(statistics.median(f_sum) >= 0.1 * statistics.median(f_wall)))
        for name, ms, flops, work in (("forward", f_ms, blend_flops(fwork), fwork),
                                      ("backward", b_ms, bflops, bwork)):
            st = _stats(ms)
            rate = [flops / (m * 1e-3) for m in ms if _finite(m) and m > 0]
            out[name] = dict(kernel=f"rasterize_{name}", ms=st, flops=flops, work=work,
                             gflops_per_s=statistics.median(rate) / 1e9 if rate else None,
                             fraction_of_peak=statistics.median(rate) / peak["flops_per_s"] if rate else None,
                             fraction_min=min(rate) / peak["flops_per_s"] if rate else None,
                             fraction_max=max(rate) / peak["flops_per_s"] if rate else None)
        return out

    def train_run(self, scene, plan, label, iterations, cfg_kwargs, eval_at=None, profile_every=0, blend=False):
        """One training run (quick preset scaled to ``iterations``) with evaluations at ``eval_at``
        (default: the end) and optional per-stage profiling / blend measurement."""
        from .train.trainer import TrainConfig, Trainer
        views = eval_views(scene, plan.test_views)
        cfg = TrainConfig(iterations=int(iterations), quick=True, seed=0,
                          background=tuple(float(x) for x in scene.background), log_every=0, **cfg_kwargs)
        t_run = time.perf_counter()
        t = Trainer(scene, cfg, renderer=self.renderer)
        sched = t.sched
        init = dict(vertices=t.n, triangles=t.m)
        eval_at = sorted(set(eval_at or []) | {int(iterations)})
        points, stage_rows, segments = [], [], []
        train_s = prof_s = 0.0
        prof_n = 0
        peak_v = t.n
        bar = None
        if self.progress:
            from tqdm import tqdm
            bar = tqdm(total=int(iterations), desc=f"{plan.name} {label}", unit="it", dynamic_ncols=True,
                       leave=False, file=sys.stderr, position=1 if self.overall is not None else 0)
        try:
            for target in eval_at:
                if target > t.iteration:
                    t.ctx.wait()
                    t0, it0, p0 = time.perf_counter(), t.iteration, prof_s
                    while t.iteration < target:
                        it = t.iteration + 1
                        topo = cfg.topology and (sched.is_prune_step(it) or sched.is_densify_step(it))
                        prof = profile_every > 0 and (it % profile_every == 0 or topo)
                        if prof:
                            ts = time.perf_counter()
                            t.step(profile=True)
                            prof_s += time.perf_counter() - ts
                            prof_n += 1
                            stage_rows.append(dict(iteration=it, topology_step=bool(topo), **t.step_times))
                        else:
                            t.step()
                        peak_v = max(peak_v, t.n)
                        if bar is not None:
                            bar.update(1)
                        if self.overall is not None:
                            self.overall.update(1)
                    t.ctx.wait()
                    dt = time.perf_counter() - t0
                    train_s += dt
                    n_plain = (t.iteration - it0) - sum(1 for r in stage_rows if r["iteration"] > it0)
                    if n_plain > 0:
                        segments.append(n_plain / max(dt - (prof_s - p0), 1e-9))
                pt = self.evaluate_point(t, scene, views)
                pt["train_seconds"] = train_s
                points.append(pt)
                if bar is not None:
                    bar.set_postfix(mesh_psnr=f"{pt['mesh_psnr']:.2f}", tris=t.m)
        finally:
            if bar is not None:
                bar.close()
        plain_n = int(iterations) - prof_n
        rec = dict(label=label, run_seconds=time.perf_counter() - t_run, iterations=int(iterations), config={k: v for k, v in asdict(cfg).items() if k != "extra"},
                   initial=init, points=points, final=points[-1], train_seconds=train_s,
                   its_per_s=plain_n / max(train_s - prof_s, 1e-9) if plain_n > 0 else int(iterations) / max(train_s, 1e-9),
                   its_per_s_segments=_stats(segments), profiled_iterations=prof_n, peak_vertices=peak_v,
                   densify_stopped=t.topology.densify_stopped,
                   topology_events=sum(1 for e in t.topology.events if e.get("event") == "topology"),
                   eval_views=len(views))
        if stage_rows:
            rec["stages"] = summarize_stages(stage_rows, int(iterations), t._profiler.method)
        if blend:
            rec["blend"] = self.measure_blend(t, scene, plan.blend_repeats, plan.peak_repeats)
            rec["run_seconds"] = time.perf_counter() - t_run
        return rec

    # ------------------------------------------------------------------ one scene
    def scene(self, plan):
        """Every measurement of one scene; a scene that does not load is a one-line record."""
        from .evaluate import load_scene_arg
        from .train.ablations import ABLATIONS, PAPER_BASELINE
        rec = dict(name=plan.name, scene=plan.scene, downscale=plan.downscale, plan=asdict(plan),
                   loadavg_start=list(os.getloadavg()), started=time.strftime("%Y-%m-%d %H:%M:%S"))
        t0 = time.perf_counter()
        try:
            scene = load_scene_arg(plan.scene, plan.downscale)
            if not scene.train_indices:
                raise ValueError("no training views")
            if scene.points is None or len(scene.points) < 3:
                raise ValueError("no initial points")
        except Exception as exc:
            rec["status"] = f"error: scene did not load ({_one_line(exc)})"
            self.log(f"{plan.name}: {rec['status']}")
            return rec
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
        base_key = dict(scene=plan.scene, downscale=plan.downscale, test_views=plan.test_views)
        n = int(plan.iterations)
        runs = rec["runs"] = {}

        def run(name, fn, key):
            try:
                runs[name] = self._cached(plan.name, name, dict(base_key, run=name, **key), fn)
                if runs[name].get("cached") and self.overall is not None:   # nothing left to do: out of the ETA
                    self.overall.total = max(self.overall.n, self.overall.total - int(runs[name].get("iterations", 0)))
                    self.overall.refresh()
            except KeyboardInterrupt:
                raise
            except Exception as exc:
                runs[name] = dict(error=_one_line(exc))
                self.log(f"  {name}: failed ({runs[name]['error']})")
                return None
            r = runs[name]
            f = r["final"]
            self.log(f"  {name}: {r['iterations']} it in {r['train_seconds']:.1f}s ({r['its_per_s']:.2f} it/s); mesh "
                     f"{f['mesh_psnr']:.2f} dB / {f['mesh_ssim']:.3f}, soft {f['soft_psnr']:.2f} dB, "
                     f"{f['mesh_vertices']} vertices")
            return r

        # 1. curves: the quick preset with topology off and a longer run; blend on the quick one
        pts = plan.eval_points
        run("quick", lambda: self.train_run(scene, plan, "quick", n, dict(topology=False),
                                            curve_iterations(n, pts), blend=True),
            dict(iterations=n, topology=False, points=pts, blend=(plan.blend_repeats, plan.peak_repeats)))
        if plan.long and plan.long_factor > 1:
            nl = n * int(plan.long_factor)
            run("long", lambda: self.train_run(scene, plan, "long", nl, dict(topology=False), curve_iterations(nl, pts)),
                dict(iterations=nl, topology=False, points=pts))
        # 2. the method with topology (the ablations' baseline, the plateau stop), profiled per stage
        topo = dict(topology=True, quick_topology_epochs=float(plan.topology_epochs))
        for name in plan.ablations:
            over = ABLATIONS[name][2]
            run(f"ablation-{name}", lambda over=over, name=name: self.train_run(
                scene, plan, f"ablation {name}", n, dict(topo, **over),
                profile_every=plan.profile_every if name == "baseline" else 0),
                dict(iterations=n, cfg=dict(topo, **over), profile=plan.profile_every if name == "baseline" else 0))
        # 3. vertices vs PSNR: no stop, then budgets V0 + f (peak - V0) (plateau stop off). Densification
        #    starts long before the first prune, so a cap below V0 would only stop it; f = 0 is "none".
        if plan.budget_runs:
            nostop = run("densify-no-stop", lambda: self.train_run(scene, plan, "no stop", n,
                                                                   dict(topo, densify_stop_rel=0.0)),
                         dict(iterations=n, cfg=dict(topo, densify_stop_rel=0.0)))
            if nostop is not None:
                v0 = int(nostop["initial"]["vertices"])
                for f in plan.budgets:
                    cap = max(3, int(round(v0 + f * max(0, nostop["peak_vertices"] - v0))))
                    run(f"budget-{f:g}", lambda cap=cap, f=f: self.train_run(
                        scene, plan, f"budget {cap}", n, dict(topo, densify_stop_rel=0.0, max_vertices=cap)),
                        dict(iterations=n, cfg=dict(topo, densify_stop_rel=0.0, max_vertices=cap)))
        # 4. the classical baseline
        if plan.poisson:
            try:
                rec["poisson"] = self._cached(plan.name, "poisson", dict(base_key, run="poisson", depth=plan.poisson_depth),
                                              lambda: self.poisson(scene, views, plan.poisson_depth))
                p = rec["poisson"]
                self.log(f"  poisson: {p['psnr']:.2f} dB / {p['ssim']:.3f}, {p['vertices']} vertices")
            except KeyboardInterrupt:
                raise
            except Exception as exc:
                rec["poisson"] = dict(error=_one_line(exc))
        rec["ablations"] = ablation_table(runs, plan.ablations, ABLATIONS, PAPER_BASELINE)
        rec["budgets"] = budget_table(runs)
        rec["seconds"] = time.perf_counter() - t0
        # what the runs took when they were measured (cached runs included), evaluations included
        rec["measured_seconds"] = sum(float(r.get("run_seconds") or 0.0) for r in runs.values()) + \
            float((rec.get("poisson") or {}).get("seconds") or 0.0)
        rec["loadavg_end"] = list(os.getloadavg())
        return rec

    def poisson(self, scene, views, depth):
        from .evaluate import evaluate_mesh, poisson_baseline
        t0 = time.perf_counter()
        model = poisson_baseline(scene, depth=depth)
        rows = evaluate_mesh(model, scene, views, self.mr, supersample=4,
                             background=tuple(float(x) for x in scene.background))
        return dict(depth=depth, psnr=float(np.mean([r["psnr"] for r in rows])),
                    ssim=float(np.mean([r["ssim"] for r in rows])), vertices=model.num_vertices,
                    triangles=model.num_triangles, seconds=time.perf_counter() - t0, points=int(len(scene.points)))


# ---------------------------------------------------------------------------------------- summaries

def summarize_stages(rows, iterations, method):
    """Median and min-max per stage over the profiled steps that edited nothing; the topology
    edits separately, amortised over the run."""
    from .train.profile import STAGES
    plain = [r for r in rows if not r["topology_step"]] or rows
    keys = list(STAGES) + ["other", "wall"]
    out = dict(method=method, profiled=len(rows), plain_steps=len(plain),
               ms={k: _stats([r[k] for r in plain]) for k in keys})
    edits = [r for r in rows if r["topology_step"]]
    acc = out["ms"]["topology"]["median"] if out["ms"]["topology"] else 0.0
    edit_ms = [max(0.0, r["topology"] - acc) for r in edits]
    out["topology_edits"] = dict(count=len(edits), ms=_stats(edit_ms),
                                 amortised_ms_per_iteration=sum(edit_ms) / max(1, iterations))
    gpu = statistics.median(sum(r[k] for k in STAGES) for r in plain)
    out["timestamps_plausible"] = bool(gpu >= 0.1 * statistics.median(r["wall"] for r in plain))
    return out


def ablation_table(runs, names, ablations, paper_baseline):
    base = runs.get("ablation-baseline")
    rows = []
    for name in names:
        r = runs.get(f"ablation-{name}")
        table, label, over, paper = ablations[name]
        row = dict(name=name, table=table, label=label, overrides=over, paper_delta=paper,
                   paper_psnr=paper_baseline["psnr"] + paper["psnr"], paper_ssim=paper_baseline["ssim"] + paper["ssim"])
        if r is None or "error" in r:
            row["error"] = (r or {}).get("error", "not run")
            rows.append(row)
            continue
        f = r["final"]
        row.update(mesh_psnr=f["mesh_psnr"], mesh_ssim=f["mesh_ssim"], soft_psnr=f["soft_psnr"], soft_ssim=f["soft_ssim"],
                   mesh_vertices=f["mesh_vertices"], mesh_triangles=f["mesh_triangles"],
                   model_vertices=f["model_vertices"], train_seconds=r["train_seconds"], its_per_s=r["its_per_s"])
        if base is not None and "error" not in base:
            b = base["final"]
            row.update(delta_mesh_psnr=f["mesh_psnr"] - b["mesh_psnr"], delta_soft_psnr=f["soft_psnr"] - b["soft_psnr"],
                       delta_mesh_ssim=f["mesh_ssim"] - b["mesh_ssim"], delta_soft_ssim=f["soft_ssim"] - b["soft_ssim"],
                       vertices_ratio=f["mesh_vertices"] / max(1, b["mesh_vertices"]),
                       time_ratio=r["train_seconds"] / max(1e-9, base["train_seconds"]))
        rows.append(row)
    return rows


def budget_table(runs):
    rows = []
    for key, label in [("ablation-baseline", "plateau stop (densify_stop_rel 0.01)"),
                       ("densify-no-stop", "no stop (densify_stop_rel 0)")] + \
            sorted(((k, None) for k in runs if k.startswith("budget-")), key=lambda kv: float(kv[0].split("-", 1)[1])):
        r = runs.get(key)
        if r is None or "error" in r:
            continue
        f = r["final"]
        cfg = r["config"]
        rows.append(dict(run=key, label=label or f"--max-vertices {cfg['max_vertices']}",
                         max_vertices=cfg["max_vertices"], densify_stop_rel=cfg["densify_stop_rel"],
                         peak_vertices=r["peak_vertices"], model_vertices=f["model_vertices"],
                         mesh_vertices=f["mesh_vertices"], mesh_triangles=f["mesh_triangles"],
                         mesh_psnr=f["mesh_psnr"], mesh_ssim=f["mesh_ssim"], soft_psnr=f["soft_psnr"],
                         densify_stopped=r.get("densify_stopped"), train_seconds=r["train_seconds"]))
    return rows


def headline_rows(report):
    rows = []
    for s in report["scenes"]:
        if s.get("status") != "ok":
            rows.append(dict(scene=s["name"], status=s.get("status")))
            continue
        res = f"{s['resolution'][0]}x{s['resolution'][1]}"
        q = s["runs"].get("quick") or {}
        for key, label in (("quick", "quick, topology off"), ("long", "longer, topology off"),
                           ("ablation-baseline", "quick, topology on")):
            r = s["runs"].get(key)
            if r is None or "error" in r:
                continue
            f = r["final"]
            rows.append(dict(scene=s["name"], resolution=res, run=label, iterations=r["iterations"],
                             train_seconds=r["train_seconds"], its_per_s=r["its_per_s"],
                             time_vs_quick=r["train_seconds"] / q["train_seconds"] if q.get("train_seconds") else None,
                             mesh_psnr=f["mesh_psnr"],
                             mesh_ssim=f["mesh_ssim"], soft_psnr=f["soft_psnr"], mesh_vertices=f["mesh_vertices"],
                             mesh_triangles=f["mesh_triangles"]))
        p = s.get("poisson")
        if p and "error" not in p:
            rows.append(dict(scene=s["name"], resolution=res, run=f"Poisson (depth {p['depth']})", iterations=None,
                             train_seconds=p["seconds"], its_per_s=None, time_vs_quick=None, mesh_psnr=p["psnr"],
                             mesh_ssim=p["ssim"],
                             soft_psnr=None, mesh_vertices=p["vertices"], mesh_triangles=p["triangles"]))
    return rows


# ---------------------------------------------------------------------------------------- markdown

def _f(x, fmt="{:.2f}", none="-"):
    return none if x is None else fmt.format(x)


def headline_markdown(report):
    lines = ["| scene | resolution | run | iterations | train s | x quick | it/s | mesh PSNR | mesh SSIM | soft PSNR "
             "| vertices | triangles |", "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in headline_rows(report):
        if "status" in r:
            lines.append(f"| {r['scene']} | {r['status']} | | | | | | | | | | |")
            continue
        lines.append(f"| {r['scene']} | {r['resolution']} | {r['run']} | {_f(r['iterations'], '{:d}')} | "
                     f"{_f(r['train_seconds'], '{:.0f}')} | {_f(r['time_vs_quick'])} | {_f(r['its_per_s'])} | "
                     f"**{_f(r['mesh_psnr'])}** | "
                     f"{_f(r['mesh_ssim'], '{:.3f}')} | {_f(r['soft_psnr'])} | {r['mesh_vertices']:,} | "
                     f"{r['mesh_triangles']:,} |")
    return "\n".join(lines)


def _stop_reason(reason):
    """The log's densify_stop reason, short."""
    if not reason:
        return "did not stop"
    if "relative improvement" in reason:
        head, _, tail = reason.partition("mean over the last ")
        return "training L1: last " + tail
    return reason


def _caption(report, s, iterations, runs=()):
    m = report["meta"]
    commits = sorted({s["runs"][k]["commit"] for k in runs if s["runs"].get(k, {}).get("commit")}) or [m["commit"]]
    return (f"adapter {m['adapter']}, {s['resolution'][0]}x{s['resolution'][1]}, {iterations} iterations, "
            f"commit {'+'.join(commits)}")


def render_markdown(report):
    m = report["meta"]
    peak = report.get("peak") or {}
    L = ["# tsplus bench report", "",
         f"- adapter: **{m['adapter']}** ({m['timing']}); commit `{m['commit']}`; {m['date']}; host {m['host']}, "
         f"{m['cpus']} CPUs",
         f"- command: `{m['command']}`",
         f"- wall time of this invocation: {m['seconds'] / 60:.1f} min" + (" (some runs from the cache)" if m.get("cached_runs") else ""),
         f"- CPU load average (1 min) at start / end: {m['loadavg_start'][0]:.2f} / {m.get('loadavg_end', [float('nan')])[0]:.2f}"
         f" on {m['cpus']} CPUs" + (" — the device is a CPU driver shared with other processes: timings are contended"
                                    if m.get("is_cpu") else ""),
         ]
    commits = sorted({r.get("commit") for s in report["scenes"] for r in s.get("runs", {}).values()
                      if r.get("commit")} - {m["commit"]})
    if commits:
        L.append(f"- some runs come from the cache of an earlier invocation at commit(s) {', '.join(commits)} "
                 f"(each run's commit is in report.json)")
    if peak:
        L.append(f"- peak FMA rate measured in this run: **{peak['median'] / 1e9:.1f} GFLOP/s** (median of "
                 f"{peak['n']} measurements, {peak['min'] / 1e9:.1f}-{peak['max'] / 1e9:.1f})")
    L += ["", "PSNR/SSIM: held-out views; **mesh** = the exported opaque mesh (sigma and opacity dropped, SH DC "
              "colours) drawn by the depth-tested mesh renderer at 4x4 supersampling; **soft** = the model as trained "
              "(its final sigma and opacities) through the splatting renderer at 4x. Train s: training wall time "
              "without evaluations; it/s: of the unprofiled steps. Timings: median [min-max] of repeats.", "",
          "## Headline", "", headline_markdown(report), ""]
    for s in report["scenes"]:
        L += [f"## {s['name']}", ""]
        if s.get("status") != "ok":
            L += [f"{s['scene']}: {s.get('status')}", ""]
            continue
        runs = s["runs"]
        L.append(f"`{s['scene']}` downscale {s['downscale']}: {s['resolution'][0]}x{s['resolution'][1]}, "
                 f"{s['train_views']} training views, evaluated on {s['eval_note']}; {s['points']:,} initial points; "
                 f"{s['seconds'] / 60:.1f} min in this invocation"
                 + (f" (the runs took {s['measured_seconds'] / 60:.1f} min when measured)" if s.get("measured_seconds")
                    and s["measured_seconds"] > 1.2 * s["seconds"] else "")
                 + f"; load average {s['loadavg_start'][0]:.2f} -> {s['loadavg_end'][0]:.2f}.")
        L.append("")
        for key in ("quick", "long"):
            r = runs.get(key)
            if r is None:
                continue
            if "error" in r:
                L += [f"{key}: failed: {r['error']}", ""]
                continue
            seg = r.get("its_per_s_segments")
            L += [f"**{key}** ({_caption(report, s, r['iterations'], [key])}; {r['train_seconds']:.0f} s, "
                  f"{r['its_per_s']:.2f} it/s" + (f" [{seg['min']:.2f}-{seg['max']:.2f} over {seg['n']} segments]"
                                                   if seg else "") + "):", "",
                  "| iteration | train s | sigma | mesh PSNR | mesh SSIM | soft PSNR | soft SSIM | mesh vertices | "
                  "model triangles |", "|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
            for p in r["points"]:
                L.append(f"| {p['iteration']} | {p['train_seconds']:.0f} | {p['sigma']:.4f} | {p['mesh_psnr']:.2f} | "
                         f"{p['mesh_ssim']:.3f} | {p['soft_psnr']:.2f} | {p['soft_ssim']:.3f} | {p['mesh_vertices']:,} | "
                         f"{p['model_triangles']:,} |")
            L.append("")
        for plot in s.get("plots", []):
            L += [f"![{Path(plot).stem}]({plot})", ""]
        b = (runs.get("ablation-baseline") or {}).get("stages")
        if b:
            ms = b["ms"]
            L += [f"**Per-stage time per iteration** (method run, topology on; {b['method']}; {b['plain_steps']} profiled "
                  f"steps without topology edits; "
                  f"{_caption(report, s, runs['ablation-baseline']['iterations'], ['ablation-baseline'])}):", "",
                  "| stage | ms median | min-max | share of wall |", "|---|---:|---:|---:|"]
            wall = ms["wall"]["median"] if ms.get("wall") else None
            for k, v in ms.items():
                if v is None:
                    continue
                share = f"{100 * v['median'] / wall:.1f} %" if wall and k != "wall" else ""
                L.append(f"| {k} | {v['median']:.2f} | {v['min']:.2f}-{v['max']:.2f} | {share} |")
            if not b.get("timestamps_plausible", True):
                L += ["", "**Warning:** the stages account for less than a tenth of the step's wall time: the "
                          "device's timestamps are not plausible here."]
            te = b["topology_edits"]
            L += ["", f"Topology edits (host round trip: prune, densify, buffers re-created): {te['count']}"
                      + (f", {te['ms']['median']:.1f} ms median [{te['ms']['min']:.1f}-{te['ms']['max']:.1f}]"
                         if te["ms"] else "") + f", amortised {te['amortised_ms_per_iteration']:.2f} ms per iteration.", ""]
        bl = (runs.get("quick") or {}).get("blend")
        if bl:
            L += [f"**Blend kernels vs the device's peak** (trained quick model, view {bl['view']}, {bl['width']}x"
                  f"{bl['height']}, sigma {bl['sigma']:.4g}, {bl['triangles']:,} triangles, {bl['pairs']:,} tile pairs; "
                  f"peak {bl['peak']['flops_per_s'] / 1e9:.1f} GFLOP/s measured just before, "
                  f"[{bl['peak']['flops_per_s_min'] / 1e9:.1f}-{bl['peak']['flops_per_s_max'] / 1e9:.1f}]):", "",
                  "| kernel | ms median [min-max] | GFLOP/s | fraction of peak [range] |", "|---|---:|---:|---:|"]
            for k in ("forward", "backward"):
                x = bl[k]
                if x["ms"] is None:
                    continue
                L.append(f"| {x['kernel']} | {x['ms']['median']:.2f} [{x['ms']['min']:.2f}-{x['ms']['max']:.2f}] | "
                         f"{_f(x['gflops_per_s'])} | {_f(x['fraction_of_peak'], '{:.1%}')} "
                         f"[{_f(x['fraction_min'], '{:.1%}')}-{_f(x['fraction_max'], '{:.1%}')}] |")
            if not bl.get("timestamps_plausible", True):
                L.append("\n**Warning:** the forward's timestamps sum to less than a tenth of its wall time: not "
                         "plausible on this device.")
            L.append("")
        if s.get("budgets"):
            L += [f"**Vertices vs PSNR** (topology on, {runs.get('ablation-baseline', {}).get('iterations', '')} "
                  f"iterations; --max-vertices budgets V0 + f (peak - V0) with V0 the initial and peak the no-stop "
                  f"run's largest vertex count, plateau stop off):", "",
                  "| run | max vertices | peak vertices | mesh vertices | mesh PSNR | mesh SSIM | soft PSNR | why "
                  "densifying stopped |", "|---|---:|---:|---:|---:|---:|---:|---|"]
            for r in s["budgets"]:
                L.append(f"| {r['label']} | {r['max_vertices']:,} | {r['peak_vertices']:,} | {r['mesh_vertices']:,} | "
                         f"{r['mesh_psnr']:.2f} | {r['mesh_ssim']:.3f} | {r['soft_psnr']:.2f} | "
                         f"{_stop_reason(r['densify_stopped'])}"
                         + (" (capped by the budget)" if not r["densify_stopped"] and r["max_vertices"] < 3_000_000
                            and r["peak_vertices"] >= 0.95 * r["max_vertices"] else "") + " |")
            p = s.get("poisson")
            if p and "error" not in p:
                L.append(f"| Poisson baseline (depth {p['depth']}) | | | {p['vertices']:,} | {p['psnr']:.2f} | "
                         f"{p['ssim']:.3f} | | |")
            L.append("")
        if s.get("ablations"):
            base = runs.get("ablation-baseline") or {}
            L += [f"**Ablations** ({_caption(report, s, base.get('iterations', '?'), [k for k in runs if k.startswith('ablation-')])}; topology on; change against this "
                  f"run's baseline beside the paper's change on Mip-NeRF360, Tables 2-3):", "",
                  "| table | ablation | mesh PSNR | Δ mesh | soft PSNR | Δ soft | paper Δ PSNR | mesh SSIM | Δ mesh SSIM "
                  "| paper Δ SSIM | vertices (x baseline) | time (x baseline) |",
                  "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
            for r in s["ablations"]:
                if "error" in r:
                    L.append(f"| {r['table']} | {r['label']} | {r['error']} | | | | {r['paper_delta']['psnr']:+.2f} | | | "
                             f"{r['paper_delta']['ssim']:+.3f} | | |")
                    continue
                L.append(f"| {r['table']} | {r['label']} | {r['mesh_psnr']:.2f} | {_f(r.get('delta_mesh_psnr'), '{:+.2f}')} | "
                         f"{r['soft_psnr']:.2f} | {_f(r.get('delta_soft_psnr'), '{:+.2f}')} | "
                         f"{r['paper_delta']['psnr']:+.2f} | {r['mesh_ssim']:.3f} | "
                         f"{_f(r.get('delta_mesh_ssim'), '{:+.3f}')} | {r['paper_delta']['ssim']:+.3f} | "
                         f"{r['mesh_vertices']:,} ({_f(r.get('vertices_ratio'))}) | {_f(r.get('time_ratio'))} |")
            L += ["", "The paper reports the soft / free variants as trained (semi-transparent, soft triangles): "
                      "compare its change with the *soft* column; the *mesh* column is what survives export.", ""]
        p = s.get("poisson")
        if p and "error" in p:
            L += [f"Poisson baseline: failed ({p['error']})", ""]
    return "\n".join(L) + "\n"


# ---------------------------------------------------------------------------------------- command

def add_parser(sub):
    plans = "; ".join(
        f"{name} ({'procedural:small 160x120' if name == 'procedural' else 'downscale %d' % kw['downscale']}, "
        f"{kw['iterations']} iterations per run, longer run x{kw['long_factor']}, ~{kw['minutes']:g} min)"
        for name, kw in DEFAULT_PLANS.items())
    p = sub.add_parser(
        "bench", help="speed against error: PSNR/SSIM-vs-time curves, per-stage costs, fraction of peak, vertices vs "
                      "PSNR, the paper's ablations and the Poisson baseline in one report",
        description="Train on every SCENE and write OUT/report.md, OUT/report.json and PNG plots: held-out PSNR/SSIM "
                    "of the exported opaque mesh (mesh renderer, 4x4) and of the soft model vs training wall time and "
                    "iteration for the quick preset with topology off (as the trainer advises for runs this short) and "
                    "a longer run; per-stage time per "
                    "iteration of the method's run (topology on; timestamp queries, host timing otherwise); the "
                    "device's peak FMA rate measured in the same run and the fraction the forward/backward blend "
                    "kernels reach; mesh vertices vs PSNR for the plateau stop, no stop and --max-vertices budgets; "
                    "the paper's ablations (Tables 2-3) beside the paper's numbers; the Poisson baseline. Every run is "
                    "cached in OUT/cache, so an interrupted bench resumes (--fresh: start over); a scene that does not "
                    "load is one line in the report. Default scenes and sizes: " + plans + "; any other folder: "
                    "downscale 4, 300 iterations. Each scene runs: quick, longer, 7 ablations, no-stop and 3 budget "
                    "runs (12 trainings) plus evaluations. The times are measured on lavapipe with 2 CPU cores shared "
                    "with other jobs (load average 1-5): procedural + cup + chair about 31 min, all four about 39 "
                    "min. --smoke: procedural:tiny, 16 iterations per run, under 2 minutes (about 25-50 s).")
    p.add_argument("scenes", nargs="*", metavar="SCENE",
                   help="procedural[:tiny|small|demo], a scene folder, or the name of a folder in TSPLUS_DATA (default: "
                        "procedural and every folder in TSPLUS_DATA, currently " + ", ".join(Path(s).name for s in default_scenes()) + ")")
    p.add_argument("--out", required=True, help="output folder (report.md, report.json, *.png, cache/)")
    p.add_argument("--smoke", action="store_true",
                   help="the smallest complete report: procedural:tiny (64x48), 16 iterations per run, every section "
                        "(used by the test suite; under two minutes on lavapipe). Other SCENES are ignored")
    p.add_argument("--iterations", type=int, default=None,
                   help="iterations of the quick run and of every ablation / budget run (default per scene, above)")
    p.add_argument("--long-factor", type=int, default=None, help="the longer run has this many times the iterations "
                                                                  "(default per scene, above)")
    p.add_argument("--downscale", type=int, default=None, help="image downscale of folder scenes (default per scene)")
    p.add_argument("--eval-points", type=int, default=None, help="evaluations along each curve, iteration 0 included "
                                                                  "(default 5)")
    p.add_argument("--test-views", type=int, default=None, help="evaluate on at most this many held-out views, evenly "
                                                                 "spaced (default 25)")
    p.add_argument("--topology-epochs", type=float, default=None,
                   help="quick_topology_epochs of the runs with topology on (default 1: a topology event at most once "
                        "per epoch; the preset's 3 leaves almost no densification in a few hundred iterations)")
    p.add_argument("--profile-every", type=int, default=None, help="profile 1 in this many steps of the method's run "
                                                                    "(plus every topology step; default 10)")
    p.add_argument("--budgets", type=float, nargs="+", default=None,
                   help="--max-vertices budgets: the initial vertex count V0 plus this fraction of the growth the "
                        "no-stop run reached, V0 + f (peak - V0); 0 = no densification (default 0 0.25 0.5)")
    p.add_argument("--no-long", action="store_true", help="skip the longer run")
    p.add_argument("--no-ablations", action="store_true", help="skip the ablations (the baseline still runs)")
    p.add_argument("--no-budgets", action="store_true", help="skip the no-stop and budget runs")
    p.add_argument("--no-poisson", action="store_true", help="skip the Poisson baseline")
    p.add_argument("--fresh", action="store_true", help="ignore cached runs in OUT/cache")
    p.add_argument("--report-only", action="store_true",
                   help="measure nothing: rewrite OUT/report.md and the plots from OUT/report.json (its numbers and "
                        "metadata kept)")
    p.add_argument("--no-plots", action="store_true", help="no PNG plots")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.add_argument("--adapter", default=None, help="GPU adapter to use (substring of its name)")
    return p


def _peak_summary(peaks):
    if not peaks:
        return None
    v = [p["flops_per_s"] for p in peaks]
    return dict(median=statistics.median(v), min=min(v), max=max(v), n=len(v), samples=peaks)


def write_report(report, out, plots=True):
    """report.json, report.md and the plots, each written atomically."""
    out = Path(out)
    report["peak"] = _peak_summary(report["meta"].get("_peaks", []))
    if plots:
        from .bench_plots import make_plots
        for s in report["scenes"]:
            if s.get("status") == "ok":
                try:
                    s["plots"] = make_plots(report, s, out)
                except Exception as exc:       # a plot must not lose the measurements
                    s["plots"] = []
                    s["plot_error"] = _one_line(exc)
    meta = dict(report["meta"])
    meta.pop("_peaks", None)
    data = _clean(dict(report, meta=meta))
    atomic_write_text(out / "report.json", json.dumps(data, indent=1) + "\n")
    atomic_write_text(out / "report.md", render_markdown(data))
    return data


def command_line(args):
    """The ``tsplus bench`` command that reproduces ``args``."""
    parts = ["tsplus", "bench"] + ([] if args.smoke else list(args.scenes)) + ["--out", str(args.out)]
    for flag in ("smoke", "no_long", "no_ablations", "no_budgets", "no_poisson", "fresh", "no_plots"):
        if getattr(args, flag, False):
            parts.append("--" + flag.replace("_", "-"))
    for key in ("iterations", "long_factor", "downscale", "eval_points", "test_views", "topology_epochs",
                "profile_every", "adapter"):
        v = getattr(args, key, None)
        if v is not None:
            parts += [f"--{key.replace('_', '-')}", f"{v:g}" if isinstance(v, float) else str(v)]
    if getattr(args, "budgets", None):
        parts += ["--budgets"] + [f"{b:g}" for b in args.budgets]
    return " ".join(parts)


def run_bench(args):
    from .bench import git_commit
    from .mesh_renderer import MeshRenderer
    from .renderer import Renderer
    t0 = time.perf_counter()
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out}: exists and is not a folder")
    for key in ("iterations", "long_factor", "eval_points", "test_views", "profile_every", "downscale"):
        v = getattr(args, key, None)
        if v is not None and v < (0 if key == "profile_every" else 1):
            raise ValueError(f"--{key.replace('_', '-')}: expected a positive integer, got {v}")
    if args.budgets is not None and any(not 0 <= f for f in args.budgets):
        raise ValueError("--budgets: expected fractions >= 0")
    if getattr(args, "report_only", False):
        path = out / "report.json"
        if not path.is_file():
            raise FileNotFoundError(f"--report-only: no {path}")
        report = json.loads(path.read_text())
        meta = report["meta"]
        meta["_peaks"] = (report.get("peak") or {}).get("samples", [])
        data = write_report(report, out, plots=not args.no_plots)
        print(headline_markdown(data))
        print(f"rewrote {out}/report.md" + ("" if args.no_plots else " and the plots") + " from report.json")
        return 0
    specs = ["procedural:tiny"] if args.smoke else (list(args.scenes) or default_scenes())
    plans = [plan_for(s, args) for s in specs]
    out.mkdir(parents=True, exist_ok=True)
    renderer = Renderer(args.adapter)
    ctx = renderer.ctx
    # the mesh renderer gets a device of its own: on lavapipe (Mesa 22.3) a render pass on a device
    # leaves that device's later compute-pass timestamps near zero, which would void the stage times
    from .gpu import GpuContext
    mr = MeshRenderer(GpuContext(args.adapter))
    bench = Bench(out, renderer, mr, progress=not args.no_progress, fresh=args.fresh)
    meta = dict(adapter=ctx.name, is_cpu=bool(ctx.is_cpu), commit=git_commit(), date=time.strftime("%Y-%m-%d %H:%M:%S"),
                host=platform.node(), cpus=os.cpu_count(), python=platform.python_version(),
                command=command_line(args),
                timing="timestamp queries" if ctx.features.timestamps else "host timing",
                loadavg_start=list(os.getloadavg()), smoke=bool(args.smoke), _peaks=bench.peaks)
    report = dict(version=REPORT_VERSION, meta=meta, scenes=[])
    print(f"adapter: {ctx.name}; commit {meta['commit']}; scenes: {', '.join(p.name for p in plans)}", flush=True)
    bench.peak(plans[0].peak_repeats if plans else 5)
    print(f"peak FMA rate: {bench.peaks[-1]['flops_per_s'] / 1e9:.1f} GFLOP/s", flush=True)
    if not args.no_progress:
        from tqdm import tqdm
        # smoothing 0: the rate over the whole bench, evaluations included, drives the ETA
        bench.overall = tqdm(total=sum(p.planned_iterations() for p in plans), desc="bench (all training runs)",
                             unit="it", dynamic_ncols=True, file=sys.stderr, position=0, smoothing=0)
        bench.log = bench.overall.write
    try:
        for plan in plans:
            rec = bench.scene(plan)
            report["scenes"].append(rec)
            meta.update(seconds=time.perf_counter() - t0, loadavg_end=list(os.getloadavg()),
                        cached_runs=sum(1 for s in report["scenes"] for r in s.get("runs", {}).values()
                                        if r.get("cached")))
            write_report(report, out, plots=not args.no_plots)
    except KeyboardInterrupt:
        meta.update(seconds=time.perf_counter() - t0, loadavg_end=list(os.getloadavg()), interrupted=True)
        write_report(report, out, plots=not args.no_plots)
        print(f"tsplus bench: interrupted; finished runs are cached in {out}/cache (run the same command to go on)",
              file=sys.stderr)
        return 130
    if bench.overall is not None:
        bench.overall.close()
    bench.peak(3)
    meta.update(seconds=time.perf_counter() - t0, loadavg_end=list(os.getloadavg()))
    data = write_report(report, out, plots=not args.no_plots)
    print(headline_markdown(data))
    print(f"wrote {out}/report.md, report.json and plots in {meta['seconds'] / 60:.1f} min")
    return 0


__all__ = ["ScenePlan", "Bench", "plan_for", "default_scenes", "run_bench", "add_parser", "render_markdown",
           "headline_markdown", "write_report"]
