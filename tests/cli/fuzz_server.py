"""Run many ``tsplus`` command lines, each in its own forked child process, from one process that
has imported the package once (``python -m tsplus_wgpu.cli`` costs ~0.7 s of imports per run;
the fuzz test has ~180 of them).

A child does what ``python -m tsplus_wgpu.cli ARGV`` does: ``sys.exit(main(ARGV))`` with stdout
and stderr going to files, an uncaught exception printed as a traceback, atexit handlers run,
and the exit status kept. The request (JSON on stdin): ``{"jobs": [{"id", "argv", "stdout",
"stderr"}], "workers": N, "timeout": S, "memory": BYTES}``; the answer (JSON on stdout): ``{id:
{"rc", "seconds"}}``, rc -999 for a child killed at the timeout.

Usage: ``python tests/cli/fuzz_server.py < request.json``."""

from __future__ import annotations

import atexit
import json
import os
import resource
import signal
import sys
import time
import traceback


def _preload():
    """Import what the commands import, without touching a GPU (no adapter before a fork)."""
    import numpy  # noqa: F401
    import PIL.Image  # noqa: F401
    import scipy.spatial  # noqa: F401
    import trimesh  # noqa: F401
    from tsplus_wgpu.cli.main import build_parser, command_module, COMMANDS
    build_parser()
    for name in COMMANDS:
        command_module(name)
    for mod in ("pycolmap", "tsplus_wgpu.data", "tsplus_wgpu.data.loader", "tsplus_wgpu.data.colmap",
                "tsplus_wgpu.data.procedural", "tsplus_wgpu.apps.runs", "tsplus_wgpu.io.export",
                "tsplus_wgpu.train.trainer", "tsplus_wgpu.render.renderer"):
        try:
            __import__(mod)
        except ImportError:
            pass


def _child(job, memory):
    """In the forked child: run the command line; never returns."""
    rc = 1
    try:
        if memory:
            resource.setrlimit(resource.RLIMIT_AS, (memory, memory))
        out = os.open(job["stdout"], os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        err = os.open(job["stderr"], os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        os.dup2(out, 1)
        os.dup2(err, 2)
        os.close(out)
        os.close(err)
        sys.stdin = open(os.devnull)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        signal.signal(signal.SIGINT, signal.default_int_handler)
        sys.argv = ["tsplus", *job["argv"]]
        from tsplus_wgpu.cli.main import main
        try:
            code = main(job["argv"])
        except SystemExit as exc:
            code = exc.code
        rc = code if isinstance(code, int) else (0 if code is None else 1)
        if not isinstance(code, int) and code is not None:
            print(code, file=sys.stderr)
    except BaseException:                 # what the interpreter would print for an uncaught exception
        traceback.print_exc()
        rc = 1
    finally:
        try:
            atexit._run_exitfuncs()
            sys.stdout.flush()
            sys.stderr.flush()
        finally:
            os._exit(rc & 0xFF)


def serve(request):
    jobs = list(request["jobs"])
    workers, timeout, memory = int(request.get("workers", 2)), float(request.get("timeout", 120)), \
        request.get("memory")
    running, results = {}, {}
    sys.stdout.flush()
    sys.stderr.flush()
    while jobs or running:
        while jobs and len(running) < workers:
            job = jobs.pop(0)
            pid = os.fork()
            if pid == 0:
                _child(job, memory)
            running[pid] = (job, time.perf_counter())
        pid, status = os.waitpid(-1, os.WNOHANG)
        if pid == 0:
            now = time.perf_counter()
            for p, (job, t0) in list(running.items()):
                if now - t0 > timeout:
                    os.kill(p, signal.SIGKILL)
                    os.waitpid(p, 0)
                    results[job["id"]] = {"rc": -999, "seconds": now - t0}
                    del running[p]
            time.sleep(0.02)
            continue
        job, t0 = running.pop(pid)
        rc = os.waitstatus_to_exitcode(status)
        results[job["id"]] = {"rc": rc, "seconds": time.perf_counter() - t0}
    return results


if __name__ == "__main__":
    req = json.load(sys.stdin)
    _preload()
    json.dump(serve(req), sys.stdout)
