"""A copy of a folder of photos carrying the EXIF a phone writes: make, model, focal length.

The shared scenes' photos carry no EXIF, while every phone photo does, and the photo folder's
SfM starts from its focal length (and holds it through a forward walk: docs/data.md). This
makes the copies that measure that case: each JPEG or PNG re-saved as a JPEG (quality 95) with
``FocalLengthIn35mmFilm`` (COLMAP's prior: that over 35 mm film's 43.3 mm diagonal, times the
image's diagonal: 34 mm is 982 px at 1000x750), optionally at a smaller width.

    python -m tsplus_wgpu.bench.exif_copy ../shared/data/lund/images LUND_EXIF --focal35 34
    tsplus train LUND_EXIF --out RUN
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ..data.images import list_images


def exif_copy(src, dst, focal35: float, width: int | None = None) -> list:
    """Writes every image of ``src`` into ``dst`` (created) as ``NAME.jpg``-style JPEGs with EXIF
    make "Apple", model "iPhone", focal length 4.2 mm and ``FocalLengthIn35mmFilm`` ``focal35``;
    ``width``: resized to that many pixels wide (Lanczos). Returns the names written."""
    from PIL import Image  # noqa: PLC0415
    src, dst = Path(src), Path(dst)
    if not src.is_dir():
        raise ValueError(f"{src}: not a folder of photos")
    names = list_images(src)
    if not names:
        raise ValueError(f"{src}: no images found")
    if not 1 <= focal35 <= 2000:
        raise ValueError(f"--focal35 {focal35}: expected a 35 mm equivalent focal length in mm (1-2000)")
    dst.mkdir(parents=True, exist_ok=True)
    written = []
    for n in names:
        with Image.open(src / n) as im:
            rgb = im.convert("RGB")
        if width:
            rgb = rgb.resize((int(width), max(1, round(width * rgb.size[1] / rgb.size[0]))), Image.LANCZOS)
        ex = rgb.getexif()
        ex[0x010F], ex[0x0110] = "Apple", "iPhone"
        sub = ex.get_ifd(0x8769)
        sub[0x920A] = 4.2
        sub[0xA405] = int(round(focal35))
        out = dst / (Path(n).stem + ".jpg")
        rgb.save(out, quality=95, exif=ex.tobytes())
        written.append(out.name)
    return written


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m tsplus_wgpu.bench.exif_copy",
                                description="Copy a folder of photos as JPEGs carrying a phone's EXIF focal length.")
    p.add_argument("src", help="folder of photos")
    p.add_argument("dst", help="folder to write (created)")
    p.add_argument("--focal35", type=float, required=True, help="35 mm equivalent focal length in mm")
    p.add_argument("--width", type=int, help="resize to this width in pixels (default: keep the size)")
    args = p.parse_args(argv)
    if args.width is not None and args.width < 16:
        raise SystemExit(f"exif_copy: error: --width {args.width}: expected at least 16 pixels")
    try:
        names = exif_copy(args.src, args.dst, args.focal35, args.width)
    except (ValueError, OSError) as e:
        raise SystemExit(f"exif_copy: error: {e}") from None
    print(f"wrote {len(names)} photos to {args.dst}")


if __name__ == "__main__":
    main()
