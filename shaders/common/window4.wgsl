// The forward blend's per-pixel window and alpha for four pixels of a column at once, used by
// both variants of rasterize_forward (the image, and with TRIANGLE_IDS the triangle-ID buffer)
// so that the two make the same decisions bit for bit. Needs frame.wgsl (ALPHA_MAX).

// min_k of the edge ratios L_k / phi(s) at four pixels dy rows below the staged origin: the
// window's base max(0, .) before the power (a = value at the origin, gy = per-row step).
fn ratio4(dy: vec4<f32>, a: vec3<f32>, gy: vec3<f32>) -> vec4<f32> {
    return min(min(a.x + gy.x * dy, a.y + gy.y * dy), a.z + gy.z * dy);
}

// alpha = min(0.99, o_T * ratio^sigma) at four pixels (ratio <= 0 gives 0 through the clamp).
fn alpha4(ratio: vec4<f32>, opacity: f32, sigma: f32) -> vec4<f32> {
    return min(vec4<f32>(ALPHA_MAX), opacity * exp2(sigma * log2(max(ratio, vec4<f32>(1e-30)))));
}

// The same at one pixel (the GPU layout's kernels, one pixel per invocation): the same
// operations in the same order as one lane of ratio4 / alpha4.
fn ratio1(dy: f32, a: vec3<f32>, gy: vec3<f32>) -> f32 {
    return min(min(a.x + gy.x * dy, a.y + gy.y * dy), a.z + gy.z * dy);
}

fn alpha1(ratio: f32, opacity: f32, sigma: f32) -> f32 {
    return min(ALPHA_MAX, opacity * exp2(sigma * log2(max(ratio, 1e-30))));
}
