// Shared by the SSIM loss stages (ssim_blur_h, ssim_loss, ssim_grad_h, ssim_grad_v, ssim_reduce).
struct SsimParams {
    width: u32,
    height: u32,
    num_pixels: u32,
    inv_n: f32,      // 1 / (3 * num_pixels)
}

// Pixels per workgroup of the per-pixel SSIM stages (ssim_loss writes one partial per group).
const SSIM_GROUP: u32 = 256u;
// Outputs per invocation of the four blur stages: a run of SSIM_SEG pixels along the blur's
// direction (a row for ssim_blur_h / ssim_grad_h, a column for ssim_loss / ssim_grad_v), with the
// window's 11 inputs kept in registers, so each input is loaded once per run, not 11 times.
const SSIM_SEG: u32 = 16u;
// The loss: L1_WEIGHT * L1 + SSIM_WEIGHT * (1 - SSIM); SSIM's stabilisers C1 = 0.01^2, C2 = 0.03^2.
const L1_WEIGHT: f32 = 0.8;
const SSIM_WEIGHT: f32 = 0.2;
const C1: f32 = 0.0001;
const C2: f32 = 0.0009;
// The window: RADIUS taps either side (11 taps), Gaussian of standard deviation WINDOW_SIGMA.
const RADIUS: i32 = 5;
const WINDOW_SIGMA: f32 = 1.5;

// The normalised 11-tap Gaussian (sigma 1.5) of 3DGS, rounded to f32.
const GAUSS = array<f32, 11>(0.001028380123898387, 0.0075987582094967365, 0.036000773310661316,
    0.10936068743467331, 0.21300554275512695, 0.26601171493530273, 0.21300554275512695,
    0.10936068743467331, 0.036000773310661316, 0.0075987582094967365, 0.001028380123898387);

// The window of the blur stages over the three derivative maps (ssim_grad_h, ssim_grad_v): slot
// k holds the sample at offset k - RADIUS from the output pixel (0 outside the image).
var<private> win_a: array<vec4<f32>, 11>;
var<private> win_b: array<vec4<f32>, 11>;
var<private> win_c: array<vec4<f32>, 11>;

// One pixel of the three maps (a, b, c), or their blurs.
struct Maps3 {
    a: vec4<f32>,
    b: vec4<f32>,
    c: vec4<f32>,
}

fn win3_set(k: i32, m: Maps3) {
    win_a[k] = m.a;
    win_b[k] = m.b;
    win_c[k] = m.c;
}

// Slide the window one pixel on (the samples move down a slot, m enters at the top) and return
// the blur at the new output pixel, the taps summed in window order.
fn win3_push_blur(m: Maps3) -> Maps3 {
    for (var k = 0; k < 2 * RADIUS; k++) {
        win_a[k] = win_a[k + 1];
        win_b[k] = win_b[k + 1];
        win_c[k] = win_c[k + 1];
    }
    win3_set(2 * RADIUS, m);
    var out = Maps3(vec4<f32>(0.0), vec4<f32>(0.0), vec4<f32>(0.0));
    for (var k = 0; k < 2 * RADIUS + 1; k++) {
        let w = GAUSS[k];
        out.a += w * win_a[k];
        out.b += w * win_b[k];
        out.c += w * win_c[k];
    }
    return out;
}
