//! Compressed rows: a list of lists stored in two flat vectors.

/// `items[offsets[r]..offsets[r + 1]]` is row `r`.
#[derive(Clone, Debug, Default)]
pub(crate) struct Csr<T> {
    offsets: Vec<usize>,
    items: Vec<T>,
}

impl<T> Csr<T> {
    /// Groups `(row, item)` pairs into `rows` rows, keeping the input order within a row.
    pub(crate) fn from_pairs(
        rows: usize,
        pairs: impl IntoIterator<Item = (usize, T)> + Clone,
    ) -> Self {
        let mut offsets = vec![0usize; rows + 1];
        for (r, _) in pairs.clone() {
            offsets[r + 1] += 1;
        }
        for r in 0..rows {
            offsets[r + 1] += offsets[r];
        }
        let mut slots: Vec<Option<T>> = Vec::with_capacity(offsets[rows]);
        slots.resize_with(offsets[rows], || None);
        let mut next = offsets.clone();
        for (r, item) in pairs {
            slots[next[r]] = Some(item);
            next[r] += 1;
        }
        Self {
            offsets,
            items: slots.into_iter().flatten().collect(),
        }
    }

    /// The rows in order, each given by its items.
    pub(crate) fn from_rows<R: IntoIterator<Item = T>>(rows: impl IntoIterator<Item = R>) -> Self {
        let mut offsets = vec![0];
        let mut items = Vec::new();
        for row in rows {
            items.extend(row);
            offsets.push(items.len());
        }
        Self { offsets, items }
    }

    pub(crate) fn row(&self, r: usize) -> &[T] {
        &self.items[self.range(r)]
    }

    /// Positions of row `r`'s items in the flat item list.
    pub(crate) fn range(&self, r: usize) -> std::ops::Range<usize> {
        self.offsets[r]..self.offsets[r + 1]
    }

    /// Total number of items.
    pub(crate) fn len(&self) -> usize {
        self.items.len()
    }

    /// All items, row after row.
    pub(crate) fn items(&self) -> &[T] {
        &self.items
    }
}
