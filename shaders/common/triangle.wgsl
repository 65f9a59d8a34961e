// A triangle projected to the image, in the form the blend reads.
//
// Window ratio: e_k(p) = 1 + dot(g_k, p - s) is edge k's signed distance divided by
// phi(s) = -r (1 at the incenter s, 0 on the edge); phi(p)/phi(s) = min_k e_k(p).
// Colour is affine in screen space: c(p) = color + dcolor_dx * (p-s).x + dcolor_dy * (p-s).y
// (screen-space barycentrics b_k(p) = e_k(p) * len_k / perimeter).
struct Tri2D {
    s: vec2<f32>,         // incenter, pixels
    opacity: f32,         // min of the vertices' opacities
    tau: f32,             // window ratio at which alpha reaches 1/255
    g0: vec2<f32>,
    g1: vec2<f32>,
    g2: vec2<f32>,
    depth: f32,           // camera-space z of the centroid
    inradius: f32,
    color: vec4<f32>,     // rgb at s
    dcolor_dx: vec4<f32>,
    dcolor_dy: vec4<f32>,
}

// Does the alpha >= 1/255 region of the triangle (the triangle shrunk about s to
// {min_k e_k >= tau}) meet the rectangle [lo, hi] of pixel centres? Separating axes:
// the rectangle's (already ensured by the caller's pixel bounding box) and the three
// edge normals. Used by both the counting and the writing pass of binning.
fn rect_overlaps(t: Tri2D, lo: vec2<f32>, hi: vec2<f32>) -> bool {
    let thr = t.tau - BIN_MARGIN;
    // (unrolled: no loop, see the loop budget note in frame.wgsl)
    return edge_reaches(t.g0, t.s, lo, hi, thr) && edge_reaches(t.g1, t.s, lo, hi, thr)
        && edge_reaches(t.g2, t.s, lo, hi, thr);
}

// Largest e = 1 + g.(p - s) over the rectangle [lo, hi] (at the corner g points to) >= thr?
fn edge_reaches(g: vec2<f32>, s: vec2<f32>, lo: vec2<f32>, hi: vec2<f32>, thr: f32) -> bool {
    let corner = vec2<f32>(select(lo.x, hi.x, g.x > 0.0), select(lo.y, hi.y, g.y > 0.0));
    return 1.0 + dot(g, corner - s) >= thr;
}

// Rectangle of pixel centres shared by tile (tx, ty) and the triangle's pixel box
// rect = (x0, y0, x1, y1), inclusive pixel indices.
fn tile_overlaps(t: Tri2D, rect: vec4<i32>, tx: i32, ty: i32) -> bool {
    let x0 = max(rect.x, tx * i32(TILE));
    let y0 = max(rect.y, ty * i32(TILE));
    let x1 = min(rect.z, tx * i32(TILE) + i32(TILE) - 1);
    let y1 = min(rect.w, ty * i32(TILE) + i32(TILE) - 1);
    if (x0 > x1 || y0 > y1) {
        return false;
    }
    return rect_overlaps(t, vec2<f32>(f32(x0), f32(y0)) + 0.5, vec2<f32>(f32(x1), f32(y1)) + 0.5);
}
