//! The compact binary vocabulary format (little endian throughout):
//!
//! | offset | size | field |
//! |---|---|---|
//! | 0 | 8 | magic `b"FSLAMVOC"` |
//! | 8 | 4 | format version (`1`) |
//! | 12 | 4 | branching factor `k` |
//! | 16 | 4 | levels `L` |
//! | 20 | 4 | weighting (DBoW2 code: 0 TF-IDF, 1 TF, 2 IDF, 3 binary); scoring is always L1 |
//! | 24 | 4 | node count `n`, root included |
//! | 28 | 4 | reserved, 0 |
//! | 32 | 4 (n-1) | parent id of nodes 1..n |
//! | .. | 32 (n-1) | descriptor of nodes 1..n |
//! | .. | 8 (n-1) | weight (f64) of nodes 1..n |
//! | .. | 8 | checksum: FNV-1a-style hash of every preceding byte, taken as u64 words |
//!
//! The root is implicit (zero descriptor, weight 0); leaves are the nodes without children.
//! About 44 bytes per node: 49 MB for a `k = 10, L = 6` tree with 10^6 words.

use std::io::{Read, Write};
use std::path::Path;

use ferroslam_features::Descriptor;

use crate::error::{Result, VocabularyError};
use crate::vocabulary::Vocabulary;
use crate::weighting::Weighting;

const MAGIC: &[u8; 8] = b"FSLAMVOC";
/// Binary format version written and read by this build.
pub const FORMAT_VERSION: u32 = 1;
const HEADER_LEN: usize = 32;
const BYTES_PER_NODE: usize = 4 + 32 + 8;

impl Vocabulary {
    /// Serialises to the binary format described in the [module docs](crate::binary).
    pub fn to_bytes(&self) -> Vec<u8> {
        let (parents, descriptors, weights) = self.raw_parts();
        let n = parents.len();
        let mut out = Vec::with_capacity(HEADER_LEN + (n - 1) * BYTES_PER_NODE + 8);
        out.extend_from_slice(MAGIC);
        for field in [
            FORMAT_VERSION,
            self.branching(),
            self.levels(),
            self.weighting().code(),
            n as u32,
            0,
        ] {
            out.extend_from_slice(&field.to_le_bytes());
        }
        parents[1..]
            .iter()
            .for_each(|p| out.extend_from_slice(&p.to_le_bytes()));
        descriptors[1..]
            .iter()
            .for_each(|d| out.extend_from_slice(d));
        weights[1..]
            .iter()
            .for_each(|w| out.extend_from_slice(&w.to_le_bytes()));
        let sum = checksum(&out);
        out.extend_from_slice(&sum.to_le_bytes());
        out
    }

    /// Parses the binary format.
    ///
    /// # Errors
    /// [`VocabularyError::Truncated`] when shorter than the header says,
    /// [`VocabularyError::BadMagic`], [`VocabularyError::UnsupportedVersion`],
    /// [`VocabularyError::ChecksumMismatch`] for any flipped byte,
    /// [`VocabularyError::Malformed`] for trailing bytes or an invalid tree.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self> {
        if bytes.len() < HEADER_LEN {
            if !bytes.is_empty() && !MAGIC.starts_with(&bytes[..bytes.len().min(8)]) {
                return Err(VocabularyError::BadMagic);
            }
            return Err(truncated(HEADER_LEN as u64, bytes.len()));
        }
        if &bytes[..8] != MAGIC {
            return Err(VocabularyError::BadMagic);
        }
        let field = |i: usize| {
            u32::from_le_bytes([
                bytes[8 + 4 * i],
                bytes[9 + 4 * i],
                bytes[10 + 4 * i],
                bytes[11 + 4 * i],
            ])
        };
        let (version, k, levels, weighting, n) =
            (field(0), field(1), field(2), field(3), field(4) as usize);
        if version != FORMAT_VERSION {
            return Err(VocabularyError::UnsupportedVersion {
                found: version,
                supported: FORMAT_VERSION,
            });
        }
        if n < 2 {
            return Err(VocabularyError::Malformed(format!("node count {n} < 2")));
        }
        let needed = (n as u64 - 1) * BYTES_PER_NODE as u64 + HEADER_LEN as u64 + 8;
        if (bytes.len() as u64) < needed {
            return Err(truncated(needed, bytes.len()));
        }
        if bytes.len() as u64 > needed {
            return Err(VocabularyError::Malformed(format!(
                "{} trailing bytes after the checksum",
                bytes.len() as u64 - needed
            )));
        }
        let body_len = bytes.len() - 8;
        let stored = u64::from_le_bytes(
            bytes[body_len..]
                .try_into()
                .map_err(|_| truncated(needed, bytes.len()))?,
        );
        if checksum(&bytes[..body_len]) != stored {
            return Err(VocabularyError::ChecksumMismatch);
        }
        let weighting = Weighting::from_code(weighting)?;
        let m = n - 1;
        let (parent_bytes, rest) = bytes[HEADER_LEN..body_len].split_at(4 * m);
        let (descriptor_bytes, weight_bytes) = rest.split_at(32 * m);
        let parents = std::iter::once(0)
            .chain(
                parent_bytes
                    .chunks_exact(4)
                    .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]])),
            )
            .collect();
        let descriptors = std::iter::once([0u8; 32])
            .chain(descriptor_bytes.chunks_exact(32).map(|c| {
                let mut d: Descriptor = [0; 32];
                d.copy_from_slice(c);
                d
            }))
            .collect();
        let weights = std::iter::once(0.0)
            .chain(
                weight_bytes
                    .chunks_exact(8)
                    .map(|c| f64::from_le_bytes([c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]])),
            )
            .collect();
        Vocabulary::from_raw_parts(k, levels, weighting, parents, descriptors, weights)
    }

    /// Writes the binary format to `path` through [`ferroslam_files::write_atomically`] (a
    /// temporary file renamed over `path`; a folder, FIFO or device there is refused).
    ///
    /// # Errors
    /// [`VocabularyError::Io`] when the file cannot be written.
    pub fn save(&self, path: impl AsRef<Path>) -> Result<()> {
        let bytes = self.to_bytes();
        ferroslam_files::write_atomically(path.as_ref(), |w| Ok(w.write_all(&bytes)?))
    }

    /// Reads the binary format from `path`.
    ///
    /// # Errors
    /// [`VocabularyError::Io`] when the file cannot be read, is not a regular file (a device
    /// such as `/dev/zero` would be read forever, a FIFO block) or is larger than
    /// [`crate::MAX_FILE_BYTES`], else as [`Vocabulary::from_bytes`].
    pub fn load(path: impl AsRef<Path>) -> Result<Self> {
        let mut bytes = Vec::new();
        crate::open_regular_file(path.as_ref())?.read_to_end(&mut bytes)?;
        Vocabulary::from_bytes(&bytes)
    }
}

fn truncated(needed: u64, available: usize) -> VocabularyError {
    VocabularyError::Truncated {
        needed,
        available: available as u64,
    }
}

/// FNV-1a over little-endian u64 words (the tail zero-padded), with a final avalanche:
/// eight times faster than byte-wise FNV and enough to catch corruption (not an authenticator).
fn checksum(bytes: &[u8]) -> u64 {
    const PRIME: u64 = 0x0000_0100_0000_01B3;
    let mut h: u64 = 0xCBF2_9CE4_8422_2325 ^ bytes.len() as u64;
    let mut words = bytes.chunks_exact(8);
    for w in &mut words {
        h = (h ^ u64::from_le_bytes([w[0], w[1], w[2], w[3], w[4], w[5], w[6], w[7]]))
            .wrapping_mul(PRIME);
        h ^= h >> 29;
    }
    let mut tail = [0u8; 8];
    tail[..words.remainder().len()].copy_from_slice(words.remainder());
    h = (h ^ u64::from_le_bytes(tail)).wrapping_mul(PRIME);
    h ^ (h >> 32)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tiny() -> Vocabulary {
        Vocabulary::from_raw_parts(
            2,
            2,
            Weighting::TfIdf,
            vec![0, 0, 0, 1, 1],
            vec![[0; 32], [1; 32], [2; 32], [3; 32], [4; 32]],
            vec![0.0, 0.0, 0.7, 1.5, 0.25],
        )
        .unwrap()
    }

    #[test]
    fn round_trip_is_identical() {
        let v = tiny();
        let bytes = v.to_bytes();
        assert_eq!(bytes.len(), HEADER_LEN + 4 * BYTES_PER_NODE + 8);
        assert_eq!(Vocabulary::from_bytes(&bytes).unwrap(), v);
    }

    #[test]
    fn every_truncation_and_every_flipped_byte_is_an_error() {
        let bytes = tiny().to_bytes();
        for len in 0..bytes.len() {
            assert!(
                Vocabulary::from_bytes(&bytes[..len]).is_err(),
                "length {len}"
            );
        }
        for i in 0..bytes.len() {
            let mut b = bytes.clone();
            b[i] ^= 0x10;
            assert!(Vocabulary::from_bytes(&b).is_err(), "byte {i}");
        }
        let mut longer = bytes.clone();
        longer.push(0);
        assert!(matches!(
            Vocabulary::from_bytes(&longer),
            Err(VocabularyError::Malformed(_))
        ));
    }

    #[test]
    fn specific_errors() {
        let bytes = tiny().to_bytes();
        assert!(matches!(
            Vocabulary::from_bytes(b"not a vocabulary at all, no no no"),
            Err(VocabularyError::BadMagic)
        ));
        assert!(matches!(
            Vocabulary::from_bytes(&bytes[..100]),
            Err(VocabularyError::Truncated { .. })
        ));
        let mut v2 = bytes.clone();
        v2[8] = 2;
        assert!(matches!(
            Vocabulary::from_bytes(&v2),
            Err(VocabularyError::UnsupportedVersion { found: 2, .. })
        ));
        let mut flipped = bytes.clone();
        flipped[HEADER_LEN + 20] ^= 1;
        assert!(matches!(
            Vocabulary::from_bytes(&flipped),
            Err(VocabularyError::ChecksumMismatch)
        ));
        // A branching factor of 2^32 - 1 with a valid checksum is refused, not loaded.
        let mut wide = bytes.clone();
        wide[12..16].copy_from_slice(&u32::MAX.to_le_bytes());
        let body_len = wide.len() - 8;
        let sum = checksum(&wide[..body_len]);
        wide[body_len..].copy_from_slice(&sum.to_le_bytes());
        let err = Vocabulary::from_bytes(&wide).unwrap_err();
        assert!(err.to_string().contains("k = 4294967295"), "{err}");
        // A huge node count in the header is reported as truncation, not an allocation.
        let mut huge = bytes;
        huge[24..28].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(matches!(
            Vocabulary::from_bytes(&huge),
            Err(VocabularyError::Truncated { .. })
        ));
    }

    mod fuzz {
        //! Seeded, bounded property tests of both readers: random bytes and mutations of
        //! valid files (binary resealed with its checksum so the parser sees them) are a
        //! clean `Err` or a valid vocabulary; nothing panics.
        use proptest::prelude::*;
        use proptest::test_runner::{Config, RngAlgorithm, TestRng, TestRunner};

        use super::*;

        fn runner(cases: u32) -> TestRunner {
            let config = Config {
                cases,
                failure_persistence: None,
                ..Config::default()
            };
            TestRunner::new_with_rng(config, TestRng::from_seed(RngAlgorithm::ChaCha, &[53; 32]))
        }

        /// k = 3, L = 2: 13 nodes, 9 words.
        fn sample() -> Vocabulary {
            let parents = vec![0, 0, 0, 0, 1, 1, 1, 2, 2, 2, 3, 3, 3];
            let descriptors = (0..13u8).map(|i| [i.wrapping_mul(37); 32]).collect();
            let weights = (0..13).map(|i| f64::from(i) * 0.25).collect();
            Vocabulary::from_raw_parts(3, 2, Weighting::TfIdf, parents, descriptors, weights)
                .unwrap()
        }

        fn reseal(bytes: &mut [u8]) {
            if bytes.len() >= 8 {
                let body = bytes.len() - 8;
                let sum = checksum(&bytes[..body]);
                bytes[body..].copy_from_slice(&sum.to_le_bytes());
            }
        }

        #[test]
        fn mutated_binary_files_fail_cleanly() {
            let bytes = sample().to_bytes();
            let n = bytes.len();
            let edits = prop::collection::vec((0..n - 8, any::<u8>()), 1..6);
            runner(512)
                .run(&(edits, any::<bool>(), 0..n + 1), |(edits, seal, cut)| {
                    let mut bad = bytes.clone();
                    edits.iter().for_each(|&(i, b)| bad[i] = b);
                    bad.truncate(cut);
                    if seal {
                        reseal(&mut bad);
                    }
                    if let Ok(v) = Vocabulary::from_bytes(&bad) {
                        // Whatever loads is a vocabulary that saves and loads again.
                        prop_assert_eq!(Vocabulary::from_bytes(&v.to_bytes()).unwrap(), v);
                    }
                    Ok(())
                })
                .unwrap();
        }

        #[test]
        fn random_binary_bytes_fail_cleanly() {
            runner(256)
                .run(&prop::collection::vec(any::<u8>(), 0..256), |mut bytes| {
                    prop_assert!(Vocabulary::from_bytes(&bytes).is_err());
                    if bytes.len() >= HEADER_LEN + 8 {
                        bytes[..8].copy_from_slice(MAGIC);
                        bytes[8..12].copy_from_slice(&FORMAT_VERSION.to_le_bytes());
                        reseal(&mut bytes);
                        let _ = Vocabulary::from_bytes(&bytes);
                    }
                    Ok(())
                })
                .unwrap();
        }

        #[test]
        fn mutated_and_random_text_files_fail_cleanly() {
            let mut text = Vec::new();
            sample().write_dbow2_text(&mut text).unwrap();
            let n = text.len();
            // Bytes likely to keep the text parseable (digits, spaces, newlines, signs).
            let byte = prop_oneof![
                prop::sample::select(b"0123456789 \n-.e".to_vec()),
                any::<u8>()
            ];
            let edits = prop::collection::vec((0..n, byte), 1..6);
            runner(512)
                .run(&(edits, 0..n + 1), |(edits, cut)| {
                    let mut bad = text.clone();
                    edits.iter().for_each(|&(i, b)| bad[i] = b);
                    bad.truncate(cut);
                    let _ = Vocabulary::read_dbow2_text(&bad[..]);
                    Ok(())
                })
                .unwrap();
            runner(256)
                .run(&prop::collection::vec(any::<u8>(), 0..256), |bytes| {
                    prop_assert!(Vocabulary::read_dbow2_text(&bytes[..]).is_err());
                    Ok(())
                })
                .unwrap();
        }
    }
}
