//! A persistent vector: a radix trie of `Arc` nodes (branching factor 16).
//!
//! Cloning is O(1) (one `Arc` clone of the root); writing an element copies the path to it,
//! O(log16 n) nodes of 16 pointers, and only when the path is shared. This is what lets the
//! particles of [`super::FastSlam`] share their maps after resampling: a resampled particle
//! is a clone of its parent's root, and the features it later updates are copied on write.

use std::sync::Arc;

const BITS: u32 = 4;
const WIDTH: usize = 1 << BITS;
const MASK: usize = WIDTH - 1;

#[derive(Debug)]
enum Node<T> {
    Branch(Vec<Arc<Node<T>>>),
    Leaf(Vec<Option<Arc<T>>>),
}

impl<T> Clone for Node<T> {
    fn clone(&self) -> Self {
        match self {
            Node::Branch(children) => Node::Branch(children.clone()),
            Node::Leaf(values) => Node::Leaf(values.clone()),
        }
    }
}

/// A persistent vector of optional elements (a removed element leaves a hole, so indices are
/// stable identifiers).
#[derive(Debug)]
pub(crate) struct PVec<T> {
    root: Arc<Node<T>>,
    /// Number of slots (holes included).
    len: usize,
    /// Trie levels above the leaves.
    shift: u32,
}

impl<T> Clone for PVec<T> {
    fn clone(&self) -> Self {
        PVec {
            root: Arc::clone(&self.root),
            len: self.len,
            shift: self.shift,
        }
    }
}

impl<T> Default for PVec<T> {
    fn default() -> Self {
        PVec {
            root: Arc::new(Node::Leaf(Vec::new())),
            len: 0,
            shift: 0,
        }
    }
}

impl<T: Clone> PVec<T> {
    /// The element in slot `index`, if any.
    pub(crate) fn get(&self, index: usize) -> Option<&T> {
        if index >= self.len {
            return None;
        }
        let mut node = self.root.as_ref();
        let mut shift = self.shift;
        loop {
            match node {
                Node::Branch(children) => {
                    node = children.get((index >> shift) & MASK)?.as_ref();
                    shift = shift.saturating_sub(BITS);
                }
                Node::Leaf(values) => return values.get(index & MASK)?.as_deref(),
            }
        }
    }

    /// Capacity of a trie with `shift`.
    fn capacity(shift: u32) -> usize {
        1usize << (shift + BITS)
    }

    /// Appends an element; returns its slot.
    pub(crate) fn push(&mut self, value: T) -> usize {
        let index = self.len;
        if index >= Self::capacity(self.shift) {
            let old = std::mem::replace(&mut self.root, Arc::new(Node::Branch(Vec::new())));
            self.root = Arc::new(Node::Branch(vec![old]));
            self.shift += BITS;
        }
        self.len += 1;
        self.write(index, Some(Arc::new(value)));
        index
    }

    /// Replaces slot `index` (which must exist) by `value` (`None`: a hole).
    pub(crate) fn set(&mut self, index: usize, value: Option<T>) {
        if index < self.len {
            self.write(index, value.map(Arc::new));
        }
    }

    /// A mutable reference to the element in slot `index`, copying it (and its path) when
    /// shared with another vector.
    pub(crate) fn get_mut(&mut self, index: usize) -> Option<&mut T> {
        if index >= self.len {
            return None;
        }
        let mut node = Arc::make_mut(&mut self.root);
        let mut shift = self.shift;
        loop {
            match node {
                Node::Branch(children) => {
                    let child = children.get_mut((index >> shift) & MASK)?;
                    node = Arc::make_mut(child);
                    shift = shift.saturating_sub(BITS);
                }
                Node::Leaf(values) => {
                    return values.get_mut(index & MASK)?.as_mut().map(Arc::make_mut);
                }
            }
        }
    }

    fn write(&mut self, index: usize, value: Option<Arc<T>>) {
        let mut node = Arc::make_mut(&mut self.root);
        let mut shift = self.shift;
        loop {
            match node {
                Node::Branch(children) => {
                    let slot = (index >> shift) & MASK;
                    while children.len() <= slot {
                        let fresh = if shift == BITS {
                            Node::Leaf(Vec::new())
                        } else {
                            Node::Branch(Vec::new())
                        };
                        children.push(Arc::new(fresh));
                    }
                    node = Arc::make_mut(&mut children[slot]);
                    shift -= BITS;
                }
                Node::Leaf(values) => {
                    let slot = index & MASK;
                    while values.len() <= slot {
                        values.push(None);
                    }
                    values[slot] = value;
                    return;
                }
            }
        }
    }

    /// Occupied slots with their elements, in slot order.
    pub(crate) fn iter(&self) -> impl Iterator<Item = (usize, &T)> {
        let mut out = Vec::new();
        collect(&self.root, 0, &mut out);
        out.into_iter()
    }
}

fn collect<'a, T>(node: &'a Node<T>, base: usize, out: &mut Vec<(usize, &'a T)>) {
    match node {
        Node::Branch(children) => {
            let span = subtree_span(node);
            for (k, child) in children.iter().enumerate() {
                collect(child, base + k * span, out);
            }
        }
        Node::Leaf(values) => {
            for (k, value) in values.iter().enumerate() {
                if let Some(v) = value {
                    out.push((base + k, v.as_ref()));
                }
            }
        }
    }
}

/// Slots under each child of a branch node.
fn subtree_span<T>(node: &Node<T>) -> usize {
    let mut depth = 0;
    let mut current = node;
    while let Node::Branch(children) = current {
        depth += 1;
        match children.first() {
            Some(child) => current = child,
            None => break,
        }
    }
    WIDTH.pow(depth)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn behaves_like_a_vector_and_shares_unchanged_slots() {
        let mut a = PVec::default();
        let mut reference = Vec::new();
        for i in 0..1000usize {
            assert_eq!(a.push(i), i);
            reference.push(Some(i));
        }
        let mut b = a.clone();
        for i in (0..1000).step_by(7) {
            *b.get_mut(i).unwrap() += 1;
        }
        b.set(3, None);
        for (i, value) in reference.iter().enumerate() {
            assert_eq!(a.get(i), value.as_ref(), "a[{i}]");
            let expected = if i == 3 {
                None
            } else if i % 7 == 0 {
                Some(i + 1)
            } else {
                Some(i)
            };
            assert_eq!(b.get(i).copied(), expected, "b[{i}]");
        }
        let listed: Vec<usize> = b.iter().map(|(k, _)| k).collect();
        assert_eq!(listed.len(), 999);
        assert!(!listed.contains(&3));
        assert!(listed.windows(2).all(|w| w[0] < w[1]));
        assert_eq!(a.get(1000), None);
        // An untouched slot is the same allocation in both.
        assert!(std::ptr::eq(a.get(5).unwrap(), b.get(5).unwrap()));
    }
}
