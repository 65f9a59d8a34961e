"""The case table of tests/cli/test_fuzz.py: one row per corruption.

A row: ``C(id, base, mutate, argv, expect, names)``. ``base`` is the pristine input copied to
``{d}`` (``colmap_txt``, ``colmap_bin``, ``transforms``, ``llff``, ``run``, ``meshes``, ``masks``,
``empty``; None: an empty folder), ``mutate(d, ctx)`` corrupts the copy, ``argv`` may use ``{d}``,
``{out}`` (a path that does not exist yet) and the pristine bases by name (``{run}``,
``{colmap_txt}``, ...). ``names``: what the error or warning line must contain (each entry a
string or a tuple of alternatives)."""

from __future__ import annotations

import shutil
from dataclasses import dataclass, field

import numpy as np
import pytest

import fuzz_data as fd

TRAIN_FAST = ["--preset", "quick", "--iterations", "30", "--topology", "off", "--no-progress"]
S = "sparse/0"


@dataclass
class C:
    id: str
    base: str | None
    mutate: object
    argv: list
    expect: str                      # "error" | "warn" | "either" | "ok" (exit status 0)
    names: tuple
    check: object = None
    cost: float = 1.0                # relative run time (the slow ones start first)
    marks: list = field(default_factory=list)


def xfail(reason):
    return [pytest.mark.xfail(strict=True, reason=reason)]


# ----------------------------------------------------------------------------------- mutations

def rm(rel):
    def f(d, ctx):
        p = d / rel
        shutil.rmtree(p) if p.is_dir() else p.unlink()
    return f


def write(rel, text):
    def f(d, ctx):
        (d / rel).parent.mkdir(parents=True, exist_ok=True)
        if isinstance(text, bytes):
            (d / rel).write_bytes(text)
        else:
            (d / rel).write_text(text)
    return f


def garbage(rel, n=4096):
    return lambda d, ctx: fd.garbage(d / rel, n)


def truncate(rel, keep=0.5):
    return lambda d, ctx: fd.truncate(d / rel, keep)


def append(rel, data):
    def f(d, ctx):
        with open(d / rel, "ab") as fh:
            fh.write(data)
    return f


def model_txt(**kw):
    return lambda d, ctx: fd.write_colmap_text(d / S, fd.edit_model(ctx.model, **kw))


def model_bin(counts=None, **kw):
    return lambda d, ctx: fd.write_colmap_binary(d / S, fd.edit_model(ctx.model, **kw), counts)


def tf(fn):
    return lambda d, ctx: fd.edit_json(d / "transforms.json", fn)


def setitem(path, value):
    """A transforms.json edit: set ``data[path[0]][path[1]]... = value`` (a None value deletes)."""
    def fn(data):
        obj = data
        for k in path[:-1]:
            obj = obj[k]
        if value is None:
            del obj[path[-1]]
        else:
            obj[path[-1]] = value
    return fn


def llff(fn):
    def f(d, ctx):
        arr = np.load(d / "poses_bounds.npy")
        arr = fn(arr.copy())
        np.save(d / "poses_bounds.npy", arr)
    return f


def llff_set(cols, value):
    def fn(a):
        a[:, cols] = value
        return a
    return fn


def interrupted(fn=None):
    """A run stopped before its end: no mesh.ply / metrics.json; then ``fn`` (another mutation)."""
    def f(d, ctx):
        (d / "mesh.ply").unlink()
        (d / "metrics.json").unlink()
        if fn is not None:
            fn(d, ctx)
    return f


def npz(fn):
    return lambda d, ctx: fd.edit_npz(d / "checkpoint.npz", fn)


def meta(fn):
    return npz(lambda a: fd.edit_meta(a, fn))


def png(rel, w, h):
    return lambda d, ctx: fd.write_png(d / rel, np.zeros((h, w, 3), np.uint8))


def truncate_images_txt(d, ctx):
    """Cut images.txt inside the third image's line, after its quaternion's first values."""
    p = d / S / "images.txt"
    lines = p.read_text().splitlines()
    data = [i for i, ln in enumerate(lines) if not ln.startswith("#")]
    cut = data[4]                                    # image 3's header line
    p.write_text("\n".join(lines[:cut] + [" ".join(lines[cut].split()[:3])]))


def all_images(fn):
    def f(d, ctx):
        for p in sorted((d / "images").iterdir()):
            fn(p)
    return f


def mesh(name, vertices, faces):
    def f(d, ctx):
        writer = fd.write_obj if name.endswith(".obj") else fd.write_ply_ascii
        writer(d / name, vertices, faces)
    return f


NAN_V = [(float("nan"), 0.0, 0.0)] + fd.TETRA_V[1:]


# ----------------------------------------------------------------------------------- checks

def loader_warning_recorded(r):
    """train shows the loader's warning and records it in config.json and metrics.json."""
    cfg = (r.out / "config.json").read_text()
    met = (r.out / "metrics.json").read_text()
    assert "view_003.png" in cfg and "view_003.png" in met, "the loader's warning is not in config.json/metrics.json"


# ----------------------------------------------------------------------------------- the table

INSPECT = ["inspect", "{d}"]
INSPECT_FRUSTA = ["inspect", "{d}", "--points", "frusta"]
TRAIN = ["train", "{d}", "--out", "{out}", *TRAIN_FAST]
TRAIN_P = ["train", "procedural:tiny", "--out", "{out}", *TRAIN_FAST]
RESUME = ["train", "procedural:tiny", "--out", "{d}", "--resume", *TRAIN_FAST]
EXPORT_CKPT = ["export", "{d}/checkpoint.npz", "--out", "{out}/m.ply"]
CT, CB, TXT, BIN = "cameras.txt", "cameras.bin", "images.txt", "images.bin"


def cfg(name, text, *names, expect="error"):
    return C(f"config-{name}", None, write("c.toml", text), [*TRAIN_P, "--config", "{d}/c.toml"], expect,
             ("c.toml", *names))


CASES = [
    # ---- COLMAP, text
    C("colmap-txt-cameras-missing", "colmap_txt", rm(f"{S}/cameras.txt"), INSPECT, "error", (CT,)),
    C("colmap-txt-images-missing", "colmap_txt", rm(f"{S}/images.txt"), INSPECT, "error", (TXT,)),
    C("colmap-txt-points-missing", "colmap_txt", rm(f"{S}/points3D.txt"), INSPECT, "either", ("points3D.txt",)),
    C("colmap-txt-unknown-model", "colmap_txt", write(f"{S}/cameras.txt", "1 FOO 64 48 47 47 32 24\n"), INSPECT,
      "error", (CT, "FOO")),
    C("colmap-txt-equirectangular", "colmap_txt", model_txt(cameras={"model": "EQUIRECTANGULAR", "params": []}),
      INSPECT, "error", (CT, "EQUIRECTANGULAR")),
    C("colmap-txt-few-params", "colmap_txt", write(f"{S}/cameras.txt", "1 PINHOLE 64 48 47\n"), INSPECT, "error",
      (CT,)),
    C("colmap-txt-width-text", "colmap_txt", write(f"{S}/cameras.txt", "1 PINHOLE abc 48 47 47 32 24\n"), INSPECT,
      "error", (CT,)),
    C("colmap-txt-negative-focal", "colmap_txt", model_txt(cameras={"params": [-47.0, -47.0, 32.0, 24.0]}),
      INSPECT, "error", (CT,)),
    C("colmap-txt-zero-width", "colmap_txt", model_txt(cameras={"w": 0}), INSPECT, "error", (CT,)),
    C("colmap-txt-huge-k1", "colmap_txt", model_txt(cameras={"model": "SIMPLE_RADIAL", "params": [47.4, 32, 24, 1e6]}),
      INSPECT, "either", (CT,)),
    C("colmap-txt-cameras-empty", "colmap_txt", write(f"{S}/cameras.txt", "# nothing\n"), INSPECT, "error",
      ((CT, "camera 1"),)),
    C("colmap-txt-cameras-garbage", "colmap_txt", garbage(f"{S}/cameras.txt"), INSPECT, "error", (CT,)),
    C("colmap-txt-zero-quaternion", "colmap_txt", model_txt(image=(1, {"q": (0.0, 0.0, 0.0, 0.0)})), INSPECT,
      "either", (TXT,)),
    C("colmap-txt-nan-translation", "colmap_txt", model_txt(image=(1, {"t": (float("nan"), 0.0, 0.0)})), INSPECT,
      "error", (TXT,)),
    C("colmap-txt-huge-translation", "colmap_txt", model_txt(image=(1, {"t": (1e300, 0.0, 0.0)})), INSPECT,
      "either", (TXT,)),
    C("colmap-txt-unknown-camera-id", "colmap_txt", model_txt(image=(1, {"cid": 7})), INSPECT, "error",
      ((TXT, CT),)),
    C("colmap-txt-pose-text", "colmap_txt", lambda d, ctx: fd.edit_text(d / S / TXT, "\n2 ", "\n2 abc "), INSPECT,
      "error", (TXT,)),
    C("colmap-txt-images-truncated", "colmap_txt", truncate_images_txt, INSPECT, "error", (TXT,)),
    C("colmap-txt-no-images", "colmap_txt", write(f"{S}/images.txt", "# none\n"), INSPECT, "error",
      ((TXT, "points3D.txt"),)),
    C("colmap-txt-points-nan", "colmap_txt", model_txt(point=(0, (float("nan"), 0.0, 0.0))), INSPECT, "either",
      ("points3D.txt",)),
    C("colmap-txt-points-garbage", "colmap_txt", garbage(f"{S}/points3D.txt"), INSPECT, "error", ("points3D.txt",)),
    C("colmap-image-missing", "colmap_txt", rm("images/view_002.png"), INSPECT, "warn", ("view_002.png",)),
    C("colmap-image-garbage", "colmap_txt", garbage("images/view_002.png"), INSPECT, "warn", ("view_002.png",)),
    C("colmap-image-empty", "colmap_txt", write("images/view_002.png", b""), INSPECT, "warn", ("view_002.png",)),
    C("colmap-image-wrong-size", "colmap_txt", png("images/view_002.png", 40, 30), INSPECT, "either",
      ("view_002.png",)),
    C("colmap-all-images-unreadable", "colmap_txt", all_images(lambda p: p.write_bytes(b"x")), INSPECT, "error",
      (("images", "view_000.png"),)),
    C("colmap-images-folder-missing", "colmap_txt", rm("images"), INSPECT, "error", ("images",)),
    C("colmap-downscale-1000", "colmap_txt", None, [*INSPECT, "--downscale", "1000"], "error", ("downscale",)),
    C("colmap-train-downscale-1000", "colmap_txt", None, [*TRAIN, "--downscale", "1000"], "error", ("--downscale",)),
    C("colmap-train-image-missing", "colmap_txt", rm("images/view_003.png"), TRAIN, "warn", ("view_003.png",),
      check=loader_warning_recorded, cost=8),
    C("colmap-train-nan-pose", "colmap_txt", model_txt(image=(2, {"t": (float("nan"), 0.0, 0.0)})), TRAIN, "error",
      (TXT,), cost=2),
    C("colmap-txt-huge-size", "colmap_txt", model_txt(cameras={"w": 10**9, "h": 10**9}), INSPECT, "either", (CT,)),
    C("colmap-image-is-a-folder", "colmap_txt", lambda d, ctx: ((d / "images/view_002.png").unlink(),
                                                              (d / "images/view_002.png").mkdir()),
      INSPECT, "warn", ("view_002.png",)),
    C("colmap-train-images-flag-missing", "colmap_txt", None, [*TRAIN, "--images", "nope"], "error",
      (("--images", "nope"),)),
    C("inspect-background-out-of-range", "colmap_txt", None, [*INSPECT, "--background", "2,0,0"], "error",
      ("background",)),
    C("inspect-split-every0", "colmap_txt", None, [*INSPECT, "--split", "every0"], "error", ("split",)),
    # ---- COLMAP, binary
    C("colmap-bin-cameras-truncated", "colmap_bin", truncate(f"{S}/cameras.bin"), INSPECT, "error", (CB,)),
    C("colmap-bin-images-truncated", "colmap_bin", truncate(f"{S}/images.bin"), INSPECT, "error", (BIN,)),
    C("colmap-bin-points-truncated", "colmap_bin", truncate(f"{S}/points3D.bin"), INSPECT, "error",
      ("points3D.bin",)),
    C("colmap-bin-points-truncated-header", "colmap_bin", truncate(f"{S}/points3D.bin", 0.01), INSPECT, "error",
      ("points3D.bin",)),
    C("colmap-bin-points-huge-count", "colmap_bin", model_bin({"points": 2**40}), INSPECT, "error", ("points3D.bin",)),
    C("colmap-bin-points-huge-track", "colmap_bin", model_bin({"track": 2**40}), INSPECT, "error", ("points3D.bin",)),
    C("colmap-bin-points-trailing-bytes", "colmap_bin", append(f"{S}/points3D.bin", b"\1" * 100), INSPECT, "either",
      ("points3D.bin",)),
    C("colmap-bin-images-huge-points2d", "colmap_bin", model_bin({"points2D": 2**40}), INSPECT, "error", (BIN,)),
    C("colmap-bin-images-huge-count", "colmap_bin", model_bin({"images": 2**33}), INSPECT, "error", (BIN,)),
    C("colmap-bin-cameras-huge-count", "colmap_bin", model_bin({"cameras": 2**40}), INSPECT, "error", (CB,)),
    C("colmap-bin-unknown-model-id", "colmap_bin", model_bin(cameras={"model": 99}), INSPECT, "error", (CB,)),
    C("colmap-bin-cameras-garbage", "colmap_bin", garbage(f"{S}/cameras.bin"), INSPECT, "error", (CB,)),
    C("colmap-bin-cameras-empty", "colmap_bin", write(f"{S}/cameras.bin", b""), INSPECT, "error", (CB,)),
    C("colmap-bin-images-garbage", "colmap_bin", garbage(f"{S}/images.bin"), INSPECT, "error", (BIN,)),
    C("colmap-bin-zero-quaternion", "colmap_bin", model_bin(image=(1, {"q": (0.0, 0.0, 0.0, 0.0)})), INSPECT,
      "either", (BIN,)),
    C("colmap-bin-nan-pose", "colmap_bin", model_bin(image=(1, {"q": (float("nan"), 0.0, 0.0, 0.0)})), INSPECT,
      "error", (BIN,)),
    C("colmap-bin-huge-k1", "colmap_bin", model_bin(cameras={"model": "SIMPLE_RADIAL", "params": [47.4, 32, 24, 1e6]}),
      INSPECT, "either", (CB,)),
    C("colmap-bin-train-points-truncated", "colmap_bin", truncate(f"{S}/points3D.bin"), TRAIN, "error",
      ("points3D.bin",), cost=2),
    # ---- transforms.json
    C("transforms-invalid-json", "transforms", write("transforms.json", "{ not json"), INSPECT, "error",
      ("transforms.json",)),
    C("transforms-binary", "transforms", garbage("transforms.json"), INSPECT, "error", ("transforms.json",)),
    C("transforms-list", "transforms", write("transforms.json", "[1, 2]"), INSPECT, "error", ("transforms.json",)),
    C("transforms-frames-empty", "transforms", tf(setitem(["frames"], [])), INSPECT, "error", ("transforms.json",)),
    C("transforms-frames-missing", "transforms", tf(setitem(["frames"], None)), INSPECT, "error",
      ("transforms.json",)),
    C("transforms-frame-string", "transforms", tf(setitem(["frames", 1], "x")), INSPECT, "error",
      ("transforms.json",)),
    C("transforms-file-path-null", "transforms", tf(setitem(["frames", 1, "file_path"], None)), INSPECT, "error",
      ("transforms.json", "file_path")),
    C("transforms-file-path-number", "transforms", tf(setitem(["frames", 1, "file_path"], 5)), INSPECT, "error",
      ("transforms.json", "file_path")),
    C("transforms-angle-zero", "transforms", tf(setitem(["camera_angle_x"], 0)), INSPECT, "error",
      ("transforms.json", "camera_angle_x")),
    C("transforms-angle-text", "transforms", tf(setitem(["camera_angle_x"], "wide")), INSPECT, "error",
      ("transforms.json", "camera_angle_x")),
    C("transforms-angle-negative", "transforms", tf(setitem(["camera_angle_x"], -1.0)), INSPECT, "error",
      ("transforms.json", "camera_angle_x")),
    C("transforms-angle-over-pi", "transforms", tf(setitem(["camera_angle_x"], 4.0)), INSPECT, "error",
      ("transforms.json", "camera_angle_x")),
    C("transforms-no-focal", "transforms", tf(setitem(["camera_angle_x"], None)), INSPECT, "error",
      ("transforms.json", ("focal", "fl_x", "camera_angle_x"))),
    C("transforms-fl-text", "transforms", tf(setitem(["fl_x"], "abc")), INSPECT, "error", ("transforms.json", "fl_x")),
    C("transforms-fl-zero", "transforms", tf(setitem(["fl_x"], 0)), INSPECT, "error", ("transforms.json", "fl_x")),
    C("transforms-matrix-3x3", "transforms", tf(setitem(["frames", 1, "transform_matrix"], np.eye(3).tolist())),
      INSPECT, "error", ("transforms.json", "transform_matrix")),
    C("transforms-matrix-nan", "transforms", tf(setitem(["frames", 1, "transform_matrix", 0, 3], float("nan"))),
      INSPECT, "error", ("transforms.json",)),
    C("transforms-matrix-text", "transforms", tf(setitem(["frames", 1, "transform_matrix"], "identity")), INSPECT,
      "error", ("transforms.json", "transform_matrix")),
    C("transforms-matrix-zero", "transforms", tf(setitem(["frames", 1, "transform_matrix"], np.zeros((4, 4)).tolist())),
      INSPECT, "error", ("transforms.json",)),
    C("transforms-huge-translation", "transforms", tf(setitem(["frames", 1, "transform_matrix", 0, 3], 1e300)),
      INSPECT_FRUSTA, "either", ("transforms.json",)),
    C("transforms-huge-k1", "transforms", tf(setitem(["k1"], 1e6)), INSPECT_FRUSTA, "either", ("transforms.json",)),
    C("transforms-huge-size", "transforms", tf(lambda t: t.update(w=1e9, h=1e9)), INSPECT_FRUSTA, "either",
      ("transforms.json",)),
    C("transforms-negative-width", "transforms", tf(lambda t: t.update(w=-64, h=48)), INSPECT, "error",
      ("transforms.json",)),
    C("transforms-unknown-model", "transforms", tf(setitem(["camera_model"], "FOO")), INSPECT, "error",
      ("transforms.json", "FOO")),
    C("transforms-image-missing", "transforms", rm("images/view_002.png"), INSPECT_FRUSTA, "warn", ("view_002",)),
    C("transforms-all-images-missing", "transforms", all_images(lambda p: p.unlink()), INSPECT_FRUSTA, "error",
      (("images", "view_000"),)),
    C("transforms-train-angle-zero", "transforms", tf(setitem(["camera_angle_x"], 0)), TRAIN, "error",
      ("transforms.json", "camera_angle_x")),
    # ---- LLFF
    C("llff-garbage", "llff", garbage("poses_bounds.npy"), INSPECT, "error", ("poses_bounds.npy",)),
    C("llff-truncated", "llff", truncate("poses_bounds.npy"), INSPECT, "error", ("poses_bounds.npy",)),
    C("llff-empty", "llff", write("poses_bounds.npy", b""), INSPECT, "error", ("poses_bounds.npy",)),
    C("llff-15-columns", "llff", llff(lambda a: a[:, :15]), INSPECT, "error", ("poses_bounds.npy",)),
    C("llff-count-mismatch", "llff", llff(lambda a: a[:-1]), INSPECT, "error", ("poses_bounds.npy",)),
    C("llff-nan", "llff", llff(llff_set(3, np.nan)), INSPECT, "error", ("poses_bounds.npy",)),
    C("llff-huge-size", "llff", llff(llff_set([4, 9], 1e9)), INSPECT_FRUSTA, "either", ("poses_bounds.npy",)),
    C("llff-zero-focal", "llff", llff(llff_set(14, 0.0)), INSPECT, "error", ("poses_bounds.npy",)),
    C("llff-negative-focal", "llff", llff(llff_set(14, -10.0)), INSPECT, "error", ("poses_bounds.npy",)),
    C("llff-zero-rotation", "llff", llff(llff_set([0, 1, 2, 5, 6, 7, 10, 11, 12], 0.0)), INSPECT, "error",
      ("poses_bounds.npy",)),
    C("llff-huge-translation", "llff", llff(llff_set(3, 1e300)), INSPECT_FRUSTA, "either", ("poses_bounds.npy",)),
    C("llff-negative-bounds", "llff", llff(llff_set([15, 16], -1.0)), INSPECT_FRUSTA, "warn", ("poses_bounds.npy",)),
    C("llff-object-array", "llff", lambda d, ctx: np.save(d / "poses_bounds.npy", np.array([{"a": 1}], object)),
      INSPECT, "error", ("poses_bounds.npy",)),
    C("llff-train-count-mismatch", "llff", llff(lambda a: a[:-1]), TRAIN, "error", ("poses_bounds.npy",)),
    # ---- scene paths
    C("scene-missing", None, None, ["inspect", "{d}/nope"], "error", ("nope",)),
    C("scene-train-missing", None, None, ["train", "{d}/nope", "--out", "{out}", *TRAIN_FAST], "error", ("nope",)),
    C("scene-empty-folder", "empty", None, INSPECT, "error", ("empty",)),
    C("scene-a-file", None, write("notes.txt", "hello"), ["inspect", "{d}/notes.txt"], "error", ("notes.txt",)),
    # ---- videos: tsplus train VIDEO, tsplus frames VIDEO --out DIR
    C("video-junk", None, write("walk.mp4", bytes(range(256)) * 40), ["inspect", "{d}/walk.mp4"], "error",
      ("walk.mp4",)),
    C("video-empty-file", None, write("walk.mov", b""), ["train", "{d}/walk.mov", "--out", "{out}", *TRAIN_FAST],
      "error", ("walk.mov",)),
    C("frames-junk", None, write("walk.mp4", bytes(range(256)) * 40), ["frames", "{d}/walk.mp4", "--out", "{out}"],
      "error", ("walk.mp4",)),
    C("frames-missing", None, None, ["frames", "{d}/nope.mp4", "--out", "{out}"], "error", ("nope.mp4",)),
    C("frames-not-a-video", None, write("notes.txt", "hello"), ["frames", "{d}/notes.txt", "--out", "{out}"],
      "error", ("notes.txt",)),
    C("frames-count-2", None, write("walk.mp4", b"x"), ["frames", "{d}/walk.mp4", "--out", "{out}", "--count", "2"],
      "error", ("--count",)),
    C("frames-out-is-a-file", None, lambda d, ctx: [write("walk.mp4", b"x")(d, ctx), write("f", "x")(d, ctx)],
      ["frames", "{d}/walk.mp4", "--out", "{d}/f"], "error", ("--out",)),
    C("frames-out-not-empty", None, lambda d, ctx: [write("walk.mp4", b"x")(d, ctx), write("o/a.jpg", "x")(d, ctx)],
      ["frames", "{d}/walk.mp4", "--out", "{d}/o"], "error", ("--out",)),
    # ---- HEIC photos (an iPhone's): converted to JPEG in the cache first
    C("heic-junk", None, lambda d, ctx: [write(f"IMG_{i}.HEIC", bytes(range(256)) * 8)(d, ctx) for i in range(3)],
      INSPECT, "error", ("IMG_0.HEIC",)),
    C("heic-empty-train", None, lambda d, ctx: [write(f"IMG_{i}.heic", b"")(d, ctx) for i in range(3)],
      ["train", "{d}", "--out", "{out}", *TRAIN_FAST], "error", ("IMG_0.heic",)),
    # ---- train flags
    C("flag-iterations-0", None, None, [*TRAIN_P, "--iterations", "0"], "error", ("--iterations",)),
    C("flag-iterations-10e12", None, None, [*TRAIN_P, "--iterations", "1000000000000"], "error", ("--iterations",)),
    C("flag-iterations-text", None, None, [*TRAIN_P, "--iterations", "ten"], "error", ("--iterations",)),
    C("flag-max-vertices-negative", None, None, [*TRAIN_P, "--max-vertices", "-5"], "error", ("--max-vertices",)),
    C("flag-log-every-negative", None, None, [*TRAIN_P, "--log-every", "-1"], "error", ("--log-every",)),
    C("flag-densify-stop-nan", None, None, [*TRAIN_P, "--densify-stop", "nan"], "error", ("--densify-stop",)),
    C("flag-densify-stop-inf", None, None, [*TRAIN_P, "--densify-stop", "inf"], "error", ("--densify-stop",)),
    C("flag-checkpoint-every-negative", None, None, [*TRAIN_P, "--checkpoint-every", "-3"], "error",
      ("--checkpoint-every",)),
    C("flag-downscale-0", "colmap_txt", None, [*TRAIN, "--downscale", "0"], "error", ("--downscale",)),
    C("flag-out-empty", None, None, ["train", "procedural:tiny", "--out", "", *TRAIN_FAST], "error", ("--out",)),
    C("flag-out-under-a-file", None, write("f", "x"), ["train", "procedural:tiny", "--out", "{d}/f/sub", *TRAIN_FAST],
      "error", ("--out",)),
    C("flag-out-is-a-file", None, write("f", "x"), ["train", "procedural:tiny", "--out", "{d}/f", *TRAIN_FAST],
      "error", ("--out",)),
    C("flag-out-in-sys", None, None, ["train", "procedural:tiny", "--out", "/sys/tsplus-fuzz/run", *TRAIN_FAST],
      "error", ("--out",)),
    C("flag-out-in-proc", None, None, ["train", "procedural:tiny", "--out", "/proc/tsplus-fuzz", *TRAIN_FAST],
      "error", ("--out",)),
    C("flag-normals-missing", None, None, [*TRAIN_P, "--normals", "{d}/nope"], "error", ("--normals",)),
    C("flag-resume-nothing", None, None, [*TRAIN_P, "--resume"], "error", ("--resume",)),
    C("flag-config-missing", None, None, [*TRAIN_P, "--config", "{d}/nope.toml"], "error", ("--config",)),
    C("flag-seed-text", None, None, [*TRAIN_P, "--seed", "abc"], "error", ("--seed",)),
    # ---- --config files
    cfg("toml-invalid", "iterations = = 3\n"),
    C("config-json-invalid", None, write("c.json", "{iterations: 3"), [*TRAIN_P, "--config", "{d}/c.json"], "error",
      ("c.json",)),
    C("config-json-list", None, write("c.json", "[1, 2]"), [*TRAIN_P, "--config", "{d}/c.json"], "error", ("c.json",)),
    C("config-garbage", None, garbage("c.toml"), [*TRAIN_P, "--config", "{d}/c.toml"], "error", ("c.toml",)),
    C("config-a-folder", None, lambda d, ctx: (d / "c.toml").mkdir(), [*TRAIN_P, "--config", "{d}/c.toml"], "error",
      ("c.toml",)),
    cfg("iterations-text", 'iterations = "ten"\n', "iterations"),
    cfg("iterations-negative", "iterations = -5\n", "iterations"),
    cfg("unknown-table", "[foo]\nx = 1\n", "foo"),
    cfg("unknown-key", "itrations = 3\n", "itrations"),
    cfg("background-out-of-range", "background = [2, 0, 0]\n", "background"),
    cfg("background-text", 'background = "red"\n', "background"),
    cfg("seed-float", "seed = 1.5\n", "seed"),
    cfg("quick-text", 'quick = "yes"\n', "quick"),
    cfg("topology-text", 'topology = "maybe"\n', "topology"),
    cfg("max-vertices-negative", "max_vertices = -5\n", "max_vertices"),
    cfg("sigma-final-nan", "sigma_final = nan\n", "sigma_final"),
    cfg("opacity-unknown", 'opacity = "glass"\n', "opacity"),
    C("config-normals-missing", None, write("c.toml", 'normals = "/nonexistent/normals"\n'),
      [*TRAIN_P, "--config", "{d}/c.toml"], "error", ("normals", "/nonexistent/normals")),
    C("config-json-iterations-float", None, write("c.json", '{"iterations": 3.5}'),
      [*TRAIN_P, "--config", "{d}/c.json"], "error", ("c.json", "iterations")),
    C("normals-file-garbage", None, garbage("view_001.npy"), [*TRAIN_P, "--normals", "{d}"], "error",
      ("view_001.npy",)),
    C("normals-wrong-shape", None, lambda d, ctx: np.save(d / "view_001.npy", np.zeros((5, 3))),
      [*TRAIN_P, "--normals", "{d}"], "error", ("view_001.npy",)),
    # ---- checkpoints
    C("checkpoint-missing-positions", "run", npz(lambda a: a.pop("positions")), EXPORT_CKPT, "error",
      ("checkpoint.npz",)),
    C("checkpoint-truncated", "run", truncate("checkpoint.npz"), EXPORT_CKPT, "error", ("checkpoint.npz",)),
    C("checkpoint-garbage", "run", garbage("checkpoint.npz"), EXPORT_CKPT, "error", ("checkpoint.npz",)),
    C("checkpoint-empty", "run", write("checkpoint.npz", b""), EXPORT_CKPT, "error", ("checkpoint.npz",)),
    C("checkpoint-positions-text", "run", npz(lambda a: a.update(positions=a["positions"].astype(str))), EXPORT_CKPT,
      "error", ("checkpoint.npz",)),
    C("checkpoint-positions-2d", "run", npz(lambda a: a.update(positions=a["positions"][:, :2])), EXPORT_CKPT,
      "error", ("checkpoint.npz",)),
    C("checkpoint-triangles-out-of-range", "run", npz(lambda a: a.update(triangles=a["triangles"] + 10**6)),
      EXPORT_CKPT, "error", ("checkpoint.npz",)),
    C("checkpoint-nan-positions", "run", npz(lambda a: a["positions"].__setitem__(0, np.nan)), EXPORT_CKPT, "either",
      ("checkpoint.npz",)),
    C("checkpoint-no-meta", "run", npz(lambda a: a.pop("meta")), EXPORT_CKPT, "error", ("checkpoint.npz",)),
    C("checkpoint-meta-garbage", "run", npz(lambda a: a.update(meta=np.frombuffer(b"xyz", np.uint8))), EXPORT_CKPT,
      "error", ("checkpoint.npz",)),
    C("checkpoint-meta-no-config", "run", meta(lambda m: m.pop("config")), EXPORT_CKPT, "error", ("checkpoint.npz",)),
    C("checkpoint-run-folder-no-mesh", "run",
      lambda d, ctx: ((d / "mesh.ply").unlink(), fd.truncate(d / "checkpoint.npz")),
      ["export", "{d}", "--out", "{out}/m.ply"], "error", ("checkpoint.npz",)),
    C("checkpoint-view", "run", npz(lambda a: a.pop("logits")),
      ["view", "{d}/checkpoint.npz", "--scene", "procedural:tiny", "--camera", "0", "--screenshot", "{out}/s.png"],
      "error", ("checkpoint.npz",)),
    C("resume-missing-array", "run", interrupted(npz(lambda a: a.pop("logits"))), RESUME, "error",
      ("checkpoint.npz", "logits"), cost=2),
    C("resume-truncated", "run", interrupted(truncate("checkpoint.npz")), RESUME, "error", ("checkpoint.npz",),
      cost=2),
    C("resume-version", "run", interrupted(meta(lambda m: m.update(version=99))), RESUME, "error",
      ("checkpoint.npz",), cost=2),
    C("resume-other-scene", "run", interrupted(), ["train", "{colmap_txt}", "--out", "{d}", "--resume", *TRAIN_FAST],
      "error", ("scene",), cost=2),
    C("resume-other-procedural-size", "run", interrupted(),
      ["train", "procedural:small", "--out", "{d}", "--resume", *TRAIN_FAST], "error", ("scene",), cost=3),
    C("train-over-a-finished-run", "run", None, ["train", "procedural:tiny", "--out", "{d}", *TRAIN_FAST], "error",
      ("--out",)),
    # ---- meshes
    C("mesh-ply-truncated", "meshes", truncate("good.ply", 0.6), ["export", "{d}/good.ply", "--out", "{out}/m.glb"],
      "error", ("good.ply",)),
    C("mesh-ply-garbage", "meshes", garbage("good.ply"), ["export", "{d}/good.ply", "--out", "{out}/m.glb"], "error",
      ("good.ply",)),
    C("mesh-ply-empty", "meshes", write("good.ply", b""), ["export", "{d}/good.ply", "--out", "{out}/m.glb"], "error",
      ("good.ply",)),
    C("mesh-ply-no-faces", "meshes", mesh("good.ply", fd.TETRA_V, []),
      ["export", "{d}/good.ply", "--out", "{out}/m.glb"], "error", ("good.ply",)),
    C("mesh-ply-nan-vertex", "meshes", mesh("good.ply", NAN_V, fd.TETRA_F),
      ["export", "{d}/good.ply", "--out", "{out}/m.glb"], "error", ("good.ply",)),
    C("mesh-ply-index-out-of-range", "meshes", mesh("good.ply", fd.TETRA_V, [(0, 1, 99)]),
      ["export", "{d}/good.ply", "--out", "{out}/m.glb"], "error", ("good.ply",)),
    C("mesh-glb-truncated", "meshes", truncate("good.glb"), ["export", "{d}/good.glb", "--out", "{out}/m.ply"],
      "error", ("good.glb",)),
    C("mesh-glb-garbage", "meshes", garbage("good.glb"), ["export", "{d}/good.glb", "--out", "{out}/m.ply"], "error",
      ("good.glb",)),
    C("mesh-obj-garbage", "meshes", garbage("good.obj"), ["export", "{d}/good.obj", "--out", "{out}/m.ply"], "error",
      ("good.obj",)),
    C("mesh-obj-no-faces", "meshes", mesh("good.obj", fd.TETRA_V, []),
      ["export", "{d}/good.obj", "--out", "{out}/m.ply"], "error", ("good.obj",)),
    C("mesh-obj-nan-vertex", "meshes", mesh("good.obj", NAN_V, fd.TETRA_F),
      ["export", "{d}/good.obj", "--out", "{out}/m.ply"], "error", ("good.obj",)),
    C("mesh-unknown-suffix", "meshes", lambda d, ctx: (d / "good.ply").rename(d / "good.xyz"),
      ["export", "{d}/good.xyz", "--out", "{out}/m.ply"], "error", ("good.xyz",)),
    C("mesh-export-unknown-format", "meshes", None, ["export", "{d}/good.ply", "--format", "fbx", "--out", "{out}/m"],
      "error", ("--format",)),
    C("mesh-export-out-under-a-file", "meshes", None, ["export", "{d}/good.ply", "--out", "{d}/good.obj/m.glb"],
      "error", ("--out",)),
    C("mesh-view-no-faces", "meshes", mesh("good.ply", fd.TETRA_V, []),
      ["view", "{d}/good.ply", "--scene", "procedural:tiny", "--camera", "0", "--screenshot", "{out}/s.png"], "error",
      ("good.ply",)),
    C("mesh-view-nan-vertex", "meshes", mesh("good.ply", NAN_V, fd.TETRA_F),
      ["view", "{d}/good.ply", "--scene", "procedural:tiny", "--camera", "0", "--screenshot", "{out}/s.png"], "error",
      ("good.ply",)),
    C("mesh-eval-no-faces", "meshes", mesh("good.ply", fd.TETRA_V, []),
      ["eval", "{d}/good.ply", "procedural:tiny", "--out", "{out}", "--no-splat", "--supersample", "1"], "error",
      ("good.ply",)),
    C("mesh-eval-garbage", "meshes", garbage("good.glb"),
      ["eval", "{d}/good.glb", "procedural:tiny", "--out", "{out}", "--no-splat", "--supersample", "1"], "error",
      ("good.glb",)),
    C("mesh-ply-huge-count", "meshes", lambda d, ctx: fd.edit_text(d / "good.ply", "element vertex 4",
                                                                      "element vertex 1000000000000"),
      ["export", "{d}/good.ply", "--out", "{out}/m.glb"], "error", ("good.ply",)),
    C("mesh-ply-binary-huge-count", "meshes", write("good.ply", b"ply\nformat binary_little_endian 1.0\n"
                                                   b"element vertex 1000000000000\nproperty float x\n"
                                                   b"property float y\nproperty float z\nelement face 1\n"
                                                   b"property list uchar int vertex_indices\nend_header\n"
                                                   + b"\0" * 64),
      ["export", "{d}/good.ply", "--out", "{out}/m.glb"], "error", ("good.ply",)),
    C("run-config-garbage-eval", "run", garbage("config.json"), ["eval", "{d}", "--out", "{out}", "--no-splat",
                                                                "--supersample", "1"], "error", ("config.json",)),
    C("export-bake-views-scene-missing", None, None,
      ["export", "{run}", "--bake", "views", "--scene", "{d}/nope", "--out", "{out}/m.glb"], "error", ("nope",)),
    C("view-scene-missing", None, None, ["view", "{run}", "--scene", "{d}/nope", "--screenshot", "{out}/s.png"],
      "error", ("nope",)),
    C("eval-normals-missing", None, None,
      ["eval", "{run}", "procedural:tiny", "--out", "{out}", "--normals", "{d}/nope"], "error", ("--normals",)),
    C("view-camera-out-of-range", None, None,
      ["view", "{run}", "--scene", "procedural:tiny", "--camera", "99", "--screenshot", "{out}/s.png"], "error",
      ("--camera",)),
    C("view-size-text", None, None, ["view", "{run}", "--size", "abc", "--screenshot", "{out}/s.png"], "error",
      ("--size",)),
    C("view-size-zero", None, None, ["view", "{run}", "--size", "0x0", "--screenshot", "{out}/s.png"], "error",
      ("--size",)),
    C("eval-scene-missing", None, None, ["eval", "{run}", "{d}/nope", "--out", "{out}"], "error", ("nope",)),
    C("eval-supersample-0", None, None, ["eval", "{run}", "procedural:tiny", "--out", "{out}", "--supersample", "0"],
      "error", ("--supersample",)),
    # ---- masks
    C("masks-wrong-size", "masks", png("view_001.png", 10, 10), ["select", "{run}", "--masks", "{d}", "--out", "{out}"],
      "either", ("view_001.png",), cost=2),
    C("masks-unreadable", "masks", garbage("view_001.png"), ["select", "{run}", "--masks", "{d}", "--out", "{out}"],
      "either", ("view_001.png",), cost=2),
    C("masks-empty-file", "masks", write("view_001.png", b""), ["select", "{run}", "--masks", "{d}", "--out", "{out}"],
      "either", ("view_001.png",), cost=2),
    C("masks-folder-missing", None, None, ["select", "{run}", "--masks", "{d}/nope", "--out", "{out}"], "error",
      ("--masks",)),
    C("masks-no-name-matches", "masks",
      lambda d, ctx: [p.rename(p.with_name("x" + p.name)) for p in sorted(d.iterdir())],
      ["select", "{run}", "--masks", "{d}", "--out", "{out}"], "error", ("--masks",)),
    C("masks-all-zero", "masks", lambda d, ctx: [fd.write_png(p, np.zeros((48, 64), np.uint8)) for p in d.iterdir()],
      ["select", "{run}", "--masks", "{d}", "--out", "{out}"], "error", ("--masks",), cost=2),
    C("masks-vote-0", "masks", None, ["select", "{run}", "--masks", "{d}", "--out", "{out}", "--vote", "0"], "error",
      ("--vote",)),
    # ---- more
    C("command-unknown", None, None, ["nope"], "error", ("nope",)),
    C("flag-preset-unknown", None, None, [*TRAIN_P, "--preset", "fast"], "error", ("--preset",)),
    C("colmap-bin-nan-focal", "colmap_bin", model_bin(cameras={"params": [float("nan"), 47.0, 32.0, 24.0]}), INSPECT,
      "error", (CB,)),
    C("colmap-image-in-missing-subfolder", "colmap_txt", model_txt(image=(1, {"name": "sub/view_001.png"})), INSPECT,
      "warn", ("view_001.png",)),
    C("transforms-frame-fl-nan", "transforms", tf(setitem(["frames", 1, "fl_x"], float("nan"))), INSPECT, "error",
      ("transforms.json", "fl_x")),
    C("mesh-ply-negative-index", "meshes", mesh("good.ply", fd.TETRA_V, [(0, 1, -2)]),
      ["export", "{d}/good.ply", "--out", "{out}/m.glb"], "error", ("good.ply",)),
    C("mesh-glb-empty", "meshes", write("good.glb", b""), ["export", "{d}/good.glb", "--out", "{out}/m.ply"], "error",
      ("good.glb",)),
    C("run-mesh-garbage-view", "run", garbage("mesh.ply"), ["view", "{d}", "--camera", "0", "--screenshot",
                                                            "{out}/s.png"], "error", ("mesh.ply",)),
    C("run-folder-empty-export", "empty", None, ["export", "{d}", "--out", "{out}/m.ply"], "error",
      (("no mesh.ply", "not a tsplus run", "mesh.ply"),)),
    C("colmap-bin-points-nan", "colmap_bin", model_bin(point=(0, (float("nan"), 0.0, 0.0))), INSPECT, "warn",
      ("points3D.bin",)),
    C("colmap-txt-duplicate-image-id", "colmap_txt", lambda d, ctx: fd.edit_text(d / S / TXT, "\n2 ", "\n1 "),
      INSPECT, "error", (TXT,)),
    C("eval-downscale-1000", None, None, ["eval", "{run}", "{colmap_txt}", "--out", "{out}", "--downscale", "1000"],
      "error", ("--downscale",)),
    C("select-scene-missing", None, None,
      ["select", "{run}", "--masks", "{masks}", "--scene", "{d}/nope", "--out", "{out}"], "error", ("nope",)),
]

assert len({c.id for c in CASES}) == len(CASES), "duplicate case ids"

#: case id -> why it fails, for a fix that has not landed (strict xfail: a case that starts to pass fails the
#: suite, so that its entry is removed)
KNOWN_FAILURES: dict = {}
for _c in CASES:
    if _c.id in KNOWN_FAILURES:
        _c.marks = xfail(KNOWN_FAILURES[_c.id])
assert set(KNOWN_FAILURES) <= {c.id for c in CASES}
__all__ = ["CASES", "TRAIN_FAST"]
