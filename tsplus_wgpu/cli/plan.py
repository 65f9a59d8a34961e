"""What ``tsplus train`` trains with where the command line leaves it open (:func:`plan_run`),
and what it prints about that (:func:`plan_lines`).

On a CPU adapter (lavapipe, llvmpipe) a first ``tsplus train SCENE --out DIR`` takes the quick
preset at a downscale that keeps a training image within :data:`CPU_MAX_PIXELS`, and as many
iterations as fit :data:`CPU_TRAIN_SECONDS` of training on 2 cores (:func:`cpu_iterations`, from
the time model :func:`cpu_seconds`), so that it takes about a quarter of an hour, not days, meshing
at most :data:`CPU_INIT_POINTS_SHARE` of the vertex cap in initial points (elsewhere every point). On a
GPU adapter: the paper preset at full size, or at the downscale that brings the long side to
:data:`GPU_MAX_SIDE` where an image is larger (the paper's images). A resumed run keeps its own.
The iteration count is a function of the scene and the settings only, never of a clock, so the
same command trains the same model on any machine; only its duration differs."""

from __future__ import annotations

import math
from dataclasses import dataclass

#: the most pixels of a training image when ``tsplus train`` picks the downscale for a CPU adapter:
#: 2**15 keeps the common 16:9 and 4:3 captures at a quarter or an eighth of their size (960x540 ->
#: 240x135, 1080x1920 -> 135x240, 32,400 pixels each). The paper's run at full size takes days there.
CPU_MAX_PIXELS = 2**15
#: the longest side of a training image when ``tsplus train`` picks the downscale for a GPU
#: adapter: the paper trains on images of 1-1.6k pixels (the Mip-NeRF360 and Tanks&Temples
#: protocols), and a phone's 4032x3024 photo at full size would be 7x the pixels of its 1344x1008,
#: with a vertex cap (2 a pixel) past the 3M maximum and a colour fit of 12M samples a view
GPU_MAX_SIDE = 1600
#: the training seconds a CPU adapter's default run aims at on the reference machine (2 cores of
#: an AMD EPYC, llvmpipe; docs/measurements.md): loading, the end of training and the held-out
#: evaluation add 1-2 minutes, so the whole run takes about 13.
CPU_TRAIN_SECONDS = 660
#: the iterations of a CPU adapter's default run: a multiple of CPU_ITERATION_STEP, at least
#: CPU_MIN_ITERATIONS (a whole quick schedule compressed: 3.5-14 min on the four shared real
#: scenes on a machine 2-3x slower than the reference) and at most the quick preset's own 3000
CPU_MIN_ITERATIONS = 600
CPU_MAX_ITERATIONS = 3000
CPU_ITERATION_STEP = 100
#: the time model of :func:`cpu_seconds` (reference machine): seconds of one iteration =
#: CPU_SECONDS_PER_PIXEL x training pixels + CPU_SECONDS_PER_TRIANGLE x triangles drawn. Fitted to
#: the first iterations of the shared real scenes (the initial mesh, before the first prune): cup
#: 0.29 s (30,000 pixels, 100,036 triangles), office 0.31, fox 0.48, lund 0.107 (26,980, 20,894).
CPU_SECONDS_PER_PIXEL = 2.2e-6
CPU_SECONDS_PER_TRIANGLE = 2.26e-6
#: after the first prune the model grows towards the vertex cap, and the last sixth of a quick run
#: renders at 2x and 4x supersampling: an iteration then costs about CPU_LATE_FACTOR x the model's
#: cost at the cap's vertex count in triangles (office and lund over 3000 quick iterations: 0.235
#: and 0.196 s measured against 0.218 and 0.182 s at the cap)
CPU_LATE_FACTOR = 1.08
#: the most initial points a CPU adapter's default run meshes, as a share of its vertex cap
#: (``init_points_share``; elsewhere every point): the initial mesh's Delaunay faces, about 12 a
#: point, are drawn until the first prune, so every point costs a fixed-time run iterations (the
#: cup's default run: 24.57 dB at 0.5 and 1,700 iterations against 23.37 with every point and 1,100)
CPU_INIT_POINTS_SHARE = 0.5
#: triangles of the initial mesh (the points' Delaunay faces and the background shell) per
#: initial point, for the time model before the mesh is built: cup 11.0, fox 11.3, office 11.7,
#: lund 14.1
TRIANGLES_PER_POINT = 11.5


def cpu_downscale(width, height, max_pixels=CPU_MAX_PIXELS):
    """The smallest integer factor d >= 1 whose ``--downscale d`` leaves a ``width`` x ``height``
    image at most ``max_pixels`` pixels (its sides rounded as the loader rounds them), short of
    one that would leave a side under the loader's minimum."""
    from ..data.plausible import MIN_TRAIN_SIDE
    from ..data.scene import downscaled_size
    d = 1
    while (math.prod(downscaled_size(width, height, d)) > max_pixels
           and min(downscaled_size(width, height, d + 1)) >= MIN_TRAIN_SIDE):
        d += 1
    return d


def gpu_downscale(width, height, max_side=GPU_MAX_SIDE):
    """The smallest integer factor d >= 1 whose ``--downscale d`` leaves the longer side of a
    ``width`` x ``height`` image at most ``max_side`` pixels (as the loader rounds it), short of
    one that would leave a side under the loader's minimum."""
    from ..data.plausible import MIN_TRAIN_SIDE
    from ..data.scene import downscaled_size
    d = 1
    while (max(downscaled_size(width, height, d)) > max_side
           and min(downscaled_size(width, height, d + 1)) >= MIN_TRAIN_SIDE):
        d += 1
    return d


def first_prune(cfg, views):
    """The iteration of ``cfg``'s first prune step with ``views`` training views (the last
    iteration + 1 when there is none)."""
    first = cfg.schedule(views).first_prune_step()
    return int(cfg.iterations) + 1 if first is None else first


def cpu_seconds(cfg, cameras, triangles):
    """The rough training seconds of ``cfg`` on the reference machine: the initial mesh's
    ``triangles`` drawn at each iteration until the first prune, then :data:`CPU_LATE_FACTOR` x
    the cost of the run's vertex cap in triangles (``cameras``: the training cameras at the
    training size; :data:`CPU_SECONDS_PER_PIXEL`, :data:`CPU_SECONDS_PER_TRIANGLE`)."""
    early, late = _iteration_seconds(cfg, cameras, triangles)
    if late is None:
        return cfg.iterations * early
    pre = min(int(cfg.iterations), first_prune(cfg, len(cameras)) - 1)
    return pre * early + (int(cfg.iterations) - pre) * late


def cpu_late_ratio(cfg, cameras, triangles):
    """How many times an iteration after the first prune costs one before it, by the time model
    of :func:`cpu_seconds` (None without topology: no prune); for the early estimate of
    :class:`~tsplus_wgpu.train.callbacks.RateEstimate`, which measures the slow first steps."""
    early, late = _iteration_seconds(cfg, cameras, triangles)
    return None if late is None else late / early


def _iteration_seconds(cfg, cameras, triangles):
    """The modelled seconds of one iteration before the first prune (the initial mesh's
    ``triangles``) and after it (None without topology)."""
    from ..train.strategy.cap import vertex_cap
    pixels = float(sum(c.width * c.height for c in cameras)) / max(1, len(cameras))
    early = CPU_SECONDS_PER_PIXEL * pixels + CPU_SECONDS_PER_TRIANGLE * triangles
    if not cfg.topology:
        return early, None
    return early, CPU_LATE_FACTOR * (CPU_SECONDS_PER_PIXEL * pixels
                                     + CPU_SECONDS_PER_TRIANGLE * vertex_cap(cfg, cameras).vertices)


def cpu_iterations(cfg, scene, seconds=CPU_TRAIN_SECONDS, none_fit=CPU_MIN_ITERATIONS):
    """The iterations of a CPU adapter's default run of ``cfg`` (a
    :class:`~tsplus_wgpu.train.config.TrainConfig`, whose own ``iterations`` are ignored) on
    ``scene`` (at the training size): the most, in steps of :data:`CPU_ITERATION_STEP` between
    :data:`CPU_MIN_ITERATIONS` and :data:`CPU_MAX_ITERATIONS`, whose :func:`cpu_seconds` (initial
    mesh: :data:`TRIANGLES_PER_POINT` per point it meshes, within
    :func:`~tsplus_wgpu.train.strategy.cap.initial_points_bound`) fit ``seconds``; ``none_fit``
    where not even the fewest do."""
    from dataclasses import replace
    from ..train.strategy.cap import initial_points_bound
    cams = [scene.cameras[i] for i in scene.train_indices]
    points = 0 if scene.points is None else len(scene.points)
    most = initial_points_bound(cfg, cams)
    triangles = TRIANGLES_PER_POINT * (points if most is None else min(points, most))
    for n in range(CPU_MAX_ITERATIONS, CPU_MIN_ITERATIONS - 1, -CPU_ITERATION_STEP):
        if cpu_seconds(replace(cfg, iterations=n), cams, triangles) <= seconds:
            return n
    return none_fit


def slower_machine(cfg, scene, triangles):
    """:class:`~tsplus_wgpu.train.callbacks.RateEstimate`'s ``planned`` for a run whose
    iterations the CPU plan chose (``cfg``, the initial mesh's ``triangles``): the time model's
    training seconds, and a function from a slowdown ``r`` to the iterations that ``--iterations
    N`` (which meshes every point) fits in :data:`CPU_TRAIN_SECONDS` on a machine ``r`` times
    slower than the reference, or None where not even the fewest fit."""
    from dataclasses import replace
    cams = [scene.cameras[i] for i in scene.train_indices]
    given = replace(cfg, init_points_share=0.0)
    return (cpu_seconds(cfg, cams, triangles),
            lambda slower: cpu_iterations(given, scene, CPU_TRAIN_SECONDS / slower, none_fit=None))


@dataclass(frozen=True)
class Plan:
    """What a run trains with where the command line leaves it open: ``preset`` (``"paper"``,
    ``"quick"``, or None: the ``--config`` file's), ``downscale``, and where each came from
    (``preset_from``, ``downscale_from``: ``"--preset"`` / ``"--downscale"``, ``"--config"``,
    ``"checkpoint"``, ``"CPU adapter"`` or ``"default"``); ``iterations`` where the plan sets
    them: a resumed run's own (``iterations_from="checkpoint"``); ``iterations_from="CPU
    adapter"`` with ``iterations=None``: the CPU adapter's default, :func:`cpu_iterations` once
    the scene is loaded, meshing at most ``init_points_share`` of the vertex cap in points."""

    preset: str | None
    downscale: int
    preset_from: str
    downscale_from: str
    #: the iterations the plan sets (None: the flag's, the config file's or the preset's, or, with
    #: ``iterations_from="CPU adapter"``, :func:`cpu_iterations`'s) and where they came from
    #: (``"CPU adapter"`` or ``"checkpoint"``)
    iterations: int | None = None
    iterations_from: str | None = None
    #: the ``init_points_share`` the plan sets (None: the config file's or the default, every point):
    #: :data:`CPU_INIT_POINTS_SHARE` where the CPU adapter's plan picks the iterations, a resumed
    #: run's own
    init_points_share: float | None = None


def plan_run(args, is_cpu, image_sizes, checkpoint=None):
    """The run's preset and downscale (:class:`Plan`). ``--preset`` and ``--downscale`` stand as
    given, and a ``--config`` file that sets ``quick`` or ``iterations`` chooses the preset. What
    is left open: resuming (``checkpoint``: the checkpoint's config), the run's own, so a plain
    ``--resume`` continues its run; on a CPU adapter (``is_cpu``), the quick preset with
    :func:`cpu_iterations` (unless ``--iterations`` is given) and :func:`cpu_downscale` of the
    largest image (``image_sizes()``: every image's ``(width, height)`` before any downscale; not
    asked for the procedural scene, whose sizes are fixed) and at most :data:`CPU_INIT_POINTS_SHARE`
    of the vertex cap in initial points (unless the ``--config`` file sets ``init_points_share``);
    else the paper preset at full size, or at :func:`gpu_downscale` of the largest image."""
    from .scenes import is_procedural
    from ..train.config import load_config_file
    preset, preset_from = args.preset, "--preset"
    in_file = set(load_config_file(args.config) if args.config else {})
    if preset is None:
        if {"quick", "iterations"} & in_file:
            preset_from = "--config"
        elif checkpoint is not None:
            preset, preset_from = ("quick" if checkpoint.get("quick") else "paper"), "checkpoint"
        else:
            preset, preset_from = ("quick", "CPU adapter") if is_cpu else ("paper", "default")
    downscale, downscale_from = args.downscale, "--downscale"
    if downscale is None:
        if checkpoint is not None:
            downscale, downscale_from = int((checkpoint.get("extra") or {}).get("downscale", 1)), "checkpoint"
        elif is_cpu and not is_procedural(args.scene):
            downscale = max(cpu_downscale(w, h) for w, h in set(image_sizes()))
            downscale_from = "CPU adapter"
        elif not is_cpu and not is_procedural(args.scene):
            downscale = max(gpu_downscale(w, h) for w, h in set(image_sizes()))
            downscale_from = "GPU adapter" if downscale > 1 else "default"
        else:
            downscale, downscale_from = 1, "default"
    iterations, iterations_from = None, None
    if args.iterations is None and checkpoint is not None and "iterations" in checkpoint:
        iterations, iterations_from = int(checkpoint["iterations"]), "checkpoint"
    elif args.iterations is None and preset_from == "CPU adapter":
        iterations_from = "CPU adapter"
    share = None           # the initial points: a resumed run's own record, or the CPU plan's bound
    if "init_points_share" not in in_file:
        if checkpoint is not None and "init_points_share" in checkpoint:
            share = float(checkpoint["init_points_share"])
        elif iterations_from == "CPU adapter":
            share = CPU_INIT_POINTS_SHARE
    return Plan(preset, downscale, preset_from, downscale_from, iterations, iterations_from, share)


#: how the plan line names where a choice came from (:attr:`Plan.preset_from`, ``downscale_from``)
_FROM_TEXT = {"--preset": "as given", "--downscale": "as given", "--config": "from --config",
              "checkpoint": "the run's own", "CPU adapter": "for the CPU adapter",
              "GPU adapter": f"for the GPU: a long side of at most {GPU_MAX_SIDE:,} px, the paper's",
              "default": "default"}


def plan_lines(plan, cfg, scene, triangles=0):
    """What ``tsplus train`` prints about its plan: the preset, the iterations and the training
    size, each with where it came from; for a CPU adapter's choices, a line with the rough
    duration (:func:`cpu_seconds` with the initial mesh's ``triangles``) and how to ask for the
    paper's run instead."""
    cam = scene.cameras[scene.train_indices[0]]
    size = f"{cam.width}x{cam.height}"
    by_cpu = plan.iterations_from == "CPU adapter"
    lines = [f"plan: {'quick' if cfg.quick else 'paper'} preset ({_FROM_TEXT[plan.preset_from]}), "
             f"{cfg.iterations:,} iterations"
             f"{f' ({_FROM_TEXT[plan.iterations_from]})' if plan.iterations_from else ''} at {size} "
             f"(--downscale {plan.downscale}, {_FROM_TEXT[plan.downscale_from]})"]
    cpu = [(chose, undo) for chose, undo, by in (
        ("quick preset", "--preset paper", plan.preset_from),
        (f"{cfg.iterations:,} iterations", None, "CPU adapter" if by_cpu else None),
        (f"--downscale {plan.downscale} ({size})", "--downscale 1", plan.downscale_from)) if by == "CPU adapter"]
    if cpu:
        from ..train.callbacks import duration_text
        seconds = cpu_seconds(cfg, [scene.cameras[i] for i in scene.train_indices], triangles)
        lines.append(f"CPU adapter: {', '.join(c for c, _ in cpu)} so the training takes about "
                     f"{duration_text(seconds)} on 2 cores; pass {' '.join(u for _, u in cpu if u)} for the "
                     f"paper's run")
    if plan.downscale_from == "GPU adapter":
        lines.append(f"GPU adapter: --downscale {plan.downscale} ({size}), the paper's image size; pass --downscale 1 "
                     f"to train at full size")
    return lines
