//! Bilinear resizing of 8-bit images, bit for bit OpenCV's `cv::resize` with
//! `INTER_LINEAR_EXACT` (the resize OpenCV's ORB builds its pyramid with; its fixed-point
//! arithmetic is the same on every machine).
//!
//! Output column `u` samples the source at `x = s (u + 0.5) - 0.5` with
//! `s = 1 / (width_out / width_in)`, in `f64` and in that order, as OpenCV computes it; rows
//! likewise. Along each axis the sample interpolates pixels `floor(x)` and `floor(x) + 1` with
//! weights in 8.8 fixed point, `w1 = round_half_even(256 frac(x))` and `w0 = 256 - w1`; a
//! sample before the first pixel centre takes the first pixel, one past the last the last.
//! The value is `(wy0 (wx0 a + wx1 b) + wy1 (wx0 c + wx1 d) + 2^15) >> 16`, rounded once: the
//! sums are exact integers, so OpenCV's order (along x first) and ours (along y first, which
//! vectorises) give the same value.
//!
//! (OpenCV halves an image by averaging 2 x 2 blocks instead, `(a + b + c + d + 2) >> 2`:
//! the same values, as both weights are then 128.)

use multiversion::multiversion;
use rayon::prelude::*;

use crate::image::{GrayImage, OwnedGrayImage};

/// 1 in 8.8 fixed point.
const ONE: u16 = 256;

/// Output rows per parallel task.
const ROWS_PER_TASK: usize = 16;

/// Where the output pixels sample along one axis: output `u` blends source pixels `first[u]`
/// and `first[u] + 1` with weights `ONE - w1[u]` and `w1[u]` (8.8 fixed point). A sample
/// clamped to an end pixel has `w1 = 0`, so its second pixel (maybe one past the end) counts
/// for nothing.
#[derive(Clone, Debug, PartialEq, Eq)]
struct Taps {
    first: Vec<u32>,
    w1: Vec<u16>,
}

impl Taps {
    /// The taps of `dst` output pixels along an axis of `src` source pixels (both >= 1).
    fn new(src: usize, dst: usize) -> Self {
        let scale = 1.0 / (dst as f64 / src as f64);
        let (first, w1) = (0..dst)
            .map(|u| {
                let x = scale * (u as f64 + 0.5) - 0.5;
                let i = x.floor();
                if i < 0.0 || src == 1 {
                    (0, 0)
                } else if i as usize >= src - 1 {
                    ((src - 1) as u32, 0)
                } else {
                    let w1 = ((x - i) * f64::from(ONE)).round_ties_even() as u16;
                    (i as u32, w1)
                }
            })
            .unzip();
        Self { first, w1 }
    }
}

/// Two output rows are resized together, one in each 32-bit half of a `u64`: a vertical blend
/// stays below 2^16 and the horizontal one below 2^25, so one 64-bit multiply-add serves both
/// rows without carrying from one into the other.
const LANE_BITS: u32 = 32;

/// The vertical blends of two output rows: `out[x]` holds
/// `(ONE - w1) a0[x] + w1 a1[x]` (exact, at most 256 * 255) of each row `(a0, a1, w1)`, the
/// first row in the low half.
#[multiversion(targets("x86_64+avx2"))]
fn blend_rows(rows: [(&[u8], &[u8], u16); 2], out: &mut [u64]) {
    let [(a0, a1, wa), (b0, b1, wb)] = rows;
    let (wa0, wa1) = (u64::from(ONE - wa), u64::from(wa));
    let (wb0, wb1) = (u64::from(ONE - wb), u64::from(wb));
    let pixels = a0.iter().zip(a1).zip(b0.iter().zip(b1));
    for (o, ((&a0, &a1), (&b0, &b1))) in out.iter_mut().zip(pixels) {
        let a = wa0 * u64::from(a0) + wa1 * u64::from(a1);
        let b = wb0 * u64::from(b0) + wb1 * u64::from(b1);
        *o = a | (b << LANE_BITS);
    }
}

/// The two rows blended by [`blend_rows`] (one more entry readable past the last pixel)
/// interpolated at the taps and rounded, into `out0` and `out1`.
#[multiversion(targets("x86_64+avx2"))]
fn interpolate(blended: &[u64], taps: &Taps, out0: &mut [u8], out1: &mut [u8]) {
    const HALF: u64 = 1 << 15;
    let columns = taps.first.iter().zip(&taps.w1);
    for ((o0, o1), (&first, &w1)) in out0.iter_mut().zip(out1).zip(columns) {
        let i = first as usize;
        let (w0, w1) = (u64::from(ONE - w1), u64::from(w1));
        let s = w0 * blended[i] + w1 * blended[i + 1] + (HALF | HALF << LANE_BITS);
        // each half is below 2^24 + 2^15: shifted down by 16 it is at most 255
        *o0 = (s >> 16) as u8;
        *o1 = (s >> (LANE_BITS + 16)) as u8;
    }
}

/// `src` resized to `width x height` pixels (see the module doc); `None` when either is 0.
pub fn resize_linear_exact(
    src: &GrayImage<'_>,
    width: usize,
    height: usize,
) -> Option<OwnedGrayImage> {
    if width == 0 || height == 0 {
        return None;
    }
    let (sw, sh) = (src.width(), src.height());
    let x_taps = Taps::new(sw, width);
    let y_taps = Taps::new(sh, height);
    let source_rows = |y: usize| {
        let (y0, w1) = (y_taps.first[y] as usize, y_taps.w1[y]);
        let row = |y: usize| &src.pixels()[y * sw..(y + 1) * sw];
        (row(y0), row((y0 + 1).min(sh - 1)), w1)
    };
    let mut out = vec![0u8; width * height];
    out.par_chunks_mut(ROWS_PER_TASK * width)
        .enumerate()
        .for_each(|(task, rows)| {
            // one entry more, read with weight 0 by taps clamped to the last pixel
            let mut blended = vec![0u64; sw + 1];
            let mut spare = vec![0u8; width];
            for (pair, out_rows) in rows.chunks_mut(2 * width).enumerate() {
                let y = task * ROWS_PER_TASK + 2 * pair;
                let (out0, out1) = out_rows.split_at_mut(width);
                // an odd last row is resized twice, the copy into `spare`
                let (y1, out1) = match out1.is_empty() {
                    true => (y, &mut spare[..]),
                    false => (y + 1, out1),
                };
                blend_rows([source_rows(y), source_rows(y1)], &mut blended[..sw]);
                interpolate(&blended, &x_taps, out0, out1);
            }
        });
    OwnedGrayImage::new(width, height, out).ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn resize(w: usize, h: usize, data: &[u8], dw: usize, dh: usize) -> Vec<u8> {
        let src = GrayImage::new(w, h, data).unwrap();
        let out = resize_linear_exact(&src, dw, dh).unwrap();
        assert_eq!((out.view().width(), out.view().height()), (dw, dh));
        out.into_pixels()
    }

    #[test]
    fn a_constant_image_stays_constant() {
        for (w, h, dw, dh) in [
            (640, 480, 533, 400),
            (37, 11, 5, 9),
            (1, 1, 3, 2),
            (9, 2, 1, 1),
        ] {
            for v in [0, 1, 128, 254, 255] {
                let out = resize(w, h, &vec![v; w * h], dw, dh);
                assert!(
                    out.iter().all(|&o| o == v),
                    "{w}x{h} -> {dw}x{dh}, value {v}"
                );
            }
        }
    }

    #[test]
    fn halving_averages_two_by_two_blocks() {
        let (w, h) = (10, 6);
        let data: Vec<u8> = (0..w * h).map(|i| (i * 37 % 256) as u8).collect();
        let out = resize(w, h, &data, w / 2, h / 2);
        for (i, &o) in out.iter().enumerate() {
            let (x, y) = (2 * (i % (w / 2)), 2 * (i / (w / 2)));
            let sum: u32 = [(0, 0), (1, 0), (0, 1), (1, 1)]
                .iter()
                .map(|(dx, dy)| u32::from(data[(y + dy) * w + x + dx]))
                .sum();
            assert_eq!(u32::from(o), (sum + 2) >> 2, "pixel {i}");
        }
    }

    #[test]
    fn same_size_is_a_copy() {
        let data: Vec<u8> = (0..35).map(|i| (i * 71 % 256) as u8).collect();
        assert_eq!(resize(7, 5, &data, 7, 5), data);
    }

    #[test]
    fn taps_follow_opencv_sampling() {
        // 6 -> 5: s = 1.2, x = 1.2 u + 0.1
        let t = Taps::new(6, 5);
        assert_eq!(t.first, [0, 1, 2, 3, 4]);
        assert_eq!(t.w1, [26, 77, 128, 179, 230]);
        // 2 -> 4: x = 0.5 u - 0.25, the first sample before the first centre, the last
        // (1.25) past the last
        let t = Taps::new(2, 4);
        assert_eq!(t.first, [0, 0, 0, 1]);
        assert_eq!(t.w1, [0, 64, 192, 0]);
    }

    #[test]
    fn ramps_stay_monotonic_and_sizes_are_kept() {
        let (w, h) = (97, 61);
        let data: Vec<u8> = (0..w * h).map(|i| ((i % w) * 2 + i / w) as u8).collect();
        let out = resize(w, h, &data, 81, 51);
        for row in out.chunks_exact(81) {
            assert!(row.windows(2).all(|p| p[0] <= p[1]));
        }
        assert!(resize_linear_exact(&GrayImage::new(w, h, &data).unwrap(), 0, 5).is_none());
    }
}
