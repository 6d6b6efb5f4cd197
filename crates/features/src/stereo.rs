//! Stereo matching of ORB features on a rectified pair (ORB-SLAM2 `Frame::ComputeStereoMatches`).
//!
//! For each left keypoint: candidates are right keypoints in the same row band (+-2 px scaled by
//! the candidate's pyramid level), within one octave and the disparity range
//! `[MIN_DISPARITY_PX, fx)` (depth above one baseline); the best Hamming distance under `(TH_HIGH + TH_LOW) / 2` wins. Its
//! column is refined by sum-of-absolute-differences correlation of an 11x11 patch on the
//! keypoint's pyramid level over +-5 level pixels, then a parabola fit through the best three
//! costs. Matches whose SAD cost exceeds 1.5 x 1.4 x the median are dropped.
//!
//! The pair must be rectified (epipolar lines are image rows) and keypoints must be pixel
//! coordinates of the rectified images; disparity `d = u_left - u_right` gives depth
//! `z = bf / d` with `bf = fx * baseline` (pixels * metres).

use crate::descriptor::{hamming, Descriptor};
use crate::image::GrayImage;
use crate::keypoint::Keypoint;
use crate::matcher::{TH_HIGH, TH_LOW};
use crate::pyramid::ScalePyramid;
use rayon::prelude::*;

/// Half size of the SAD correlation window, level pixels (11 x 11 patch).
const PATCH_HALF: isize = 5;
/// Search range of the SAD refinement around the descriptor match, level pixels.
const SEARCH_HALF: isize = 5;
/// Least disparity of a match, level-0 pixels. ORB-SLAM keeps disparities down to 0 (as
/// 0.01 px): points hundreds of kilometres away (KITTI 01: 259 km), and a pair whose right
/// image is the left one matches every keypoint at 0 and "tracks". The parabola-refined
/// disparity is good to a few tenths of a pixel, so below one pixel depth is unknown to
/// within a factor of two; depth stays below `bf / 1 px` (KITTI 386 m, EuRoC 50 m).
pub const MIN_DISPARITY_PX: f64 = 1.0;

/// One side of a rectified stereo pair: keypoints, their descriptors and the image pyramid
/// (level `l` is the image scaled by `1 / scale[l]`, unblurred, as used for detection).
#[derive(Clone, Copy, Debug)]
pub struct StereoView<'a> {
    /// Keypoints in level-0 pixels of the rectified image.
    pub keypoints: &'a [Keypoint],
    /// One descriptor per keypoint.
    pub descriptors: &'a [Descriptor],
    /// Image pyramid, at least as many levels as the highest keypoint octave.
    pub levels: &'a [GrayImage<'a>],
}

/// The right-image observation of a left keypoint.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StereoMatch {
    /// Column of the match in the right image, level-0 pixels (sub-pixel).
    pub u_right: f32,
    /// Depth `bf / (u_left - u_right)`, metres.
    pub depth_m: f32,
}

/// Matches every left keypoint into the right image; `None` where no reliable match exists.
///
/// `bf` is `fx * baseline` (pixels * metres) and `fx` the focal length in pixels; the
/// disparity search covers `[MIN_DISPARITY_PX, fx)`, i.e. depths from one baseline to
/// `bf / MIN_DISPARITY_PX`. Entries with
/// mismatched lengths, non-finite coordinates or octaves beyond the pyramid are left
/// unmatched (never a panic).
pub fn match_stereo(
    left: &StereoView<'_>,
    right: &StereoView<'_>,
    pyramid: &ScalePyramid,
    bf: f64,
    fx: f64,
) -> Vec<Option<StereoMatch>> {
    let n = left.keypoints.len();
    let mut out = vec![None; n];
    let Some(base) = left.levels.first() else {
        return out;
    };
    if !(bf.is_finite() && bf > 0.0 && fx.is_finite() && fx > 0.0) {
        return out;
    }
    let rows = rows_of_right_keypoints(right, pyramid, base.height());
    let matched: Vec<Option<(StereoMatch, u32)>> = (0..n)
        .into_par_iter()
        .map(|i| match_one(i, left, right, &rows, pyramid, bf, fx))
        .collect();
    let mut costs = Vec::new();
    for (i, m) in matched.into_iter().enumerate() {
        if let Some((m, sad)) = m {
            out[i] = Some(m);
            costs.push((sad, i));
        }
    }
    reject_costly_matches(&mut out, costs);
    out
}

/// The match of left keypoint `i` and its correlation cost, before the median test.
fn match_one(
    i: usize,
    left: &StereoView<'_>,
    right: &StereoView<'_>,
    rows: &[Vec<usize>],
    pyramid: &ScalePyramid,
    bf: f64,
    fx: f64,
) -> Option<(StereoMatch, u32)> {
    let kp = &left.keypoints[i];
    let desc = left.descriptors.get(i)?;
    let level = kp.octave as usize;
    if !(kp.x.is_finite() && kp.y.is_finite())
        || level >= pyramid.n_levels
        || kp.y < 0.0
        || kp.y as usize >= rows.len()
    {
        return None;
    }
    let (min_d, max_d) = (MIN_DISPARITY_PX, fx);
    let (u_l, min_u, max_u) = (kp.x as f64, kp.x as f64 - max_d, kp.x as f64 - min_d);
    if max_u < 0.0 {
        return None;
    }
    let mut best: Option<(u32, usize)> = None;
    for &j in &rows[kp.y as usize] {
        let r = &right.keypoints[j];
        if (r.octave as i32 - level as i32).abs() > 1 || !(min_u..=max_u).contains(&(r.x as f64)) {
            continue;
        }
        let d = hamming(desc, &right.descriptors[j]);
        if best.is_none_or(|(bd, _)| d < bd) {
            best = Some((d, j));
        }
    }
    let (_, j) = best.filter(|&(d, _)| d < (TH_HIGH + TH_LOW) / 2)?;
    let (u_r, sad) = refine_by_correlation(left, right, kp, right.keypoints[j].x, pyramid)?;
    let disparity = u_l - u_r;
    if !(min_d..max_d).contains(&disparity) {
        return None;
    }
    let m = StereoMatch {
        u_right: u_r as f32,
        depth_m: (bf / disparity) as f32,
    };
    Some((m, sad))
}

/// For every image row (level 0), the right keypoints whose +-2 px (scaled) band covers it.
fn rows_of_right_keypoints(
    right: &StereoView<'_>,
    pyramid: &ScalePyramid,
    height: usize,
) -> Vec<Vec<usize>> {
    let mut rows = vec![Vec::new(); height];
    for (j, kp) in right.keypoints.iter().enumerate() {
        let level = kp.octave as usize;
        if j >= right.descriptors.len() || level >= pyramid.n_levels || !kp.y.is_finite() {
            continue;
        }
        let r = 2.0 * pyramid.scale[level];
        let lo = (kp.y as f64 - r).floor().max(0.0) as usize;
        let hi = (kp.y as f64 + r).ceil().min(height as f64 - 1.0);
        if hi < 0.0 {
            continue;
        }
        for row in rows.iter_mut().take(hi as usize + 1).skip(lo) {
            row.push(j);
        }
    }
    rows
}

/// Sub-pixel right column (level 0) and SAD cost of the best patch offset around `u_r0`.
///
/// Patches are compared after subtracting their centre pixel, which cancels a brightness
/// offset between the cameras. `None` when a patch leaves the image, the optimum sits on the
/// border of the search range or the parabola's vertex is more than a pixel away.
fn refine_by_correlation(
    left: &StereoView<'_>,
    right: &StereoView<'_>,
    kp: &Keypoint,
    u_r0: f32,
    pyramid: &ScalePyramid,
) -> Option<(f64, u32)> {
    let level = kp.octave as usize;
    let (img_l, img_r) = (left.levels.get(level)?, right.levels.get(level)?);
    let s = pyramid.inv_scale[level];
    let (ul, vl, ur0) = (
        (kp.x as f64 * s).round() as isize,
        (kp.y as f64 * s).round() as isize,
        (u_r0 as f64 * s).round() as isize,
    );
    let width = (2 * PATCH_HALF + 1) as usize;
    let center_l = img_l.row_span(ul, vl, 1)?[0] as i32;
    let mut patch_l = Vec::with_capacity(width * width);
    for dy in -PATCH_HALF..=PATCH_HALF {
        let row = img_l.row_span(ul - PATCH_HALF, vl + dy, width)?;
        patch_l.extend(row.iter().map(|&p| p as i32 - center_l));
    }
    let mut costs = [u32::MAX; (2 * SEARCH_HALF + 1) as usize];
    for (k, inc) in (-SEARCH_HALF..=SEARCH_HALF).enumerate() {
        let uc = ur0 + inc;
        let center_r = img_r.row_span(uc, vl, 1)?[0] as i32;
        let mut sad = 0u32;
        for (r, dy) in (-PATCH_HALF..=PATCH_HALF).enumerate() {
            let row = img_r.row_span(uc - PATCH_HALF, vl + dy, width)?;
            let lrow = &patch_l[r * width..(r + 1) * width];
            sad += row
                .iter()
                .zip(lrow)
                .map(|(&p, &q)| (p as i32 - center_r - q).unsigned_abs())
                .sum::<u32>();
        }
        costs[k] = sad;
    }
    let best = (0..costs.len()).min_by_key(|&k| (costs[k], k))?;
    if best == 0 || best == costs.len() - 1 {
        return None;
    }
    let (c1, c2, c3) = (
        costs[best - 1] as f64,
        costs[best] as f64,
        costs[best + 1] as f64,
    );
    let denom = 2.0 * (c1 + c3 - 2.0 * c2);
    let delta = if denom > 0.0 { (c1 - c3) / denom } else { 0.0 };
    if !(-1.0..=1.0).contains(&delta) {
        return None;
    }
    let inc = best as isize - SEARCH_HALF;
    Some((
        pyramid.scale[level] * ((ur0 + inc) as f64 + delta),
        costs[best],
    ))
}

/// Drops matches whose correlation cost exceeds 1.5 x 1.4 x the median (ORB-SLAM's rule).
fn reject_costly_matches(out: &mut [Option<StereoMatch>], mut costs: Vec<(u32, usize)>) {
    if costs.is_empty() {
        return;
    }
    costs.sort_unstable();
    let median = costs[costs.len() / 2].0 as f64;
    let limit = 1.5 * 1.4 * median;
    for &(c, i) in costs.iter().rev() {
        if c as f64 <= limit {
            break;
        }
        out[i] = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const W: usize = 160;
    const H: usize = 60;

    /// Smooth texture sampled at `(x + shift, y)`: a right image seeing the scene `shift`
    /// pixels to the left of the left image.
    fn texture(shift: f64) -> Vec<u8> {
        let mut img = Vec::with_capacity(W * H);
        for y in 0..H {
            for x in 0..W {
                let (x, y) = (x as f64 + shift, y as f64);
                let v = 128.0
                    + 50.0 * (0.31 * x + 0.17 * y).sin()
                    + 40.0 * (0.23 * x - 0.41 * y).cos()
                    + 30.0 * (0.07 * x * (1.0 + 0.01 * y)).sin();
                img.push(v.clamp(0.0, 255.0) as u8);
            }
        }
        img
    }

    fn keypoint(x: f32, y: f32, octave: u8) -> Keypoint {
        Keypoint {
            x,
            y,
            octave,
            angle_deg: 0.0,
            response: 1.0,
        }
    }

    struct Pair {
        left: Vec<u8>,
        right: Vec<u8>,
        pyramid: ScalePyramid,
    }

    impl Pair {
        fn new(disparity: f64) -> Self {
            Self {
                left: texture(0.0),
                right: texture(disparity),
                pyramid: ScalePyramid::new(1.2, 3).unwrap(),
            }
        }

        fn run(&self, l: &[Keypoint], r: &[Keypoint], bf: f64) -> Vec<Option<StereoMatch>> {
            let li = [GrayImage::new(W, H, &self.left).unwrap()];
            let ri = [GrayImage::new(W, H, &self.right).unwrap()];
            let dl = vec![[7u8; 32]; l.len()];
            let dr = vec![[7u8; 32]; r.len()];
            let left = StereoView {
                keypoints: l,
                descriptors: &dl,
                levels: &li,
            };
            let right = StereoView {
                keypoints: r,
                descriptors: &dr,
                levels: &ri,
            };
            match_stereo(&left, &right, &self.pyramid, bf, 100.0)
        }
    }

    #[test]
    fn recovers_sub_pixel_disparity_and_depth() {
        let d = 12.3;
        let pair = Pair::new(d);
        let l = [keypoint(80.0, 30.0, 0), keypoint(100.0, 25.0, 0)];
        // The descriptor match lands a pixel off; correlation must pull it to the truth.
        let r = [
            keypoint(80.0 - 13.0, 30.5, 0),
            keypoint(100.0 - 11.0, 24.0, 0),
        ];
        let m = pair.run(&l, &r, 50.0);
        for (kp, m) in l.iter().zip(&m) {
            let m = m.expect("matched");
            let disparity = kp.x as f64 - m.u_right as f64;
            assert!((disparity - d).abs() < 0.15, "disparity {disparity} vs {d}");
            assert!((m.depth_m as f64 - 50.0 / disparity).abs() < 1e-3);
        }
    }

    #[test]
    fn candidates_respect_row_band_octave_and_disparity_sign() {
        let pair = Pair::new(10.0);
        let l = [keypoint(80.0, 30.0, 0)];
        for r in [
            keypoint(70.0, 33.0, 0), // 3 rows away: outside the +-2 px band at level 0
            keypoint(70.0, 30.0, 2), // two octaves apart
            keypoint(90.0, 30.0, 0), // negative disparity
        ] {
            assert_eq!(pair.run(&l, &[r], 50.0), vec![None], "{r:?}");
        }
        assert!(pair.run(&l, &[keypoint(70.0, 31.9, 1)], 50.0)[0].is_some());
    }

    #[test]
    fn disparities_under_a_pixel_are_unmatched() {
        // The right image is the left one: every match would sit at zero disparity.
        let l = [keypoint(80.0, 30.0, 0), keypoint(100.0, 25.0, 0)];
        let shifted = |d: f32| l.map(|k| keypoint(k.x - d, k.y, 0));
        assert!(Pair::new(0.0)
            .run(&l, &shifted(0.0), 50.0)
            .iter()
            .all(Option::is_none));
        // Half a pixel: too far to tell; one and a half: matched, depth bf / d.
        assert!(Pair::new(0.5)
            .run(&l, &shifted(0.5), 50.0)
            .iter()
            .all(Option::is_none));
        for m in Pair::new(1.5).run(&l, &shifted(1.5), 50.0) {
            let m = m.expect("matched at 1.5 px");
            assert!((m.depth_m - 50.0 / 1.5).abs() < 5.0, "{m:?}");
        }
    }

    #[test]
    fn malformed_input_is_left_unmatched() {
        let pair = Pair::new(10.0);
        let l = [
            keypoint(f32::NAN, 30.0, 0),
            keypoint(80.0, 30.0, 9), // octave beyond the pyramid
            keypoint(80.0, -4.0, 0),
            keypoint(3.0, 30.0, 0), // patch leaves the image
        ];
        let r = [keypoint(70.0, 30.0, 0), keypoint(-7.0, 30.0, 0)];
        assert!(pair.run(&l, &r, 50.0).iter().all(Option::is_none));
        assert!(pair.run(&l[..1], &r, f64::NAN)[0].is_none());
    }

    #[test]
    fn costly_outliers_are_rejected_against_the_median() {
        let mut out = vec![
            Some(StereoMatch {
                u_right: 1.0,
                depth_m: 1.0
            });
            4
        ];
        reject_costly_matches(&mut out, vec![(100, 0), (110, 1), (120, 2), (400, 3)]);
        assert_eq!(out.iter().filter(|m| m.is_some()).count(), 3);
        assert!(out[3].is_none());
    }
}
