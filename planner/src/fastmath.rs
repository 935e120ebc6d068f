//! Branch-free `exp` and `log2` approximations for the softmax policy's hot loop.
//!
//! The learner samples an action from four softmax weights every step; libm's `expf`/`logf`
//! would cost more than the rest of the step. These polynomial approximations are accurate to
//! about 1e-5 relative over the ranges the policy uses, far below the sampling noise.

/// `e^x` for `x <= 0`, clamped to 2^-126 below; relative error below 5e-5.
///
/// Written without `floor` (a libm call on baseline x86-64) so that four lanes vectorise.
#[inline(always)]
pub fn exp_neg(x: f32) -> f32 {
    // Written as compares, not `clamp`: single instructions, and NaN lands on -126.
    let t = x * std::f32::consts::LOG2_E;
    let t = if t > -126.0 { t } else { -126.0 };
    let t = if t < 0.0 { t } else { 0.0 };
    let i = t as i32; // truncates towards zero: i in [-126, 0]
    let f = t - i as f32; // in (-1, 0]
    // Taylor series of 2^f = e^(f ln 2), degree 6.
    let p = 1.0
        + f * (std::f32::consts::LN_2
            + f * (0.240_226_5
                + f * (0.055_504_11 + f * (0.009_618_13 + f * (0.001_333_36 + f * 0.000_154_04)))));
    f32::from_bits((p.to_bits() as i32).wrapping_add(i << 23) as u32)
}

/// `log2(x)` for positive, finite, normal `x`; absolute error about 1e-6.
#[inline(always)]
pub fn log2_pos(x: f32) -> f32 {
    let bits = x.to_bits();
    let mut exp = ((bits >> 23) & 0xff) as i32 - 127;
    // Mantissa in [1, 2), then folded into [sqrt(1/2), sqrt(2)) so the series below is short.
    let mut m = f32::from_bits((bits & 0x007f_ffff) | 0x3f80_0000);
    if m > std::f32::consts::SQRT_2 {
        m *= 0.5;
        exp += 1;
    }
    // ln(m) = 2 atanh(s), s = (m - 1) / (m + 1), |s| <= 0.172.
    let s = (m - 1.0) / (m + 1.0);
    let s2 = s * s;
    let ln = 2.0 * s * (1.0 + s2 * (1.0 / 3.0 + s2 * (0.2 + s2 * (1.0 / 7.0))));
    exp as f32 + ln * std::f32::consts::LOG2_E
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_matches_std() {
        let mut x = 0.0f32;
        while x > -80.0 {
            let (a, b) = (exp_neg(x), x.exp());
            assert!(((a - b) / b).abs() < 5e-5, "x={x} approx={a} std={b}");
            x -= 0.037;
        }
        assert!(exp_neg(-1e9) > 0.0);
    }

    #[test]
    fn log2_matches_std() {
        for i in 1..20000 {
            let x = i as f32 * 0.0137;
            let (a, b) = (log2_pos(x), x.log2());
            assert!((a - b).abs() < 1e-5, "x={x} approx={a} std={b}");
        }
        assert!((log2_pos(1e-30) - 1e-30f32.log2()).abs() < 1e-5);
    }
}
