//! One level of k-majority clustering (k-medians on bits): k-means++ seeding with Hamming
//! distances, then alternating nearest-centroid assignment and bitwise-majority centroids.

use ferroslam_features::{hamming, Descriptor};
use rand::Rng;
use rayon::prelude::*;

/// Below this many descriptors per rayon task, splitting work costs more than it saves.
const MIN_PAR_LEN: usize = 2048;

/// A cluster: its centroid and the indices (into the training set) of its members.
pub(crate) struct Cluster {
    pub centroid: Descriptor,
    pub members: Vec<u32>,
}

/// Splits `members` (indices into `all`) into at most `k` non-empty clusters.
///
/// With at most `k` distinct descriptors each distinct value becomes its own cluster (as
/// DBoW2 does, minus duplicates). Otherwise iterates until assignments stop changing or
/// `max_iterations` centroid updates were made; members are always assigned to their nearest
/// returned centroid (lowest index on ties), which is what the tree descent reproduces.
pub(crate) fn k_majority<R: Rng>(
    all: &[Descriptor],
    members: &[u32],
    k: usize,
    max_iterations: u32,
    rng: &mut R,
) -> Vec<Cluster> {
    if let Some(groups) = distinct_groups(all, members, k) {
        return groups;
    }
    let mut centroids = seed_kmeans_pp(all, members, k, rng);
    let mut assignment = assign(all, members, &centroids);
    for _ in 0..max_iterations {
        centroids = majority_centroids(all, members, &assignment, &centroids);
        let next = assign(all, members, &centroids);
        let converged = next == assignment;
        assignment = next;
        if converged {
            break;
        }
    }
    let mut groups: Vec<Vec<u32>> = vec![Vec::new(); centroids.len()];
    for (&m, &c) in members.iter().zip(&assignment) {
        groups[c as usize].push(m);
    }
    centroids
        .into_iter()
        .zip(groups)
        .filter(|(_, g)| !g.is_empty())
        .map(|(centroid, members)| Cluster { centroid, members })
        .collect()
}

/// One cluster per distinct descriptor when there are at most `k` of them, else `None`.
fn distinct_groups(all: &[Descriptor], members: &[u32], k: usize) -> Option<Vec<Cluster>> {
    let mut groups: Vec<Cluster> = Vec::new();
    for &m in members {
        let d = &all[m as usize];
        match groups.iter().position(|g| &g.centroid == d) {
            Some(i) => groups[i].members.push(m),
            None if groups.len() == k => return None,
            None => groups.push(Cluster {
                centroid: *d,
                members: vec![m],
            }),
        }
    }
    Some(groups)
}

/// k-means++: first centroid uniform, each next one drawn with probability proportional to
/// the squared Hamming distance to the nearest chosen centroid. Stops early if every
/// remaining descriptor coincides with a chosen one.
fn seed_kmeans_pp<R: Rng>(
    all: &[Descriptor],
    members: &[u32],
    k: usize,
    rng: &mut R,
) -> Vec<Descriptor> {
    let first = all[members[rng.random_range(0..members.len())] as usize];
    let mut centroids = vec![first];
    let mut nearest: Vec<u64> = members
        .par_iter()
        .with_min_len(MIN_PAR_LEN)
        .map(|&m| u64::from(hamming(&all[m as usize], &first)).pow(2))
        .collect();
    while centroids.len() < k {
        let total: u64 = nearest.iter().sum();
        if total == 0 {
            break;
        }
        let mut target = rng.random_range(0..total);
        let pick = nearest
            .iter()
            .position(|&d| {
                if target < d {
                    true
                } else {
                    target -= d;
                    false
                }
            })
            .unwrap_or(members.len() - 1);
        let c = all[members[pick] as usize];
        centroids.push(c);
        nearest
            .par_iter_mut()
            .with_min_len(MIN_PAR_LEN)
            .zip(members.par_iter().with_min_len(MIN_PAR_LEN))
            .for_each(|(n, &m)| *n = (*n).min(u64::from(hamming(&all[m as usize], &c)).pow(2)));
    }
    centroids
}

/// Index of the nearest centroid of each member (lowest index on ties).
fn assign(all: &[Descriptor], members: &[u32], centroids: &[Descriptor]) -> Vec<u32> {
    members
        .par_iter()
        .with_min_len(MIN_PAR_LEN)
        .map(|&m| {
            let d = &all[m as usize];
            let mut best = (u32::MAX, 0u32);
            for (j, c) in centroids.iter().enumerate() {
                let dist = hamming(d, c);
                if dist < best.0 {
                    best = (dist, j as u32);
                }
            }
            best.1
        })
        .collect()
}

/// Bitwise majority of each cluster (a bit is set when at least half the members set it,
/// as DBoW2's `FORB::meanValue`); empty clusters keep their previous centroid.
fn majority_centroids(
    all: &[Descriptor],
    members: &[u32],
    assignment: &[u32],
    previous: &[Descriptor],
) -> Vec<Descriptor> {
    let k = previous.len();
    let zero = || (vec![0u32; k * 256], vec![0u32; k]);
    let (bits, sizes) = members
        .par_iter()
        .with_min_len(MIN_PAR_LEN)
        .zip(assignment.par_iter().with_min_len(MIN_PAR_LEN))
        .fold(zero, |(mut bits, mut sizes), (&m, &c)| {
            let row = &mut bits[c as usize * 256..(c as usize + 1) * 256];
            for (byte_index, &byte) in all[m as usize].iter().enumerate() {
                for bit in 0..8 {
                    row[byte_index * 8 + bit] += u32::from((byte >> bit) & 1);
                }
            }
            sizes[c as usize] += 1;
            (bits, sizes)
        })
        .reduce(zero, |(mut b1, mut s1), (b2, s2)| {
            b1.iter_mut().zip(b2).for_each(|(a, b)| *a += b);
            s1.iter_mut().zip(s2).for_each(|(a, b)| *a += b);
            (b1, s1)
        });
    (0..k)
        .map(|c| {
            if sizes[c] == 0 {
                return previous[c];
            }
            let row = &bits[c * 256..(c + 1) * 256];
            core::array::from_fn(|byte_index| {
                (0..8).fold(0u8, |acc, bit| {
                    let set = 2 * row[byte_index * 8 + bit] >= sizes[c];
                    acc | (u8::from(set) << bit)
                })
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn majority_sets_bits_held_by_at_least_half() {
        let mut a = [0u8; 32];
        let mut b = [0u8; 32];
        let mut c = [0u8; 32];
        a[0] = 0b0000_0111;
        b[0] = 0b0000_0011;
        c[0] = 0b0000_0001;
        c[31] = 0x80;
        let all = [a, b, c];
        let got = majority_centroids(&all, &[0, 1, 2], &[0, 0, 0], &[[0xAA; 32]]);
        let mut want = [0u8; 32];
        want[0] = 0b0000_0011;
        assert_eq!(got, vec![want]);
        // Two members: ties (1 of 2) set the bit.
        let got = majority_centroids(&all, &[0, 2], &[0, 0], &[[0; 32]]);
        want[0] = 0b0000_0111;
        want[31] = 0x80;
        assert_eq!(got, vec![want]);
    }

    #[test]
    fn few_distinct_descriptors_become_their_own_clusters() {
        let all = [[1u8; 32], [2u8; 32], [1u8; 32]];
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        let clusters = k_majority(&all, &[0, 1, 2], 2, 10, &mut rng);
        assert_eq!(clusters.len(), 2);
        assert_eq!(clusters[0].members, vec![0, 2]);
        assert_eq!(clusters[1].members, vec![1]);
    }

    #[test]
    fn separates_two_far_groups() {
        let mut all = Vec::new();
        for i in 0..50u8 {
            let mut d = [0u8; 32];
            d[(i % 32) as usize] = 1;
            all.push(d);
            let mut e = [0xFFu8; 32];
            e[(i % 32) as usize] = 0xFE;
            all.push(e);
        }
        let members: Vec<u32> = (0..all.len() as u32).collect();
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let clusters = k_majority(&all, &members, 2, 10, &mut rng);
        assert_eq!(clusters.len(), 2);
        for c in &clusters {
            let parity = c.members[0] % 2;
            assert!(c.members.iter().all(|m| m % 2 == parity));
            assert_eq!(c.members.len(), 50);
        }
    }
}
