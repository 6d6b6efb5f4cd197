//! Map points: a 3-D landmark, its observations and its appearance summary.

use std::collections::BTreeMap;

use ferroslam_features::{Descriptor, ScalePyramid};
use nalgebra::Vector3;

use crate::{KeyFrameId, MapPointId, Rgb};

/// A 3-D map point (ORB-SLAM `MapPoint`).
///
/// Read-only outside the crate; mutate it through [`crate::Map`]. A `&MapPoint` obtained
/// from the map is always good (bad points are removed from the arena).
#[derive(Clone, Debug)]
pub struct MapPoint {
    pub(crate) id: MapPointId,
    pub(crate) position: Vector3<f64>,
    pub(crate) normal: Vector3<f64>,
    pub(crate) min_distance: f64,
    pub(crate) max_distance: f64,
    pub(crate) descriptor: Descriptor,
    pub(crate) observations: BTreeMap<KeyFrameId, usize>,
    /// ORB-SLAM `nObs`: stereo/RGB-D observations count 2.
    pub(crate) n_obs: usize,
    pub(crate) reference: KeyFrameId,
    pub(crate) first_keyframe: KeyFrameId,
    pub(crate) visible: u32,
    pub(crate) found: u32,
    pub(crate) color: Option<Rgb>,
}

impl MapPoint {
    pub(crate) fn new(id: MapPointId, position: Vector3<f64>, reference: KeyFrameId) -> Self {
        Self {
            id,
            position,
            normal: Vector3::zeros(),
            min_distance: 0.0,
            max_distance: 0.0,
            descriptor: [0; 32],
            observations: BTreeMap::new(),
            n_obs: 0,
            reference,
            first_keyframe: reference,
            // ORB-SLAM starts both counters at 1.
            visible: 1,
            found: 1,
            color: None,
        }
    }

    /// The point's id.
    pub fn id(&self) -> MapPointId {
        self.id
    }

    /// Position in the world, `p_w` (m).
    pub fn position(&self) -> Vector3<f64> {
        self.position
    }

    /// Mean viewing direction, unit length, pointing from the observing cameras to the point
    /// (zero before [`crate::Map::update_normal_and_depth`] ran with an observation). Unlike
    /// ORB-SLAM2, the mean is renormalised, so `cos = normal.dot(ray) / |ray|`.
    pub fn normal(&self) -> Vector3<f64> {
        self.normal
    }

    /// Smallest distance (m) at which the point stays detectable (ORB-SLAM `mfMinDistance`,
    /// before the 0.8 tolerance of `GetMinDistanceInvariance`).
    pub fn min_distance(&self) -> f64 {
        self.min_distance
    }

    /// Largest distance (m) at which the point stays detectable (ORB-SLAM `mfMaxDistance`,
    /// before the 1.2 tolerance of `GetMaxDistanceInvariance`).
    pub fn max_distance(&self) -> f64 {
        self.max_distance
    }

    /// Distinctive descriptor: the observation descriptor with the least median Hamming
    /// distance to the others (all zeros before the first
    /// [`crate::Map::compute_distinctive_descriptor`]).
    pub fn descriptor(&self) -> &Descriptor {
        &self.descriptor
    }

    /// Observations: keyframe -> keypoint index.
    pub fn observations(&self) -> &BTreeMap<KeyFrameId, usize> {
        &self.observations
    }

    /// Keypoint index through which `kf` observes the point.
    pub fn observation(&self, kf: KeyFrameId) -> Option<usize> {
        self.observations.get(&kf).copied()
    }

    /// ORB-SLAM `nObs`: number of observations, stereo/RGB-D ones (keypoint with
    /// `u_right >= 0`) counting 2.
    pub fn num_observations(&self) -> usize {
        self.n_obs
    }

    /// Reference keyframe: the creating keyframe while it observes the point, otherwise one
    /// of the observing keyframes (the lowest id after an erase, as ORB-SLAM's
    /// `mObservations.begin()`).
    pub fn reference_keyframe(&self) -> KeyFrameId {
        self.reference
    }

    /// The keyframe the point was created with (ORB-SLAM `mnFirstKFid`); it may have been
    /// culled since.
    pub fn first_keyframe(&self) -> KeyFrameId {
        self.first_keyframe
    }

    /// Always `false`: bad points are removed from the map, so a reference obtained from it
    /// is good. For an id, use [`crate::Map::is_map_point_bad`].
    pub fn is_bad(&self) -> bool {
        false
    }

    /// Times the point was predicted visible in a tracked frame (starts at 1).
    pub fn visible(&self) -> u32 {
        self.visible
    }

    /// Times the point was matched in a tracked frame (starts at 1).
    pub fn found(&self) -> u32 {
        self.found
    }

    /// Colour of the image where the point was first observed: the colour of the first
    /// keypoint linked to it ([`crate::Map::add_observation`]) that has one, which is the
    /// creating keyframe's keypoint wherever points are made (created, then observed from
    /// their reference keyframe first). `None` if that frame came without colours.
    pub fn color(&self) -> Option<Rgb> {
        self.color
    }

    /// `found / visible` (ORB-SLAM `GetFoundRatio`).
    pub fn found_ratio(&self) -> f64 {
        f64::from(self.found) / f64::from(self.visible.max(1))
    }

    /// Pyramid level at which the point should appear when seen from `distance` (m)
    /// (ORB-SLAM `PredictScale`).
    pub fn predict_level(&self, distance: f64, pyramid: &ScalePyramid) -> usize {
        pyramid.predict_level(distance, self.max_distance)
    }
}
