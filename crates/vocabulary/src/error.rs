//! The crate's error type.

/// Everything that can go wrong when training, loading or saving a vocabulary.
#[derive(Debug, thiserror::Error)]
pub enum VocabularyError {
    /// A training or construction parameter is out of range.
    #[error("invalid parameter: {0}")]
    InvalidParameter(String),
    /// Training was given no descriptors at all.
    #[error("no training descriptors")]
    NoTrainingData,
    /// Reading or writing a file failed.
    #[error(transparent)]
    Io(#[from] std::io::Error),
    /// The binary file does not start with the ferroslam vocabulary magic bytes.
    #[error("not a ferroslam vocabulary file (bad magic bytes)")]
    BadMagic,
    /// The binary file has a format version this build cannot read.
    #[error(
        "unsupported vocabulary format version {found} (this build reads version {supported})"
    )]
    UnsupportedVersion {
        /// Version in the file.
        found: u32,
        /// Version this build reads.
        supported: u32,
    },
    /// The binary file is shorter than its header says.
    #[error("vocabulary file truncated: need {needed} bytes, have {available}")]
    Truncated {
        /// Bytes the header implies.
        needed: u64,
        /// Bytes present.
        available: u64,
    },
    /// The payload does not match the stored checksum.
    #[error("vocabulary file checksum mismatch (corrupt file)")]
    ChecksumMismatch,
    /// The tree or header is structurally invalid (bad parent ids, depth, weights, ...).
    #[error("malformed vocabulary: {0}")]
    Malformed(String),
    /// A line of a DBoW2 text vocabulary could not be parsed (1-based line number).
    #[error("DBoW2 text vocabulary, line {line}: {message}")]
    Parse {
        /// 1-based line number.
        line: usize,
        /// What was wrong.
        message: String,
    },
}

/// Result alias of this crate.
pub type Result<T> = std::result::Result<T, VocabularyError>;
