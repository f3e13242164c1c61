//! Global (prior-free) coarse alignment.
//!
//! 1. Planes: 1-point RANSAC with grid normals finds the dominant planes (floor, table, mounting
//!    surface). A floor/table-mounted robot stands on one of them: the plane fixes two rotations
//!    and the height up to the thickness of a mounting plate. When the scan shows no plane the
//!    robot could stand on, mounting planes are derived from the axes of its visible cylinders
//!    and the heights at which its surfaces appear ([`derived_planes`]).
//! 2. Position and yaw in the plane: a Hough vote over (x, y, yaw). Each side-facing scan point
//!    above the plane pairs with the side-facing samples of the posed model (base, shoulder,
//!    upper arm at the measured joints) at about its height; the horizontal normals give the
//!    pair's yaw, the positions the robot origin. The whole visible robot votes, so a base
//!    hidden under the shoulder (camera above the robot) is still found.
//! 3. The strongest peaks (and the plate height) are scored on the whole posed model against
//!    the range image with [`super::verify`]'s projective test, so free-space violations count
//!    against a hypothesis.
//! 4. For a camera fixed in the cell, which sees the whole arm from afar through noisier depth,
//!    [`objects`] adds hypotheses from the clumps of scan points standing on each plane.

use std::f64::consts::PI;

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rayon::prelude::*;

use super::range::RangeImage;
use super::surface::{ModelSurface, Sample};
use super::verify::{evidence, score, Tolerances};

pub(crate) mod objects;

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
    let idx: Vec<usize> = range.grid(target, 97).collect();
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

/// How far a scan point may lie from a plane and be on it, for scans as precise as the
/// registration's tuning (metres); widened with the scan's noise by the caller. A fixed 4 mm on
/// a consumer RGB-D camera's table 1.3 m away keeps a thin slab of its bumps, whose fit is
/// tilted by 2–8° from frame to frame; widened, 2–3°.
pub(crate) const PLANE_TOLERANCE_M: f64 = 0.004;

/// Up to `max_planes` dominant planes, each supported by at least `min_fraction` of `pts`
/// within `tol` metres.
pub(crate) fn find_planes(
    pts: &[Oriented],
    max_planes: usize,
    min_fraction: f64,
    seed: u64,
    tol: f64,
) -> Vec<Plane> {
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let mut remaining: Vec<usize> = (0..pts.len()).collect();
    let mut planes = Vec::new();
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

/// The scan's planes (up to 10, each with ≥ 1 % of the points) with the number of scan points
/// behind each, fewest first. The camera cannot see behind a floor, table or wall the robot is
/// mounted on (except past its edge), while a flat patch on the robot's own links or on clutter
/// has the floor behind it. A view filled by a big robot can make such patches (tangent planes
/// of its big cylinders, within the plane tolerance `tol_m`) larger than the floor.
pub(crate) fn support_planes(pts: &[Oriented], seed: u64, tol_m: f64) -> Vec<(usize, Plane)> {
    let behind = |pl: &Plane| {
        pts.iter()
            .filter(|o| pl.n.dot(&o.p.coords) + pl.d < -0.02)
            .count()
    };
    let mut ranked: Vec<(usize, Plane)> = find_planes(pts, 10, 0.01, seed, tol_m)
        .into_iter()
        .map(|pl| (behind(&pl), pl))
        .collect();
    // Stable: equally plausible planes keep the order of their support.
    ranked.sort_by_key(|r| r.0);
    tracing::debug!(
        planes = ?ranked.iter().map(|(b, p)| (*b, p.n.as_slice().to_vec(), p.d)).collect::<Vec<_>>(),
        "support planes (points behind, normal, offset)"
    );
    ranked
}

/// Cylinder axes [`derived_planes`] takes as "up" directions (each both ways).
const DERIVED_AXES: usize = 3;
/// Mounting heights [`derived_planes`] tries per "up" direction: clutter standing on the floor
/// shapes the height histogram too, and the best match can be 15 cm off while the right height
/// is the next peak.
const DERIVED_HEIGHTS: usize = 2;
/// Mounting heights [`derived_planes`] tries along one direction are at least this far apart.
const MIN_HEIGHTS_APART_M: f64 = 0.05;
/// How far the floor may lie below the face the robot stands on (a mounting plate), metres.
const PLATE_M: f64 = 0.03;
/// A scan point this close to one of the scan's planes (and facing the same way) lies on it.
const FLAT_TOLERANCE_M: f64 = 0.01;

/// Mounting planes derived from the robot's shape when the scan shows none it could stand on
/// (the floor beyond the camera's range or seen edge-on by a camera level with the base): the
/// robot's first axis is the axis of its base cylinder, so the axes of the scan's cylinders
/// (directions that many scan normals are perpendicular to; the strongest three) are candidate
/// "up" directions, both ways; along each, the heights of the mounting face are where the
/// scan's heights of side-, up- and down-facing surface best match the model's (the best
/// [`DERIVED_HEIGHTS`] matches) and the lowest surface in view.
///
/// Scan points on the scan's `flat` planes (box sides, the floor) are left out: they are not the
/// robot, and clutter standing on the floor would shape the height histogram.
pub(crate) fn derived_planes(
    pts: &[Oriented],
    flat: &[Plane],
    surface: &ModelSurface,
    seed: u64,
) -> Vec<Plane> {
    let curved: Vec<Oriented> = pts
        .iter()
        .filter(|o| {
            !flat.iter().any(|pl| {
                (pl.n.dot(&o.p.coords) + pl.d).abs() < FLAT_TOLERANCE_M && pl.n.dot(&o.n) > 0.9
            })
        })
        .copied()
        .collect();
    let all = pts;
    let pts = &curved[..];
    let mut planes: Vec<Plane> = Vec::new();
    for axis in cylinder_axes(pts, DERIVED_AXES, seed) {
        for up in [axis, -axis] {
            let mut heights = mounting_heights(pts, &up, surface, DERIVED_HEIGHTS);
            // Seen from the side (the camera level with the base), the robot's side-facing
            // surface matches at almost any height; the lowest curved surface in view is then
            // where the base or its cable meets the mounting face.
            if let Some(low) = lowest_height(pts, &up) {
                if heights
                    .iter()
                    .all(|h| (h - low).abs() >= MIN_HEIGHTS_APART_M)
                {
                    heights.push(low);
                }
            }
            for h in heights {
                planes.push(Plane { n: up, d: -h });
            }
        }
    }
    // The planes take turns in the hypothesis list: the plausible ones first, with (almost)
    // nothing of the scan below them (a mounting plate's top may stand a little above the
    // floor); a mounting face put too high has the robot's foot below it.
    let below = |pl: &Plane| {
        all.iter()
            .filter(|o| pl.n.dot(&o.p.coords) + pl.d < -PLATE_M)
            .count()
    };
    planes.sort_by_cached_key(below);
    tracing::debug!(
        planes = ?planes.iter().map(|p| (p.n.as_slice().to_vec(), p.d)).collect::<Vec<_>>(),
        "derived planes (normal, offset)"
    );
    planes
}

/// Up to `max_axes` distinct directions (≥ 20° apart) to which many scan normals are
/// perpendicular: the axes of the cylinders in view, strongest first.
fn cylinder_axes(pts: &[Oriented], max_axes: usize, seed: u64) -> Vec<Vector3<f64>> {
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed ^ 0xa5e5);
    if pts.len() < 100 {
        return Vec::new();
    }
    let mut probe: Vec<Vector3<f64>> = (0..2000)
        .map(|_| pts[rng.random_range(0..pts.len())].n)
        .collect();
    // Perpendicular within ~5°.
    let tol = 0.08;
    let mut axes: Vec<Vector3<f64>> = Vec::new();
    for _ in 0..2 * max_axes {
        if axes.len() >= max_axes || probe.len() < 100 {
            break;
        }
        let mut best: Option<(usize, Vector3<f64>)> = None;
        for _ in 0..300 {
            let a = probe[rng.random_range(0..probe.len())];
            let b = probe[rng.random_range(0..probe.len())];
            let Some(axis) = a.cross(&b).try_normalize(0.3) else {
                continue;
            };
            let count = probe.iter().filter(|n| n.dot(&axis).abs() < tol).count();
            if best.is_none_or(|b| count > b.0) {
                best = Some((count, axis));
            }
        }
        let Some((count, mut axis)) = best else { break };
        if count < probe.len() / 20 {
            break;
        }
        // Refit: the direction least represented among the inliers' normals.
        let mut m = Matrix3::zeros();
        for n in probe.iter().filter(|n| n.dot(&axis).abs() < tol) {
            m += n * n.transpose();
        }
        let eig = m.symmetric_eigen();
        axis = eig.eigenvectors.column(eig.eigenvalues.imin()).into_owned();
        tracing::debug!(count, axis = ?axis.as_slice(), "cylinder axis");
        probe.retain(|n| n.dot(&axis).abs() >= tol);
        if axes
            .iter()
            .all(|o| o.dot(&axis).abs() < 20f64.to_radians().cos())
        {
            axes.push(axis);
        }
    }
    axes
}

/// The height along `up` below which only 0.5 % of `pts` lie (robust to flying pixels).
fn lowest_height(pts: &[Oriented], up: &Vector3<f64>) -> Option<f64> {
    if pts.is_empty() {
        return None;
    }
    let mut along: Vec<f64> = pts.iter().map(|o| up.dot(&o.p.coords)).collect();
    let k = along.len() / 200;
    let (_, low, _) = along.select_nth_unstable_by(k, f64::total_cmp);
    Some(*low)
}

/// Up to `max` heights `h` of the robot's mounting face along `up` (the plane `up · p = h`,
/// camera frame), best first: each scan point votes for the heights at which the model has
/// surface facing the same way (side, up, down) at its height, in proportion to how much; the
/// heights are the strongest local maxima of the votes, at least [`MIN_HEIGHTS_APART_M`] apart.
fn mounting_heights(
    pts: &[Oriented],
    up: &Vector3<f64>,
    surface: &ModelSurface,
    max: usize,
) -> Vec<f64> {
    const BIN_M: f64 = 0.01;
    let class = |nz: f64| {
        if nz > 0.8 {
            Some(0)
        } else if nz < -0.8 {
            Some(1)
        } else if nz.abs() < 0.5 {
            Some(2)
        } else {
            None
        }
    };
    // Model heights per class, as a distribution (model frame: z up from the mounting face).
    let (m_lo, m_hi) = surface
        .coarse
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), s| {
            (lo.min(s.p.z), hi.max(s.p.z))
        });
    if !m_lo.is_finite() {
        return Vec::new();
    }
    let m_bins = ((m_hi - m_lo) / BIN_M) as usize + 1;
    let mut model = vec![vec![0.0; m_bins]; 3];
    for s in &surface.coarse {
        if let Some(c) = class(s.n.z) {
            model[c][((s.p.z - m_lo) / BIN_M) as usize] += 1.0;
        }
    }
    for hist in &mut model {
        let total: f64 = hist.iter().sum();
        if total > 0.0 {
            hist.iter_mut().for_each(|v| *v /= total);
        }
    }
    // Scan heights per class.
    let heights: Vec<(f64, usize)> = pts
        .iter()
        .filter_map(|o| Some((up.dot(&o.p.coords), class(up.dot(&o.n))?)))
        .collect();
    let (s_lo, s_hi) = heights
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), h| {
            (lo.min(h.0), hi.max(h.0))
        });
    if !s_lo.is_finite() {
        return Vec::new();
    }
    let s_bins = (((s_hi - s_lo) / BIN_M) as usize + 1).min(1000);
    let mut scan = vec![vec![0.0; s_bins]; 3];
    for &(z, c) in &heights {
        let i = ((z - s_lo) / BIN_M) as usize;
        if i < s_bins {
            scan[c][i] += 1.0;
        }
    }
    // h = s_lo + i·BIN − (m_lo + j·BIN): index i − j + m_bins.
    let mut votes = vec![0.0; s_bins + m_bins];
    for c in 0..3 {
        for (i, &sv) in scan[c].iter().enumerate().filter(|v| *v.1 > 0.0) {
            for (j, &mv) in model[c].iter().enumerate().filter(|v| *v.1 > 0.0) {
                votes[i + m_bins - j] += sv * mv;
            }
        }
    }
    let smooth: Vec<f64> = (0..votes.len())
        .map(|k| {
            votes[k.saturating_sub(1)..(k + 2).min(votes.len())]
                .iter()
                .sum()
        })
        .collect();
    // Local maxima, strongest first (the first of equal ones).
    let mut peaks: Vec<usize> = (0..smooth.len())
        .filter(|&k| {
            smooth[k] > 0.0
                && (k == 0 || smooth[k] > smooth[k - 1])
                && smooth.get(k + 1).is_none_or(|&n| smooth[k] >= n)
        })
        .collect();
    peaks.sort_by(|&a, &b| smooth[b].total_cmp(&smooth[a]).then(a.cmp(&b)));
    let apart = (MIN_HEIGHTS_APART_M / BIN_M).round() as usize;
    let mut chosen: Vec<usize> = Vec::new();
    for k in peaks {
        if chosen.len() >= max {
            break;
        }
        if chosen.iter().all(|&c| c.abs_diff(k) >= apart) {
            chosen.push(k);
        }
    }
    chosen
        .into_iter()
        .map(|k| s_lo - m_lo + (k as f64 - m_bins as f64) * BIN_M)
        .collect()
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

/// Yaw bins of the Hough accumulator (5°).
const N_YAW: usize = 72;
/// Side-facing scan points that vote (evenly thinned beyond): the votes cost
/// voters × model samples at their height.
const MAX_VOTERS: usize = 2500;
/// Cell of the Hough accumulator in the plane, metres.
const HOUGH_CELL_M: f64 = 0.015;

/// Candidate `camera_from_model` poses, best first, from planes + a (x, y, yaw) Hough vote +
/// projective scoring of the peaks.
///
/// The plane fixes two rotations and the height (up to a mounting plate), leaving x, y and the
/// yaw. Every side-facing scan point above the plane is paired with the side-facing model
/// samples (base, shoulder, upper arm posed at the measured joints) at about the same height;
/// the horizontal normals give the yaw of the pair and the positions the robot origin, so the
/// pair votes for one (x, y, yaw) cell. Heights and normals make the vote specific: a base
/// hidden under the shoulder (camera above the robot) is found from the shoulder and upper arm.
/// Peaks whose pose is not `admissible` (an eye-in-hand camera too far from the flange) are
/// skipped.
pub(crate) fn hypotheses(
    range: &RangeImage<'_>,
    surface: &ModelSurface,
    pts: &[Oriented],
    planes: &[Plane],
    max_out: usize,
    admissible: &(dyn Fn(&Isometry3<f64>) -> bool + Sync),
) -> Vec<(Isometry3<f64>, f64)> {
    let fit_depth = surface.fit_depth;
    // Side-facing model samples of the fitted links, in 1 cm height slices (model frame: z up
    // from the mounting face).
    let slice = 0.01;
    let side: Vec<&Sample> = surface
        .coarse
        .iter()
        .filter(|s| s.depth as usize <= fit_depth && s.n.xy().norm() > 0.5 && s.p.z > -0.01)
        .collect();
    if side.is_empty() {
        return Vec::new();
    }
    let zmax = side.iter().map(|s| s.p.z).fold(0.0, f64::max).min(1.5);
    let n_slices = (zmax / slice).ceil() as usize + 2;
    let mut slices: Vec<Vec<(f64, f64, f64)>> = vec![Vec::new(); n_slices];
    for s in &side {
        let k = ((s.p.z.max(0.0)) / slice) as usize;
        if let Some(v) = slices.get_mut(k) {
            v.push((s.p.x, s.p.y, s.n.y.atan2(s.n.x)));
        }
    }
    let rmax = side.iter().map(|s| s.p.x.hypot(s.p.y)).fold(0.0, f64::max);

    // Loose: a peak is up to half a cell and half a yaw bin off, which moves the upper arm's
    // samples by ~15 mm; a tight tolerance would rank the right pose below clutter.
    let tol = Tolerances {
        matched_m: 0.015,
        free_m: 0.03,
    };
    let scoring = ranking_samples(surface);
    let mut per_plane: Vec<Vec<(Isometry3<f64>, f64)>> = Vec::new();
    for pl in planes {
        let cam_from_plane = camera_from_plane(pl);
        let plane_from_cam = cam_from_plane.inverse();
        // Side-facing scan points above the plane (plane frame): x, y, height, normal angle.
        let mut scan: Vec<(f64, f64, f64, f64)> = pts
            .iter()
            .filter_map(|o| {
                let q = plane_from_cam * o.p;
                let n = plane_from_cam.rotation * o.n;
                (q.z > 0.004 && q.z < zmax + 0.03 && n.xy().norm() > 0.5)
                    .then(|| (q.x, q.y, q.z, n.y.atan2(n.x)))
            })
            .collect();
        if scan.len() < 20 {
            continue;
        }
        if scan.len() > MAX_VOTERS {
            let step = scan.len() as f64 / MAX_VOTERS as f64;
            scan = (0..MAX_VOTERS)
                .map(|k| scan[(k as f64 * step) as usize])
                .collect();
        }
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for b in &scan {
            lo = [lo[0].min(b.0), lo[1].min(b.1)];
            hi = [hi[0].max(b.0), hi[1].max(b.1)];
        }
        let margin = rmax.min(0.3) + HOUGH_CELL_M;
        let (x0, y0) = (lo[0] - margin, lo[1] - margin);
        let nx = (((hi[0] - lo[0] + 2.0 * margin) / HOUGH_CELL_M).ceil() as usize + 1).min(400);
        let ny = (((hi[1] - lo[1] + 2.0 * margin) / HOUGH_CELL_M).ceil() as usize + 1).min(400);
        let cells = nx * ny;
        let yaw_step = 2.0 * PI / N_YAW as f64;
        let chunk = scan.len().div_ceil(rayon::current_num_threads().max(1));
        let acc = scan
            .par_chunks(chunk.max(1))
            .map(|part| {
                let mut acc = vec![0u32; N_YAW * cells];
                for &(sx, sy, sz, sa) in part {
                    // The robot may stand on this plane or on a plate up to 2.5 cm thick.
                    let k_lo = ((sz - 0.025).max(0.0) / slice) as usize;
                    let k_hi = (((sz + 0.005) / slice) as usize).min(n_slices - 1);
                    for sl in &slices[k_lo..=k_hi] {
                        for &(mx, my, ma) in sl {
                            let yaw = (sa - ma).rem_euclid(2.0 * PI);
                            let (s, c) = yaw.sin_cos();
                            let cx = sx - (c * mx - s * my);
                            let cy = sy - (s * mx + c * my);
                            let ix = ((cx - x0) / HOUGH_CELL_M) as isize;
                            let iy = ((cy - y0) / HOUGH_CELL_M) as isize;
                            if ix < 0 || iy < 0 || ix as usize >= nx || iy as usize >= ny {
                                continue;
                            }
                            let b = ((yaw / yaw_step).round() as usize) % N_YAW;
                            acc[b * cells + iy as usize * nx + ix as usize] += 1;
                        }
                    }
                }
                acc
            })
            .reduce_with(|mut a, b| {
                a.iter_mut().zip(b).for_each(|(x, y)| *x += y);
                a
            });
        let Some(acc) = acc else { continue };
        // Strongest cells, ranked by their 3×3×3 box sum (yaw circular).
        let mut order: Vec<usize> = (0..acc.len()).filter(|&i| acc[i] > 1).collect();
        if order.len() > 8192 {
            order.select_nth_unstable_by(8192, |&a, &b| acc[b].cmp(&acc[a]));
            order.truncate(8192);
        }
        let boxed = |i: usize| -> u32 {
            let (b, c) = (i / cells, i % cells);
            let (ix, iy) = (c % nx, c / nx);
            if ix == 0 || iy == 0 || ix + 1 >= nx || iy + 1 >= ny {
                return acc[i];
            }
            let mut s = 0;
            for db in [N_YAW - 1, 0, 1] {
                let bb = (b + db) % N_YAW;
                for dy in 0..3 {
                    let row = bb * cells + (iy + dy - 1) * nx + ix - 1;
                    s += acc[row] + acc[row + 1] + acc[row + 2];
                }
            }
            s
        };
        let mut order: Vec<(usize, u32)> = order.into_iter().map(|i| (i, boxed(i))).collect();
        order.sort_unstable_by_key(|o| std::cmp::Reverse(o.1));
        let keep = 24;
        let mut peaks: Vec<(f64, f64, f64)> = Vec::new();
        for (i, _) in order {
            let (b, c) = (i / cells, i % cells);
            let p = (
                x0 + (c % nx) as f64 * HOUGH_CELL_M + 0.5 * HOUGH_CELL_M,
                y0 + (c / nx) as f64 * HOUGH_CELL_M + 0.5 * HOUGH_CELL_M,
                b as f64 * yaw_step,
            );
            let distinct = peaks.iter().all(|o| {
                let dyaw = (o.2 - p.2 + PI).rem_euclid(2.0 * PI) - PI;
                (o.0 - p.0).hypot(o.1 - p.1) > 0.03 || dyaw.abs() > 3.0 * yaw_step
            });
            if distinct && admissible(&(cam_from_plane * plane_pose(p.0, p.1, 0.0, p.2))) {
                peaks.push(p);
                if peaks.len() >= keep {
                    break;
                }
            }
        }
        // Projective scoring of each peak at its yaw ± half a bin and two heights.
        let jobs: Vec<(usize, f64, f64)> = (0..peaks.len())
            .flat_map(|k| {
                [-0.5, 0.0, 0.5].into_iter().flat_map(move |dy| {
                    [0.0, 0.015].into_iter().map(move |h| (k, dy * yaw_step, h))
                })
            })
            .collect();
        let scored: Vec<(Isometry3<f64>, f64)> = jobs
            .par_iter()
            .map(|&(k, dyaw, h)| {
                let (x, y, yaw) = peaks[k];
                let pose = cam_from_plane * plane_pose(x, y, h, yaw + dyaw);
                let e = evidence(range, &scoring, &pose, fit_depth, tol);
                (pose, score(&e))
            })
            .collect();
        per_plane.push(scored);
    }
    // Non-maximum suppression per plane, then the planes take turns: a plane of clutter on
    // which the robot's shape happens to score well must not crowd the floor's peaks out (the
    // right pose on a 15 mm / 5° grid scores below its polished value).
    let mut per_plane: Vec<std::vec::IntoIter<(Isometry3<f64>, f64)>> = per_plane
        .into_iter()
        .map(|mut v| {
            v.sort_by(|a, b| b.1.total_cmp(&a.1));
            // Peaks far behind their plane's best are not worth a polish.
            let floor = 0.4 * v.first().map_or(0.0, |h| h.1);
            let mut kept: Vec<(Isometry3<f64>, f64)> = Vec::new();
            for (pose, s) in v {
                if s > 0.0 && s >= floor && kept.iter().all(|(o, _)| distinct_hypotheses(o, &pose))
                {
                    kept.push((pose, s));
                }
            }
            kept.into_iter()
        })
        .collect();
    let mut out: Vec<(Isometry3<f64>, f64)> = Vec::new();
    while out.len() < max_out {
        let mut any = false;
        for it in per_plane.iter_mut() {
            // The next hypothesis of this plane not already found on another one.
            if let Some(h) = it.find(|(p, _)| out.iter().all(|(o, _)| distinct_hypotheses(o, p))) {
                any = true;
                if out.len() < max_out {
                    out.push(h);
                }
            }
        }
        if !any {
            break;
        }
    }
    out.sort_by(|a, b| b.1.total_cmp(&a.1));
    out
}

/// The samples coarse hypotheses are ranked on: polishing judges them again, so a third of the
/// model's coarse samples will do.
fn ranking_samples(surface: &ModelSurface) -> Vec<Sample> {
    surface.coarse.iter().step_by(3).copied().collect()
}

/// The robot standing at `(x, y, h)` turned by `yaw` in a plane's frame (`plane_from_model`).
fn plane_pose(x: f64, y: f64, h: f64, yaw: f64) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(x, y, h),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw),
    )
}

/// Whether two coarse hypotheses would polish to different poses (2 cm or 12° apart).
fn distinct_hypotheses(a: &Isometry3<f64>, b: &Isometry3<f64>) -> bool {
    !super::within(a, b, 0.02, 12.0)
}
