//! View-2 features indexed by their place in the pencil of epipolar lines, so that an epipolar
//! line visits only the features near it.

use nalgebra::{Matrix3, Vector3};
use std::f64::consts::PI;
use std::ops::Range;

/// `|F21^T e2| / (|F21| |e2|)` below which F21 counts as rank 2, every epipolar line passing
/// through the epipole `e2`. F21 built from two poses is rank 2 to rounding (about 1e-16).
const RANK2_TOLERANCE: f64 = 1e-9;
/// Widening, px, of every acceptance band: covers the epipolar line missing the computed
/// epipole by rounding and, for an epipole treated as at infinity, the lines' convergence.
const MARGIN_PX: f64 = 1.0;
/// Widening, radians, of every angular window (`atan2` rounding).
const ANGLE_SLACK: f64 = 1e-9;

/// Features (keypoint index, undistorted pixel `x`, `y`, and `max_r2`: the largest squared
/// distance to an epipolar line that still passes), indexed so that [`Self::near_line`]
/// scans a few times a line's acceptance band instead of every feature.
///
/// Every epipolar line passes through the epipole `e2`. A feature at distance `r` from it,
/// with band `d = sqrt(max_r2) + margin`, lies within `d` of a line only if its direction
/// from `e2` is within `asin(d / r)` of the line's (modulo pi). So the features are sorted
/// into rings of doubling `r / d` (`2^k .. 2^(k+1)`), and by direction within a ring, where a
/// line scans one angular window of half-width `asin(2^-k)`. An epipole too far to subtract
/// pixels from leaves the lines parallel: one ring, sorted by offset across them. An `F21`
/// that is not rank 2 (lines sharing no point) leaves one ring, scanned whole.
#[derive(Default)]
pub(super) struct PencilIndex {
    /// Keypoint index of each feature, in insertion order.
    pub(super) index: Vec<usize>,
    x: Vec<f64>,
    y: Vec<f64>,
    max_r2: Vec<f64>,
    pencil: Pencil,
    /// The features sorted ring by ring, by key within a ring.
    sorted: Sorted,
    rings: Vec<Ring>,
    /// Per ring, where each of its buckets starts in `sorted` (see [`Ring::buckets`]).
    bucket_start: Vec<usize>,
}

/// Features of one ring, by direction.
struct Ring {
    /// Positions in `sorted`.
    run: Range<usize>,
    /// Half-width of a line's window, radians (`>= PI / 2`: the ring is scanned whole).
    half: f64,
    /// The keys are bucketed by `floor((key - from) * per_radian)`, from the ring's smallest
    /// key, buckets as wide as a window's half (wider when the ring has fewer features than
    /// that makes buckets), so a window is scanned as the few whole buckets it touches;
    /// `buckets` indexes `bucket_start`, one entry per bucket and one for the end.
    from: f64,
    per_radian: f64,
    buckets: Range<usize>,
}

/// How the epipolar lines are laid out.
#[derive(Default, Clone, Copy)]
enum Pencil {
    /// Through the epipole at this pixel; features keyed by direction from it, in `[0, pi]`.
    Through(f64, f64),
    /// Parallel, with this unit normal; features keyed by offset along it. A line is keyed
    /// at its point nearest `centre` (the features' bounding box centre); `half_px` bounds
    /// every feature's band plus the lines' convergence over the features' extent.
    Parallel {
        normal: (f64, f64),
        centre: (f64, f64),
        half_px: f64,
    },
    /// Not through one point: every feature is a candidate of every line.
    #[default]
    Unordered,
}

/// Features copied in scan order, with their keys.
#[derive(Default)]
struct Sorted {
    key: Vec<f64>,
    x: Vec<f64>,
    y: Vec<f64>,
    max_r2: Vec<f64>,
    /// Insertion position of each copy.
    k: Vec<usize>,
    /// Features scanned so far (the tests check the index's selectivity).
    #[cfg(test)]
    scanned: std::sync::atomic::AtomicUsize,
}

impl PencilIndex {
    pub(super) fn push(&mut self, index: usize, x: f64, y: f64, max_r2: f64) {
        self.index.push(index);
        self.x.push(x);
        self.y.push(y);
        self.max_r2.push(max_r2);
    }

    /// Sorts the features pushed so far for the lines of `f21`.
    pub(super) fn build(&mut self, f21: &Matrix3<f64>) {
        let n = self.index.len();
        if n == 0 {
            return;
        }
        let band = |k: usize| self.max_r2[k].sqrt() + MARGIN_PX;
        self.pencil = self.pencil_of(f21, (0..n).map(band).fold(0.0, f64::max));
        // (ring, key) of each feature.
        let placed: Vec<(u32, f64)> = (0..n)
            .map(|k| match self.pencil {
                Pencil::Through(ex, ey) => {
                    let (dx, dy) = (self.x[k] - ex, self.y[k] - ey);
                    let rho = dx.hypot(dy) / band(k);
                    let ring = if rho < 2.0 { 0 } else { rho.log2() as u32 };
                    (ring, dy.atan2(dx).rem_euclid(PI))
                }
                Pencil::Parallel { normal, .. } => (0, normal.0 * self.x[k] + normal.1 * self.y[k]),
                Pencil::Unordered => (0, 0.0),
            })
            .collect();
        let mut order: Vec<usize> = (0..n).collect();
        order.sort_unstable_by(|&a, &b| {
            (placed[a].0.cmp(&placed[b].0)).then(placed[a].1.total_cmp(&placed[b].1))
        });
        self.sorted = Sorted {
            key: order.iter().map(|&k| placed[k].1).collect(),
            x: order.iter().map(|&k| self.x[k]).collect(),
            y: order.iter().map(|&k| self.y[k]).collect(),
            max_r2: order.iter().map(|&k| self.max_r2[k]).collect(),
            k: order.clone(),
            #[cfg(test)]
            scanned: Default::default(),
        };
        self.rings.clear();
        self.bucket_start.clear();
        let mut start = 0;
        while start < n {
            let ring = placed[order[start]].0;
            let end = start + order[start..].partition_point(|&k| placed[k].0 == ring);
            let half = match (self.pencil, ring) {
                (Pencil::Through(..), r) if r > 0 => (0.5f64).powi(r as i32).asin() + ANGLE_SLACK,
                _ => PI,
            };
            // Buckets over the ring's keys only (a far epipole packs them into a sliver),
            // and never more than features.
            let keys = &self.sorted.key[start..end];
            let (from, span) = (keys[0], keys[keys.len() - 1] - keys[0]);
            let count = ((span / half).ceil() as usize).clamp(1, keys.len());
            let per_radian = count as f64 / span.max(f64::MIN_POSITIVE);
            let first = self.bucket_start.len();
            let mut b = 0;
            for (j, &key) in keys.iter().enumerate() {
                while b <= bucket_of(key - from, per_radian, count) {
                    self.bucket_start.push(start + j);
                    b += 1;
                }
            }
            while b <= count {
                self.bucket_start.push(end);
                b += 1;
            }
            self.rings.push(Ring {
                run: start..end,
                half,
                from,
                per_radian,
                buckets: first..self.bucket_start.len(),
            });
            start = end;
        }
    }

    /// The layout of `f21`'s lines over the features, `max_band` being their widest band.
    fn pencil_of(&self, f21: &Matrix3<f64>, max_band: f64) -> Pencil {
        // e2 is orthogonal to every column of F21: the largest cross product of two columns.
        let cols = [f21.column(0), f21.column(1), f21.column(2)];
        let e = [(0, 1), (0, 2), (1, 2)]
            .map(|(i, j)| cols[i].cross(&cols[j]))
            .into_iter()
            .max_by(|a, b| a.norm_squared().total_cmp(&b.norm_squared()))
            .unwrap_or_else(Vector3::zeros);
        let scale = f21.norm() * e.norm();
        let residual = (f21.transpose() * e).norm();
        if !(scale > 0.0 && scale.is_finite() && residual <= RANK2_TOLERANCE * scale) {
            return Pencil::Unordered;
        }
        let fold = |v: &[f64]| {
            v.iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &x| {
                    (lo.min(x), hi.max(x))
                })
        };
        let ((x0, x1), (y0, y1)) = (fold(&self.x), fold(&self.y));
        let centre = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
        let (ex, ey) = (e.x / e.z, e.y / e.z);
        let distance = (ex - centre.0).hypot(ey - centre.1);
        // Near the features, a line through a point R away deviates from the epipole's
        // direction (seen from the origin) by under E / R, E being the features' reach from
        // the origin plus their extent and band; over the extent, offsets across that
        // direction drift by under 2 E^2 / R. Within the margin, the lines count as parallel.
        let reach = centre.0.hypot(centre.1) + (x1 - x0).hypot(y1 - y0) + max_band;
        if e.z != 0.0 && distance.is_finite() && reach * reach > 0.5 * MARGIN_PX * distance {
            return Pencil::Through(ex, ey);
        }
        let norm = e.x.hypot(e.y);
        Pencil::Parallel {
            normal: (-e.y / norm, e.x / norm),
            centre,
            half_px: max_band + MARGIN_PX,
        }
    }

    /// Fills `out` with the features (insertion positions, in no particular order) whose
    /// squared distance to `line` (`a x + b y + c = 0`, `norm2 = a^2 + b^2`, an epipolar line
    /// of the `f21` given to [`Self::build`]) is below their bound: the same test as a scan
    /// over all of them.
    pub(super) fn near_line(&self, line: &Vector3<f64>, norm2: f64, out: &mut Vec<usize>) {
        out.clear();
        let s = &self.sorted;
        match self.pencil {
            Pencil::Through(..) => {
                let phi = (-line.x).atan2(line.y).rem_euclid(PI);
                for ring in &self.rings {
                    let (run, half) = (ring.run.clone(), ring.half);
                    if half >= 0.5 * PI {
                        s.scan(line, norm2, run, out);
                        continue;
                    }
                    // Whole buckets: those holding the window's ends and any between.
                    let (lo, hi) = (phi - half, phi + half);
                    let at = |key: f64| self.bucket_run(ring, key);
                    let (from, to) = if lo < 0.0 {
                        (at(lo + PI).start, at(hi).end)
                    } else if hi > PI {
                        (at(lo).start, at(hi - PI).end)
                    } else {
                        s.scan(line, norm2, at(lo).start..at(hi).end, out);
                        continue;
                    };
                    // A window across key 0 wraps from the ring's end to its start; its ends
                    // share a bucket when the ring has few.
                    if to >= from {
                        s.scan(line, norm2, run, out);
                    } else {
                        s.scan(line, norm2, from..run.end, out);
                        s.scan(line, norm2, run.start..to, out);
                    }
                }
            }
            Pencil::Parallel {
                normal,
                centre,
                half_px,
            } => {
                let t = (line.x * centre.0 + line.y * centre.1 + line.z) / norm2;
                let (qx, qy) = (centre.0 - t * line.x, centre.1 - t * line.y);
                let key = normal.0 * qx + normal.1 * qy;
                let lo = s.key.partition_point(|&k| k < key - half_px);
                let hi = s.key.partition_point(|&k| k <= key + half_px);
                s.scan(line, norm2, lo..hi, out);
            }
            Pencil::Unordered => s.scan(line, norm2, 0..s.key.len(), out),
        }
    }

    /// Positions in `sorted` of the bucket of `ring` holding `key`.
    fn bucket_run(&self, ring: &Ring, key: f64) -> Range<usize> {
        let count = ring.buckets.len() - 1;
        let b = ring.buckets.start + bucket_of(key - ring.from, ring.per_radian, count);
        self.bucket_start[b]..self.bucket_start[b + 1]
    }
}

/// Bucket of `offset` (radians past a ring's smallest key) among `count` buckets, `per_radian`
/// to a radian, the first and last open-ended: monotone in `offset`, as multiplication by a
/// positive number is.
fn bucket_of(offset: f64, per_radian: f64, count: usize) -> usize {
    ((offset.max(0.0) * per_radian) as usize).min(count - 1)
}

impl Sorted {
    /// Appends (in order) the features of positions `run` whose squared distance to `line` is
    /// below their bound. Branch-free: all are appended, then each is moved down to the count,
    /// which advances past those that pass (a branch on the test mispredicts).
    fn scan(&self, line: &Vector3<f64>, norm2: f64, run: Range<usize>, out: &mut Vec<usize>) {
        if run.is_empty() {
            return;
        }
        #[cfg(test)]
        self.scanned
            .fetch_add(run.len(), std::sync::atomic::Ordering::Relaxed);
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
    use crate::ScalePyramid;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use std::sync::atomic::Ordering;

    fn random_matrix(rng: &mut ChaCha8Rng) -> Matrix3<f64> {
        Matrix3::from_fn(|_, _| rng.random_range(-1.0..1.0))
    }

    /// For epipoles in the image, beside it, far away, at infinity, and for an F21 that is
    /// not rank 2: the index returns exactly what a scan over every feature accepts, for
    /// lines of every direction (near-vertical ones included) and features of every level,
    /// scanning few more features than pass.
    #[test]
    fn near_line_equals_the_full_scan() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let sigma2 = ScalePyramid::new(1.2, 8).unwrap().sigma2;
        let epipoles = [
            (Vector3::new(620.0, 190.0, 1.0), "through"),
            (Vector3::new(-900.0, 4000.0, 1.0), "through"),
            (Vector3::new(3e5, -2e5, 1.0), "through"),
            (Vector3::new(7e9, 2e9, 1.0), "parallel"),
            (Vector3::new(0.3, 1.0, 0.0), "parallel"),
            (Vector3::new(1.0, 0.0, 0.0), "parallel"),
            (Vector3::zeros(), "unordered"),
        ];
        for (e, layout) in epipoles {
            let mut index = PencilIndex::default();
            for i in 0..3000 {
                let s2 = sigma2[rng.random_range(0..8)];
                let (x, y) = (rng.random_range(-5.0..1246.0), rng.random_range(0.0..376.0));
                index.push(i, x, y, 3.84 * s2);
            }
            // Lines F21 x1 = e x (M x1) all pass through e; a random F21 is rank 3.
            let f21 = if e == Vector3::zeros() {
                random_matrix(&mut rng)
            } else {
                e.cross_matrix() * random_matrix(&mut rng)
            };
            index.build(&f21);
            let got_layout = match index.pencil {
                Pencil::Through(..) => "through",
                Pencil::Parallel { .. } => "parallel",
                Pencil::Unordered => "unordered",
            };
            assert_eq!(got_layout, layout, "{e:?}");
            // At most one bucket per feature, however far the epipole.
            let buckets = index.bucket_start.len() - index.rings.len();
            assert!(buckets <= index.index.len(), "{e:?}: {buckets} buckets");
            let (mut near, mut total) = (Vec::new(), 0);
            for _ in 0..2000 {
                // Through a random pixel, at any scale: e x p for a pencil, F21 p otherwise.
                let p = Vector3::new(
                    rng.random_range(-100.0..1300.0),
                    rng.random_range(-100.0..500.0),
                    1.0,
                );
                let scale = rng.random_range(1e-4..1e2);
                let line = scale
                    * if layout == "unordered" {
                        f21 * p
                    } else {
                        e.cross(&p)
                    };
                let norm2 = line.x * line.x + line.y * line.y;
                index.near_line(&line, norm2, &mut near);
                near.sort_unstable();
                let scan: Vec<usize> = (0..index.index.len())
                    .filter(|&k| {
                        let r = line.x * index.x[k] + line.y * index.y[k] + line.z;
                        r * r / norm2 < index.max_r2[k]
                    })
                    .collect();
                assert_eq!(near, scan, "{e:?}");
                total += scan.len();
            }
            assert!(
                total > 20_000,
                "the lines must cross features: {total}, {e:?}"
            );
            // Selectivity: a few times the passing features (2.2-2.8 here) where the lines
            // share a point, against 3000 per line for the rank-3 F.
            let scanned = index.sorted.scanned.load(Ordering::Relaxed);
            if layout != "unordered" {
                assert!(
                    scanned < 4 * total,
                    "{e:?}: {scanned} scanned, {total} pass"
                );
            }
        }
    }

    /// A window across direction 0 in a ring of one bucket (here, of one feature) visits
    /// each feature once.
    #[test]
    fn a_wrapping_window_scans_a_small_ring_once() {
        let mut index = PencilIndex::default();
        // Lines through the epipole (100, 100); features alone in their rings on either
        // side of it along the horizontal, and one off it.
        index.push(0, 900.0, 100.5, 4.0);
        index.push(1, 130.0, 140.0, 4.0);
        index.push(2, 60.0, 100.0, 4.0);
        let e = Vector3::new(100.0, 100.0, 1.0);
        let m = Matrix3::new(0.3, 0.1, 0.2, -0.4, 0.9, 0.1, 0.2, 0.5, 0.7);
        index.build(&(e.cross_matrix() * m));
        assert!(matches!(index.pencil, Pencil::Through(..)));
        let line = e.cross(&Vector3::new(900.0, 100.2, 1.0));
        let mut near = Vec::new();
        index.near_line(&line, line.x * line.x + line.y * line.y, &mut near);
        near.sort_unstable();
        assert_eq!(near, vec![0, 2]);
    }
}
