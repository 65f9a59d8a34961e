"""``tsplus render``: the built-in procedural scene's ground-truth mesh through the WGSL
rasterizer, from every camera, with PSNR against the scene's images and per-stage timings."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from .adapters import add_adapter_arg


def add_parser(sub):
    p = sub.add_parser("render", help="render the built-in procedural scene's ground-truth mesh through the WGSL rasterizer",
                       description="Render the built-in procedural scene's ground-truth mesh (vertex colours, "
                                   "opaque) through the WGSL rasterizer from every camera, compare with the scene's "
                                   "reference images (PSNR) and print per-stage timings.")
    p.add_argument("--size", choices=["tiny", "small", "demo"], default="demo", help="scene size (default demo)")
    p.add_argument("--sigma", type=float, default=1e-4, help="window sharpness (default 1e-4: nearly opaque)")
    p.add_argument("--out", default="runs/render", help="output folder for images (default runs/render)")
    p.add_argument("--seed", type=int, default=0, help="scene seed (default 0)")
    add_adapter_arg(p)
    return p


def run(args):
    from tqdm import tqdm

    from ..data.procedural import demo_model, load_procedural
    from ..io.atomic import write_image
    from ..io.metrics import psnr
    from ..render.renderer import Renderer
    t0 = time.perf_counter()
    scene = load_procedural(args.size, seed=args.seed)
    t_scene = time.perf_counter() - t0
    model = demo_model(args.seed)
    renderer = Renderer(args.adapter)
    print(f"adapter: {renderer.adapter_name}")
    print(f"scene: procedural '{args.size}' ({len(scene.cameras)} views, {scene.cameras[0].width}x"
          f"{scene.cameras[0].height}), mesh {model.num_vertices} vertices / {model.num_triangles} triangles "
          f"(built in {t_scene:.1f}s)")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    renderer.forward(model, scene.cameras[0], args.sigma).image   # warm-up: compile pipelines
    stage_ms, walls, psnrs = {}, [], []
    for i, cam in enumerate(tqdm(scene.cameras, desc="render", unit="view", dynamic_ncols=True)):
        t = time.perf_counter()
        res = renderer.forward(model, cam, args.sigma, profile=True)
        img = res.image
        walls.append(time.perf_counter() - t)
        for k, v in res.timings.items():
            stage_ms.setdefault(k, []).append(v)
        psnrs.append(psnr(img, scene.images[i]))
        if i < 4:
            write_image(out / f"view_{i:03d}.png", np.concatenate([scene.images[i], img], axis=1))
    print(f"{'stage':<20}{'median ms':>12}")
    for k, v in stage_ms.items():
        print(f"{k:<20}{np.median(v):>12.3f}")
    print(f"{'wall per view':<20}{1e3 * np.median(walls):>12.3f}")
    print(f"PSNR of the vertex-coloured mesh against the textured reference images: mean {np.mean(psnrs):.2f} dB "
          f"(min {np.min(psnrs):.2f}, max {np.max(psnrs):.2f})")
    print(f"wrote reference | render pairs to {out}/view_000.png ...")
    return 0
