//! From captured frames to a gated result: register every frame against the model posed at its
//! joints, close the kinematic chain, fuse, gate and report. The calibration run, `handeye
//! solve` (replay of recorded captures) and the benchmark trial all go through
//! [`calibrate_frames`].

use std::time::Instant;

use handeye_hal::ur_dh::DhParams;
use handeye_hal::PointCloud;
use nalgebra::Isometry3;

use crate::calib::fuse::fuse_solution;
use crate::calib::gate::frame_quality_reasons;
use crate::calib::outline::{fit_outline, OutlineFit, OutlineView};
use crate::calib::register::covariance::{position_sigma_m, rotation_sigma_deg};
use crate::calib::report::{OutlineReport, SplitHalf};
use crate::calib::solve::distance;
use crate::calib::solve::solve_setting_aside;
use crate::calib::surface::PosedModel;
use crate::calib::{
    gate, posed_model, posed_model_with_controller_kinematics, register_posed, CalibError,
    CalibrationReport, FrameInput, GateThresholds, HandEyeSolution, Mount, RegisterOptions,
    Registration, SolveOptions, Verdict,
};
use crate::model::reading::FlangeError;
use crate::model::{KinematicError, RobotModel};

/// One captured frame, ready to register.
#[derive(Debug, Clone)]
pub struct Frame {
    /// Frames with the same view were captured without moving the arm.
    pub view: usize,
    /// The scan, camera frame, metres.
    pub cloud: PointCloud,
    /// Measured joint angles at capture, radians, URDF order.
    pub joints: Vec<f64>,
    /// `model_from_flange` as the controller reported it at capture (its own kinematics),
    /// converted to the model frame; `None` = the model's forward kinematics at `joints`.
    pub model_from_flange: Option<Isometry3<f64>>,
    /// Where the scan came from (file name, camera and frame number), for the report.
    pub source: String,
    /// The colour (or intensity) image registered to the scan, pixel for pixel, when the
    /// camera gives one: the arm's outline in it is fitted beside the depth
    /// ([`crate::calib::outline`]). `None`: depth only.
    pub image: Option<std::sync::Arc<crate::cloud::ColorImage>>,
}

/// How to turn frames into a result.
#[derive(Debug, Clone)]
pub struct PipelineOptions {
    /// Eye-in-hand or eye-to-hand.
    pub mount: Mount,
    /// Guess of the unknown: eye-in-hand `flange_from_camera`, eye-to-hand `model_from_camera`.
    pub prior: Option<Isometry3<f64>>,
    /// The controller's calibrated kinematics: the model is posed by them (and the reported
    /// flange poses agree with them). `None`: the nominal URDF.
    pub controller_dh: Option<DhParams>,
    /// Registration tuning.
    pub register: RegisterOptions,
    /// Fusion outlier thresholds.
    pub solve: SolveOptions,
    /// Pass/fail thresholds.
    pub gate: GateThresholds,
    /// The previous accepted result in the same frame as the estimate, for the gate's
    /// largest-change check.
    pub previous: Option<Isometry3<f64>>,
    /// Frame the report's `base_from_camera` is expressed in (a fixed link of the model, e.g.
    /// `base` for the UR controller's frame); `None` = the model root.
    pub base_frame: Option<String>,
    /// Eye-in-hand: the flange poses are in a frame known only to within this 1σ per axis
    /// (shift m, turn rad) of the model's (poses from elsewhere than the controller, posed by
    /// the nominal URDF: a ROS `world`, a URDF root whose z is not joint 1's axis); the views
    /// estimate it with the mount. `None`: the controller's own poses, in its `base` (read from
    /// it, or checked against its DH to a micrometre, [`crate::model::reported`]).
    pub pose_frame: Option<(f64, f64)>,
}

impl PipelineOptions {
    /// Defaults for `mount`: no prior, nominal kinematics, default tuning (eye-to-hand: every
    /// link fitted, no flange reach) and gate; for UR models the report speaks in the
    /// controller's `base` frame.
    pub fn new(mount: Mount) -> Self {
        let register = match mount {
            Mount::EyeInHand => RegisterOptions::default(),
            // A fixed camera sees the whole arm (often from a metre or more): every link is
            // fitted, each posed at the measured joints with its kinematic error.
            Mount::EyeToHand => RegisterOptions {
                max_camera_flange_distance_m: None,
                fit_chain_depth: usize::MAX,
                ..RegisterOptions::default()
            },
        };
        Self {
            mount,
            prior: None,
            controller_dh: None,
            register,
            solve: SolveOptions::default(),
            gate: GateThresholds::default(),
            previous: None,
            base_frame: None,
            pose_frame: None,
        }
    }
}

/// The result of [`calibrate_frames`].
#[derive(Debug, Clone)]
pub struct Calibration {
    /// One per frame used, input order (a run of views sets aside a frame in which the robot
    /// is not found: see `frames`).
    pub registrations: Vec<Registration>,
    /// The input frame each of `registrations` is of (its index in the frames given).
    pub frames: Vec<usize>,
    /// The fused result.
    pub solution: HandEyeSolution,
    /// What the gate decided.
    pub verdict: Verdict,
    /// `base_frame_from_model` (the report's frame from the model root).
    pub base_from_model: Isometry3<f64>,
    /// The camera in the report's frame (eye-in-hand: at the first frame).
    pub base_from_camera: Isometry3<f64>,
    /// The report (JSON of `handeye solve`, part of every run record).
    pub report: CalibrationReport,
}

/// `model_from_frame` for a fixed link `frame` of `model` (no movable joint above it).
pub fn fixed_frame(model: &RobotModel, frame: &str) -> Result<Isometry3<f64>, CalibError> {
    let zero = vec![0.0; model.dof()];
    let pose = model.frame_pose(frame, &zero).map_err(CalibError::Model)?;
    if model.chain_depth(frame).unwrap_or(0) != 0 {
        return Err(CalibError::BadFrame {
            frame: 0,
            detail: format!(
                "`{frame}` moves with the joints; give a fixed frame such as the root link"
            ),
        });
    }
    Ok(pose)
}

/// The frames a run of several views sets aside: a wrist camera's views are fitted together
/// (`calib::fuse`), and a frame whose quality the gate refuses (too little of the model in
/// view, seen through, …) is left out of the fit when at least three views were captured, two
/// keep good frames and no more than the gate's share of frames
/// ([`GateThresholds::max_dropped_fraction`]) goes; the gate then judges the rest. Otherwise
/// none: every frame is judged as it is.
fn frames_to_set_aside(
    mount: Mount,
    inputs: &[FrameInput],
    registrations: &[Registration],
    th: &GateThresholds,
) -> Vec<bool> {
    let none = vec![false; inputs.len()];
    if mount != Mount::EyeInHand {
        return none;
    }
    let faults: Vec<Vec<String>> = registrations
        .iter()
        .enumerate()
        .map(|(i, r)| frame_quality_reasons(i, r, th))
        .collect();
    let aside: Vec<bool> = faults.iter().map(|f| !f.is_empty()).collect();
    let views: Vec<usize> = inputs.iter().map(|f| f.view).collect();
    if !aside.contains(&true) || !may_set_aside(mount, &views, &aside, th) {
        return none;
    }
    for reason in faults.iter().flatten() {
        tracing::info!("set aside from the views fitted together: {reason}");
    }
    aside
}

/// Registers every frame, solves, fuses and gates. Errors only when nothing can be computed
/// (no frames, a joint count that does not match, a scan in which the robot is not found); a
/// result the data does not support comes back with a failed verdict.
pub fn calibrate_frames(
    model: &RobotModel,
    frames: &[Frame],
    opts: &PipelineOptions,
) -> Result<Calibration, CalibError> {
    let t0 = Instant::now();
    if frames.is_empty() {
        return Err(CalibError::NoFrames);
    }
    let base_frame = opts
        .base_frame
        .clone()
        .unwrap_or_else(|| model.root_link().to_string());
    let base_from_model = fixed_frame(model, &base_frame)?.inverse();
    // Posed by the controller's DH, each fitted link is on its calibrated axis; how far along
    // and turned about it the DH cannot tell, and the kinematic error's sizes say by how much
    // it may be off (see `calib::links`).
    let register = opts.register.clone();
    let mut registrations = Vec::with_capacity(frames.len());
    let mut inputs = Vec::with_capacity(frames.len());
    let mut poseds = Vec::with_capacity(frames.len());
    // Frames in which the robot is not found, and why.
    let mut lost: Vec<(usize, CalibError)> = Vec::new();
    for (i, f) in frames.iter().enumerate() {
        if f.joints.len() != model.dof() {
            return Err(CalibError::JointCountMismatch {
                expected: model.dof(),
                got: f.joints.len(),
            });
        }
        let posed = match &opts.controller_dh {
            Some(dh) => posed_model_with_controller_kinematics(model, &f.joints, dh)?,
            None => posed_model(model, &f.joints)?,
        };
        let model_from_flange = match f.model_from_flange {
            Some(p) => p,
            None => posed
                .model_from_flange
                .ok_or_else(|| CalibError::BadFrame {
                    frame: i,
                    detail: format!("the model has no flange link `{}`", model.flange_link()),
                })?,
        };
        let prior = opts.prior.map(|p| match opts.mount {
            Mount::EyeInHand => (model_from_flange * p).inverse(),
            Mount::EyeToHand => p.inverse(),
        });
        let mut reg = match register_posed(&f.cloud, &posed, prior, &register) {
            Ok(reg) => reg,
            Err(e @ CalibError::RobotNotFound { .. }) => {
                lost.push((i, e));
                continue;
            }
            Err(e) => return Err(e),
        };
        if opts.mount == Mount::EyeInHand {
            carry_flange_error(&mut reg, model, &f.joints, &register.kinematic_error);
        }
        inputs.push(FrameInput {
            view: f.view,
            camera_from_model: reg.camera_from_model,
            model_from_flange: Some(model_from_flange),
            sigma: Some((
                reg.uncertainty.position_mm(opts.mount).0,
                reg.uncertainty.rotation_deg,
            )),
        });
        registrations.push(reg);
        poseds.push(posed);
    }
    // A run of views set aside a frame in which the robot is not found, as a poor one; a single
    // view (or too many lost) ends with the error.
    let aside: Vec<bool> = (0..frames.len())
        .map(|i| lost.iter().any(|(j, _)| *j == i))
        .collect();
    if let Some((_, e)) = lost.into_iter().next() {
        let views: Vec<usize> = frames.iter().map(|f| f.view).collect();
        if !may_set_aside(opts.mount, &views, &aside, &opts.gate) {
            return Err(e);
        }
        for f in frames
            .iter()
            .zip(&aside)
            .filter(|(_, a)| **a)
            .map(|(f, _)| f)
        {
            tracing::warn!(
                "set aside from the views fitted together: {} (view {}) does not show the robot",
                f.source,
                f.view + 1
            );
        }
    }
    // The frames registered: the input index of each, and the frame.
    let kept: Vec<usize> = (0..frames.len()).filter(|&i| !aside[i]).collect();
    let frames: Vec<&Frame> = kept.iter().map(|&i| &frames[i]).collect();
    let t_solve = Instant::now();
    let set_aside = frames_to_set_aside(opts.mount, &inputs, &registrations, &opts.gate);
    let mut solution = solve_setting_aside(opts.mount, &inputs, &opts.solve, &set_aside)?;
    // The views of one arm fitted together: what one view cannot tell apart from the mount
    // (its links' housings), several views can.
    if let Some((estimate, uncertainty)) = fuse_solution(
        &solution,
        &inputs,
        &registrations,
        opts.register.model_accuracy,
        opts.pose_frame,
    ) {
        solution.re_estimate(estimate, &inputs)?;
        solution.uncertainty = Some(uncertainty);
    }
    // A fixed camera with a colour image: the arm's outline in it, fitted with the depth.
    let outline = match opts.mount {
        Mount::EyeToHand => {
            let used: Vec<usize> = (0..registrations.len())
                .filter(|&i| solution.frames.get(i).is_some_and(|r| r.used))
                .collect();
            outline_fit(&frames, &registrations, &poseds, &used, &solution.estimate)
        }
        Mount::EyeInHand => None,
    };
    if let Some(fit) = &outline {
        solution.re_estimate(fit.camera_from_model.inverse(), &inputs)?;
        solution.uncertainty = Some(fit.uncertainty);
    }
    let split_half = split_half(
        opts,
        &frames,
        &registrations,
        &poseds,
        &inputs,
        &solution,
        outline.is_some(),
    );
    // The outline's σ is a model of its errors (each part's outline a pixel or two off); two
    // halves of the frames that disagree by more than it allows show errors it does not model.
    // Two halves, each with half the frames, differ by twice the whole's σ: the σ is at least
    // half their disagreement.
    if let (Some(split), Some(u), true) =
        (&split_half, &mut solution.uncertainty, outline.is_some())
    {
        u.translation_mm = u.translation_mm.max(split.translation_mm / 2.0);
        u.rotation_deg = u.rotation_deg.max(split.rotation_deg / 2.0);
        if let (Some(w), Some(mm)) = (&mut u.workspace, split.workspace_mm) {
            w.translation_mm = w.translation_mm.max(mm / 2.0);
        }
    }
    let mut verdict = gate(
        &registrations,
        &solution,
        opts.previous.as_ref(),
        &opts.gate,
    );
    if let Some(reason) = split_half.as_ref().and_then(|s| s.reason(&opts.gate)) {
        verdict.reasons.push(reason);
        verdict.outcome = crate::calib::Outcome::Rejected;
    }
    let solve_ms = t_solve.elapsed().as_secs_f64() * 1e3;
    let model_from_camera = solution
        .model_from_camera(inputs.first().and_then(|f| f.model_from_flange.as_ref()))
        .ok_or(CalibError::NoFrames)?;
    let base_from_camera = base_from_model * model_from_camera;
    let sources: Vec<String> = frames.iter().map(|f| f.source.clone()).collect();
    let report = CalibrationReport::new(
        &solution,
        &registrations,
        &sources,
        &verdict,
        &base_frame,
        &base_from_camera,
        solve_ms,
        t0.elapsed().as_secs_f64() * 1e3,
    );
    let mut report = report;
    report.split_half = split_half;
    report.outline = outline.map(|f| OutlineReport {
        edges: f.edges,
        spread_px: f.spread_px,
        support: f.support,
    });
    Ok(Calibration {
        registrations,
        frames: kept,
        solution,
        verdict,
        base_from_model,
        base_from_camera,
        report,
    })
}

/// The outline fit ([`crate::calib::outline`]) of the registered frames `used` (indices into
/// `registrations`, `poseds` and `frames`) that carry an image, started at the eye-to-hand
/// estimate `model_from_camera`; `None` when none has an image or the fit finds too little.
fn outline_fit(
    frames: &[&Frame],
    registrations: &[Registration],
    poseds: &[PosedModel],
    used: &[usize],
    model_from_camera: &Isometry3<f64>,
) -> Option<OutlineFit> {
    let views: Vec<OutlineView<'_>> = used
        .iter()
        .filter_map(|&i| {
            let r = registrations.get(i)?;
            Some(OutlineView {
                cloud: &frames.get(i)?.cloud,
                image: frames[i].image.as_deref()?,
                posed: poseds.get(i)?,
                depth_pose: r.camera_from_model,
                depth_covariance: r.covariance_6x6,
                camera_error: r.camera_error_columns,
            })
        })
        .collect();
    if views.is_empty() {
        return None;
    }
    let fit = fit_outline(&views, &model_from_camera.inverse());
    if fit.is_none() {
        tracing::warn!("the arm's outline was not found in the images: the depth alone is used");
    }
    fit
}

/// A reference-free measure of agreement for several configurations: the used frames split
/// into two disjoint halves (alternate frames), each fitted on its own as the whole was (the
/// fusion, and the outline when `with_outline`), and how far apart the two put the camera.
/// `None` for fewer than two used frames.
fn split_half(
    opts: &PipelineOptions,
    frames: &[&Frame],
    registrations: &[Registration],
    poseds: &[PosedModel],
    inputs: &[FrameInput],
    solution: &HandEyeSolution,
    with_outline: bool,
) -> Option<SplitHalf> {
    let used: Vec<usize> = (0..registrations.len())
        .filter(|&i| solution.frames.get(i).is_some_and(|r| r.used))
        .collect();
    if used.len() < 2 {
        return None;
    }
    let halves: [Vec<usize>; 2] = [
        used.iter().step_by(2).copied().collect(),
        used.iter().skip(1).step_by(2).copied().collect(),
    ];
    let fit = |half: &[usize]| -> Option<Isometry3<f64>> {
        let part: Vec<FrameInput> = half.iter().map(|&i| inputs[i].clone()).collect();
        let depth = crate::calib::solve(opts.mount, &part, &opts.solve).ok()?;
        if with_outline {
            let regs: Vec<Registration> = half.iter().map(|&i| registrations[i].clone()).collect();
            let posed: Vec<PosedModel> = half.iter().map(|&i| poseds[i].clone()).collect();
            let fr: Vec<&Frame> = half.iter().map(|&i| frames[i]).collect();
            let all: Vec<usize> = (0..half.len()).collect();
            return outline_fit(&fr, &regs, &posed, &all, &depth.estimate)
                .map(|f| f.camera_from_model.inverse());
        }
        let model_from_flange = part.first().and_then(|f| f.model_from_flange);
        depth.model_from_camera(model_from_flange.as_ref())
    };
    let (a, b) = (fit(&halves[0])?, fit(&halves[1])?);
    // Eye-in-hand halves are compared at the first frame's flange pose.
    let at = |x: Isometry3<f64>| match opts.mount {
        Mount::EyeToHand => x,
        Mount::EyeInHand => inputs[used[0]].model_from_flange.unwrap_or_default() * x,
    };
    let (a, b) = (at(a), at(b));
    let (translation_mm, rotation_deg) = distance(&a, &b);
    Some(SplitHalf {
        frames: [halves[0].len(), halves[1].len()],
        translation_mm,
        workspace_mm: solution.workspace_point.map(|_| base_apart_mm(&a, &b)),
        rotation_deg,
    })
}

/// How far apart two `model_from_camera` put the model origin as the camera sees it, mm.
fn base_apart_mm(a: &Isometry3<f64>, b: &Isometry3<f64>) -> f64 {
    (a.inverse().translation.vector - b.inverse().translation.vector).norm() * 1e3
}

/// Whether a run may set aside the frames marked in `aside` (frame `i` captured at view
/// `views[i]`) and fit the rest together: a wrist camera's run of three views or more where at
/// least two views keep a frame and no more than the gate's share of frames
/// ([`GateThresholds::max_dropped_fraction`]) goes. Poor frames (`frames_to_set_aside`) and
/// frames in which the robot is not found follow this one rule.
fn may_set_aside(mount: Mount, views: &[usize], aside: &[bool], th: &GateThresholds) -> bool {
    let count = |keep: &dyn Fn(usize) -> bool| {
        let mut v: Vec<usize> = (0..views.len())
            .filter(|&i| keep(i))
            .map(|i| views[i])
            .collect();
        v.sort_unstable();
        v.dedup();
        v.len()
    };
    let gone = aside.iter().filter(|a| **a).count();
    mount == Mount::EyeInHand
        && count(&|_| true) >= 3
        && count(&|i| !aside[i]) >= 2
        && gone as f64 <= th.max_dropped_fraction * views.len() as f64
}

/// A wrist camera's registration with the error of the flange pose it was captured at: the
/// joint readings' errors of `sizes` (encoder error and unmodelled sag at `joints`) carried
/// through the arm's Jacobian ([`FlangeError`]) into the registration's σ, where the
/// mount of this view alone is off by as much, and kept for the views fitted together.
fn carry_flange_error(
    reg: &mut Registration,
    model: &RobotModel,
    joints: &[f64],
    sizes: &KinematicError,
) {
    let Some(error) = FlangeError::at(
        model,
        joints,
        sizes.joint_reading_sigma_rad,
        sizes.deflection_rad,
    ) else {
        return;
    };
    if error.is_exact() {
        return;
    }
    let cov = error.covariance();
    // Where the mount's σ is measured: the camera origin, in the model frame.
    let origin = reg.camera_from_model.inverse().translation.vector;
    let position_mm = position_sigma_m(&cov, &origin) * 1e3;
    let rotation_deg = rotation_sigma_deg(&cov);
    let u = &mut reg.uncertainty;
    u.translation_mm = u.translation_mm.hypot(position_mm);
    u.rotation_deg = u.rotation_deg.hypot(rotation_deg);
    reg.flange_error = Some(error);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::testutil::good_registration;
    use nalgebra::Vector3;

    /// Three views of a wrist camera, view 1's frame too little of the model: it is set aside
    /// and reported unused, its disagreement measured; with two views, or a camera fixed in the
    /// cell, or two of three frames bad, nothing is set aside (the gate judges them all).
    #[test]
    fn a_run_of_three_views_sets_a_poor_one_aside() {
        let flange = |k: f64| Isometry3::new(Vector3::new(0.1 * k, 0.2, 0.5), Vector3::z() * k);
        let mount = Isometry3::translation(0.0, -0.08, 0.03);
        let inputs: Vec<FrameInput> = (0..3)
            .map(|v| FrameInput {
                sigma: None,
                view: v,
                camera_from_model: (Isometry3::translation(0.0005 * v as f64, 0.0, 0.0)
                    * flange(v as f64)
                    * mount)
                    .inverse(),
                model_from_flange: Some(flange(v as f64)),
            })
            .collect();
        let mut regs = vec![good_registration(); 3];
        regs[1].quality.coverage = 0.4;
        let th = GateThresholds::default();
        let aside = frames_to_set_aside(Mount::EyeInHand, &inputs, &regs, &th);
        assert_eq!(aside, [false, true, false]);
        let sol = solve_setting_aside(Mount::EyeInHand, &inputs, &SolveOptions::default(), &aside)
            .expect("solved");
        assert_eq!(
            sol.frames.iter().map(|f| f.used).collect::<Vec<_>>(),
            [true, false, true]
        );
        assert_eq!(sol.views.len(), 3);
        assert!(!sol.views[1].used);
        // View 1 is 0.5 mm from the mean of views 0 and 2 (0 and 1 mm off).
        assert!(
            (sol.frames[1].translation_mm - 0.5).abs() < 0.05,
            "{:?}",
            sol.frames[1]
        );
        assert_eq!(
            frames_to_set_aside(Mount::EyeInHand, &inputs[..2], &regs[..2], &th),
            [false, false]
        );
        assert_eq!(
            frames_to_set_aside(Mount::EyeToHand, &inputs, &regs, &th),
            [false; 3]
        );
        regs[2].quality.coverage = 0.4;
        assert_eq!(
            frames_to_set_aside(Mount::EyeInHand, &inputs, &regs, &th),
            [false; 3]
        );
    }
}
