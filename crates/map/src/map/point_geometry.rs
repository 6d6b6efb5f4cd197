//! A point's appearance and viewing geometry summaries: distinctive descriptor, mean viewing
//! direction and scale-invariance distances (ORB-SLAM `ComputeDistinctiveDescriptors`,
//! `UpdateNormalAndDepth`).

use super::journal::MapEdit;
use ferroslam_features::{hamming, Descriptor};
use nalgebra::Vector3;

use super::Map;
use crate::{KeyFrameId, MapError, MapPointId};

impl Map {
    /// Median depth of `kf`'s map points in its camera, metres (ORB-SLAM
    /// `ComputeSceneMedianDepth`); `None` for an unknown keyframe or without points in front
    /// of it.
    pub fn scene_median_depth(&self, kf: KeyFrameId) -> Option<f64> {
        let k = self.keyframe(kf)?;
        let mut z: Vec<f64> = k
            .map_points()
            .iter()
            .flatten()
            .filter_map(|m| self.map_point(*m))
            .map(|p| (k.T_c_w() * nalgebra::Point3::from(p.position())).z)
            .filter(|z| *z > 0.0)
            .collect();
        if z.is_empty() {
            return None;
        }
        let mid = z.len() / 2;
        Some(*z.select_nth_unstable_by(mid, f64::total_cmp).1)
    }

    /// Recomputes the point's mean viewing direction (unit mean of the unit rays from every
    /// observing camera centre to the point) and its distance range: with `d` the distance
    /// from the reference keyframe's centre and `o` the octave of its keypoint,
    /// `max = d * scale[o]`, `min = max / scale[n_levels - 1]`. Does nothing for a point
    /// without observations.
    ///
    /// # Errors
    /// [`MapError::UnknownMapPoint`].
    pub fn update_normal_and_depth(&mut self, mp: MapPointId) -> Result<(), MapError> {
        self.journaled(
            || MapEdit::UpdateNormalAndDepth { mp },
            |map| map.update_normal_and_depth_now(mp),
        )
    }

    /// The body of [`Map::update_normal_and_depth`], run inside its journal entry.
    fn update_normal_and_depth_now(&mut self, mp: MapPointId) -> Result<(), MapError> {
        let point = self
            .map_points
            .get(&mp)
            .ok_or(MapError::UnknownMapPoint(mp))?;
        let reference = point.observation(point.reference).and_then(|index| {
            let frame = self.keyframes.get(&point.reference)?;
            Some((
                frame.camera_center(),
                frame.features.keypoints.get(index)?.octave,
            ))
        });
        let Some((reference_center, octave)) = reference else {
            return Ok(());
        };
        let ray_sum: Vector3<f64> = point
            .observations
            .keys()
            .filter_map(|kf| self.keyframes.get(kf))
            .filter_map(|frame| (point.position - frame.camera_center()).try_normalize(0.0))
            .sum();
        let distance = (point.position - reference_center).norm();
        let (min, max) = self.pyramid.distance_bounds(distance, octave);

        let point = self.map_point_mut(mp)?;
        point.normal = ray_sum.try_normalize(0.0).unwrap_or_else(Vector3::zeros);
        point.min_distance = min;
        point.max_distance = max;
        Ok(())
    }

    /// Sets the point's descriptor to the medoid of its observations' descriptors: the one
    /// whose median Hamming distance to all of them (itself included, median index
    /// `(n - 1) / 2`) is least, the first in keyframe-id order on ties. Does nothing for a
    /// point without observations.
    ///
    /// # Errors
    /// [`MapError::UnknownMapPoint`].
    pub fn compute_distinctive_descriptor(&mut self, mp: MapPointId) -> Result<(), MapError> {
        self.journaled(
            || MapEdit::ComputeDistinctiveDescriptor { mp },
            |map| map.compute_distinctive_descriptor_now(mp),
        )
    }

    /// The body of [`Map::compute_distinctive_descriptor`], run inside its journal entry.
    fn compute_distinctive_descriptor_now(&mut self, mp: MapPointId) -> Result<(), MapError> {
        let point = self
            .map_points
            .get(&mp)
            .ok_or(MapError::UnknownMapPoint(mp))?;
        let descriptors: Vec<Descriptor> = point
            .observations
            .iter()
            .filter_map(|(kf, &i)| self.keyframes.get(kf)?.features.descriptors.get(i).copied())
            .collect();
        let Some(best) = medoid(&descriptors) else {
            return Ok(());
        };
        self.map_point_mut(mp)?.descriptor = best;
        Ok(())
    }
}

/// The descriptor with the least median distance to the set; `None` for an empty set.
fn medoid(descriptors: &[Descriptor]) -> Option<Descriptor> {
    let median_distance = |d: &Descriptor| {
        let mut distances: Vec<u32> = descriptors.iter().map(|o| hamming(d, o)).collect();
        distances.sort_unstable();
        distances[(distances.len() - 1) / 2]
    };
    // min_by_key keeps the first minimum.
    descriptors
        .iter()
        .min_by_key(|d| median_distance(d))
        .copied()
}

#[cfg(test)]
mod tests {
    use approx::assert_relative_eq;
    use nalgebra::Vector3;

    use super::medoid;
    use crate::test_support::map_with_keyframes;

    fn with_bits(n: usize) -> [u8; 32] {
        let mut d = [0u8; 32];
        for bit in 0..n {
            d[bit / 8] |= 1 << (bit % 8);
        }
        d
    }

    #[test]
    fn medoid_minimises_the_median_distance() {
        // Sorted distances (median at index 2): from 0 [0, 10, 12, 14, 40], from 10
        // [0, 2, 4, 10, 30], from 12 [0, 2, 2, 12, 28], from 14 [0, 2, 4, 14, 26].
        let set = [
            with_bits(0),
            with_bits(10),
            with_bits(12),
            with_bits(14),
            with_bits(40),
        ];
        assert_eq!(medoid(&set), Some(with_bits(12)));
        // Ties keep the first.
        assert_eq!(medoid(&[with_bits(3), with_bits(0)]), Some(with_bits(3)));
        assert_eq!(medoid(&[]), None);
    }

    #[test]
    fn distinctive_descriptor_comes_from_the_observations() {
        let (mut map, kfs) = map_with_keyframes(5, 8);
        let mp = map
            .create_map_point(Vector3::new(0.0, 0.0, 5.0), kfs[0])
            .unwrap();
        // test_support gives keypoint i of keyframe k the descriptor with_bits(8 * k + i):
        // bits {0, 10, 17, 24, 39}, median distances 17, 10, 7, 14, 22.
        for (k, i) in [(0, 0), (1, 2), (2, 1), (3, 0), (4, 7)] {
            map.add_observation(mp, kfs[k], i).unwrap();
        }
        map.compute_distinctive_descriptor(mp).unwrap();
        assert_eq!(*map.map_point(mp).unwrap().descriptor(), with_bits(17));
    }

    #[test]
    fn normal_and_distances() {
        // Camera centres at (k, 0, 0); the point at (0.5, 0, 2) seen by keyframes 0 and 1.
        let (mut map, kfs) = map_with_keyframes(2, 4);
        let p_w = Vector3::new(0.5, 0.0, 2.0);
        let mp = map.create_map_point(p_w, kfs[1]).unwrap();
        map.add_observation(mp, kfs[0], 0).unwrap();
        map.add_observation(mp, kfs[1], 2).unwrap(); // octave 2 (test_support: octave = i)
        map.update_normal_and_depth(mp).unwrap();
        let point = map.map_point(mp).unwrap();
        assert_relative_eq!(point.normal(), Vector3::z(), epsilon = 1e-12);
        let d = (p_w - Vector3::x()).norm();
        let pyramid = map.pyramid();
        assert_relative_eq!(point.max_distance(), d * 1.2f64.powi(2), epsilon = 1e-12);
        assert_relative_eq!(
            point.min_distance(),
            d * 1.2f64.powi(2) / 1.2f64.powi(7),
            epsilon = 1e-12
        );
        assert_eq!(point.predict_level(d * 1.000_001, pyramid), 2);
        assert_eq!(point.predict_level(point.max_distance(), pyramid), 0);
    }
}
