// Per pixel, the state the backward blend starts from and carries between its passes:
// (T = 1, acc = 0, Z = image . v + T_final * v_T, last contributing pair + 1 as bits).
#import frame
#import dispatch

@group(0) @binding(0) var<uniform> params: FrameParams;
@group(0) @binding(1) var<storage, read> image: array<f32>;             // [H, W, 3]
@group(0) @binding(2) var<storage, read> final_t: array<f32>;           // [H, W]
@group(0) @binding(3) var<storage, read> n_contrib: array<vec2<u32>>;   // [H, W]
@group(0) @binding(4) var<storage, read> v_out: array<vec4<f32>>;       // [H, W]
@group(0) @binding(5) var<storage, read_write> state: array<vec4<f32>>; // [H, W]

const WG: u32 = 256u;   // invocations per workgroup

@compute @workgroup_size(WG)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) li: u32) {
    let pix = linear_group(wid, nwg) * WG + li;
    if (pix >= params.width * params.height) {
        return;
    }
    let v = v_out[pix];
    let z = dot(vec3<f32>(image[3u * pix], image[3u * pix + 1u], image[3u * pix + 2u]), v.xyz) + final_t[pix] * v.w;
    state[pix] = vec4<f32>(1.0, 0.0, z, bitcast<f32>(n_contrib[pix].x));
}
