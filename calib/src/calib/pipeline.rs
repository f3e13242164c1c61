//! From captured frames to a gated result: register every frame against the model posed at its
//! joints, close the kinematic chain, fuse, gate and report. The calibration run, `handeye
//! solve` (replay of recorded captures) and the benchmark trial all go through
//! [`calibrate_frames`].

use std::time::Instant;

use handeye_hal::ur_dh::DhParams;
use handeye_hal::PointCloud;
use nalgebra::Isometry3;

use crate::calib::fuse::fuse_solution;
use crate::calib::{
    gate, posed_model, posed_model_with_controller_kinematics, register_posed, solve, CalibError,
    CalibrationReport, FrameInput, GateThresholds, HandEyeSolution, Mount, RegisterOptions,
    Registration, SolveOptions, Verdict,
};
use crate::model::RobotModel;

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
        }
    }
}

/// The result of [`calibrate_frames`].
#[derive(Debug, Clone)]
pub struct Calibration {
    /// One per frame, input order.
    pub registrations: Vec<Registration>,
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
        let reg = register_posed(&f.cloud, &posed, prior, &register)?;
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
    }
    let t_solve = Instant::now();
    let mut solution = solve(opts.mount, &inputs, &opts.solve)?;
    // The views of one arm fitted together: what one view cannot tell apart from the mount
    // (its links' housings), several views can.
    if let Some((estimate, uncertainty)) = fuse_solution(
        &solution,
        &inputs,
        &registrations,
        opts.register.model_accuracy,
    ) {
        solution.re_estimate(estimate, &inputs)?;
        solution.uncertainty = Some(uncertainty);
    }
    let verdict = gate(
        &registrations,
        &solution,
        opts.previous.as_ref(),
        &opts.gate,
    );
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
    Ok(Calibration {
        registrations,
        solution,
        verdict,
        base_from_model,
        base_from_camera,
        report,
    })
}
