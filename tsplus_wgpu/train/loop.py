"""The training loop behind :meth:`~.trainer.Trainer.train`: steps, ``log.jsonl``, checkpoints,
Ctrl-C, the progress bar, the step hooks (live viewer) and the :class:`~.callbacks.TrainCallback`
hooks (benchmarks)."""

from __future__ import annotations

import json
import signal
import time
from pathlib import Path


def _log_record(trainer, stats, ips):
    """The ``log.jsonl`` line of a step whose stats were read back."""
    it, s = trainer.iteration, trainer.sched
    rec = dict(iteration=it, loss=stats["loss"], l1=stats["l1"], ssim=stats["ssim"], psnr=stats["psnr"],
               vertices=trainer.n, triangles=trainer.m, sigma=s.sigma(it), floor=s.opacity_floor(it),
               supersample=stats["supersample"], sh_degree=s.sh_degree(it), iterations_per_s=ips,
               elapsed=trainer.elapsed)
    rec.update({k: stats[k] for k in ("normal_loss", "normal_weight") if k in stats})
    return rec


class _Sigint:
    """Ctrl-C finishes the current step (``stop`` becomes True) instead of raising."""

    def __init__(self):
        self.stop = False
        try:
            self.old = signal.signal(signal.SIGINT, self.handle)
        except ValueError:     # not the main thread: Ctrl-C is not ours to catch
            self.old = None

    def handle(self, *args):
        self.stop = True

    def restore(self):
        if self.old is not None:
            signal.signal(signal.SIGINT, self.old)


class TrainLoop:
    """One call of :meth:`~.trainer.Trainer.train` (see there for the arguments)."""

    def __init__(self, trainer, out_dir=None, progress=True, until=None, log_every=None, callbacks=()):
        cfg = trainer.config
        self.t = trainer
        self.until = int(cfg.iterations if until is None else until)
        self.log_every = int(cfg.log_every if log_every is None else log_every)
        self.out = Path(out_dir) if out_dir is not None else None
        self.callbacks = list(callbacks)
        self.progress = progress

    def _write(self, records):
        if self.out is not None and records:
            with open(self.out / "log.jsonl", "a") as f:
                for rec in records:
                    f.write(json.dumps(rec) + "\n")

    def run(self):
        t, out = self.t, self.out
        if out is not None:
            out.mkdir(parents=True, exist_ok=True)
        sigint = _Sigint()
        self.bar = None
        if self.progress:
            from tqdm import tqdm
            self.bar = tqdm(total=self.until, initial=t.iteration, desc="train", unit="it", dynamic_ncols=True)
        try:
            self.t_last, self.it_last = time.perf_counter(), t.iteration
            t0, base_elapsed = time.perf_counter(), t.elapsed
            while t.iteration < self.until and not sigint.stop:
                if self.one_step(t0, base_elapsed) is False:
                    sigint.stop = True
        finally:
            if self.bar is not None:
                self.bar.close()
            sigint.restore()
        if out is not None:
            t.save_checkpoint(out / "checkpoint.npz")
        if sigint.stop:
            raise KeyboardInterrupt
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
        if self.out is not None and cfg.checkpoint_every and t.iteration % cfg.checkpoint_every == 0:
            t.save_checkpoint(self.out / "checkpoint.npz")
        return go_on


__all__ = ["TrainLoop"]
