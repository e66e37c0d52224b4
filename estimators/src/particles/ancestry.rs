//! A particle's path: its pose at every recorded step, shared with its ancestors' after
//! resampling (a persistent list of `Arc`s), so that copying a particle is O(1) and the
//! particles' paths together cost memory only where they differ.
//!
//! A node holds the poses a particle recorded while it owned the node alone (between two
//! resamplings): a push appends in place when no other path shares the last node, and starts
//! a node only when one does, so a path costs an allocation per resampling, not per pose.

use std::sync::Arc;

/// Poses recorded in a row and the path before them.
#[derive(Debug)]
struct Node<P> {
    poses: Vec<P>,
    /// Poses recorded up to and including this node's.
    len: usize,
    before: Option<Arc<Node<P>>>,
}

/// The poses a particle recorded, oldest first; clones share their nodes.
#[derive(Clone, Debug)]
pub(crate) struct Ancestry<P> {
    last: Option<Arc<Node<P>>>,
}

impl<P> Default for Ancestry<P> {
    fn default() -> Self {
        Ancestry { last: None }
    }
}

impl<P: Copy> Ancestry<P> {
    /// Appends `pose`: to the last node when this path alone holds it, else in a new node.
    pub(crate) fn push(&mut self, pose: P) {
        if let Some(node) = self.last.as_mut().and_then(Arc::get_mut) {
            node.poses.push(pose);
            node.len += 1;
            return;
        }
        let before = self.last.take();
        let len = before.as_ref().map_or(0, |n| n.len) + 1;
        self.last = Some(Arc::new(Node {
            poses: vec![pose],
            len,
            before,
        }));
    }

    /// Number of recorded poses.
    pub(crate) fn len(&self) -> usize {
        self.last.as_ref().map_or(0, |n| n.len)
    }

    /// The recorded poses, oldest first.
    pub(crate) fn to_vec(&self) -> Vec<P> {
        let mut poses = Vec::with_capacity(self.len());
        let mut node = self.last.as_deref();
        while let Some(n) = node {
            poses.extend(n.poses.iter().rev());
            node = n.before.as_deref();
        }
        poses.reverse();
        poses
    }
}

impl<P> Drop for Node<P> {
    /// Frees the nodes before this one that no other path shares, one at a time: a recursive
    /// drop of a long path would overflow the stack. Paths may be dropped on several threads
    /// at once: a node whose other owner lets go at the same moment is freed by whichever
    /// thread drops it last, again one node at a time.
    fn drop(&mut self) {
        let mut next = self.before.take();
        while let Some(node) = next {
            match Arc::try_unwrap(node) {
                Ok(mut owned) => next = owned.before.take(),
                Err(_) => break,
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clones_share_the_past_and_diverge_after() {
        let mut parent = Ancestry::default();
        for i in 0..3 {
            parent.push(i);
        }
        let mut child = parent.clone();
        child.push(10);
        parent.push(20);
        assert_eq!(parent.to_vec(), vec![0, 1, 2, 20]);
        assert_eq!(child.to_vec(), vec![0, 1, 2, 10]);
        assert_eq!(child.len(), 4);
        drop(parent);
        assert_eq!(child.to_vec(), vec![0, 1, 2, 10]);
    }

    #[test]
    fn a_long_path_drops_without_overflowing_the_stack() {
        let mut path = Ancestry::default();
        for i in 0..1_000_000u32 {
            // A copy held across the push makes every pose a node of its own.
            let copy = path.clone();
            path.push(i);
            drop(copy);
        }
        let shared = path.clone();
        assert_eq!(shared.len(), 1_000_000);
        drop(path);
        drop(shared);
    }

    #[test]
    fn shared_paths_drop_on_two_threads_at_once() {
        for _ in 0..20 {
            let mut path = Ancestry::default();
            for i in 0..200_000u32 {
                // A copy held across the push makes every pose a node of its own.
                let copy = path.clone();
                path.push(i);
                drop(copy);
            }
            let copies: Vec<Ancestry<u32>> = (0..8).map(|_| path.clone()).collect();
            drop(path);
            let (left, right) = copies.split_at(4);
            let (left, right) = (left.to_vec(), right.to_vec());
            std::thread::scope(|scope| {
                scope.spawn(move || drop(left));
                scope.spawn(move || drop(right));
            });
        }
    }

    #[test]
    fn pushes_after_clones_keep_every_path_its_own() {
        let mut paths = vec![Ancestry::default()];
        let mut expected = vec![Vec::new()];
        for step in 0..200u32 {
            if step % 7 == 3 {
                // "Resampling": every path replaced by a copy of one of them.
                let chosen: Vec<usize> =
                    (0..4).map(|k| (k * step as usize) % paths.len()).collect();
                paths = chosen.iter().map(|&i| paths[i].clone()).collect();
                expected = chosen.iter().map(|&i| expected[i].clone()).collect();
            }
            for (k, (path, poses)) in paths.iter_mut().zip(&mut expected).enumerate() {
                path.push(step * 10 + k as u32);
                poses.push(step * 10 + k as u32);
            }
        }
        for (path, poses) in paths.iter().zip(&expected) {
            assert_eq!(&path.to_vec(), poses);
            assert_eq!(path.len(), poses.len());
        }
    }
}
