//! ORB-SLAM's two FAST thresholds: on a grid of ~30 px cells, a cell keeps only its corners
//! scoring at least the initial threshold when it has any, else all its corners (found at the
//! lower threshold).
//!
//! Running FAST once at the low threshold and filtering by score gives what running it at the
//! initial threshold first and falling back per cell would: the score does not depend on the
//! threshold FAST ran with.

use super::Corner;

/// Cell side (pixels) of the fallback grid.
const CELL_PX: usize = 30;

/// Which `corners` survive the fallback, for corners found in the region `margin` px inside
/// a `width x height` level (the grid covers that region).
pub fn threshold_fallback(
    corners: &[Corner],
    width: usize,
    height: usize,
    margin: usize,
    ini_threshold: f32,
) -> Vec<bool> {
    let (region_w, region_h) = (
        width.saturating_sub(2 * margin).max(1),
        height.saturating_sub(2 * margin).max(1),
    );
    let (cols, rows) = ((region_w / CELL_PX).max(1), (region_h / CELL_PX).max(1));
    let (cell_w, cell_h) = (region_w.div_ceil(cols), region_h.div_ceil(rows));
    let cell_of = |c: &Corner| {
        let cx = ((c.x as usize).saturating_sub(margin) / cell_w).min(cols - 1);
        let cy = ((c.y as usize).saturating_sub(margin) / cell_h).min(rows - 1);
        cy * cols + cx
    };
    let mut has_strong = vec![false; cols * rows];
    for c in corners.iter().filter(|c| c.score >= ini_threshold) {
        has_strong[cell_of(c)] = true;
    }
    corners
        .iter()
        .map(|c| c.score >= ini_threshold || !has_strong[cell_of(c)])
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weak_corners_survive_only_in_cells_without_strong_ones() {
        let c = |x, y, score| Corner { x, y, score };
        // 100x100 level, margin 10: an 80 px region, 2x2 cells of 40 px.
        let corners = [
            c(20, 20, 30.0),
            c(25, 22, 8.0),
            c(70, 20, 8.0),
            c(70, 70, 9.0),
            c(20, 70, 20.0),
        ];
        let keep = threshold_fallback(&corners, 100, 100, 10, 20.0);
        assert_eq!(keep, vec![true, false, true, true, true]);
    }
}
