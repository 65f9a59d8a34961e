// Shared by the normal-loss stages (normal_model, normal_backward, normal_accumulate;
// tsplus_wgpu.train.normals): one uniform struct and the oriented triangle normal.

struct NormalParams {
    rot0: vec4<f32>,     // row 0 of R (xyz) and t.x (w): x_cam = R x_world + t
    rot1: vec4<f32>,
    rot2: vec4<f32>,
    num_triangles: u32,
    num_vertices: u32,
    _pad0: u32,
    _pad1: u32,
    weight: f32,         // the loss weight (normal_accumulate)
    _pad2: f32,
    _pad3: f32,
    _pad4: f32,
}

// The triangle's normal: e = cross(x1 - x0, x2 - x0), u = e / |e| (world), n = s R u in
// camera space with s = +-1 so that n faces the camera: dot(n, centroid_cam) <= 0 (for a
// plane that dot is the same at every point of it). Returned as (u, |e|) and s; a
// degenerate triangle (|e|^2 == 0 in float) gives |e| = 0 and n = 0.
struct TriNormal {
    u: vec3<f32>,
    len: f32,
    n: vec3<f32>,
    sign: f32,
}

fn rot_apply(p: NormalParams, u: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(dot(p.rot0.xyz, u), dot(p.rot1.xyz, u), dot(p.rot2.xyz, u));
}

fn rot_transpose_apply(p: NormalParams, v: vec3<f32>) -> vec3<f32> {
    return p.rot0.xyz * v.x + p.rot1.xyz * v.y + p.rot2.xyz * v.z;
}

fn tri_normal(p: NormalParams, x0: vec3<f32>, x1: vec3<f32>, x2: vec3<f32>) -> TriNormal {
    var r = TriNormal(vec3<f32>(0.0), 0.0, vec3<f32>(0.0), 1.0);
    let e = cross(x1 - x0, x2 - x0);
    let e2 = dot(e, e);
    if (!(e2 > 0.0)) {
        return r;
    }
    r.len = sqrt(e2);
    r.u = e / r.len;
    let c = rot_apply(p, (x0 + x1 + x2) / 3.0) + vec3<f32>(p.rot0.w, p.rot1.w, p.rot2.w);
    let n = rot_apply(p, r.u);
    if (dot(n, c) > 0.0) {
        r.sign = -1.0;
    }
    r.n = r.sign * n;
    return r;
}
