//! `Vocabulary` and `KeyframeDatabase` Python classes over `ferroslam-vocabulary`.
//!
//! BoW vectors cross the boundary as `dict[int, float]` (word id -> L1-normalised weight).
//! File errors name the file: unreadable -> `OSError` (`FileNotFoundError` when missing),
//! anything wrong inside the file -> `ValueError`.

use crate::pool;
use std::collections::HashSet;
use std::path::PathBuf;
use std::sync::Arc;

use ferroslam_features::Descriptor;
use ferroslam_vocabulary::{BowVector, Database, EntryId, TrainParams, Vocabulary, WordId};
use numpy::{PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyString};

use crate::convert;
use crate::errors::vocabulary_file_error as file_error;

/// `obj` as `(N, 32)` uint8 descriptors; errors name the argument `name`.
fn descriptor_rows(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<Vec<Descriptor>> {
    let arr: PyReadonlyArray2<'_, u8> = convert::array(obj, name, "a uint8 (N, 32) array")?;
    let shape = arr.shape();
    if shape[1] != 32 {
        return Err(PyValueError::new_err(format!(
            "{name} must have shape (N, 32) uint8 (256-bit ORB), got ({}, {})",
            shape[0], shape[1]
        )));
    }
    convert::descriptors(&arr)
}

/// An integer argument in `lo..=hi` (Python ints are unbounded; a clear ValueError beats
/// pyo3's OverflowError for negative values).
fn bounded(value: i64, name: &str, lo: i64, hi: i64) -> PyResult<i64> {
    if (lo..=hi).contains(&value) {
        Ok(value)
    } else {
        Err(PyValueError::new_err(format!(
            "{name} must be in {lo}..={hi}, got {value}"
        )))
    }
}

/// A keyframe id (u32).
fn entry_id(value: i64, name: &str) -> PyResult<EntryId> {
    bounded(value, name, 0, i64::from(u32::MAX)).map(|v| v as EntryId)
}

/// A `dict[int, float]` BoW vector; weights must be finite and non-negative.
fn bow_from_dict(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<BowVector> {
    let dict = obj.cast::<PyDict>().map_err(|_| {
        PyTypeError::new_err(format!(
            "{name} must be a dict[int, float] BoW vector (from Vocabulary.transform)"
        ))
    })?;
    let mut pairs = Vec::with_capacity(dict.len());
    for (key, value) in dict.iter() {
        let word: i64 = key
            .extract()
            .map_err(|_| PyTypeError::new_err(format!("{name}: word ids must be int")))?;
        let weight: f64 = value
            .extract()
            .map_err(|_| PyTypeError::new_err(format!("{name}: weights must be float")))?;
        if !(weight.is_finite() && weight >= 0.0) {
            return Err(PyValueError::new_err(format!(
                "{name}: weight of word {word} is {weight}; must be finite and >= 0"
            )));
        }
        let word = bounded(word, &format!("{name}: word id"), 0, i64::from(u32::MAX))?;
        pairs.push((word as WordId, weight));
    }
    Ok(BowVector::from_weights(pairs))
}

fn bow_to_dict<'py>(py: Python<'py>, bow: &BowVector) -> PyResult<Bound<'py, PyDict>> {
    let dict = PyDict::new(py);
    for (word, weight) in bow.iter() {
        dict.set_item(word, weight)?;
    }
    Ok(dict)
}

/// An ORB vocabulary tree (k-majority clustering, TF-IDF weights), as DBoW2's.
#[pyclass(name = "Vocabulary", module = "ferroslam._core", frozen)]
pub struct PyVocabulary {
    inner: Arc<Vocabulary>,
}

impl PyVocabulary {
    fn bow(&self, py: Python<'_>, descriptors: &Bound<'_, PyAny>) -> PyResult<BowVector> {
        let descs = descriptor_rows(descriptors, "descriptors")?;
        let voc = &*self.inner;
        pool::detach(py, move || voc.transform(&descs, 0).0)
    }
}

impl PyVocabulary {
    /// The vocabulary, shared (no copy) with a SLAM system.
    pub(crate) fn shared(&self) -> Arc<Vocabulary> {
        Arc::clone(&self.inner)
    }
}

#[pymethods]
impl PyVocabulary {
    /// Trains a vocabulary on the descriptors of a set of images (one `(N, 32)` uint8 array
    /// per image: IDF weights count images). Deterministic for a given seed.
    #[staticmethod]
    #[pyo3(signature = (descriptor_list, k = 10, levels = 5, seed = 0))]
    fn train(
        py: Python<'_>,
        descriptor_list: &Bound<'_, PyAny>,
        k: i64,
        levels: i64,
        seed: u64,
    ) -> PyResult<Self> {
        if descriptor_list.is_instance_of::<PyString>() {
            return Err(PyTypeError::new_err(
                "descriptor_list must be a list of uint8 (N, 32) arrays, got str",
            ));
        }
        let items: Vec<Bound<'_, PyAny>> = descriptor_list.extract().map_err(|_| {
            PyTypeError::new_err("descriptor_list must be a list of uint8 (N, 32) arrays")
        })?;
        let images = items
            .iter()
            .enumerate()
            .map(|(i, obj)| descriptor_rows(obj, &format!("descriptor_list[{i}]")))
            .collect::<PyResult<Vec<_>>>()?;
        let params = TrainParams {
            k: bounded(k, "k", 2, 1 << 16)? as u32,
            levels: bounded(
                levels,
                "levels",
                1,
                i64::from(ferroslam_vocabulary::MAX_LEVELS),
            )? as u32,
            seed,
            ..TrainParams::default()
        };
        let voc = pool::detach(py, move || Vocabulary::train(&images, &params))?
            .map_err(|e| PyValueError::new_err(format!("descriptor_list: {e}")))?;
        Ok(PyVocabulary {
            inner: Arc::new(voc),
        })
    }

    /// Reads the compact binary format written by `save` (checksummed).
    #[staticmethod]
    fn load(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        let voc =
            pool::detach(py, || Vocabulary::load(&path))?.map_err(|e| file_error(&path, e))?;
        Ok(PyVocabulary {
            inner: Arc::new(voc),
        })
    }

    /// Reads DBoW2's text format (ORB-SLAM's `ORBvoc.txt`).
    #[staticmethod]
    fn load_dbow2_text(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        let voc = pool::detach(py, || Vocabulary::load_dbow2_text(&path))?
            .map_err(|e| file_error(&path, e))?;
        Ok(PyVocabulary {
            inner: Arc::new(voc),
        })
    }

    /// Writes the compact binary format.
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        pool::detach(py, || self.inner.save(&path))?.map_err(|e| file_error(&path, e))
    }

    /// Writes DBoW2's text format, readable by ORB-SLAM2/3.
    fn save_dbow2_text(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        pool::detach(py, || self.inner.save_dbow2_text(&path))?.map_err(|e| file_error(&path, e))
    }

    /// The BoW vector of an image's `(N, 32)` uint8 descriptors: word id -> weight,
    /// L1-normalised (empty for no descriptors).
    fn transform<'py>(
        &self,
        py: Python<'py>,
        descriptors: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let bow = self.bow(py, descriptors)?;
        bow_to_dict(py, &bow)
    }

    /// DBoW2's L1 similarity of two BoW vectors, in [0, 1] (0 if either is empty).
    #[staticmethod]
    fn score(a: &Bound<'_, PyAny>, b: &Bound<'_, PyAny>) -> PyResult<f64> {
        Ok(bow_from_dict(a, "a")?.l1_score(&bow_from_dict(b, "b")?))
    }

    /// Branching factor.
    #[getter]
    fn k(&self) -> u32 {
        self.inner.branching()
    }

    /// Tree depth.
    #[getter]
    fn levels(&self) -> u32 {
        self.inner.levels()
    }

    /// Number of words (leaves).
    #[getter]
    fn num_words(&self) -> usize {
        self.inner.word_count()
    }

    fn __repr__(&self) -> String {
        format!(
            "Vocabulary(k={}, levels={}, num_words={})",
            self.inner.branching(),
            self.inner.levels(),
            self.inner.word_count()
        )
    }
}

/// Inverted-index keyframe database scored with DBoW2's L1 score.
#[pyclass(name = "KeyframeDatabase", module = "ferroslam._core")]
pub struct PyKeyframeDatabase {
    vocabulary: Arc<Vocabulary>,
    inner: Database,
}

#[pymethods]
impl PyKeyframeDatabase {
    #[new]
    fn new(vocabulary: &Bound<'_, PyAny>) -> PyResult<Self> {
        let voc = vocabulary
            .cast::<PyVocabulary>()
            .map_err(|_| PyTypeError::new_err("vocabulary must be a ferroslam Vocabulary"))?;
        Ok(PyKeyframeDatabase {
            vocabulary: Arc::clone(&voc.get().inner),
            inner: Database::new(),
        })
    }

    /// Adds keyframe `id` with its `(N, 32)` uint8 descriptors; returns True when it
    /// replaced an entry with the same id.
    fn add(&mut self, py: Python<'_>, id: i64, descriptors: &Bound<'_, PyAny>) -> PyResult<bool> {
        let id = entry_id(id, "id")?;
        let descs = descriptor_rows(descriptors, "descriptors")?;
        let (voc, db) = (&*self.vocabulary, &mut self.inner);
        pool::detach(py, move || db.add(id, &voc.transform(&descs, 0).0))
    }

    /// Removes keyframe `id`; returns whether it was present.
    fn remove(&mut self, id: i64) -> PyResult<bool> {
        Ok(self.inner.remove(entry_id(id, "id")?))
    }

    /// The `max_results` keyframes scoring highest against the descriptors, as
    /// `[(id, score)]` best first (ties by id); keyframes sharing no word and those in
    /// `exclude` are left out.
    #[pyo3(signature = (descriptors, max_results = 10, exclude = None))]
    fn query(
        &self,
        py: Python<'_>,
        descriptors: &Bound<'_, PyAny>,
        max_results: i64,
        exclude: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Vec<(EntryId, f64)>> {
        let max_results = bounded(max_results, "max_results", 0, i64::MAX)? as usize;
        let mut excluded = HashSet::new();
        if let Some(obj) = exclude {
            let bad = || PyTypeError::new_err("exclude must be an iterable of int ids");
            if obj.is_instance_of::<PyString>() {
                return Err(bad());
            }
            for item in obj.try_iter().map_err(|_| bad())? {
                excluded.insert(item?.extract::<i64>().map_err(|_| bad())?);
            }
        }
        let descs = descriptor_rows(descriptors, "descriptors")?;
        let (voc, db) = (&*self.vocabulary, &self.inner);
        pool::detach(py, move || {
            let bow = voc.transform(&descs, 0).0;
            db.query(&bow, max_results, |id| !excluded.contains(&i64::from(id)))
        })
    }

    fn __len__(&self) -> usize {
        self.inner.len()
    }

    fn __contains__(&self, id: i64) -> bool {
        u32::try_from(id).is_ok_and(|id| self.inner.contains(id))
    }

    fn __repr__(&self) -> String {
        format!("KeyframeDatabase({} keyframes)", self.inner.len())
    }
}
