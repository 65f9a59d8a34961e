// Per triangle: project to pixels, build the window's edge equations pre-divided by
// phi(s) = -r, the affine colour, the depth sort key and the pixel box of the
// alpha >= 1/255 region. Culled triangles get an empty box and the largest key.
#import frame
#import dispatch
#import triangle

@group(0) @binding(0) var<uniform> params: FrameParams;
@group(0) @binding(1) var<storage, read> positions: array<f32>;        // [N, 3]
@group(0) @binding(2) var<storage, read> triangles: array<u32>;        // [M, 3]
@group(0) @binding(3) var<storage, read> opacities: array<f32>;        // [N]
@group(0) @binding(4) var<storage, read> colors: array<vec4<f32>>;     // [N]
@group(0) @binding(5) var<storage, read_write> tris: array<Tri2D>;     // [M]
@group(0) @binding(6) var<storage, read_write> pixel_rects: array<vec4<i32>>;  // [M]
@group(0) @binding(7) var<storage, read_write> depth_keys: array<u32>; // [M]
@group(0) @binding(8) var<storage, read_write> tri_ids: array<u32>;    // [M]
// The projected triangles may outgrow one binding: then one dispatch per range of triangles
// [items.first, items.first + items.count), tris bound to that range (tsplus_wgpu.gpu.chunks).
@group(0) @binding(9) var<uniform> items: ItemRange;

fn cull(t: u32) {
    pixel_rects[t] = vec4<i32>(1, 1, 0, 0);
    depth_keys[t] = 0xffffffffu;
    var z: Tri2D;
    tris[t - items.first] = z;
}

const THREADS: u32 = 256u;   // one item per invocation

@compute @workgroup_size(THREADS)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let local = linear_group(wid, nwg) * THREADS + li;
    if (local >= items.count) {
        return;
    }
    let t = items.first + local;
    tri_ids[t] = t;
    var p2: array<vec2<f32>, 3>;
    var zsum = 0.0;
    var opacity = 1.0;
    var vid: array<u32, 3>;
    for (var k = 0u; k < 3u; k++) {
        let v = triangles[3u * t + k];
        vid[k] = v;
        let xw = vec3<f32>(positions[3u * v], positions[3u * v + 1u], positions[3u * v + 2u]);
        let xc = world_to_camera(params, xw);
        if (!(xc.z > params.near)) {
            cull(t);
            return;
        }
        p2[k] = vec2<f32>(params.fx * xc.x / xc.z + params.cx, params.fy * xc.y / xc.z + params.cy);
        zsum += xc.z;
        opacity = min(opacity, opacities[v]);
    }
    if (opacity < ALPHA_MIN) {  // alpha <= opacity < 1/255 everywhere: never drawn
        cull(t);
        return;
    }
    // Side k is opposite vertex k.
    let e1 = p2[1] - p2[0];
    let e2 = p2[2] - p2[0];
    let len = vec3<f32>(length(p2[1] - p2[2]), length(e2), length(e1));
    let perim = len.x + len.y + len.z;
    let area2 = abs(e1.x * e2.y - e1.y * e2.x);
    if (!(perim > 0.0) || !(area2 >= MIN_THINNESS * perim * perim) || !(area2 < 3.0e38)) {
        cull(t);
        return;
    }
    let r = area2 / perim;
    let s = p2[0] + (len.y * e1 + len.z * e2) / perim;  // (a A + b B + c C) / (a + b + c)
    var g: array<vec2<f32>, 3>;
    for (var k = 0u; k < 3u; k++) {
        let a = p2[(k + 1u) % 3u];
        let b = p2[(k + 2u) % 3u];
        let dir = (b - a) / len[k];
        var n = vec2<f32>(dir.y, -dir.x);
        if (dot(n, p2[k] - a) > 0.0) {
            n = -n;   // outward: L_k < 0 inside
        }
        g[k] = -n / r;
    }
    var tri: Tri2D;
    tri.s = s;
    tri.opacity = opacity;
    // alpha = o * ratio^sigma >= 1/255  <=>  ratio >= (1 / (255 o))^(1/sigma)
    tri.tau = exp2(log2(ALPHA_MIN / opacity) / params.sigma);
    tri.g0 = g[0];
    tri.g1 = g[1];
    tri.g2 = g[2];
    tri.depth = zsum / 3.0;
    tri.inradius = r;
    var c = vec3<f32>(0.0);
    var cdx = vec3<f32>(0.0);
    var cdy = vec3<f32>(0.0);
    for (var k = 0u; k < 3u; k++) {
        let w = colors[vid[k]].xyz * (len[k] / perim);
        c += w;
        cdx += w * g[k].x;
        cdy += w * g[k].y;
    }
    tri.color = vec4<f32>(c, 0.0);
    tri.dcolor_dx = vec4<f32>(cdx, 0.0);
    tri.dcolor_dy = vec4<f32>(cdy, 0.0);
    // Pixel box of the alpha >= 1/255 region: the triangle shrunk about s by (1 - tau).
    let shrink = 1.0 - (tri.tau - BIN_MARGIN);
    var lo = vec2<f32>(3.0e38);
    var hi = vec2<f32>(-3.0e38);
    for (var k = 0u; k < 3u; k++) {
        let q = s + shrink * (p2[k] - s);
        lo = min(lo, q);
        hi = max(hi, q);
    }
    // pixel j is inside when j + 0.5 in [lo, hi]; clamp in float before converting
    let lim = vec2<f32>(f32(params.width), f32(params.height));
    let plo = clamp(ceil(lo - 0.5), vec2<f32>(-1.0), lim);
    let phi = clamp(floor(hi - 0.5), vec2<f32>(-1.0), lim);
    let rect = vec4<i32>(max(i32(plo.x), 0), max(i32(plo.y), 0),
                         min(i32(phi.x), i32(params.width) - 1), min(i32(phi.y), i32(params.height) - 1));
    if (rect.x > rect.z || rect.y > rect.w) {
        cull(t);
        return;
    }
    tris[local] = tri;
    pixel_rects[t] = rect;
    depth_keys[t] = bitcast<u32>(tri.depth);   // positive floats order like their bits
}
