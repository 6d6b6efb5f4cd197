//! Bilinear resizing of 8-bit images, bit for bit OpenCV's `cv::resize` with
//! `INTER_LINEAR_EXACT` (the resize OpenCV's ORB builds its pyramid with; its fixed-point
//! arithmetic is the same on every machine).
//!
//! Output column `u` samples the source at `x = s (u + 0.5) - 0.5` with
//! `s = 1 / (width_out / width_in)`, in `f64` and in that order, as OpenCV computes it; rows
//! likewise. Along each axis the sample interpolates pixels `floor(x)` and `floor(x) + 1` with
//! weights in 8.8 fixed point, `w1 = round_half_even(256 frac(x))` and `w0 = 256 - w1`; a
//! sample before the first pixel centre takes the first pixel, one past the last the last.
//! Rows are interpolated first, exactly (`w0 a + w1 b` < 2^16), then columns, with a single
//! rounding at the end: `(w0 h0 + w1 h1 + 2^15) >> 16`.
//!
//! (OpenCV halves an image by averaging 2 x 2 blocks instead, `(a + b + c + d + 2) >> 2`:
//! the same values, as both weights are then 128.)

use rayon::prelude::*;

use crate::image::{GrayImage, OwnedGrayImage};

/// 1 in 8.8 fixed point.
const ONE: u32 = 256;

/// Output rows per parallel task: the source rows a task needs are interpolated once within
/// it, and the first one again by the previous task.
const ROWS_PER_TASK: usize = 16;

/// Where one output pixel samples along one axis: two source indices and their weights
/// (8.8 fixed point, summing to 1).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Tap {
    first: usize,
    second: usize,
    weights: [u32; 2],
}

/// The taps of the `dst` output pixels along an axis of `src` source pixels (both >= 1).
fn taps(src: usize, dst: usize) -> Vec<Tap> {
    let scale = 1.0 / (dst as f64 / src as f64);
    let clamped = |i| Tap {
        first: i,
        second: i,
        weights: [ONE, 0],
    };
    (0..dst)
        .map(|u| {
            let x = scale * (u as f64 + 0.5) - 0.5;
            let i = x.floor();
            if i < 0.0 || src == 1 {
                clamped(0)
            } else if i as usize >= src - 1 {
                clamped(src - 1)
            } else {
                let w1 = ((x - i) * f64::from(ONE)).round_ties_even() as u32;
                Tap {
                    first: i as usize,
                    second: i as usize + 1,
                    weights: [ONE - w1, w1],
                }
            }
        })
        .collect()
}

/// The source rows of one task, interpolated along x: row `y` in slot `y % 2`. The two rows
/// an output row needs are equal or neighbours, so they never share a slot.
struct InterpolatedRows<'a> {
    src: GrayImage<'a>,
    x_taps: &'a [Tap],
    row_in_slot: [Option<usize>; 2],
    slots: [Vec<u16>; 2],
}

impl InterpolatedRows<'_> {
    /// Source rows `y0` and `y1` (`y1 == y0` or `y0 + 1`), interpolated along x.
    fn pair(&mut self, y0: usize, y1: usize) -> (&[u16], &[u16]) {
        for y in [y0, y1] {
            let slot = y % 2;
            if self.row_in_slot[slot] != Some(y) {
                let w = self.src.width();
                let row = &self.src.pixels()[y * w..(y + 1) * w];
                for (out, t) in self.slots[slot].iter_mut().zip(self.x_taps) {
                    let (a, b) = (u32::from(row[t.first]), u32::from(row[t.second]));
                    // < 256 * 255 + 1: no overflow
                    *out = (t.weights[0] * a + t.weights[1] * b) as u16;
                }
                self.row_in_slot[slot] = Some(y);
            }
        }
        (&self.slots[y0 % 2], &self.slots[y1 % 2])
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
    let x_taps = taps(src.width(), width);
    let y_taps = taps(src.height(), height);
    let mut out = vec![0u8; width * height];
    out.par_chunks_mut(ROWS_PER_TASK * width)
        .zip(y_taps.par_chunks(ROWS_PER_TASK))
        .for_each(|(rows, y_taps)| {
            let mut lines = InterpolatedRows {
                src: *src,
                x_taps: &x_taps,
                row_in_slot: [None; 2],
                slots: [vec![0; width], vec![0; width]],
            };
            for (row, t) in rows.chunks_exact_mut(width).zip(y_taps) {
                let (h0, h1) = lines.pair(t.first, t.second);
                let [w0, w1] = t.weights;
                for ((o, &a), &b) in row.iter_mut().zip(h0).zip(h1) {
                    // < 2^24 + 2^15, and the shift leaves at most 255
                    *o = ((w0 * u32::from(a) + w1 * u32::from(b) + (1 << 15)) >> 16) as u8;
                }
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
        assert_eq!((out.width(), out.height()), (dw, dh));
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
        let t = taps(6, 5);
        let weights: Vec<[u32; 2]> = t.iter().map(|t| t.weights).collect();
        assert_eq!(
            weights,
            [[230, 26], [179, 77], [128, 128], [77, 179], [26, 230]]
        );
        let firsts: Vec<usize> = t.iter().map(|t| t.first).collect();
        assert_eq!(firsts, [0, 1, 2, 3, 4]);
        // 2 -> 4: x = 0.5 u - 0.25, the first sample before the first centre, the last
        // (1.25) past the last
        let clamped = |i| Tap {
            first: i,
            second: i,
            weights: [256, 0],
        };
        let second = Tap {
            first: 0,
            second: 1,
            weights: [192, 64],
        };
        assert_eq!(
            taps(2, 4),
            [
                clamped(0),
                second,
                Tap {
                    weights: [64, 192],
                    ..second
                },
                clamped(1)
            ]
        );
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
