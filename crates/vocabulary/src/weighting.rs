//! Word weighting schemes, numbered as DBoW2's `WeightingType`.

use crate::error::{Result, VocabularyError};

/// How a word occurrence is weighted in a [`BowVector`](crate::BowVector).
///
/// BoW vectors are always L1-normalised afterwards (DBoW2's L1 scoring), so the term
/// frequency's `1 / n_features` factor cancels: `TfIdf` and `Idf` give identical vectors,
/// as do `Tf` and term counts. `Binary` marks each present word with 1.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Weighting {
    /// Term frequency times inverse document frequency `ln(N / n_i)` (DBoW2 code 0, the default).
    TfIdf,
    /// Term frequency only; word weights are 1 (code 1).
    Tf,
    /// Inverse document frequency summed per occurrence (code 2).
    Idf,
    /// 1 for every word present, whatever its count (code 3).
    Binary,
}

impl Weighting {
    /// DBoW2's numeric code (`TF_IDF = 0, TF = 1, IDF = 2, BINARY = 3`).
    pub fn code(self) -> u32 {
        match self {
            Weighting::TfIdf => 0,
            Weighting::Tf => 1,
            Weighting::Idf => 2,
            Weighting::Binary => 3,
        }
    }

    /// Inverse of [`Weighting::code`].
    ///
    /// # Errors
    /// [`VocabularyError::Malformed`] for codes other than 0..=3.
    pub fn from_code(code: u32) -> Result<Self> {
        match code {
            0 => Ok(Weighting::TfIdf),
            1 => Ok(Weighting::Tf),
            2 => Ok(Weighting::Idf),
            3 => Ok(Weighting::Binary),
            _ => Err(VocabularyError::Malformed(format!(
                "unknown weighting code {code}"
            ))),
        }
    }

    /// Whether word weights are IDF values learnt at training time (otherwise all 1).
    pub fn uses_idf(self) -> bool {
        matches!(self, Weighting::TfIdf | Weighting::Idf)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_round_trip_and_reject_unknown() {
        for w in [
            Weighting::TfIdf,
            Weighting::Tf,
            Weighting::Idf,
            Weighting::Binary,
        ] {
            assert_eq!(Weighting::from_code(w.code()).unwrap(), w);
        }
        assert!(Weighting::from_code(4).is_err());
    }
}
