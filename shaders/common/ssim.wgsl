// Shared by the SSIM loss stages (ssim_blur_h, ssim_loss, ssim_grad_h, ssim_grad_v, ssim_reduce).
struct SsimParams {
    width: u32,
    height: u32,
    num_pixels: u32,
    inv_n: f32,      // 1 / (3 * num_pixels)
}

// The normalised 11-tap Gaussian (sigma 1.5) of 3DGS, rounded to f32.
const GAUSS = array<f32, 11>(0.001028380123898387, 0.0075987582094967365, 0.036000773310661316,
    0.10936068743467331, 0.21300554275512695, 0.26601171493530273, 0.21300554275512695,
    0.10936068743467331, 0.036000773310661316, 0.0075987582094967365, 0.001028380123898387);
