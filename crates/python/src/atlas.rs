//! The atlas's records as Python dicts: maps, merges and loops (`SlamSystem.maps`,
//! `merges`, `loops`, `TrackResult.merge`).

use ferroslam_slam::{LoopClosure, MapMerge, MapSummary};
use numpy::ndarray::Array2;
use numpy::PyArray2;
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// `{"id", "frames", "keyframes", "points", "current"}` per map.
pub(crate) fn map_dicts<'py>(
    py: Python<'py>,
    maps: &[MapSummary],
) -> PyResult<Vec<Bound<'py, PyDict>>> {
    maps.iter()
        .map(|m| {
            let d = PyDict::new(py);
            d.set_item("id", m.id)?;
            d.set_item("frames", m.frames)?;
            d.set_item("keyframes", m.keyframes)?;
            d.set_item("points", m.points)?;
            d.set_item("current", m.current)?;
            Ok(d)
        })
        .collect()
}

/// One merge: the two map ids ("merged_map" into "into_map"), the keyframes ("current",
/// "matched"), their "timestamps", "num_matches", the similarity's "scale", "graph_cost",
/// "welded_keyframes" (the seam's local BA) and the "similarity" itself, (4, 4) float64 `[s R | t]` (`p_into = s R p_merged + t`).
pub(crate) fn merge_dict<'py>(py: Python<'py>, m: &MapMerge) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("merged_map", m.merged_map)?;
    d.set_item("into_map", m.into_map)?;
    d.set_item("current", m.current.0)?;
    d.set_item("matched", m.matched.0)?;
    d.set_item("timestamps", m.timestamps)?;
    d.set_item("num_matches", m.num_matches)?;
    d.set_item("scale", m.scale)?;
    d.set_item("graph_cost", m.graph_cost)?;
    d.set_item("welded_keyframes", m.welded_keyframes)?;
    let S = &m.similarity;
    let sR = S.rotation.to_rotation_matrix().into_inner() * S.scale;
    let similarity = Array2::from_shape_fn((4, 4), |(r, c)| match (r, c) {
        (3, 3) => 1.0,
        (3, _) => 0.0,
        (_, 3) => S.translation[r],
        _ => sR[(r, c)],
    });
    d.set_item("similarity", PyArray2::from_owned_array(py, similarity))?;
    Ok(d)
}

/// One loop (see `SlamSystem.loops`).
pub(crate) fn loop_dict<'py>(py: Python<'py>, l: &LoopClosure) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("current", l.current.0)?;
    d.set_item("matched", l.matched.0)?;
    d.set_item("timestamps", l.timestamps)?;
    d.set_item("num_matches", l.num_matches)?;
    d.set_item("scale", l.scale)?;
    d.set_item("correction_m", l.correction_m)?;
    d.set_item("graph_cost", l.graph_cost)?;
    Ok(d)
}
