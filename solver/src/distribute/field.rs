//! Per-node fields that carry their numbering: owned entries (interior, then border) first,
//! then halo entries, as `LocalNumbering` orders a process's nodes. The named slices say
//! which entries a loop may write (owned) and which are copies of other processes' values
//! (halo, written only by `Halo::finish`).

use eprop_partition::Layout;
use std::ops::{Deref, DerefMut};

/// A value per local node.
#[derive(Clone, Debug, PartialEq)]
pub struct NodeField<T> {
    data: Vec<T>,
    layout: Layout,
}

impl<T: Clone> NodeField<T> {
    /// Every entry set to `value`.
    pub fn filled(layout: Layout, value: T) -> NodeField<T> {
        NodeField {
            data: vec![value; layout.n_local],
            layout,
        }
    }
}

impl<T> NodeField<T> {
    /// A field over `layout` from its values (owned, then halo).
    pub fn from_vec(layout: Layout, data: Vec<T>) -> NodeField<T> {
        assert_eq!(data.len(), layout.n_local, "a field needs one value per local node");
        NodeField { data, layout }
    }
    pub fn layout(&self) -> Layout {
        self.layout
    }
    /// Entries of nodes whose rows read no halo value.
    pub fn interior(&self) -> &[T] {
        &self.data[self.layout.interior()]
    }
    /// Entries this process computes.
    pub fn owned(&self) -> &[T] {
        &self.data[self.layout.owned()]
    }
    pub fn owned_mut(&mut self) -> &mut [T] {
        let r = self.layout.owned();
        &mut self.data[r]
    }
    /// Copies of other processes' entries.
    pub fn halo(&self) -> &[T] {
        &self.data[self.layout.halo()]
    }
    pub fn into_vec(self) -> Vec<T> {
        self.data
    }
}

impl<const N: usize> NodeField<[f64; N]> {
    /// The values as one flat slice (N per node), for messages and output.
    pub fn flat(&self) -> &[f64] {
        self.data.as_flattened()
    }
    pub fn flat_mut(&mut self) -> &mut [f64] {
        self.data.as_flattened_mut()
    }
    /// The owned values as one flat slice.
    pub fn owned_flat(&self) -> &[f64] {
        self.owned().as_flattened()
    }
}

impl<T> Deref for NodeField<T> {
    type Target = [T];
    fn deref(&self) -> &[T] {
        &self.data
    }
}

impl<T> DerefMut for NodeField<T> {
    fn deref_mut(&mut self) -> &mut [T] {
        &mut self.data
    }
}

impl<'a, T> IntoIterator for &'a NodeField<T> {
    type Item = &'a T;
    type IntoIter = std::slice::Iter<'a, T>;
    fn into_iter(self) -> Self::IntoIter {
        self.data.iter()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slices_follow_the_layout() {
        let layout = Layout {
            n_interior: 2,
            n_owned: 3,
            n_local: 5,
        };
        let mut f = NodeField::from_vec(layout, vec![[0.0; 3], [1.0; 3], [2.0; 3], [3.0; 3], [4.0; 3]]);
        assert_eq!(f.interior().len(), 2);
        assert_eq!(f.owned().len(), 3);
        assert_eq!(f.halo(), &[[3.0; 3], [4.0; 3]]);
        f.owned_mut()[2] = [9.0; 3];
        assert_eq!(f[2], [9.0; 3]);
        assert_eq!(f.owned_flat().len(), 9);
        assert_eq!(f.flat()[6..9], [9.0; 3]);
    }

    #[test]
    #[should_panic(expected = "one value per local node")]
    fn a_field_of_the_wrong_length_is_refused() {
        NodeField::from_vec(Layout::serial(3), vec![0.0; 2]);
    }
}
