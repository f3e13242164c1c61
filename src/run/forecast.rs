//! A dry run's forecast of the run it planned: the σ to expect (scans simulated at the planned
//! views, the camera at the mount prior, registered and fitted together as the run would) and
//! the run's time at the configured speed caps. Nothing moves and nothing is captured.

use std::sync::Arc;

use handeye_hal::MotionLimits;
use nalgebra::Isometry3;

use crate::calib::pipeline::{calibrate_frames, Frame, PipelineOptions};
use crate::calib::Mount;
use crate::geometry::SensorClass;
use crate::model::RobotModel;
use crate::plan::joint_span;
use crate::record::Forecast;
use crate::sim::{simulate_scan, Intrinsics, Placement, ScanRequest, SimSettings};

/// Capture and registration of one frame, s: the order of a 1280×960 structured-light scan
/// on a 2-core cell PC (the simulated rig: transfer ~0.45 s, registration ~0.45 s).
const FRAME_S: f64 = 0.9;
/// Preflight, planning, solving and writing back, s (the simulated rig: ~1 s).
const FIXED_S: f64 = 1.0;

/// The time of one `movej` from `a` to `b` at the caps `limits`, s: every joint arrives
/// together, so the largest change decides (a trapezoid of speed, or a triangle when the
/// change is too short to reach the cap).
pub(super) fn move_s(a: &[f64], b: &[f64], limits: &MotionLimits) -> f64 {
    let d = joint_span(a, b);
    let (v, acc) = (
        limits.max_joint_speed_rad_s.max(1e-6),
        limits.max_joint_accel_rad_s2.max(1e-6),
    );
    if d >= v * v / acc {
        d / v + v / acc
    } else {
        2.0 * (d / acc).sqrt()
    }
}

/// What the run planned from `start` through `views` (and back, when `return_to_start`)
/// would take and how precise it would be (see the module's doc). Blocking: a second or two
/// a view (simulation and registration).
#[allow(clippy::too_many_arguments)]
pub(super) fn forecast(
    model: &Arc<RobotModel>,
    start: &[f64],
    views: &[Vec<f64>],
    return_to_start: bool,
    limits: &MotionLimits,
    settle_s: f64,
    frames_per_view: usize,
    prior: Option<Isometry3<f64>>,
    sensor: SensorClass,
) -> Forecast {
    let mut moves_s = 0.0;
    let mut from = start;
    for q in views {
        moves_s += move_s(from, q, limits);
        from = q;
    }
    if return_to_start {
        moves_s += move_s(from, start, limits);
    }
    let n = views.len() as f64;
    let run_s = FIXED_S + moves_s + n * settle_s + n * frames_per_view as f64 * FRAME_S;
    let (sigma, note) = match prior {
        Some(mount) => match simulated_sigma(model, views, mount, sensor) {
            Ok(s) => (Some(s), None),
            Err(e) => (None, Some(e)),
        },
        None => (
            None,
            Some("no mount prior to simulate the views with (mount.prior)".to_string()),
        ),
    };
    Forecast {
        uncertainty_translation_mm: sigma.map(|s| s.0),
        uncertainty_rotation_deg: sigma.map(|s| s.1),
        uncertainty_note: note,
        moves_s,
        run_s,
    }
}

/// The σ (mm, degrees) of a wrist camera at `mount` calibrated from one simulated scan at each
/// of `views` (a manufactured arm, the structured-light preset's 1280×960 camera), or why not.
fn simulated_sigma(
    model: &RobotModel,
    views: &[Vec<f64>],
    mount: Isometry3<f64>,
    sensor: SensorClass,
) -> Result<(f64, f64), String> {
    let settings = SimSettings::default();
    let frames = views
        .iter()
        .enumerate()
        .map(|(k, q)| {
            let req = ScanRequest::new(
                model,
                q.clone(),
                Placement::EyeInHand {
                    flange_from_camera: mount,
                },
                Intrinsics::compact_1280x960(),
                &settings,
                k as u64 + 1,
            );
            let scan = simulate_scan(&req).map_err(|e| e.to_string())?;
            Ok(Frame {
                view: k,
                cloud: scan.cloud,
                joints: q.clone(),
                model_from_flange: Some(scan.truth.model_from_flange_reported),
                source: format!("view {} simulated", k + 1),
                image: None,
            })
        })
        .collect::<Result<Vec<_>, String>>()?;
    let mut opts = PipelineOptions::new(Mount::EyeInHand);
    opts.register = opts.register.for_sensor(sensor);
    opts.prior = Some(mount);
    let c = calibrate_frames(model, &frames, &opts).map_err(|e| {
        format!("the views simulated at the mount prior do not register ({e}); check the views")
    })?;
    let u = match c.solution.uncertainty {
        Some(u) => u,
        None => c.report.uncertainty,
    };
    Ok((u.translation_mm, u.rotation_deg))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_move_takes_its_largest_joint_change_at_the_caps() {
        let limits = MotionLimits {
            max_joint_speed_rad_s: 1.0,
            max_joint_accel_rad_s2: 2.0,
            ..MotionLimits::default()
        };
        // 2 rad at 1 rad/s with 0.5 s to reach it and 0.5 s to stop: 2.5 s.
        let t = move_s(&[0.0, 0.0], &[2.0, -1.0], &limits);
        assert!((t - 2.5).abs() < 1e-9, "{t}");
        // 0.1 rad never reaches the cap: 2·√(0.1/2).
        let t = move_s(&[0.0], &[0.1], &limits);
        assert!((t - 2.0 * 0.05f64.sqrt()).abs() < 1e-9, "{t}");
        assert_eq!(move_s(&[0.3], &[0.3], &limits), 0.0);
    }
}
