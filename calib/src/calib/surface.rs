//! The posed robot model as registration sees it: triangles in the model frame, sampled into
//! surface points (with normals and the triangle they lie on) and indexed by a k-d tree.

use std::sync::Arc;

use nalgebra::{Isometry3, Point3, Unit, Vector3};
use rayon::prelude::*;

use super::kdtree::KdTree;
use crate::model::TriMesh;

/// One link's mesh posed in the model frame at the measured joints.
#[derive(Debug, Clone)]
pub struct PosedPart {
    /// URDF link name (for reports).
    pub link: String,
    /// Movable joints between the model root and this link (base links 0, shoulder 1, upper
    /// arm 2, …): kinematic error grows along the chain, so registration trusts low depths most.
    pub chain_depth: usize,
    /// `model_from_link` at the measured joints (model = URDF root link).
    pub model_from_link: Isometry3<f64>,
    /// The link's mesh, vertices in metres in the link frame.
    pub mesh: Arc<TriMesh>,
}

impl PosedPart {
    /// The link's mesh vertices in the model frame.
    pub fn vertices_in_model(&self) -> Vec<Point3<f64>> {
        self.mesh
            .vertices
            .iter()
            .map(|p| self.model_from_link * p)
            .collect()
    }

    /// The link's mesh in the model frame.
    pub fn mesh_in_model(&self) -> TriMesh {
        TriMesh {
            vertices: self.vertices_in_model(),
            triangles: self.mesh.triangles.clone(),
        }
    }
}

/// The robot posed at the measured joints: every link with geometry, in the model frame.
#[derive(Debug, Clone, Default)]
pub struct PosedModel {
    /// All links with geometry (the ones not used for fitting still explain scan points).
    pub parts: Vec<PosedPart>,
    /// The chain joints in chain order: joint `i` moves every part of chain depth > `i`.
    /// Registration estimates the fitted links' displacements by their origin errors (unless
    /// `link_axes` describes them); empty when unknown (then the links are trusted).
    pub joints: Vec<PosedJoint>,
    /// Where the flange is at the measured joints, model frame; `None` when unknown. An
    /// eye-in-hand camera rides on it (see `RegisterOptions::max_camera_flange_distance_m`).
    pub model_from_flange: Option<Isometry3<f64>>,
    /// UR arms posed by a controller's DH set: the calibrated joint axes (model frame, entry `k − 1` for joint `k`, see
    /// [`RobotModel::dh_axes`](crate::model::RobotModel::dh_axes)). The link of chain depth `k`
    /// is on axis `k − 1`, but how far along and how far turned about it the axes cannot tell;
    /// registration estimates that. `None`: the links are posed by the nominal model, and
    /// per-joint origin errors at `joints` describe how they may be off.
    pub link_axes: Option<Vec<handeye_hal::ur_dh::Line>>,
    /// `model_from_link` of each chain depth's link at the measured joints (entry 0 the root,
    /// entry `d` the link chain joint `d − 1` moves, see
    /// [`RobotModel::chain_link_frames`](crate::model::RobotModel::chain_link_frames)): the
    /// frames a link's housing offset is fixed in, the same in every view of one arm.
    pub chain_link_frames: Vec<Isometry3<f64>>,
}

/// A chain joint of the posed model.
#[derive(Debug, Clone, Copy)]
pub struct PosedJoint {
    /// `model_from_joint` at the measured joints: the frame after the joint's nominal origin,
    /// before its motion (see [`RobotModel::joint_frames`](crate::model::RobotModel::joint_frames)).
    pub model_from_joint: Isometry3<f64>,
    /// Its axis in the joint frame.
    pub axis: Unit<Vector3<f64>>,
    /// Its nominal origin in its parent link (the link vector leading to it).
    pub parent_from_joint: Isometry3<f64>,
}

/// A triangle of the posed model (model frame, metres).
#[derive(Debug, Clone, Copy)]
pub struct Triangle {
    pub a: Point3<f64>,
    pub b: Point3<f64>,
    pub c: Point3<f64>,
    /// Outward unit normal (counter-clockwise winding seen from outside).
    pub n: Vector3<f64>,
}

impl Triangle {
    /// Closest point of the triangle to `p` (Ericson, Real-Time Collision Detection 5.1.5).
    pub fn closest_point(&self, p: &Point3<f64>) -> Point3<f64> {
        let (a, b, c) = (self.a, self.b, self.c);
        let ab = b - a;
        let ac = c - a;
        let ap = p - a;
        let d1 = ab.dot(&ap);
        let d2 = ac.dot(&ap);
        if d1 <= 0.0 && d2 <= 0.0 {
            return a;
        }
        let bp = p - b;
        let d3 = ab.dot(&bp);
        let d4 = ac.dot(&bp);
        if d3 >= 0.0 && d4 <= d3 {
            return b;
        }
        let vc = d1 * d4 - d3 * d2;
        if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
            return a + ab * (d1 / (d1 - d3));
        }
        let cp = p - c;
        let d5 = ab.dot(&cp);
        let d6 = ac.dot(&cp);
        if d6 >= 0.0 && d5 <= d6 {
            return c;
        }
        let vb = d5 * d2 - d1 * d6;
        if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
            return a + ac * (d2 / (d2 - d6));
        }
        let va = d3 * d6 - d5 * d4;
        if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
            return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
        }
        let denom = 1.0 / (va + vb + vc);
        a + ab * (vb * denom) + ac * (vc * denom)
    }
}

/// Most scoring samples ([`ModelSurface::coarse`]) kept; beyond it they are thinned evenly.
const MAX_COARSE_SAMPLES: usize = 3000;

/// A surface sample: position and normal in the model frame.
#[derive(Debug, Clone, Copy)]
pub struct Sample {
    pub p: Point3<f64>,
    pub n: Vector3<f64>,
    pub tri: u32,
    pub depth: u8,
    /// In a concave corner where a time-of-flight camera's range is biased by multipath (see
    /// `ModelSurface::mark_multipath`): the fit does not use scan points there.
    pub biased: bool,
}

/// Smallest cosine between a surface's normal and the direction to another surface for the
/// two to face each other (10° above its plane): points of one plane never face each other.
const FACING_COS: f64 = 0.17;

/// Spacing of the surface probes [`ModelSurface::mark_multipath`] looks for facing surface
/// among, metres: fine against a clearance of centimetres.
const PROBE_SPACING_M: f64 = 0.008;

/// The sampled posed model.
#[derive(Debug)]
pub struct ModelSurface {
    pub triangles: Vec<Triangle>,
    /// Dense samples of every part (the k-d tree's points, same order).
    pub(crate) samples: Vec<Sample>,
    pub(crate) tree: KdTree,
    /// Sparse samples of parts with `chain_depth <= fit_depth`, for hypothesis scoring.
    pub(crate) coarse: Vec<Sample>,
    /// Chain depth up to which parts are fitted.
    pub(crate) fit_depth: usize,
}

impl ModelSurface {
    /// Samples the posed model: `spacing_m` between samples on fitted parts (twice that on the
    /// others, which only explain scan points), `coarse_spacing_m` for the scoring set.
    pub fn new(
        model: &PosedModel,
        fit_depth: usize,
        spacing_m: f64,
        coarse_spacing_m: f64,
    ) -> Self {
        // Deeper than the deepest part fits nothing more (`usize::MAX` = every link).
        let fit_depth = fit_depth.min(model.parts.iter().map(|p| p.chain_depth).max().unwrap_or(0));
        let mut triangles = Vec::new();
        let mut samples = Vec::new();
        let mut coarse = Vec::new();
        // Deterministic low-discrepancy barycentric sampling (R2 sequence).
        let (g1, g2) = (0.754_877_666_246_692_7, 0.569_840_290_998_053_2);
        let mut seq = 0u64;
        for part in &model.parts {
            let fitted = part.chain_depth <= fit_depth;
            let area_per_sample = if fitted {
                spacing_m * spacing_m
            } else {
                4.0 * spacing_m * spacing_m
            };
            let area_per_coarse = coarse_spacing_m * coarse_spacing_m;
            let depth = part.chain_depth.min(255) as u8;
            let (mut acc, mut acc_c) = (0.5, 0.5);
            for t in &part.mesh.triangles {
                let Some([a, b, c]) = t
                    .iter()
                    .map(|&i| {
                        part.mesh
                            .vertices
                            .get(i as usize)
                            .map(|v| part.model_from_link * v)
                    })
                    .collect::<Option<Vec<_>>>()
                    .and_then(|v| <[Point3<f64>; 3]>::try_from(v).ok())
                else {
                    continue;
                };
                let cr = (b - a).cross(&(c - a));
                let area2 = cr.norm();
                if area2.is_nan() || area2 <= 1e-14 {
                    continue;
                }
                let n = cr / area2;
                let area = 0.5 * area2;
                let tri = triangles.len() as u32;
                triangles.push(Triangle { a, b, c, n });
                let mut emit = |count: &mut f64, per: f64, out: &mut Vec<Sample>| {
                    *count += area / per;
                    while *count >= 1.0 {
                        *count -= 1.0;
                        seq += 1;
                        let (mut r1, mut r2) =
                            ((seq as f64 * g1).fract(), (seq as f64 * g2).fract());
                        if r1 + r2 > 1.0 {
                            r1 = 1.0 - r1;
                            r2 = 1.0 - r2;
                        }
                        let p = a + (b - a) * r1 + (c - a) * r2;
                        out.push(Sample {
                            p,
                            n,
                            tri,
                            depth,
                            biased: false,
                        });
                    }
                };
                emit(&mut acc, area_per_sample, &mut samples);
                if fitted {
                    emit(&mut acc_c, area_per_coarse, &mut coarse);
                }
            }
        }
        // Big robots: coarser scoring samples, so hypothesis scoring costs the same for all.
        if coarse.len() > MAX_COARSE_SAMPLES {
            let step = coarse.len() as f64 / MAX_COARSE_SAMPLES as f64;
            coarse = (0..MAX_COARSE_SAMPLES)
                .map(|k| coarse[(k as f64 * step) as usize])
                .collect();
        }
        let pts: Vec<Point3<f32>> = samples.iter().map(|s| s.p.cast::<f32>()).collect();
        let tree = KdTree::new(&pts);
        ModelSurface {
            triangles,
            samples,
            tree,
            coarse,
            fit_depth,
        }
    }

    /// Marks the fitted samples where a time-of-flight camera's range is biased long by
    /// multipath: within `clearance_m` of other model surface that faces them and that they
    /// face (a concave corner: between links), or of the plane the robot stands on (horizontal,
    /// through the base's lowest point: the base's foot). Light bounced off that surface comes
    /// back late; on open and convex surface nothing faces the sample.
    pub(crate) fn mark_multipath(&mut self, clearance_m: f64) {
        let cell = |p: &Point3<f64>, size: f64| {
            [
                (p.x / size).floor() as i64,
                (p.y / size).floor() as i64,
                (p.z / size).floor() as i64,
            ]
        };
        // Probes: one sample per small cell and normal octant (the samples there share its
        // verdict), hashed by clearance cells.
        let probe_key = |s: &Sample| {
            (
                cell(&s.p, PROBE_SPACING_M),
                [s.n.x > 0.0, s.n.y > 0.0, s.n.z > 0.0],
            )
        };
        let mut probe_of = std::collections::HashMap::new();
        let mut probes: Vec<(Point3<f64>, Vector3<f64>)> = Vec::new();
        let mut near: std::collections::HashMap<[i64; 3], Vec<usize>> =
            std::collections::HashMap::new();
        for s in &self.samples {
            probe_of.entry(probe_key(s)).or_insert_with(|| {
                near.entry(cell(&s.p, clearance_m))
                    .or_default()
                    .push(probes.len());
                probes.push((s.p, s.n));
                probes.len() - 1
            });
        }
        let floor = self
            .samples
            .iter()
            .filter(|s| s.depth == 0)
            .map(|s| s.p.z)
            .fold(f64::INFINITY, f64::min);
        let facing = |p: &Point3<f64>, n: &Vector3<f64>, q: &Point3<f64>, m: &Vector3<f64>| {
            let d = q - p;
            let dist = d.norm();
            dist > 1e-4
                && dist <= clearance_m
                && n.dot(&d) > FACING_COS * dist
                && -m.dot(&d) > FACING_COS * dist
        };
        let up = Vector3::z();
        let biased: Vec<bool> = probes
            .par_iter()
            .map(|(p, n)| {
                // The floor: its nearest facing points lie below the probe, out along its
                // normal's horizontal part.
                let h = p.z - floor;
                if h > 1e-4 && h <= clearance_m {
                    let out = Vector3::new(n.x, n.y, 0.0)
                        .try_normalize(1e-9)
                        .unwrap_or_else(Vector3::x);
                    let foot = Point3::new(p.x, p.y, floor);
                    if (0..=8)
                        .any(|k| facing(p, n, &(foot + out * (clearance_m * k as f64 / 8.0)), &up))
                    {
                        return true;
                    }
                }
                let c = cell(p, clearance_m);
                (-1..=1).any(|i| {
                    (-1..=1).any(|j| {
                        (-1..=1).any(|k| {
                            near.get(&[c[0] + i, c[1] + j, c[2] + k]).is_some_and(|v| {
                                v.iter().any(|&o| facing(p, n, &probes[o].0, &probes[o].1))
                            })
                        })
                    })
                })
            })
            .collect();
        let fit_depth = self.fit_depth;
        for s in &mut self.samples {
            s.biased = s.depth as usize <= fit_depth
                && probe_of.get(&probe_key(s)).is_some_and(|&o| biased[o]);
        }
    }

    /// Nearest surface sample to `p` (model frame) within `max_dist_m`.
    #[inline]
    pub fn nearest(&self, p: &Point3<f64>, max_dist_m: f64) -> Option<&Sample> {
        self.nearest_with_distance(p, max_dist_m).map(|(s, _)| s)
    }

    /// [`Self::nearest`] and its distance, metres.
    #[inline]
    pub(crate) fn nearest_with_distance(
        &self,
        p: &Point3<f64>,
        max_dist_m: f64,
    ) -> Option<(&Sample, f64)> {
        self.tree
            .nearest([p.x as f32, p.y as f32, p.z as f32], max_dist_m as f32)
            .map(|(i, d2)| (&self.samples[i], f64::from(d2).sqrt()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The toy arm's base (a cylinder on the floor) under its shoulder: the base's wall is
    /// biased within the clearance of the floor and not above it, the rim of its top where the
    /// shoulder stands on it and the shoulder's wall just above that are biased, open surface
    /// is not.
    #[test]
    fn multipath_marks_the_concave_corners_only() {
        let mut s = ModelSurface::new(
            &crate::calib::testutil::toy_robot(&[0.0; 3]),
            2,
            0.002,
            0.012,
        );
        assert!(s.samples.iter().all(|x| !x.biased));
        s.mark_multipath(0.03);
        let share = |f: &dyn Fn(&Sample) -> bool| {
            let v: Vec<&Sample> = s.samples.iter().filter(|x| f(x)).collect();
            assert!(v.len() > 20, "{} samples", v.len());
            v.iter().filter(|x| x.biased).count() as f64 / v.len() as f64
        };
        let wall = |x: &Sample| x.depth == 0 && x.n.z.abs() < 0.1;
        let foot = share(&|x| wall(x) && x.p.z < 0.015);
        let open_wall = share(&|x| wall(x) && (0.04..0.06).contains(&x.p.z));
        let rim = share(&|x| {
            x.depth == 0 && x.n.z > 0.9 && x.p.z > 0.09 && x.p.coords.xy().norm() > 0.064
        });
        let shoulder_foot = share(&|x| {
            x.depth == 1
                && x.n.z.abs() < 0.1
                && (0.1..0.115).contains(&x.p.z)
                && x.p.coords.xy().norm() < 0.061
        });
        eprintln!(
            "foot {foot:.2} open wall {open_wall:.2} rim {rim:.2} shoulder foot {shoulder_foot:.2}"
        );
        assert!(foot > 0.9 && rim > 0.9 && shoulder_foot > 0.9);
        assert!(open_wall < 0.05);
        // Deeper than the fitted links nothing is marked (they give no correspondences).
        assert!(s.samples.iter().filter(|x| x.depth > 2).all(|x| !x.biased));
    }

    #[test]
    fn closest_point_on_triangle_regions() {
        let t = Triangle {
            a: Point3::new(0.0, 0.0, 0.0),
            b: Point3::new(1.0, 0.0, 0.0),
            c: Point3::new(0.0, 1.0, 0.0),
            n: Vector3::z(),
        };
        let q = t.closest_point(&Point3::new(0.2, 0.2, 0.7));
        assert!((q - Point3::new(0.2, 0.2, 0.0)).norm() < 1e-12);
        let q = t.closest_point(&Point3::new(-1.0, -1.0, 0.0));
        assert!((q - t.a).norm() < 1e-12);
        let q = t.closest_point(&Point3::new(1.0, 1.0, 0.0));
        assert!((q - Point3::new(0.5, 0.5, 0.0)).norm() < 1e-12);
        let q = t.closest_point(&Point3::new(0.5, -2.0, 1.0));
        assert!((q - Point3::new(0.5, 0.0, 0.0)).norm() < 1e-12);
    }
}
