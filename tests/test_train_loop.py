"""The training loop: device-resident forward/backward, Trainer (quality, resume, determinism)
and ``tsplus train``."""

import numpy as np
import pytest
from scenes import random_scene

from tsplus_wgpu import DeviceModel


def test_device_model_forward_backward_equal_host_path(renderer):
    model, cam = random_scene(3, 48, 40, sh_k=4)
    dm = DeviceModel.from_model(renderer, model)
    ref = renderer.forward(model, cam, 0.7)
    dev = renderer.forward(dm, cam, 0.7)
    assert dev.model is dm and dev.model_buffers is dm.buffers
    np.testing.assert_array_equal(dev.image, ref.image)
    np.testing.assert_array_equal(dev.transmittance, ref.transmittance)
    rng = np.random.default_rng(0)
    v_img = rng.normal(size=(40, 48, 3)).astype(np.float32)
    v_t = rng.normal(size=(40, 48)).astype(np.float32)
    g_ref = renderer.backward(ref, v_img, v_t)
    # v_image as a device buffer in the kernel's layout, gradients into caller-owned buffers
    c = renderer.ctx
    v_out = c.upload(np.concatenate([v_img.reshape(-1, 3), v_t.reshape(-1, 1)], axis=1).astype(np.float32))
    n, k = model.num_vertices, model.sh_size
    out = dict(v_positions=c.buffer(12 * n), v_sh=c.buffer(12 * n * k), v_opacity=c.buffer(4 * n))
    assert renderer.backward(dev, v_out, read=False, out=out) is not None
    np.testing.assert_array_equal(c.read(out["v_positions"], np.float32, 3 * n).reshape(n, 3), g_ref.v_positions)
    np.testing.assert_array_equal(c.read(out["v_sh"], np.float32, 3 * n * k).reshape(n, k, 3), g_ref.v_sh)
    np.testing.assert_array_equal(c.read(out["v_opacity"], np.float32, n), g_ref.v_opacity)
    back = dm.to_model()
    np.testing.assert_array_equal(back.triangles, model.triangles)
    np.testing.assert_array_equal(back.positions, model.positions.astype(np.float32))


def test_device_model_errors(renderer):
    model, cam = random_scene(4, 32, 32)
    dm = DeviceModel.from_model(renderer, model)
    with pytest.raises(ValueError, match="v_transmittance"):
        renderer.backward(renderer.forward(dm, cam, 0.5), renderer.ctx.buffer(16 * 32 * 32), np.zeros((32, 32)))
    with pytest.raises(ValueError, match="needs"):
        renderer.backward(renderer.forward(dm, cam, 0.5), renderer.ctx.buffer(16 * 10))
    with pytest.raises(ValueError, match="missing"):
        DeviceModel(renderer.ctx, {"positions": dm.buffers["positions"]}, 1, 1, 1)
    with pytest.raises(ValueError, match="TriangleModel or DeviceModel"):
        renderer.forward("nope", cam, 0.5)
