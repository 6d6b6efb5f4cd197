//! ORB-SLAM's two FAST thresholds: on a grid of ~30 px cells, a cell keeps its corners
//! scoring at least the initial threshold when it has any, else its corners at the lower
//! threshold.
//!
//! FAST runs at the initial threshold on the whole level, then at the lower one only in the
//! cells left empty. This equals running FAST once at the lower threshold and filtering by
//! score: a corner's score does not depend on the threshold, and a corner scoring at least
//! the initial threshold is suppressed only by a neighbour that does too.

use std::ops::Range;

use rayon::prelude::*;

use super::{fast, Corner, FastThresholds};
use crate::GrayImage;

/// Cell side (pixels) of the fallback grid.
const CELL_PX: usize = 30;

/// The fallback grid over the region `margin` px inside a level; the last column and row of
/// cells also take whatever lies beyond the region.
#[derive(Clone, Copy, Debug)]
struct FallbackGrid {
    margin: usize,
    cols: usize,
    rows: usize,
    cell_w: usize,
    cell_h: usize,
}

impl FallbackGrid {
    fn new(width: usize, height: usize, margin: usize) -> Self {
        let (region_w, region_h) = (
            width.saturating_sub(2 * margin).max(1),
            height.saturating_sub(2 * margin).max(1),
        );
        let (cols, rows) = ((region_w / CELL_PX).max(1), (region_h / CELL_PX).max(1));
        Self {
            margin,
            cols,
            rows,
            cell_w: region_w.div_ceil(cols),
            cell_h: region_h.div_ceil(rows),
        }
    }

    /// Row-major index of the cell holding pixel `(x, y)`.
    fn cell_of(&self, x: u32, y: u32) -> usize {
        let cx = ((x as usize).saturating_sub(self.margin) / self.cell_w).min(self.cols - 1);
        let cy = ((y as usize).saturating_sub(self.margin) / self.cell_h).min(self.rows - 1);
        cy * self.cols + cx
    }

    /// Pixels of cells `first..=last` along one axis of `count` cells of side `side`.
    fn span(&self, first: usize, last: usize, count: usize, side: usize) -> Range<usize> {
        let start = if first == 0 {
            0
        } else {
            self.margin + first * side
        };
        let end = if last + 1 == count {
            usize::MAX
        } else {
            self.margin + (last + 1) * side
        };
        start..end
    }

    /// Windows `(columns, rows)` covering exactly the cells where `empty` holds: each run of
    /// neighbouring empty cells in a grid row is one window.
    fn windows(&self, empty: &[bool]) -> Vec<(Range<usize>, Range<usize>)> {
        let mut windows = Vec::new();
        for cy in 0..self.rows {
            let row = &empty[cy * self.cols..(cy + 1) * self.cols];
            let mut cx = 0;
            while cx < self.cols {
                if !row[cx] {
                    cx += 1;
                    continue;
                }
                let first = cx;
                while cx + 1 < self.cols && row[cx + 1] {
                    cx += 1;
                }
                windows.push((
                    self.span(first, cx, self.cols, self.cell_w),
                    self.span(cy, cy, self.rows, self.cell_h),
                ));
                cx += 1;
            }
        }
        windows
    }
}

/// The FAST corners of `level` (at least `edge_px` from its border, see
/// [`fast::fast_corners`]) that survive the fallback on the grid `margin` px inside it, in
/// row-major order.
pub fn fallback_corners(
    level: &GrayImage<'_>,
    fast: FastThresholds,
    edge_px: usize,
    margin: usize,
) -> Vec<Corner> {
    let mut corners = fast::fast_corners(level, fast.initial, edge_px);
    let grid = FallbackGrid::new(level.width(), level.height(), margin);
    let mut empty = vec![true; grid.cols * grid.rows];
    for c in &corners {
        empty[grid.cell_of(c.x, c.y)] = false;
    }
    corners.par_extend(
        grid.windows(&empty)
            .into_par_iter()
            .flat_map_iter(|(xs, ys)| fast::fast_corners_in(level, fast.min, edge_px, xs, ys)),
    );
    corners.sort_unstable_by_key(|c| (c.y, c.x));
    corners
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn windows_cover_runs_of_empty_cells_and_the_borders() {
        // 100x100 level, margin 10: an 80 px region, 2x2 cells of 40 px.
        let grid = FallbackGrid::new(100, 100, 10);
        assert_eq!(grid.cell_of(49, 49), 0);
        assert_eq!(grid.cell_of(50, 49), 1);
        assert_eq!(grid.cell_of(95, 95), 3);
        let windows = grid.windows(&[true, true, false, true]);
        assert_eq!(
            windows,
            vec![(0..usize::MAX, 0..50), (50..usize::MAX, 50..usize::MAX)]
        );
        assert!(grid.windows(&[false; 4]).is_empty());
    }

    #[test]
    fn weak_corners_only_in_cells_without_strong_ones() {
        // Bright dots on 100: contrast 150 (strong) or 15 (weak at thresholds 20 / 7).
        let (w, h) = (100, 100);
        let dots = [(25, 25, 250), (35, 30, 115), (70, 25, 115), (70, 70, 115)];
        let mut data = vec![100u8; w * h];
        for &(x, y, v) in &dots {
            data[y * w + x] = v;
        }
        let level = GrayImage::new(w, h, &data).unwrap();
        let thresholds = FastThresholds {
            initial: 20,
            min: 7,
        };
        let found: Vec<(u32, u32, f32)> = fallback_corners(&level, thresholds, 13, 10)
            .iter()
            .map(|c| (c.x, c.y, c.score))
            .collect();
        // (35, 30) shares its cell with the strong (25, 25)
        assert_eq!(found, vec![(25, 25, 149.0), (70, 25, 14.0), (70, 70, 14.0)]);
    }

    #[test]
    fn equals_one_pass_at_the_low_threshold_filtered_by_score() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        for (w, h) in [(160usize, 120usize), (97, 211)] {
            // sparse blobs on 100 (noise breaks the ties suppression would drop), of strong
            // contrast (+-60) or weak (+-12)
            let mut data: Vec<u8> = (0..w * h).map(|_| rng.random_range(99..=101)).collect();
            for blob in 0..16 {
                let (cx, cy, r) = (
                    rng.random_range(0..w),
                    rng.random_range(0..h),
                    rng.random_range(1..4),
                );
                let contrast = if blob % 2 == 0 { 60 } else { 12 };
                let sign = if rng.random_bool(0.5) { 1 } else { -1 };
                for y in cy.saturating_sub(r)..(cy + r).min(h) {
                    for x in cx.saturating_sub(r)..(cx + r).min(w) {
                        data[y * w + x] = (i32::from(data[y * w + x]) + sign * contrast) as u8;
                    }
                }
            }
            let level = GrayImage::new(w, h, &data).unwrap();
            let thresholds = FastThresholds {
                initial: 20,
                min: 7,
            };
            let grid = FallbackGrid::new(w, h, 16);
            let all = fast::fast_corners(&level, thresholds.min, 19);
            let mut has_strong = vec![false; grid.cols * grid.rows];
            for c in all.iter().filter(|c| c.score >= 20.0) {
                has_strong[grid.cell_of(c.x, c.y)] = true;
            }
            let expected: Vec<Corner> = all
                .iter()
                .filter(|c| c.score >= 20.0 || !has_strong[grid.cell_of(c.x, c.y)])
                .copied()
                .collect();
            assert!(expected.iter().any(|c| c.score < 20.0));
            assert!(expected.iter().any(|c| c.score >= 20.0));
            assert_eq!(fallback_corners(&level, thresholds, 19, 16), expected);
        }
    }
}
