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
    /// Children at node indices `left` and `right`.
    Split { left: u32, right: u32 },
}

/// Static k-d tree; `nearest` returns the index the point had in the slice given to [`KdTree::new`].
#[derive(Debug, Clone)]
pub(crate) struct KdTree {
    nodes: Vec<Node>,
    /// Per node, the bounding box `[lo, hi]` of its points (same index as `nodes`).
    boxes: Vec<[[f32; 3]; 2]>,
    points: Vec<[f32; 3]>,
    ids: Vec<u32>,
}

impl KdTree {
    /// Builds the tree over `points` (any frame; queries must use the same frame).
    pub(crate) fn new(points: &[Point3<f32>]) -> Self {
        let mut ids: Vec<u32> = (0..points.len() as u32).collect();
        let mut nodes = Vec::with_capacity(2 * points.len() / LEAF_SIZE + 1);
        let mut boxes = Vec::with_capacity(nodes.capacity());
        if !points.is_empty() {
            build(points, &mut ids, 0, &mut nodes, &mut boxes);
        }
        let pts = ids
            .iter()
            .map(|&i| points[i as usize].coords.into())
            .collect();
        KdTree {
            nodes,
            boxes,
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
    /// A subtree is skipped when the bounding box of its points is farther than the best
    /// point so far. The boxes are the points' own (not the cells the splits cut), which on
    /// points sampled from surfaces are far smaller: a query that finds nothing within the
    /// radius, a scan point off the model, visits only the few subtrees whose points come
    /// near it.
    pub(crate) fn nearest(&self, q: [f32; 3], max_dist: f32) -> Option<(usize, f32)> {
        let root = self.boxes.first()?;
        let mut best_d2 = max_dist * max_dist;
        let mut best: Option<u32> = None;
        // (node, squared distance to its box)
        let mut stack: [(u32, f32); 64] = [(0, 0.0); 64];
        stack[0] = (0, box_dist2(root, q));
        let mut sp = 1usize;
        while sp > 0 {
            sp -= 1;
            let (ni, bound) = stack[sp];
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
                Node::Split { left, right } => {
                    let dl = box_dist2(&self.boxes[left as usize], q);
                    let dr = box_dist2(&self.boxes[right as usize], q);
                    // The nearer child on top of the stack: searched first.
                    let (near, far) = if dl <= dr {
                        ((left, dl), (right, dr))
                    } else {
                        ((right, dr), (left, dl))
                    };
                    for (child, d2) in [far, near] {
                        if d2 < best_d2 && sp < stack.len() {
                            stack[sp] = (child, d2);
                            sp += 1;
                        }
                    }
                }
            }
        }
        best.map(|k| (self.ids[k as usize] as usize, best_d2))
    }
}

/// Squared distance from `q` to the box `[lo, hi]` (0 inside).
#[inline]
fn box_dist2(b: &[[f32; 3]; 2], q: [f32; 3]) -> f32 {
    let mut d2 = 0.0;
    for k in 0..3 {
        let d = (b[0][k] - q[k]).max(q[k] - b[1][k]).max(0.0);
        d2 += d * d;
    }
    d2
}

/// Builds the subtree over `ids` (at `offset` in the permuted arrays); returns its node.
fn build(
    points: &[Point3<f32>],
    ids: &mut [u32],
    offset: usize,
    nodes: &mut Vec<Node>,
    boxes: &mut Vec<[[f32; 3]; 2]>,
) -> u32 {
    let me = nodes.len() as u32;
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for &i in ids.iter() {
        let p = points[i as usize];
        for d in 0..3 {
            lo[d] = lo[d].min(p[d]);
            hi[d] = hi[d].max(p[d]);
        }
    }
    boxes.push([lo, hi]);
    if ids.len() <= LEAF_SIZE {
        nodes.push(Node::Leaf {
            start: offset as u32,
            end: (offset + ids.len()) as u32,
        });
        return me;
    }
    let dim = (0..3)
        .max_by(|&a, &b| (hi[a] - lo[a]).total_cmp(&(hi[b] - lo[b])))
        .unwrap_or(0);
    let mid = ids.len() / 2;
    ids.select_nth_unstable_by(mid, |&a, &b| {
        points[a as usize][dim].total_cmp(&points[b as usize][dim])
    });
    nodes.push(Node::Leaf { start: 0, end: 0 });
    let (l, r) = ids.split_at_mut(mid);
    let left = build(points, l, offset, nodes, boxes);
    let right = build(points, r, offset + mid, nodes, boxes);
    nodes[me as usize] = Node::Split { left, right };
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

    /// Points on a surface (a sphere shell, as the model's samples are on its triangles) and
    /// queries off it, many with nothing within the radius: the same answers as a brute-force
    /// search, `None` included.
    #[test]
    fn surface_points_and_misses_match_brute_force() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(11);
        let pts: Vec<Point3<f32>> = (0..20000)
            .map(|_| {
                let v = nalgebra::Vector3::new(
                    rng.random::<f32>() - 0.5,
                    rng.random::<f32>() - 0.5,
                    rng.random::<f32>() - 0.5,
                );
                Point3::from(v.normalize() * 0.3)
            })
            .collect();
        let tree = KdTree::new(&pts);
        let (mut hits, mut misses) = (0, 0);
        for _ in 0..2000 {
            let q = [
                rng.random::<f32>() - 0.5,
                rng.random::<f32>() - 0.5,
                rng.random::<f32>() - 0.5,
            ];
            let radius = 0.005 + 0.1 * rng.random::<f32>();
            let brute = pts
                .iter()
                .enumerate()
                .map(|(i, p)| (i, (p.coords - nalgebra::Vector3::from(q)).norm_squared()))
                .filter(|(_, d2)| *d2 < radius * radius)
                .min_by(|a, b| a.1.total_cmp(&b.1));
            let got = tree.nearest(q, radius);
            assert_eq!(
                got.map(|g| g.0),
                brute.map(|b| b.0),
                "query {q:?} radius {radius}"
            );
            if got.is_some() {
                hits += 1;
            } else {
                misses += 1;
            }
        }
        assert!(hits > 200 && misses > 200, "{hits} hits, {misses} misses");
    }
}
