//! `merge_map_files`: saved maps merged offline, in one call without the GIL.

use std::path::PathBuf;

use ferroslam_slam::{MapMerge, MapSummary, SlamConfig, SlamSystem};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::camera::camera_model_of;
use crate::config;
use crate::errors::to_py;
use crate::pool;
use crate::vocabulary::PyVocabulary;

/// What the merge did: the map ids each input file's maps got, the merges, the maps left.
struct MergeOutcome {
    inputs: Vec<Vec<usize>>,
    merges: Vec<MapMerge>,
    maps: Vec<MapSummary>,
}

/// Merges the maps saved in `inputs` where they overlap (`SlamSystem.merge_maps`) and
/// writes every map left, merged or not, to `output` (an atlas file). The maps must come
/// from one camera (the first file's sensor and camera build the system that merges).
/// Returns a dict: `inputs` (per input file, the map ids its maps got), `merges` (as
/// `SlamSystem.merges`, each with its `similarity`) and `maps` (as `SlamSystem.maps`).
///
/// Raises `FileNotFoundError` / `ValueError` for a missing, corrupt or incompatible file
/// (nothing is written then), `ValueError` for a multi-camera rig's maps.
#[pyfunction]
pub fn merge_map_files<'py>(
    py: Python<'py>,
    inputs: Vec<PathBuf>,
    output: PathBuf,
    vocabulary: PyRef<'_, PyVocabulary>,
) -> PyResult<Bound<'py, PyDict>> {
    let Some(first) = inputs.first().cloned() else {
        return Err(PyValueError::new_err(
            "merge_map_files: give at least one map file",
        ));
    };
    let vocabulary = vocabulary.shared();
    let outcome = pool::detach(py, move || -> PyResult<MergeOutcome> {
        let map = ferroslam_slam::load_map_file(&first).map_err(to_py)?;
        let Some(rig) = map.rig().cloned() else {
            return Err(PyValueError::new_err(format!(
                "{}: the map has no camera record (a map file older than version 3)",
                first.display()
            )));
        };
        if !rig.cameras.is_empty() || rig.pair.is_some() {
            return Err(PyValueError::new_err(format!(
                "{}: merging maps of a multi-camera rig or an unrectified pair is not \
                 supported yet",
                first.display()
            )));
        }
        let dist = if rig.model == "kannala_brandt" {
            &rig.distortion[..4]
        } else {
            &rig.distortion[..]
        };
        let camera = camera_model_of(&rig.model, rig.intrinsics, dist, rig.width, rig.height, 0.0)?;
        let mut config = SlamConfig::for_sensor(config::sensor(&rig.sensor)?);
        config.extractor.scale_factor = map.pyramid().scale_factor;
        config.extractor.n_levels = map.pyramid().n_levels;
        // No frame is tracked: the virtual baseline only has to pass validation.
        config.depth.bf = config.depth.bf.max(1.0);
        let mut system = SlamSystem::new(camera, config).map_err(to_py)?;
        system.set_vocabulary(vocabulary);
        let inputs = inputs
            .iter()
            .map(|path| system.add_maps(path))
            .collect::<Result<Vec<_>, _>>()
            .map_err(to_py)?;
        let merges = system.merge_maps().map_err(to_py)?;
        system.save_map(&output).map_err(to_py)?;
        Ok(MergeOutcome {
            inputs,
            merges,
            maps: system.maps(),
        })
    })??;
    let d = PyDict::new(py);
    d.set_item("inputs", outcome.inputs)?;
    let merges = outcome
        .merges
        .iter()
        .map(|m| crate::atlas::merge_dict(py, m))
        .collect::<PyResult<Vec<_>>>()?;
    d.set_item("merges", merges)?;
    d.set_item("maps", crate::atlas::map_dicts(py, &outcome.maps)?)?;
    Ok(d)
}
