//! The map's tables: ordered maps whose copies share everything until written.
//!
//! Concurrent mapping hands a copy of the map to the mapping thread for every keyframe (see
//! `ferroslam_slam`'s mapping pipeline). With plain `BTreeMap`s that copy cloned every
//! keyframe and point, on the tracking thread, in time growing with the map. An [`Arena`] is
//! a persistent B-tree (`imbl::OrdMap`) of reference-counted entries: a copy costs O(1), and
//! a write to an entry both copies still share clones that entry (and the tree path to it)
//! only, once.

use std::sync::Arc;

use imbl::OrdMap;

/// An ordered map from ids to entries, cheap to copy (see the module doc). Iteration is by
/// increasing key, as with `BTreeMap`.
#[derive(Debug)]
pub(crate) struct Arena<K: Ord + Clone, V> {
    entries: OrdMap<K, Arc<V>>,
}

impl<K: Ord + Clone, V> Clone for Arena<K, V> {
    fn clone(&self) -> Self {
        Self {
            entries: self.entries.clone(),
        }
    }
}

impl<K: Ord + Clone, V> Default for Arena<K, V> {
    fn default() -> Self {
        Self {
            entries: OrdMap::new(),
        }
    }
}

impl<K: Ord + Clone, V: Clone> Arena<K, V> {
    /// The entry under `key`, for writing: cloned first if a copy of the arena shares it.
    pub(crate) fn get_mut(&mut self, key: &K) -> Option<&mut V> {
        self.entries.get_mut(key).map(Arc::make_mut)
    }

    /// Removes the entry under `key` and returns it (cloned if a copy shares it).
    pub(crate) fn remove(&mut self, key: &K) -> Option<V> {
        self.entries.remove(key).map(Arc::unwrap_or_clone)
    }

    /// All entries by increasing key, taken out (each cloned only if a copy shares it).
    pub(crate) fn into_entries(self) -> impl Iterator<Item = (K, V)> {
        self.entries
            .into_iter()
            .map(|(key, entry)| (key, Arc::unwrap_or_clone(entry)))
    }
}

impl<K: Ord + Clone, V> Arena<K, V> {
    pub(crate) fn get(&self, key: &K) -> Option<&V> {
        self.entries.get(key).map(|entry| &**entry)
    }

    pub(crate) fn contains_key(&self, key: &K) -> bool {
        self.entries.contains_key(key)
    }

    pub(crate) fn insert(&mut self, key: K, value: V) {
        self.entries.insert(key, Arc::new(value));
    }

    /// Moves every entry of `other` in, without copying any (an entry under a key both hold
    /// is `other`'s afterwards).
    pub(crate) fn append(&mut self, other: Self) {
        for (key, entry) in other.entries {
            self.entries.insert(key, entry);
        }
    }

    pub(crate) fn len(&self) -> usize {
        self.entries.len()
    }

    pub(crate) fn clear(&mut self) {
        self.entries.clear();
    }

    pub(crate) fn keys(&self) -> impl Iterator<Item = &K> {
        self.entries.keys()
    }

    pub(crate) fn values(&self) -> impl ExactSizeIterator<Item = &V> {
        self.entries.values().map(|entry| &**entry)
    }

    pub(crate) fn iter(&self) -> impl Iterator<Item = (&K, &V)> {
        self.entries.iter().map(|(key, entry)| (key, &**entry))
    }
}

impl<K: Ord + Clone, V> FromIterator<(K, V)> for Arena<K, V> {
    fn from_iter<I: IntoIterator<Item = (K, V)>>(iter: I) -> Self {
        Self {
            entries: iter.into_iter().map(|(k, v)| (k, Arc::new(v))).collect(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_copy_shares_entries_until_either_side_writes_one() {
        let mut a: Arena<u32, Vec<u8>> = (0..100).map(|k| (k, vec![k as u8; 4])).collect();
        let b = a.clone();
        a.get_mut(&7).unwrap().push(1);
        assert_eq!(a.get(&7).unwrap().len(), 5);
        assert_eq!(b.get(&7).unwrap().len(), 4);
        // Untouched entries are the same allocation in both.
        assert!(std::ptr::eq(a.get(&8).unwrap(), b.get(&8).unwrap()));
        assert!(!std::ptr::eq(a.get(&7).unwrap(), b.get(&7).unwrap()));
        assert!(a.remove(&3).is_some() && a.remove(&3).is_none());
        assert_eq!((a.len(), b.len()), (99, 100));
        assert_eq!(b.keys().copied().take(3).collect::<Vec<_>>(), [0, 1, 2]);
    }
}
