//! Global (prior-free) coarse alignment.
//!
//! 1. Planes: 1-point RANSAC with grid normals finds the dominant planes (floor, table, mounting
//!    surface). A floor/table-mounted robot stands on one of them: the plane fixes two rotations
//!    and the height up to the thickness of a mounting plate.
//! 2. Position in the plane: generalized Hough transform. Scan points in a height band above the
//!    plane vote, for every yaw bin and every point of the model's base/shoulder outline in that
//!    band, for where the robot origin would be. A round base makes every yaw vote for the same
//!    centre, so the centre is found even where the yaw is not.
//! 3. Yaw (and the plate height): a sweep scoring the whole posed model (base, shoulder, upper
//!    arm at the measured joints) against the range image with [`super::verify`]'s projective
//!    test, so free-space violations count against a hypothesis.

use std::f64::consts::PI;

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rayon::prelude::*;

use super::range::RangeImage;
use super::surface::{ModelSurface, Sample};
use super::verify::{evidence, score, Tolerances};

/// A detected plane: unit normal `n` pointing towards the camera, `n·p + d = 0` (camera frame).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Plane {
    pub(crate) n: Vector3<f64>,
    pub(crate) d: f64,
}

/// A scan point with its grid normal (camera frame).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Oriented {
    pub(crate) p: Point3<f64>,
    pub(crate) n: Vector3<f64>,
}

/// Scan points on a coarse grid (about `target` of them) with normals over `radius_m`.
pub(crate) fn oriented_subsample(
    range: &RangeImage<'_>,
    target: usize,
    radius_m: f64,
) -> Vec<Oriented> {
    let n = range.points.len();
    let valid = range
        .points
        .iter()
        .step_by(97)
        .filter(|p| p.z > 0.0)
        .count()
        * 97;
    let stride = ((valid as f64 / target as f64).sqrt().floor() as usize).max(1);
    let w = range.cam.width;
    let idx: Vec<usize> = (0..range.cam.height)
        .step_by(stride)
        .flat_map(|v| (0..w).step_by(stride).map(move |u| v * w + u))
        .filter(|&i| i < n)
        .collect();
    idx.par_iter()
        .filter_map(|&i| {
            let p = range.point(i)?;
            let nn = range.normal(i, radius_m)?;
            Some(Oriented {
                p: p.cast::<f64>(),
                n: nn,
            })
        })
        .collect()
}

/// Up to `max_planes` dominant planes, each supported by at least `min_fraction` of `pts`.
pub(crate) fn find_planes(
    pts: &[Oriented],
    max_planes: usize,
    min_fraction: f64,
    seed: u64,
) -> Vec<Plane> {
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let mut remaining: Vec<usize> = (0..pts.len()).collect();
    let mut planes = Vec::new();
    let tol = 0.004;
    let cos_tol = 20f64.to_radians().cos();
    for _ in 0..max_planes {
        if remaining.len() < 100 {
            break;
        }
        let probe: Vec<usize> = (0..1500)
            .map(|_| remaining[rng.random_range(0..remaining.len())])
            .collect();
        let mut best: Option<(usize, Vector3<f64>, f64)> = None;
        for _ in 0..150 {
            let s = &pts[remaining[rng.random_range(0..remaining.len())]];
            let (n, d) = (s.n, -s.n.dot(&s.p.coords));
            let count = probe
                .iter()
                .filter(|&&k| {
                    let q = &pts[k];
                    (n.dot(&q.p.coords) + d).abs() < tol && n.dot(&q.n) > cos_tol
                })
                .count();
            if best.as_ref().is_none_or(|b| count > b.0) {
                best = Some((count, n, d));
            }
        }
        let Some((_, mut n, mut d)) = best else { break };
        // Least-squares refit on the inliers (twice).
        let mut inliers = Vec::new();
        for _ in 0..2 {
            inliers = remaining
                .iter()
                .copied()
                .filter(|&k| {
                    (n.dot(&pts[k].p.coords) + d).abs() < tol && n.dot(&pts[k].n) > cos_tol
                })
                .collect::<Vec<_>>();
            if inliers.len() < 3 {
                break;
            }
            let c = inliers
                .iter()
                .map(|&k| pts[k].p.coords)
                .sum::<Vector3<f64>>()
                / inliers.len() as f64;
            let mut cov = Matrix3::zeros();
            for &k in &inliers {
                let r = pts[k].p.coords - c;
                cov += r * r.transpose();
            }
            let eig = cov.symmetric_eigen();
            let imin = eig.eigenvalues.imin();
            let mut nn: Vector3<f64> = eig.eigenvectors.column(imin).into_owned();
            if nn.dot(&n) < 0.0 {
                nn = -nn;
            }
            n = nn;
            d = -n.dot(&c);
        }
        if (inliers.len() as f64) < min_fraction * pts.len() as f64 {
            break;
        }
        // Orient towards the camera (origin): signed distance of the origin is d.
        if d < 0.0 {
            n = -n;
            d = -d;
        }
        planes.push(Plane { n, d });
        let set: std::collections::HashSet<usize> = inliers.into_iter().collect();
        remaining.retain(|k| !set.contains(k));
    }
    planes
}

/// `camera_from_plane`: a frame with z along the plane normal and origin on the plane, below the
/// camera (x, y arbitrary but deterministic).
fn camera_from_plane(pl: &Plane) -> Isometry3<f64> {
    let z = pl.n;
    let helper = if z.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let x = helper.cross(&z).normalize();
    let y = z.cross(&x);
    let rot = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x, y, z]));
    let origin = -z * pl.d; // projection of the camera origin onto the plane
    Isometry3::from_parts(
        Translation3::from(origin),
        UnitQuaternion::from_rotation_matrix(&rot),
    )
}

/// Candidate `camera_from_model` poses, best first, from planes + Hough + yaw sweep.
pub(crate) fn hypotheses(
    range: &RangeImage<'_>,
    surface: &ModelSurface,
    pts: &[Oriented],
    planes: &[Plane],
    max_out: usize,
) -> Vec<(Isometry3<f64>, f64)> {
    let fit_depth = surface.fit_depth;
    // Outline of the base/shoulder in a height band (model frame: z up from the mounting face).
    let low: Vec<&Sample> = surface.samples.iter().filter(|s| s.depth <= 1).collect();
    if low.is_empty() {
        return Vec::new();
    }
    let ztop = low
        .iter()
        .map(|s| s.p.z)
        .fold(f64::NEG_INFINITY, f64::max)
        .min(0.30);
    let band = (0.025, 0.025 + 0.6 * (ztop - 0.025).max(0.02));
    let cell = 0.005;
    // Side walls only (top faces and horizontal internals would smear the votes).
    let mut outline: Vec<(i64, i64)> = low
        .iter()
        .filter(|s| s.p.z >= band.0 && s.p.z <= band.1 && s.n.z.abs() < 0.5)
        .map(|s| ((s.p.x / cell).round() as i64, (s.p.y / cell).round() as i64))
        .collect();
    outline.sort_unstable();
    outline.dedup();
    let keep = 160usize;
    let step = (outline.len() as f64 / keep as f64).max(1.0);
    let outline: Vec<(f64, f64)> = (0..outline.len().min(keep))
        .map(|k| outline[(k as f64 * step) as usize])
        .map(|(x, y)| (x as f64 * cell, y as f64 * cell))
        .collect();
    let radius = outline.iter().map(|o| o.0.hypot(o.1)).fold(0.0, f64::max);

    let tol = Tolerances {
        matched_m: 0.008,
        free_m: 0.015,
    };
    let mut all: Vec<(Isometry3<f64>, f64)> = Vec::new();
    for pl in planes {
        let cam_from_plane = camera_from_plane(pl);
        let plane_from_cam = cam_from_plane.inverse();
        let mut band_pts: Vec<(f64, f64)> = pts
            .iter()
            .map(|o| plane_from_cam * o.p)
            .filter(|q| q.z >= band.0 - 0.005 && q.z <= band.1 + 0.02)
            .map(|q| (q.x, q.y))
            .collect();
        if band_pts.len() < 20 {
            continue;
        }
        if band_pts.len() > 1500 {
            let step = band_pts.len() as f64 / 1500.0;
            band_pts = (0..1500)
                .map(|k| band_pts[(k as f64 * step) as usize])
                .collect();
        }
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for b in &band_pts {
            lo = [lo[0].min(b.0), lo[1].min(b.1)];
            hi = [hi[0].max(b.0), hi[1].max(b.1)];
        }
        let (x0, y0) = (lo[0] - radius - cell, lo[1] - radius - cell);
        let nx = (((hi[0] - lo[0] + 2.0 * radius) / cell).ceil() as usize + 3).min(1500);
        let ny = (((hi[1] - lo[1] + 2.0 * radius) / cell).ceil() as usize + 3).min(1500);
        let n_yaw = 36;
        let acc = (0..n_yaw)
            .into_par_iter()
            .fold(
                || vec![0u32; nx * ny],
                |mut acc, k| {
                    let a = 2.0 * PI * k as f64 / n_yaw as f64;
                    let (s, c) = a.sin_cos();
                    let rotated: Vec<(f64, f64)> = outline
                        .iter()
                        .map(|o| (c * o.0 - s * o.1, s * o.0 + c * o.1))
                        .collect();
                    for b in &band_pts {
                        for r in &rotated {
                            let ix = ((b.0 - r.0 - x0) / cell) as isize;
                            let iy = ((b.1 - r.1 - y0) / cell) as isize;
                            if ix >= 0 && iy >= 0 && (ix as usize) < nx && (iy as usize) < ny {
                                acc[iy as usize * nx + ix as usize] += 1;
                            }
                        }
                    }
                    acc
                },
            )
            .reduce(
                || vec![0u32; nx * ny],
                |mut a, b| {
                    a.iter_mut().zip(b).for_each(|(x, y)| *x += y);
                    a
                },
            );
        // 3×3 box filter, then peaks at least 4 cm apart.
        let mut smooth = vec![0u32; nx * ny];
        for iy in 1..ny.saturating_sub(1) {
            for ix in 1..nx.saturating_sub(1) {
                let mut s = 0;
                for dy in 0..3 {
                    for dx in 0..3 {
                        s += acc[(iy + dy - 1) * nx + ix + dx - 1];
                    }
                }
                smooth[iy * nx + ix] = s;
            }
        }
        let mut order: Vec<usize> = (0..nx * ny).filter(|&i| smooth[i] > 0).collect();
        order.sort_unstable_by(|&a, &b| smooth[b].cmp(&smooth[a]));
        let mut centres: Vec<(f64, f64)> = Vec::new();
        for i in order {
            let c = (
                x0 + (i % nx) as f64 * cell + 0.5 * cell,
                y0 + (i / nx) as f64 * cell + 0.5 * cell,
            );
            if centres.iter().all(|o| (o.0 - c.0).hypot(o.1 - c.1) > 0.025) {
                centres.push(c);
                if centres.len() >= 6 {
                    break;
                }
            }
        }
        // Yaw × height sweep for each centre.
        let n_sweep = 72;
        let heights = [0.0, 0.015];
        let jobs: Vec<(usize, usize, usize)> = (0..centres.len())
            .flat_map(|c| {
                (0..heights.len()).flat_map(move |h| (0..n_sweep).map(move |k| (c, h, k)))
            })
            .collect();
        let scored: Vec<(Isometry3<f64>, f64)> = jobs
            .par_iter()
            .map(|&(c, h, k)| {
                let yaw = 2.0 * PI * k as f64 / n_sweep as f64;
                let plane_from_model = Isometry3::from_parts(
                    Translation3::new(centres[c].0, centres[c].1, heights[h]),
                    UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw),
                );
                let pose = cam_from_plane * plane_from_model;
                let e = evidence(range, &surface.coarse, &pose, fit_depth, tol);
                (pose, score(&e))
            })
            .collect();
        all.extend(scored);
    }
    all.sort_by(|a, b| b.1.total_cmp(&a.1));
    // Non-maximum suppression: distinct poses only.
    let mut out: Vec<(Isometry3<f64>, f64)> = Vec::new();
    for (pose, s) in all {
        if s <= 0.0 {
            break;
        }
        let distinct = out.iter().all(|(o, _)| {
            let d = o.inverse() * pose;
            d.translation.vector.norm() > 0.02 || d.rotation.angle() > 12f64.to_radians()
        });
        if distinct {
            out.push((pose, s));
            if out.len() >= max_out {
                break;
            }
        }
    }
    out
}
