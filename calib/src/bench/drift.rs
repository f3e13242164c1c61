//! What a drift check can tell, from a benchmark's calibration runs.
//!
//! A check (`handeye check`, the daemon's schedule) runs the calibration's views again, solves
//! the mount as a calibration would and raises the alarm when it is farther from the current
//! calibration than `[check] max_drift_translation_mm` / `max_drift_rotation_deg`. The
//! benchmark's trials of one run (`--views-per-run N --scans-per-view K`) are exactly that: K
//! calibrations of one arm at the same N views, each from fresh scans; any two of them are a
//! calibration and a check of an unmoved camera, sharing what a real check shares with its
//! calibration (the arm's housings, its encoders' errors at those angles, its sag) and nothing
//! else. Their differences give the false alarms; the same differences with a bump of the
//! camera added give the detection rate of each bump size. The bump is added to the check's
//! result, not simulated: a camera knocked by a few millimetres sees the base as it did, so
//! the check's own error is taken to be that of an unmoved one.

use nalgebra::{Isometry3, Unit, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use serde::Serialize;

use super::{percentile, RobotSummary, Stats, Trial};
use crate::calib::solve::distance;
use crate::calib::Outcome;

/// Directions each pair is bumped in (spread over the sphere).
const BUMP_DIRECTIONS: usize = 32;
/// Seed of the bump directions.
const DIRECTION_SEED: u64 = 0x6472_6966_745f_6469;
/// The bump sizes searched: translation step, mm, and rotation step, degrees.
const TRANSLATION_STEP_MM: f64 = 0.02;
const ROTATION_STEP_DEG: f64 = 0.002;
/// Largest bump searched, in steps.
const MAX_STEPS: usize = 1000;
/// A bump of the camera of a size in a direction: `camera_before_from_camera_after`.
type Bump = dyn Fn(f64, &Unit<Vector3<f64>>) -> Isometry3<f64>;

/// The share of checks a bump must be detected in.
pub const DETECTED_SHARE: f64 = 0.95;

/// The drift-check thresholds studied (`[check]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct CheckLimits {
    /// `max_drift_translation_mm`.
    pub translation_mm: f64,
    /// `max_drift_rotation_deg`.
    pub rotation_deg: f64,
}

/// What the checks of a benchmark's runs can tell at [`CheckLimits`].
#[derive(Debug, Clone, Serialize)]
pub struct DriftStudy {
    /// The limits judged.
    pub limits: CheckLimits,
    /// Calibration runs with at least two accepted trials.
    pub runs: usize,
    /// Checks: ordered pairs (calibration, check) of accepted trials of one run.
    pub checks: usize,
    /// Trials of those runs not accepted (a check that fails is not compared).
    pub not_accepted: usize,
    /// How far an unmoved camera's check lands from its calibration, mm.
    pub unmoved_translation_mm: Stats,
    /// The same, degrees.
    pub unmoved_rotation_deg: Stats,
    /// The largest 0.1 % of those (p99.9), mm and degrees.
    pub unmoved_p999: (f64, f64),
    /// Checks of an unmoved camera beyond the limits (false alarms).
    pub false_alarms: usize,
    /// The smallest shift of the camera (mm, any direction, no turn) detected in at least
    /// [`DETECTED_SHARE`] of the checks.
    pub detected_shift_mm: f64,
    /// The smallest turn of the camera about its own origin (degrees, any axis) detected in
    /// at least [`DETECTED_SHARE`] of the checks.
    pub detected_turn_deg: f64,
}

/// `truth⁻¹ · estimate` of a trial with a result.
fn error_pose(t: &Trial) -> Option<Isometry3<f64>> {
    let e = t.error_pose?;
    Some(Isometry3::new(
        Vector3::new(e[0], e[1], e[2]) * 1e-3,
        Vector3::new(e[3], e[4], e[5]).map(f64::to_radians),
    ))
}

/// The drift checks of `summaries`' calibration runs (trials of one robot with the same first
/// view, one per scan); `None` when no run has two accepted trials.
pub fn study(summaries: &[RobotSummary], limits: CheckLimits) -> Option<DriftStudy> {
    let mut pairs = Vec::new();
    let (mut runs, mut not_accepted) = (0, 0);
    for s in summaries {
        let mut firsts: Vec<usize> = s.details.iter().map(|t| t.view).collect();
        firsts.sort_unstable();
        firsts.dedup();
        for first in firsts {
            let run: Vec<&Trial> = s.details.iter().filter(|t| t.view == first).collect();
            let ok: Vec<Isometry3<f64>> = run
                .iter()
                .filter(|t| t.outcome == Outcome::Accepted)
                .filter_map(|t| error_pose(t))
                .collect();
            if ok.len() < 2 {
                continue;
            }
            runs += 1;
            not_accepted += run.len() - ok.len();
            for (i, a) in ok.iter().enumerate() {
                for (j, b) in ok.iter().enumerate() {
                    if i != j {
                        pairs.push((*a, *b));
                    }
                }
            }
        }
    }
    if pairs.is_empty() {
        return None;
    }
    let unmoved: Vec<(f64, f64)> = pairs.iter().map(|(a, b)| distance(a, b)).collect();
    let alarm = |(mm, deg): (f64, f64)| mm > limits.translation_mm || deg > limits.rotation_deg;
    let p999 = |f: fn(&(f64, f64)) -> f64| {
        let mut v: Vec<f64> = unmoved.iter().map(f).collect();
        v.sort_by(f64::total_cmp);
        percentile(&v, 0.999)
    };
    let directions = directions();
    // The smallest bump (in steps) whose checks raise the alarm in the detected share.
    let smallest = |bump: &Bump, step: f64| {
        (1..=MAX_STEPS)
            .map(|k| k as f64 * step)
            .find(|&size| {
                let mut detected = 0usize;
                for (a, b) in &pairs {
                    for d in &directions {
                        // The check sees the bumped camera: `truth_new = truth · bump`.
                        if alarm(distance(a, &(bump(size, d) * b))) {
                            detected += 1;
                        }
                    }
                }
                detected as f64 >= DETECTED_SHARE * (pairs.len() * directions.len()) as f64
            })
            .unwrap_or(f64::INFINITY)
    };
    Some(DriftStudy {
        limits,
        runs,
        checks: pairs.len(),
        not_accepted,
        unmoved_translation_mm: Stats::of(unmoved.iter().map(|u| u.0)),
        unmoved_rotation_deg: Stats::of(unmoved.iter().map(|u| u.1)),
        unmoved_p999: (p999(|u| u.0), p999(|u| u.1)),
        false_alarms: unmoved.iter().filter(|&&u| alarm(u)).count(),
        detected_shift_mm: smallest(
            &|mm, d| {
                let v = d.into_inner() * mm * 1e-3;
                Isometry3::translation(v.x, v.y, v.z)
            },
            TRANSLATION_STEP_MM,
        ),
        detected_turn_deg: smallest(
            &|deg, d| {
                Isometry3::from_parts(
                    Default::default(),
                    UnitQuaternion::from_axis_angle(d, deg.to_radians()),
                )
            },
            ROTATION_STEP_DEG,
        ),
    })
}

/// [`BUMP_DIRECTIONS`] unit vectors drawn uniformly over the sphere (seeded).
fn directions() -> Vec<Unit<Vector3<f64>>> {
    let mut rng = rand::rngs::StdRng::seed_from_u64(DIRECTION_SEED);
    (0..BUMP_DIRECTIONS)
        .map(|_| {
            let z: f64 = rng.random_range(-1.0..1.0);
            let phi: f64 = rng.random_range(0.0..std::f64::consts::TAU);
            let r = (1.0 - z * z).sqrt();
            Unit::new_normalize(Vector3::new(r * phi.cos(), r * phi.sin(), z))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn trial(view: usize, outcome: Outcome, e: [f64; 6]) -> Trial {
        Trial {
            outcome,
            translation_error_mm: Vector3::new(e[0], e[1], e[2]).norm(),
            rotation_error_deg: Vector3::new(e[3], e[4], e[5]).norm(),
            uncertainty_translation_mm: 0.1,
            uncertainty_rotation_deg: 0.01,
            calibrated_kinematics: true,
            error_pose: Some(e),
            ..Trial::new(view, 0)
        }
    }

    /// Two runs whose trials differ by 0.3 mm / 0.03° at most: no false alarm at 1 mm /
    /// 0.2°; a shift is caught once it outgrows the limit by about the spread (the check and
    /// the calibration differ by at most 0.3 mm: beyond 1.3 mm every direction is caught,
    /// below 0.7 mm none), a turn likewise; a rejected trial is not a check; trials of
    /// different runs are never paired.
    #[test]
    fn checks_pair_the_trials_of_one_run() {
        let s = RobotSummary::new(
            "r",
            vec![
                trial(0, Outcome::Accepted, [0.1, 0.0, 0.0, 0.0, 0.01, 0.0]),
                trial(0, Outcome::Accepted, [-0.2, 0.0, 0.0, 0.0, -0.02, 0.0]),
                trial(0, Outcome::Rejected, [5.0, 0.0, 0.0, 0.0, 0.0, 0.0]),
                trial(3, Outcome::Accepted, [0.0, 0.3, 0.0, 0.0, 0.0, 0.03]),
                trial(3, Outcome::Accepted, [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]),
                // A run of one accepted trial has no check.
                trial(6, Outcome::Accepted, [9.0, 0.0, 0.0, 0.0, 0.0, 0.0]),
            ],
        );
        let limits = CheckLimits {
            translation_mm: 1.0,
            rotation_deg: 0.2,
        };
        let d = study(&[s], limits).expect("two runs");
        assert_eq!((d.runs, d.checks, d.not_accepted), (2, 4, 1));
        assert_eq!(d.false_alarms, 0);
        assert!((d.unmoved_translation_mm.max - 0.3).abs() < 1e-9);
        assert!(
            (0.7..=1.32).contains(&d.detected_shift_mm),
            "{}",
            d.detected_shift_mm
        );
        assert!(
            (0.17..=0.232).contains(&d.detected_turn_deg),
            "{}",
            d.detected_turn_deg
        );
        assert!(study(&[RobotSummary::new("r", Vec::new())], limits).is_none());
    }

    #[test]
    fn limits_tighter_than_the_spread_raise_false_alarms() {
        let s = RobotSummary::new(
            "r",
            vec![
                trial(0, Outcome::Accepted, [0.0; 6]),
                trial(0, Outcome::Accepted, [0.5, 0.0, 0.0, 0.0, 0.0, 0.0]),
            ],
        );
        let d = study(
            &[s],
            CheckLimits {
                translation_mm: 0.25,
                rotation_deg: 1.0,
            },
        )
        .expect("a run");
        assert_eq!((d.checks, d.false_alarms), (2, 2));
    }
}
