//! The smoothing ORB applies to a pyramid level before describing it, bit for bit OpenCV's:
//! a 7 x 7 Gaussian of sigma 2, separable, with reflected borders (`BORDER_REFLECT_101`,
//! `dcb|abcd|cba`).
//!
//! OpenCV's ORB blurs each level inside its padded pyramid, where `cv::GaussianBlur` becomes
//! `cv::sepFilter2D` with `getGaussianKernel(7, 2)` in `f32` (`KERNEL`). Rows first:
//! `r(x) = sum_k K[k] I(x - 3 + k)`, accumulated from `k = 0` up; then columns:
//! `c(y) = K[3] r(y)`, then `+ K[3 + j] (r(y + j) + r(y - j))` for `j = 1, 2, 3`; `c` rounded
//! half to even and saturated to `0..=255`.
//!
//! Bit for bit, the rounding of each step matters. On a CPU with AVX2 and FMA, OpenCV's x86-64
//! builds run vector kernels that fuse each multiply-add, and scalar loops, unfused, for the
//! columns left over: the row pass fuses the first `32 floor(w / 32)` columns of a `w` px row
//! (`fused_row_columns`), the column pass 32 at a time, then 16 once, then 4 at a time
//! (`fused_column_columns`). OpenCV on a CPU without them rounds a few pixels per image one
//! grey level differently.

use multiversion::multiversion;
use rayon::prelude::*;

use super::rounding::round_half_even;
use crate::image::{GrayImage, OwnedGrayImage};

/// Radius (pixels) of the kernel.
const RADIUS: usize = 3;

/// `getGaussianKernel(7, 2)` rounded to `f32`: `exp(-(k - 3)^2 / 8)` normalised to sum 1.
const KERNEL: [f32; 2 * RADIUS + 1] = {
    let (a, b, c, d) = (
        f32::from_bits(0x3d8f_afb1),
        f32::from_bits(0x3e06_387e),
        f32::from_bits(0x3e43_4a39),
        f32::from_bits(0x3e5d_4ae0),
    );
    [a, b, c, d, c, b, a]
};

/// Rows per parallel task.
const ROWS_PER_TASK: usize = 16;

/// Index `p` reflected into `0..len` as OpenCV's `borderInterpolate` does with
/// `BORDER_REFLECT_101`, repeatedly for images narrower than the kernel.
fn reflect_101(mut p: isize, len: usize) -> usize {
    let len = len as isize;
    if len == 1 {
        return 0;
    }
    while p < 0 || p >= len {
        p = if p < 0 { -p } else { 2 * (len - 1) - p };
    }
    p as usize
}

/// Columns of a `width` px row that OpenCV's row pass filters with fused multiply-adds (32 at
/// a time; the rest one at a time, unfused).
fn fused_row_columns(width: usize) -> usize {
    width - width % 32
}

/// Columns of a `width` px row that OpenCV's column pass computes with fused multiply-adds:
/// 32 at a time, then 16 once, then 4 at a time; the rest one at a time, unfused.
fn fused_column_columns(width: usize) -> usize {
    let mut fused = width - width % 32;
    if width - fused >= 16 {
        fused += 16;
    }
    fused + (width - fused) / 4 * 4
}

/// `row` filtered along x into `out`; `padded` is scratch of `row.len() + 2 RADIUS`.
#[multiversion(targets("x86_64+avx2+fma"))]
fn filter_row(row: &[u8], padded: &mut [f32], out: &mut [f32]) {
    let w = row.len();
    for (p, &v) in padded[RADIUS..RADIUS + w].iter_mut().zip(row) {
        *p = f32::from(v);
    }
    for i in 0..RADIUS {
        let (before, after) = (i as isize - RADIUS as isize, (w + i) as isize);
        padded[i] = f32::from(row[reflect_101(before, w)]);
        padded[RADIUS + w + i] = f32::from(row[reflect_101(after, w)]);
    }
    // tap k of output x is padded[x + k]; slices of equal length, so the loop vectorises
    let taps: [&[f32]; 2 * RADIUS + 1] = std::array::from_fn(|k| &padded[k..k + w]);
    let k = KERNEL;
    let fused = fused_row_columns(w);
    for (x, o) in out[..fused].iter_mut().enumerate() {
        let s = taps[0][x] * k[0];
        let s = taps[1][x].mul_add(k[1], s);
        let s = taps[2][x].mul_add(k[2], s);
        let s = taps[3][x].mul_add(k[3], s);
        let s = taps[4][x].mul_add(k[4], s);
        let s = taps[5][x].mul_add(k[5], s);
        *o = taps[6][x].mul_add(k[6], s);
    }
    for (x, o) in out.iter_mut().enumerate().skip(fused) {
        let s = taps[0][x] * k[0] + taps[1][x] * k[1];
        let s = s + taps[2][x] * k[2] + taps[3][x] * k[3];
        *o = s + taps[4][x] * k[4] + taps[5][x] * k[5] + taps[6][x] * k[6];
    }
}

/// One output row from the x-filtered rows `y - 3 ..= y + 3` (`rows[3]` the centre).
#[multiversion(targets("x86_64+avx2+fma"))]
fn filter_column(rows: [&[f32]; 2 * RADIUS + 1], out: &mut [u8]) {
    let w = out.len();
    let r = rows.map(|row| &row[..w]);
    let [k3, k4, k5, k6] = [KERNEL[3], KERNEL[4], KERNEL[5], KERNEL[6]];
    let to_u8 = |c: f32| round_half_even(c).clamp(0, 255) as u8;
    let (fused, unfused) = out.split_at_mut(fused_column_columns(w));
    for (x, o) in fused.iter_mut().enumerate() {
        let c = k3 * r[3][x];
        let c = (r[4][x] + r[2][x]).mul_add(k4, c);
        let c = (r[5][x] + r[1][x]).mul_add(k5, c);
        *o = to_u8((r[6][x] + r[0][x]).mul_add(k6, c));
    }
    let start = fused.len();
    for (x, o) in (start..).zip(unfused) {
        let c = k3 * r[3][x];
        let c = c + k4 * (r[4][x] + r[2][x]);
        let c = c + k5 * (r[5][x] + r[1][x]);
        *o = to_u8(c + k6 * (r[6][x] + r[0][x]));
    }
}

/// `image` smoothed as ORB smooths it before BRIEF (see the module doc).
pub fn smooth_for_brief(image: &GrayImage<'_>) -> OwnedGrayImage {
    let (w, h) = (image.width(), image.height());
    let mut by_rows = vec![0f32; w * h];
    by_rows
        .par_chunks_mut(ROWS_PER_TASK * w)
        .zip(image.pixels().par_chunks(ROWS_PER_TASK * w))
        .for_each(|(out, rows)| {
            let mut padded = vec![0f32; w + 2 * RADIUS];
            for (o, row) in out.chunks_exact_mut(w).zip(rows.chunks_exact(w)) {
                filter_row(row, &mut padded, o);
            }
        });
    let mut out = vec![0u8; w * h];
    out.par_chunks_mut(ROWS_PER_TASK * w)
        .enumerate()
        .for_each(|(task, rows)| {
            for (i, o) in rows.chunks_exact_mut(w).enumerate() {
                let y = (task * ROWS_PER_TASK + i) as isize;
                let window = std::array::from_fn(|k| {
                    let r = reflect_101(y + k as isize - RADIUS as isize, h);
                    &by_rows[r * w..(r + 1) * w]
                });
                filter_column(window, o);
            }
        });
    OwnedGrayImage::new(w, h, out).unwrap_or_else(|_| unreachable!("w x h pixels of an image"))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn smooth(w: usize, h: usize, data: &[u8]) -> Vec<u8> {
        smooth_for_brief(&GrayImage::new(w, h, data).unwrap()).into_pixels()
    }

    #[test]
    fn kernel_is_the_normalised_gaussian_of_sigma_2() {
        let g: Vec<f64> = (0..7)
            .map(|k| (-((k as f64 - 3.0).powi(2)) / 8.0).exp())
            .collect();
        let sum: f64 = g.iter().sum();
        let expected: Vec<f32> = g.iter().map(|v| (v / sum) as f32).collect();
        assert_eq!(KERNEL.to_vec(), expected);
    }

    #[test]
    fn reflection_mirrors_about_the_border_pixels() {
        let reflected: Vec<usize> = (-3..8).map(|p| reflect_101(p, 5)).collect();
        assert_eq!(reflected, [3, 2, 1, 0, 1, 2, 3, 4, 3, 2, 1]);
        // narrower than the kernel: reflected again
        assert_eq!(reflect_101(-3, 2), 1);
        assert_eq!(reflect_101(4, 2), 0);
        assert_eq!(reflect_101(-3, 1), 0);
    }

    #[test]
    fn fused_columns_follow_opencv_vector_widths() {
        let rows: Vec<usize> = [5, 32, 49, 640].map(fused_row_columns).to_vec();
        assert_eq!(rows, [0, 32, 32, 640]);
        // 55 = 32 + 16 + 4 + 3 and 349 = 320 + 16 + 3 * 4 + 1
        let columns: Vec<usize> = [3, 5, 55, 349, 640].map(fused_column_columns).to_vec();
        assert_eq!(columns, [0, 4, 52, 348, 640]);
    }

    #[test]
    fn a_constant_image_stays_constant() {
        for (w, h) in [(640, 480), (1, 1), (2, 3), (5, 40), (33, 17)] {
            for v in [0u8, 1, 77, 128, 254, 255] {
                let out = smooth(w, h, &vec![v; w * h]);
                assert!(out.iter().all(|&o| o == v), "{w}x{h}, value {v}");
            }
        }
    }

    #[test]
    fn a_bright_pixel_spreads_as_the_kernel() {
        let (w, h) = (15, 15);
        let mut data = vec![0u8; w * h];
        data[7 * w + 7] = 255;
        let out = smooth(w, h, &data);
        let at = |dx: usize, dy: usize| out[(7 + dy) * w + 7 + dx];
        // the peak is 255 K[3]^2, rounded
        assert_eq!(at(0, 0), (255.0 * KERNEL[3] * KERNEL[3]).round() as u8);
        // symmetric, decreasing outwards, nothing beyond the radius
        for d in 0..RADIUS {
            assert_eq!(at(d, 0), at(0, d));
            assert!(at(d, 0) >= at(d + 1, 0));
            assert_eq!(out[(7 - d) * w + 7], at(0, d));
        }
        assert_eq!(at(RADIUS + 1, 0), 0);
    }

    #[test]
    fn a_linear_ramp_is_kept_inside() {
        // the kernel is symmetric: a ramp stays a ramp away from the borders
        let (w, h) = (40, 9);
        let data: Vec<u8> = (0..w * h).map(|i| (3 * (i % w)) as u8).collect();
        let out = smooth(w, h, &data);
        for y in 0..h {
            for x in RADIUS..w - RADIUS {
                assert_eq!(out[y * w + x], data[y * w + x], "({x}, {y})");
            }
        }
    }
}
