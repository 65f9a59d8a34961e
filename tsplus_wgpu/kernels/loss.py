"""Host classes of shaders/loss/: the image loss (L1 + D-SSIM) and its gradient, the gradient
packing and the supersampling area filter. Twins: :mod:`tsplus_wgpu.reference.loss`."""

from __future__ import annotations

from ..gpu import Stage
from ..types import Camera


def supersampled_camera(camera, s):
    """The exact s-times camera: ``fx s, fy s, cx s, cy s, width s, height s``. With pixel
    centres at ``(j + 0.5, i + 0.5)`` the s x s sub-pixels of pixel (i, j) have centres at
    ``j + (b + 0.5) / s`` (b = 0..s-1), mean ``j + 0.5``: their area average is that pixel."""
    s = int(s)
    if s < 1:
        raise ValueError(f"supersampling factor: expected an integer >= 1, got {s}")
    if s == 1:
        return camera
    return Camera(camera.width * s, camera.height * s, camera.fx * s, camera.fy * s, camera.cx * s, camera.cy * s,
                  camera.world_to_camera)


class PackVOut(Stage):
    """``v_image [H * W * 3]`` -> ``v_out [H * W]`` vec4 (the backward's input, ``.w = 0``)."""
    stage = "pack_v_out"

    def __call__(self, enc, v_image, v_out, num_pixels, profiler=None):
        pp = self.uniform("PackParams", num_pixels=num_pixels)
        self.dispatch(enc, self.groups(num_pixels), dict(pp=pp, v_image=v_image, v_out=v_out), profiler)


class DownsampleArea(Stage):
    """``fine [s H * s W * 3]`` -> ``coarse [H * W * 3]`` (area mean), ``width``/``height`` coarse."""
    stage = "downsample_area"

    def __call__(self, enc, fine, coarse, width, height, s, profiler=None):
        dp = self.uniform("DownParams", width=width, height=height, factor=s, inv_area=1.0 / (s * s))
        self.dispatch(enc, self.groups(width * height), dict(dp=dp, fine=fine, coarse=coarse), profiler)


class DownsampleAreaT(Stage):
    """``v_coarse [H * W * 3]`` -> ``v_fine [s H * s W]`` vec4 (the backward's input, ``.w = 0``)."""
    stage = "downsample_area_t"

    def __call__(self, enc, v_coarse, v_fine, width, height, s, profiler=None):
        dp = self.uniform("DownParams", width=width, height=height, factor=s, inv_area=1.0 / (s * s))
        self.dispatch(enc, self.groups(width * height * s * s), dict(dp=dp, v_coarse=v_coarse, v_fine=v_fine),
                      profiler)


class _SsimStage(Stage):
    """The SSIM stages share ``SsimParams`` (``shaders/common/ssim.wgsl``)."""

    def runs(self, width, height, along="row"):
        """Invocations of a blur stage: one per run of ``SSIM_SEG`` pixels of a row (``along="row"``)
        or of a column."""
        seg = int(self.const("SSIM_SEG"))
        w, h = int(width), int(height)
        return h * -(-w // seg) if along == "row" else w * -(-h // seg)

    def partial_count(self, width, height):
        """``ssim_loss``'s workgroups, one ``(sum |x - y|, sum m)`` partial each."""
        return self.groups(self.runs(width, height, along="column"))

    def params(self, width, height):
        n = int(width) * int(height)
        return self.uniform("SsimParams", width=width, height=height, num_pixels=n, inv_n=1.0 / (3.0 * n))


class SsimBlurH(_SsimStage):
    """Row blur of x, y, x^2, y^2, xy: ``image, target [H, W, 3]`` -> ``rows [H * W, 4]`` vec4."""
    stage = "ssim_blur_h"

    def __call__(self, enc, sp, image, target, rows, width, height, profiler=None):
        self.dispatch(enc, self.groups(self.runs(width, height)),
                      dict(sp=sp, image=image, target_image=target, rows=rows), profiler)


class SsimLoss(_SsimStage):
    """Column blur, SSIM map and its derivative maps ``dmaps [H * W, 3]`` vec4, and one
    ``(sum |x - y|, sum m)`` partial per workgroup (``partials [partial_count]`` vec2)."""
    stage = "ssim_loss"

    def __call__(self, enc, sp, image, target, rows, dmaps, partials, width, height, profiler=None):
        self.dispatch(enc, self.partial_count(width, height), dict(sp=sp, image=image, target_image=target, rows=rows,
                                                          dmaps=dmaps, partials=partials), profiler)


class SsimGradH(_SsimStage):
    """Row blur of the derivative maps: ``dmaps`` -> ``grows [H * W, 3]`` vec4."""
    stage = "ssim_grad_h"

    def __call__(self, enc, sp, dmaps, grows, width, height, profiler=None):
        self.dispatch(enc, self.groups(self.runs(width, height)), dict(sp=sp, dmaps=dmaps, grows=grows), profiler)


class SsimGradV(_SsimStage):
    """Column blur of ``grows`` and d loss / d image: ``v_image [H, W, 3]``."""
    stage = "ssim_grad_v"

    def __call__(self, enc, sp, image, target, grows, v_image, width, height, profiler=None):
        self.dispatch(enc, self.groups(self.runs(width, height, along="column")),
                      dict(sp=sp, image=image, target_image=target, grows=grows, v_image=v_image), profiler)


class SsimReduce(_SsimStage):
    """One workgroup: ``partials`` -> ``result [4]`` = (loss, l1, ssim, 0)."""
    stage = "ssim_reduce"

    def __call__(self, enc, sp, partials, result, profiler=None):
        self.dispatch(enc, 1, dict(sp=sp, partials=partials, result=result), profiler)


__all__ = ["supersampled_camera", "PackVOut", "DownsampleArea", "DownsampleAreaT", "SsimBlurH", "SsimLoss",
           "SsimGradH", "SsimGradV", "SsimReduce"]
