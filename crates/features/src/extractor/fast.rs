//! FAST-9 corners (Rosten & Drummond, 2006) with OpenCV's score and 3x3 non-maximum
//! suppression, so that the corners equal `cv2.FastFeatureDetector(threshold, True)`'s.
//!
//! A pixel `p` of intensity `v` is a corner when 9 contiguous pixels of the radius-3 Bresenham
//! circle are all brighter than `v + t` or all darker than `v - t`. Its score is
//! `s - 1`, where `s` is the largest `min |x - v|` over such arcs (one polarity per arc):
//! the highest threshold at which `p` would still be a corner. A corner survives suppression
//! when its score is strictly larger than those of its 8 neighbours (0 where no corner).

use std::ops::Range;

use rayon::prelude::*;
use wide::u8x32;

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

/// Pixels tested together; sized so the per-pixel loops vectorise.
const LANES: usize = 32;

/// FAST corners whose pixel lies at least `margin` px from every border (`margin >= 3`),
/// in row-major order, with their scores.
///
/// `threshold` is the intensity difference a circle pixel must exceed. Pixels closer than
/// `margin` to the border are not tested and count as non-corners for the suppression.
pub fn fast_corners(image: &GrayImage<'_>, threshold: u8, margin: usize) -> Vec<Corner> {
    let (w, h) = (image.width(), image.height());
    corners_in_window(image, threshold, margin, 0..w, 0..h, true)
}

/// The corners of [`fast_corners`] whose column lies in `xs` and row in `ys`: exactly those,
/// at the cost of testing the window and a 1 px ring around it (for the suppression). Runs
/// on the calling thread, for many small windows scanned in parallel.
pub fn fast_corners_in(
    image: &GrayImage<'_>,
    threshold: u8,
    margin: usize,
    xs: Range<usize>,
    ys: Range<usize>,
) -> Vec<Corner> {
    corners_in_window(image, threshold, margin, xs, ys, false)
}

/// [`fast_corners_in`], its rows scored in parallel when `parallel_rows`.
fn corners_in_window(
    image: &GrayImage<'_>,
    threshold: u8,
    margin: usize,
    xs: Range<usize>,
    ys: Range<usize>,
    parallel_rows: bool,
) -> Vec<Corner> {
    let (w, h) = (image.width(), image.height());
    let margin = margin.max(3);
    if w <= 2 * margin || h <= 2 * margin {
        return Vec::new();
    }
    // Reported window, then the tested one: 1 px more on each side, inside the margin.
    let (rx, ry) = (
        xs.start.max(margin)..xs.end.min(w - margin),
        ys.start.max(margin)..ys.end.min(h - margin),
    );
    if rx.is_empty() || ry.is_empty() {
        return Vec::new();
    }
    let (mut x0, mut x1) = (rx.start.max(margin + 1) - 1, (rx.end + 1).min(w - margin));
    // At least a whole block of columns where the image allows, as narrower rows are scalar.
    x1 = x1.max((x0 + LANES).min(w - margin));
    x0 = x0.min(x1.saturating_sub(LANES).max(margin));
    let (y0, y1) = (ry.start.max(margin + 1) - 1, (ry.end + 1).min(h - margin));
    // Scores of columns x0 - 1 ..= x1 and rows y0 - 1 ..= y1 (the outer ring stays zero) so
    // the suppression needs no bounds tests.
    let stride = x1 - x0 + 2;
    let at = |x: usize| x + 1 - x0;
    let mut scores = vec![0u8; (y1 - y0 + 2) * stride];
    let scored_rows = &mut scores[stride..(y1 - y0 + 1) * stride];
    let score =
        |(i, row): (usize, &mut [u8])| score_row(image, y0 + i, x0, x1, threshold, &mut row[1..]);
    let found: Vec<Vec<usize>> = if parallel_rows {
        scored_rows
            .par_chunks_mut(stride)
            .enumerate()
            .map(score)
            .collect()
    } else {
        scored_rows
            .chunks_mut(stride)
            .enumerate()
            .map(score)
            .collect()
    };
    let mut corners = Vec::new();
    for y in ry {
        let r = y + 1 - y0; // score row of image row y
        let (above, row, below) = (
            &scores[(r - 1) * stride..r * stride],
            &scores[r * stride..(r + 1) * stride],
            &scores[(r + 1) * stride..(r + 2) * stride],
        );
        for &x in found[y - y0].iter().filter(|&x| rx.contains(x)) {
            let c = at(x);
            let s = row[c];
            // One branch-free maximum over the 8 neighbours: per-neighbour early exits
            // mispredict (fast_corners on a TUM frame: 20 % slower).
            let (up, down) = (&above[c - 1..=c + 1], &below[c - 1..=c + 1]);
            let strongest_neighbour = [
                row[c - 1],
                row[c + 1],
                up[0],
                up[1],
                up[2],
                down[0],
                down[1],
                down[2],
            ]
            .into_iter()
            .fold(0, u8::max);
            if s > strongest_neighbour {
                corners.push(Corner {
                    x: x as u32,
                    y: y as u32,
                    score: f32::from(s),
                });
            }
        }
    }
    corners
}

/// Writes the score of every corner of row `y`, columns `x0..x1`, into `out` (`out[x - x0]`;
/// non-corners are left at 0) and returns their columns, increasing.
///
/// Compiled for AVX-512 (BW, VL) and AVX2 too, the widest the CPU has chosen at run time:
/// AVX2's vectors are twice as wide as SSE2's, and AVX-512 adds compares into mask registers
/// and three-input logic for the flags and arcs of the segment test.
fn score_row(
    image: &GrayImage<'_>,
    y: usize,
    x0: usize,
    x1: usize,
    t: u8,
    out: &mut [u8],
) -> Vec<usize> {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx512bw")
        && std::arch::is_x86_feature_detected!("avx512vl")
    {
        // SAFETY: the CPU has AVX-512 F, BW and VL (BW implies F), checked just above.
        return unsafe { score_row_avx512(image, y, x0, x1, t, out) };
    }
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2, checked just above.
        return unsafe { score_row_avx2(image, y, x0, x1, t, out) };
    }
    score_row_portable(image, y, x0, x1, t, out)
}

/// [`score_row_portable`] compiled with AVX-512 BW and VL (see [`score_row`]).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,avx512vl")]
fn score_row_avx512(
    image: &GrayImage<'_>,
    y: usize,
    x0: usize,
    x1: usize,
    t: u8,
    out: &mut [u8],
) -> Vec<usize> {
    score_row_portable(image, y, x0, x1, t, out)
}

/// [`score_row_portable`] compiled with AVX2 (32 lanes per instruction).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn score_row_avx2(
    image: &GrayImage<'_>,
    y: usize,
    x0: usize,
    x1: usize,
    t: u8,
    out: &mut [u8],
) -> Vec<usize> {
    score_row_portable(image, y, x0, x1, t, out)
}

/// [`score_row`] for the target's baseline instructions (SSE2 on x86_64), and inlined into
/// [`score_row_avx2`] and [`score_row_avx512`].
#[inline(always)]
fn score_row_portable(
    image: &GrayImage<'_>,
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
        // Lanes holding a corner; the overlapping last block revisits columns before x.
        let mut corners = if n == LANES {
            if compass_candidate::<LANES>(&rows, start, t) {
                lanes_above(&segment_test::<LANES>(&rows, start, t), 0)
            } else {
                0
            }
        } else {
            (0..n)
                .filter(|&i| arc_contrast::<1>(&rows, start + i)[0] > t)
                .fold(0u32, |mask, i| mask | 1 << i)
        } & (u32::MAX << (x - start));
        // Only the blocks holding a corner are scored (a third of those passing the compass
        // test at threshold 7, an eighth at 20).
        if corners != 0 {
            let contrast: [u8; LANES] = if n == LANES {
                arc_contrast::<LANES>(&rows, start)
            } else {
                std::array::from_fn(|i| {
                    if i < n {
                        arc_contrast::<1>(&rows, start + i)[0]
                    } else {
                        0
                    }
                })
            };
            while corners != 0 {
                let i = corners.trailing_zeros() as usize;
                corners &= corners - 1;
                out[start + i - x0] = contrast[i] - 1;
                columns.push(start + i);
            }
        }
        x = start + n;
    }
    columns
}

/// Bit `i` set where `values[i] > t`: a vector compare and its byte mask (SSE2 at least), as
/// a bit-by-bit fold compiles to scalar code.
#[inline(always)]
fn lanes_above(values: &[u8; LANES], t: u8) -> u32 {
    u8x32::from(*values).simd_gt(u8x32::splat(t)).to_bitmask()
}

/// The circle pixel `k` (mod 16) for the `N` pixels of the middle row from column `x`.
#[inline(always)]
fn ring<'r, const N: usize>(rows: &[&'r [u8]; 7], x: usize, k: usize) -> &'r [u8; N] {
    let (dx, dy) = CIRCLE[k % 16];
    let from = (x as isize + dx) as usize;
    rows[(dy + 3) as usize][from..from + N]
        .try_into()
        .expect("N pixels")
}

/// Whether any of the `N` pixels of the middle row from column `x` may be a corner at
/// threshold `t`: an arc of 9 holds two neighbouring compass pixels (0-4, 4-8, 8-12 or 12-0)
/// beyond the threshold on the same side, which rejects most blocks after 4 of the 16 loads.
#[inline(always)] // into score_row_avx2 and score_row_avx512
fn compass_candidate<const N: usize>(rows: &[&[u8]; 7], x: usize, t: u8) -> bool {
    let center: &[u8; N] = rows[3][x..x + N].try_into().expect("N pixels");
    // Plain loops rather than `<[u8; N]>::map`, which the compiler may leave a call in this
    // hot loop (it did once the crate grew: FAST 1.3x slower).
    let (mut bright, mut dark) = ([0u8; N], [0u8; N]);
    for ((b, d), &v) in bright.iter_mut().zip(&mut dark).zip(center) {
        (*b, *d) = (v.saturating_add(t), v.saturating_sub(t));
    }
    let (mut b_prev, mut d_prev) = ([false; N], [false; N]);
    let mut candidate = [false; N];
    for k in [0, 4, 8, 12, 0] {
        let p = ring::<N>(rows, x, k);
        for i in 0..N {
            let (b, d) = (p[i] > bright[i], p[i] < dark[i]);
            candidate[i] |= (b & b_prev[i]) | (d & d_prev[i]);
            b_prev[i] = b;
            d_prev[i] = d;
        }
    }
    candidate.iter().any(|&c| c)
}

/// For the `N` pixels of the middle row from column `x`: nonzero exactly where the pixel is a
/// corner at threshold `t` (where `arc_contrast > t`, without computing it). Each circle pixel
/// becomes a flag, 1 when brighter than the centre by more than `t` and 2 when darker, and
/// an arc of 9 whose flags share a bit is a corner: one byte per lane for both polarities,
/// and `&` rather than `min` (60-65 % of the cost of [`arc_contrast`] on a TUM frame).
#[inline(always)] // into score_row_avx2 and score_row_avx512
fn segment_test<const N: usize>(rows: &[&[u8]; 7], x: usize, t: u8) -> [u8; N] {
    let center: &[u8; N] = rows[3][x..x + N].try_into().expect("N pixels");
    let (mut bright, mut dark) = ([0u8; N], [0u8; N]);
    for ((b, d), &v) in bright.iter_mut().zip(&mut dark).zip(center) {
        (*b, *d) = (v.saturating_add(t), v.saturating_sub(t));
    }
    let mut sides = [[0u8; N]; 16];
    for (k, side) in sides.iter_mut().enumerate() {
        let p = ring::<N>(rows, x, k);
        for i in 0..N {
            side[i] = u8::from(p[i] > bright[i]) | u8::from(p[i] < dark[i]) << 1;
        }
    }
    strongest_arc(&sides, |a, b| a & b)
}

/// For the `N` pixels of the middle row from column `x`: the largest `c` such that 9
/// contiguous circle pixels are all at least `c` brighter, or all at least `c` darker, than
/// the centre (0 when there is none). The pixel is a corner at threshold `t` exactly when
/// `c > t`, and its score (see the module doc) is `c - 1`.
///
/// Per polarity, the saturated differences `d_k`, then minima over windows of 2, 4, 8 and 9
/// contiguous circle pixels (indices mod 16), all lane-wise so they vectorise.
#[inline(always)] // into score_row_avx2 and score_row_avx512
fn arc_contrast<const N: usize>(rows: &[&[u8]; 7], x: usize) -> [u8; N] {
    let center: &[u8; N] = rows[3][x..x + N].try_into().expect("N pixels");
    let mut brighter = [[0u8; N]; 16];
    let mut darker = [[0u8; N]; 16];
    for k in 0..16 {
        let p = ring::<N>(rows, x, k);
        for i in 0..N {
            brighter[k][i] = p[i].saturating_sub(center[i]);
            darker[k][i] = center[i].saturating_sub(p[i]);
        }
    }
    let mut best = strongest_arc(&brighter, u8::min);
    let dark = strongest_arc(&darker, u8::min);
    for i in 0..N {
        best[i] = best[i].max(dark[i]);
    }
    best
}

/// Lane-wise maximum over the 16 arcs of 9 contiguous circle pixels of `d` joined along the
/// arc by `join` (associative, idempotent: `min`, `&`): joins over windows of 2, 4, 8, then 9
/// pixels (indices mod 16).
#[inline(always)]
fn strongest_arc<const N: usize>(d: &[[u8; N]; 16], join: impl Fn(u8, u8) -> u8 + Copy) -> [u8; N] {
    let window = |a: &[[u8; N]; 16], b: &[[u8; N]; 16], step: usize| {
        let mut out = [[0u8; N]; 16];
        for k in 0..16 {
            let (ak, bk) = (&a[k], &b[(k + step) & 15]);
            for i in 0..N {
                out[k][i] = join(ak[i], bk[i]);
            }
        }
        out
    };
    let m2 = window(d, d, 1);
    let m4 = window(&m2, &m2, 2);
    let m8 = window(&m4, &m4, 4);
    let m9 = window(&m8, d, 8);
    let mut best = [0u8; N];
    for arc in &m9 {
        for i in 0..N {
            best[i] = best[i].max(arc[i]);
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

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
            arc_contrast::<1>(&rows, 3)[0] > t
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
    fn lane_mask_sets_the_bits_of_values_above_the_threshold() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        for t in [0, 1, 7, 20, 127, 128, 200, 254, 255] {
            for _ in 0..50 {
                let values: [u8; LANES] = std::array::from_fn(|_| rng.random());
                let expected = (0..LANES)
                    .filter(|&i| values[i] > t)
                    .fold(0u32, |mask, i| mask | 1 << i);
                assert_eq!(lanes_above(&values, t), expected, "t = {t}, {values:?}");
            }
        }
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

    /// Every score of `fast_corners` computed pixel by pixel with the one-lane reference
    /// `arc_contrast::<1>`, then suppressed as documented: `(x, y, score)` row-major.
    fn reference_corners(img: &GrayImage<'_>, t: u8, margin: usize) -> Vec<(usize, usize, u8)> {
        let (w, h) = (img.width(), img.height());
        let margin = margin.max(3);
        let mut scores = vec![0u8; w * h];
        for y in margin..h.saturating_sub(margin) {
            let rows: [&[u8]; 7] =
                std::array::from_fn(|i| img.row_span(0, (y + i - 3) as isize, w).unwrap());
            for x in margin..w.saturating_sub(margin) {
                let c = arc_contrast::<1>(&rows, x)[0];
                if c > t {
                    scores[y * w + x] = c - 1;
                }
            }
        }
        let mut corners = Vec::new();
        for y in margin..h.saturating_sub(margin) {
            for x in margin..w.saturating_sub(margin) {
                let s = scores[y * w + x];
                let neighbours = (y - 1..=y + 1)
                    .flat_map(|ny| (x - 1..=x + 1).map(move |nx| (nx, ny)))
                    .filter(|&p| p != (x, y));
                if s > 0
                    && neighbours
                        .into_iter()
                        .all(|(nx, ny)| scores[ny * w + nx] < s)
                {
                    corners.push((x, y, s));
                }
            }
        }
        corners
    }

    fn as_tuples(corners: &[Corner]) -> Vec<(usize, usize, u8)> {
        corners
            .iter()
            .map(|c| (c.x as usize, c.y as usize, c.score as u8))
            .collect()
    }

    type RowScorer = fn(&GrayImage<'_>, usize, usize, usize, u8, &mut [u8]) -> Vec<usize>;

    /// The row scorers this CPU runs: the baseline one always, the AVX2 and AVX-512 ones where
    /// it has those.
    fn row_scorers() -> Vec<(&'static str, RowScorer)> {
        let mut paths: Vec<(&'static str, RowScorer)> =
            vec![("portable", |img, y, x0, x1, t, out| {
                score_row_portable(img, y, x0, x1, t, out)
            })];
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2, checked just above.
            paths.push(("avx2", |img, y, x0, x1, t, out| unsafe {
                score_row_avx2(img, y, x0, x1, t, out)
            }));
        }
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx512bw")
            && std::arch::is_x86_feature_detected!("avx512vl")
        {
            // SAFETY: the CPU has AVX-512 F, BW and VL, checked just above.
            paths.push(("avx512", |img, y, x0, x1, t, out| unsafe {
                score_row_avx512(img, y, x0, x1, t, out)
            }));
        }
        paths
    }

    /// Each row scorer against `arc_contrast::<1>` pixel by pixel, on every row and on windows
    /// of several widths (whole blocks, the overlapping last block, rows narrower than a block).
    fn assert_rows_match_reference(img: &GrayImage<'_>, t: u8, what: &str) {
        let w = img.width();
        for (path, score) in row_scorers() {
            for y in 3..img.height() - 3 {
                let rows: [&[u8]; 7] =
                    std::array::from_fn(|i| img.row_span(0, (y + i - 3) as isize, w).unwrap());
                let windows = [
                    (3, w - 3),
                    (5, (5 + 40).min(w - 3)),
                    (4, (4 + 17).min(w - 3)),
                ];
                for (x0, x1) in windows.into_iter().filter(|(x0, x1)| x0 < x1) {
                    let mut out = vec![0u8; x1 - x0];
                    let columns = score(img, y, x0, x1, t, &mut out);
                    let expected: Vec<usize> = (x0..x1)
                        .filter(|&x| arc_contrast::<1>(&rows, x)[0] > t)
                        .collect();
                    assert_eq!(
                        columns, expected,
                        "{what}, {path}, t = {t}, row {y}, {x0}..{x1}"
                    );
                    for x in x0..x1 {
                        let c = arc_contrast::<1>(&rows, x)[0];
                        let want = if c > t { c - 1 } else { 0 };
                        assert_eq!(out[x - x0], want, "{what}, {path}, t = {t}, ({x}, {y})");
                    }
                }
            }
        }
    }

    fn random_image(w: usize, h: usize, seed: u64) -> Vec<u8> {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        // Few levels so that arcs of equal sides and ties of the suppression are common.
        let levels: Vec<u8> = vec![0, 30, 100, 128, 129, 160, 230, 255];
        (0..w * h)
            .map(|_| levels[rng.random_range(0..levels.len())])
            .collect()
    }

    #[test]
    fn row_scorers_equal_the_one_lane_reference_on_random_images() {
        for seed in 0..6 {
            let data = random_image(83, 23, seed);
            let img = GrayImage::new(83, 23, &data).unwrap();
            for t in [0, 1, 7, 20, 29, 70, 128, 254, 255] {
                assert_rows_match_reference(&img, t, &format!("seed {seed}"));
            }
        }
    }

    /// The first frames of TUM fr1/rpy in grey (from `FERROSLAM_DATA`, default
    /// `../shared/data` beside the repository), every `step`-th of the first `count`.
    fn tum_frames(count: usize, step: usize) -> Vec<(usize, usize, Vec<u8>)> {
        let data = std::env::var_os("FERROSLAM_DATA").map_or_else(
            || std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"),
            Into::into,
        );
        let rgb = data.join("tum/rgbd_dataset_freiburg1_rpy/rgb");
        let mut files: Vec<_> = std::fs::read_dir(&rgb)
            .unwrap_or_else(|e| panic!("{}: {e} (set FERROSLAM_DATA)", rgb.display()))
            .map(|e| e.unwrap().path())
            .collect();
        files.sort();
        files
            .iter()
            .take(count)
            .step_by(step)
            .map(|f| {
                let mut decoder = jpeg_decoder::Decoder::new(std::io::BufReader::new(
                    std::fs::File::open(f).unwrap(),
                ));
                let pixels = decoder.decode().unwrap();
                let info = decoder.info().unwrap();
                let gray = pixels
                    .chunks_exact(3)
                    .map(|p| {
                        (0.299 * f32::from(p[0])
                            + 0.587 * f32::from(p[1])
                            + 0.114 * f32::from(p[2]))
                        .round() as u8
                    })
                    .collect();
                (usize::from(info.width), usize::from(info.height), gray)
            })
            .collect()
    }

    #[test]
    fn tum_frames_give_the_reference_corners_and_scores() {
        let frames = tum_frames(300, 100);
        assert_eq!(frames.len(), 3);
        for (n, (w, h, data)) in frames.iter().enumerate() {
            let img = GrayImage::new(*w, *h, data).unwrap();
            for t in [7, 20] {
                let corners = as_tuples(&fast_corners(&img, t, 19));
                assert!(corners.len() > 100, "frame {n}, t = {t}: {}", corners.len());
                assert_eq!(
                    corners,
                    reference_corners(&img, t, 19),
                    "frame {n}, t = {t}"
                );
                let window = as_tuples(&fast_corners_in(&img, t, 3, 100..160, 200..260));
                let expected: Vec<_> = reference_corners(&img, t, 3)
                    .into_iter()
                    .filter(|&(x, y, _)| (100..160).contains(&x) && (200..260).contains(&y))
                    .collect();
                assert_eq!(window, expected, "frame {n}, t = {t}, window");
            }
            assert_rows_match_reference(&img, 20, &format!("TUM frame {n}"));
        }
    }

    proptest! {
        #[test]
        fn small_images_give_the_reference_corners(
            (w, h, data) in (7usize..80, 7usize..20).prop_flat_map(|(w, h)| {
                (Just(w), Just(h), proptest::collection::vec(any::<u8>(), w * h))
            }),
            t in any::<u8>(),
            margin in 3usize..6,
        ) {
            // Quantised so that corners and ties are common on so few pixels.
            let data: Vec<u8> = data.iter().map(|v| v & 0xE0).collect();
            let img = GrayImage::new(w, h, &data).unwrap();
            prop_assert_eq!(as_tuples(&fast_corners(&img, t, margin)), reference_corners(&img, t, margin));
            assert_rows_match_reference(&img, t, "proptest");
        }
    }
}
