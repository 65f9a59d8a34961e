"""``tsplus frames VIDEO --out DIR``: the sharpest frames of a video as a folder of photos.

``tsplus train VIDEO`` does the same into the cache with :data:`~tsplus_wgpu.data.video.DEFAULT_FRAMES`
frames; this command picks the number and keeps the folder where the user wants it.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import UserError


def add_parser(subparsers) -> argparse.ArgumentParser:
    from ..data.video import DEFAULT_FRAMES, VIDEO_EXTENSIONS
    p = subparsers.add_parser(
        "frames", help="the sharpest frames of a video as a folder of photos, ready for `tsplus train DIR`",
        description="Cut a video into COUNT windows of equal length and write the sharpest frame of each "
                    "(the variance of the Laplacian of its grey image) to OUT as frame_NNNNNN.jpg (N: the frame's "
                    "index in the video), with frames.json naming the video and the frames kept. `tsplus train "
                    "OUT` then runs SfM on them, matching each frame with its neighbours in time. `tsplus train "
                    f"VIDEO` does the same with {DEFAULT_FRAMES} frames, kept in the cache. Reads "
                    + ", ".join(VIDEO_EXTENSIONS) + " (whatever OpenCV's FFmpeg decodes).")
    p.add_argument("video", help="the video file")
    p.add_argument("--out", required=True, metavar="DIR", help="folder to write the frames to (must not hold files, "
                                                                  "unless --overwrite)")
    p.add_argument("--count", type=int, default=DEFAULT_FRAMES,
                   help=f"frames to keep (default {DEFAULT_FRAMES}; all of them when the video has fewer). More "
                        "frames: more views to train on and a slower SfM")
    p.add_argument("--overwrite", action="store_true", help="replace what OUT holds")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    import shutil

    from ..data.video import extract_frames, is_video
    video, out = Path(args.video).expanduser(), Path(args.out).expanduser()
    if not video.is_file():
        raise UserError(f"{video}: no such video file; check the path")
    if not is_video(video):
        raise UserError(f"{video}: not a video file by its name (expected .mp4, .mov, ...); give a video, or train "
                        "on a folder of photos directly")
    if args.count < 3:
        raise UserError(f"--count {args.count}: SfM needs at least 3 frames; ask for 3 or more")
    if out.exists() and not out.is_dir():
        raise UserError(f"--out {out}: is a file; give a folder")
    if out.is_dir() and any(out.iterdir()):
        if not args.overwrite:
            raise UserError(f"--out {out}: the folder is not empty; choose another or add --overwrite")
    new = out.parent / f".{out.name}.new"
    shutil.rmtree(new, ignore_errors=True)     # left by a run killed at its last step
    manifest = extract_frames(video, new, args.count, progress=not args.no_progress)
    if out.is_dir():
        shutil.rmtree(out)
    new.rename(out)
    n, k = manifest["frames_decoded"], len(manifest["frames"])
    print(f"wrote {k} frames of {video.name} to {out} (the sharpest of each window of about {n / k:.1f} of its {n} "
          f"frames); next: tsplus train {out} --out RUN")
    return 0
