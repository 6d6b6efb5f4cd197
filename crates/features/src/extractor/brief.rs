//! Rotated BRIEF, ORB's steered descriptor (Rublee et al., ICCV 2011): 256 intensity
//! comparisons between pixel pairs of a smoothed image around an oriented corner, the pairs
//! rotated by the corner's angle.
//!
//! The comparisons are OpenCV's, to the bit: the pattern is rotated in `f32` (`x cos - y sin`,
//! `x sin + y cos`), offsets are rounded half to even, and bit `k` of byte `i` is
//! `I(first) < I(second)` of test `8 i + k`. With OpenCV's tests ([`BriefPattern::opencv`])
//! on levels smoothed as OpenCV's ORB smooths them ([`smooth_for_brief`]), the descriptors
//! equal those of the ORB implementation the vocabulary was trained with.
//!
//! [`smooth_for_brief`]: super::smoothing::smooth_for_brief

use rayon::prelude::*;

use super::opencv_brief_tests::OPENCV_BRIEF_TESTS;
use super::rounding::round_half_even;
use crate::{Descriptor, GrayImage};

/// Offsets (pixels, x right, y down) of the two pixels one test compares, before rotation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BriefTest {
    /// The pixel whose intensity must be the lower for the bit to be set.
    pub first: [i8; 2],
    /// The pixel compared against.
    pub second: [i8; 2],
}

/// The 256 tests of a descriptor, test `8 i + k` giving bit `k` of byte `i`.
#[derive(Clone, Debug, PartialEq)]
pub struct BriefPattern {
    /// Coordinates of the test pixels, `2 j` the first and `2 j + 1` the second of test `j`
    /// (apart, so that rotating them all vectorises).
    xs: [f32; 512],
    ys: [f32; 512],
    /// Largest distance (pixels) of a test pixel from the centre, over all rotations.
    reach_px: f32,
}

impl BriefPattern {
    /// The pattern of `tests`.
    pub fn new(tests: &[BriefTest; 256]) -> Self {
        let points = || tests.iter().flat_map(|t| [t.first, t.second]);
        let mut xs = [0.0; 512];
        let mut ys = [0.0; 512];
        for ((x, y), [px, py]) in xs.iter_mut().zip(&mut ys).zip(points()) {
            (*x, *y) = (f32::from(px), f32::from(py));
        }
        let reach_px = points()
            .map(|[x, y]| f32::from(x).hypot(f32::from(y)))
            .fold(0.0, f32::max);
        Self { xs, ys, reach_px }
    }

    /// OpenCV's ORB pattern ([`OPENCV_BRIEF_TESTS`]).
    pub fn opencv() -> Self {
        Self::new(&OPENCV_BRIEF_TESTS.map(|[x1, y1, x2, y2]| BriefTest {
            first: [x1, y1],
            second: [x2, y2],
        }))
    }

    /// Largest distance (pixels) of a test pixel from the centre: a corner needs this much
    /// room, rounded, on every side.
    pub fn reach_px(&self) -> f32 {
        self.reach_px
    }

    /// The descriptor of the corner at pixel `(x, y)` of `smoothed` with orientation
    /// `angle_deg`; `None` when the corner lies closer to the border than the tests reach
    /// (at any angle).
    pub fn describe(
        &self,
        smoothed: &GrayImage<'_>,
        x: usize,
        y: usize,
        angle_deg: f32,
    ) -> Option<Descriptor> {
        let angle = angle_deg * (std::f32::consts::PI / 180.0);
        let (sin, cos) = (f64::from(angle).sin() as f32, f64::from(angle).cos() as f32);
        let (w, h) = (smoothed.width(), smoothed.height());
        // A rotated offset is at most the reach long; rounding is monotonic.
        let room = self.reach_px.round() as usize;
        if x < room || y < room || x + room >= w || y + room >= h {
            return None;
        }
        // Offsets of the rotated test pixels from the centre, in the row-major buffer.
        let stride = w as i32;
        let mut offsets = [0i32; 512];
        for ((o, &px), &py) in offsets.iter_mut().zip(&self.xs).zip(&self.ys) {
            *o = round_half_even(py * cos + px * sin) * stride
                + round_half_even(px * cos - py * sin);
        }
        let centre = &smoothed.pixels()[(y - room) * w + x - room..];
        let centre_at = (room * w + room) as i32;
        let at = |o: i32| centre[(centre_at + o) as usize];
        let mut descriptor = [0u8; 32];
        for (byte, pairs) in descriptor.iter_mut().zip(offsets.chunks_exact(16)) {
            *byte = pairs.chunks_exact(2).enumerate().fold(0, |b, (k, pair)| {
                b | (u8::from(at(pair[0]) < at(pair[1])) << k)
            });
        }
        Some(descriptor)
    }

    /// [`BriefPattern::describe`] for many corners `(level, x, y, angle_deg)` of a smoothed
    /// pyramid, in parallel; `None` where the corner's level is missing or its tests leave
    /// the level.
    pub fn describe_all(
        &self,
        smoothed: &[GrayImage<'_>],
        corners: &[(usize, usize, usize, f32)],
    ) -> Vec<Option<Descriptor>> {
        corners
            .par_iter()
            .with_min_len(64)
            .map(|&(level, x, y, angle_deg)| self.describe(smoothed.get(level)?, x, y, angle_deg))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 256 tests with offsets in [-13, 13], from a fixed linear congruential sequence.
    fn pattern() -> BriefPattern {
        let mut s: u32 = 2011;
        let mut next = || {
            s = s.wrapping_mul(1_103_515_245).wrapping_add(12_345);
            ((s >> 16) % 27) as i8 - 13
        };
        let tests = std::array::from_fn(|_| BriefTest {
            first: [next(), next()],
            second: [next(), next()],
        });
        BriefPattern::new(&tests)
    }

    /// A `side x side` image of pseudo-random intensities.
    fn noise(side: usize) -> Vec<u8> {
        (0..side * side)
            .map(|i| ((i * 7919 + 13) % 251) as u8 ^ ((i / side) as u8).wrapping_mul(31))
            .collect()
    }

    #[test]
    fn unrotated_bits_compare_the_test_pixels() {
        let p = pattern();
        let data = noise(48);
        let img = GrayImage::new(48, 48, &data).unwrap();
        let d = p.describe(&img, 24, 24, 0.0).unwrap();
        let at =
            |[x, y]: [f32; 2]| data[(24 + y as isize) as usize * 48 + (24 + x as isize) as usize];
        for j in 0..256 {
            let (a, b) = (
                [p.xs[2 * j], p.ys[2 * j]],
                [p.xs[2 * j + 1], p.ys[2 * j + 1]],
            );
            assert_eq!((d[j / 8] >> (j % 8)) & 1 == 1, at(a) < at(b), "test {j}");
        }
    }

    /// Turning the image a quarter turn about the corner and the corner's angle with it
    /// gives the same descriptor (sin 90 deg and cos 90 deg round to exact offsets).
    #[test]
    fn a_quarter_turn_of_image_and_angle_keeps_the_descriptor() {
        let (side, c) = (49, 24isize);
        let a = noise(side);
        // b(c + u) = a(c + (u_y, -u_x)): a turned by +90 degrees (x right, y down).
        let b: Vec<u8> = (0..side * side)
            .map(|i| {
                let (ux, uy) = ((i % side) as isize - c, (i / side) as isize - c);
                a[((c - ux) * side as isize + c + uy) as usize]
            })
            .collect();
        let p = pattern();
        let img_a = GrayImage::new(side, side, &a).unwrap();
        let img_b = GrayImage::new(side, side, &b).unwrap();
        assert_eq!(
            p.describe(&img_a, 24, 24, 0.0),
            p.describe(&img_b, 24, 24, 90.0)
        );
        assert_ne!(
            p.describe(&img_a, 24, 24, 0.0),
            p.describe(&img_b, 24, 24, 0.0)
        );
    }

    #[test]
    fn opencv_tests_fit_inside_the_border_keypoints_keep() {
        let reach = BriefPattern::opencv().reach_px();
        assert!(reach.round() < super::super::EDGE_PX as f32, "{reach}");
        // one test compares a pixel with itself in none
        assert!(OPENCV_BRIEF_TESTS
            .iter()
            .all(|[x1, y1, x2, y2]| (x1, y1) != (x2, y2)));
    }

    #[test]
    fn corners_without_room_for_the_tests_get_none() {
        let p = pattern();
        let room = p.reach_px().round() as usize;
        let data = noise(48);
        let img = GrayImage::new(48, 48, &data).unwrap();
        assert!(p.describe(&img, room, room, 30.0).is_some());
        assert!(p.describe(&img, room - 1, 24, 30.0).is_none());
        assert!(p.describe(&img, 24, 48 - room, 30.0).is_none());
        let all = p.describe_all(
            &[img],
            &[(0, 24, 24, 10.0), (1, 24, 24, 10.0), (0, 2, 2, 0.0)],
        );
        assert_eq!(all[0], p.describe(&img, 24, 24, 10.0));
        assert_eq!(all[1..], [None, None]);
    }
}
