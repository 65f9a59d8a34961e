// Per-view parameters shared by the rasterizer stages (one uniform struct, read by
// the host through reflection of this file: tsplus_wgpu.gpu.struct_dtype).
struct FrameParams {
    rot0: vec4<f32>,        // row 0 of R (xyz) and t.x (w): x_cam = R x_world + t
    rot1: vec4<f32>,        // row 1 of R, t.y
    rot2: vec4<f32>,        // row 2 of R, t.z
    cam_center: vec4<f32>,  // camera centre in world space (xyz)
    background: vec4<f32>,  // rgb
    fx: f32,
    fy: f32,
    cx: f32,
    cy: f32,
    near: f32,
    sigma: f32,
    width: u32,
    height: u32,
    tiles_x: u32,
    tiles_y: u32,
    num_vertices: u32,
    num_triangles: u32,
    sh_k: u32,
    num_pairs: u32,
    num_rows: u32,      // (triangle, tile row) work items of binning
    _pad1: u32,
}

const TILE: u32 = 16u;
const ALPHA_MIN: f32 = 0.0039215686274509803;  // 1/255: a triangle below this is skipped
const ALPHA_MAX: f32 = 0.99;
const T_MIN: f32 = 0.0001;                      // stop before T would fall below this
// Thinness below which a projected triangle is numerically degenerate and not drawn:
// 2*area / perimeter^2 (0.096 for an equilateral triangle).
const MIN_THINNESS: f32 = 1e-6;
// Conservative margin of the tile-overlap test, in units of the window ratio.
const BIN_MARGIN: f32 = 1e-5;

// lavapipe (Mesa's llvmpipe) ends every loop after 65535 iterations in total per
// invocation, silently. Every kernel bounds its per-invocation work well below that:
// binning works per (triangle, tile row) over at most MAX_TILES_PER_ROW tiles (the host
// refuses wider images), the blend runs in passes of at most PASS_PAIRS pairs per tile
// (rasterize_forward.wgsl).
const MAX_TILES_PER_ROW: u32 = 16384u;

fn world_to_camera(p: FrameParams, x: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(dot(p.rot0.xyz, x) + p.rot0.w,
                     dot(p.rot1.xyz, x) + p.rot1.w,
                     dot(p.rot2.xyz, x) + p.rot2.w);
}
