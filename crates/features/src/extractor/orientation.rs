//! Keypoint orientation by intensity centroid (Rosin 1999; ORB, Rublee et al. 2011) over the
//! circular patch of radius 15 ORB describes.

use crate::GrayImage;

/// Radius (pixels) of the orientation patch.
pub const PATCH_RADIUS: usize = 15;

/// Half-widths `u_max[|v|]` of the circular patch rows, made symmetric in u and v so that the
/// patch is the same shape rotated by 90 degrees (as OpenCV's and ORB-SLAM's).
fn half_widths() -> [usize; PATCH_RADIUS + 1] {
    let r = PATCH_RADIUS as f64;
    let mut umax = [0usize; PATCH_RADIUS + 1];
    let v_max = (r * std::f64::consts::FRAC_1_SQRT_2 + 1.0).floor() as usize;
    let v_min = (r * std::f64::consts::FRAC_1_SQRT_2).ceil() as usize;
    for (v, u) in umax.iter_mut().enumerate().take(v_max + 1) {
        *u = (r * r - (v * v) as f64).sqrt().round() as usize;
    }
    // Rows past 45 degrees take the column extents of the rows before it.
    let mut v0 = 0;
    for v in (v_min..=PATCH_RADIUS).rev() {
        while umax[v0] == umax[v0 + 1] {
            v0 += 1;
        }
        umax[v] = v0;
        v0 += 1;
    }
    umax
}

/// The circular patch; computes orientations.
#[derive(Clone, Debug)]
pub struct CentroidPatch {
    umax: [usize; PATCH_RADIUS + 1],
}

impl Default for CentroidPatch {
    fn default() -> Self {
        Self {
            umax: half_widths(),
        }
    }
}

impl CentroidPatch {
    /// Orientation (degrees, `[0, 360)`) of the patch centred on pixel `(x, y)`: the angle of
    /// `(m10, m01) = sum over the patch of (u, v) * I(x + u, y + v)`, y down.
    ///
    /// `None` when the patch does not fit inside the image.
    pub fn angle_deg(&self, image: &GrayImage<'_>, x: usize, y: usize) -> Option<f32> {
        let (x, y) = (x as isize, y as isize);
        let span = |v: isize| {
            let half = self.umax[v.unsigned_abs()] as isize;
            image.row_span(x - half, y + v, (2 * half + 1) as usize)
        };
        // u-moment of a row (or of two rows' sum); i32 (at most 2 * 255 * 15 * 16) vectorises
        let moment = |row: &[u8], other: &[u8]| -> i32 {
            let half = (row.len() / 2) as i32;
            (-half..)
                .zip(row.iter().zip(other))
                .map(|(u, (&a, &b))| u * (i32::from(a) + i32::from(b)))
                .sum()
        };
        let centre = span(0)?;
        let mut m10 = i64::from(moment(centre, &[0; 2 * PATCH_RADIUS + 1]));
        let mut m01 = 0i64;
        // rows v and -v together
        for v in 1..=PATCH_RADIUS as isize {
            let (below, above) = (span(v)?, span(-v)?);
            let diff: i32 = below
                .iter()
                .zip(above)
                .map(|(&b, &a)| i32::from(b) - i32::from(a))
                .sum();
            m10 += i64::from(moment(below, above));
            m01 += v as i64 * i64::from(diff);
        }
        let deg = (m01 as f64)
            .atan2(m10 as f64)
            .to_degrees()
            .rem_euclid(360.0);
        Some(deg as f32)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn patch_is_symmetric_and_round() {
        let u = half_widths();
        assert_eq!(u[0], 15);
        assert_eq!(u[15], 3);
        // symmetric: the number of rows reaching column c equals row c's half-width
        for c in 0..=PATCH_RADIUS {
            let rows = (0..=PATCH_RADIUS).filter(|&v| u[v] >= c).count() - 1;
            assert_eq!(rows, u[c], "column {c}");
        }
    }

    #[test]
    fn ramp_points_towards_the_bright_side() {
        let (w, h) = (40usize, 40usize);
        let ramp = |f: &dyn Fn(usize, usize) -> u8| -> Vec<u8> {
            (0..h)
                .flat_map(|y| (0..w).map(move |x| (x, y)))
                .map(|(x, y)| f(x, y))
                .collect()
        };
        let right = ramp(&|x, _| (x * 5) as u8);
        let down = ramp(&|_, y| (y * 5) as u8);
        let up_left = ramp(&|x, y| (200 - 2 * x - 2 * y) as u8);
        let patch = CentroidPatch::default();
        let angle = |d: &[u8]| {
            patch
                .angle_deg(&GrayImage::new(w, h, d).unwrap(), 20, 20)
                .unwrap()
        };
        assert!(angle(&right) < 1e-6);
        assert!((angle(&down) - 90.0).abs() < 1e-4);
        assert!((angle(&up_left) - 225.0).abs() < 1e-4);
        let img = GrayImage::new(w, h, &right).unwrap();
        assert_eq!(patch.angle_deg(&img, 14, 20), None);
        assert_eq!(patch.angle_deg(&img, 20, 25), None);
    }
}
