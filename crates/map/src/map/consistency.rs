//! The map's invariants, checked exhaustively (for tests and debug assertions).

use super::Map;

impl Map {
    /// Checks every invariant of the map, returning a description of the first violation:
    /// - observations: each `kf -> index` of a point has a live `kf` whose slot `index` holds
    ///   the point, each slot's point lists the keyframe with that index, `nObs` matches, and
    ///   a point with observations has one of them as reference;
    /// - covisibility: symmetric, no self edge, each weight equals the number of shared good
    ///   points and is positive, and each edge is selected by one of its endpoints;
    /// - spanning tree: parents and children are live and agree, the origin has no parent,
    ///   and parent chains end (no cycle);
    /// - tombstones never shadow live entities.
    ///
    /// Cost: O(observations + edges + keyframes * tree depth).
    pub fn check_consistency(&self) -> Result<(), String> {
        self.check_observations()?;
        self.check_covisibility()?;
        self.check_spanning_tree()?;
        if let Some(id) = self
            .replaced_points
            .keys()
            .find(|id| self.map_points.contains_key(id))
        {
            return Err(format!("{id} is live but recorded as replaced"));
        }
        if let Some(id) = self
            .culled_keyframes
            .keys()
            .find(|id| self.keyframes.contains_key(id))
        {
            return Err(format!("{id} is live but recorded as culled"));
        }
        Ok(())
    }

    fn check_observations(&self) -> Result<(), String> {
        for (&mp, point) in self.map_points.iter() {
            let mut n_obs = 0;
            for (&kf, &index) in &point.observations {
                let frame = self
                    .keyframes
                    .get(&kf)
                    .ok_or(format!("{mp} observed by culled {kf}"))?;
                if frame.map_point(index) != Some(mp) {
                    return Err(format!(
                        "{mp} observed by {kf}:{index}, slot holds {:?}",
                        frame.map_point(index)
                    ));
                }
                n_obs += if frame.features.is_stereo(index) {
                    2
                } else {
                    1
                };
            }
            if n_obs != point.n_obs {
                return Err(format!(
                    "{mp} has nObs {} but its observations count {n_obs}",
                    point.n_obs
                ));
            }
            if !point.observations.is_empty() && !point.observations.contains_key(&point.reference)
            {
                return Err(format!(
                    "{mp}'s reference {} does not observe it",
                    point.reference
                ));
            }
        }
        for (&kf, frame) in self.keyframes.iter() {
            for (index, mp) in frame.map_points.iter().enumerate() {
                let Some(mp) = mp else { continue };
                let point = self
                    .map_points
                    .get(mp)
                    .ok_or(format!("{kf}:{index} holds removed {mp}"))?;
                if point.observation(kf) != Some(index) {
                    return Err(format!(
                        "{kf}:{index} holds {mp}, which records {:?}",
                        point.observation(kf)
                    ));
                }
            }
        }
        Ok(())
    }

    fn check_covisibility(&self) -> Result<(), String> {
        for (&kf, frame) in self.keyframes.iter() {
            let counts = self.shared_point_counts(frame);
            for (&other, &weight) in &frame.covisibility {
                let neighbour = self
                    .keyframes
                    .get(&other)
                    .ok_or(format!("{kf} connected to culled {other}"))?;
                if other == kf {
                    return Err(format!("{kf} connected to itself"));
                }
                if neighbour.covisibility.get(&kf) != Some(&weight) {
                    return Err(format!(
                        "edge {kf}-{other} weight {weight} is not symmetric"
                    ));
                }
                let shared = counts.get(&other).copied().unwrap_or(0);
                if weight != shared || weight == 0 {
                    return Err(format!(
                        "edge {kf}-{other} has weight {weight}, shared points {shared}"
                    ));
                }
                if !frame.chosen.contains(&other) && !neighbour.chosen.contains(&kf) {
                    return Err(format!("edge {kf}-{other} is selected by neither endpoint"));
                }
            }
            if let Some(other) = frame
                .chosen
                .iter()
                .find(|k| !frame.covisibility.contains_key(k))
            {
                return Err(format!("{kf} selects {other} without an edge"));
            }
        }
        Ok(())
    }

    fn check_spanning_tree(&self) -> Result<(), String> {
        if let Some(parent) = self
            .origin
            .and_then(|o| self.keyframes.get(&o))
            .and_then(|f| f.parent)
        {
            return Err(format!("the origin has parent {parent}"));
        }
        for (&kf, frame) in self.keyframes.iter() {
            if let Some(parent) = frame.parent {
                let p = self
                    .keyframes
                    .get(&parent)
                    .ok_or(format!("{kf} has culled parent {parent}"))?;
                if !p.children.contains(&kf) {
                    return Err(format!(
                        "{kf}'s parent {parent} does not list it as a child"
                    ));
                }
                if self.is_descendant(parent, kf) {
                    return Err(format!("the parent chain of {kf} is a cycle"));
                }
            }
            for &child in &frame.children {
                let c = self
                    .keyframes
                    .get(&child)
                    .ok_or(format!("{kf} has culled child {child}"))?;
                if c.parent != Some(kf) {
                    return Err(format!(
                        "{kf} lists {child} as child, whose parent is {:?}",
                        c.parent
                    ));
                }
            }
        }
        Ok(())
    }
}
