//! Uniform grid over the image for fast radius search (ORB-SLAM `Frame::AssignFeaturesToGrid`
//! and `Frame::GetFeaturesInArea`).

use crate::Keypoint;

/// Grid columns, as ORB-SLAM `FRAME_GRID_COLS`.
pub const GRID_COLS: usize = 64;
/// Grid rows, as ORB-SLAM `FRAME_GRID_ROWS`.
pub const GRID_ROWS: usize = 48;

/// Axis-aligned bounds (px) of the undistorted image: the region the grid covers.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImageBounds {
    /// Smallest x (px).
    pub min_x: f64,
    /// Largest x (px).
    pub max_x: f64,
    /// Smallest y (px).
    pub min_y: f64,
    /// Largest y (px).
    pub max_y: f64,
}

/// Keypoint indices bucketed into `GRID_COLS x GRID_ROWS` cells over [`ImageBounds`].
///
/// Unlike ORB-SLAM, keypoints outside the bounds are not dropped but kept in the nearest
/// border cell, so [`KeypointGrid::features_in_area`] is exact for every keypoint. Degenerate
/// bounds (empty or non-finite) put everything into one cell: still exact, just slower.
#[derive(Clone, Debug)]
pub struct KeypointGrid {
    bounds: ImageBounds,
    /// Cells per pixel along x and y (0 for degenerate bounds).
    inv_cell_w: f64,
    inv_cell_h: f64,
    /// Compressed rows: the keypoints of cell `c` are `indices[starts[c]..starts[c + 1]]`,
    /// cells in row-major order.
    starts: Vec<usize>,
    indices: Vec<usize>,
}

impl KeypointGrid {
    /// Buckets `keypoints` (undistorted px) into the grid. Indices refer to `keypoints`.
    pub fn new(keypoints: &[Keypoint], bounds: ImageBounds) -> Self {
        let inv = |n: usize, lo: f64, hi: f64| {
            let inv = n as f64 / (hi - lo);
            if inv.is_finite() && inv > 0.0 {
                inv
            } else {
                0.0
            }
        };
        let mut grid = Self {
            bounds,
            inv_cell_w: inv(GRID_COLS, bounds.min_x, bounds.max_x),
            inv_cell_h: inv(GRID_ROWS, bounds.min_y, bounds.max_y),
            starts: vec![0; GRID_COLS * GRID_ROWS + 1],
            indices: vec![0; keypoints.len()],
        };
        // Counting sort: count per cell, prefix-sum, then scatter (keeps indices ascending).
        let cells: Vec<usize> = keypoints
            .iter()
            .map(|kp| {
                let (cx, cy) = grid.cell_of(f64::from(kp.x), f64::from(kp.y));
                cy * GRID_COLS + cx
            })
            .collect();
        for &c in &cells {
            grid.starts[c + 1] += 1;
        }
        for c in 0..GRID_COLS * GRID_ROWS {
            grid.starts[c + 1] += grid.starts[c];
        }
        let mut next = grid.starts.clone();
        for (i, &c) in cells.iter().enumerate() {
            grid.indices[next[c]] = i;
            next[c] += 1;
        }
        grid
    }

    /// The bounds the grid was built over.
    pub fn bounds(&self) -> ImageBounds {
        self.bounds
    }

    /// Indices of the keypoints with `|kp.x - x| < radius` and `|kp.y - y| < radius` (a square
    /// window, as ORB-SLAM) and, when given, `min_level <= octave <= max_level`.
    ///
    /// `keypoints` must be the slice the grid was built from; indices beyond it are skipped.
    /// The result is sorted by cell (row-major), then by index. A non-finite or non-positive
    /// radius returns nothing.
    pub fn features_in_area(
        &self,
        keypoints: &[Keypoint],
        x: f64,
        y: f64,
        radius: f64,
        min_level: Option<u8>,
        max_level: Option<u8>,
    ) -> Vec<usize> {
        let mut out = Vec::new();
        if !(radius > 0.0 && radius.is_finite() && x.is_finite() && y.is_finite()) {
            return out;
        }
        let (x0, y0) = self.cell_of(x - radius, y - radius);
        let (x1, y1) = self.cell_of(x + radius, y + radius);
        for cy in y0..=y1 {
            let row = cy * GRID_COLS;
            let cell_indices = &self.indices[self.starts[row + x0]..self.starts[row + x1 + 1]];
            for &i in cell_indices {
                let Some(kp) = keypoints.get(i) else { continue };
                if min_level.is_some_and(|l| kp.octave < l)
                    || max_level.is_some_and(|l| kp.octave > l)
                {
                    continue;
                }
                if (f64::from(kp.x) - x).abs() < radius && (f64::from(kp.y) - y).abs() < radius {
                    out.push(i);
                }
            }
        }
        out
    }

    /// Cell containing pixel `(x, y)`, clamped to the grid (NaN maps to cell 0).
    fn cell_of(&self, x: f64, y: f64) -> (usize, usize) {
        // `as usize` saturates: negatives and NaN become 0.
        let cx = ((x - self.bounds.min_x) * self.inv_cell_w).floor() as usize;
        let cy = ((y - self.bounds.min_y) * self.inv_cell_h).floor() as usize;
        (cx.min(GRID_COLS - 1), cy.min(GRID_ROWS - 1))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    const BOUNDS: ImageBounds = ImageBounds {
        min_x: 0.0,
        max_x: 640.0,
        min_y: 0.0,
        max_y: 480.0,
    };

    fn random_keypoints(rng: &mut ChaCha8Rng, n: usize) -> Vec<Keypoint> {
        (0..n)
            .map(|_| Keypoint {
                // Some keypoints fall outside the bounds on purpose.
                x: rng.random_range(-20.0..660.0),
                y: rng.random_range(-20.0..500.0),
                octave: rng.random_range(0..8),
                angle_deg: rng.random_range(0.0..360.0),
                response: 1.0,
            })
            .collect()
    }

    fn naive(
        kps: &[Keypoint],
        x: f64,
        y: f64,
        r: f64,
        lo: Option<u8>,
        hi: Option<u8>,
    ) -> Vec<usize> {
        (0..kps.len())
            .filter(|&i| {
                let kp = kps[i];
                (f64::from(kp.x) - x).abs() < r
                    && (f64::from(kp.y) - y).abs() < r
                    && lo.is_none_or(|l| kp.octave >= l)
                    && hi.is_none_or(|l| kp.octave <= l)
            })
            .collect()
    }

    #[test]
    fn matches_naive_scan_on_random_data() {
        let seed = 7;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let kps = random_keypoints(&mut rng, 2000);
        for bounds in [
            BOUNDS,
            ImageBounds {
                min_x: 5.0,
                max_x: 5.0,
                min_y: 0.0,
                max_y: f64::NAN,
            },
        ] {
            let grid = KeypointGrid::new(&kps, bounds);
            for q in 0..300 {
                let x = rng.random_range(-50.0..690.0);
                let y = rng.random_range(-50.0..530.0);
                let r = rng.random_range(0.5..80.0);
                let lo = rng.random_bool(0.5).then(|| rng.random_range(0..8));
                let hi = rng.random_bool(0.5).then(|| rng.random_range(0..8));
                let mut got = grid.features_in_area(&kps, x, y, r, lo, hi);
                got.sort_unstable();
                assert_eq!(got, naive(&kps, x, y, r, lo, hi), "seed {seed}, query {q}");
            }
        }
    }

    #[test]
    fn boundary_is_strict_and_bad_radius_is_empty() {
        let kp = Keypoint {
            x: 110.0,
            y: 100.0,
            octave: 0,
            angle_deg: 0.0,
            response: 1.0,
        };
        let grid = KeypointGrid::new(&[kp], BOUNDS);
        assert!(grid
            .features_in_area(&[kp], 100.0, 100.0, 10.0, None, None)
            .is_empty());
        assert_eq!(
            grid.features_in_area(&[kp], 100.0, 100.0, 10.001, None, None),
            vec![0]
        );
        assert!(grid
            .features_in_area(&[kp], 100.0, 100.0, f64::NAN, None, None)
            .is_empty());
        assert!(grid
            .features_in_area(&[kp], 100.0, 100.0, -1.0, None, None)
            .is_empty());
        // A shorter keypoint slice than the grid was built from is tolerated.
        assert!(grid
            .features_in_area(&[], 110.0, 100.0, 5.0, None, None)
            .is_empty());
    }
}
