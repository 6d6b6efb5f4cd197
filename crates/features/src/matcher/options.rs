//! Matching thresholds and their ORB-SLAM presets.

/// Loose Hamming threshold, ORB-SLAM `ORBmatcher::TH_HIGH` (projection searches).
pub const TH_HIGH: u32 = 100;
/// Strict Hamming threshold, ORB-SLAM `ORBmatcher::TH_LOW` (BoW, initialisation, triangulation).
pub const TH_LOW: u32 = 50;

/// Options shared by all matchers.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MatchOptions {
    /// Largest accepted Hamming distance (inclusive), e.g. [`TH_LOW`] or [`TH_HIGH`].
    pub max_distance: u32,
    /// Nearest-neighbour ratio (ORB-SLAM `mfNNratio`); `None` disables the ratio test.
    /// Each matcher documents how it applies it.
    pub nn_ratio: Option<f32>,
    /// Reject matches outside the 3 dominant bins of the rotation histogram.
    pub check_orientation: bool,
}

impl MatchOptions {
    /// `TH_LOW`, ratio 0.7, orientation check: ORB-SLAM `TrackReferenceKeyFrame`
    /// (`ORBmatcher(0.7, true)` + `SearchByBoW`).
    pub const fn strict() -> Self {
        Self {
            max_distance: TH_LOW,
            nn_ratio: Some(0.7),
            check_orientation: true,
        }
    }

    /// `TH_LOW`, ratio 0.9, orientation check: ORB-SLAM monocular initialisation
    /// (`ORBmatcher(0.9, true)` + `SearchForInitialization`).
    pub const fn initialization() -> Self {
        Self {
            max_distance: TH_LOW,
            nn_ratio: Some(0.9),
            check_orientation: true,
        }
    }

    /// `TH_HIGH`, ratio 0.9, orientation check: ORB-SLAM `TrackWithMotionModel`
    /// (`ORBmatcher(0.9, true)` + `SearchByProjection(Frame, Frame)`).
    pub const fn motion_model() -> Self {
        Self {
            max_distance: TH_HIGH,
            nn_ratio: Some(0.9),
            check_orientation: true,
        }
    }

    /// `TH_HIGH`, ratio 0.8, no orientation check: ORB-SLAM `SearchLocalPoints`
    /// (`ORBmatcher(0.8)` + `SearchByProjection(Frame, vector<MapPoint*>)`).
    pub const fn local_map() -> Self {
        Self {
            max_distance: TH_HIGH,
            nn_ratio: Some(0.8),
            check_orientation: false,
        }
    }

    /// `TH_LOW`, no ratio, no orientation check: ORB-SLAM `LocalMapping::CreateNewMapPoints`
    /// (`ORBmatcher(0.6, false)` + `SearchForTriangulation`, which ignores the ratio).
    pub const fn triangulation() -> Self {
        Self {
            max_distance: TH_LOW,
            nn_ratio: None,
            check_orientation: false,
        }
    }
}

impl Default for MatchOptions {
    /// [`MatchOptions::strict`].
    fn default() -> Self {
        Self::strict()
    }
}
