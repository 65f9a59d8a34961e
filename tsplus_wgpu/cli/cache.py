"""``tsplus cache``: what the user cache holds (SfM models, triangulated points, a video's frames,
JPEG copies of HEIC photos), and ``--clean`` to free the space (:mod:`tsplus_wgpu.data.cache`)."""

from __future__ import annotations

import argparse
import shutil
import time

from ..errors import UserError


def add_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "cache", help="what the cache of SfM models, triangulated points and video frames holds; --clean frees it",
        description="Lists the cache that `tsplus train`, `eval` and `inspect` keep so that a scene's SfM, "
                    "triangulation, video frames and HEIC conversion run once (the folder is $TSPLUS_CACHE, else "
                    "$XDG_CACHE_HOME/tsplus_wgpu, else ~/.cache/tsplus_wgpu): each entry's kind, whether it is "
                    "finished, its size, when it was last used and what it was made from. With --clean: removes "
                    "the unfinished entries that stopped or failed jobs left (never one changed in the last hour: "
                    "a running job's) and the intermediate files of finished ones; --older-than and --all remove "
                    "finished entries too. A removed entry is only made again when a scene needs it.")
    p.add_argument("--clean", action="store_true", help="remove unfinished entries and intermediate files")
    p.add_argument("--older-than", type=float, default=None, metavar="DAYS",
                   help="with --clean: also remove the finished entries unused for more than DAYS days")
    p.add_argument("--all", action="store_true", help="with --clean: remove every entry (but a running job's)")
    p.add_argument("--dry-run", action="store_true", help="with --clean: say what would be removed, remove nothing")
    p.set_defaults(func=run)
    return p


def _row(e, now):
    from ..data.cache import KINDS, human_size
    state = "finished" if e.finished else "unfinished"
    if e.spare:
        state += f" (+{human_size(e.spare)} spare)"
    days = (now - e.used) / 86400.0
    used = "today" if days < 1 else f"{days:.0f} days ago"
    return [e.path.name, KINDS[e.kind], state, human_size(e.size), used, e.source or "?"]


def _table(rows):
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]) - 1)]
    return ["  ".join(c.ljust(w) for c, w in zip(r, widths)) + "  " + r[-1] for r in rows]


def run(args) -> int:
    from ..data.cache import human_size, list_entries, plan_clean, trim
    from ..data.sfm import cache_root
    if args.older_than is not None and not args.older_than >= 0:
        raise UserError(f"--older-than {args.older_than}: give a number of days, 0 or more")
    if (args.older_than is not None or args.all or args.dry_run) and not args.clean:
        raise UserError("--older-than, --all and --dry-run go with --clean; add --clean")
    root, note = cache_root()
    if note:
        print(f"note: {note}")
    entries, now = list_entries(root), time.time()
    total = sum(e.size for e in entries)
    print(f"cache: {root} ({len(entries)} entries, {human_size(total)}; TSPLUS_CACHE moves it)")
    if entries and not args.clean:
        head = ["entry", "holds", "state", "size", "last used", "made from"]
        print("\n".join(_table([head] + [_row(e, now) for e in entries])))
    if not args.clean:
        remove, trims, _ = plan_clean(entries)
        free = sum(e.size for e, _ in remove) + sum(e.spare for e in trims)
        if free:
            print(f"`tsplus cache --clean` frees {human_size(free)} (unfinished entries, intermediate files)")
        return 0
    remove, trims, busy = plan_clean(entries, everything=args.all, older_than_days=args.older_than, now=now)
    verb = "would remove" if args.dry_run else "removed"
    freed = 0
    for e, why in remove:
        if not args.dry_run:
            shutil.rmtree(e.path)
        freed += e.size
        print(f"{verb} {e.path.name}: {why}, {human_size(e.size)}")
    for e in trims:
        if not args.dry_run:
            trim(e.path, e.kind)
        freed += e.spare
        print(f"{'would trim' if args.dry_run else 'trimmed'} {e.path.name}: intermediate files, {human_size(e.spare)}")
    for e, _ in busy:
        print(f"kept {e.path.name}: unfinished but changed in the last hour (a running job's?)")
    print(f"{'would free' if args.dry_run else 'freed'} {human_size(freed)}")
    return 0
