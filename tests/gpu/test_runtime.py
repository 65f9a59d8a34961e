"""The wgpu runtime: adapters, limits, WGSL loading and reflection, bad input."""


import numpy as np
import pytest
from scenes import look_at_camera, random_scene

from tsplus_wgpu import Camera, TriangleModel, gpu


def test_every_shader_compiles_and_binds_contiguously(ctx):
    stages = gpu.all_stages()
    assert {"sh_to_color", "project_triangles", "bin_count", "bin_emit", "radix_count", "radix_scatter",
            "scan_block", "scan_add", "tile_ranges", "rasterize_forward"} <= set(stages)
    for stage in stages:
        pipe, layout, src = ctx.pipeline(stage)
        assert [b.slot for b in sorted(src.bindings.values(), key=lambda b: b.slot)] == list(range(len(src.bindings)))
        storage = [b for b in src.bindings.values() if b.kind != "uniform"]
        assert len(storage) <= 8, f"{stage}: more storage buffers than WebGPU's default limit"


def test_pipelines_are_cached(ctx):
    assert ctx.pipeline("scan_add") is ctx.pipeline("scan_add")


def test_device_uses_webgpu_default_limits_but_the_adapters_sizes(ctx):
    assert ctx.limits["max-compute-workgroup-storage-size"] == 16384
    assert ctx.limits["max-storage-buffers-per-shader-stage"] == 8
    assert ctx.limits["max-compute-invocations-per-workgroup"] == 256
    offered = dict(ctx.adapter.limits)
    asked = gpu.adapter_size_limits(offered)
    for k in gpu.SIZE_LIMITS:
        assert ctx.limits[k] == asked[k] <= offered[k], k
    if offered["max-buffer-size"] > gpu.WEBGPU_DEFAULT_LIMITS["max-buffer-size"]:     # llvmpipe: 2 GiB
        assert ctx.limits["max-buffer-size"] > gpu.WEBGPU_DEFAULT_LIMITS["max-buffer-size"]


def test_webgpu_limits_keep_every_default(monkeypatch, ctx):
    for plain in (gpu.GpuContext(ctx.adapter, limits="webgpu"), None):
        if plain is None:
            monkeypatch.setenv("TSPLUS_WEBGPU_LIMITS", "1")
            plain = gpu.GpuContext(ctx.adapter)
        assert plain.limits["max-storage-buffer-binding-size"] == 128 * 2**20
        assert plain.limits["max-buffer-size"] == 256 * 2**20


def test_adapter_size_limits_are_capped_aligned_and_a_binding_fits_a_buffer():
    f = gpu.adapter_size_limits
    assert f({"max-storage-buffer-binding-size": 2**32 - 1, "max-buffer-size": 2**64 - 1}) == {
        "max-storage-buffer-binding-size": gpu.SIZE_LIMIT_CAP, "max-buffer-size": gpu.SIZE_LIMIT_CAP}
    assert f({"max-storage-buffer-binding-size": 2**27, "max-buffer-size": 2**31 - 1}) == {
        "max-storage-buffer-binding-size": 2**27, "max-buffer-size": 2**31 - 256}
    assert f({"max-storage-buffer-binding-size": 2**30, "max-buffer-size": 2**29 + 100}) == {
        "max-storage-buffer-binding-size": 2**29, "max-buffer-size": 2**29}


def test_larger_limit_only_when_available():
    with pytest.raises(ValueError, match="max-buffer-size"):
        gpu.GpuContext(limits={"max_buffer_size": 2**62})


def test_struct_reflection_follows_wgsl_layout(ctx):
    src = ctx.source("project_triangles")
    fp = src.structs["FrameParams"]
    assert fp.fields["rot0"][1] == 0 and fp.fields["background"][1] == 64 and fp.fields["fx"][1] == 80
    assert fp.fields["width"][1] == 104 and fp.itemsize == 144
    tri = src.structs["Tri2D"]
    assert tri.itemsize == 96 and tri.fields["color"][1] == 48


def test_struct_layout_rules():
    dt = gpu.struct_dtype("a: f32, b: vec3<f32>, c: f32, d: vec2<f32>", {})
    assert [dt.fields[n][1] for n in "abcd"] == [0, 16, 28, 32] and dt.itemsize == 48


def test_import_resolver_inlines_each_file_once():
    code = gpu.resolve_imports("#import frame\n#import triangle\n#import frame\n")
    assert code.count("struct FrameParams") == 1 and code.count("struct Tri2D") == 1
    with pytest.raises(FileNotFoundError, match="nope"):
        gpu.resolve_imports("#import nope\n")


def test_bind_by_name_rejects_missing_buffers(ctx):
    from tsplus_wgpu.kernels.sort import ScanAdd
    st = ScanAdd(ctx)
    with pytest.raises(KeyError, match="block_offsets"):
        st.bind({"sp": ctx.buffer(16), "data": ctx.buffer(16)})


def test_adapter_selection():
    """Every adapter is found by its own device name; ``lavapipe`` finds llvmpipe where Mesa's CPU
    driver is installed (CI), and names it in the error where it is not (a GPU machine)."""
    adapters = gpu.list_adapters()
    for a in adapters:
        assert gpu.select_adapter(a.info["device"].upper()).info["device"] == a.info["device"]
    if any("llvmpipe" in a.info["device"].lower() for a in adapters):
        assert "llvmpipe" in gpu.select_adapter("lavapipe").info["device"].lower()
    else:
        with pytest.raises(gpu.NoAdapterError, match="'lavapipe' matches no adapter; available: "):
            gpu.select_adapter("lavapipe")
    with pytest.raises(gpu.NoAdapterError, match="matches no adapter"):
        gpu.select_adapter("no-such-gpu-xyz")


def test_adapter_from_environment(monkeypatch):
    monkeypatch.setenv("TSPLUS_ADAPTER", "no-such-gpu-xyz")
    with pytest.raises(gpu.NoAdapterError):
        gpu.select_adapter()


def test_features_detected(ctx):
    f = ctx.features
    assert isinstance(f.timestamps, bool) and isinstance(f.float32_atomics, bool) and isinstance(f.subgroups, bool)


def test_timing_without_timestamps_falls_back_to_host(monkeypatch):
    monkeypatch.setenv("TSPLUS_NO_TIMESTAMPS", "1")
    from tsplus_wgpu import Renderer
    r = Renderer()
    assert not r.ctx.features.timestamps
    model, cam = random_scene(0, 32, 32)
    res = r.forward(model, cam, 1.0, profile=True)
    assert {"project_triangles", "rasterize_forward"} <= set(res.timings) and all(v >= 0 for v in res.timings.values())


# ----------------------------------------------------------------------------- bad input

def good():
    model, cam = random_scene(0, 16, 16)
    return model, cam


@pytest.mark.parametrize("bad,match", [
    (lambda p: p.__setitem__((0, 0), np.nan), "positions: 1 non-finite"),
    (lambda p: p.__setitem__((1, 2), np.inf), "positions: 1 non-finite"),
])
def test_non_finite_positions(bad, match):
    model, _ = good()
    pos = model.positions.copy()
    bad(pos)
    with pytest.raises(ValueError, match=match):
        TriangleModel(pos, model.triangles, model.sh, model.opacity)


def test_bad_models():
    model, _ = good()
    n = model.num_vertices
    with pytest.raises(ValueError, match=r"triangles: index out of range \[0, %d\)" % n):
        TriangleModel(model.positions, model.triangles + n, model.sh, model.opacity)
    with pytest.raises(ValueError, match="triangles: index out of range"):
        TriangleModel(model.positions, model.triangles - 100, model.sh, model.opacity)
    with pytest.raises(ValueError, match=r"positions: expected shape \[N, 3\]"):
        TriangleModel(model.positions[:, :2], model.triangles, model.sh, model.opacity)
    with pytest.raises(ValueError, match=r"triangles: expected shape \[M, 3\]"):
        TriangleModel(model.positions, model.triangles[:, :2], model.sh, model.opacity)
    with pytest.raises(ValueError, match="triangles: expected integer"):
        TriangleModel(model.positions, model.triangles + 0.5, model.sh, model.opacity)
    with pytest.raises(ValueError, match="sh: expected shape"):
        TriangleModel(model.positions, model.triangles, np.zeros((n, 5, 3)), model.opacity)
    with pytest.raises(ValueError, match="sh: 1 non-finite"):
        sh = model.sh.copy(); sh[0, 0, 0] = np.nan
        TriangleModel(model.positions, model.triangles, sh, model.opacity)
    with pytest.raises(ValueError, match="opacity: values must be activated"):
        TriangleModel(model.positions, model.triangles, model.sh, model.opacity + 1.0)
    with pytest.raises(ValueError, match=r"opacity: expected shape \[N="):
        TriangleModel(model.positions, model.triangles, model.sh, model.opacity[:-1])
    with pytest.raises(ValueError, match="positions: expected a float array"):
        TriangleModel(np.full((n, 3), "x"), model.triangles, model.sh, model.opacity)


def test_bad_cameras():
    m = np.eye(4)
    with pytest.raises(ValueError, match="Camera width: must be >= 1"):
        Camera(0, 10, 1, 1, 0, 0, m)
    with pytest.raises(ValueError, match="Camera height: must be >= 1"):
        Camera(10, 0, 1, 1, 0, 0, m)
    with pytest.raises(ValueError, match="Camera fx: focal length must be > 0"):
        Camera(10, 10, 0, 1, 0, 0, m)
    with pytest.raises(ValueError, match="Camera cy: must be finite"):
        Camera(10, 10, 1, 1, 0, np.nan, m)
    with pytest.raises(ValueError, match="Camera world_to_camera: 1 non-finite"):
        mm = m.copy(); mm[0, 3] = np.inf
        Camera(10, 10, 1, 1, 0, 0, mm)
    with pytest.raises(ValueError, match=r"world_to_camera: expected shape \[4, 4\]"):
        Camera(10, 10, 1, 1, 0, 0, np.eye(3))


def test_bad_forward_arguments(renderer):
    model, cam = good()
    for sigma in (0.0, -1.0, np.nan, np.inf, "x"):
        with pytest.raises(ValueError, match="sigma"):
            renderer.forward(model, cam, sigma)
    with pytest.raises(ValueError, match="background"):
        renderer.forward(model, cam, 1.0, background=(0, 0))
    with pytest.raises(ValueError, match="background"):
        renderer.forward(model, cam, 1.0, background=(0, np.nan, 0))
    with pytest.raises(ValueError, match="near"):
        renderer.forward(model, cam, 1.0, near=-1)
    with pytest.raises(ValueError, match="model: expected"):
        renderer.forward("model", cam, 1.0)
    with pytest.raises(ValueError, match="camera: expected"):
        renderer.forward(model, "cam", 1.0)


def test_empty_model_is_rejected(renderer):
    model = TriangleModel(np.zeros((3, 3)), np.zeros((0, 3), int), np.zeros((3, 1, 3)), np.ones(3))
    with pytest.raises(ValueError, match=r"model: it has no triangles \(M = 0\)"):
        renderer.forward(model, look_at_camera(8, 8), 1.0)


def _webgpu_binding(monkeypatch, ctx):
    """The device's binding size as WebGPU's default for the checks (a GPU's own is up to 2 GiB)."""
    monkeypatch.setitem(ctx.limits, "max-storage-buffer-binding-size", 2**27)


def test_sizes_over_device_limits(renderer, monkeypatch):
    _webgpu_binding(monkeypatch, renderer.ctx)
    model, _ = good()
    huge = look_at_camera(12000, 12000)   # 12000^2 * 12 bytes > 128 MiB per binding
    with pytest.raises(ValueError, match="image: needs .* MiB .* storage-binding limit"):
        renderer.forward(model, huge, 1.0)


def test_too_many_pairs_is_a_clear_error(renderer, monkeypatch):
    # at 3000x2000 (23.5k tiles) each screen-covering triangle gives 23.5k pairs: 1500 of
    # them need 35M pairs = 141 MiB, over the 128 MiB binding limit
    _webgpu_binding(monkeypatch, renderer.ctx)
    cam = look_at_camera(3000, 2000)
    big = np.array([[-60, 40, 0], [60, 40, 0], [0, -80, 0]], float)
    k = 1500
    pos = np.concatenate([big + [0, 0, 0.001 * i] for i in range(k)])
    model = TriangleModel(pos, np.arange(3 * k).reshape(k, 3), np.zeros((3 * k, 1, 3)), np.ones(3 * k))
    with pytest.raises(ValueError, match="tile-triangle pairs"):
        renderer.forward(model, cam, 1.0)


def test_no_reliance_on_zeroed_memory():
    """Every scratch and output buffer filled with 0xFF: same image, bit for bit."""
    from tsplus_wgpu import Renderer
    poisoned = Renderer(gpu.GpuContext(poison=True))
    clean = Renderer(gpu.GpuContext(poison=False))
    model, cam = random_scene(4, 96, 80)
    a = poisoned.forward(model, cam, 0.5, background=(0.1, 0.2, 0.3))
    b = clean.forward(model, cam, 0.5, background=(0.1, 0.2, 0.3))
    assert np.isfinite(a.image).all()
    assert a.image.tobytes() == b.image.tobytes()
    assert a.max_weight.tobytes() == b.max_weight.tobytes()
    assert a.transmittance.tobytes() == b.transmittance.tobytes()
    ga = poisoned.backward(a, np.ones_like(a.image))
    gb = clean.backward(b, np.ones_like(b.image))
    assert ga.v_positions.tobytes() == gb.v_positions.tobytes()
    assert ga.v_sh.tobytes() == gb.v_sh.tobytes() and ga.v_opacity.tobytes() == gb.v_opacity.tobytes()


def test_no_adapter_message(monkeypatch):
    monkeypatch.setattr(gpu.context, "list_adapters", lambda *a, **k: [])
    with pytest.raises(gpu.NoAdapterError, match="apt-get install -y mesa-vulkan-drivers"):
        gpu.select_adapter()


def test_too_wide_image_is_rejected(renderer):
    model, _ = good()
    wide = look_at_camera(16 * 16384 + 1, 1)
    with pytest.raises(ValueError, match="camera: .* is too large"):
        renderer.forward(model, wide, 1.0)


def test_kernel_layout_follows_the_adapter_type_and_is_overridable(ctx, monkeypatch):
    from tsplus_wgpu.kernels.blend import kernel_layout
    monkeypatch.delenv("TSPLUS_LAYOUT", raising=False)
    assert gpu.choose_layout({"adapter_type": "CPU"}) == "cpu"
    for kind in ("DiscreteGPU", "IntegratedGPU", "VirtualGPU", "Unknown"):
        assert gpu.choose_layout({"adapter_type": kind}) == "gpu"
    monkeypatch.setenv("TSPLUS_LAYOUT", "gpu")
    assert gpu.choose_layout({"adapter_type": "CPU"}) == "gpu"
    assert gpu.choose_layout({"adapter_type": "CPU"}, "cpu") == "cpu"       # the argument wins
    monkeypatch.setenv("TSPLUS_LAYOUT", "wide")
    with pytest.raises(ValueError, match="TSPLUS_LAYOUT: expected one of cpu, gpu, pixel, got 'wide'"):
        gpu.choose_layout({"adapter_type": "CPU"})
    with pytest.raises(ValueError, match="layout: expected one of cpu, gpu, pixel"):
        gpu.GpuContext(ctx.adapter, layout="pixels")
    assert kernel_layout(ctx).startswith(ctx.layout + " (")
    column, pixel = "16 invocations a 16x16 tile, 16 px each", "256 invocations a 16x16 tile, 1 px each"
    columns = "8 invocations a 16x16 tile, 32 px each"      # the forward's column kernel: two columns each
    for name, (fwd, bwd) in {"cpu": (columns, column), "gpu": (pixel, column), "pixel": (pixel, pixel)}.items():
        assert kernel_layout(gpu.GpuContext(ctx.adapter, layout=name)) == f"{name} (forward {fwd}; backward {bwd})"
    from tsplus_wgpu.cli.adapters import LAYOUT_NAMES
    assert LAYOUT_NAMES == gpu.LAYOUTS       # --help names them without importing wgpu


def test_each_layout_renders_with_its_own_kernels(renderer, layout_renderers):
    """The renderer's forward and backward stages are the layout's kernels, and every layout
    gives the same image and gradients within float32 (the kernels against the twin:
    tests/kernels/test_blend.py and test_backward.py)."""
    from tsplus_wgpu.kernels.backward import RasterizeBackwardGpu
    from tsplus_wgpu.kernels.blend import RasterizeForwardGpu
    from tsplus_wgpu.render.backward import BackwardPass
    model, cam = random_scene(31, 64, 48, sh_k=4)
    v = np.random.default_rng(6).normal(size=(48, 64, 3)).astype(np.float32)
    out = {}
    for name, r in layout_renderers.items():
        pixel = {w: gpu.layout_kernel(name, w) == "pixel" for w in ("forward", "backward")}
        assert isinstance(r.blend, RasterizeForwardGpu) == pixel["forward"], name
        assert isinstance(BackwardPass(r).raster, RasterizeBackwardGpu) == pixel["backward"], name
        res = r.forward(model, cam, 0.5)
        out[name] = res.image, r.backward(res, v)
    img, g = out["cpu"]
    for name, (img2, g2) in out.items():
        np.testing.assert_allclose(img2, img, rtol=0, atol=2e-6, err_msg=name)
        for key in ("v_positions", "v_sh", "v_opacity"):
            a, b = getattr(g2, key), getattr(g, key)
            assert np.abs(a - b).max() <= 1e-5 * np.abs(b).max(), (name, key)
