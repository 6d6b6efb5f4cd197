//! FAST-9 corners (Rosten & Drummond, 2006) with OpenCV's score and 3x3 non-maximum
//! suppression, so that the corners equal `cv2.FastFeatureDetector(threshold, True)`'s.
//!
//! A pixel `p` of intensity `v` is a corner when 9 contiguous pixels of the radius-3 Bresenham
//! circle are all brighter than `v + t` or all darker than `v - t`. Its score is
//! `s - 1`, where `s` is the largest `min |x - v|` over such arcs (one polarity per arc):
//! the highest threshold at which `p` would still be a corner. A corner survives suppression
//! when its score is strictly larger than those of its 8 neighbours (0 where no corner).

use multiversion::multiversion;
use rayon::prelude::*;

use super::Corner;
use crate::GrayImage;

/// The radius-3 circle, clockwise from the top: `(dx, dy)` in pixels.
const CIRCLE: [(isize, isize); 16] = [
    (0, -3),
    (1, -3),
    (2, -2),
    (3, -1),
    (3, 0),
    (3, 1),
    (2, 2),
    (1, 3),
    (0, 3),
    (-1, 3),
    (-2, 2),
    (-3, 1),
    (-3, 0),
    (-3, -1),
    (-2, -2),
    (-1, -3),
];

/// Contiguous circle pixels a corner needs.
const ARC: usize = 9;

/// Pixels tested together; sized so the per-pixel loops vectorise.
const LANES: usize = 32;

/// FAST corners whose pixel lies at least `margin` px from every border (`margin >= 3`),
/// in row-major order, with their scores.
///
/// `threshold` is the intensity difference a circle pixel must exceed. Pixels closer than
/// `margin` to the border are not tested and count as non-corners for the suppression.
pub fn fast_corners(image: &GrayImage<'_>, threshold: u8, margin: usize) -> Vec<Corner> {
    let (w, h) = (image.width(), image.height());
    let margin = margin.max(3);
    if w <= 2 * margin || h <= 2 * margin {
        return Vec::new();
    }
    let (x0, x1) = (margin, w - margin);
    // Score rows y0 - 1 ..= y1 (the outer two stay zero) so suppression needs no bounds tests.
    let (y0, y1) = (margin, h - margin);
    let mut scores = vec![0u8; (y1 - y0 + 2) * w];
    let found: Vec<Vec<usize>> = scores[w..(y1 - y0 + 1) * w]
        .par_chunks_mut(w)
        .enumerate()
        .map(|(i, row)| score_row(image, y0 + i, x0, x1, threshold, row))
        .collect();
    let mut corners = Vec::new();
    for (i, xs) in found.iter().enumerate() {
        let r = i + 1; // score row of image row y0 + i
        let (above, row, below) = (
            &scores[(r - 1) * w..r * w],
            &scores[r * w..(r + 1) * w],
            &scores[(r + 1) * w..(r + 2) * w],
        );
        let is_peak = |x: usize| {
            let s = row[x];
            s > row[x - 1]
                && s > row[x + 1]
                && above[x - 1..=x + 1].iter().all(|&n| s > n)
                && below[x - 1..=x + 1].iter().all(|&n| s > n)
        };
        corners.extend(
            xs.iter()
                .filter(|&&x| row[x] > 0 && is_peak(x))
                .map(|&x| Corner {
                    x: x as u32,
                    y: (y0 + i) as u32,
                    score: f32::from(row[x]),
                }),
        );
    }
    corners
}

/// Writes the score of every corner of row `y`, columns `x0..x1`, into `out` (indexed by
/// column; non-corners are left at 0) and returns their columns, increasing.
///
/// Compiled for AVX2 too, chosen at run time: the lanes are twice as wide.
#[multiversion(targets("x86_64+avx2"))]
fn score_row<'a>(
    image: &GrayImage<'a>,
    y: usize,
    x0: usize,
    x1: usize,
    t: u8,
    out: &mut [u8],
) -> Vec<usize> {
    let w = image.width();
    let rows: [&[u8]; 7] = std::array::from_fn(|i| {
        image
            .row_span(0, y as isize + i as isize - 3, w)
            .expect("rows y-3..=y+3 lie inside (margin >= 3)")
    });
    let mut columns = Vec::new();
    let mut x = x0;
    while x < x1 {
        // Whole blocks only (the last one overlaps its predecessor) so the lanes vectorise.
        let start = if x1 - x0 >= LANES {
            x.min(x1 - LANES)
        } else {
            x
        };
        let n = LANES.min(x1 - start);
        let found = if n == LANES {
            arc_found::<LANES>(&rows, start, t)
        } else {
            std::array::from_fn(|i| i < n && arc_found::<1>(&rows, start + i, t)[0])
        };
        // The overlapping last block revisits columns before x: skip them.
        for i in (x - start..n).filter(|&i| found[i]) {
            out[start + i] = corner_score(&rows, start + i);
            columns.push(start + i);
        }
        x = start + n;
    }
    columns
}

/// For the `N` pixels of the middle row from column `x`: whether 9 contiguous circle pixels
/// are all brighter than `v + t` or all darker than `v - t`.
///
/// Such an arc holds two neighbouring compass pixels (0-4, 4-8, 8-12 or 12-0), which rejects
/// most blocks after 4 of the 16 loads; then the longest run of brighter / darker pixels
/// along the circle, walked twice round so no arc wraps.
#[inline(always)] // into score_row's AVX2 version
fn arc_found<const N: usize>(rows: &[&[u8]; 7], x: usize, t: u8) -> [bool; N] {
    let center: &[u8; N] = rows[3][x..x + N].try_into().expect("N pixels");
    let bright: [u8; N] = center.map(|v| v.saturating_add(t));
    let dark: [u8; N] = center.map(|v| v.saturating_sub(t));
    let ring = |k: usize| -> &[u8; N] {
        let (dx, dy) = CIRCLE[k % 16];
        let from = (x as isize + dx) as usize;
        rows[(dy + 3) as usize][from..from + N]
            .try_into()
            .expect("N pixels")
    };
    let (mut b_prev, mut d_prev) = ([false; N], [false; N]);
    let mut candidate = false;
    for k in [0, 4, 8, 12, 0] {
        let p = ring(k);
        for i in 0..N {
            let (b, d) = (p[i] > bright[i], p[i] < dark[i]);
            candidate |= (b & b_prev[i]) | (d & d_prev[i]);
            b_prev[i] = b;
            d_prev[i] = d;
        }
    }
    if !candidate {
        return [false; N];
    }
    let (mut b_run, mut d_run, mut longest) = ([0u8; N], [0u8; N], [0u8; N]);
    for k in 0..16 + ARC - 1 {
        let p = ring(k);
        for i in 0..N {
            // run + 1 where the pixel continues the arc, else 0 (branch-free for the lanes)
            b_run[i] = (b_run[i] + 1) & u8::from(p[i] > bright[i]).wrapping_neg();
            d_run[i] = (d_run[i] + 1) & u8::from(p[i] < dark[i]).wrapping_neg();
            longest[i] = longest[i].max(b_run[i]).max(d_run[i]);
        }
    }
    longest.map(|run| usize::from(run) >= ARC)
}

/// `s - 1` for the corner at column `x` of the middle row (see the module doc).
#[inline(always)]
fn corner_score(rows: &[&[u8]; 7], x: usize) -> u8 {
    let v = i16::from(rows[3][x]);
    // The circle twice, so every arc is a window; minima over windows of 2, 4, 8 then 9.
    let circle: [i16; 16] = std::array::from_fn(|k| {
        let (dx, dy) = CIRCLE[k];
        i16::from(rows[(dy + 3) as usize][(x as isize + dx) as usize]) - v
    });
    let diff: [i16; 32] = std::array::from_fn(|k| circle[k % 16]);
    let best_arc = |d: [i16; 32]| {
        let m2: [i16; 31] = std::array::from_fn(|i| d[i].min(d[i + 1]));
        let m4: [i16; 29] = std::array::from_fn(|i| m2[i].min(m2[i + 2]));
        let m8: [i16; 25] = std::array::from_fn(|i| m4[i].min(m4[i + 4]));
        (0..16).map(|i| m8[i].min(d[i + 8])).max().unwrap_or(0)
    };
    let best = best_arc(diff).max(best_arc(diff.map(|d| -d)));
    (best - 1).clamp(0, 255) as u8
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(w: usize, h: usize, f: impl Fn(usize, usize) -> u8) -> Vec<u8> {
        (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| f(x, y))
            .collect()
    }

    #[test]
    fn arc_test_needs_nine_contiguous_pixels_across_the_wrap() {
        // centre 100 on a 7x7 patch; the listed circle pixels set to 200
        let found = |ks: &[usize], t: u8| {
            let mut data = [100u8; 49];
            for &k in ks {
                let (dx, dy) = CIRCLE[k];
                data[((3 + dy) * 7 + 3 + dx) as usize] = 200;
            }
            let rows: [&[u8]; 7] = std::array::from_fn(|r| &data[r * 7..r * 7 + 7]);
            arc_found::<1>(&rows, 3, t)[0]
        };
        assert!(found(&(0..9).collect::<Vec<_>>(), 20));
        assert!(!found(&(0..9).collect::<Vec<_>>(), 100)); // 200 is not brighter than 100 + 100
        assert!(found(&[12, 13, 14, 15, 0, 1, 2, 3, 4], 20));
        assert!(!found(&[13, 14, 15, 0, 1, 2, 3, 4], 20));
        assert!(!found(&(0..8).collect::<Vec<_>>(), 20));
        assert!(!found(&[0, 2, 4, 6, 8, 10, 12, 14], 20));
        assert!(found(&(0..16).collect::<Vec<_>>(), 20));
    }

    #[test]
    fn bright_dot_is_one_corner_scored_by_its_contrast() {
        // One pixel of 200 on 100: all 16 circle pixels are darker by 100 -> a corner of
        // score 99; no other pixel has 9 differing circle pixels.
        let data = image(40, 40, |x, y| if (x, y) == (20, 20) { 200 } else { 100 });
        let img = GrayImage::new(40, 40, &data).unwrap();
        let corners = fast_corners(&img, 20, 3);
        assert_eq!(
            corners,
            vec![Corner {
                x: 20,
                y: 20,
                score: 99.0
            }]
        );
        assert!(fast_corners(&img, 120, 3).is_empty());
    }

    #[test]
    fn margin_excludes_corners_and_flat_images_have_none() {
        let data = image(40, 40, |x, y| if (x, y) == (5, 5) { 200 } else { 100 });
        let img = GrayImage::new(40, 40, &data).unwrap();
        assert_eq!(fast_corners(&img, 20, 3).len(), 1);
        assert!(fast_corners(&img, 20, 6).is_empty());
        let flat = vec![7u8; 40 * 40];
        assert!(fast_corners(&GrayImage::new(40, 40, &flat).unwrap(), 1, 3).is_empty());
    }
}
