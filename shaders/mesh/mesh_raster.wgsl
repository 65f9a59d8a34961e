// Depth-tested mesh rasterisation with an ordinary render pipeline (vertex + fragment stages):
// how an engine draws the exported mesh. No blending, no face culling, reversed depth.
//
// Clip space from the COLMAP/OpenCV pinhole camera (x_cam = R x + t, u = fx x/z + cx,
// v = fy y/z + cy, pixel centres at +0.5): with w = z,
//   clip.x = (2 fx / W) x + (2 cx / W - 1) z     -> x_ndc = 2u/W - 1   (framebuffer x = u)
//   clip.y = -(2 fy / H) y + (1 - 2 cy / H) z    -> y_ndc = 1 - 2v/H   (framebuffer y = v)
//   clip.z = near                                -> depth = near / z in (0, 1] for z >= near
// WebGPU clips to 0 <= clip.z <= clip.w, i.e. z >= near (infinite far plane); nearer is
// larger depth, so the test is "greater" against a clear value of 0 (float depth keeps its
// precision far away). The host builds clip_from_world = P * world_to_camera in float64.
//
// The rgba32float target holds the colour in rgb and the camera-space z in a (0 = nothing).

struct MeshParams {
    clip_from_world: mat4x4<f32>,
    view_z: vec4<f32>,       // third row of world_to_camera: z_cam = dot(view_z, (x, 1))
    near: f32,
    drop_near: u32,          // 1: a triangle with any vertex at z <= near is not drawn at all
    linear_color: u32,       // 1: colour interpolated affinely in screen space (as the splatting model)
    color_sh_dc: u32,        // 1: the colour attribute is an SH DC row: colour = max(0, C0 dc + 0.5)
}

@group(0) @binding(0) var<uniform> params: MeshParams;

struct VertexOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) color_perspective: vec3<f32>,
    // colour * z, perspective-interpolated: divided by the interpolated z it is the colour interpolated
    // affinely in screen space (sum l_i c_i with screen barycentrics l_i), without @interpolate(linear),
    // which lavapipe gets wrong (NaN) on triangles clipped at the guard band
    @location(1) color_z: vec3<f32>,
    @location(2) z_cam: f32,
    @location(3) behind: f32,
}

@vertex
fn vs_main(@location(0) position: vec3<f32>, @location(1) color: vec3<f32>) -> VertexOut {
    var out: VertexOut;
    let p = vec4<f32>(position, 1.0);
    out.clip = params.clip_from_world * p;
    var c = color;
    if (params.color_sh_dc != 0u) {
        c = max(color * 0.28209479177387814 + vec3<f32>(0.5), vec3<f32>(0.0));
    }
    out.color_perspective = c;
    let z = dot(params.view_z, p);
    out.color_z = c * z;
    out.z_cam = z;
    // > 0 everywhere inside a triangle that has a vertex at or behind the near plane
    out.behind = select(0.0, 1.0, z <= params.near);
    return out;
}

@fragment
fn fs_main(in: VertexOut) -> @location(0) vec4<f32> {
    // (written so that a NaN from clipping a triangle through the camera plane also discards)
    if (params.drop_near != 0u && !(in.behind <= 0.0)) {
        discard;
    }
    var c = in.color_perspective;
    if (params.linear_color != 0u) {
        c = in.color_z / in.z_cam;
    }
    return vec4<f32>(c, in.z_cam);
}
