//! Registration: one scan (camera frame) against the robot model posed at the measured joints.
//!
//! Pipeline (stage names are the keys of [`StageTimings`]):
//! 1. `preprocess`: range image (pinhole intrinsics estimated from the organized grid), posed
//!    model sampled into surface points with a k-d tree, a coarse grid of scan points.
//! 2. `coarse`: with a prior, a short robust ICP from it and a projective check; without one (or
//!    when the prior fails its check) the global search of `coarse` (dominant planes →
//!    Hough for the base position → yaw/height sweep, the planes taking turns so clutter cannot
//!    crowd the floor out), each hypothesis — and the strongest ones turned by half a turn about
//!    the robot's axis — polished by a short ICP and ranked by the projective evidence (matched
//!    surface minus free-space violations).
//! 3. `fine`: robust point-to-plane ICP against the exact triangles of the base and first links
//!    (`fit_chain_depth`), with the depth scale as a 7th parameter when enabled, for the best
//!    hypothesis, up to three distinct runners-up that scored almost as well and the best
//!    hypothesis turned by half a turn about the robot's axis (with a prior: the prior and its
//!    half-turn). The winner has the most dense coverage times sharpness (how tightly the scan
//!    hugs the model, overall and on the moving links, which break the base's symmetry); how
//!    close the best other pose comes on coverage and on both misfits (`1 − sharpness`) is
//!    reported as [`Quality::ambiguity`] and gated (a nearly symmetric view is rejected rather
//!    than answered wrong). The winner is then refined once more with the fitted moving links'
//!    kinematic error as parameters of the fit, each with a prior of the arm's calibration size
//!    (`calib::links`): the base holds what it can, the shoulder and upper arm add what they
//!    know beyond their kinematic error.
//! 4. `verify`: coverage of the expected visible model surface and free-space violations on the
//!    dense model samples; degeneracy from the information matrix; the covariance from the
//!    residuals (cluster-robust, per model patch) and the links' prior, over pose and link
//!    parameters together.
//!
//! One file per stage: `prepare.rs` (1, and the polishing fit the later stages share),
//! `candidates.rs` (2), `contenders.rs` and `link_fit.rs` (3), `covariance.rs` (4);
//! [`register_posed`] here runs them in order. Distances are widened for a scan noisier than
//! the simulator's structured-light camera (see `prepare.rs`).

use std::time::Instant;

use handeye_hal::ur_dh::DhParams;
use handeye_hal::PointCloud;
use nalgebra::{Isometry3, Matrix6, Matrix6x4, Vector6};
use serde::Serialize;

use super::links::LinkFit;
use super::solve::Mount;
use super::surface::{PosedJoint, PosedModel};
use super::verify::{evidence_per_depth, Evidence};
use super::CalibError;
use crate::geometry::SensorClass;
use crate::model::{GeometryKind, KinematicError, RobotModel};

/// Tuning of [`register`]. `Default` is what the benchmark measures.
#[derive(Debug, Clone, PartialEq)]
pub struct RegisterOptions {
    /// Links up to this many movable joints from the root are fitted (0 base, 1 shoulder, 2
    /// upper arm; `usize::MAX` every link). Deeper links carry more kinematic error; they only
    /// explain scan points. A camera on the flange sees the base and the first links from
    /// close by; a camera fixed in the cell sees the whole arm from afar, where every link's
    /// surface counts (see [`crate::calib::pipeline::PipelineOptions::new`]).
    pub fit_chain_depth: usize,
    /// Spacing of the model surface samples used for correspondences, metres.
    pub sample_spacing_m: f64,
    /// Spacing of the samples scoring coarse hypotheses, metres.
    pub coarse_spacing_m: f64,
    /// Scan points used by the final ICP (uniformly thinned); more costs time, not accuracy.
    pub max_icp_points: usize,
    /// Estimate the camera's depth-scale error as a parameter of the fit (the model's size
    /// fixes it).
    pub estimate_depth_scale: bool,
    /// The largest depth-scale error an estimated scale may reach: beyond it the scan's
    /// estimate is not the camera's scale (too little depth relief, or smooth depth errors
    /// on a few links pulling it) and the scale is left at 1, its error in the covariance by
    /// [`Self::fixed_depth_error`].
    pub max_depth_scale_error: f64,
    /// Estimate the camera's range offset (every pixel's distance off by the same length along
    /// its ray, a time-of-flight camera's systematic error) as a parameter of the fit. Over the
    /// narrow depth range of one view an offset and a scale error look nearly alike (an offset
    /// δ at distance r is a scale error δ / r), so [`Self::for_sensor`] estimates the one the
    /// sensor class has and puts the other's effect in the covariance
    /// ([`Self::fixed_depth_error`]).
    pub estimate_depth_offset: bool,
    /// 1σ of the depth-scale error (relative) and of the range offset (metres) the fit does
    /// *not* estimate: how much each moves the pose enters the covariance. An estimated one
    /// brings its own uncertainty instead.
    pub fixed_depth_error: (f64, f64),
    /// Time-of-flight multipath: scan points on model surface within this distance of other
    /// surface facing it (a concave corner: the base's foot on the floor, between links) are
    /// not used, their range being biased long by light bounced off that surface (metres;
    /// `None`: every point is used, for sensors without multipath).
    pub multipath_clearance_m: Option<f64>,
    /// 1σ of a depth error that grows across the image (1/m per unit of the normalized image
    /// coordinates x/z and y/z, see [`crate::sim::ScanNoise::depth_gradient`]): no fit
    /// estimates it, its effect on the pose enters the covariance. 0 for sensors without it.
    pub depth_gradient_error: f64,
    /// Whether the covariance's smooth depth error counts only the residual spread beyond the
    /// scan's own per-pixel noise. A time-of-flight camera's 1 mm at 1 m is independent from
    /// pixel to pixel, and counted as shared it doubled the σ (error / σ 0.57). For structured
    /// light and active stereo the whole spread counts: subtracting the per-pixel noise there
    /// left the σ of a fixed camera 2.2–2.4 m away too small (`handeye bench --mount
    /// eye-to-hand`: error / σ p95 2.4 on the UR10e and UR20 placements, one wrong accept).
    pub smooth_error_beyond_pixel_noise: bool,
    /// Coarse hypotheses polished and compared.
    pub max_hypotheses: usize,
    /// Below this coverage (or above `max_violation_found` free-space violations) the robot is
    /// reported as not found instead of returning a pose.
    pub min_coverage_found: f64,
    /// Free-space violation fraction above which the robot is reported as not found.
    pub max_violation_found: f64,
    /// A prior is trusted without the global search when its refined coverage reaches this.
    pub min_coverage_prior: f64,
    /// Verification: a scan point this close (along the normal) to the model surface counts
    /// as matched, metres.
    pub match_tolerance_m: f64,
    /// Verification: a scan point this far behind the model surface is a free-space
    /// violation, metres.
    pub free_space_tolerance_m: f64,
    /// How the real arm differs from the model it is registered against (1σ of zero offsets,
    /// link lengths, axis misalignments of the joints; for UR arms of the DH θ, d and a, α).
    /// The shoulder and upper arm are posed with the model's kinematics; their displacements
    /// are estimated with this as their prior, and what the scan cannot tell apart from them
    /// (the yaw of a round base) is in the covariance. `KinematicError::none()` when the model
    /// is posed with the controller's own calibration
    /// ([`posed_model_with_controller_kinematics`], [`posed_model_with_kinematics`]).
    pub kinematic_error: KinematicError,
    /// An information eigenvalue below this fraction of the largest marks a degenerate
    /// direction (rotations scaled by 0.1 m).
    pub degeneracy_ratio: f64,
    /// 1σ of the camera pose error (position, m; rotation, rad; isotropic, root-sum-square
    /// over the axes) that the model's own inaccuracy leaves: the CAD is not the real part and
    /// lacks what is bolted or cabled to it. Such errors are shared by whole parts, so the
    /// residuals do not show them; the covariance adds them. With the arm's kinematics known
    /// exactly, the simulator's CAD mismatch (mounting plate, bolts, cable, label) leaves a
    /// median error of 0.035 mm / 0.0045° (bench, 90 scans): 0.04 mm / 0.004° makes the error
    /// over the reported σ that of a Gaussian. Raise it for meshes known to be coarse.
    pub model_accuracy: (f64, f64),
    /// Eye-in-hand: the camera rides on the flange, at most this far from its origin (metres).
    /// A pose that puts the camera farther from the posed model's flange is not considered:
    /// the wrong poses a nearly symmetric view allows (the base turned or flipped, shifted
    /// along the floor) move the camera by far more than any bracket. `None` for a camera
    /// fixed in the cell, or when the posed model does not know its flange.
    pub max_camera_flange_distance_m: Option<f64>,
    /// Seed of every random choice (results are deterministic).
    pub seed: u64,
}

impl Default for RegisterOptions {
    fn default() -> Self {
        RegisterOptions {
            fit_chain_depth: 2,
            sample_spacing_m: 0.002,
            coarse_spacing_m: 0.012,
            max_icp_points: 8000,
            estimate_depth_scale: true,
            max_depth_scale_error: crate::calib::fine::MAX_SCALE_ERROR,
            estimate_depth_offset: false,
            fixed_depth_error: (0.0, 0.0),
            depth_gradient_error: 0.0,
            multipath_clearance_m: None,
            smooth_error_beyond_pixel_noise: false,
            max_hypotheses: 8,
            min_coverage_found: 0.3,
            max_violation_found: 0.25,
            min_coverage_prior: 0.6,
            match_tolerance_m: 0.003,
            free_space_tolerance_m: 0.006,
            kinematic_error: KinematicError::default(),
            degeneracy_ratio: 1e-3,
            model_accuracy: (0.04e-3, 0.004f64.to_radians()),
            max_camera_flange_distance_m: Some(DEFAULT_CAMERA_FLANGE_DISTANCE_M),
            seed: 1,
        }
    }
}

impl RegisterOptions {
    /// The stages' depth-scale freedom: `Some(bound)` when the scale is estimated.
    pub(crate) fn free_depth_scale(&self) -> Option<f64> {
        self.estimate_depth_scale
            .then_some(self.max_depth_scale_error)
    }

    /// These options tuned for a sensor class's depth errors. Structured light: the depth
    /// scale estimated, as by default. Active stereo: the scale estimated within
    /// [`ACTIVE_STEREO_SCALE_ERROR`]'s 2σ (beyond, left at 1 with that 1σ in the covariance),
    /// [`ACTIVE_STEREO_DEPTH_GRADIENT`] in the covariance, half the ICP points. Time of
    /// flight: the range offset estimated instead of the scale (a phase measurement's scale is
    /// set by its modulation frequency; its systematic error is an offset), the scale's error
    /// of [`TOF_SCALE_ERROR`] in the covariance, and scan points in concave corners of the
    /// model (within [`TOF_MULTIPATH_CLEARANCE_M`] of facing surface) left out.
    pub fn for_sensor(self, class: SensorClass) -> Self {
        match class {
            SensorClass::StructuredLight => self,
            // Smooth depth errors on a few links can pull the estimated scale: on the real
            // frames of a D4xx it came out 0.5–1.0 % on three and 2.5–2.8 % on two, whose
            // poses it moved along the line of sight by 30 mm. An estimate beyond Intel's
            // documented bound is not the camera's scale: the scale is left at 1 and its
            // documented error enters the covariance. Its smooth depth errors are shared by
            // whole patches, and more points do not average them away: half the points leave
            // the real frames' bases within 3 mm, their rotations within 0.1° and their σ
            // unchanged, in two thirds of the time.
            SensorClass::ActiveStereo => Self {
                max_icp_points: self.max_icp_points / 2,
                max_depth_scale_error: 2.0 * ACTIVE_STEREO_SCALE_ERROR,
                fixed_depth_error: (ACTIVE_STEREO_SCALE_ERROR, 0.0),
                depth_gradient_error: ACTIVE_STEREO_DEPTH_GRADIENT,
                ..self
            },
            SensorClass::TimeOfFlight => Self {
                estimate_depth_scale: false,
                estimate_depth_offset: true,
                fixed_depth_error: (TOF_SCALE_ERROR, 0.0),
                multipath_clearance_m: Some(TOF_MULTIPATH_CLEARANCE_M),
                smooth_error_beyond_pixel_noise: true,
                ..self
            },
        }
    }
}

/// 1σ of an active-stereo camera's depth-scale error: Intel documents the RealSense D4xx's
/// absolute depth error as ≤ 2 % within 2 m, taken as 2σ.
pub const ACTIVE_STEREO_SCALE_ERROR: f64 = 0.01;

/// 1σ of an active-stereo camera's depth error across the image, 1/m per unit of the
/// normalized image coordinates: at 2 m and the edge of a D4xx's field of view (x/z ≈ 0.7)
/// 2 % of the depth, Intel's documented bound on its absolute error. The real frames of
/// `../shared/realdata/xarm7_realsense` measure 0.009–0.031 /m down the image at their
/// reference pose.
pub const ACTIVE_STEREO_DEPTH_GRADIENT: f64 = 0.015;

/// 1σ of a time-of-flight camera's depth-scale error: Microsoft documents the Azure Kinect's
/// systematic error as < 11 mm + 0.1 % of the distance.
pub const TOF_SCALE_ERROR: f64 = 0.001;

/// How far from facing surface a time-of-flight camera's range is taken as biased by
/// multipath, metres: a few centimetres.
pub const TOF_MULTIPATH_CLEARANCE_M: f64 = 0.03;

/// 1-σ uncertainty of a pose.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, serde::Deserialize)]
pub struct Uncertainty {
    /// Root-sum-square 1-σ of the camera origin's position, mm.
    pub translation_mm: f64,
    /// Root-sum-square 1-σ of the rotation vector, degrees.
    pub rotation_deg: f64,
    /// The position σ where the camera looks, at the robot base. For a camera fixed in the
    /// cell the camera origin is 1–2 m from the arm, and its σ is mostly the rotation σ times
    /// that lever; what the result is used for is where `base_from_camera` puts the points the
    /// camera sees, whose error is this one. A registration always reports it; a fused result
    /// only for eye-to-hand (a wrist camera sees the base from another place in every view).
    /// `None` in records written before it was reported.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub workspace: Option<WorkspaceSigma>,
}

/// Root-sum-square 1-σ of the position of one point the camera sees: the robot base (the
/// model root's origin), as `camera_from_model` (or `base_from_camera`) places it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, serde::Deserialize)]
pub struct WorkspaceSigma {
    /// 1-σ of the point's position, mm: for a left perturbation `(ρ, φ)` of the pose in the
    /// camera frame, the σ of `ρ + φ × p` at the point `p` (camera frame).
    pub translation_mm: f64,
    /// Distance of the point from the camera origin, metres: the lever between the two
    /// position σ (a 0.03° rotation σ moves the camera origin 2 m away by 1 mm, not the base).
    pub distance_m: f64,
}

impl Uncertainty {
    /// The position σ the gate judges for a camera mounted as `mount`, mm, with the distance
    /// of the point it is measured at from the camera (metres) when that is the robot base:
    /// eye-to-hand at the robot base (when reported), else at the camera origin (`None`).
    pub fn position_mm(&self, mount: Mount) -> (f64, Option<f64>) {
        match (mount, self.workspace) {
            (Mount::EyeToHand, Some(w)) => (w.translation_mm, Some(w.distance_m)),
            _ => (self.translation_mm, None),
        }
    }

    /// The workspace σ for the reports' text (empty when not reported), e.g. `"; at the robot
    /// base, 1.42 m from the camera: 0.210 mm"`.
    pub fn workspace_note(&self) -> String {
        self.workspace
            .map(|w| {
                format!(
                    "; at the robot base, {:.2} m from the camera: {:.3} mm",
                    w.distance_m, w.translation_mm
                )
            })
            .unwrap_or_default()
    }
}

/// How well the result is supported by the scan (independent of ICP fitness).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, serde::Deserialize)]
pub struct Quality {
    /// Fraction of the model surface the camera should see (fitted links, front-facing, in
    /// the image, not occluded) that has scan points on it, 0–1.
    pub coverage: f64,
    /// Fraction of that surface where the scan sees *through* the model (free-space
    /// violations), 0–1. Near 0 for a right pose.
    pub free_space_violations: f64,
    /// RMS point-to-surface residual of the inlier correspondences, mm.
    pub rmse_mm: f64,
    /// The scan's measured per-pixel noise, mm (the median RMS of small surface fits on the
    /// range image); `None` when too few patches qualify.
    #[serde(default)]
    pub noise_mm: Option<f64>,
    /// Fraction of scan points near the fitted links that are inliers, 0–1.
    pub inlier_fraction: f64,
    /// Correspondences used by the final ICP.
    pub points_used: usize,
    /// Model samples expected visible (matched + violated + missing).
    pub visible_samples: usize,
    /// Coarse hypotheses compared (1 when a prior was accepted).
    pub hypotheses: usize,
    /// Whether the result came from the prior (no global search).
    pub from_prior: bool,
    /// How well the best *different* pose (e.g. the robot turned by half a turn, when the
    /// visible base and shoulder are nearly symmetric) explains the scan, relative to the
    /// result: 0 when nothing else comes close, 1 when the scan cannot tell them apart.
    pub ambiguity: f64,
    /// Support of each fitted link on its own (entry `k` for chain depth `k`: the base, the
    /// shoulder, the upper arm): of its expected visible surface that the scan measured, the
    /// fraction where the scan has the surface rather than seeing through it, 0–1; `None` when
    /// the link is not fitted or too little of it is measured to tell. Fitted links that
    /// disagree (the fit follows some, the scan sees through another where the model puts it)
    /// are posed by kinematics that are not the arm's (a wrong model, a wrong calibration); a
    /// link merely out of view or at a grazing angle has no measurements, not low support.
    pub link_support: [Option<f64>; MAX_REPORTED_LINKS],
}

impl Quality {
    /// How much wider than tuned the registration's distances were for this scan's noise: 1
    /// for scans as precise as the tuning (a structured-light camera), the noise over 0.25 mm
    /// for noisier ones, at most 8. The gate's residual limit widens by it.
    pub fn noise_scale(&self) -> f64 {
        prepare::noise_scale(self.noise_mm.map(|mm| mm * 1e-3))
    }
}

/// Fitted links (by chain depth, the base first) whose support [`Quality::link_support`]
/// reports.
pub const MAX_REPORTED_LINKS: usize = 3;

/// A fitted link is judged on its own when at least this many of its samples, and this
/// fraction of all the fitted links' measured samples, are measured (matched or seen through).
const MIN_LINK_SAMPLES: f64 = 100.0;
const MIN_LINK_SHARE: f64 = 0.03;

/// [`Quality::link_support`] from the evidence of each chain depth (entry 0 the base).
fn link_support(per_depth: &[Evidence]) -> [Option<f64>; MAX_REPORTED_LINKS] {
    let measured = |e: &Evidence| e.matched + e.violated;
    let total: f64 = per_depth.iter().map(measured).sum();
    std::array::from_fn(|k| {
        let e = per_depth.get(k)?;
        let m = measured(e);
        (m >= MIN_LINK_SAMPLES && m >= MIN_LINK_SHARE * total).then(|| e.matched / m)
    })
}

/// Wall-clock time per stage, milliseconds.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, serde::Deserialize)]
pub struct StageTimings {
    /// Range image, model sampling, scan subsampling.
    pub preprocess: f64,
    /// Prior check or global search, including hypothesis polishing.
    pub coarse: f64,
    /// Final ICP.
    pub fine: f64,
    /// Projective verification, covariance, degeneracy.
    pub verify: f64,
    /// Everything.
    pub total: f64,
}

/// Result of registering one scan.
#[derive(Debug, Clone, PartialEq)]
pub struct Registration {
    /// Pose of the model (URDF root link) in the camera frame, metres.
    pub camera_from_model: Isometry3<f64>,
    /// Covariance of the result (residuals and the arm's kinematic error, see
    /// [`RegisterOptions::kinematic_error`]) as a left perturbation
    /// in the camera frame: `camera_from_model_true = exp(δ) · camera_from_model`,
    /// `δ = (ρ [m], φ [rad])`. `ρ` is also the displacement of the camera origin.
    pub covariance_6x6: Matrix6<f64>,
    /// 1-σ summary of `covariance_6x6`.
    pub uncertainty: Uncertainty,
    /// The part of [`Self::uncertainty`] the camera's own depth errors give (a depth scale the
    /// fit left at 1, a depth error growing across the image; [`RegisterOptions::fixed_depth_error`],
    /// [`RegisterOptions::depth_gradient_error`]): every frame of this camera shares it, and
    /// fusing frames does not shrink it. Zero when the fit estimates them all.
    pub camera_error: Uncertainty,
    /// How the camera's own depth errors move the pose, one column per error at its 1σ (a
    /// left perturbation in the camera frame, as [`Self::covariance_6x6`]): the depth scale,
    /// the range offset, the depth gradient across and down the image. Their outer product is
    /// the covariance of [`Self::camera_error`]; frames of one camera share the errors, and a
    /// fit of them together estimates them once.
    pub camera_error_columns: Matrix6x4<f64>,
    /// Support of the result in the scan.
    pub quality: Quality,
    /// Directions the visible geometry leaves unconstrained, empty when the pose is fully
    /// determined: unit 6-vectors `(ρ, φ·L)` in camera axes, the rotation `φ` taken about the
    /// centroid of the fitted points and scaled by their RMS spread `L` (so a pure yaw of a
    /// round base is `(0, 0, 0, axis)`).
    pub degenerate_directions: Vec<Vector6<f64>>,
    /// Estimated depth scale of the camera (measured / true distance) when estimated.
    pub depth_scale: Option<f64>,
    /// Estimated range offset of the camera (measured − true distance along each pixel's ray,
    /// metres) when estimated.
    pub depth_offset_m: Option<f64>,
    /// Time per stage.
    pub timings_ms: StageTimings,
    /// The fitted links' parameters and their joint covariance with the pose, for fitting the
    /// views of one arm together (`None` when the links were trusted as posed).
    pub link_fit: Option<LinkFit>,
    /// A wrist camera's: how the flange pose the controller reported with the scan is off
    /// (its joint readings' errors, [`crate::model::reading::FlangeError`]).
    /// [`Self::uncertainty`] includes its covariance (the mount of one view is off by as
    /// much); the views fitted together estimate the readings' errors with the mount.
    /// `None`: the flange pose is taken as exact (a fixed camera, or no reading error).
    pub flange_error: Option<crate::model::reading::FlangeError>,
}

/// Registers `scan` (camera frame) against `model` posed at `joints` (radians, URDF order),
/// using the visual meshes. `prior` is a guess of `camera_from_model` (e.g. the nominal mount
/// or the last calibration); without it the search is global.
pub fn register(
    scan: &PointCloud,
    model: &RobotModel,
    joints: &[f64],
    prior: Option<Isometry3<f64>>,
    opts: &RegisterOptions,
) -> Result<Registration, CalibError> {
    let posed = posed_model(model, joints)?;
    register_posed(scan, &posed, prior, opts)
}

/// The model's visual geometry posed at `joints` (radians, URDF order) in the model frame,
/// with the nominal kinematics.
pub fn posed_model(model: &RobotModel, joints: &[f64]) -> Result<PosedModel, CalibError> {
    posed_model_with_kinematics(model, joints, None)
}

/// Like [`posed_model`], for an arm whose real kinematics differ from the URDF:
/// `joint_origin_errors` (one per chain joint, see [`RobotModel::link_poses_with_errors`]) is
/// the controller's factory calibration relative to the nominal model. Registering against the
/// calibrated arm removes the kinematic mismatch of the shoulder and upper arm, which otherwise
/// dominates the error (the base alone is round and cannot give the yaw).
pub fn posed_model_with_kinematics(
    model: &RobotModel,
    joints: &[f64],
    joint_origin_errors: Option<&[Isometry3<f64>]>,
) -> Result<PosedModel, CalibError> {
    check_joint_count(model, joints)?;
    let poses = match joint_origin_errors {
        Some(e) => model.link_poses_with_errors(joints, e),
        None => model.link_poses(joints),
    }
    .map_err(CalibError::Model)?;
    Ok(assemble_posed_model(model, joints, &poses, None))
}

/// Like [`posed_model`], posed as a UR controller knows its arm: `calibrated` is the DH set the
/// controller uses for the flange poses it reports (absolute values, UR `base` frame; the
/// primary interface's KinematicsInfo), see [`RobotModel::link_poses_with_controller_dh`].
/// The shoulder and upper arm are then where the flange pose says they are, so their nominal
/// kinematic error does not mislead the fit; the posed model's `model_from_flange` is the
/// controller's flange pose in the model frame. Register with
/// `RegisterOptions::kinematic_error` = `KinematicError::none()` (or what remains after the
/// controller's calibration).
///
/// Errors: the joint count, or [`CalibError::Model`] when `model` is not a 6-joint UR arm.
pub fn posed_model_with_controller_kinematics(
    model: &RobotModel,
    joints: &[f64],
    calibrated: &DhParams,
) -> Result<PosedModel, CalibError> {
    check_joint_count(model, joints)?;
    let poses = model
        .link_poses_with_controller_dh(joints, calibrated)
        .map_err(CalibError::Model)?;
    // A calibration moves a link by millimetres (a real UR's published DH, posed: < 5 mm,
    // 10 mrad); centimetres mean another arm's kinematics (a wrong model or file).
    let nominal = model.link_poses(joints).map_err(CalibError::Model)?;
    if let Some((link, off, turn)) = model
        .link_names()
        .iter()
        .zip(poses.iter().zip(&nominal))
        .map(|(l, (p, n))| {
            let off = (p.translation.vector - n.translation.vector).norm();
            (l, off, p.rotation.angle_to(&n.rotation))
        })
        .filter(|(_, off, turn)| *off > MAX_CALIBRATION_MOVE_M || *turn > MAX_CALIBRATION_TURN_RAD)
        .max_by(|a, b| a.1.total_cmp(&b.1))
    {
        return Err(CalibError::KinematicsNotThisArm {
            link: link.clone(),
            off_mm: off * 1e3,
            turn_deg: turn.to_degrees(),
            model: model.name().to_string(),
        });
    }
    Ok(assemble_posed_model(
        model,
        joints,
        &poses,
        Some(calibrated),
    ))
}

/// Farthest a calibration moves a link from where the nominal model has it, metres and radians.
const MAX_CALIBRATION_MOVE_M: f64 = 0.03;
const MAX_CALIBRATION_TURN_RAD: f64 = 0.05;

fn check_joint_count(model: &RobotModel, joints: &[f64]) -> Result<(), CalibError> {
    if joints.len() != model.dof() {
        return Err(CalibError::JointCountMismatch {
            expected: model.dof(),
            got: joints.len(),
        });
    }
    Ok(())
}

/// The visual parts, chain joints and flange of `model` at `poses` (`model_from_link` of
/// every link, [`RobotModel::link_names`] order, at `joints`). The joint frames follow their
/// parent links. `dh`: the controller's DH set a UR arm is posed by, whose axes the model
/// carries.
fn assemble_posed_model(
    model: &RobotModel,
    joints: &[f64],
    poses: &[Isometry3<f64>],
    dh: Option<&DhParams>,
) -> PosedModel {
    let parts = model
        .geometry(GeometryKind::Visual)
        .iter()
        .filter_map(|g| {
            let i = model.link_index(&g.link)?;
            Some(super::PosedPart {
                chain_depth: model.chain_depth(&g.link).unwrap_or(usize::MAX),
                link: g.link.clone(),
                model_from_link: *poses.get(i)?,
                mesh: g.mesh.clone(),
            })
        })
        .collect();
    let chain = model
        .joint_frames_of(poses)
        .into_iter()
        .zip(model.joint_axes())
        .zip(model.joint_origins())
        .map(|((model_from_joint, axis), parent_from_joint)| PosedJoint {
            model_from_joint,
            axis,
            parent_from_joint,
        })
        .collect();
    let flange = model
        .link_index(model.flange_link())
        .and_then(|i| poses.get(i).copied());
    PosedModel {
        parts,
        joints: chain,
        model_from_flange: flange,
        link_axes: dh.and_then(|dh| model.dh_axes(joints, dh).ok()),
        chain_link_frames: model.chain_link_frames(poses),
    }
}

mod candidates;
mod contenders;
#[cfg(test)]
mod controller_kinematics_tests;
pub(crate) mod covariance;
#[cfg(test)]
mod issue_3_tests;
mod link_fit;
mod prepare;
#[cfg(test)]
mod sim_tests;
#[cfg(test)]
mod tests;
mod tof;
#[cfg(test)]
mod tof_tests;
#[cfg(test)]
mod ur_tests;

/// [`register`] on an already posed model (model frame = the frame of `model`'s parts).
pub fn register_posed(
    scan: &PointCloud,
    model: &PosedModel,
    prior: Option<Isometry3<f64>>,
    opts: &RegisterOptions,
) -> Result<Registration, CalibError> {
    let t0 = Instant::now();
    let p = prepare::preprocess(scan, model, opts)?;
    let mut timings = StageTimings {
        preprocess: elapsed_ms(t0),
        ..Default::default()
    };
    let t1 = Instant::now();
    let mut cands = candidates::candidates(&p, prior, opts, false)?;
    timings.coarse = elapsed_ms(t1);
    let t2 = Instant::now();
    let judged = match contenders::judge(&p, &cands.ranked, opts) {
        Err(CalibError::RobotNotFound { .. }) if cands.shortcut => {
            cands = candidates::candidates(&p, prior, opts, true)?;
            contenders::judge(&p, &cands.ranked, opts)?
        }
        judged => judged?,
    };
    let (camera_from_model, mut estimate, links) =
        link_fit::refine_with_links(&p, model, &judged, opts)?;
    estimate.pixel_noise_m = p.noise_m.unwrap_or(0.0);
    tracing::debug!(
        depth = ?estimate.depth,
        spread_mm = estimate.residual_spread_m * 1e3,
        noise_mm = estimate.pixel_noise_m * 1e3,
        "depth correction"
    );
    timings.fine = elapsed_ms(t2);
    let t3 = Instant::now();
    let (covariance_6x6, camera_error_columns, uncertainty, camera_error, degenerate_directions) =
        covariance::uncertainty(&estimate, &judged.fine, &camera_from_model, opts);
    // The pose's own share of a smooth depth error is this view's, as in its covariance.
    let link_fit = links.map(|mut fit| {
        fit.add_pose_noise(&covariance::smooth_depth_error(&estimate, opts));
        fit
    });
    timings.verify = elapsed_ms(t3);
    timings.total = elapsed_ms(t0);
    let e = &judged.e;
    Ok(Registration {
        camera_from_model,
        covariance_6x6,
        uncertainty,
        camera_error,
        camera_error_columns,
        quality: Quality {
            coverage: e.coverage(),
            free_space_violations: e.violation_fraction(),
            rmse_mm: estimate.rmse_m * 1000.0,
            noise_mm: p.noise_m.map(|m| m * 1e3),
            inlier_fraction: estimate.inlier_fraction,
            points_used: estimate.n_used,
            visible_samples: (e.matched + e.violated + e.missing) as usize,
            hypotheses: cands.hypotheses,
            from_prior: cands.from_prior,
            ambiguity: judged.ambiguity,
            link_support: link_support(&evidence_per_depth(
                &p.range,
                &p.surface.samples,
                &camera_from_model,
                p.surface.fit_depth,
                contenders::tolerances(&p, opts),
            )),
        },
        degenerate_directions,
        depth_scale: estimate
            .scale_estimated
            .then(|| estimate.depth.depth_scale()),
        depth_offset_m: estimate
            .offset_estimated
            .then(|| estimate.depth.range_offset_m()),
        timings_ms: timings,
        link_fit,
        flange_error: None,
    })
}

/// A polished coarse hypothesis.
#[derive(Debug, Clone)]
struct Candidate {
    /// `camera_from_model`.
    pose: Isometry3<f64>,
    /// Its projective evidence at the polishing tolerance.
    e: Evidence,
    /// How tightly the short fit hugs the scan: sharpness overall × on the moving links.
    fit: f64,
}

/// Default of [`RegisterOptions::max_camera_flange_distance_m`]: a wrist camera on a bracket,
/// with room for a tool changer (metres).
const DEFAULT_CAMERA_FLANGE_DISTANCE_M: f64 = 0.3;

// Test builds: the true `camera_from_model` of the trial being probed (see `probe.rs`), so the
// debug log can say how far each hypothesis is from it.
#[cfg(test)]
thread_local! {
    pub(crate) static PROBE_TRUTH: std::cell::Cell<Option<Isometry3<f64>>> =
        const { std::cell::Cell::new(None) };
}

/// Distance of `camera_from_model` from the probed truth as "mm/deg" (test builds only).
#[allow(unused_variables)]
fn probe_err(camera_from_model: &Isometry3<f64>) -> String {
    #[cfg(test)]
    if let Some(t) = PROBE_TRUTH.with(|c| c.get()) {
        let d = camera_from_model.inverse() * t;
        let mm = (camera_from_model.inverse().translation.vector - t.inverse().translation.vector)
            .norm()
            * 1000.0;
        let axis = d
            .rotation
            .axis()
            .map(|a| a.into_inner())
            .unwrap_or_default();
        return format!(
            "{mm:.1}mm/{:.2}deg@[{:.2},{:.2},{:.2}]",
            d.rotation.angle().to_degrees(),
            axis.x,
            axis.y,
            axis.z
        );
    }
    String::new()
}

/// Milliseconds since `since`: the unit of every timing a registration, a run and the bench
/// keep.
pub fn elapsed_ms(since: Instant) -> f64 {
    since.elapsed().as_secs_f64() * 1e3
}
