//! ORB-SLAM's even spread of corners over a level (its `DistributeOctTree`), as a ranking.
//!
//! Each corner gets the coarsest quadtree depth at which it is the strongest corner of its
//! cell; the level keeps its budget ordered by (depth, score), i.e. the best corner of every
//! cell at the deepest depth that fits the budget, then the strongest of the next finer one.
//! In Z-order every quadtree cell is a contiguous run, so each depth is one linear pass.

use super::Corner;

/// Finest depth: cells below one pixel for levels under 2048 px.
const MAX_DEPTH: u32 = 11;

/// Indices of the `budget` corners kept, in order of (depth, rank by score); all indices in
/// their given order when there are no more than `budget`.
///
/// `corners` lie in the square region starting `margin` px inside the level whose larger
/// side is `extent_px = max(width, height) - 2 * margin`. Equal scores rank by index.
pub fn spread(corners: &[Corner], extent_px: usize, margin: usize, budget: usize) -> Vec<usize> {
    let n = corners.len();
    if n <= budget {
        return (0..n).collect();
    }
    let mut by_score: Vec<usize> = (0..n).collect();
    by_score.sort_by(|&a, &b| corners[b].score.total_cmp(&corners[a].score));
    let mut rank = vec![0usize; n];
    for (r, &i) in by_score.iter().enumerate() {
        rank[i] = r;
    }
    let cells = 1u32 << MAX_DEPTH;
    // f32 arithmetic on purpose: the selection was specified (and its tests tuned) with it.
    let px_to_cell = (f64::from(cells) / extent_px.max(1) as f64) as f32;
    let cell_coord = |v: u32| {
        let q = (v as f32 - margin as f32) * px_to_cell;
        q.clamp(0.0, (cells - 1) as f32) as u32
    };
    let mut z: Vec<(u64, usize)> = corners
        .iter()
        .zip(&rank)
        .map(|(c, &r)| (morton(cell_coord(c.x), cell_coord(c.y)), r))
        .collect();
    z.sort_by_key(|&(code, _)| code); // stable: equal codes keep index order
    let mut depth_of_rank = vec![MAX_DEPTH + 1; n];
    for depth in 0..=MAX_DEPTH {
        let shift = 2 * (MAX_DEPTH - depth);
        let mut cells_seen = 0;
        for run in z.chunk_by(|a, b| a.0 >> shift == b.0 >> shift) {
            let best = run
                .iter()
                .map(|&(_, r)| r)
                .min()
                .expect("runs are non-empty");
            depth_of_rank[best] = depth_of_rank[best].min(depth);
            cells_seen += 1;
        }
        if cells_seen >= budget {
            break;
        }
    }
    let mut ranks: Vec<usize> = (0..n).collect();
    ranks.sort_by_key(|&r| depth_of_rank[r]); // stable: ties by rank
    ranks.truncate(budget);
    ranks.into_iter().map(|r| by_score[r]).collect()
}

/// Z-order code of 16-bit cell coordinates: bits of `x` at even, of `y` at odd positions.
fn morton(x: u32, y: u32) -> u64 {
    fn spread_bits(v: u32) -> u64 {
        let mut v = u64::from(v & 0xFFFF);
        v = (v | (v << 8)) & 0x00FF_00FF;
        v = (v | (v << 4)) & 0x0F0F_0F0F;
        v = (v | (v << 2)) & 0x3333_3333;
        (v | (v << 1)) & 0x5555_5555
    }
    spread_bits(x) | (spread_bits(y) << 1)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn corners(xy_score: &[(u32, u32, f32)]) -> Vec<Corner> {
        xy_score
            .iter()
            .map(|&(x, y, score)| Corner { x, y, score })
            .collect()
    }

    #[test]
    fn morton_interleaves_x_then_y() {
        assert_eq!(morton(0b11, 0), 0b0101);
        assert_eq!(morton(0, 0b11), 0b1010);
        assert_eq!(morton(1, 1), 0b11);
    }

    #[test]
    fn picks_the_best_of_each_quadrant_before_the_strongest_overall() {
        // 4 strong corners crowd one quadrant, 4 weak ones spread out: with budget 4 the
        // spread takes the best of each quadrant rather than the 4 strongest.
        let c = corners(&[
            (36, 36, 90.0),
            (37, 38, 80.0),
            (39, 36, 70.0),
            (41, 41, 60.0),
            (216, 36, 10.0),
            (36, 216, 11.0),
            (216, 216, 12.0),
            (126, 126, 13.0),
        ]);
        let mut chosen = spread(&c, 240, 16, 4);
        chosen.sort_unstable();
        assert_eq!(chosen, vec![0, 4, 5, 6]);
    }

    #[test]
    fn few_corners_are_all_kept_in_order_and_ties_rank_by_index() {
        let c = corners(&[(20, 20, 5.0), (30, 30, 9.0)]);
        assert_eq!(spread(&c, 100, 16, 5), vec![0, 1]);
        let same = corners(&[(20, 20, 5.0), (21, 20, 5.0), (22, 20, 5.0)]);
        assert_eq!(spread(&same, 100, 16, 1), vec![0]);
    }
}
