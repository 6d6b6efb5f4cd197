//! Tracking's copy of the local map, taken once per frame: what projecting and searching a
//! local point needs, read out of the map when the local points are gathered rather than
//! looked up again for every camera and test.

use ferroslam_features::matcher::TH_HIGH;
use ferroslam_features::{Descriptor, MatchOptions, ProjectionQuery};
use ferroslam_map::{KeyFrameId, Map, MapPointId};
use nalgebra::{Isometry3, Vector3};

use super::projection_search::ProjectionSearch;
use crate::context::Context;
use crate::error::SlamError;
use crate::frame::Frame;
use crate::frustum::PointShape;

/// One local point as the map held it when the local map was gathered.
#[derive(Clone, Copy, Debug)]
struct LocalPoint {
    id: MapPointId,
    shape: PointShape,
    descriptor: Descriptor,
}

/// The local points of the current local keyframes, with the buffers of their search, kept
/// from frame to frame so that none is allocated once they have grown.
#[derive(Debug, Default)]
pub(super) struct LocalMap {
    ids: Vec<MapPointId>,
    points: Vec<LocalPoint>,
    /// All zeros between calls: the bitset of `Map::points_seen_by_into`, then of the points
    /// already matched in the frame.
    seen: Vec<u64>,
    /// The points predicted visible in the frame, counted in one call.
    visible: Vec<MapPointId>,
    searches: Vec<ProjectionSearch<MapPointId>>,
    poses: Vec<(Isometry3<f64>, Vector3<f64>)>,
    taken: Vec<bool>,
}

impl LocalMap {
    /// Gathers the points seen by `keyframes` (in [`Map::points_seen_by`] order) and copies
    /// what the search reads of each. Valid until the map's points change: tracking gathers
    /// right before searching.
    pub(super) fn gather(&mut self, map: &Map, keyframes: &[KeyFrameId]) {
        map.points_seen_by_into(keyframes.iter().copied(), &mut self.seen, &mut self.ids);
        self.points.clear();
        // A point missing from the map is one `visible_point` would not see either.
        self.points.extend(self.ids.iter().filter_map(|&id| {
            let point = map.map_point(id)?;
            Some(LocalPoint {
                id,
                shape: PointShape::from(point),
                descriptor: *point.descriptor(),
            })
        }));
    }

    /// Projects the local points not yet matched into the frame and searches for their
    /// keypoints (ORB-SLAM `SearchLocalPoints`; ratio and radius by viewing angle from
    /// `tracking`). The points already matched and those predicted visible get their visible
    /// counter raised, in one map call.
    pub(super) fn search(
        &mut self,
        frame: &mut Frame,
        map: &mut Map,
        ctx: &Context,
        th: f64,
    ) -> Result<(), SlamError> {
        self.visible.clear();
        for &m in frame.map_points.iter().flatten() {
            let (word, bit) = (m.0 as usize / 64, m.0 % 64);
            if self.seen.len() <= word {
                self.seen.resize(word + 1, 0);
            }
            if self.seen[word] & (1 << bit) == 0 {
                self.seen[word] |= 1 << bit;
                self.visible.push(m);
            }
        }
        let in_frame = self.visible.len();
        let pyramid = map.pyramid();
        let tracking = &ctx.config.tracking;
        let cameras = ctx.num_cameras();
        self.searches
            .resize_with(cameras, ProjectionSearch::default);
        self.searches.iter_mut().for_each(ProjectionSearch::clear);
        let center = frame.camera_center();
        self.poses.clear();
        self.poses.extend((0..cameras).map(|k| {
            let view = ctx.view(k);
            let T_c_w = view.pose(&frame.T_c_w);
            let center = if k == 0 {
                center
            } else {
                view.center(&frame.T_c_w)
            };
            (T_c_w, center)
        }));
        for point in &self.points {
            let m = point.id;
            let (word, bit) = (m.0 as usize / 64, m.0 % 64);
            if self.seen.get(word).is_some_and(|w| w & (1 << bit) != 0) {
                continue;
            }
            let mut seen = false;
            for (k, search) in self.searches.iter_mut().enumerate() {
                let view = ctx.view(k);
                let (T_c_w, center) = &self.poses[k];
                let Some(vis) = point.shape.visible_from(
                    T_c_w,
                    center,
                    view.camera,
                    view.bounds,
                    &ctx.config.visibility,
                    pyramid,
                ) else {
                    continue;
                };
                seen = true;
                let r = if vis.view_cos > tracking.frontal_view_cos {
                    tracking.frontal_radius
                } else {
                    tracking.oblique_radius
                } * th;
                let query = ProjectionQuery {
                    u: vis.u,
                    v: vis.v,
                    radius: r * pyramid.scale[vis.level as usize],
                    min_level: vis.level.saturating_sub(1),
                    max_level: vis.level,
                    descriptor: point.descriptor,
                    angle_deg: None,
                };
                search.push(query, view.u_right(&vis.p_c, vis.u), m);
            }
            if seen {
                self.visible.push(m);
            }
        }
        for m in &self.visible[..in_frame] {
            self.seen[m.0 as usize / 64] = 0;
        }
        map.increase_visible_many(&self.visible)?;
        self.taken.clear();
        self.taken
            .extend(frame.map_points.iter().map(Option::is_some));
        let opts = MatchOptions {
            max_distance: TH_HIGH,
            nn_ratio: Some(tracking.local_search_nn_ratio),
            check_orientation: false,
        };
        for (k, search) in self.searches.iter().enumerate() {
            for (i, m) in search.run(frame, k, &self.taken, &opts) {
                frame.map_points[i] = Some(m);
            }
        }
        Ok(())
    }
}
