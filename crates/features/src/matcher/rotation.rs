//! Rotation-consistency check (ORB-SLAM `rotHist` + `ORBmatcher::ComputeThreeMaxima`).

/// Number of bins of the rotation histogram: 12 bins of 30 degrees, which is what ORB-SLAM2/3
/// effectively use (`bin = round(rot / 30)` with `HISTO_LENGTH = 30`); narrower 12-degree bins
/// rejected good matches under the fast roll of TUM fr1/rpy (ATE 3.7 cm vs 3.2 cm).
pub const HISTO_LENGTH: usize = 12;

/// Histogram of keypoint orientation differences between matched features.
///
/// A rigid camera motion rotates all features by about the same in-plane angle, so true
/// matches share one angle difference. Entries are binned into [`HISTO_LENGTH`] bins of
/// `360 / HISTO_LENGTH = 30` degrees centred on multiples of 30 degrees (bin 0 covers
/// `[-15, 15)`), and only the (up to) three most populated bins are kept.
#[derive(Clone, Debug)]
pub struct RotationHistogram {
    bins: Vec<Vec<usize>>,
    /// Entries with a non-finite angle difference: always rejected.
    invalid: Vec<usize>,
}

impl Default for RotationHistogram {
    fn default() -> Self {
        Self::new()
    }
}

impl RotationHistogram {
    /// An empty histogram.
    pub fn new() -> Self {
        Self {
            bins: vec![Vec::new(); HISTO_LENGTH],
            invalid: Vec::new(),
        }
    }

    /// Records `entry` (a caller-chosen id, e.g. a query index) with angle difference
    /// `rot_deg` (degrees, any range: reduced modulo 360). Non-finite angles are recorded as
    /// inconsistent.
    pub fn add(&mut self, entry: usize, rot_deg: f32) {
        if !rot_deg.is_finite() {
            self.invalid.push(entry);
            return;
        }
        let bin_width = 360.0 / HISTO_LENGTH as f32;
        let bin = (rot_deg.rem_euclid(360.0) / bin_width).round() as usize % HISTO_LENGTH;
        self.bins[bin].push(entry);
    }

    /// Indices of the (up to) three most populated bins — ORB-SLAM `ComputeThreeMaxima`:
    /// ties go to the lower bin, empty bins are never chosen, and the second (third) bin is
    /// dropped when it holds fewer than `0.1 *` the entries of the first.
    pub fn dominant_bins(&self) -> Vec<usize> {
        let mut top: Vec<(usize, usize)> = Vec::with_capacity(4); // (count, bin), descending
        for (bin, entries) in self.bins.iter().enumerate() {
            let count = entries.len();
            let pos = top
                .iter()
                .position(|&(c, _)| count > c)
                .unwrap_or(top.len());
            if count > 0 && pos < 3 {
                top.insert(pos, (count, bin));
                top.truncate(3);
            }
        }
        let Some(&(max1, _)) = top.first() else {
            return Vec::new();
        };
        let min_count = 0.1 * max1 as f64;
        // Counts are descending, so cutting at the first small bin drops it and all after it.
        if let Some(k) = top.iter().position(|&(c, _)| (c as f64) < min_count) {
            top.truncate(k);
        }
        top.into_iter().map(|(_, bin)| bin).collect()
    }

    /// Entries to reject: those outside [`Self::dominant_bins`] plus those with a
    /// non-finite angle, sorted ascending.
    pub fn rejected(&self) -> Vec<usize> {
        let keep = self.dominant_bins();
        let mut out: Vec<usize> = self
            .bins
            .iter()
            .enumerate()
            .filter(|(bin, _)| !keep.contains(bin))
            .flat_map(|(_, entries)| entries.iter().copied())
            .chain(self.invalid.iter().copied())
            .collect();
        out.sort_unstable();
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rejects_an_inconsistent_minority() {
        let mut h = RotationHistogram::new();
        // 40 consistent matches rotated by ~30 deg (noise +-3 deg, one bin at 12-deg bins).
        for i in 0..40 {
            h.add(i, 30.0 + ((i % 7) as f32 - 3.0));
        }
        // 6 outliers spread over distinct far-away angles.
        let outliers = [100, 101, 102, 103, 104, 105];
        for (k, &e) in outliers.iter().enumerate() {
            h.add(e, 100.0 + 40.0 * k as f32);
        }
        // 30 +- 3 deg straddles bins 2 (24 deg) and 3 (36 deg); both dominate, 0.1 rule
        // drops each lone outlier bin (1 < 0.1 * max).
        assert_eq!(h.rejected(), outliers.to_vec());
    }

    #[test]
    fn keeps_three_bins_and_wraps_around() {
        let mut h = RotationHistogram::new();
        let mut e = 0;
        for (angle, n) in [
            (0.0, 10),
            (359.0, 5),
            (-1.0, 5),
            (30.0, 8),
            (60.0, 6),
            (120.0, 6),
        ] {
            for _ in 0..n {
                h.add(e, angle);
                e += 1;
            }
        }
        // Bin 0 holds 20 (0, 359, -1 deg), bin 1 holds 8, bin 2 and bin 4 hold 6 each: the
        // tie goes to bin 2, bin 4 is rejected.
        assert_eq!(h.dominant_bins(), vec![0, 1, 2]);
        assert_eq!(h.rejected(), (34..40).collect::<Vec<_>>());
    }

    #[test]
    fn ten_percent_rule_and_invalid_angles() {
        let mut h = RotationHistogram::new();
        for i in 0..50 {
            h.add(i, 95.0);
        }
        for i in 50..54 {
            h.add(i, 180.0); // 4 < 0.1 * 50
        }
        h.add(54, f32::NAN);
        assert_eq!(h.dominant_bins(), vec![3]);
        assert_eq!(h.rejected(), vec![50, 51, 52, 53, 54]);
        assert!(RotationHistogram::new().rejected().is_empty());
    }
}
