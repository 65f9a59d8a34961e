"""Fuzz test of every command against bad input (issue 15): copies of tiny scenes, runs, meshes,
checkpoints, configs and masks, each corrupted in one way, each run as its own ``tsplus``
process. Each case expects one of:

- ``error``: exit status 2, ONE line ``tsplus[ COMMAND]: error: ...`` on stderr (``warning:``
  lines may precede it) naming the culprit, no traceback, no file left under ``--out``;
- ``warn``: exit status 0 and a warning line (``warning: ...`` or an item of inspect's
  ``warnings:`` list) naming the culprit;
- ``either``: one of the two (the issue allows a warning or an error, never silence).

The table is in fuzz_cases.py. The cases run in parallel, each in its own process forked from one
that imported the package once (tests/cli/fuzz_server.py; fixture ``results``, once a session). Also here:
export, view --screenshot and select on a full disk (a small tmpfs; root only). The SIGTERM,
read-only and train/eval disk-full tests are in tests/cli/test_run_safety.py."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
import fuzz_data as fd  # noqa: E402
from fuzz_cases import CASES, TRAIN_FAST  # noqa: E402
from scenes import child_env  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
ERROR_LINE = re.compile(r"^tsplus(?: [\w-]+)?: error: ")
CASE_TIMEOUT = 120
MEMORY_LIMIT = 6 * 2**30          # a case that allocates more (pycolmap on a bad count) fails fast


def cli(*argv, env=None, cwd=None, timeout=CASE_TIMEOUT):
    """Run ``python -m tsplus_wgpu.cli ARGV`` under a memory limit; the CompletedProcess."""
    cmd = [sys.executable, "-m", "tsplus_wgpu.cli", *argv]
    if shutil.which("prlimit"):
        cmd = ["prlimit", f"--as={MEMORY_LIMIT}", "--", *cmd]
    try:
        return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env, cwd=cwd or ROOT)
    except subprocess.TimeoutExpired as exc:
        return subprocess.CompletedProcess(cmd, -999, exc.stdout or "", f"TIMEOUT after {timeout} s")


def cli_env(cache):
    env = child_env(ROOT, XDG_CACHE_HOME=str(cache), TSPLUS_CACHE=str(cache), NO_COLOR="1")
    env.setdefault("XDG_RUNTIME_DIR", "/tmp/xdg")
    return env


# ----------------------------------------------------------------------------------- fixtures

def _build_bases(base: Path, env):
    """The pristine inputs every case copies: scenes, a trained run, meshes, masks."""
    views = fd.procedural_views()
    model = fd.make_colmap(base / "colmap_txt", views, binary=False)
    fd.make_colmap(base / "colmap_bin", views, binary=True)
    fd.make_transforms(base / "transforms", views)
    fd.make_llff(base / "llff", views)
    (base / "empty").mkdir()
    meshes = base / "meshes"
    meshes.mkdir()
    fd.write_ply_ascii(meshes / "good.ply", fd.TETRA_V, fd.TETRA_F)
    fd.write_obj(meshes / "good.obj", fd.TETRA_V, fd.TETRA_F)
    import trimesh
    trimesh.Trimesh(np.array(fd.TETRA_V), np.array(fd.TETRA_F), process=False).export(meshes / "good.glb")
    from tsplus_wgpu.data.procedural import load_procedural
    sc = load_procedural("tiny")
    ids, counts = np.unique(np.concatenate([m.ravel() for m in sc.masks]), return_counts=True)
    obj = int(ids[np.argsort(counts)[len(counts) // 2]])           # a middle-sized object
    for name, m in zip(sc.image_names, sc.masks):
        fd.write_png(base / "masks" / name, ((m == obj) * 255).astype(np.uint8))
    # the pristine run every run case copies: setup, not a case, so not held to CASE_TIMEOUT (it
    # took over 120 s once, beside two training runs on the 2 cores, and failed all 217 cases)
    out = cli("train", "procedural:tiny", "--out", str(base / "run"), *TRAIN_FAST, env=env, timeout=900)
    assert out.returncode == 0, out.stderr
    return SimpleNamespace(base=base, views=views, model=model, env=env,
                           paths={k: str(base / k) for k in ("colmap_txt", "colmap_bin", "transforms", "llff",
                                                              "empty", "meshes", "masks", "run")})


# Session-scoped, not module-scoped: under pytest-xdist's --dist loadgroup a worker may run another
# module's test between two fuzz cases, and a module fixture would then be torn down and every case
# run again (the suite at -n 2 --dist loadgroup ran ``results`` twice, 99 s and 87 s).
@pytest.fixture(scope="session")
def bases(tmp_path_factory):
    root = tmp_path_factory.mktemp("fuzz")
    return _build_bases(root / "base", cli_env(root / "cache"))


def _prepare(case, k, ctx):
    work = ctx.base.parent / f"c{k:03d}"            # no case name in the path: culprits must come from the message
    d, out = work / "d", work / "out"
    if case.base:
        shutil.copytree(ctx.base / case.base, d)
    else:
        d.mkdir(parents=True)
    if case.mutate is not None:
        case.mutate(d, ctx)
    argv = [a.format(d=d, out=out, **ctx.paths) for a in case.argv]
    return d, out, argv


@pytest.fixture(scope="session")
def results(request):
    """Every selected case run once, in parallel forked children of tests/cli/fuzz_server.py:
    case id -> result (``proc``: returncode, stdout, stderr)."""
    main_argv = getattr(request.config, "workerinput", {}).get("mainargv") or []   # a worker's own option is "no"
    if os.environ.get("PYTEST_XDIST_WORKER") and not any(a.split("=")[-1] in ("loadgroup", "loadfile")
                                                         for a in main_argv):
        pytest.skip("under pytest-xdist every worker would run every fuzz case: add --dist loadfile (or loadgroup)")
    bases = request.getfixturevalue("bases")
    wanted = {item.callspec.params["case"].id for item in request.session.items
              if getattr(item, "originalname", None) == "test_fuzz" and Path(str(item.fspath)) == Path(__file__)}
    todo = sorted(((k, c) for k, c in enumerate(CASES) if c.id in wanted), key=lambda kc: -kc[1].cost)
    jobs, prepared = [], {}
    for k, case in todo:
        d, out, argv = _prepare(case, k, bases)
        log = str(d.parent / "log")
        jobs.append(dict(id=case.id, argv=argv, stdout=log + ".out", stderr=log + ".err"))
        prepared[case.id] = (d, out, argv, log)
    workers = max(2, min(4, (os.cpu_count() or 2) + 1))
    req = json.dumps(dict(jobs=jobs, workers=workers, timeout=CASE_TIMEOUT, memory=MEMORY_LIMIT))
    server = subprocess.run([sys.executable, str(Path(__file__).with_name("fuzz_server.py"))], input=req,
                            capture_output=True, text=True, env=bases.env, cwd=ROOT, timeout=1200)
    assert server.returncode == 0, server.stderr[-3000:]
    answers = json.loads(server.stdout)
    done = {}
    for cid, (d, out, argv, log) in prepared.items():
        proc = subprocess.CompletedProcess(argv, answers[cid]["rc"], Path(log + ".out").read_text(errors="replace"),
                                           Path(log + ".err").read_text(errors="replace"))
        done[cid] = SimpleNamespace(proc=proc, d=d, out=out, argv=argv, seconds=answers[cid]["seconds"])
    slow = sorted(done.items(), key=lambda kv: -kv[1].seconds)[:8]
    print("\nslowest fuzz cases: " + ", ".join(f"{cid} {r.seconds:.1f} s" for cid, r in slow))
    return done


# ----------------------------------------------------------------------------------- checks

def _mentions(line, names):
    """Every entry of ``names`` (a string, or a tuple of alternatives) occurs in ``line``."""
    return all(any(n in line for n in ((alt,) if isinstance(alt, str) else alt)) for alt in names)


def _warning_lines(proc):
    lines = (proc.stdout + "\n" + proc.stderr).splitlines()
    return [ln.strip() for ln in lines if ln.startswith("warning:") or ln.startswith("  - ")]


def _error_problem(r, names):
    """What is wrong with ``r`` as a one-line error naming ``names``, or None."""
    p = r.proc
    lines = [ln for ln in p.stderr.splitlines() if ln.strip() and not ln.startswith("warning:")]
    if p.returncode != 2:
        return f"exit status {p.returncode}, expected 2"
    if len(lines) != 1 or not ERROR_LINE.match(lines[0]):
        return f"expected one 'tsplus: error:' line on stderr, got {len(lines)} line(s)"
    if not _mentions(lines[0], names):
        return f"the error line does not name {names}"
    if r.argv[0] == "train" and str(r.out) in r.argv and r.out.exists():
        return f"train failed but left its --out folder {r.out}"
    if r.out.exists():
        left = [str(f.relative_to(r.out)) for f in r.out.rglob("*") if f.is_file()]
        if left:
            return f"files left under --out after the error: {left}"
    return None


def _warn_problem(r, names):
    p = r.proc
    if p.returncode != 0:
        return f"exit status {p.returncode}, expected 0 with a warning"
    if not any(_mentions(w, names) for w in _warning_lines(p)):
        return f"no warning line names {names}"
    return None


#: every case on one pytest-xdist worker (with ``--dist loadgroup``; ``loadfile``, ci/test.sh's, keeps the
#: whole file on one anyway): ``results`` runs every selected case once per process, so twelve workers
#: would run all of them twelve times over
ONE_WORKER = pytest.mark.xdist_group("fuzz")


def _marks(case):
    own = case.marks if isinstance(case.marks, (list, tuple)) else [case.marks]
    return [*own, ONE_WORKER]


@pytest.mark.parametrize("case", [pytest.param(c, id=c.id, marks=_marks(c)) for c in CASES])
def test_fuzz(case, results):
    r = results[case.id]
    p = r.proc
    shown = (f"tsplus {' '.join(r.argv)}\n-> exit {p.returncode} in {r.seconds:.1f} s\n--- stderr:\n"
             f"{p.stderr[-3000:]}\n--- stdout:\n{p.stdout[-1500:]}")
    assert "Traceback" not in p.stderr + p.stdout, shown
    assert p.returncode != -999, shown
    if case.expect == "error":
        problem = _error_problem(r, case.names)
    elif case.expect == "warn":
        problem = _warn_problem(r, case.names)
    elif case.expect == "ok":
        problem = None if p.returncode == 0 else f"exit status {p.returncode}, expected 0"
    else:
        e, w = _error_problem(r, case.names), _warn_problem(r, case.names)
        problem = None if e is None or w is None else f"neither a one-line error ({e}) nor a warning ({w})"
    assert problem is None, f"{problem}\n{shown}"
    for where in (r.d, r.out):
        if where.exists():
            tmp = [str(f) for f in where.rglob("*.tmp*")]
            assert not tmp, f"temporary files left: {tmp}\n{shown}"
    if case.check is not None:
        case.check(r)


# ----------------------------------------------------------------------------------- disk full, read-only

def _mount_tmpfs(path: Path, size: str) -> bool:
    path.mkdir(parents=True, exist_ok=True)
    if os.geteuid() != 0 or not shutil.which("mount"):
        return False
    p = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)], capture_output=True)
    return p.returncode == 0


def _umount(path: Path):
    subprocess.run(["umount", "-l", str(path)], capture_output=True)


def _fill(path: Path):
    """Fill the file system holding ``path`` to the last byte."""
    fd = os.open(path / "filler", os.O_WRONLY | os.O_CREAT)
    try:
        for block in (65536, 4096, 1):
            try:
                while True:
                    os.write(fd, b"\0" * block)
            except OSError:
                pass
    finally:
        os.close(fd)


def _one_error_line(proc, *names):
    assert "Traceback" not in proc.stderr + proc.stdout, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip() and not ln.startswith("warning:")]
    assert proc.returncode == 2 and len(lines) == 1 and ERROR_LINE.match(lines[0]), proc.stderr
    assert _mentions(lines[0], names), proc.stderr


def _complete_files(folder: Path):
    """Every file in ``folder`` is whole: no temporaries, no empty files, JSON / PLY / NPZ / PNG readable."""
    import trimesh
    from PIL import Image
    for f in folder.rglob("*"):
        if not f.is_file() or f.name.startswith("filler"):
            continue
        assert ".tmp" not in f.name, f
        assert f.stat().st_size > 0, f
        if f.suffix == ".json":
            json.loads(f.read_text())
        elif f.suffix == ".jsonl":
            for ln in f.read_text().splitlines():
                json.loads(ln)
        elif f.suffix == ".npz":
            with np.load(f) as z:
                [z[k] for k in z.files]
        elif f.suffix == ".ply":
            assert len(trimesh.load(f, process=False).faces) > 0, f
        elif f.suffix == ".png":
            Image.open(f).load()


@ONE_WORKER      # it shares ``bases`` with the fuzz cases: one worker builds them
def test_disk_full_leaves_nothing_at_the_target(bases, tmp_path):
    """export, view --screenshot and select on a full disk: one line, nothing at the target path,
    no temporary file (train and eval on a full disk and a read-only --out: tests/cli/test_run_safety.py)."""
    full = tmp_path / "full"
    if not _mount_tmpfs(full, "64k"):
        pytest.skip("cannot mount a tmpfs here (needs root)")
    try:
        _fill(full)
        env, run = bases.env, bases.paths["run"]
        for argv, target in (
                (["export", run, "--format", "glb", "--out", str(full / "m.glb")], full / "m.glb"),
                (["view", run, "--camera", "0", "--screenshot", str(full / "s.png")], full / "s.png"),
                (["select", run, "--masks", bases.paths["masks"], "--out", str(full / "sel")], full / "sel")):
            p = cli(*argv, env=env)
            _one_error_line(p, ("disk full", "no space left"))
            assert not target.exists() or (target.is_dir() and not any(f.is_file() for f in target.rglob("*"))), \
                f"{argv[0]}: {target} left behind"
            _complete_files(full)
    finally:
        _umount(full)
