"""The training loop behind :meth:`~.trainer.Trainer.train`: steps, ``log.jsonl``, checkpoints,
Ctrl-C / SIGTERM / SIGHUP (finish the step, checkpoint, raise :class:`Interrupted`), the
progress bar, the step hooks (live viewer) and the :class:`~.callbacks.TrainCallback` hooks
(benchmarks)."""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path

from ..io.atomic import write_error


def _log_record(trainer, stats, ips):
    """The ``log.jsonl`` line of a step whose stats were read back."""
    it, s = trainer.iteration, trainer.sched
    rec = dict(iteration=it, loss=stats["loss"], l1=stats["l1"], ssim=stats["ssim"], psnr=stats["psnr"],
               vertices=trainer.n, triangles=trainer.m, sigma=s.sigma(it), floor=s.opacity_floor(it),
               supersample=stats["supersample"], sh_degree=s.sh_degree(it), iterations_per_s=ips,
               elapsed=trainer.elapsed)
    rec.update({k: stats[k] for k in ("normal_loss", "normal_weight") if k in stats})
    return rec


class Interrupted(KeyboardInterrupt):
    """Training stopped by a signal (``signum``: SIGINT, SIGTERM, SIGHUP) or a step hook
    (``signum`` None) after the checkpoint was written."""

    def __init__(self, signum=None):
        super().__init__(signum)
        self.signum = signum

    @property
    def signal_name(self):
        return signal.Signals(self.signum).name if self.signum else "a step hook"


#: the signals that stop training after the current step, with a checkpoint: Ctrl-C, and what
#: ``kill``, ``timeout``, job schedulers (SIGTERM) and a closed terminal (SIGHUP) send
STOP_SIGNALS = tuple(getattr(signal, n) for n in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, n))


class _StopSignals:
    """Ctrl-C, SIGTERM and SIGHUP finish the current step (``stop`` becomes True, ``signum``
    the signal) instead of raising or killing the process. A signal the process ignores
    (``nohup``: SIGHUP; a background job: SIGINT) stays ignored."""

    def __init__(self):
        self.stop = False
        self.signum = None
        self.old = {}
        for sig in STOP_SIGNALS:
            try:
                if signal.getsignal(sig) == signal.SIG_IGN:
                    continue
                self.old[sig] = signal.signal(sig, self.handle)
            except (ValueError, OSError):     # not the main thread: the signals are not ours to catch
                break

    def handle(self, signum, frame):
        self.stop = True
        if self.signum is None:
            self.signum = signum

    def restore(self):
        from ..data.long_calls import restore_signals  # noqa: PLC0415
        restore_signals(self.old)


class TrainLoop:
    """One call of :meth:`~.trainer.Trainer.train` (see there for the arguments)."""

    def __init__(self, trainer, out_dir=None, progress=True, until=None, log_every=None, callbacks=(),
                 checkpoint_at_end=True):
        cfg = trainer.config
        self.checkpoint_at_end = checkpoint_at_end
        self.t = trainer
        self.until = int(cfg.iterations if until is None else until)
        self.log_every = int(cfg.log_every if log_every is None else log_every)
        self.out = Path(out_dir) if out_dir is not None else None
        self.callbacks = list(callbacks)
        self.progress = progress

    def _write(self, records):
        if self.out is not None and records:
            path, size = self.out / "log.jsonl", None
            try:
                with open(path, "a") as f:
                    size = f.tell()
                    f.write("".join(json.dumps(rec) + "\n" for rec in records))
            except OSError as exc:
                if size is not None:       # no half line left behind (disk full)
                    try:
                        os.truncate(path, size)
                    except OSError:
                        pass
                raise write_error(path, exc) from None

    def run(self):
        t, out = self.t, self.out
        if out is not None:
            try:
                out.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise write_error(out, exc) from None
        stop = _StopSignals()
        self.bar = None
        if self.progress:
            from tqdm import tqdm
            # smoothing=0: the rate and ETA are the run's mean so far. tqdm's moving average
            # made one topology edit of a paper-scale model on an H200 (30-46 s among 20 ms
            # steps) read as an ETA of 22 hours for a run of under 30 minutes
            self.bar = tqdm(total=self.until, initial=t.iteration, desc="train", unit="it", dynamic_ncols=True,
                            smoothing=0)
        try:
            self.t_last, self.it_last = time.perf_counter(), t.iteration
            t0, base_elapsed = time.perf_counter(), t.elapsed
            while t.iteration < self.until and not stop.stop:
                if self.one_step(t0, base_elapsed) is False:
                    stop.stop = True
            if self.bar is not None:
                self.bar.close()
                self.bar = None
            if out is not None and (stop.stop or self.checkpoint_at_end):
                t.save_checkpoint(out / "checkpoint.npz")    # a second signal now waits for it
        finally:
            if self.bar is not None:
                self.bar.close()
            stop.restore()
        if stop.stop:
            raise Interrupted(stop.signum)
        return t

    def one_step(self, t0, base_elapsed):
        """Iteration ``t.iteration + 1`` with its logging; False: a step hook asked to stop."""
        t, cfg = self.t, self.t.config
        it = t.iteration + 1
        log_now = self.log_every > 0 and (it % self.log_every == 0 or it == self.until or it == 1)
        profile = any([cb.wants_profile(t, it) for cb in self.callbacks])
        topology = t.is_topology_step(it)
        stats = t.step(read_stats=log_now, profile=profile)
        t.elapsed = base_elapsed + time.perf_counter() - t0
        if self.callbacks:
            info = dict(iteration=it, profiled=profile, step_times=dict(t.step_times) if profile else None,
                        topology=topology, vertices=t.n)
            for cb in self.callbacks:
                cb.after_step(t, it, info)
        if self.bar is not None:
            self.bar.update(1)
        if stats is not None:
            t.last_stats = dict(stats, iteration=t.iteration)
        go_on = True
        for hook in list(t.step_hooks):
            if hook(t, stats) is False:
                go_on = False
        if stats is not None:
            now = time.perf_counter()
            ips = (t.iteration - self.it_last) / max(now - self.t_last, 1e-9)
            self.t_last, self.it_last = now, t.iteration
            self._write([_log_record(t, stats, ips)])
        if t.topology.events:
            self._write(t.topology.events)
            t.topology.events = []
        if self.bar is not None and stats is not None:
            self.bar.set_postfix(loss=f"{stats['loss']:.4f}", psnr=f"{stats['psnr']:.2f}", tris=t.m)
        last = t.iteration >= self.until and not self.checkpoint_at_end     # the caller writes that one
        if self.out is not None and cfg.checkpoint_every and t.iteration % cfg.checkpoint_every == 0 and not last:
            t.save_checkpoint(self.out / "checkpoint.npz")
        return go_on


__all__ = ["TrainLoop", "Interrupted", "STOP_SIGNALS"]
