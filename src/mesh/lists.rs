//! Lists of values laid one after another, with where each ends: building
//! them allocates nothing per list, and cleared they keep their room (face
//! loops of a trial split, the elements a rollback saves).

/// Lists of `T`, one after another.
#[derive(Clone, Debug)]
pub struct Lists<T> {
    values: Vec<T>,
    ends: Vec<usize>,
}

impl<T> Default for Lists<T> {
    fn default() -> Self {
        Lists { values: Vec::new(), ends: Vec::new() }
    }
}

impl<T: Copy> Lists<T> {
    /// No lists, with room for `lists` lists of `values` values in all.
    pub fn with_capacity(lists: usize, values: usize) -> Self {
        Lists { values: Vec::with_capacity(values), ends: Vec::with_capacity(lists) }
    }

    /// The `lists`, one after another, sized once (two passes).
    pub fn of<'a>(lists: impl Iterator<Item = &'a [T]> + Clone) -> Self
    where
        T: 'a,
    {
        let (count, total) = lists.clone().fold((0, 0), |(c, t), list| (c + 1, t + list.len()));
        let mut out = Self::with_capacity(count, total);
        for list in lists {
            out.push(list.iter().copied());
        }
        out
    }

    /// No lists (the room is kept).
    pub fn clear(&mut self) {
        self.values.clear();
        self.ends.clear();
    }

    /// Appends one list.
    pub fn push(&mut self, values: impl IntoIterator<Item = T>) {
        self.values.extend(values);
        self.ends.push(self.values.len());
    }

    /// Reverses the last list.
    pub fn reverse_last(&mut self) {
        let start = if self.ends.len() < 2 { 0 } else { self.ends[self.ends.len() - 2] };
        self.values[start..].reverse();
    }

    /// Number of lists.
    pub fn len(&self) -> usize {
        self.ends.len()
    }

    /// Whether there are no lists.
    pub fn is_empty(&self) -> bool {
        self.ends.is_empty()
    }

    /// List `i`.
    pub fn get(&self, i: usize) -> &[T] {
        let start = if i == 0 { 0 } else { self.ends[i - 1] };
        &self.values[start..self.ends[i]]
    }

    /// The lists in order.
    pub fn iter(&self) -> impl Iterator<Item = &[T]> + Clone {
        (0..self.len()).map(|i| self.get(i))
    }

    /// Every value of every list, list after list.
    pub fn values(&self) -> &[T] {
        &self.values
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lists_keep_their_order_and_ends() {
        let mut lists = Lists::default();
        lists.push([1, 2, 3]);
        lists.push([]);
        lists.push([4, 5]);
        lists.reverse_last();
        assert_eq!(lists.len(), 3);
        assert_eq!(lists.iter().collect::<Vec<_>>(), [&[1, 2, 3][..], &[], &[5, 4]]);
        assert_eq!(lists.values(), [1, 2, 3, 5, 4]);
        let copy = Lists::of(lists.iter());
        assert_eq!(copy.iter().collect::<Vec<_>>(), lists.iter().collect::<Vec<_>>());
        lists.clear();
        assert!(lists.is_empty() && lists.values().is_empty());
        lists.push([7]);
        lists.reverse_last();
        assert_eq!(lists.get(0), [7]);
    }
}
