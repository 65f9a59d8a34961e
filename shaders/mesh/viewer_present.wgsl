// The live viewer's present pass: one full-screen triangle puts the rgba32float frame
// (rgb = colour, a = camera z, 0 = nothing drawn) on the canvas's texture, the background
// where nothing was drawn, with the HUD's text mask over the top-left corner.

struct PresentParams {
    background: vec4<f32>,   // rgb (a unused)
    hud_size: vec2<u32>,     // width, height of the HUD text in px (0, 0: no HUD)
    _p0: u32,
    _p1: u32,
}

@group(0) @binding(0) var<uniform> params: PresentParams;
@group(0) @binding(1) var frame: texture_2d<f32>;   // rgba32float: rgb, a = z (0: nothing drawn)
@group(0) @binding(2) var hud: texture_2d<f32>;     // r8unorm text mask

@vertex
fn vs_main(@builtin(vertex_index) vi: u32) -> @builtin(position) vec4<f32> {
    let x = f32((vi << 1u) & 2u) * 2.0 - 1.0;
    let y = f32(vi & 2u) * 2.0 - 1.0;
    return vec4<f32>(x, y, 0.0, 1.0);
}

@fragment
fn fs_main(@builtin(position) pos: vec4<f32>) -> @location(0) vec4<f32> {
    let xy = vec2<i32>(pos.xy);
    let f = textureLoad(frame, xy, 0);
    var c = select(params.background.rgb, f.rgb, f.a > 0.0);
    if (u32(xy.x) < params.hud_size.x && u32(xy.y) < params.hud_size.y) {
        let m = textureLoad(hud, xy, 0).r;
        c = mix(c * 0.35, vec3<f32>(1.0, 1.0, 0.85), m);
    }
    return vec4<f32>(clamp(c, vec3<f32>(0.0), vec3<f32>(1.0)), 1.0);
}
