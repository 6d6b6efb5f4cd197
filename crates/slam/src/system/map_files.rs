//! Map files: the whole atlas saved and loaded (sessions), and saved maps merged offline.
//!
//! A file holds one map record per map, back to back (`ferroslam_map::Map::save_all_to_path`):
//! the atlas's maps oldest first, the current map last. Loading makes the last one current
//! and puts the others in the atlas; a one-map file is an atlas of one.

use std::path::Path;

use ferroslam_map::Map;

use super::SlamSystem;
use crate::atlas::StoredMap;
use crate::error::SlamError;
use crate::loop_closing::{LoopDetector, MapMerge};
use crate::tracking::TrackingState;

impl SlamSystem {
    /// Writes every map of [`Self::maps`], in its order, to `path` (see the module doc); an
    /// empty map when there is none.
    ///
    /// # Errors
    /// `InvalidInput` for an empty path or a folder; [`SlamError::MapFile`] when the file
    /// cannot be written.
    pub fn save_map(&self, path: &Path) -> Result<(), SlamError> {
        if path.as_os_str().is_empty() || path.is_dir() {
            return Err(SlamError::InvalidInput(format!(
                "save_map: {:?} is {}: give a file path",
                path.display().to_string(),
                if path.as_os_str().is_empty() {
                    "empty"
                } else {
                    "a folder"
                }
            )));
        }
        let maps: Vec<&Map> = self
            .atlas
            .iter()
            .map(|s| &s.map)
            .chain(std::iter::once(&self.map))
            .filter(|m| m.num_keyframes() > 0)
            .collect();
        let maps = if maps.is_empty() {
            vec![&self.map]
        } else {
            maps
        };
        Map::save_all_to_path(&maps, path).map_err(|e| map_file_error(path, e))
    }

    /// Makes the last map in `path` the current one (the others go to the atlas); tracking
    /// then relocalises in it with the next frame (state `Lost` until it does), and maps
    /// onward from it (unless localisation-only). Lost for
    /// `tracking.relocalisation_window_s`, the run starts a map of its own, merged into a
    /// loaded one once it recognises it. The map tracked until now goes to the atlas.
    ///
    /// # Errors
    /// [`SlamError::MapFile`] for a missing, truncated or corrupt file, another format version,
    /// or a map built with another sensor, camera or ORB pyramid than this system's; the
    /// system is unchanged.
    pub fn load_map(&mut self, path: &Path) -> Result<(), SlamError> {
        let mut maps = self.checked_maps(path)?;
        let current = maps.pop().expect("a map file holds a map");
        if self.map.num_keyframes() > 0 {
            self.store_current_map();
        }
        self.clear_map();
        self.store_loaded(maps);
        // The current map's id is still unused (a fresh one if the map went to the atlas).
        self.map = current;
        self.index_keyframes();
        self.tracker.state = if self.map.num_keyframes() > 0 {
            TrackingState::Lost
        } else {
            TrackingState::NotInitialized
        };
        Ok(())
    }

    /// Adds every map in `path` to the atlas (the current map stays), for
    /// [`Self::merge_maps`]; returns their new ids.
    ///
    /// # Errors
    /// As [`Self::load_map`]; the system is unchanged.
    pub fn add_maps(&mut self, path: &Path) -> Result<Vec<usize>, SlamError> {
        let maps = self.checked_maps(path)?;
        let first = self.next_map_id;
        self.store_loaded(maps);
        Ok((first..self.next_map_id).collect())
    }

    /// Merges the maps of the atlas (and the current one) where they overlap, offline: the
    /// keyframes of each map, in id order, look for a place of every older map as a new
    /// keyframe would (bag-of-words candidates consistent over consecutive keyframes, then
    /// the loop verification); a verified place merges the newer map into the older one.
    /// Returns the merges made (also in [`Self::merges`]); maps that match nothing stay as
    /// they are. Needs a vocabulary.
    ///
    /// # Errors
    /// `InvalidInput` without a vocabulary; what a merge met.
    pub fn merge_maps(&mut self) -> Result<Vec<MapMerge>, SlamError> {
        if self.place.is_none() {
            return Err(SlamError::InvalidInput(
                "merge_maps needs a vocabulary to recognise places: set_vocabulary first".into(),
            ));
        }
        let before = self.merges.len();
        // Oldest first: each map in turn is the current one and looks into the older ones.
        let mut ids: Vec<usize> = self.maps().iter().map(|m| m.id).collect();
        ids.sort_unstable();
        for id in ids.into_iter().skip(1) {
            if id != self.map_id {
                let Some(i) = self.atlas.iter().position(|s| s.id == id) else {
                    continue;
                };
                let stored = self.atlas.remove(i);
                self.make_current(stored);
            }
            for kf in self.map.keyframe_ids() {
                let merges = self.merges.len();
                self.check_merges_at(&[kf])?;
                if self.merges.len() > merges {
                    break;
                }
            }
        }
        // Each merge's global BA, if the mapping thread runs it.
        self.finish_mapping()?;
        self.tracker.state = TrackingState::Lost;
        Ok(self.merges[before..].to_vec())
    }

    /// The maps in `path`, checked against this system's rig and pyramid, with ids after
    /// every id this run has used.
    fn checked_maps(&self, path: &Path) -> Result<Vec<Map>, SlamError> {
        let mut maps = Map::load_all_from_path(path).map_err(|e| map_file_error(path, e))?;
        let invalid = |reason: String| SlamError::MapFile {
            path: path.display().to_string(),
            reason,
            not_found: false,
        };
        let ours = self.ctx.rig();
        let (mut kf, mut mp) = self.used_ids();
        for map in &mut maps {
            if let Some(reason) = map.rig().and_then(|theirs| theirs.mismatch(&ours)) {
                return Err(invalid(reason));
            }
            map.set_rig(ours.clone());
            let (theirs, ours) = (map.pyramid(), self.map.pyramid());
            if theirs.n_levels != ours.n_levels
                || (theirs.scale_factor - ours.scale_factor).abs() > 1e-9
            {
                return Err(invalid(format!(
                    "built with {} pyramid levels of scale {}, this system uses {} of {}",
                    theirs.n_levels, theirs.scale_factor, ours.n_levels, ours.scale_factor
                )));
            }
            // Ids after every id used so far, so the maps can merge with the run's.
            map.shift_ids(kf.0, mp.0)
                .map_err(|e| map_file_error(path, e))?;
            (kf, mp) = map.next_ids();
        }
        Ok(maps)
    }

    /// Puts loaded `maps` in the atlas, each with a keyframe index of its own.
    fn store_loaded(&mut self, maps: Vec<Map>) {
        for map in maps {
            let mut place = self.fresh_place();
            if let Some(p) = place.as_mut() {
                p.sync(&map);
            }
            let stored = StoredMap {
                id: self.new_map_id(),
                map,
                trajectory: Default::default(),
                place,
                detector: LoopDetector::default(),
                inertial: None,
            };
            self.atlas.push(stored);
        }
    }
}

/// The current (last) map saved at `path`, as it is: for reading it without a system
/// (exports).
///
/// # Errors
/// [`SlamError::MapFile`] for a missing, truncated or corrupt file or another format version.
pub fn load_map_file(path: &Path) -> Result<Map, SlamError> {
    let mut maps = Map::load_all_from_path(path).map_err(|e| map_file_error(path, e))?;
    Ok(maps.pop().expect("a map file holds a map"))
}

pub(super) fn map_file_error(path: &Path, e: ferroslam_map::MapError) -> SlamError {
    let not_found = matches!(
        &e,
        ferroslam_map::MapError::MapFileIo { kind, .. } if *kind == std::io::ErrorKind::NotFound
    );
    SlamError::MapFile {
        path: path.display().to_string(),
        reason: e.to_string(),
        not_found,
    }
}
