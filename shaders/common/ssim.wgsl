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
