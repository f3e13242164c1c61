//! Hypotheses from the objects standing on a plane: for a camera fixed in the cell, which sees
//! the whole arm from afar.
//!
//! The Hough vote of [`super::hypotheses`] pairs scan and model points by their normals. A
//! consumer RGB-D camera 1–2 m away measures normals that are tens of degrees off (its depth is
//! bent in blobs of ±10–20 mm a few centimetres wide), so the right pair's yaw is lost and
//! clutter outvotes the arm. The arm is still an object of its own: the scan points above the
//! plane fall into separate clumps (the arm, another robot, a monitor, boxes), and the arm's
//! clump has the arm's visible side's shape. For each clump and each turn of the arm about its
//! axis, the posed model's camera-facing surface is placed so that its centroid falls on the
//! clump's (in the plane), and the pose is scored on the range image: positions and the plane
//! alone, no normals but the model's.

use std::collections::{HashMap, VecDeque};
use std::f64::consts::PI;

use nalgebra::{Isometry3, Point3, Vector2, Vector3};
use rayon::prelude::*;

use super::{camera_from_plane, distinct_hypotheses, plane_pose, Oriented, Plane};
use crate::calib::kdtree::KdTree;
use crate::calib::range::RangeImage;
use crate::calib::surface::{ModelSurface, Sample};
use crate::calib::verify::{evidence, score, Tolerances};

/// Cell of the occupancy grid the clumps are separated on, metres: objects this far apart on
/// the plane are told apart.
const CELL_M: f64 = 0.03;
/// Turns of the arm about its axis tried per clump (5° apart).
const TURNS: usize = 72;
/// Distinct turns kept per clump.
const PER_CLUMP: usize = 2;
/// Clumps tried, most points first.
const MAX_CLUMPS: usize = 8;
/// A clump with fewer scan points than this is too small to be the arm.
const MIN_CLUMP_POINTS: usize = 30;
/// How far above the plane a scan point must at least be to belong to an object, metres.
const ABOVE_M: f64 = 0.02;

/// Candidate `camera_from_model` poses of the robot standing on `plane` with their scores (at
/// most `max_out`): the posed model's camera-facing surface placed on each clump of scan points
/// above the plane at every turn about its axis, scored on the range image with `tol`; each
/// clump's [`PER_CLUMP`] best distinct turns, the best turn of every clump first. A score may
/// be negative: the turns are 5° apart and the plane a few degrees off the robot's axis, so the
/// right pose can be centimetres off before polishing, which judges again. `height_m`: how far
/// above the plane a scan point must be to count (the plane's noise; at least [`ABOVE_M`]).
pub(crate) fn hypotheses(
    range: &RangeImage<'_>,
    surface: &ModelSurface,
    pts: &[Oriented],
    plane: &Plane,
    tol: Tolerances,
    height_m: f64,
    max_out: usize,
) -> Vec<(Isometry3<f64>, f64)> {
    let fit_depth = surface.fit_depth;
    let model: Vec<&Sample> = surface
        .coarse
        .iter()
        .filter(|s| s.depth as usize <= fit_depth)
        .collect();
    let zmax = model.iter().map(|s| s.p.z).fold(0.0, f64::max);
    if model.is_empty() || zmax <= 0.0 {
        return Vec::new();
    }
    let cam_from_plane = camera_from_plane(plane);
    let plane_from_cam = cam_from_plane.inverse();
    let camera = plane_from_cam * Point3::origin();
    let above: Vec<Point3<f64>> = pts
        .iter()
        .map(|o| plane_from_cam * o.p)
        .filter(|q| q.z > height_m.max(ABOVE_M) && q.z < zmax + 0.05)
        .collect();
    let clumps = clumps(&above);
    let scoring = super::ranking_samples(surface);
    let score_at = |pose: &Isometry3<f64>| score(&evidence(range, &scoring, pose, fit_depth, tol));
    let jobs: Vec<(usize, usize)> = (0..clumps.len())
        .flat_map(|c| (0..TURNS).map(move |t| (c, t)))
        .collect();
    let scored: Vec<(usize, Isometry3<f64>, f64)> = jobs
        .par_iter()
        .map(|&(c, t)| {
            let yaw = t as f64 * 2.0 * PI / TURNS as f64;
            let at = place(&model, &clumps[c], yaw, &camera);
            let pose = cam_from_plane * plane_pose(at.x, at.y, 0.0, yaw);
            (c, pose, score_at(&pose))
        })
        .collect();
    // Per clump its best distinct turns, each refined between the grid's steps and off the
    // plane's normal; the clumps take turns, so that the arm's clump is not crowded out by a
    // bigger object on which the model happens to score well.
    let mut per_clump: Vec<Vec<(Isometry3<f64>, f64)>> = vec![Vec::new(); clumps.len()];
    for (c, pose, s) in scored {
        per_clump[c].push((pose, s));
    }
    per_clump.par_iter_mut().for_each(|v| {
        v.sort_by(|a, b| b.1.total_cmp(&a.1));
        let mut starts: Vec<Isometry3<f64>> = Vec::new();
        for (pose, _) in v.iter() {
            if starts.len() >= REFINED_TURNS {
                break;
            }
            if starts.iter().all(|o| distinct_hypotheses(o, pose)) {
                starts.push(*pose);
            }
        }
        let mut refined: Vec<(Isometry3<f64>, f64)> = starts
            .iter()
            .map(|start| {
                refine(
                    &cam_from_plane,
                    &(cam_from_plane.inverse() * start),
                    &score_at,
                )
            })
            .collect();
        refined.sort_by(|a, b| b.1.total_cmp(&a.1));
        let mut kept: Vec<(Isometry3<f64>, f64)> = Vec::new();
        for (pose, s) in refined {
            if kept.len() >= PER_CLUMP {
                break;
            }
            if kept.iter().all(|(o, _)| distinct_hypotheses(o, &pose)) {
                kept.push((pose, s));
            }
        }
        *v = kept;
    });
    let mut out: Vec<(Isometry3<f64>, f64)> = Vec::new();
    for rank in 0..PER_CLUMP {
        for v in &per_clump {
            if let Some(h) = v.get(rank) {
                if out.len() < max_out {
                    out.push(*h);
                }
            }
        }
    }
    out
}

/// Distinct turns of a clump refined by [`refine`].
const REFINED_TURNS: usize = 4;
/// [`refine`]'s first steps: position in the plane (metres), turn about the robot's axis and
/// tilt of the axis off the plane's normal (degrees); each halved three times.
const REFINE_STEP_M: f64 = 0.02;
const REFINE_TURN_DEG: f64 = 2.0;
const REFINE_TILT_DEG: f64 = 2.0;
/// Largest tilt of the robot's axis off the plane's normal [`refine`] tries, degrees: a
/// stereo camera's plane at grazing incidence is tilted by its depth errors (3.4° on frame 2
/// of `../shared/realdata` against the data authors' reference), a mounting plate or a table
/// by a degree or two.
const MAX_TILT_DEG: f64 = 6.0;
/// Rounds of [`refine`] at one step size.
const REFINE_ROUNDS: usize = 8;

/// The pose about `start` (`plane_from_model`, on the plane) that scores best by `score_at`:
/// coordinate ascent over the position in the plane, the turn about the robot's axis and the
/// axis's tilt off the plane's normal, the steps halved when none improves. A turn 2.5° off
/// (half the grid's step) and an axis 3° off the normal misplace a hand 0.6 m out by 6 cm:
/// the right turn scores there like a wrong one (on frame 2 of the real frames, 147 at the
/// reference's turn on the plane, 293 refined; wrong turns −355 and below).
fn refine(
    cam_from_plane: &Isometry3<f64>,
    start: &Isometry3<f64>,
    score_at: &(dyn Fn(&Isometry3<f64>) -> f64 + Sync),
) -> (Isometry3<f64>, f64) {
    // x, y (metres), turn, tilt about x, tilt about y (radians).
    let pose = |v: &[f64; 5]| {
        let tilt = nalgebra::UnitQuaternion::from_scaled_axis(Vector3::new(v[3], v[4], 0.0));
        cam_from_plane
            * Isometry3::from_parts(
                nalgebra::Translation3::new(v[0], v[1], 0.0),
                tilt * nalgebra::UnitQuaternion::from_axis_angle(&Vector3::z_axis(), v[2]),
            )
            * Isometry3::from_parts(nalgebra::Translation3::identity(), start.rotation)
    };
    let mut v = [start.translation.x, start.translation.y, 0.0, 0.0, 0.0];
    let mut best = score_at(&pose(&v));
    let mut step = [
        REFINE_STEP_M,
        REFINE_STEP_M,
        REFINE_TURN_DEG.to_radians(),
        REFINE_TILT_DEG.to_radians(),
        REFINE_TILT_DEG.to_radians(),
    ];
    let max_tilt = MAX_TILT_DEG.to_radians();
    for _ in 0..4 {
        for _ in 0..REFINE_ROUNDS {
            let mut improved = false;
            for k in 0..5 {
                for sign in [-1.0, 1.0] {
                    let mut w = v;
                    w[k] += sign * step[k];
                    if w[3].hypot(w[4]) > max_tilt {
                        continue;
                    }
                    let s = score_at(&pose(&w));
                    if s > best {
                        (v, best, improved) = (w, s, true);
                    }
                }
            }
            if !improved {
                break;
            }
        }
        step.iter_mut().for_each(|s| *s /= 2.0);
    }
    (pose(&v), best)
}

/// Model samples [`place`] centres per turn, and of those it pairs with the clump's points
/// (evenly thinned beyond).
const PLACE_SAMPLES: usize = 1000;
const PAIRED_SAMPLES: usize = 150;
/// Rounds of [`place`]'s planar alignment and the distance a pair may span in each, metres.
const PLACE_GATES_M: [f64; 3] = [0.12, 0.06, 0.03];

/// Where the robot's origin stands (plane x, y) turned by `yaw` on `clump`: first so that the
/// centroid of its surface facing `camera` falls on the clump's centroid, then where most of
/// that surface finds clump points at its own height ([`vote`]: the clump may hold more than
/// the arm), then moved in the plane by the median offset of each facing sample to its nearest
/// clump point, in rounds of tighter gates (the clump has cables and parts the arm hides, the
/// model surface the arm hides from itself).
fn place(model: &[&Sample], clump: &Clump, yaw: f64, camera: &Point3<f64>) -> Vector2<f64> {
    let (s, c) = yaw.sin_cos();
    let turn = |v: &Vector3<f64>| Vector3::new(c * v.x - s * v.y, s * v.x + c * v.y, v.z);
    let turned: Vec<(Vector3<f64>, Vector3<f64>)> = model
        .iter()
        .step_by((model.len() / PLACE_SAMPLES).max(1))
        .map(|m| (turn(&m.p.coords), turn(&m.n)))
        .collect();
    let facing = |at: Vector2<f64>| {
        turned.iter().filter(move |(p, n)| {
            n.dot(&(camera.coords - (p + Vector3::new(at.x, at.y, 0.0)))) > 0.0
        })
    };
    let mut at = clump.centroid;
    for _ in 0..2 {
        let (mut sum, mut n) = (Vector2::zeros(), 0usize);
        for (p, _) in facing(at) {
            sum += p.xy();
            n += 1;
        }
        if n == 0 {
            return at;
        }
        at = clump.centroid - sum / n as f64;
    }
    let front: Vec<&(Vector3<f64>, Vector3<f64>)> = facing(at).collect();
    at = vote(&front, clump).unwrap_or(at);
    for gate in PLACE_GATES_M {
        let front: Vec<&(Vector3<f64>, Vector3<f64>)> = facing(at).collect();
        let step = (front.len() / PAIRED_SAMPLES).max(1);
        let (mut dx, mut dy): (Vec<f64>, Vec<f64>) = front
            .iter()
            .step_by(step)
            .filter_map(|(p, _)| {
                let q = p + Vector3::new(at.x, at.y, 0.0);
                let (k, _) = clump.tree.nearest(q.cast::<f32>().into(), gate as f32)?;
                let d = clump.points[k].coords.cast::<f64>() - q;
                Some((d.x, d.y))
            })
            .unzip();
        if dx.len() < 10 {
            break;
        }
        at += Vector2::new(median(&mut dx), median(&mut dy));
    }
    at
}

/// Cell of [`vote`]'s grid of offsets, metres.
const VOTE_CELL_M: f64 = 0.02;
/// Heights within which a model sample and a clump point may pair, metres.
const VOTE_HEIGHT_M: f64 = 0.03;
/// Clump points and model samples [`vote`] pairs (evenly thinned beyond).
const VOTE_POINTS: usize = 1500;
const VOTE_SAMPLES: usize = 120;
/// Largest side of [`vote`]'s grid, cells (6 m of offsets at [`VOTE_CELL_M`]: a clump wider
/// than that, less the arm's own width, leaves offsets out).
const VOTE_MAX_CELLS: usize = 300;

/// Where the robot's origin stands (plane x, y) so that most of the `front` samples (turned,
/// origin at 0) fall on clump points at their own height: every pair at a like height votes
/// for its offset on a [`VOTE_CELL_M`] grid, the densest 3×3 cells win. The clump's centroid
/// is a poor start where the grid joins the arm to what stands beside it (a power strip along
/// its base, a box a cable links it to: 20 cm off on the real frames of `../shared/realdata`);
/// the votes of the arm's own points agree, the others' scatter. `None` without pairs.
fn vote(front: &[&(Vector3<f64>, Vector3<f64>)], clump: &Clump) -> Option<Vector2<f64>> {
    let voters = &clump.voters;
    let samples: Vec<Vector3<f64>> = front
        .iter()
        .step_by((front.len() / VOTE_SAMPLES).max(1))
        .map(|(p, _)| *p)
        .collect();
    if voters.bands.is_empty() || samples.is_empty() {
        return None;
    }
    let (mlo, mhi) = bounds(&mut samples.iter().map(|m| m.xy()));
    let lo = voters.lo - mhi;
    let side = |k: usize| {
        (((voters.hi[k] - mlo[k] - lo[k]) / VOTE_CELL_M) as usize + 1).min(VOTE_MAX_CELLS)
    };
    let (nx, ny) = (side(0), side(1));
    let bands = &voters.bands;
    let mut votes = vec![0u32; nx * ny];
    for m in &samples {
        let b = vote_band(m.z);
        let near = bands
            .get(b.saturating_sub(1)..(b + 2).min(bands.len()))
            .unwrap_or_default();
        for q in near.iter().flatten() {
            if (f64::from(q.z) - m.z).abs() > VOTE_HEIGHT_M {
                continue;
            }
            let ix = ((f64::from(q.x) - m.x - lo.x) / VOTE_CELL_M) as usize;
            let iy = ((f64::from(q.y) - m.y - lo.y) / VOTE_CELL_M) as usize;
            if ix < nx && iy < ny {
                votes[iy * nx + ix] += 1;
            }
        }
    }
    let mut best = (0u32, 0usize, 0usize);
    for iy in 1..ny.saturating_sub(1) {
        for ix in 1..nx.saturating_sub(1) {
            let sum: u32 = (iy - 1..=iy + 1)
                .flat_map(|y| (ix - 1..=ix + 1).map(move |x| (x, y)))
                .map(|(x, y)| votes[y * nx + x])
                .sum();
            if sum > best.0 {
                best = (sum, ix, iy);
            }
        }
    }
    (best.0 > 0).then(|| {
        lo + Vector2::new(
            (best.1 as f64 + 0.5) * VOTE_CELL_M,
            (best.2 as f64 + 0.5) * VOTE_CELL_M,
        )
    })
}

/// A clump's points as [`vote`] pairs them, the same for every turn: evenly thinned to
/// [`VOTE_POINTS`], by height band ([`VOTE_HEIGHT_M`]: a sample looks only at its own band and
/// the two beside it), with their extent in the plane.
struct Voters {
    bands: Vec<Vec<Point3<f32>>>,
    lo: Vector2<f64>,
    hi: Vector2<f64>,
}

impl Voters {
    fn new(points: &[Point3<f32>]) -> Self {
        let pts: Vec<&Point3<f32>> = points
            .iter()
            .step_by((points.len() / VOTE_POINTS).max(1))
            .collect();
        let (lo, hi) = bounds(&mut pts.iter().map(|q| q.coords.xy().cast::<f64>()));
        let mut bands: Vec<Vec<Point3<f32>>> = Vec::new();
        for q in pts {
            let b = vote_band(f64::from(q.z));
            if b >= bands.len() {
                bands.resize_with(b + 1, Vec::new);
            }
            bands[b].push(*q);
        }
        Self { bands, lo, hi }
    }
}

/// The height band of [`Voters`] a height above the plane falls in.
fn vote_band(z: f64) -> usize {
    (z / VOTE_HEIGHT_M).floor().max(0.0) as usize
}

/// The smallest and largest coordinates of `it`.
fn bounds(it: &mut dyn Iterator<Item = Vector2<f64>>) -> (Vector2<f64>, Vector2<f64>) {
    it.fold(
        (
            Vector2::repeat(f64::INFINITY),
            Vector2::repeat(f64::NEG_INFINITY),
        ),
        |(lo, hi), p| (lo.inf(&p), hi.sup(&p)),
    )
}

fn median(v: &mut [f64]) -> f64 {
    let mid = v.len() / 2;
    *v.select_nth_unstable_by(mid, f64::total_cmp).1
}

/// One clump of scan points above the plane (plane frame).
struct Clump {
    centroid: Vector2<f64>,
    points: Vec<Point3<f32>>,
    tree: KdTree,
    voters: Voters,
}

/// The clumps of `above` (points in the plane frame): the
/// connected occupied cells of a [`CELL_M`] grid, the [`MAX_CLUMPS`] with most points, each
/// with at least [`MIN_CLUMP_POINTS`].
fn clumps(above: &[Point3<f64>]) -> Vec<Clump> {
    let key = |q: &Point3<f64>| ((q.x / CELL_M).floor() as i64, (q.y / CELL_M).floor() as i64);
    let mut count: HashMap<(i64, i64), usize> = HashMap::new();
    for q in above {
        *count.entry(key(q)).or_default() += 1;
    }
    // Connected components of the occupied cells (8-neighbourhood), in the cells' order (the
    // same every run): (points, component).
    let mut cells: Vec<(i64, i64)> = count.keys().copied().collect();
    cells.sort_unstable();
    let mut label: HashMap<(i64, i64), usize> = HashMap::new();
    let mut found: Vec<(usize, usize)> = Vec::new();
    for start in cells {
        if label.contains_key(&start) {
            continue;
        }
        let id = found.len();
        let mut n = 0usize;
        let mut queue = VecDeque::from([start]);
        label.insert(start, id);
        while let Some((x, y)) = queue.pop_front() {
            n += count[&(x, y)];
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let j = (x + dx, y + dy);
                    if count.contains_key(&j) && !label.contains_key(&j) {
                        label.insert(j, id);
                        queue.push_back(j);
                    }
                }
            }
        }
        found.push((n, id));
    }
    found.sort_by_key(|f| std::cmp::Reverse(f.0));
    found.retain(|(n, _)| *n >= MIN_CLUMP_POINTS);
    found.truncate(MAX_CLUMPS);
    let mut members: Vec<Vec<&Point3<f64>>> = vec![Vec::new(); found.len()];
    for q in above {
        let component = label.get(&key(q));
        if let Some(k) = component.and_then(|id| found.iter().position(|f| f.1 == *id)) {
            members[k].push(q);
        }
    }
    members
        .into_iter()
        .map(|m| {
            let centroid = m.iter().map(|q| q.xy().coords).sum::<Vector2<f64>>() / m.len() as f64;
            let points: Vec<Point3<f32>> = m.iter().map(|q| q.cast::<f32>()).collect();
            Clump {
                centroid,
                tree: KdTree::new(&points),
                voters: Voters::new(&points),
                points,
            }
        })
        .collect()
}
