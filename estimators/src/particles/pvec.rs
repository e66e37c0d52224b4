//! A persistent vector: a radix trie of `Arc` nodes (branching factor 16).
//!
//! Cloning is O(1) (one `Arc` clone of the root); writing an element copies the path to it,
//! O(log16 n) nodes of 16 pointers, and only when the path is shared. This is what lets the
//! particles of [`super::FastSlam`] share their maps after resampling: a resampled particle
//! is a clone of its parent's root, and the features it later updates are copied on write.
//!
//! Each node may also keep a [`Summary`] of its subtree (a bounding box of its features, say),
//! computed when a query first asks for it and forgotten when the subtree is written, so that
//! [`PVec::iter_where`] skips whole subtrees a query cannot want. Each element keeps its own
//! summary the same way, shared by every vector that shares the element.

use std::fmt::Debug;
use std::sync::{Arc, OnceLock};

const BITS: u32 = 4;
const WIDTH: usize = 1 << BITS;
const MASK: usize = WIDTH - 1;

/// What a node knows of the elements under it: `of` one element, `join`ed over a subtree.
/// A subtree whose summary a query rejects holds no element the query wants, so the summary
/// of a set must be rejected only when every element's summary would be.
pub(crate) trait Summary<T>: Clone + Debug + Send + Sync {
    /// The summary of no element.
    fn empty() -> Self;
    /// The summary of one element.
    fn of(value: &T) -> Self;
    /// Adds `other`'s elements to this summary.
    fn join(&mut self, other: &Self);
}

/// No summary: every query visits every element.
impl<T> Summary<T> for () {
    fn empty() -> Self {}
    fn of(_: &T) -> Self {}
    fn join(&mut self, _: &Self) {}
}

#[derive(Debug)]
enum Children<T, S> {
    Branch(Vec<Arc<Node<T, S>>>),
    Leaf(Vec<Option<Arc<Element<T, S>>>>),
}

/// An element with its own summary, computed on first use and forgotten when the element is
/// written: vectors that share the element share its summary too.
#[derive(Clone, Debug)]
struct Element<T, S> {
    value: T,
    summary: OnceLock<S>,
}

impl<T, S: Summary<T>> Element<T, S> {
    fn new(value: T) -> Self {
        Element {
            value,
            summary: OnceLock::new(),
        }
    }

    fn summary(&self) -> &S {
        self.summary.get_or_init(|| S::of(&self.value))
    }
}

#[derive(Debug)]
struct Node<T, S> {
    children: Children<T, S>,
    /// The subtree's summary, once a query asked for it; cleared on every write below.
    summary: OnceLock<S>,
}

impl<T, S: Clone> Clone for Node<T, S> {
    fn clone(&self) -> Self {
        let children = match &self.children {
            Children::Branch(children) => Children::Branch(children.clone()),
            Children::Leaf(values) => Children::Leaf(values.clone()),
        };
        Node {
            children,
            summary: self.summary.clone(),
        }
    }
}

impl<T, S> Node<T, S> {
    fn branch(children: Vec<Arc<Node<T, S>>>) -> Self {
        Node {
            children: Children::Branch(children),
            summary: OnceLock::new(),
        }
    }

    fn leaf() -> Self {
        Node {
            children: Children::Leaf(Vec::new()),
            summary: OnceLock::new(),
        }
    }
}

impl<T, S: Summary<T>> Node<T, S> {
    /// The subtree's summary, computed (and kept) on first use.
    fn summary(&self) -> &S {
        self.summary.get_or_init(|| {
            let mut summary = S::empty();
            match &self.children {
                Children::Branch(children) => {
                    for child in children {
                        summary.join(child.summary());
                    }
                }
                Children::Leaf(values) => {
                    for element in values.iter().flatten() {
                        summary.join(element.summary());
                    }
                }
            }
            summary
        })
    }
}

/// `Arc::make_mut` on a node that is about to change below: its summary is forgotten.
fn make_mut<T: Clone, S: Clone>(node: &mut Arc<Node<T, S>>) -> &mut Node<T, S> {
    let node = Arc::make_mut(node);
    node.summary.take();
    node
}

/// A persistent vector of optional elements (a removed element leaves a hole, so indices are
/// stable identifiers).
#[derive(Debug)]
pub(crate) struct PVec<T, S = ()> {
    root: Arc<Node<T, S>>,
    /// Number of slots (holes included).
    len: usize,
    /// Trie levels above the leaves.
    shift: u32,
}

impl<T, S> Clone for PVec<T, S> {
    fn clone(&self) -> Self {
        PVec {
            root: Arc::clone(&self.root),
            len: self.len,
            shift: self.shift,
        }
    }
}

impl<T, S> Default for PVec<T, S> {
    fn default() -> Self {
        PVec {
            root: Arc::new(Node::leaf()),
            len: 0,
            shift: 0,
        }
    }
}

impl<T: Clone, S: Summary<T>> PVec<T, S> {
    /// The element in slot `index`, if any.
    pub(crate) fn get(&self, index: usize) -> Option<&T> {
        if index >= self.len {
            return None;
        }
        let mut node = self.root.as_ref();
        let mut shift = self.shift;
        loop {
            match &node.children {
                Children::Branch(children) => {
                    node = children.get((index >> shift) & MASK)?.as_ref();
                    shift = shift.saturating_sub(BITS);
                }
                Children::Leaf(values) => {
                    return values.get(index & MASK)?.as_deref().map(|e| &e.value);
                }
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
            let old = std::mem::replace(&mut self.root, Arc::new(Node::branch(Vec::new())));
            self.root = Arc::new(Node::branch(vec![old]));
            self.shift += BITS;
        }
        self.len += 1;
        self.write(index, Some(Arc::new(Element::new(value))));
        index
    }

    /// Replaces slot `index` (which must exist) by `value` (`None`: a hole).
    pub(crate) fn set(&mut self, index: usize, value: Option<T>) {
        if index < self.len {
            self.write(index, value.map(|v| Arc::new(Element::new(v))));
        }
    }

    /// A mutable reference to the element in slot `index`, copying it (and its path) when
    /// shared with another vector.
    pub(crate) fn get_mut(&mut self, index: usize) -> Option<&mut T> {
        if index >= self.len {
            return None;
        }
        let mut node = make_mut(&mut self.root);
        let mut shift = self.shift;
        loop {
            match &mut node.children {
                Children::Branch(children) => {
                    let child = children.get_mut((index >> shift) & MASK)?;
                    node = make_mut(child);
                    shift = shift.saturating_sub(BITS);
                }
                Children::Leaf(values) => {
                    let element = Arc::make_mut(values.get_mut(index & MASK)?.as_mut()?);
                    element.summary.take();
                    return Some(&mut element.value);
                }
            }
        }
    }

    fn write(&mut self, index: usize, value: Option<Arc<Element<T, S>>>) {
        let mut node = make_mut(&mut self.root);
        let mut shift = self.shift;
        loop {
            match &mut node.children {
                Children::Branch(children) => {
                    let slot = (index >> shift) & MASK;
                    while children.len() <= slot {
                        let fresh = if shift == BITS {
                            Node::leaf()
                        } else {
                            Node::branch(Vec::new())
                        };
                        children.push(Arc::new(fresh));
                    }
                    node = make_mut(&mut children[slot]);
                    shift -= BITS;
                }
                Children::Leaf(values) => {
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
        collect(&self.root, 0, &|_: &S| true, &mut out);
        out.into_iter().map(|(slot, value, _)| (slot, value))
    }

    /// The occupied slots, in slot order, whose element's summary `wanted` accepts, with
    /// their elements and summaries; whole subtrees whose summary it rejects are skipped (see
    /// [`Summary`]).
    pub(crate) fn iter_where(&self, wanted: impl Fn(&S) -> bool) -> Vec<(usize, &T, &S)> {
        // Room for a leaf's worth: most queries want a few elements.
        let mut out = Vec::with_capacity(WIDTH);
        collect(&self.root, 0, &wanted, &mut out);
        out
    }
}

fn collect<'a, T, S: Summary<T>>(
    node: &'a Node<T, S>,
    base: usize,
    wanted: &impl Fn(&S) -> bool,
    out: &mut Vec<(usize, &'a T, &'a S)>,
) {
    match &node.children {
        Children::Branch(children) => {
            let span = subtree_span(node);
            for (k, child) in children.iter().enumerate() {
                if wanted(child.summary()) {
                    collect(child, base + k * span, wanted, out);
                }
            }
        }
        Children::Leaf(values) => {
            for (k, element) in values.iter().enumerate() {
                if let Some(element) = element {
                    let summary = element.summary();
                    if wanted(summary) {
                        out.push((base + k, &element.value, summary));
                    }
                }
            }
        }
    }
}

/// Slots under each child of a branch node.
fn subtree_span<T, S>(node: &Node<T, S>) -> usize {
    let mut depth = 0;
    let mut current = node;
    while let Children::Branch(children) = &current.children {
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
        let mut a: PVec<usize> = PVec::default();
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

    /// The range of the values under a node.
    #[derive(Clone, Debug)]
    struct Range(usize, usize);

    impl Summary<usize> for Range {
        fn empty() -> Self {
            Range(usize::MAX, 0)
        }
        fn of(value: &usize) -> Self {
            Range(*value, *value)
        }
        fn join(&mut self, other: &Self) {
            self.0 = self.0.min(other.0);
            self.1 = self.1.max(other.1);
        }
    }

    #[test]
    fn iter_where_matches_a_filter_after_writes_to_shared_copies() {
        let mut a: PVec<usize, Range> = PVec::default();
        for i in 0..700usize {
            a.push((i * 37) % 1000);
        }
        let query = |v: &PVec<usize, Range>, lo: usize, hi: usize| {
            let pruned: Vec<(usize, usize)> = v
                .iter_where(|r| r.0 <= hi && lo <= r.1)
                .into_iter()
                .map(|(k, x, _)| (k, *x))
                .collect();
            let filtered: Vec<(usize, usize)> = v
                .iter()
                .filter(|(_, x)| lo <= **x && **x <= hi)
                .map(|(k, x)| (k, *x))
                .collect();
            assert_eq!(pruned, filtered, "query {lo}..={hi}");
        };
        // Summaries computed, then the copy written: both must answer from their own values.
        query(&a, 100, 200);
        let mut b = a.clone();
        for i in (0..700).step_by(11) {
            *b.get_mut(i).unwrap() = 5000 + i;
        }
        b.set(4, None);
        b.push(150);
        for (lo, hi) in [(100, 200), (0, 50), (5000, 5300), (990, 999), (2000, 3000)] {
            query(&a, lo, hi);
            query(&b, lo, hi);
        }
        assert!(b.iter_where(|r| r.0 <= 5300 && 5000 <= r.1).len() >= 28);
        assert!(a.iter_where(|r| r.0 <= 5300 && 5000 <= r.1).is_empty());
    }
}
