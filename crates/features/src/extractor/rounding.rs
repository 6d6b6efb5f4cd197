//! OpenCV's `cvRound` of `f32`: to the nearest integer, ties to even.

/// `v` rounded to the nearest integer, ties to even (OpenCV's `cvRound`), for `|v| < 2^22`.
/// `v + 1.5 * 2^23` keeps no fraction bits, so the FPU rounds it so, and its bits then count
/// whole units up from 1.5 * 2^23: integer arithmetic that vectorises, where
/// `f32::round_ties_even` is a library call on x86-64 without SSE4.1 (BRIEF 4x slower).
#[inline(always)]
pub(crate) fn round_half_even(v: f32) -> i32 {
    const SHIFT: f32 = 12_582_912.0;
    (v + SHIFT).to_bits() as i32 - SHIFT.to_bits() as i32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rounding_is_to_nearest_with_ties_to_even() {
        let cases = [
            (0.5, 0),
            (1.5, 2),
            (2.5, 2),
            (-0.5, 0),
            (-1.5, -2),
            (2.4999, 2),
            (-2.6, -3),
            (17.0, 17),
        ];
        for (v, want) in cases {
            assert_eq!(round_half_even(v), want, "{v}");
        }
    }
}
