// The live viewer's wireframe: a line list pulled from the same storage buffers the trainer
// (or a loaded model) keeps: 3 edges per triangle, 2 ends per edge, no vertex buffers.
// Colour: the vertex's colour from this camera, max(0, SH(dir) + 0.5), which the forward's own
// sh_to_color writes just before (Renderer.record_vertex_colors: in ranges of vertices where the
// SH outgrow one storage binding, so a model of any size is coloured whole).

struct WireParams {
    clip_from_world: mat4x4<f32>,   // P * world_to_camera (column-major), as MeshParams
}

@group(0) @binding(0) var<uniform> params: WireParams;
@group(0) @binding(1) var<storage, read> positions: array<f32>;   // [N, 3]
@group(0) @binding(2) var<storage, read> triangles: array<u32>;   // [M, 3]
@group(0) @binding(3) var<storage, read> colors: array<vec4<f32>>; // [N]: rgb, 1

struct Out {
    @builtin(position) clip: vec4<f32>,
    @location(0) color: vec3<f32>,
}

@vertex
fn vs_main(@builtin(vertex_index) vi: u32) -> Out {
    // line list: 3 edges per triangle, 2 ends per edge
    let e = vi / 2u;
    let tri = e / 3u;
    let corner = (e % 3u + vi % 2u) % 3u;
    let v = triangles[3u * tri + corner];
    let p = vec3<f32>(positions[3u * v], positions[3u * v + 1u], positions[3u * v + 2u]);
    var out: Out;
    out.clip = params.clip_from_world * vec4<f32>(p, 1.0);
    out.color = colors[v].rgb;
    return out;
}

@fragment
fn fs_main(in: Out) -> @location(0) vec4<f32> {
    return vec4<f32>(in.color, 1.0);
}
