//! 256-bit ORB descriptors and their Hamming distance.

/// A 256-bit binary ORB descriptor (OpenCV layout: 32 bytes, one row of the N x 32 `u8` array).
pub type Descriptor = [u8; 32];

/// Hamming distance between two descriptors: the number of differing bits, in `0..=256`.
///
/// Computed as four 64-bit popcounts (the compiler emits `popcnt` where available).
///
/// ```
/// use ferroslam_features::hamming;
/// let a = [0u8; 32];
/// let mut b = [0u8; 32];
/// b[0] = 0b1011;
/// b[31] = 0xFF;
/// assert_eq!(hamming(&a, &b), 11);
/// ```
#[inline]
pub fn hamming(a: &Descriptor, b: &Descriptor) -> u32 {
    a.chunks_exact(8)
        .zip(b.chunks_exact(8))
        .map(|(x, y)| {
            // chunks_exact(8) guarantees 8-byte slices, so the conversions cannot fail.
            let x = u64::from_le_bytes(x.try_into().unwrap_or([0; 8]));
            let y = u64::from_le_bytes(y.try_into().unwrap_or([0; 8]));
            (x ^ y).count_ones()
        })
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identical_is_zero_and_complement_is_256() {
        let a: Descriptor = core::array::from_fn(|i| (i * 37 + 11) as u8);
        let not_a: Descriptor = core::array::from_fn(|i| !a[i]);
        assert_eq!(hamming(&a, &a), 0);
        assert_eq!(hamming(&a, &not_a), 256);
    }

    #[test]
    fn known_patterns() {
        let zero = [0u8; 32];
        // 0x55 = 0101_0101: four bits per byte.
        assert_eq!(hamming(&zero, &[0x55; 32]), 128);
        assert_eq!(hamming(&[0x55; 32], &[0xAA; 32]), 256);
        assert_eq!(hamming(&[0x0F; 32], &[0x3C; 32]), 4 * 32);
        // One bit in each 64-bit chunk, at chunk boundaries.
        let mut b = [0u8; 32];
        for i in [0usize, 7, 8, 15, 16, 23, 24, 31] {
            b[i] = 0x80;
        }
        assert_eq!(hamming(&zero, &b), 8);
    }

    #[test]
    fn matches_bytewise_popcount() {
        let mut s: u32 = 12345;
        for _ in 0..100 {
            let mut next = || {
                s = s.wrapping_mul(1_103_515_245).wrapping_add(12_345);
                (s >> 16) as u8
            };
            let a: Descriptor = core::array::from_fn(|_| next());
            let b: Descriptor = core::array::from_fn(|_| next());
            let naive: u32 = a.iter().zip(&b).map(|(x, y)| (x ^ y).count_ones()).sum();
            assert_eq!(hamming(&a, &b), naive);
        }
    }
}
