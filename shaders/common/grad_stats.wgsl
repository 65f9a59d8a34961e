// Per (triangle, tile) sufficient statistics of the backward blend, summed over the
// tile's pixels p with d = p - s (s: the triangle's incenter as stored in Tri2D):
//   [3 c + m]      sum v_colour_c(p) * mom_m(d)        c = 0..2 (rgb), m = 0..2
//   [9 + 3 k + m]  sum over pixels whose window argmin is edge k of dL/d ratio * mom_m(d)
//   [18]           sum dL/d o_T
//   [19]           unused (zero)
// with mom_0 = 1, mom_1 = d.x, mom_2 = d.y. Every per-pixel derivative of the forward
// model is affine in p for a fixed triangle, so these 19 numbers give the exact gradient
// of the triangle's 2D vertices, vertex colours and opacity (project_backward).
const NSTAT: u32 = 20u;
