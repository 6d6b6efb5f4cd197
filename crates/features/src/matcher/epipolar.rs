//! Epipolar-constrained matching of unmatched features for triangulation.

use super::{best_two::BestTwo, finalize, MatchOptions};
use crate::{hamming, Descriptor, Keypoint};
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;
use std::ops::Range;

/// Chi-square threshold (1 DoF, 95%) on the squared point-to-epipolar-line distance,
/// in units of the keypoint's level variance (ORB-SLAM `CheckDistEpipolarLine`).
const CHI2_1DOF_95: f64 = 3.84;

/// Matches free features of view 1 to free features of view 2 under the epipolar
/// constraint — ORB-SLAM `SearchForTriangulation`, brute force instead of BoW nodes.
///
/// `f21` maps view-1 pixels to view-2 epipolar lines: `x2^T F21 x1 = 0` with homogeneous
/// undistorted pixels. A candidate `(i1, i2)` (both `free`) is kept when
/// - its Hamming distance is `<= opts.max_distance` (ORB-SLAM: [`super::TH_LOW`]);
/// - if `epipole2 = Some((ex, ey))` (the projection of camera 1's centre into view 2, px):
///   `|kp2 - e|^2 >= 100 * scale(kp2.octave)` with `scale = sqrt(sigma2)` — ORB-SLAM's
///   rule (it uses the scale factor, not its square), rejecting points too close to the
///   epipole to triangulate. ORB-SLAM skips this test when either feature has stereo
///   depth; pass `None` then;
/// - the squared distance of `kp2` to the line `F21 x1` is `< 3.84 * sigma2[kp2.octave]`.
///
/// Per `i1` the closest valid candidate wins; with `opts.nn_ratio = Some(r)` it must also
/// satisfy `best < r * second` (ORB-SLAM applies no ratio here). Each `i2` is used at most
/// once (smallest distance, ties: lowest `i1`). With `opts.check_orientation`, pairs whose
/// `kp1.angle_deg - kp2.angle_deg` falls outside the 3 dominant rotation bins are dropped.
///
/// Returns pairs `(i1, i2)` sorted by `i1`. Features with an octave beyond `sigma2`, a
/// missing `free` flag, or beyond the shorter of their keypoint/descriptor slices are
/// skipped. Parallel over view-1 features; deterministic.
#[allow(clippy::too_many_arguments)] // mirrors ORB-SLAM's inputs; grouping would add a type only used here
pub fn search_for_triangulation(
    kps1: &[Keypoint],
    desc1: &[Descriptor],
    free1: &[bool],
    kps2: &[Keypoint],
    desc2: &[Descriptor],
    free2: &[bool],
    f21: &Matrix3<f64>,
    sigma2: &[f64],
    epipole2: Option<(f64, f64)>,
    opts: &MatchOptions,
) -> Vec<(usize, usize)> {
    let n1 = kps1.len().min(desc1.len());
    let n2 = kps2.len().min(desc2.len());
    let is_free = |flags: &[bool], i: usize| flags.get(i).copied().unwrap_or(false);
    // View-2 candidates that pass the per-feature tests, bucketed on a grid so that each
    // epipolar line visits only the cells its acceptance band crosses.
    let mut candidates2 = Candidates::default();
    for i2 in (0..n2).filter(|&i2| is_free(free2, i2)) {
        let kp2 = &kps2[i2];
        let Some(&s2) = sigma2.get(usize::from(kp2.octave)) else {
            continue;
        };
        let (x, y) = (f64::from(kp2.x), f64::from(kp2.y));
        let far_from_epipole = epipole2.is_none_or(|(ex, ey)| {
            let (dx, dy) = (ex - x, ey - y);
            dx * dx + dy * dy >= 100.0 * s2.sqrt()
        });
        if far_from_epipole {
            candidates2.push(i2, x, y, CHI2_1DOF_95 * s2);
        }
    }
    candidates2.build_grid();

    let mut matches: Vec<_> = (0..n1)
        .into_par_iter()
        .map_init(Vec::new, |near, i1| {
            if !is_free(free1, i1) {
                return None;
            }
            let kp1 = &kps1[i1];
            let line = f21 * Vector3::new(f64::from(kp1.x), f64::from(kp1.y), 1.0);
            let norm2 = line.x * line.x + line.y * line.y;
            if !(norm2 > 0.0 && norm2.is_finite()) {
                return None;
            }
            candidates2.near_line(&line, norm2, near);
            let mut best = BestTwo::default();
            for &k in near.iter() {
                let i2 = candidates2.index[k];
                let d = hamming(&desc1[i1], &desc2[i2]);
                if d <= opts.max_distance {
                    best.push_unordered(d, i2, kps2[i2].octave);
                }
            }
            best.accept(opts.max_distance, opts.nn_ratio)
        })
        .collect();
    finalize(&mut matches, n2, opts.check_orientation, |i1, i2| {
        Some(kps1[i1].angle_deg - kps2[i2].angle_deg)
    });
    matches
        .into_iter()
        .enumerate()
        .filter_map(|(i1, m)| m.map(|(i2, _)| (i1, i2)))
        .collect()
}

/// Side of a [`Candidates`] grid cell, pixels.
const CELL_PX: f64 = 32.0;

/// View-2 features eligible for matching (keypoint index, undistorted pixel, and the largest
/// squared distance to an epipolar line that still passes: `3.84 * sigma2` of its level),
/// bucketed on a grid of [`CELL_PX`] cells over their bounding box.
#[derive(Default)]
struct Candidates {
    index: Vec<usize>,
    x: Vec<f64>,
    y: Vec<f64>,
    max_r2: Vec<f64>,
    origin: (f64, f64),
    cols: usize,
    rows: usize,
    /// For lines walked column by column (mostly horizontal): the cells in column-major order.
    by_column: CellRuns,
    /// For lines walked row by row: the cells in row-major order.
    by_row: CellRuns,
    /// Perpendicular distance, px, beyond which no candidate passes, plus a margin for the
    /// rounding of the normalised line.
    band_px: f64,
}

/// The candidates copied cell after cell (a cell's in increasing order), so that the cells a
/// line's band crosses in one column (or row) are one contiguous run.
#[derive(Default)]
struct CellRuns {
    /// Candidates of cell `c` (in this order of cells): positions `start[c]..start[c + 1]`.
    start: Vec<usize>,
    x: Vec<f64>,
    y: Vec<f64>,
    max_r2: Vec<f64>,
    /// Position of each copy in [`Candidates`].
    k: Vec<usize>,
}

impl CellRuns {
    /// A stable counting sort of the candidates by `cell[k]` (`cells` cells).
    fn new(c: &Candidates, cell: &[usize], cells: usize) -> Self {
        let mut start = vec![0; cells + 1];
        for &i in cell {
            start[i + 1] += 1;
        }
        for i in 0..cells {
            start[i + 1] += start[i];
        }
        let mut next = start.clone();
        let mut k_of = vec![0; cell.len()];
        for (k, &i) in cell.iter().enumerate() {
            k_of[next[i]] = k;
            next[i] += 1;
        }
        Self {
            start,
            x: k_of.iter().map(|&k| c.x[k]).collect(),
            y: k_of.iter().map(|&k| c.y[k]).collect(),
            max_r2: k_of.iter().map(|&k| c.max_r2[k]).collect(),
            k: k_of,
        }
    }
}

impl Candidates {
    fn push(&mut self, index: usize, x: f64, y: f64, max_r2: f64) {
        self.index.push(index);
        self.x.push(x);
        self.y.push(y);
        self.max_r2.push(max_r2);
    }

    /// Column and row of the cell holding candidate `k`.
    fn cell_of(&self, k: usize) -> (usize, usize) {
        let col = ((self.x[k] - self.origin.0) / CELL_PX) as usize;
        let row = ((self.y[k] - self.origin.1) / CELL_PX) as usize;
        (col.min(self.cols - 1), row.min(self.rows - 1))
    }

    /// Buckets the candidates in both cell orders.
    fn build_grid(&mut self) {
        let n = self.index.len();
        if n == 0 {
            return;
        }
        let fold = |v: &[f64]| {
            v.iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &x| {
                    (lo.min(x), hi.max(x))
                })
        };
        let ((x0, x1), (y0, y1)) = (fold(&self.x), fold(&self.y));
        self.origin = (x0, y0);
        self.cols = ((x1 - x0) / CELL_PX) as usize + 1;
        self.rows = ((y1 - y0) / CELL_PX) as usize + 1;
        let cells: Vec<(usize, usize)> = (0..n).map(|k| self.cell_of(k)).collect();
        let column_major: Vec<usize> = cells.iter().map(|&(c, r)| c * self.rows + r).collect();
        let row_major: Vec<usize> = cells.iter().map(|&(c, r)| r * self.cols + c).collect();
        self.by_column = CellRuns::new(self, &column_major, self.cols * self.rows);
        self.by_row = CellRuns::new(self, &row_major, self.cols * self.rows);
        self.band_px = self.max_r2.iter().fold(0.0f64, |m, &r| m.max(r)).sqrt() + 1.0;
    }

    /// Fills `out` with the candidates (positions, in no particular order) whose squared
    /// distance to `line` (`a x + b y + c = 0`, `norm2 = a^2 + b^2`) is below their bound:
    /// the same test as a scan over all of them.
    fn near_line(&self, line: &Vector3<f64>, norm2: f64, out: &mut Vec<usize>) {
        out.clear();
        if self.index.is_empty() {
            return;
        }
        let norm = norm2.sqrt();
        let (a, b, c) = (line.x / norm, line.y / norm, line.z / norm);
        // Walk the cells along the line's major axis: across each column (row) the band
        // spans the line's range over that column (row) widened by band / |b| (|a|).
        let mostly_horizontal = b.abs() >= a.abs();
        let (across, along, o_across, o_along, runs) = if mostly_horizontal {
            (
                self.cols,
                self.rows,
                self.origin.0,
                self.origin.1,
                &self.by_column,
            )
        } else {
            (
                self.rows,
                self.cols,
                self.origin.1,
                self.origin.0,
                &self.by_row,
            )
        };
        let (p, q) = if mostly_horizontal { (a, b) } else { (b, a) };
        let half = self.band_px / q.abs();
        let on_line = |t: f64| -(p * t + c) / q;
        for i in 0..across {
            let t0 = o_across + i as f64 * CELL_PX;
            let (u0, u1) = (on_line(t0), on_line(t0 + CELL_PX));
            let lo = (u0.min(u1) - half - o_along) / CELL_PX;
            let hi = (u0.max(u1) + half - o_along) / CELL_PX;
            if !(hi >= 0.0 && lo < along as f64) {
                continue;
            }
            let (j0, j1) = (lo.max(0.0) as usize, (hi as usize).min(along - 1));
            runs.scan(
                line,
                norm2,
                runs.start[i * along + j0]..runs.start[i * along + j1 + 1],
                out,
            );
        }
    }
}

impl CellRuns {
    /// Appends (in order) the candidates of positions `run` whose squared distance to `line`
    /// is below their bound. Branch-free: all are appended, then each is moved down to the
    /// count, which advances past those that pass (a branch on the test mispredicts).
    fn scan(&self, line: &Vector3<f64>, norm2: f64, run: Range<usize>, out: &mut Vec<usize>) {
        let base = out.len();
        let mut len = base;
        out.extend_from_slice(&self.k[run.clone()]);
        for (j, n) in run.enumerate() {
            let r = line.x * self.x[n] + line.y * self.y[n] + line.z;
            out[len] = out[base + j];
            len += usize::from(r * r / norm2 < self.max_r2[n]);
        }
        out.truncate(len);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::matcher::test_support::*;
    use crate::ScalePyramid;
    use nalgebra::{Rotation3, Vector2};
    use rand::Rng;

    /// Synthetic two-view setup: pinhole K, p_c2 = R21 p_c1 + t21.
    struct TwoView {
        k: Matrix3<f64>,
        r21: Rotation3<f64>,
        t21: Vector3<f64>,
    }

    impl TwoView {
        fn new() -> Self {
            Self {
                k: Matrix3::new(500.0, 0.0, 320.0, 0.0, 500.0, 240.0, 0.0, 0.0, 1.0),
                r21: Rotation3::from_euler_angles(0.02, -0.1, 0.03),
                t21: Vector3::new(-0.3, 0.02, 0.05),
            }
        }

        /// F21 = K^-T [t21]x R21 K^-1.
        fn f21(&self) -> Matrix3<f64> {
            let k_inv = self.k.try_inverse().unwrap_or_else(Matrix3::identity);
            k_inv.transpose() * self.t21.cross_matrix() * self.r21.matrix() * k_inv
        }

        fn project(&self, p_c: &Vector3<f64>) -> Vector2<f64> {
            let uvw = self.k * p_c;
            Vector2::new(uvw.x / uvw.z, uvw.y / uvw.z)
        }

        /// Camera 1's centre projected into view 2.
        fn epipole2(&self) -> (f64, f64) {
            let e = self.project(&self.t21);
            (e.x, e.y)
        }
    }

    fn keypoint(uv: Vector2<f64>, octave: u8) -> Keypoint {
        Keypoint {
            x: uv.x as f32,
            y: uv.y as f32,
            octave,
            angle_deg: 45.0,
            response: 1.0,
        }
    }

    fn line_distance2(f21: &Matrix3<f64>, kp1: &Keypoint, kp2: &Keypoint) -> f64 {
        let l = f21 * Vector3::new(f64::from(kp1.x), f64::from(kp1.y), 1.0);
        let r = l.x * f64::from(kp2.x) + l.y * f64::from(kp2.y) + l.z;
        r * r / (l.x * l.x + l.y * l.y)
    }

    #[test]
    fn finds_true_pairs_and_respects_the_epipolar_bound() {
        let seed = 31;
        let mut rng = rng(seed);
        let view = TwoView::new();
        let pyramid = ScalePyramid::default();
        let (mut kps1, mut desc1, mut kps2, mut desc2) = (vec![], vec![], vec![], vec![]);
        let mut truth = Vec::new(); // (i1, i2)
        let mut decoys = Vec::new(); // i2 of decoys
        while kps1.len() < 300 {
            let p1 = Vector3::new(
                rng.random_range(-2.0..2.0),
                rng.random_range(-1.5..1.5),
                rng.random_range(2.0..8.0),
            );
            let p2 = view.r21 * p1 + view.t21;
            let (uv1, uv2) = (view.project(&p1), view.project(&p2));
            let in_image =
                |uv: &Vector2<f64>| (0.0..640.0).contains(&uv.x) && (0.0..480.0).contains(&uv.y);
            if p2.z < 0.5 || !in_image(&uv1) || !in_image(&uv2) {
                continue;
            }
            let noise = Vector2::new(rng.random_range(-0.3..0.3), rng.random_range(-0.3..0.3));
            let d = random_descriptor(&mut rng);
            let i1 = kps1.len();
            kps1.push(keypoint(uv1, rng.random_range(0..8)));
            desc1.push(d);
            let n_bits = rng.random_range(0..15);
            truth.push((i1, kps2.len()));
            kps2.push(keypoint(uv2 + noise, rng.random_range(0..8)));
            desc2.push(flip_bits(&mut rng, &d, n_bits));
            if i1 % 5 == 0 {
                // A closer descriptor 25 px off the epipolar line: must never be matched.
                let l = view.f21() * Vector3::new(uv1.x, uv1.y, 1.0);
                let normal = Vector2::new(l.x, l.y).normalize();
                decoys.push(kps2.len());
                kps2.push(keypoint(uv2 + 25.0 * normal, 0));
                desc2.push(flip_bits(&mut rng, &d, 1));
            }
        }
        let free1: Vec<bool> = (0..kps1.len()).map(|i| i % 7 != 3).collect();
        let free2: Vec<bool> = (0..kps2.len()).map(|i| i % 11 != 4).collect();
        let f21 = view.f21();
        assert_eq!(decoys.len(), 60);
        for opts in [
            MatchOptions::triangulation(),
            MatchOptions {
                check_orientation: true,
                ..MatchOptions::triangulation()
            },
        ] {
            let got = search_for_triangulation(
                &kps1,
                &desc1,
                &free1,
                &kps2,
                &desc2,
                &free2,
                &f21,
                &pyramid.sigma2,
                Some(view.epipole2()),
                &opts,
            );
            let expected: Vec<_> = truth
                .iter()
                .copied()
                .filter(|&(i1, i2)| free1[i1] && free2[i2])
                .collect();
            assert!(expected.len() > 200);
            assert_eq!(got, expected, "seed {seed}");
            for &(i1, i2) in &got {
                assert!(!decoys.contains(&i2));
                let bound = CHI2_1DOF_95 * pyramid.sigma2[usize::from(kps2[i2].octave)];
                assert!(line_distance2(&f21, &kps1[i1], &kps2[i2]) < bound);
            }
        }
    }

    #[test]
    fn rejects_features_near_the_epipole_and_bad_octaves() {
        let view = TwoView::new();
        let f21 = view.f21();
        let mut rng = rng(32);
        let d = random_descriptor(&mut rng);
        // A view-1 point whose line passes through the epipole (every line does); put kp2 on
        // the line within 5 px of a pretended epipole.
        let p1 = Vector3::new(0.1, 0.2, 4.0);
        let uv1 = view.project(&p1);
        let uv2 = view.project(&(view.r21 * p1 + view.t21));
        let kp1 = [keypoint(uv1, 0)];
        let kp2 = [keypoint(uv2, 0)];
        let all = |n| vec![true; n];
        let search = |eps: Option<(f64, f64)>, sigma2: &[f64]| {
            search_for_triangulation(
                &kp1,
                &[d],
                &all(1),
                &kp2,
                &[d],
                &all(1),
                &f21,
                sigma2,
                eps,
                &MatchOptions::triangulation(),
            )
        };
        let sigma2 = ScalePyramid::default().sigma2;
        assert_eq!(search(None, &sigma2), vec![(0, 0)]);
        assert_eq!(search(Some((uv2.x + 5.0, uv2.y)), &sigma2), vec![]);
        assert_eq!(search(Some((uv2.x + 11.0, uv2.y)), &sigma2), vec![(0, 0)]);
        // An octave beyond the provided level variances is skipped, not a panic.
        assert_eq!(search(None, &[]), vec![]);
        // A zero F (degenerate line) yields nothing.
        let zero = Matrix3::zeros();
        let got = search_for_triangulation(
            &kp1,
            &[d],
            &all(1),
            &kp2,
            &[d],
            &all(1),
            &zero,
            &sigma2,
            None,
            &MatchOptions::triangulation(),
        );
        assert!(got.is_empty());
    }

    /// The grid walk returns exactly what a scan over every candidate accepts, in the same
    /// order, for lines of every direction (near-vertical ones included) and every level.
    #[test]
    fn grid_walk_equals_the_full_scan() {
        let mut rng = rng(11);
        let sigma2 = ScalePyramid::new(1.2, 8).unwrap().sigma2;
        let mut candidates = Candidates::default();
        for i in 0..3000 {
            let s2 = sigma2[rng.random_range(0..8)];
            let (x, y) = (rng.random_range(-5.0..1246.0), rng.random_range(0.0..376.0));
            candidates.push(i, x, y, CHI2_1DOF_95 * s2);
        }
        candidates.build_grid();
        let mut near = Vec::new();
        let mut total = 0;
        for _ in 0..2000 {
            let angle: f64 = rng.random_range(0.0..std::f64::consts::TAU);
            let (a, b) = (angle.cos(), angle.sin());
            let through = (rng.random_range(0.0..1241.0), rng.random_range(0.0..376.0));
            let scale = rng.random_range(1e-4..1e2);
            let line = scale * Vector3::new(a, b, -(a * through.0 + b * through.1));
            let norm2 = line.x * line.x + line.y * line.y;
            candidates.near_line(&line, norm2, &mut near);
            near.sort_unstable();
            let scan: Vec<usize> = (0..candidates.index.len())
                .filter(|&k| {
                    let r = line.x * candidates.x[k] + line.y * candidates.y[k] + line.z;
                    r * r / norm2 < candidates.max_r2[k]
                })
                .collect();
            assert_eq!(near, scan);
            total += scan.len();
        }
        assert!(total > 20_000, "the lines must cross candidates: {total}");
    }
}
