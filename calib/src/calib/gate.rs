//! Pass/fail gate of a calibration: a result that is not supported by the data comes back
//! rejected with reasons, never reported as good.

use nalgebra::Isometry3;

use super::register::Registration;
use super::solve::{distance, HandEyeSolution, Mount, Residual, OUTLIER_SIGMAS};
use super::Outcome;
use crate::geometry::SensorClass;

/// Thresholds of [`gate`]; units are in the names. `Default` is conservative.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GateThresholds {
    /// Minimum fraction of the expected visible model surface with scan points on it.
    pub min_coverage: f64,
    /// Minimum support of each fitted link on its own (base, shoulder, upper arm; see
    /// [`super::Quality::link_support`]): a link the scan sees through where the model puts it,
    /// while the fit follows the others, means kinematics that are not the arm's.
    pub min_link_support: f64,
    /// Maximum fraction of the expected visible surface where the scan sees through the model.
    pub max_free_space_violations: f64,
    /// Maximum RMS point-to-surface residual, mm, for a scan as precise as the registration's
    /// tuning; a noisier scan's limit widens with its measured noise ([`Quality::noise_scale`]:
    /// a consumer RGB-D camera at 1.3 m, 0.75 mm of noise, has 3 × this).
    ///
    /// [`Quality::noise_scale`]: super::Quality::noise_scale
    pub max_rmse_mm: f64,
    /// Minimum fraction of scan points near the model that fit it.
    pub min_inlier_fraction: f64,
    /// Maximum 1-σ uncertainty of the camera position, per registration, mm: eye-in-hand at
    /// the camera origin, eye-to-hand at the robot base ([`super::Uncertainty::workspace`]),
    /// where the fixed camera looks (its origin, 1–2 m away, moves by the rotation σ times
    /// that lever, which the rotation limit already bounds). The σ includes what no view can
    /// lower: a manufactured arm's housings off their frames leave about 0.6 mm (median) at a
    /// wrist camera.
    pub max_uncertainty_translation_mm: f64,
    /// Maximum 1-σ uncertainty of the camera rotation, per registration, degrees.
    pub max_uncertainty_rotation_deg: f64,
    /// Maximum disagreement of a used frame or view with the fused result, mm
    /// ([`super::Residual::position_mm`]: eye-to-hand at the robot base).
    pub max_residual_translation_mm: f64,
    /// Maximum disagreement of a used frame or view with the fused result, degrees.
    pub max_residual_rotation_deg: f64,
    /// Maximum fraction of frames the fusion dropped as outliers.
    pub max_dropped_fraction: f64,
    /// Maximum [`super::Quality::ambiguity`]: how well a different pose may explain the scan
    /// relative to the result (the visible geometry is nearly symmetric above this).
    pub max_ambiguity: f64,
    /// Maximum |depth scale − 1| the registration may have estimated.
    pub max_depth_scale_error: f64,
    /// Maximum |range offset| the registration may have estimated, mm (a time-of-flight
    /// camera's systematic error is up to about a centimetre; more is a wrong pose or a camera
    /// that needs its own calibration).
    pub max_depth_offset_mm: f64,
    /// Maximum change from the previous calibration, mm (checked when one is given).
    pub max_change_translation_mm: f64,
    /// Maximum change from the previous calibration, degrees (checked when one is given).
    pub max_change_rotation_deg: f64,
    /// Several configurations: the largest disagreement of two disjoint halves of them, each
    /// fitted on its own ([`super::report::SplitHalf`]), mm (eye-to-hand at the robot base)
    /// and degrees. A shared σ cannot show a systematic error each configuration makes its
    /// own way; two halves that disagree by more than the result's accuracy can. `None`: not
    /// checked (reported only).
    pub max_split_half: Option<(f64, f64)>,
}

impl Default for GateThresholds {
    fn default() -> Self {
        GateThresholds {
            min_coverage: 0.6,
            min_link_support: 0.5,
            max_free_space_violations: 0.03,
            max_rmse_mm: 1.5,
            min_inlier_fraction: 0.5,
            // 1 mm beyond the housings' floor (bench: 97.5 % of 810 manufactured-arm scans
            // accepted, 0 wrong; at 1 mm 94.7 %).
            max_uncertainty_translation_mm: 1.5,
            max_uncertainty_rotation_deg: 0.2,
            max_residual_translation_mm: 1.0,
            max_residual_rotation_deg: 0.2,
            max_dropped_fraction: 0.34,
            max_ambiguity: 0.8,
            max_depth_scale_error: 0.03,
            max_depth_offset_mm: 10.0,
            max_change_translation_mm: 5.0,
            max_change_rotation_deg: 1.0,
            max_split_half: None,
        }
    }
}

impl GateThresholds {
    /// The gate's defaults for a sensor class: what a camera of that class can honestly hold
    /// (a user's `[gate]` keys override them one by one, `handeye::config`). Structured light:
    /// [`Default`]. Time of flight: at most [`TOF_MAX_SIGMA_MM`] of 1σ per registration: its
    /// wrist scans' error / σ reaches 1.6 at p95, and a result 2 mm off is wrong (`handeye
    /// bench --camera helios2 --views 10`, both kinematics paths, 540 scans: the two accepted
    /// 2.2–2.3 mm off had σ 1.45 mm). Active stereo: see [`ACTIVE_STEREO_MAX_SIGMA`],
    /// [`ACTIVE_STEREO_MAX_SEE_THROUGH`] and [`ACTIVE_STEREO_MAX_SPLIT_HALF`].
    pub fn for_sensor(class: SensorClass) -> Self {
        match class {
            SensorClass::StructuredLight => Self::default(),
            SensorClass::ActiveStereo => Self {
                max_uncertainty_translation_mm: ACTIVE_STEREO_MAX_SIGMA.0,
                max_uncertainty_rotation_deg: ACTIVE_STEREO_MAX_SIGMA.1,
                max_free_space_violations: ACTIVE_STEREO_MAX_SEE_THROUGH,
                max_split_half: Some(ACTIVE_STEREO_MAX_SPLIT_HALF),
                ..Self::default()
            },
            SensorClass::TimeOfFlight => Self {
                max_uncertainty_translation_mm: TOF_MAX_SIGMA_MM,
                ..Self::default()
            },
        }
    }
}

/// Largest 1σ an active-stereo result may have (mm at the robot base, degrees): a RealSense
/// D4xx 1.3 m from an arm bends its depth by 1 % of the distance and by blobs of 10–20 mm, and
/// a depth-only fit of one frame has σ 9–19 mm / 1.5°, of which the camera's own depth
/// gradient is 4–18 mm / 1.2° (`calib/tests/realdata.rs`); with the arm's outline in its
/// colour image and the surface it stands on, 4–9 mm / 0.65–0.96° per frame and 4.2 mm /
/// 0.64° for five configurations together. An accepted result must stay within what such a
/// camera is bought for (5 mm where it looks, half a degree) at twice its σ, so the limit is
/// half that: not the structured-light 1.5 mm / 0.2° no such camera holds at that distance,
/// and not a σ whose two-sigma error would be wrong.
pub const ACTIVE_STEREO_MAX_SIGMA: (f64, f64) = (2.5, 0.25);

/// Largest share of the posed model an active-stereo scan may see through: its depth lies up
/// to 1 % of the distance behind the arm (`calib/tests/realdata.rs`), and the real frames of a
/// D4xx at 1.3 m see through 4.8–10.6 % of the model where their fits put it; a wrong pose
/// sees through a quarter or more ([`crate::calib::RegisterOptions::max_violation_found`]).
pub const ACTIVE_STEREO_MAX_SEE_THROUGH: f64 = 0.12;

/// Largest split-half disagreement of an active-stereo result (mm at the robot base, degrees):
/// twice the σ limit ([`ACTIVE_STEREO_MAX_SIGMA`]), what a camera of the class is bought for. Two halves of a D4xx's five configurations
/// disagree by 1–8 mm / 0.9–1.3° (systematic depth and outline errors each configuration
/// makes its own way), which the fused σ of 0.3° does not show.
pub const ACTIVE_STEREO_MAX_SPLIT_HALF: (f64, f64) = (5.0, 0.5);

/// Largest 1σ of the camera position a time-of-flight registration may have, mm
/// ([`GateThresholds::for_sensor`]).
pub const TOF_MAX_SIGMA_MM: f64 = 1.3;

/// The way out named when a result moved beyond `max_change_*`: a camera remounted on purpose
/// is accepted explicitly, never by the gate. The reason ends with it; how to accept depends on
/// where the run was asked for (the command line, or the daemon's page and API), which the
/// service adds after it (`handeye::run::remount_way_out`).
pub const REMOUNT: &str = "if the camera was remounted on purpose, accept the new mount";

/// Outcome of [`gate`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Verdict {
    /// [`Outcome::Accepted`] when the result may be used (written back), else
    /// [`Outcome::Rejected`].
    pub outcome: Outcome,
    /// Why it failed (empty when passed), one sentence each.
    pub reasons: Vec<String>,
}

impl Verdict {
    /// Whether the gate accepted the result.
    pub fn passed(&self) -> bool {
        self.outcome == Outcome::Accepted
    }
}

/// Where an eye-to-hand position is measured (the robot base, `distance_m` from the camera),
/// for the reasons; eye-in-hand positions are at the camera origin and say nothing.
fn at_the_robot_base(distance_m: f64) -> String {
    format!(" at the robot base ({distance_m:.2} m from the camera)")
}

/// The reasons a registration's quality gives against its result (index `i` in the
/// messages): coverage, the links' support, seeing through the model, residuals, inliers,
/// ambiguity and the depth corrections. Its σ is judged apart (alone, or the joint fit's).
pub(crate) fn frame_quality_reasons(
    i: usize,
    r: &Registration,
    th: &GateThresholds,
) -> Vec<String> {
    let mut reasons = Vec::new();
    let q = &r.quality;
    if q.coverage < th.min_coverage {
        reasons.push(format!(
            "frame {i}: only {:.0}% of the visible model surface is in the scan (min {:.0}%)",
            100.0 * q.coverage,
            100.0 * th.min_coverage
        ));
    }
    for (k, c) in q.link_support.iter().enumerate() {
        if let Some(c) = c.filter(|c| *c < th.min_link_support) {
            reasons.push(format!(
                "frame {i}: the fitted links disagree: the scan sees through the {} where the model puts it beside the others (only {:.0}% of what it measured there is its surface, min {:.0}%); the kinematics the model is posed by are not the arm's: check robot.model and the controller's or file's calibration",
                match k {
                    0 => "base",
                    1 => "shoulder",
                    _ => "upper arm",
                },
                100.0 * c,
                100.0 * th.min_link_support
            ));
        }
    }
    // The residual limit for this scan's noise (see `GateThresholds::max_rmse_mm`).
    let noise_scale = q.noise_scale();
    let max_rmse_mm = th.max_rmse_mm * noise_scale;
    if q.free_space_violations > th.max_free_space_violations {
        // Residuals far above the pixel noise, of a fit within the residual limit for this
        // scan's noise, are a camera's bent depth (a stereo camera a metre or more away
        // bends it by centimetre-wide blobs), which lies behind the arm in places as seeing
        // through it would. A scan as precise as the tuning never reads so.
        let bent = match q.noise_mm {
            Some(n) if q.rmse_mm - n > th.max_rmse_mm && q.rmse_mm <= max_rmse_mm => {
                format!(
                "; or the camera's depth bent behind the arm, as this scan's residuals ({:.2} mm RMS against {n:.2} mm of pixel noise) suggest, which this check cannot tell from seeing through it: if the report picture (solve --report) shows the model's outline on the arm, the camera's depth is the limit",
                q.rmse_mm
            )
            }
            _ => String::new(),
        };
        reasons.push(format!(
            "frame {i}: the scan sees through {:.1}% of the posed model (max {:.1}%): wrong pose or wrong joints{bent}",
            100.0 * q.free_space_violations,
            100.0 * th.max_free_space_violations
        ));
    }
    if q.rmse_mm > max_rmse_mm {
        let noisy = match q.noise_mm {
            Some(n) if noise_scale > 1.0 => format!(" for this scan's {n:.2} mm of noise"),
            _ => String::new(),
        };
        reasons.push(format!(
            "frame {i}: residual RMS {:.2} mm (max {max_rmse_mm:.2} mm{noisy})",
            q.rmse_mm
        ));
    }
    if q.inlier_fraction < th.min_inlier_fraction {
        reasons.push(format!(
            "frame {i}: only {:.0}% of scan points near the model fit it (min {:.0}%)",
            100.0 * q.inlier_fraction,
            100.0 * th.min_inlier_fraction
        ));
    }
    if q.ambiguity > th.max_ambiguity {
        reasons.push(format!(
            "frame {i}: a different pose explains the scan almost as well ({:.0}% of the result's support, max {:.0}%): the visible base and shoulder look nearly symmetric; show more of the upper arm",
            100.0 * q.ambiguity,
            100.0 * th.max_ambiguity
        ));
    }
    if let Some(s) = r.depth_scale {
        if (s - 1.0).abs() > th.max_depth_scale_error {
            reasons.push(format!(
                "frame {i}: estimated depth scale {s:.4} is implausible (max error {:.1}%)",
                100.0 * th.max_depth_scale_error
            ));
        }
    }
    if let Some(off_mm) = r.depth_offset_m.map(|m| m * 1e3) {
        if off_mm.abs() > th.max_depth_offset_mm {
            reasons.push(format!(
                "frame {i}: estimated range offset {off_mm:+.1} mm is implausible (max {:.1} mm): a wrong pose, or a camera whose distances need their own calibration",
                th.max_depth_offset_mm
            ));
        }
    }
    reasons
}

/// Checks every registration (index = frame index) and the fused solution; `previous` is the
/// last accepted result in the same frame as `solution.estimate`.
pub fn gate(
    registrations: &[Registration],
    solution: &HandEyeSolution,
    previous: Option<&Isometry3<f64>>,
    th: &GateThresholds,
) -> Verdict {
    let mut reasons = Vec::new();
    let over = |position_mm: f64, rotation_deg: f64| {
        position_mm > th.max_uncertainty_translation_mm
            || rotation_deg > th.max_uncertainty_rotation_deg
    };
    if let Some(u) = solution.uncertainty {
        // Eye-to-hand at the robot base, as a single frame's.
        let (position_mm, base_m) = u.position_mm(solution.mount);
        if over(position_mm, u.rotation_deg) {
            reasons.push(format!(
                "the views fitted together: uncertainty {:.2} mm{} / {:.3}° (max {:.2} mm / {:.3}°): show more of the base and first links in each view, or add views",
                position_mm,
                base_m.map(at_the_robot_base).unwrap_or_default(),
                u.rotation_deg,
                th.max_uncertainty_translation_mm,
                th.max_uncertainty_rotation_deg
            ));
        }
    }
    for (i, r) in registrations.iter().enumerate() {
        // A frame the views fitted together set aside for its quality is not judged.
        let set_aside =
            solution.uncertainty.is_some() && solution.frames.get(i).is_some_and(|f| !f.used);
        if !set_aside {
            reasons.extend(frame_quality_reasons(i, r, th));
        }
        // Views fitted together are judged by the joint fit's σ (below): a view that alone
        // leaves a direction loose, or is uncertain, adds what it knows.
        let alone = solution.uncertainty.is_none();
        let (position_mm, base_m) = r.uncertainty.position_mm(solution.mount);
        let at = base_m.map(at_the_robot_base).unwrap_or_default();
        if alone && over(position_mm, r.uncertainty.rotation_deg) {
            let (camera_mm, _) = r.camera_error.position_mm(solution.mount);
            let what_to_do = if over(camera_mm, r.camera_error.rotation_deg) {
                format!(
                    "the camera's own depth errors alone give {camera_mm:.2} mm / {:.3}° (its depth scale and a depth error across the image, which every frame of this camera shares: more views do not lower it); use a camera with more precise depth, or raise max_uncertainty_translation_mm / max_uncertainty_rotation_deg in the cell config's [gate] (solve: --max-uncertainty) if that is accurate enough for the cell",
                    r.camera_error.rotation_deg
                )
            } else if solution.mount == Mount::EyeInHand {
                // One wrist view leaves the housings' offsets in its σ; views fitted together
                // separate them from the mount (time of flight: 79.6 % of single scans accepted,
                // 781 of 783 three-view runs, docs/src/benchmarks.md).
                "show more of the base and first links, or fit three views or more together ([views])"
                    .to_string()
            } else {
                "show more of the base and first links".to_string()
            };
            reasons.push(format!(
                "frame {i}: uncertainty {position_mm:.2} mm{at} / {:.3}° (max {:.2} mm / {:.3}°): {what_to_do}",
                r.uncertainty.rotation_deg,
                th.max_uncertainty_translation_mm,
                th.max_uncertainty_rotation_deg
            ));
        }
        if alone && !r.degenerate_directions.is_empty() {
            reasons.push(format!(
                "frame {i}: the visible geometry leaves {} direction(s) unconstrained (e.g. yaw of a round base): show the shoulder and upper arm",
                r.degenerate_directions.len()
            ));
        }
    }
    let at = solution
        .workspace_point
        .map(|p| at_the_robot_base(p.coords.norm()))
        .unwrap_or_default();
    // How far a used frame or view may be from the fused result. Views fitted together
    // (`solution.uncertainty`): each view's own estimate carries its links' housings, which
    // the joint fit separates from the mount, so it may be off by its σ — up to
    // `OUTLIER_SIGMAS` of it, as the fusion keeps it.
    let sigma_of = |frames: &mut dyn Iterator<Item = usize>| {
        let s: Vec<(f64, f64)> = frames
            .filter_map(|i| registrations.get(i))
            .map(|r| {
                (
                    r.uncertainty.position_mm(solution.mount).0,
                    r.uncertainty.rotation_deg,
                )
            })
            .collect();
        let n = s.len().max(1) as f64;
        (
            (s.iter().map(|x| x.0 * x.0).sum::<f64>() / n).sqrt(),
            (s.iter().map(|x| x.1 * x.1).sum::<f64>() / n).sqrt(),
        )
    };
    let limit = |(t, r): (f64, f64)| match solution.uncertainty {
        Some(_) => (
            th.max_residual_translation_mm.max(OUTLIER_SIGMAS * t),
            th.max_residual_rotation_deg.max(OUTLIER_SIGMAS * r),
        ),
        None => (th.max_residual_translation_mm, th.max_residual_rotation_deg),
    };
    for f in solution.frames.iter().filter(|f| f.used) {
        let (max_t, max_r) = limit(sigma_of(&mut std::iter::once(f.index)));
        if f.position_mm() > max_t || f.rotation_deg > max_r {
            reasons.push(format!(
                "frame {}: disagrees with the fused result by {:.2} mm{at} / {:.3}° (max {max_t:.2} mm / {max_r:.3}°)",
                f.index, f.position_mm(), f.rotation_deg
            ));
        }
    }
    for v in solution.views.iter().filter(|v| v.used) {
        let mut members = solution
            .frames
            .iter()
            .filter(|f| f.used && f.view == v.view)
            .map(|f| f.index);
        let (max_t, max_r) = limit(sigma_of(&mut members));
        if v.position_mm() > max_t || v.rotation_deg > max_r {
            reasons.push(format!(
                "view {}: disagrees with the fused result by {:.2} mm{at} / {:.3}°",
                v.index,
                v.position_mm(),
                v.rotation_deg
            ));
        }
    }
    let dropped: Vec<&Residual> = solution.frames.iter().filter(|f| !f.used).collect();
    if !solution.frames.is_empty()
        && dropped.len() as f64 > th.max_dropped_fraction * solution.frames.len() as f64
    {
        let named: Vec<String> = dropped
            .iter()
            .map(|f| {
                format!(
                    "frame {} ({:.1} mm{at} / {:.2}° off)",
                    f.index,
                    f.position_mm(),
                    f.rotation_deg
                )
            })
            .collect();
        reasons.push(format!(
            "{} of {} frames disagree with the others and were dropped: {}; the views are inconsistent",
            dropped.len(),
            solution.frames.len(),
            named.join(", ")
        ));
    }
    if let Some(prev) = previous {
        let (t, r) = distance(prev, &solution.estimate);
        if t > th.max_change_translation_mm || r > th.max_change_rotation_deg {
            reasons.push(format!(
                "the result moved {t:.2} mm / {r:.3}° from the previous calibration (max {:.2} mm / {:.3}°): check the camera mount; {REMOUNT}",
                th.max_change_translation_mm, th.max_change_rotation_deg
            ));
        }
    }
    Verdict {
        outcome: if reasons.is_empty() {
            Outcome::Accepted
        } else {
            Outcome::Rejected
        },
        reasons,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::register::{Uncertainty, WorkspaceSigma};
    use crate::calib::solve::{solve, FrameInput, Mount, SolveOptions};
    use crate::calib::testutil::good_registration;
    use nalgebra::Vector3;

    /// Views fitted together are judged by the joint fit's σ: a view whose own σ is over the
    /// limit or that leaves a direction loose alone is kept (the others constrain it), the
    /// joint σ over the limit is not; a view may be off the joint result by 3 of its own σ
    /// (its housings), no more.
    #[test]
    fn views_fitted_together_are_judged_by_their_joint_sigma() {
        let reg = good_registration();
        let flange = |k: f64| Isometry3::new(Vector3::new(0.1 * k, 0.2, 0.5), Vector3::z() * k);
        let mount = Isometry3::translation(0.0, -0.08, 0.03);
        let frames: Vec<FrameInput> = (0..3)
            .map(|v| FrameInput {
                sigma: None,
                view: v,
                camera_from_model: (flange(v as f64) * mount).inverse(),
                model_from_flange: Some(flange(v as f64)),
            })
            .collect();
        let mut sol = solve(Mount::EyeInHand, &frames, &SolveOptions::default()).expect("solved");
        let th = GateThresholds::default();
        let mut weak = reg.clone();
        weak.uncertainty.translation_mm = 2.5;
        weak.degenerate_directions.push(nalgebra::Vector6::z());
        let regs = [reg.clone(), weak, reg.clone()];
        assert_eq!(gate(&regs, &sol, None, &th).reasons.len(), 2, "alone");
        sol.uncertainty = Some(Uncertainty {
            translation_mm: 0.08,
            rotation_deg: 0.01,
            workspace: None,
        });
        let v = gate(&regs, &sol, None, &th);
        assert!(v.passed(), "{v:?}");
        // A frame the joint fit set aside (unused) is not judged for its quality; used, it is.
        let mut poor = regs.clone();
        poor[2].quality.coverage = 0.3;
        assert!(!gate(&poor, &sol, None, &th).passed());
        let mut aside = sol.clone();
        aside.frames[2].used = false;
        let v = gate(&poor, &aside, None, &th);
        assert!(v.passed(), "{v:?}");
        sol.uncertainty = Some(Uncertainty {
            translation_mm: 1.6,
            rotation_deg: 0.01,
            workspace: None,
        });
        let v = gate(&regs, &sol, None, &th);
        assert_eq!(v.reasons.len(), 1, "{v:?}");
        assert!(v.reasons[0].starts_with("the views fitted together: uncertainty 1.60 mm"));
        // A view 0.9 mm off (its σ 0.2 mm: 3σ is 0.6 mm, the fixed limit 1 mm) passes; 1.2 mm
        // off does not; with a σ of 0.5 mm (3σ 1.5 mm) it does.
        sol.uncertainty = Some(Uncertainty::default());
        for (off_mm, sigma_mm, passes) in [(0.9, 0.2, true), (1.2, 0.2, false), (1.2, 0.5, true)] {
            let mut sol = sol.clone();
            let moved = Isometry3::translation(off_mm * 1e-3, 0.0, 0.0) * sol.estimate;
            sol.re_estimate(moved, &frames).expect("re-estimated");
            // Only view 1 is off: move the others with it.
            for r in sol.frames.iter_mut().chain(sol.views.iter_mut()) {
                if r.view != 1 {
                    r.translation_mm = 0.0;
                }
            }
            let mut regs = regs.clone();
            regs[1].uncertainty.translation_mm = sigma_mm;
            regs[1].degenerate_directions.clear();
            let v = gate(&regs, &sol, None, &th);
            assert_eq!(v.passed(), passes, "{off_mm} mm, σ {sigma_mm} mm: {v:?}");
        }
    }

    #[test]
    fn gate_passes_good_and_rejects_each_bad_property() {
        let reg = good_registration();
        let frames = [FrameInput {
            sigma: None,
            view: 0,
            camera_from_model: reg.camera_from_model,
            model_from_flange: None,
        }];
        let sol = solve(Mount::EyeToHand, &frames, &SolveOptions::default()).expect("solved");
        let th = GateThresholds::default();
        assert!(gate(std::slice::from_ref(&reg), &sol, None, &th).passed());
        type Spoil = Box<dyn Fn(&mut Registration)>;
        let bad: Vec<Spoil> = vec![
            Box::new(|r| r.quality.coverage = 0.3),
            Box::new(|r| r.quality.free_space_violations = 0.2),
            Box::new(|r| r.quality.rmse_mm = 3.0),
            Box::new(|r| r.quality.inlier_fraction = 0.2),
            Box::new(|r| r.uncertainty.translation_mm = 2.0),
            Box::new(|r| {
                r.uncertainty.workspace = Some(WorkspaceSigma {
                    translation_mm: 0.1,
                    distance_m: 0.6,
                });
                r.uncertainty.translation_mm = 2.0;
                r.uncertainty.rotation_deg = 0.5;
            }),
            Box::new(|r| r.uncertainty.rotation_deg = 0.5),
            Box::new(|r| r.degenerate_directions.push(nalgebra::Vector6::z())),
            Box::new(|r| r.depth_scale = Some(1.2)),
            Box::new(|r| r.depth_offset_m = Some(-0.015)),
            Box::new(|r| r.quality.ambiguity = 0.95),
            // The upper arm is not where the model puts it beside the others (the model's
            // kinematics are not the arm's).
            Box::new(|r| r.quality.link_support[2] = Some(0.05)),
        ];
        for (k, f) in bad.iter().enumerate() {
            let mut r = reg.clone();
            f(&mut r);
            let v = gate(&[r], &sol, None, &th);
            assert!(!v.passed() && v.reasons.len() == 1, "case {k}: {v:?}");
        }
        // A noisy scan's residuals are judged in its own noise: 3 mm passes a scan measuring
        // 0.75 mm of noise (limit 3 × 1.5 mm), 5 mm does not, and the reason says why.
        let mut noisy = reg.clone();
        noisy.quality.noise_mm = Some(0.75);
        noisy.quality.rmse_mm = 3.0;
        assert!(gate(std::slice::from_ref(&noisy), &sol, None, &th).passed());
        noisy.quality.rmse_mm = 5.0;
        assert_eq!(
            gate(std::slice::from_ref(&noisy), &sol, None, &th).reasons,
            ["frame 0: residual RMS 5.00 mm (max 4.50 mm for this scan's 0.75 mm of noise)"]
        );
        // Drift from the previous calibration.
        let prev = sol.estimate * Isometry3::translation(0.01, 0.0, 0.0);
        assert!(!gate(std::slice::from_ref(&reg), &sol, Some(&prev), &th).passed());
        // Two views that disagree: both stay "used" only if within thresholds; here they are
        // 3 mm apart, so one is dropped and half the frames are gone.
        let other = Isometry3::translation(0.003, 0.0, 0.0) * reg.camera_from_model;
        let frames = [
            FrameInput {
                sigma: None,
                view: 0,
                camera_from_model: reg.camera_from_model,
                model_from_flange: None,
            },
            FrameInput {
                sigma: None,
                view: 1,
                camera_from_model: other,
                model_from_flange: None,
            },
        ];
        let sol2 = solve(Mount::EyeToHand, &frames, &SolveOptions::default()).expect("solved");
        let v = gate(&[reg.clone(), reg.clone()], &sol2, None, &th);
        assert!(!v.passed(), "{v:?}");
        // The dropped frame is named, with how far off it is.
        let dropped = sol2.frames.iter().find(|f| !f.used).expect("one dropped");
        assert!(
            v.reasons
                .iter()
                .any(|r| r.contains(&format!("dropped: frame {} (3.0 mm", dropped.index))),
            "{v:?}"
        );
    }

    /// A camera fixed 1.6 m from the arm: its origin's σ (1.6 mm) is the rotation σ (0.05°)
    /// times the lever, the robot base's is 0.3 mm. Eye-to-hand gates the base's σ (accepted);
    /// the same numbers on a wrist camera are judged at its origin (rejected); a base σ above
    /// the limit is rejected naming the point.
    #[test]
    fn eye_to_hand_gates_the_position_sigma_at_the_robot_base() {
        let mut reg = good_registration();
        reg.camera_from_model =
            Isometry3::new(Vector3::new(0.1, 0.2, 1.6), Vector3::new(2.2, 0.0, 0.0));
        reg.uncertainty = Uncertainty {
            translation_mm: 1.6,
            rotation_deg: 0.05,
            workspace: Some(WorkspaceSigma {
                translation_mm: 0.3,
                distance_m: reg.camera_from_model.translation.vector.norm(),
            }),
        };
        let th = GateThresholds::default();
        let fixed = [FrameInput {
            sigma: None,
            view: 0,
            camera_from_model: reg.camera_from_model,
            model_from_flange: None,
        }];
        let sol = solve(Mount::EyeToHand, &fixed, &SolveOptions::default()).expect("solved");
        let v = gate(std::slice::from_ref(&reg), &sol, None, &th);
        assert!(v.passed(), "{v:?}");
        let wrist = [FrameInput {
            sigma: None,
            model_from_flange: Some(Isometry3::translation(0.4, 0.0, 0.6)),
            ..fixed[0].clone()
        }];
        let sol_wrist = solve(Mount::EyeInHand, &wrist, &SolveOptions::default()).expect("solved");
        let v = gate(std::slice::from_ref(&reg), &sol_wrist, None, &th);
        assert_eq!(
            v.reasons,
            ["frame 0: uncertainty 1.60 mm / 0.050° (max 1.50 mm / 0.200°): show more of the base and first links, or fit three views or more together ([views])"]
        );
        if let Some(w) = reg.uncertainty.workspace.as_mut() {
            w.translation_mm = 1.7;
        }
        let v = gate(std::slice::from_ref(&reg), &sol, None, &th);
        assert_eq!(
            v.reasons,
            ["frame 0: uncertainty 1.70 mm at the robot base (1.62 m from the camera) / 0.050° (max 1.50 mm / 0.200°): show more of the base and first links"]
        );
    }

    /// Seeing through the posed model is a wrong pose, or (when the residuals are far above
    /// the scan's pixel noise) a camera whose depth is bent behind the arm: the reason names
    /// both then, and how to tell them apart.
    #[test]
    fn a_camera_that_bends_its_depth_is_named_beside_seeing_through() {
        let th = GateThresholds::default();
        let frames = |reg: &Registration| {
            [FrameInput {
                sigma: None,
                view: 0,
                camera_from_model: reg.camera_from_model,
                model_from_flange: None,
            }]
        };
        let mut reg = good_registration();
        reg.quality.free_space_violations = 0.05;
        // Residuals the pixel noise explains: seeing through is the only reading.
        reg.quality.noise_mm = Some(0.2);
        reg.quality.rmse_mm = 0.5;
        let sol = solve(Mount::EyeToHand, &frames(&reg), &SolveOptions::default()).expect("solved");
        let v = gate(std::slice::from_ref(&reg), &sol, None, &th);
        assert_eq!(v.reasons.len(), 1, "{v:?}");
        assert!(
            v.reasons[0].ends_with("wrong pose or wrong joints"),
            "{v:?}"
        );
        // A real stereo frame 1.3 m away: 4.1 mm RMS against 0.7 mm of pixel noise (within
        // the 4.2 mm that noise allows).
        reg.quality.noise_mm = Some(0.7);
        reg.quality.rmse_mm = 4.1;
        let v = gate(std::slice::from_ref(&reg), &sol, None, &th);
        assert_eq!(v.reasons.len(), 1, "{v:?}");
        assert!(
            v.reasons[0].contains("the camera's depth bent behind the arm")
                && v.reasons[0].contains("4.10 mm RMS against 0.70 mm of pixel noise"),
            "{v:?}"
        );
        // A fit whose residuals are over the limit for its noise is not read as bent depth.
        reg.quality.rmse_mm = 5.0;
        let v = gate(std::slice::from_ref(&reg), &sol, None, &th);
        assert!(v.reasons.iter().all(|r| !r.contains("bent")), "{v:?}");
    }

    /// A σ over the limit that the camera's own depth errors make up (a consumer RGB-D
    /// camera's depth scale and its error across the image) is not cured by showing more of
    /// the arm: the reason says it is the camera, and what the operator can do.
    #[test]
    fn a_sigma_the_camera_itself_makes_says_so() {
        let mut reg = good_registration();
        reg.uncertainty = Uncertainty {
            translation_mm: 3.4,
            rotation_deg: 0.45,
            workspace: None,
        };
        reg.camera_error = Uncertainty {
            translation_mm: 1.1,
            rotation_deg: 0.40,
            workspace: None,
        };
        let wrist = [FrameInput {
            sigma: None,
            view: 0,
            camera_from_model: reg.camera_from_model,
            model_from_flange: Some(Isometry3::translation(0.4, 0.0, 0.6)),
        }];
        let sol = solve(Mount::EyeInHand, &wrist, &SolveOptions::default()).expect("solved");
        let th = GateThresholds::default();
        let v = gate(std::slice::from_ref(&reg), &sol, None, &th);
        assert_eq!(v.reasons.len(), 1, "{v:?}");
        assert!(
            v.reasons[0].starts_with("frame 0: uncertainty 3.40 mm / 0.450° (max 1.50 mm / 0.200°): the camera's own depth errors alone give 1.10 mm / 0.400°"),
            "{v:?}"
        );
        assert!(
            v.reasons[0].contains("raise max_uncertainty_translation_mm"),
            "{v:?}"
        );
        // The camera's part under the limits: the view is what to improve.
        reg.camera_error.rotation_deg = 0.1;
        reg.camera_error.translation_mm = 0.5;
        let v = gate(std::slice::from_ref(&reg), &sol, None, &th);
        assert!(
            v.reasons[0].ends_with(
                "show more of the base and first links, or fit three views or more together ([views])"
            ),
            "{v:?}"
        );
    }

    /// Two frames of a fixed camera 1.6 m away that differ by a turn of 0.1° about the robot
    /// base: 2.8 mm apart at the camera origin, in the same place at the base. Neither is an
    /// outlier, and the residuals say so; a wrist camera's frames are compared at its origin.
    #[test]
    fn eye_to_hand_frames_are_compared_at_the_robot_base() {
        let camera_from_model =
            Isometry3::new(Vector3::new(0.1, -0.2, 1.6), Vector3::new(2.2, 0.1, 0.0));
        let base = nalgebra::Point3::from(camera_from_model.translation.vector);
        // A turn about the base, in the camera frame.
        let turn = Isometry3::translation(base.x, base.y, base.z)
            * Isometry3::rotation(Vector3::new(0.0, 0.1f64.to_radians(), 0.0))
            * Isometry3::translation(-base.x, -base.y, -base.z);
        let frames: Vec<FrameInput> = [camera_from_model, turn * camera_from_model]
            .into_iter()
            .enumerate()
            .map(|(view, camera_from_model)| FrameInput {
                sigma: None,
                view,
                camera_from_model,
                model_from_flange: Some(Isometry3::translation(0.4, 0.0, 0.6)),
            })
            .collect();
        let opts = SolveOptions::default();
        let fixed = solve(Mount::EyeToHand, &frames, &opts).expect("solved");
        assert!(fixed.views.iter().all(|v| v.used), "{fixed:?}");
        for v in &fixed.views {
            assert!(v.translation_mm > 1.0, "{v:?}");
            assert!(v.workspace_mm.is_some_and(|w| w < 0.01), "{v:?}");
            assert_eq!(v.position_mm(), v.workspace_mm.unwrap_or(f64::NAN));
        }
        let (d, _) = crate::calib::solve::distance(
            &frames[0].camera_from_model.inverse(),
            &frames[1].camera_from_model.inverse(),
        );
        assert!(d > 2.5, "{d} mm apart at the camera origin");
        let wrist = solve(Mount::EyeInHand, &frames, &opts).expect("solved");
        assert_eq!(wrist.workspace_point, None);
        assert_eq!(
            wrist.views.iter().filter(|v| v.used).count(),
            1,
            "{wrist:?}"
        );
        assert!(wrist.views.iter().all(|v| v.workspace_mm.is_none()));
    }
}
