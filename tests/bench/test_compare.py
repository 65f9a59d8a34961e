"""The side-by-side figure of held-out views (tsplus_wgpu.bench.compare)."""

import json

import imageio.v3 as iio
import numpy as np
import pytest

from tsplus_wgpu.bench import compare


def _eval_folder(path, psnrs, shade, h=12, w=10):
    """A fake `tsplus eval` folder: metrics.json and ground truth | render | error per view."""
    path.mkdir()
    views = [dict(view=v, psnr=p) for v, p in psnrs.items()]
    path.joinpath("metrics.json").write_text(json.dumps(dict(views=views, mean_psnr=float(np.mean(list(psnrs.values()))),
                                                             adapter="fake")))
    for v in psnrs:
        img = np.zeros((h, 3 * w, 3), np.uint8)
        img[:, :w] = 10 + v           # ground truth: the view's number
        img[:, w:2 * w] = shade        # render: the mesh's shade
        iio.imwrite(path / f"view_{v:03d}.png", img)
    return path


def test_typical_view_is_closest_to_the_mean():
    assert compare.typical_view({0: 10.0, 8: 14.0, 16: 20.0}, 15.0, {0, 8, 16}) == 8
    assert compare.typical_view({0: 10.0, 8: 14.0, 16: 20.0}, 16.0, {0, 16}) == 16   # 8 has no image
    assert compare.typical_view({0: 14.0, 8: 16.0}, 15.0, {0, 8}) == 0                # a tie: the lower index
    with pytest.raises(ValueError, match="no held-out view"):
        compare.typical_view({0: 1.0}, 1.0, set())


def test_panels_split_the_eval_image(tmp_path):
    f = _eval_folder(tmp_path / "a", {0: 12.0}, shade=200)
    gt, render = compare.panels(f, 0)
    assert gt.shape == render.shape == (12, 10, 3)
    assert (gt == 10).all() and (render == 200).all()


def test_figure_rows_views_and_titles(tmp_path):
    base = _eval_folder(tmp_path / "poisson", {0: 11.0, 8: 12.0, 16: 13.0}, shade=50)
    ours = _eval_folder(tmp_path / "ours", {0: 20.0, 8: 16.0, 16: 15.0}, shade=250)   # mean 17: view 8
    out = tmp_path / "fig.png"
    got = compare.compare_figure([("scene", [("Poisson", base), ("ours", ours)])], out)
    assert got == [("scene", 8, [("Poisson", 12.0, 12.0), ("ours", 16.0, 17.0)])]
    assert iio.imread(out).shape[0] > 50
    got = compare.compare_figure([("scene", [("Poisson", base), ("ours", ours)])], out, view=16)
    assert got[0][1] == 16


def test_bad_folders_are_one_line_errors(tmp_path, capsys):
    with pytest.raises(ValueError, match="metrics.json: not found"):
        compare.load_eval(tmp_path)
    (tmp_path / "metrics.json").write_text("{}")
    with pytest.raises(ValueError, match="not a `tsplus eval` metrics file"):
        compare.load_eval(tmp_path)
    with pytest.raises(ValueError, match="view_003.png: not found"):
        compare.panels(tmp_path, 3)
    with pytest.raises(SystemExit, match="compare: error: .*metrics.json: not found"):
        compare.main(["--out", str(tmp_path / "x.png"), "--row", "s", f"ours={tmp_path / 'missing'}"])
    with pytest.raises(SystemExit):
        compare.main(["--out", str(tmp_path / "x.png"), "--row", "s", "no-equals-sign"])
    assert not (tmp_path / "x.png").exists()
