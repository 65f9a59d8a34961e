"""``tsplus bench``, ``tsplus bench-raster`` and ``tsplus bench-backward``: the benchmark
commands' options and their runs (the measurements live in :mod:`tsplus_wgpu.bench`).

:func:`add_parsers` adds the three sub-commands; :data:`COMMANDS` maps each name to the
function that runs it (``run(args) -> exit code``), and :func:`run` dispatches on ``args.command``.
``tsplus bench-viewer`` lives with the viewer (:mod:`.view`)."""

from __future__ import annotations

from pathlib import Path

from ..bench.plans import DEFAULT_PLANS, default_scenes
from .adapters import add_adapter_arg, add_layout_arg, layout_renderer


# ---------------------------------------------------------------------------------------- tsplus bench

def add_bench_parser(sub):
    """``tsplus bench``: speed against error (:mod:`tsplus_wgpu.bench.runs`)."""
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


def check_bench_args(args):
    """ValueError for options out of range (before anything is measured)."""
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out}: exists and is not a folder")
    for key in ("iterations", "long_factor", "eval_points", "test_views", "profile_every", "downscale"):
        v = getattr(args, key, None)
        if v is not None and v < (0 if key == "profile_every" else 1):
            raise ValueError(f"--{key.replace('_', '-')}: expected a positive integer, got {v}")
    if args.budgets is not None and any(not 0 <= f for f in args.budgets):
        raise ValueError("--budgets: expected fractions >= 0")


def run_bench(args):
    """``tsplus bench``: measure (or with ``--report-only`` rewrite the report) and print the headline."""
    check_bench_args(args)
    from ..bench.plans import plan_for
    from ..bench.report import headline_markdown, rewrite_report
    out = Path(args.out)
    if getattr(args, "report_only", False):
        path = out / "report.json"
        if not path.is_file():
            raise FileNotFoundError(f"--report-only: no {path}")
        data = rewrite_report(out, plots=not args.no_plots)
        print(headline_markdown(data))
        print(f"rewrote {out}/report.md" + ("" if args.no_plots else " and the plots") + " from report.json")
        return 0
    specs = ["procedural:tiny"] if args.smoke else (list(args.scenes) or default_scenes())
    plans = [plan_for(s, args) for s in specs]
    from ..bench.runs import run_bench as measure
    return measure(plans, out, adapter=args.adapter, progress=not args.no_progress, fresh=args.fresh,
                   plots=not args.no_plots, command=command_line(args), smoke=args.smoke)


# ---------------------------------------------------------------------------------------- tsplus bench-raster

def add_raster_parser(sub):
    """``tsplus bench-raster``: the forward rasterizer per stage (:mod:`tsplus_wgpu.bench.raster`)."""
    p = sub.add_parser("bench-raster", help="benchmark the forward rasterizer per stage against the device's peak",
                       description="Per-stage milliseconds (timestamp queries where supported), triangles/s and "
                                   "pixel-triangle evaluations/s for several triangle counts, with the device's peak "
                                   "FMA rate measured in the same run and the blend kernel's fraction of it.")
    p.add_argument("--triangles", nargs="+", default=["10000", "100000", "1000000"],
                   help="triangle counts (default 10000 100000 1000000)")
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    p.add_argument("--sigma", type=float, default=0.5)
    p.add_argument("--repeats", type=int, default=5, help="timed runs per size; medians are reported (default 5)")
    p.add_argument("--json", default=None, help="write the full result as JSON here")
    add_adapter_arg(p)
    add_layout_arg(p)
    return p


def _write_json(path, result, default=None):
    from ..io.atomic import write_json
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_json(path, result, indent=2, default=default)
    print(f"wrote {path}")


def run_bench_raster(args):
    """``tsplus bench-raster``: the table, and the result as JSON with ``--json``. The image is
    compared with the float64 twin for the smaller counts."""
    from tqdm import tqdm

    from .. import reference
    from ..bench.raster import format_table, raster_report
    renderer = layout_renderer(args)
    counts = [int(c) for c in args.triangles]
    bars = []

    def progress():          # the bar starts after the adapter and peak lines
        if not bars:
            bars.append(tqdm(total=len(counts) * args.repeats, desc="forward", unit="run", dynamic_ncols=True))
        bars[0].update(1)
    try:
        result = raster_report(renderer, counts, args.width, args.height, args.sigma, args.repeats,
                               reference_render=reference.render, progress=progress,
                               log=lambda msg: print(msg, flush=True))
    finally:
        for bar in bars:
            bar.close()
    print(format_table(result))
    if args.json:
        _write_json(args.json, result)
    return 0


# ---------------------------------------------------------------------------------------- tsplus bench-backward

def add_backward_parser(sub):
    """``tsplus bench-backward``: forward + backward per stage (:mod:`tsplus_wgpu.bench.backward`)."""
    from ..bench import backward
    p = sub.add_parser("bench-backward", help="benchmark forward + backward per stage, the backward/forward ratio "
                                              "and the backward blend's fraction of the device's peak",
                       description=backward.__doc__)
    p.add_argument("--adapter", default=None, help="adapter name (e.g. lavapipe); default: best")
    p.add_argument("--triangles", type=int, default=100_000)
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    p.add_argument("--sigma", type=float, default=0.5)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--json", default=None, help="write the result here")
    add_layout_arg(p)
    return p


def run_bench_backward(args):
    """``tsplus bench-backward``: the table, and the result as JSON with ``--json``."""
    from ..bench.backward import backward_report, format_table
    renderer = layout_renderer(args)
    print(f"adapter: {renderer.ctx.name}", flush=True)
    result = backward_report(renderer, args.triangles, args.width, args.height, args.sigma, args.repeats,
                             progress=lambda: print(".", end="", flush=True))
    print()
    print(format_table(result))
    if args.json:
        _write_json(args.json, result, default=float)
    return 0


# ---------------------------------------------------------------------------------------- tsplus bench-scale

def _count(text):
    """``500000``, ``500k``, ``0.5M`` -> 500000 (argparse type of ``--vertices``)."""
    import argparse
    t = str(text).strip().lower()
    scale = {"k": 1e3, "m": 1e6}.get(t[-1:], 1.0)
    try:
        n = float(t[:-1] if scale != 1.0 else t) * scale
    except ValueError:
        n = float("nan")
    if not (n >= 3 and n == n):
        raise argparse.ArgumentTypeError(f"expected a vertex count such as 500000, 500k or 0.5M, got {text!r}")
    return int(round(n))


def add_scale_parser(sub):
    """``tsplus bench-scale``: paper-sized models, forward + backward (:mod:`tsplus_wgpu.bench.scale`)."""
    from ..bench import scale
    p = sub.add_parser("bench-scale", help="forward + backward of paper-sized models (0.5M-3M vertices, SH degree 3, "
                                           "1920x1080): stages, device memory, pairs per pixel, the twin on a crop",
                       description="Forward + backward of paper-sized models, one line per size: stage "
                                   "milliseconds, tile-triangle pairs per pixel, the device buffers' bytes, what "
                                   "training the model would need, and the image against the float64 twin on a "
                                   "32x32 crop. A size whose buffer does not fit the device's storage binding is a "
                                   "line naming the buffer. The model: three wavy surfaces of shared vertices "
                                   "filling the view, about 2 triangles a vertex.")
    p.add_argument("--vertices", type=_count, nargs="+", default=list(scale.SCALE_SIZES), metavar="N",
                   help="model sizes in vertices, e.g. 500k 1M (default 0.5M 1M 2M 3M)")
    p.add_argument("--width", type=int, default=1920, help="image width in pixels (default 1920)")
    p.add_argument("--height", type=int, default=1080, help="image height in pixels (default 1080)")
    p.add_argument("--sh-degree", type=int, default=3, choices=range(4), help="SH degree of the model (default 3)")
    p.add_argument("--sigma", type=float, default=0.5, help="window sharpness (default 0.5)")
    p.add_argument("--repeats", type=int, default=1, help="timed runs per size; medians (default 1: llvmpipe is slow)")
    p.add_argument("--no-twin", action="store_true", help="skip the float64 twin on a 32x32 crop")
    p.add_argument("--train", type=int, default=0, metavar="N",
                   help="also train each size N steps at --train-size (the first steps of a paper-preset run, half "
                        "of them, a checkpoint, a resumed trainer, the rest): ms a step, loss, peak memory "
                        "(default 0: no training)")
    p.add_argument("--train-size", default="960x540", metavar="WxH", help="training image size (default 960x540)")
    p.add_argument("--json", default=None, help="write the result here")
    add_adapter_arg(p)
    add_layout_arg(p)
    return p


def _train_line(r):
    return (f"{r['vertices']:>10,} v {r['triangles']:>10,} t  trained {r['iterations']} steps at {r['width']}x"
            f"{r['height']}: {r['ms_per_step']:,.0f} ms a step ({r['ms_per_step_resumed']:,.0f} after the resume), "
            f"loss {r['loss_first']:.4f} -> {r['loss_last']:.4f}; checkpoint {r['checkpoint_bytes'] / 2**20:,.0f} MiB "
            f"in {r['checkpoint_s']:.1f} s, resumed in {r['resume_s']:.1f} s; peak buffers "
            f"{r['device_bytes_peak'] / 2**30:.2f} GiB")


def run_bench_scale(args):
    """``tsplus bench-scale``: one line per size as it finishes, the table, and JSON with ``--json``."""
    from .. import reference
    from ..bench.scale import format_table, scale_report, scale_training
    if args.width < 32 or args.height < 32 or args.repeats < 1 or args.train < 0:
        raise ValueError("--width/--height: at least 32 (the twin's crop); --repeats: at least 1; --train: >= 0")
    try:
        tw, th = (int(v) for v in str(args.train_size).lower().split("x"))
    except ValueError:
        raise ValueError(f"--train-size: expected WxH such as 960x540, got {args.train_size!r}") from None

    def report(renderer, log):
        out = scale_report(renderer, args.vertices, args.width, args.height, args.sh_degree, args.sigma,
                           args.repeats, reference_render=None if args.no_twin else reference.render, log=log)
        out["training"] = []
        for n in args.vertices if args.train else ():
            try:
                row = scale_training(renderer, n, tw, th, args.train, args.sh_degree, log=log)
            except ValueError as exc:     # a buffer over the device's limits
                row = dict(vertices=n, refused=str(exc))
            out["training"].append(row)
            log(_train_line(row) if "refused" not in row else f"{n:>10,} v  training refused: {row['refused']}")
        return out

    def fmt(result):
        lines = [_train_line(r) if "refused" not in r else f"{r['vertices']:>10,} v  training refused: {r['refused']}"
                 for r in result["training"]]
        return format_table(result) + ("\n\n" + "\n".join(lines) if lines else "")

    return _run_report(args, report, fmt)


def _run_report(args, report, fmt):
    """A renderer on ``--adapter`` and its name, ``report(renderer, log)`` (lines printed as they
    come), the result as ``fmt`` writes it, and JSON with ``--json``. Exit code 0."""
    renderer = layout_renderer(args)
    print(f"adapter: {renderer.ctx.name}", flush=True)
    result = report(renderer, lambda line: print(line, flush=True))
    print()
    print(fmt(result))
    if args.json:
        _write_json(args.json, result, default=float)
    return 0


# ---------------------------------------------------------------------------------------- tsplus bench-step

def add_step_parser(sub):
    """``tsplus bench-step``: the host's cost of a training step (:mod:`tsplus_wgpu.bench.step`)."""
    p = sub.add_parser("bench-step", help="what a training step costs the host: ms per step where the device has "
                                          "almost nothing to do, with the host caching on and off",
                       description="Trains the procedural tiny scene from a few points, so the device has almost "
                                   "nothing to do and a step's time is the host's (recording about 80 dispatches: "
                                   "what bounds training on a GPU). Blocks of steps with the host caching on and "
                                   "off in turn (uniform buffers by content, bind groups by their buffers, the "
                                   "step's forward and backward on scratch buffers, one submit for the backward; "
                                   "off: all of it anew, as before 2026-11-27); the medians, their ratio, what a "
                                   "step made, and whether both modes train to bit-identical parameters.")
    p.add_argument("--points", type=int, default=60, help="initial points of the tiny scene (default 60)")
    p.add_argument("--steps", type=int, default=20, help="steps per block (default 20)")
    p.add_argument("--blocks", type=int, default=8, help="blocks per mode (default 8)")
    p.add_argument("--json", default=None, help="write the result here")
    add_adapter_arg(p)
    add_layout_arg(p)
    return p


def run_bench_step(args):
    """``tsplus bench-step``: the report, and JSON with ``--json``."""
    from ..bench.step import format_step, step_report
    if args.points < 4 or args.steps < 1 or args.blocks < 1:
        raise ValueError("--points: at least 4; --steps, --blocks: at least 1")
    return _run_report(args, lambda renderer, log: step_report(renderer, args.points, args.steps, args.blocks,
                                                               log=log), format_step)


# ---------------------------------------------------------------------------------------- table

#: command name -> ``run(args) -> exit code``
COMMANDS = {"bench": run_bench, "bench-raster": run_bench_raster, "bench-backward": run_bench_backward,
            "bench-scale": run_bench_scale, "bench-step": run_bench_step}


def add_parsers(sub):
    """Add ``bench-raster``, ``bench`` and ``bench-backward`` to the sub-parsers ``sub``."""
    add_raster_parser(sub)
    add_bench_parser(sub)
    add_backward_parser(sub)
    add_scale_parser(sub)
    add_step_parser(sub)


def run(args):
    """Run the benchmark command ``args.command`` (one of :data:`COMMANDS`); the exit code."""
    return COMMANDS[args.command](args)


__all__ = ["COMMANDS", "add_parsers", "run", "add_bench_parser", "add_raster_parser", "add_backward_parser",
           "add_scale_parser", "add_step_parser", "run_bench", "run_bench_raster", "run_bench_backward",
           "run_bench_scale", "run_bench_step", "command_line", "check_bench_args"]
