// Gradient of the real SH basis (shaders/common/sh.wgsl) with respect to the direction,
// treating (x, y, z) as free variables; the caller projects it onto the unit sphere.
#import sh

fn sh_basis_grad(k: u32, d: vec3<f32>) -> vec3<f32> {
    let x = d.x;
    let y = d.y;
    let z = d.z;
    switch k {
        case 0u: { return vec3<f32>(0.0); }
        case 1u: { return vec3<f32>(0.0, -SH_C1, 0.0); }
        case 2u: { return vec3<f32>(0.0, 0.0, SH_C1); }
        case 3u: { return vec3<f32>(-SH_C1, 0.0, 0.0); }
        case 4u: { return SH_C2_0 * vec3<f32>(y, x, 0.0); }
        case 5u: { return SH_C2_1 * vec3<f32>(0.0, z, y); }
        case 6u: { return SH_C2_2 * vec3<f32>(-2.0 * x, -2.0 * y, 4.0 * z); }
        case 7u: { return SH_C2_3 * vec3<f32>(z, 0.0, x); }
        case 8u: { return SH_C2_4 * vec3<f32>(2.0 * x, -2.0 * y, 0.0); }
        case 9u: { return SH_C3_0 * vec3<f32>(6.0 * x * y, 3.0 * x * x - 3.0 * y * y, 0.0); }
        case 10u: { return SH_C3_1 * vec3<f32>(y * z, x * z, x * y); }
        case 11u: { return SH_C3_2 * vec3<f32>(-2.0 * x * y, 4.0 * z * z - x * x - 3.0 * y * y, 8.0 * y * z); }
        case 12u: { return SH_C3_3 * vec3<f32>(-6.0 * x * z, -6.0 * y * z, 6.0 * z * z - 3.0 * x * x - 3.0 * y * y); }
        case 13u: { return SH_C3_4 * vec3<f32>(4.0 * z * z - 3.0 * x * x - y * y, -2.0 * x * y, 8.0 * x * z); }
        case 14u: { return SH_C3_5 * vec3<f32>(2.0 * x * z, -2.0 * y * z, x * x - y * y); }
        default: { return SH_C3_6 * vec3<f32>(3.0 * x * x - 3.0 * y * y, -6.0 * x * y, 0.0); }
    }
}
