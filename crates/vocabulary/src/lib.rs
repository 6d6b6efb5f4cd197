//! Bag-of-binary-words place recognition for ferroslam, after DBoW2 (Gálvez-López and
//! Tardós, T-RO 2012) as used by ORB-SLAM2/3.
//!
//! - [`Vocabulary`]: a tree of 256-bit ORB descriptor centroids trained by hierarchical
//!   k-majority clustering ([`Vocabulary::train`], [`TrainParams`]), with TF-IDF word weights;
//!   [`Vocabulary::transform`] turns an image's descriptors into a [`BowVector`] (word ->
//!   weight, L1-normalised) and a [`FeatureVector`] (tree node -> feature indices, to restrict
//!   descriptor matching to features under the same node).
//! - [`BowVector::l1_score`]: DBoW2's L1 similarity `1 - 0.5 |a/|a| - b/|b||_1` in `[0, 1]`.
//! - Files: a compact checksummed binary format ([`Vocabulary::save`] / [`Vocabulary::load`],
//!   layout in [`binary`]) and DBoW2's text format read by ORB-SLAM
//!   ([`Vocabulary::save_dbow2_text`] / [`Vocabulary::load_dbow2_text`], see [`dbow2_text`]).
//! - [`Database`]: inverted-index keyframe database with add / remove / query and the
//!   shared-word counts of ORB-SLAM's loop and relocalisation candidate search.
//!
//! Training is deterministic for a given seed; heavy loops run on rayon. Nothing panics on
//! bad input: files and parameters are validated and errors reported as [`VocabularyError`].
#![warn(missing_docs)]

pub mod binary;
pub mod bow;
mod cluster;
pub mod database;
pub mod dbow2_text;
pub mod error;
mod file;
pub mod train;
pub mod vocabulary;
pub mod weighting;

pub use bow::{BowVector, FeatureVector, NodeId, WordId};
pub use database::{Database, EntryId};
pub use error::{Result, VocabularyError};
pub(crate) use file::open_regular_file;
pub use file::MAX_FILE_BYTES;
pub use train::TrainParams;
pub use vocabulary::{Vocabulary, MAX_BRANCHING, MAX_LEVELS};
pub use weighting::Weighting;
