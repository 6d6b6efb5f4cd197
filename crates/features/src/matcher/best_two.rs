//! Best and second-best candidate of one query, as tracked in every ORB-SLAM search loop.

use super::Candidate;

/// Running best/second-best Hamming distances (ORB-SLAM `bestDist`, `bestDist2`,
/// `bestLevel`, `bestLevel2`). Ties keep the earlier candidate as best and make the later one
/// the second best, so an exact tie fails the ratio tests.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct BestTwo {
    /// `(distance, target index, octave)`.
    best: Option<(u32, usize, u8)>,
    /// `(distance, octave)`.
    second: Option<(u32, u8)>,
}

impl BestTwo {
    /// Offers one candidate.
    pub(super) fn push(&mut self, distance: u32, index: usize, octave: u8) {
        match self.best {
            Some((d, _, _)) if distance >= d => {
                if self.second.is_none_or(|(d2, _)| distance < d2) {
                    self.second = Some((distance, octave));
                }
            }
            _ => {
                self.second = self.best.map(|(d, _, lvl)| (d, lvl));
                self.best = Some((distance, index, octave));
            }
        }
    }

    /// Offers one candidate of a query whose candidates come in any order: afterwards the best
    /// candidate and the second-best distance are those [`Self::push`] gives when offered them
    /// by increasing index (ties of distance go to the lower index).
    pub(super) fn push_unordered(&mut self, distance: u32, index: usize, octave: u8) {
        match self.best {
            Some((d, i, lvl)) if distance == d && index < i => {
                self.second = Some((d, lvl));
                self.best = Some((distance, index, octave));
            }
            _ => self.push(distance, index, octave),
        }
    }

    /// The best candidate if `best <= max_distance` and, when `ratio` is given and a second
    /// candidate exists, `best < ratio * second` (ORB-SLAM `SearchByBoW`,
    /// `SearchForInitialization`).
    pub(super) fn accept(self, max_distance: u32, ratio: Option<f32>) -> Option<Candidate> {
        let (d, i, _) = self.best.filter(|&(d, _, _)| d <= max_distance)?;
        let ambiguous = match (ratio, self.second) {
            (Some(r), Some((d2, _))) => d as f32 >= r * d2 as f32,
            _ => false,
        };
        (!ambiguous).then_some((i, d))
    }

    /// The best candidate if `best <= max_distance`, rejecting it when `ratio` is given, the
    /// second best lies on the SAME pyramid level and `best > ratio * second` (ORB-SLAM
    /// `SearchByProjection(Frame, vector<MapPoint*>)`).
    pub(super) fn accept_same_level(
        self,
        max_distance: u32,
        ratio: Option<f32>,
    ) -> Option<Candidate> {
        let (d, i, lvl) = self.best.filter(|&(d, _, _)| d <= max_distance)?;
        let ambiguous = match (ratio, self.second) {
            (Some(r), Some((d2, lvl2))) => lvl2 == lvl && d as f32 > r * d2 as f32,
            _ => false,
        };
        (!ambiguous).then_some((i, d))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tracks_best_and_second() {
        let mut b = BestTwo::default();
        for (d, i) in [(40, 0), (20, 1), (30, 2), (25, 3)] {
            b.push(d, i, 0);
        }
        assert_eq!(b.accept(50, None), Some((1, 20)));
        assert_eq!(b.accept(50, Some(0.9)), Some((1, 20))); // 20 < 0.9 * 25
        assert_eq!(b.accept(50, Some(0.7)), None); // 20 >= 0.7 * 25
        assert_eq!(b.accept(19, None), None);
    }

    #[test]
    fn ties_are_ambiguous_and_keep_the_first() {
        let mut b = BestTwo::default();
        b.push(10, 5, 0);
        b.push(10, 6, 0);
        assert_eq!(b.accept(50, None), Some((5, 10)));
        assert_eq!(b.accept(50, Some(0.99)), None);
    }

    #[test]
    fn same_level_ratio_ignores_other_levels() {
        let mut b = BestTwo::default();
        b.push(30, 0, 1);
        b.push(31, 1, 2);
        assert_eq!(b.accept_same_level(100, Some(0.8)), Some((0, 30)));
        b.push(31, 2, 1); // not better than the current second: levels unchanged
        assert_eq!(b.accept_same_level(100, Some(0.8)), Some((0, 30)));
        let mut c = BestTwo::default();
        c.push(30, 0, 1);
        c.push(31, 1, 1);
        assert_eq!(c.accept_same_level(100, Some(0.8)), None);
        assert_eq!(c.accept_same_level(100, None), Some((0, 30)));
    }

    #[test]
    fn empty_accepts_nothing() {
        assert_eq!(BestTwo::default().accept(256, None), None);
    }
}
