"""Long pycolmap calls on the command line: a progress bar that moves while a call reports
nothing (:class:`_Progress`), and signals that stop the command, even inside a call
(:func:`stop_on_signals`, :func:`import_pycolmap`)."""

from __future__ import annotations

import signal
import sys
import threading
import time

class Stopped(KeyboardInterrupt):
    """A command stopped by SIGTERM or SIGHUP (``signum``; :func:`stop_on_signals`)."""

    def __init__(self, signum):
        super().__init__(signum)
        self.signum = signum


#: the signals that stop a command outside training (Ctrl-C raises KeyboardInterrupt by itself)
STOP_SIGNALS = tuple(getattr(signal, n) for n in ("SIGTERM", "SIGHUP") if hasattr(signal, n))


def _stop(signum, frame):
    raise Stopped(signum)


def stop_on_signals() -> dict:
    """From now on SIGTERM and SIGHUP raise :class:`Stopped` in the main thread, as Ctrl-C raises
    KeyboardInterrupt (what ``tsplus`` does for every command; training puts its own handlers,
    which write a checkpoint, in their place while it runs). pycolmap runs Python's signal
    handlers while it works, so a long call ends within a moment and the caller's cleanup runs
    (a half-made cache entry is removed). A signal the process ignores stays ignored
    (``nohup``). Returns the handlers replaced, for :func:`restore_signals`."""
    if threading.current_thread() is not threading.main_thread():
        return {}
    return {sig: signal.signal(sig, _stop) for sig in STOP_SIGNALS if signal.getsignal(sig) != signal.SIG_IGN}


def restore_signals(old: dict) -> None:
    """Put back the handlers ``old`` (signal -> handler) that a ``signal.signal`` call replaced
    (None, a handler Python did not install, becomes the default)."""
    for sig, handler in old.items():
        signal.signal(sig, handler if handler is not None else signal.SIG_DFL)


def import_pycolmap():
    """``pycolmap``, imported. Its logging library installs, at the first import, a handler that
    answers SIGTERM with a crash report of the C++ stack, over whatever handler Python code had
    installed: that one is put back (none was: the library's stays). Every import of pycolmap in
    the package goes through here (tests/test_architecture.py); without pycolmap installed it is
    a one-line :class:`~.errors.SceneError`."""
    try:
        import pycolmap  # noqa: PLC0415
    except ImportError:  # pragma: no cover
        from .errors import SceneError  # noqa: PLC0415
        raise SceneError("pycolmap is missing: install it with `pip install pycolmap`") from None
    if threading.current_thread() is threading.main_thread():
        for sig in STOP_SIGNALS:
            handler = signal.getsignal(sig)
            if callable(handler):
                signal.signal(sig, handler)
    return pycolmap


class _Progress:
    """Stage progress on stderr (tqdm when available); silent when disabled."""

    def __init__(self, enabled: bool, total: float, desc: str, weighted: bool = False):
        """``weighted``: ``total`` and the advances are estimated seconds, not steps: the bar shows
        the share done and the time left, not a count."""
        self.enabled = enabled
        self.weighted = weighted
        self.bar = None
        self.t0 = time.time()
        self._lock = threading.Lock()
        if enabled:
            try:
                from tqdm import tqdm  # noqa: PLC0415
                fmt = "{desc}: {percentage:3.0f}%|{bar}| [{elapsed}<{remaining}{postfix}]" if weighted else None
                self.bar = tqdm(total=total, desc=desc, unit="step", file=sys.stderr, leave=True, bar_format=fmt)
            except ImportError:  # pragma: no cover
                print(f"{desc} ...", file=sys.stderr)

    def stage(self, text: str, advance: float = 1):
        if not self.enabled:
            return
        if self.bar is not None:
            with self._lock:
                self.bar.set_postfix_str(text)
                self.bar.update(advance)
        else:  # pragma: no cover
            print(f"  {text} ({time.time() - self.t0:.0f}s)", file=sys.stderr)

    def add(self, more: float):
        """Make the work ``more`` larger (a stage that was not planned)."""
        if self.bar is not None:
            self.bar.total += more
            self.bar.refresh()

    def creep(self, units: float, tick: float | None = None):
        """A context for one long call that reports nothing (pycolmap's feature extraction, its
        matching): inside it a ``weighted`` bar moves on by itself towards ``units`` more, never
        past 90 % of them, at the pace of the work before it (before any: the units' own, an
        estimated second of the reference machine each), so its time left keeps meaning
        something; leaving it adds the rest. A bar of whole steps only gets the rest at the end.
        ``tick``: seconds between moves (default: a 300th of the units, at least 1)."""
        return _Creep(self, units, tick if tick is not None else max(1.0, units / 300.0))

    def finish(self):
        """Fill the bar: the work is done (estimates, such as photos that never register, may
        leave a share unspent)."""
        if self.bar is not None:
            self._advance(self.bar.total - self.bar.n)

    def _advance(self, units: float):
        if self.bar is not None and units > 0:
            with self._lock:
                self.bar.update(units)

    def note(self, text: str):
        if self.enabled and self.bar is not None:
            self.bar.set_postfix_str(text)
            self.bar.refresh()

    def close(self):
        if self.bar is not None:
            self.bar.close()


class _Creep:
    """:meth:`_Progress.creep`: a thread that advances the bar while the block runs."""

    def __init__(self, prog: _Progress, units: float, tick: float):
        self.prog, self.units, self.tick = prog, float(units), float(tick)
        self.moved, self.stop, self.thread = 0.0, threading.Event(), None

    def __enter__(self):
        bar = self.prog.bar
        if bar is None or self.units <= 0 or not self.prog.weighted:
            return self
        done = bar.n
        spent = time.time() - self.prog.t0
        pace = spent / done if done > 0 and spent > 0 else 1.0      # seconds a unit, so far
        t0 = time.time()

        def run():
            while not self.stop.wait(self.tick):
                target = min(0.9 * self.units, (time.time() - t0) / pace)
                if target > self.moved:
                    self.prog._advance(target - self.moved)
                    self.moved = target

        self.thread = threading.Thread(target=run, name="sfm-progress", daemon=True)
        self.thread.start()
        return self

    def __exit__(self, *exc):
        if self.thread is not None:
            self.stop.set()
            self.thread.join()
        if exc[0] is None:
            self.prog._advance(self.units - self.moved)
        return False
