//! A static 3-D k-d tree over `f32` points: nearest neighbour within a radius.
//!
//! Built once per registration over the sampled model surface (tens of thousands of points) and
//! queried for every scan point in every ICP iteration, so it is flat (no pointers), keeps points
//! in leaf order and answers a query without allocating.

use nalgebra::Point3;

const LEAF_SIZE: usize = 12;

#[derive(Debug, Clone, Copy)]
enum Node {
    /// Points `start..end` of the permuted arrays.
    Leaf { start: u32, end: u32 },
    /// Children at `left` and `left + 1`-th subtree index `right`.
    Split {
        dim: u8,
        value: f32,
        left: u32,
        right: u32,
    },
}

/// Static k-d tree; `nearest` returns the index the point had in the slice given to [`KdTree::new`].
#[derive(Debug, Clone)]
pub(crate) struct KdTree {
    nodes: Vec<Node>,
    points: Vec<[f32; 3]>,
    ids: Vec<u32>,
}

impl KdTree {
    /// Builds the tree over `points` (any frame; queries must use the same frame).
    pub(crate) fn new(points: &[Point3<f32>]) -> Self {
        let mut ids: Vec<u32> = (0..points.len() as u32).collect();
        let mut nodes = Vec::with_capacity(2 * points.len() / LEAF_SIZE + 1);
        if !points.is_empty() {
            build(points, &mut ids, 0, &mut nodes);
        }
        let pts = ids
            .iter()
            .map(|&i| points[i as usize].coords.into())
            .collect();
        KdTree {
            nodes,
            points: pts,
            ids,
        }
    }

    /// Number of points in the tree.
    #[cfg(test)]
    pub(crate) fn len(&self) -> usize {
        self.points.len()
    }

    /// The nearest point within `max_dist` of `q`: `(original index, squared distance)`.
    ///
    /// A subtree is skipped when the box around it (as far as the splits above it bound it)
    /// is farther than the best point so far: the box's squared distance is kept per
    /// dimension and updated at each split (Arya and Mount's incremental distance), which
    /// prunes far more than the last split's distance alone.
    pub(crate) fn nearest(&self, q: [f32; 3], max_dist: f32) -> Option<(usize, f32)> {
        if self.nodes.is_empty() {
            return None;
        }
        let mut best_d2 = max_dist * max_dist;
        let mut best: Option<u32> = None;
        // (node, squared distance to its box, the box's offset from q per dimension)
        let mut stack: [(u32, f32, [f32; 3]); 64] = [(0, 0.0, [0.0; 3]); 64];
        let mut sp = 1usize;
        while sp > 0 {
            sp -= 1;
            let (ni, bound, off) = stack[sp];
            if bound >= best_d2 {
                continue;
            }
            match self.nodes[ni as usize] {
                Node::Leaf { start, end } => {
                    for k in start as usize..end as usize {
                        let p = self.points[k];
                        let d = [p[0] - q[0], p[1] - q[1], p[2] - q[2]];
                        let d2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
                        if d2 < best_d2 {
                            best_d2 = d2;
                            best = Some(k as u32);
                        }
                    }
                }
                Node::Split {
                    dim,
                    value,
                    left,
                    right,
                } => {
                    let dim = dim as usize;
                    let diff = q[dim] - value;
                    let (near, far) = if diff < 0.0 {
                        (left, right)
                    } else {
                        (right, left)
                    };
                    let far_bound = bound - off[dim] * off[dim] + diff * diff;
                    let mut far_off = off;
                    far_off[dim] = diff;
                    if sp + 2 <= stack.len() {
                        stack[sp] = (far, far_bound, far_off);
                        stack[sp + 1] = (near, bound, off);
                        sp += 2;
                    }
                }
            }
        }
        best.map(|k| (self.ids[k as usize] as usize, best_d2))
    }
}

fn build(points: &[Point3<f32>], ids: &mut [u32], offset: usize, nodes: &mut Vec<Node>) -> u32 {
    let me = nodes.len() as u32;
    if ids.len() <= LEAF_SIZE {
        nodes.push(Node::Leaf {
            start: offset as u32,
            end: (offset + ids.len()) as u32,
        });
        return me;
    }
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for &i in ids.iter() {
        let p = points[i as usize];
        for d in 0..3 {
            lo[d] = lo[d].min(p[d]);
            hi[d] = hi[d].max(p[d]);
        }
    }
    let dim = (0..3)
        .max_by(|&a, &b| (hi[a] - lo[a]).total_cmp(&(hi[b] - lo[b])))
        .unwrap_or(0);
    let mid = ids.len() / 2;
    ids.select_nth_unstable_by(mid, |&a, &b| {
        points[a as usize][dim].total_cmp(&points[b as usize][dim])
    });
    let value = points[ids[mid] as usize][dim];
    nodes.push(Node::Leaf { start: 0, end: 0 });
    let (l, r) = ids.split_at_mut(mid);
    let left = build(points, l, offset, nodes);
    let right = build(points, r, offset + mid, nodes);
    nodes[me as usize] = Node::Split {
        dim: dim as u8,
        value,
        left,
        right,
    };
    me
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    #[test]
    fn nearest_matches_brute_force() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        let pts: Vec<Point3<f32>> = (0..5000)
            .map(|_| {
                Point3::new(
                    rng.random::<f32>(),
                    rng.random::<f32>(),
                    rng.random::<f32>(),
                )
            })
            .collect();
        let tree = KdTree::new(&pts);
        assert_eq!(tree.len(), 5000);
        for _ in 0..500 {
            let q = [
                rng.random::<f32>(),
                rng.random::<f32>(),
                rng.random::<f32>(),
            ];
            let brute = pts
                .iter()
                .enumerate()
                .map(|(i, p)| (i, (p.coords - nalgebra::Vector3::from(q)).norm_squared()))
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .expect("non-empty");
            let got = tree.nearest(q, 10.0).expect("found");
            assert_eq!(got.0, brute.0);
            // Radius limit is honoured.
            let limited = tree.nearest(q, brute.1.sqrt() * 0.5);
            assert!(limited.is_none());
        }
        assert!(KdTree::new(&[]).nearest([0.0; 3], 1.0).is_none());
    }
}
