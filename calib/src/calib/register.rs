//! Registration: one scan (camera frame) against the robot model posed at the measured joints.
//!
//! Pipeline (stage names are the keys of [`StageTimings`]):
//! 1. `preprocess`: range image (pinhole intrinsics estimated from the organized grid), posed
//!    model sampled into surface points with a k-d tree, a coarse grid of scan points.
//! 2. `coarse`: with a prior, a short robust ICP from it and a projective check; without one (or
//!    when the prior fails its check) the global search of [`super::coarse`] (dominant planes →
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
//!    ([`super::links`]): the base holds what it can, the shoulder and upper arm add what they
//!    know beyond their kinematic error.
//! 4. `verify`: coverage of the expected visible model surface and free-space violations on the
//!    dense model samples; degeneracy from the information matrix; the covariance from the
//!    residuals (cluster-robust, per model patch) and the links' prior, over pose and link
//!    parameters together.

use std::time::Instant;

use handeye_hal::ur_dh::DhParams;
use handeye_hal::PointCloud;
use nalgebra::{Isometry3, Matrix3, Matrix6, Point3, Vector3, Vector6};
use rayon::prelude::*;
use serde::Serialize;

use super::coarse::{self, Oriented};
use super::fine::{icp, icp_with_links, IcpResult, LinkPrior, Stage};
use super::links::link_error_model;
use super::range::RangeImage;
use super::surface::{ModelSurface, PosedJoint, PosedModel};
use super::verify::{evidence, evidence_per_depth, score, Evidence, Tolerances};
use super::CalibError;
use crate::model::{GeometryKind, KinematicError, RobotModel};

/// Tuning of [`register`]. `Default` is what the benchmark measures.
#[derive(Debug, Clone, PartialEq)]
pub struct RegisterOptions {
    /// Links up to this many movable joints from the root are fitted (0 base, 1 shoulder, 2
    /// upper arm; `usize::MAX` every link). Deeper links carry more kinematic error; they only
    /// explain scan points. A camera on the flange sees the base and the first links from
    /// close by; a camera fixed in the cell sees the whole arm from afar, where every link's
    /// surface counts (see [`crate::calib::PipelineOptions::new`]).
    pub fit_chain_depth: usize,
    /// Spacing of the model surface samples used for correspondences, metres.
    pub sample_spacing_m: f64,
    /// Spacing of the samples scoring coarse hypotheses, metres.
    pub coarse_spacing_m: f64,
    /// Scan points used by the final ICP (uniformly thinned); more costs time, not accuracy.
    pub max_icp_points: usize,
    /// Estimate the camera's depth-scale error as a 7th parameter (the model's size fixes it).
    pub estimate_depth_scale: bool,
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

/// 1-σ uncertainty of a pose.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, serde::Deserialize)]
pub struct Uncertainty {
    /// Root-sum-square 1-σ of the camera origin's position, mm.
    pub translation_mm: f64,
    /// Root-sum-square 1-σ of the rotation vector, degrees.
    pub rotation_deg: f64,
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
    /// [`RegisterOptions::kinematic_sigma_m`]) as a left perturbation
    /// in the camera frame: `camera_from_model_true = exp(δ) · camera_from_model`,
    /// `δ = (ρ [m], φ [rad])`. `ρ` is also the displacement of the camera origin.
    pub covariance_6x6: Matrix6<f64>,
    /// 1-σ summary of `covariance_6x6`.
    pub uncertainty: Uncertainty,
    /// Support of the result in the scan.
    pub quality: Quality,
    /// Directions the visible geometry leaves unconstrained, empty when the pose is fully
    /// determined: unit 6-vectors `(ρ, φ·L)` in camera axes, the rotation `φ` taken about the
    /// centroid of the fitted points and scaled by their RMS spread `L` (so a pure yaw of a
    /// round base is `(0, 0, 0, axis)`).
    pub degenerate_directions: Vec<Vector6<f64>>,
    /// Estimated depth scale of the camera (measured / true distance) when estimated.
    pub depth_scale: Option<f64>,
    /// Time per stage.
    pub timings_ms: StageTimings,
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
    }
}

/// [`register`] on an already posed model (model frame = the frame of `model`'s parts).
pub fn register_posed(
    scan: &PointCloud,
    model: &PosedModel,
    prior: Option<Isometry3<f64>>,
    opts: &RegisterOptions,
) -> Result<Registration, CalibError> {
    let t0 = Instant::now();
    if scan.points.len() != scan.width as usize * scan.height as usize {
        return Err(CalibError::MalformedScan {
            width: scan.width,
            height: scan.height,
            points: scan.points.len(),
        });
    }
    let range = RangeImage::new(scan)?;
    // Every distance below was chosen for scans as precise as the simulator's structured-light
    // camera; a noisier scan widens them in proportion to its own measured noise.
    let noise_m = range.noise_m();
    let k = noise_scale(noise_m);
    let m = |metres: f64| metres * k;
    let surface = ModelSurface::new(
        model,
        opts.fit_chain_depth,
        opts.sample_spacing_m,
        opts.coarse_spacing_m,
    );
    if surface.coarse.is_empty() {
        return Err(CalibError::NoModelGeometry);
    }
    let pool = ScanPool::new(&range, 150_000);
    // Polishing needs 500 points per hypothesis: drawing them from a sparser pool saves
    // transforming 150 000 points for each of a dozen hypotheses.
    let polish_pool = ScanPool::new(&range, 20_000);
    let mut timings = StageTimings {
        preprocess: ms(t0),
        ..Default::default()
    };

    let t1 = Instant::now();
    let quick_stages = [
        Stage {
            gate_m: m(0.03),
            kernel_m: m(0.01),
            scale: false,
            iterations: 6,
        },
        Stage {
            gate_m: m(0.012),
            kernel_m: m(0.004),
            scale: false,
            iterations: 5,
        },
        Stage {
            gate_m: m(0.006),
            kernel_m: m(0.002),
            scale: false,
            iterations: 6,
        },
    ];
    let quick_tol = Tolerances {
        matched_m: m(0.004),
        free_m: m(0.008),
    };
    // Eye-in-hand: the camera is near the flange (see `max_camera_flange_distance_m`).
    let reach = opts
        .max_camera_flange_distance_m
        .zip(model.model_from_flange);
    let camera_within = |camera_from_model: &Isometry3<f64>, slack_m: f64| {
        reach.is_none_or(|(r, model_from_flange)| {
            let camera = camera_from_model.inverse().translation.vector;
            (camera - model_from_flange.translation.vector).norm() <= r + slack_m
        })
    };
    let plausible_seed = |c: &Isometry3<f64>| camera_within(c, COARSE_CAMERA_SLACK_M);
    let polish = |camera_from_model: &Isometry3<f64>| -> Option<Candidate> {
        if !plausible_seed(camera_from_model) {
            return None;
        }
        let pts = polish_pool.select(&range, &surface, camera_from_model, 500, m(0.03));
        let r = icp(
            &pts,
            &surface,
            &camera_from_model.inverse(),
            1.0,
            &quick_stages,
        )?;
        let pose = r.model_from_camera.inverse();
        if !camera_within(&pose, 0.0) {
            return None;
        }
        let e = evidence(&range, &surface.coarse, &pose, surface.fit_depth, quick_tol);
        Some(Candidate {
            pose,
            e,
            fit: r.sharpness * r.sharpness_moving,
        })
    };
    // Polished candidates; the prior first when it has one.
    let mut cands: Vec<Candidate> = Vec::new();
    let mut from_prior = false;
    let mut n_hyp = 0;
    if let Some(prior) = prior {
        n_hyp += 1;
        if let Some(c) = polish(&prior) {
            if c.e.coverage() >= opts.min_coverage_prior && c.e.violation_fraction() <= 0.1 {
                from_prior = true;
                // A nearly symmetric robot (round base, shoulder without the upper arm in
                // view) also fits turned by half a turn about its axis: compare that too.
                let flipped = half_turn(&c.pose);
                n_hyp += 1;
                cands.extend(polish(&flipped));
            }
            cands.push(c);
        }
    }
    let mut planes_found = 0;
    if !from_prior {
        let pts = coarse::oriented_subsample(&range, 30_000, m(0.008));
        // Hough hypotheses on `planes`, each polished (the strongest also half-turned).
        let search = |planes: &[coarse::Plane], max_out: usize| {
            let hyps = coarse::hypotheses(&range, &surface, &pts, planes, max_out, &plausible_seed);
            tracing::debug!(
                hyps = ?hyps.iter().map(|h| (h.1, probe_err(&h.0))).collect::<Vec<_>>(),
                "coarse hypotheses"
            );
            // The strongest hypotheses are also polished turned by half a turn about the
            // robot's axis: when the visible base and shoulder are nearly symmetric, the Hough
            // vote can rank the half-turned pose above the right one and lose the right one
            // altogether.
            let mut seeds: Vec<Isometry3<f64>> = hyps.iter().map(|h| h.0).collect();
            for (h, _) in hyps.iter().take(HALF_TURN_SEEDS) {
                let flipped = half_turn(h);
                if seeds.iter().all(|c| !near_pose(c, &flipped)) {
                    seeds.push(flipped);
                }
            }
            let polished: Vec<Candidate> = seeds.par_iter().filter_map(&polish).collect();
            (polished, seeds.len())
        };
        let ranked = coarse::support_planes(&pts, opts.seed);
        planes_found = ranked.len();
        // A floor, table or wall the robot is mounted on has (almost) nothing behind it.
        let plausible = ranked
            .first()
            .is_some_and(|r| r.0 as f64 <= MAX_BEHIND_SUPPORT * pts.len() as f64);
        let planes: Vec<coarse::Plane> = ranked.iter().take(SUPPORT_PLANES).map(|r| r.1).collect();
        let (polished, n) = search(&planes, opts.max_hypotheses);
        n_hyp += n;
        cands.extend(polished);
        // No plane the robot could stand on (the floor beyond the camera's range or seen
        // edge-on by a camera level with the base), or none on which it was found: derive
        // mounting planes from the robot's own cylinders.
        let best_coverage = cands.iter().map(|c| c.e.coverage()).fold(0.0, f64::max);
        if !plausible || best_coverage < FALLBACK_COVERAGE {
            let flat: Vec<coarse::Plane> = ranked.iter().map(|r| r.1).collect();
            let derived = coarse::derived_planes(&pts, &flat, &surface, opts.seed);
            planes_found += derived.len();
            // Up to 18 planes (3 axes, both ways, 3 heights): each gets a hypothesis slot.
            let (polished, n) = search(&derived, opts.max_hypotheses.max(derived.len()));
            n_hyp += n;
            cands.extend(polished);
        }
        cands.sort_by(|a, b| score(&b.e).total_cmp(&score(&a.e)));
        // The base is nearly round: the Hough peaks may all sit at the right place but at wrong
        // turns of it (bolt patterns repeat every 60° or 90°), the right turn among none of
        // them. Sweep the best candidate's turn about the robot's axis and polish the turns
        // that explain the scan best.
        if let Some(best) = cands.first() {
            let turns = yaw_sweep(&range, &surface, &best.pose, &cands, &plausible_seed);
            n_hyp += turns.len();
            let polished: Vec<Candidate> = turns.par_iter().filter_map(&polish).collect();
            cands.extend(polished);
        }
    }
    cands.sort_by(|a, b| score(&b.e).total_cmp(&score(&a.e)));
    timings.coarse = ms(t1);
    tracing::debug!(
        cands = ?cands.iter().map(|c| (score(&c.e), c.e.coverage(), c.fit, probe_err(&c.pose))).collect::<Vec<_>>(),
        "polished coarse candidates"
    );
    let Some(Candidate {
        pose: coarse_pose,
        e: coarse_e,
        ..
    }) = cands.first().cloned()
    else {
        let detail = match reach {
            Some((r, _)) => format!(
                "{planes_found} supporting planes, no pose hypothesis converged with the camera within {r:.2} m of the flange (raise the maximum camera-flange distance for a camera mounted farther out)"
            ),
            None => format!("{planes_found} supporting planes, no pose hypothesis converged"),
        };
        return Err(CalibError::RobotNotFound { detail });
    };
    if coarse_e.coverage() < opts.min_coverage_found
        || coarse_e.violation_fraction() > opts.max_violation_found
    {
        return Err(CalibError::RobotNotFound {
            detail: format!(
                "best hypothesis covers {:.0}% of the expected surface with {:.0}% free-space violations",
                100.0 * coarse_e.coverage(),
                100.0 * coarse_e.violation_fraction()
            ),
        });
    }

    let t2 = Instant::now();
    let fine_stages = [
        Stage {
            gate_m: m(0.01),
            kernel_m: m(0.003),
            scale: false,
            iterations: 8,
        },
        Stage {
            gate_m: m(0.005),
            kernel_m: m(0.0015),
            scale: opts.estimate_depth_scale,
            iterations: 10,
        },
        Stage {
            gate_m: m(0.004),
            kernel_m: m(0.001),
            scale: opts.estimate_depth_scale,
            iterations: 15,
        },
    ];
    let tol = Tolerances {
        matched_m: m(opts.match_tolerance_m),
        free_m: m(opts.free_space_tolerance_m),
    };
    // Contenders: the best candidate and distinct runners-up that score almost as well. Each
    // is fitted exactly and judged on dense evidence times sharpness: a nearly symmetric wrong
    // pose covers the scan about as well, but its residuals are several times larger.
    let best_score = score(&coarse_e);
    let mut contenders: Vec<Isometry3<f64>> = vec![coarse_pose];
    for c in cands.iter().skip(1) {
        if contenders.len() >= MAX_CONTENDERS || score(&c.e) < 0.7 * best_score {
            break;
        }
        if contenders.iter().all(|o| !same_basin(o, &c.pose)) {
            contenders.push(c.pose);
        }
    }
    // Whatever their score, the candidate covering the most of its expected surface (a wrong
    // pose that shows more of the model can out-score the right one by far while covering less
    // of what it expects) and the one its short fit hugs most tightly (the turns of a round
    // base with a 6-fold bolt pattern score alike; five or more can crowd the right one out of
    // the slots above, but their shoulders fit worse).
    let plausible: Vec<&Candidate> = cands.iter().filter(|c| score(&c.e) > 0.0).collect();
    let by_coverage = plausible
        .iter()
        .max_by(|a, b| a.e.coverage().total_cmp(&b.e.coverage()));
    let by_fit = plausible.iter().max_by(|a, b| a.fit.total_cmp(&b.fit));
    for c in by_coverage.into_iter().chain(by_fit) {
        if contenders.iter().all(|o| !same_basin(o, &c.pose)) {
            contenders.push(c.pose);
        }
    }
    // Fits `c` exactly on up to `points` scan points through `stages`; `None` if the fit fails
    // or leaves too little of the model covered.
    let fit = |c: &Isometry3<f64>, points: usize, stages: &[Stage]| {
        let pts = pool.select(&range, &surface, c, points, m(0.01));
        let fine = icp(&pts, &surface, &c.inverse(), 1.0, stages)?;
        let pose = fine.model_from_camera.inverse();
        // The verification looks at the scan as measured: apply the scale to the model.
        let e = evidence_scaled(&range, &surface, &pose, 1.0 / fine.kappa, tol);
        if e.coverage() < opts.min_coverage_found
            || e.violation_fraction() > opts.max_violation_found
        {
            return None;
        }
        let key =
            e.coverage() * fine.sharpness * fine.sharpness_moving - 3.0 * e.violation_fraction();
        Some((fine, pose, e, key))
    };
    // Several contenders are judged on a quarter of the points (their misfits differ by
    // several times; the full set only sharpens the winner's estimate), the winner refitted.
    let judge_points = if contenders.len() > 1 {
        opts.max_icp_points / 4
    } else {
        opts.max_icp_points
    };
    let fitted: Vec<(IcpResult, Isometry3<f64>, Evidence, f64)> = contenders
        .iter()
        .filter_map(|c| fit(c, judge_points, &fine_stages))
        .collect();
    // A pose whose expected surface is mostly hidden (behind a link close to the camera) can
    // cover much of the little it expects while explaining a fraction of what the others do:
    // support below half the best counts against it in proportion.
    let most_matched = fitted.iter().map(|f| f.2.matched).fold(0.0, f64::max);
    let judged_key = |f: &(IcpResult, Isometry3<f64>, Evidence, f64)| {
        f.3 * (f.2.matched / (0.5 * most_matched).max(1.0)).min(1.0)
    };
    let Some(win) = (0..fitted.len())
        .max_by(|&a, &b| judged_key(&fitted[a]).total_cmp(&judged_key(&fitted[b])))
    else {
        return Err(CalibError::RobotNotFound {
            detail: "no hypothesis survived the fine alignment with enough coverage".into(),
        });
    };
    // Ambiguity: a different pose is as good as the result only if it covers about as much of
    // the expected surface *and* hugs the scan about as tightly, both overall and on the moving
    // links alone. Tightness is compared on the misfit 1 − sharpness (noise and CAD mismatch
    // give a right pose a floor of ~0.05–0.1, the asymmetric details a nearly symmetric wrong
    // pose misses add to it). The moving links are what breaks the symmetry of a round base:
    // a pose turned about the base's axis fits the base as well as the right one, and only the
    // shoulder's misfit (several times the right pose's) tells them apart.
    let misfit = |f: &IcpResult| (1.0 - f.sharpness, 1.0 - f.sharpness_moving);
    let (win_cov, (win_misfit, win_misfit_moving)) =
        (fitted[win].2.coverage(), misfit(&fitted[win].0));
    let ambiguity = fitted
        .iter()
        .enumerate()
        .filter(|(k, f)| *k != win && !same_pose(&f.1, &fitted[win].1))
        .map(|(_, f)| {
            let (m, mm) = misfit(&f.0);
            let by_cov = f.2.coverage() / win_cov.max(1e-9);
            let by_fit = win_misfit / m.max(1e-9);
            let by_fit_moving = win_misfit_moving / mm.max(1e-9);
            by_cov.min(by_fit).min(by_fit_moving).clamp(0.0, 1.0)
        })
        .fold(0.0, f64::max);
    if tracing::enabled!(tracing::Level::DEBUG) {
        for f in &fitted {
            let loose = Tolerances {
                matched_m: m(0.01),
                free_m: m(0.02),
            };
            let all = evidence(&range, &surface.samples, &f.1, 255, loose);
            let fitd = evidence(&range, &surface.samples, &f.1, surface.fit_depth, tol);
            tracing::debug!(
                err = probe_err(&f.1),
                ?all,
                ?fitd,
                "contender evidence (all links loose / fitted links)"
            );
        }
    }
    tracing::debug!(
        keys = ?fitted.iter().map(|f| (f.3, f.0.sharpness, f.0.sharpness_moving, f.2.coverage(), f.2.violation_fraction(), probe_err(&f.1))).collect::<Vec<_>>(),
        ambiguity,
        "fine contenders"
    );
    let Some(judged) = fitted.into_iter().nth(win) else {
        return Err(CalibError::RobotNotFound {
            detail: "fine alignment found too few correspondences".into(),
        });
    };
    let (fine, camera_from_model, e, _) = if judge_points < opts.max_icp_points {
        fit(&judged.1, opts.max_icp_points, &fine_stages[1..]).unwrap_or(judged)
    } else {
        judged
    };
    // The winner once more with the fitted links' kinematic error as parameters (see
    // `super::links`); the contenders were judged on the fit that trusts the posed links, and
    // a refinement that wanders off is not trusted. The scan's residual variance that weighs
    // the links' prior is the even fit's effective one (its sandwich over its information).
    let link_prior = LinkPrior {
        a: link_error_model(model, surface.fit_depth, &opts.kinematic_error),
        residual_var: (fine.cov6 * fine.info6).trace() / 6.0,
    };
    let (camera_from_model, estimate) = if link_prior.params() > 0 {
        let pts = pool.select(
            &range,
            &surface,
            &camera_from_model,
            opts.max_icp_points,
            m(0.01),
        );
        let stage = Stage {
            gate_m: m(0.004),
            kernel_m: m(0.001),
            scale: fine.scale_estimated,
            iterations: 15,
        };
        match icp_with_links(
            &pts,
            &surface,
            &fine.model_from_camera,
            fine.kappa,
            &[stage],
            &link_prior,
        ) {
            Some((r, z))
                if super::within(
                    &r.model_from_camera.inverse(),
                    &camera_from_model,
                    m(0.01),
                    2.0 * k,
                ) =>
            {
                tracing::debug!(z = ?z.as_slice(), "link parameters (prior 1σ units)");
                (r.model_from_camera.inverse(), r)
            }
            other => {
                // Its covariance would leave the links' error out: no result rather than an
                // overconfident one.
                return Err(CalibError::RobotNotFound {
                    detail: format!(
                        "the fit with the arm's kinematic error {} the best pose",
                        if other.is_some() {
                            "wandered away from"
                        } else {
                            "did not converge near"
                        }
                    ),
                });
            }
        }
    } else {
        (camera_from_model, fine.clone())
    };
    timings.fine = ms(t2);

    let t3 = Instant::now();
    let (covariance_6x6, uncertainty, degenerate_directions) =
        uncertainty(&estimate, &fine, &camera_from_model, opts);
    timings.verify = ms(t3);
    timings.total = ms(t0);
    Ok(Registration {
        camera_from_model,
        covariance_6x6,
        uncertainty,
        quality: Quality {
            coverage: e.coverage(),
            free_space_violations: e.violation_fraction(),
            rmse_mm: estimate.rmse_m * 1000.0,
            inlier_fraction: estimate.inlier_fraction,
            points_used: estimate.n_used,
            visible_samples: (e.matched + e.violated + e.missing) as usize,
            hypotheses: n_hyp,
            from_prior,
            ambiguity,
            link_support: link_support(&evidence_per_depth(
                &range,
                &surface.samples,
                &camera_from_model,
                surface.fit_depth,
                tol,
            )),
        },
        degenerate_directions,
        depth_scale: estimate.scale_estimated.then_some(1.0 / estimate.kappa),
        timings_ms: timings,
    })
}

/// The noise of the scans every distance of [`register_posed`] was chosen for, metres: the
/// simulator's structured-light camera measures 0.02–0.15 mm by [`RangeImage::noise_m`] (its
/// documented 0.25 mm at 1 m is the upper end of its range).
const TUNED_NOISE_M: f64 = 0.25e-3;

/// How much wider than tuned every distance of the registration is for a scan of this
/// measured noise: 1 for scans as precise as the tuning (or when the noise cannot be measured),
/// the noise over [`TUNED_NOISE_M`] for noisier ones (a consumer RGB-D camera at 1.3 m measures
/// about 0.7 mm: 2.9), at most 8.
fn noise_scale(noise_m: Option<f64>) -> f64 {
    noise_m.map_or(1.0, |n| (n / TUNED_NOISE_M).clamp(1.0, 8.0))
}

/// Turns of `best` about the model's z axis (10° steps) that explain the scan best, up to
/// [`SWEEP_KEEP`], at least 20° apart and away from every candidate in `cands`.
fn yaw_sweep(
    range: &RangeImage<'_>,
    surface: &ModelSurface,
    best: &Isometry3<f64>,
    cands: &[Candidate],
    admissible: &(dyn Fn(&Isometry3<f64>) -> bool + Sync),
) -> Vec<Isometry3<f64>> {
    // Loose, like the Hough peaks' scoring: a turn 5° off the right one moves the shoulder's
    // samples by ~10 mm.
    let tol = Tolerances {
        matched_m: 0.015,
        free_m: 0.03,
    };
    let step = 10f64.to_radians();
    let mut turns: Vec<(Isometry3<f64>, f64)> = (1..36)
        .into_par_iter()
        .map(|k| best * Isometry3::rotation(Vector3::z() * (k as f64 * step)))
        .filter(|pose| admissible(pose))
        .map(|pose| {
            let e = evidence(range, &surface.coarse, &pose, surface.fit_depth, tol);
            (pose, score(&e))
        })
        .collect();
    turns.sort_by(|a, b| b.1.total_cmp(&a.1));
    let top = turns.first().map_or(0.0, |t| t.1);
    let apart = |a: &Isometry3<f64>, b: &Isometry3<f64>, deg: f64| {
        (a.inverse() * b).rotation.angle() > deg.to_radians()
    };
    let mut out: Vec<Isometry3<f64>> = Vec::new();
    for (pose, sc) in turns {
        if out.len() >= SWEEP_KEEP || sc < 0.5 * top || sc <= 0.0 {
            break;
        }
        if cands.iter().all(|c| apart(&c.pose, &pose, 10.0))
            && out.iter().all(|o| apart(o, &pose, 20.0))
        {
            out.push(pose);
        }
    }
    out
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

/// Planes of the scan the Hough vote searches for the robot, most plausible first.
const SUPPORT_PLANES: usize = 3;
/// Default of [`RegisterOptions::max_camera_flange_distance_m`]: a wrist camera on a bracket,
/// with room for a tool changer (metres).
const DEFAULT_CAMERA_FLANGE_DISTANCE_M: f64 = 0.3;
/// How far a coarse hypothesis may put the camera beyond that before it is polished: a
/// 15 mm / 5° Hough cell moves a camera 0.8 m away by up to ~7 cm (metres).
const COARSE_CAMERA_SLACK_M: f64 = 0.1;

/// Fraction of the scan points that may lie behind a plane the robot stands on (flying
/// pixels, past its edge).
const MAX_BEHIND_SUPPORT: f64 = 0.01;

/// Below this coverage of its best polished hypothesis, the search on the scan's planes has
/// not found the robot, and planes derived from its shape are searched too (right poses cover
/// 0.9 or more).
const FALLBACK_COVERAGE: f64 = 0.85;

/// Turns of the best coarse candidate polished after the sweep.
const SWEEP_KEEP: usize = 4;

/// Candidates fitted exactly and compared.
const MAX_CONTENDERS: usize = 4;

/// Strongest Hough hypotheses whose half-turn is polished too.
const HALF_TURN_SEEDS: usize = 3;

/// `camera_from_model` turned by half a turn about the model's z axis (the robot's first axis).
fn half_turn(camera_from_model: &Isometry3<f64>) -> Isometry3<f64> {
    camera_from_model * Isometry3::rotation(Vector3::z() * std::f64::consts::PI)
}

/// Whether two `camera_from_model` poses are the same result (camera within 2 mm and 0.3°).
fn same_pose(a: &Isometry3<f64>, b: &Isometry3<f64>) -> bool {
    let d = a.inverse() * b;
    (a.inverse().translation.vector - b.inverse().translation.vector).norm() < 0.002
        && d.rotation.angle() < 0.3f64.to_radians()
}

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

/// Whether two polished candidates would converge to the same fine fit (model origin within
/// 2 cm, rotation within 10°): one contender stands for both.
fn same_basin(a: &Isometry3<f64>, b: &Isometry3<f64>) -> bool {
    super::within(a, b, 0.02, 10.0)
}

/// Whether two `camera_from_model` seeds are the same hypothesis (model origin within 1 cm,
/// rotation within 2°): both would polish to the same candidate.
fn near_pose(a: &Isometry3<f64>, b: &Isometry3<f64>) -> bool {
    super::within(a, b, 0.01, 2.0)
}

fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1000.0
}

/// Evidence on the dense samples of the fitted links, for a camera whose depths are `s` times
/// the true ones: the model is placed with `camera_from_model` and scaled by `s` about the
/// camera origin before projection.
fn evidence_scaled(
    range: &RangeImage<'_>,
    surface: &ModelSurface,
    camera_from_model: &Isometry3<f64>,
    s: f64,
    tol: Tolerances,
) -> Evidence {
    if (s - 1.0).abs() < 1e-12 {
        return evidence(
            range,
            &surface.samples,
            camera_from_model,
            surface.fit_depth,
            tol,
        );
    }
    // Scaling about the camera origin keeps rays: project the true pose, compare the measured
    // depth divided by s. Equivalent: scale the samples' camera-frame positions by s.
    let scaled_samples: Vec<super::surface::Sample> = surface
        .samples
        .iter()
        .filter(|x| x.depth as usize <= surface.fit_depth)
        .map(|x| {
            let mut y = *x;
            let pc = camera_from_model * x.p;
            y.p = camera_from_model.inverse() * Point3::from(pc.coords * s);
            y
        })
        .collect();
    evidence(
        range,
        &scaled_samples,
        camera_from_model,
        surface.fit_depth,
        tol,
    )
}

/// Covariance in the camera frame (inflated), its 1-σ summary and the degenerate directions.
///
/// `estimate` is the fit whose pose is returned (its covariance is the result's, plus the
/// model's accuracy); `even` is the fit that trusts the posed links, whose information tells
/// which directions the visible geometry constrains.
fn uncertainty(
    estimate: &IcpResult,
    even: &IcpResult,
    camera_from_model: &Isometry3<f64>,
    opts: &RegisterOptions,
) -> (Matrix6<f64>, Uncertainty, Vec<Vector6<f64>>) {
    let r: Matrix3<f64> = camera_from_model.rotation.to_rotation_matrix().into_inner();
    let t = camera_from_model.translation.vector;
    let mut ad = Matrix6::zeros();
    ad.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
    ad.fixed_view_mut::<3, 3>(0, 3)
        .copy_from(&(t.cross_matrix() * r));
    ad.fixed_view_mut::<3, 3>(3, 3).copy_from(&r);
    let (floor_m, floor_rad) = opts.model_accuracy;
    let floor = Matrix6::from_diagonal(&Vector6::new(
        floor_m.powi(2) / 3.0,
        floor_m.powi(2) / 3.0,
        floor_m.powi(2) / 3.0,
        floor_rad.powi(2) / 3.0,
        floor_rad.powi(2) / 3.0,
        floor_rad.powi(2) / 3.0,
    ));
    let cov = ad * estimate.cov6 * ad.transpose() + floor;
    let tr = |k: usize| {
        (cov[(k, k)] + cov[(k + 1, k + 1)] + cov[(k + 2, k + 2)])
            .max(0.0)
            .sqrt()
    };
    let unc = Uncertainty {
        translation_mm: tr(0) * 1000.0,
        rotation_deg: tr(3).to_degrees(),
    };
    // Degeneracy: eigen-decomposition of the information about the correspondences' centroid
    // c (so rotations and translations decouple), rotations scaled by their spread L.
    // ρ = ρ' + [c]× φ maps the centred parameters to the model-origin ones.
    let c = even.centroid.coords;
    let mut a = Matrix6::identity();
    a.fixed_view_mut::<3, 3>(0, 3).copy_from(&c.cross_matrix());
    let l = even.spread_m.max(0.01);
    let s = Matrix6::from_diagonal(&Vector6::new(1.0, 1.0, 1.0, 1.0 / l, 1.0 / l, 1.0 / l));
    let to_origin = a * s;
    let info = to_origin.transpose() * even.info6 * to_origin;
    let eig = info.symmetric_eigen();
    let lmax = eig.eigenvalues.max();
    tracing::debug!(ratios = ?eig.eigenvalues.iter().map(|e| e / lmax).collect::<Vec<_>>(), "information eigenvalues");
    let mut degenerate = Vec::new();
    for k in 0..6 {
        if eig.eigenvalues[k] < opts.degeneracy_ratio * lmax {
            let v = eig.eigenvectors.column(k);
            let mut dc = Vector6::zeros();
            dc.fixed_rows_mut::<3>(0)
                .copy_from(&(r * v.fixed_rows::<3>(0)));
            dc.fixed_rows_mut::<3>(3)
                .copy_from(&(r * v.fixed_rows::<3>(3)));
            degenerate.push(dc.normalize());
        }
    }
    (cov, unc, degenerate)
}

/// A coarse grid of scan pixels from which ICP points are drawn per hypothesis.
#[derive(Debug)]
struct ScanPool {
    idx: Vec<usize>,
}

impl ScanPool {
    fn new(range: &RangeImage<'_>, target: usize) -> ScanPool {
        let idx = range
            .grid(target, 31)
            .filter(|&i| range.points[i].z > 0.0)
            .collect();
        ScanPool { idx }
    }

    /// Up to `n` scan points (with normals) near the fitted links posed by `camera_from_model`.
    fn select(
        &self,
        range: &RangeImage<'_>,
        surface: &ModelSurface,
        camera_from_model: &Isometry3<f64>,
        n: usize,
        margin_m: f64,
    ) -> Vec<Oriented> {
        let (lo, hi) = surface.fit_bounds(margin_m);
        let model_from_camera = camera_from_model.inverse();
        let near: Vec<usize> = self
            .idx
            .iter()
            .copied()
            .filter(|&i| {
                let p = model_from_camera * range.points[i].cast::<f64>();
                p.x >= lo.x
                    && p.y >= lo.y
                    && p.z >= lo.z
                    && p.x <= hi.x
                    && p.y <= hi.y
                    && p.z <= hi.z
            })
            .collect();
        let step = (near.len() as f64 / n as f64).max(1.0);
        let mut out = Vec::with_capacity(n.min(near.len()));
        let mut k = 0.0;
        while (k as usize) < near.len() {
            let i = near[k as usize];
            if let (Some(p), Some(nn)) = (range.point(i), range.normal(i, 0.003)) {
                out.push(Oriented {
                    p: p.cast::<f64>(),
                    n: nn,
                });
            }
            k += step;
        }
        out
    }
}

impl ModelSurface {
    /// Bounding box of the fitted links' samples (model frame), grown by `margin_m`.
    pub(crate) fn fit_bounds(&self, margin_m: f64) -> (Point3<f64>, Point3<f64>) {
        let mut lo = Point3::new(f64::INFINITY, f64::INFINITY, f64::INFINITY);
        let mut hi = Point3::new(f64::NEG_INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY);
        for s in self
            .coarse
            .iter()
            .filter(|s| s.depth as usize <= self.fit_depth)
        {
            lo = lo.inf(&s.p);
            hi = hi.sup(&s.p);
        }
        let m = Vector3::repeat(margin_m);
        (lo - m, hi + m)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::testutil::{base_only, look_at, render, toy_robot, Scene};

    fn errors(a: &Isometry3<f64>, b: &Isometry3<f64>) -> (f64, f64) {
        let d = a.inverse() * b;
        // Camera-origin position error and rotation error.
        let ca = a.inverse().translation.vector;
        let cb = b.inverse().translation.vector;
        ((ca - cb).norm() * 1000.0, d.rotation.angle().to_degrees())
    }

    #[test]
    fn recovers_pose_without_prior() {
        let q = [0.7, -1.2, 1.0];
        let model = toy_robot(&q);
        let truth = look_at(Point3::new(0.45, -0.3, 0.55), Point3::new(0.05, 0.0, 0.1));
        let scan = render(&model, &truth, &Scene::default());
        let reg = register_posed(&scan, &model, None, &RegisterOptions::default()).expect("found");
        let (t, r) = errors(&reg.camera_from_model, &truth);
        eprintln!("{reg:?}\nerr {t:.3} mm {r:.4} deg");
        assert!(t < 1.0 && r < 0.2, "error {t} mm {r} deg");
        assert!(reg.quality.coverage > 0.8, "{:?}", reg.quality);
        assert!(reg.degenerate_directions.is_empty());
    }

    #[test]
    fn recovers_pose_with_prior_and_rejects_empty_scene() {
        let q = [-0.4, -1.5, 1.2];
        let model = toy_robot(&q);
        let truth = look_at(Point3::new(-0.2, 0.5, 0.6), Point3::new(0.0, 0.05, 0.1));
        let scan = render(
            &model,
            &truth,
            &Scene {
                seed: 3,
                ..Scene::default()
            },
        );
        let prior = Isometry3::new(
            Vector3::new(0.01, -0.008, 0.012),
            Vector3::new(0.02, -0.03, 0.04),
        ) * truth;
        let reg =
            register_posed(&scan, &model, Some(prior), &RegisterOptions::default()).expect("found");
        assert!(reg.quality.from_prior);
        let (t, r) = errors(&reg.camera_from_model, &truth);
        assert!(t < 1.0 && r < 0.2, "error {t} mm {r} deg");

        // A floor and nothing else: not found, with or without a prior.
        let empty = render(&PosedModel::default(), &truth, &Scene::default());
        let e = register_posed(&empty, &model, None, &RegisterOptions::default());
        assert!(matches!(e, Err(CalibError::RobotNotFound { .. })), "{e:?}");
        let e = register_posed(&empty, &model, Some(truth), &RegisterOptions::default());
        assert!(matches!(e, Err(CalibError::RobotNotFound { .. })), "{e:?}");
    }

    #[test]
    fn wrong_prior_is_recovered_by_the_global_search() {
        let q = [0.3, -1.0, 0.8];
        let model = toy_robot(&q);
        let truth = look_at(Point3::new(0.5, 0.3, 0.5), Point3::new(0.0, 0.0, 0.1));
        let scan = render(
            &model,
            &truth,
            &Scene {
                seed: 4,
                ..Scene::default()
            },
        );
        // 90° of yaw and 10 cm off: the prior cannot be refined into the right pose.
        let wrong = truth * Isometry3::new(Vector3::new(0.1, 0.0, 0.0), Vector3::z() * 1.57);
        let reg =
            register_posed(&scan, &model, Some(wrong), &RegisterOptions::default()).expect("found");
        assert!(!reg.quality.from_prior);
        let (t, r) = errors(&reg.camera_from_model, &truth);
        assert!(t < 1.0 && r < 0.2, "error {t} mm {r} deg");
    }

    #[test]
    fn covariance_shrinks_with_points_and_round_base_is_degenerate() {
        let q = [0.7, -1.2, 1.0];
        let model = toy_robot(&q);
        let truth = look_at(Point3::new(0.45, -0.3, 0.55), Point3::new(0.05, 0.0, 0.1));
        let scan = render(
            &model,
            &truth,
            &Scene {
                seed: 5,
                ..Scene::default()
            },
        );
        let few = RegisterOptions {
            max_icp_points: 1000,
            ..RegisterOptions::default()
        };
        let many = RegisterOptions {
            max_icp_points: 8000,
            ..RegisterOptions::default()
        };
        let a = register_posed(&scan, &model, Some(truth), &few).expect("found");
        let b = register_posed(&scan, &model, Some(truth), &many).expect("found");
        assert!(b.quality.points_used > 2 * a.quality.points_used);
        assert!(
            b.uncertainty.translation_mm < a.uncertainty.translation_mm,
            "{:?} {:?}",
            a.uncertainty,
            b.uncertainty
        );
        assert!(b.covariance_6x6.trace() < a.covariance_6x6.trace());

        let base = base_only();
        let scan = render(
            &base,
            &truth,
            &Scene {
                seed: 6,
                ..Scene::default()
            },
        );
        let reg =
            register_posed(&scan, &base, Some(truth), &RegisterOptions::default()).expect("found");
        // The free direction is a rotation about the base axis (model z) seen in the camera.
        let axis_cam = truth.rotation * Vector3::z();
        let about_axis = reg.degenerate_directions.iter().any(|d| {
            let rot = Vector3::new(d[3], d[4], d[5]);
            rot.norm() > 0.7 && rot.normalize().dot(&axis_cam).abs() > 0.95
        });
        assert!(about_axis, "{:?}", reg.degenerate_directions);
    }
}

#[cfg(test)]
mod ur_tests {
    use super::*;
    use crate::calib::testutil::{look_at, render, Scene};
    use crate::testutil::shared_robots;

    /// Real UR5e meshes, ray-cast with the test renderer (floor, light noise), no prior.
    #[test]
    #[ignore = "slow in debug; run with --release -- --ignored"]
    fn ur5e_real_meshes_without_prior() {
        let Some(root) = shared_robots() else { return };
        let model = RobotModel::load(&root.join("ur/ur5e/ur5e.urdf")).expect("ur5e loads");
        for (k, (q, eye)) in [
            (
                [0.3, -1.2, 1.4, -1.8, -1.5, 0.0],
                Point3::new(0.35, 0.35, 0.6),
            ),
            (
                [-2.0, -1.9, 1.9, -1.6, -1.6, 0.3],
                Point3::new(-0.5, 0.2, 0.55),
            ),
            (
                [1.2, -2.2, 2.0, -1.0, -1.5, 0.0],
                Point3::new(0.1, -0.55, 0.5),
            ),
        ]
        .iter()
        .enumerate()
        {
            let posed = posed_model(&model, q).expect("posed");
            let truth = look_at(*eye, Point3::new(0.0, 0.0, 0.12));
            let scene = Scene {
                width: 640,
                height: 480,
                f: 560.0,
                seed: k as u64,
                ..Scene::default()
            };
            let scan = render(&posed, &truth, &scene);
            let reg =
                register_posed(&scan, &posed, None, &RegisterOptions::default()).expect("found");
            let d = reg.camera_from_model.inverse() * truth;
            let t_mm = (reg.camera_from_model.inverse().translation.vector
                - truth.inverse().translation.vector)
                .norm()
                * 1000.0;
            eprintln!(
                "view {k}: {t_mm:.3} mm {:.4} deg  {:?} {:?} scale {:?} degenerate {}",
                d.rotation.angle().to_degrees(),
                reg.quality,
                reg.timings_ms,
                reg.depth_scale,
                reg.degenerate_directions.len()
            );
            assert!(t_mm < 1.0 && d.rotation.angle().to_degrees() < 0.2);
        }
    }
}

#[cfg(test)]
mod sim_tests {
    use super::*;
    use crate::calib::{gate, solve, FrameInput, GateThresholds, Mount, SolveOptions};
    use crate::sim::{
        simulate_scan, Intrinsics, KinematicError, Placement, ScanRequest, SimSettings,
        SimulatedScan,
    };
    use crate::testutil::shared_robots;

    /// The UR5e, a wrist camera 8 cm off the flange tilted 15°, and planned views of its base.
    pub(super) type Ur5eViews = (RobotModel, Isometry3<f64>, Vec<Vec<f64>>);

    /// [`Ur5eViews`] with `count` planned views (seeded); `None` without `../shared/robots`.
    pub(super) fn ur5e_views(count: usize, seed: u64) -> Option<Ur5eViews> {
        let root = shared_robots()?;
        let model = RobotModel::load(&root.join("ur/ur5e/ur5e.urdf")).expect("ur5e loads");
        let mount = Isometry3::new(
            Vector3::new(0.0, -0.08, 0.03),
            Vector3::new(-15f64.to_radians(), 0.0, 0.0),
        );
        let planner = crate::plan::ViewPlanner::new(
            &model,
            mount,
            Intrinsics::compact_1280x960(),
            crate::plan::ViewConstraints::default(),
        );
        let views = planner.generate(count, seed).expect("views");
        Some((model, mount, views))
    }

    /// A 1280×960 scan from the wrist camera at `q`: default noise and cell, the real arm off
    /// its model by `kinematic_error`.
    fn wrist_scan(
        model: &RobotModel,
        mount: Isometry3<f64>,
        q: &[f64],
        kinematic_error: KinematicError,
        seed: u64,
    ) -> SimulatedScan {
        let settings = SimSettings {
            kinematic_error,
            ..SimSettings::default()
        };
        let req = ScanRequest::new(
            model,
            q.to_vec(),
            Placement::EyeInHand {
                flange_from_camera: mount,
            },
            Intrinsics::compact_1280x960(),
            &settings,
            seed,
        );
        simulate_scan(&req).expect("simulated")
    }

    /// Issue 23: a scan whose every 7th pixel has no depth (invalid pixels repeating with the
    /// period of the search's sampling grid) is registered from the rest, as the clean one.
    #[test]
    fn issue_23_periodic_holes_leave_the_rest_used() {
        let Some((model, mount, views)) = ur5e_views(1, 21) else {
            return;
        };
        let mut scan = wrist_scan(&model, mount, &views[0], KinematicError::none(), 3);
        let truth = scan.truth.camera_from_model;
        for p in scan.cloud.points.iter_mut().step_by(7) {
            *p = Point3::new(f32::NAN, f32::NAN, f32::NAN);
        }
        let opts = RegisterOptions {
            kinematic_error: KinematicError::none(),
            ..RegisterOptions::default()
        };
        let reg = register(&scan.cloud, &model, &views[0], None, &opts).expect("found");
        let off = (reg.camera_from_model.translation.vector - truth.translation.vector).norm();
        assert!(off < 1e-3, "{off} m off");
        assert!(reg.quality.coverage > 0.8, "{:?}", reg.quality);
    }

    /// The shoulder and upper arm are posed with the nominal kinematics; the real arm's zero
    /// offsets and link lengths move them, and the yaw of the round base follows them. Their
    /// displacements are estimated with the arm's kinematic error as prior: the result is
    /// closer than a fit that trusts the posed links, and its uncertainty covers the error (a
    /// fit that trusts them is 3–10× overconfident), without being uselessly loose.
    #[test]
    fn uncertainty_covers_the_arms_kinematic_error() {
        let Some((model, mount, views)) = ur5e_views(4, 5) else {
            return;
        };
        // Five times a UR's factory-calibration deltas: the kinematic error dominates noise.
        let arm = KinematicError {
            joint_offset_sigma_rad: 0.0015,
            link_length_sigma_m: 0.0015,
            axis_misalignment_sigma_rad: 0.0005,
        };
        let (mut ratios, mut ratios_trusting) = (Vec::new(), Vec::new());
        let (mut errors, mut errors_trusting) = (Vec::new(), Vec::new());
        for (k, q) in views.iter().enumerate() {
            let scan = wrist_scan(&model, mount, q, arm, 40 + k as u64);
            let posed = posed_model(&model, q).expect("posed");
            let error_mm = |reg: &Registration| {
                (reg.camera_from_model.inverse().translation.vector
                    - scan.truth.model_from_camera.translation.vector)
                    .norm()
                    * 1e3
            };
            let opts = RegisterOptions {
                kinematic_error: arm,
                ..RegisterOptions::default()
            };
            let reg = register_posed(&scan.cloud, &posed, None, &opts).expect("registered");
            errors.push(error_mm(&reg));
            ratios.push(error_mm(&reg) / reg.uncertainty.translation_mm);
            // The same scan registered as if the arm were exactly its model.
            let exact = RegisterOptions {
                kinematic_error: KinematicError::none(),
                ..RegisterOptions::default()
            };
            let trusting = register_posed(&scan.cloud, &posed, None, &exact).expect("registered");
            errors_trusting.push(error_mm(&trusting));
            ratios_trusting.push(error_mm(&trusting) / trusting.uncertainty.translation_mm);
        }
        eprintln!(
            "error {errors:.3?} mm, / reported σ {ratios:.2?}; trusting the posed links \
             {errors_trusting:.3?} mm, / σ {ratios_trusting:.2?}"
        );
        assert!(
            ratios.iter().all(|r| *r < 3.0),
            "an error beyond 3σ: {ratios:?}"
        );
        ratios.sort_by(f64::total_cmp);
        assert!(ratios[1] > 0.15, "σ uselessly loose: {ratios:?}");
        let sum = |v: &[f64]| v.iter().sum::<f64>();
        assert!(
            sum(&errors) < sum(&errors_trusting),
            "{errors:?} vs {errors_trusting:?}"
        );
        // The scenario is dominated by the kinematic error: the residuals alone do not cover it.
        assert!(
            ratios_trusting.iter().filter(|r| **r > 3.0).count() >= 2,
            "{ratios_trusting:?}"
        );
    }

    /// Eye-in-hand, the camera rides on the flange: poses that put it farther than
    /// `max_camera_flange_distance_m` are not considered. This camera is 8.5 cm off the flange:
    /// allowed 2 cm, no pose is found (and the error says what to raise); unconstrained (a
    /// camera fixed in the cell), the same pose as with the default 30 cm.
    #[test]
    fn the_camera_is_sought_near_the_flange() {
        let Some((model, mount, views)) = ur5e_views(1, 3) else {
            return;
        };
        let scan = wrist_scan(&model, mount, &views[0], KinematicError::default(), 11);
        let posed = posed_model(&model, &views[0]).expect("posed");
        let with = |distance| RegisterOptions {
            max_camera_flange_distance_m: distance,
            ..RegisterOptions::default()
        };
        match register_posed(&scan.cloud, &posed, None, &with(Some(0.02))) {
            Err(CalibError::RobotNotFound { detail }) => {
                assert!(detail.contains("0.02 m of the flange"), "{detail}")
            }
            other => panic!("expected robot not found, got {other:?}"),
        }
        let near = register_posed(&scan.cloud, &posed, None, &RegisterOptions::default())
            .expect("registered");
        let free = register_posed(&scan.cloud, &posed, None, &with(None)).expect("registered");
        assert!(same_pose(&near.camera_from_model, &free.camera_from_model));
        let err_mm = (near.camera_from_model.inverse().translation.vector
            - scan.truth.model_from_camera.translation.vector)
            .norm()
            * 1e3;
        assert!(err_mm < 2.0, "{err_mm} mm");
    }

    /// Simulated UR5e, 1280×960, default noise, cell and kinematic error, no prior; the model
    /// is posed with the controller's calibration (what the controller reports).
    #[test]
    fn simulated_ur5e_scan_is_registered_and_closes_the_chain() {
        let Some((model, mount, mut views)) = ur5e_views(1, 3) else {
            return;
        };
        let q = views.remove(0);
        let scan = wrist_scan(&model, mount, &q, KinematicError::default(), 11);
        let truth = &scan.truth;
        let posed = posed_model_with_kinematics(&model, &q, Some(&truth.joint_origin_errors))
            .expect("posed");
        let reg = register_posed(&scan.cloud, &posed, None, &RegisterOptions::default())
            .expect("registered");
        let frames = [FrameInput {
            view: 0,
            camera_from_model: reg.camera_from_model,
            model_from_flange: Some(truth.model_from_flange_reported),
        }];
        let sol = solve(Mount::EyeInHand, &frames, &SolveOptions::default()).expect("solved");
        let f_true = truth.flange_from_camera.expect("eye-in-hand truth");
        let t = (sol.estimate.translation.vector - f_true.translation.vector).norm() * 1000.0;
        let r = sol
            .estimate
            .rotation
            .angle_to(&f_true.rotation)
            .to_degrees();
        eprintln!("{t:.3} mm {r:.4} deg {:?}", reg.quality);
        assert!(t < 1.0 && r < 0.2, "hand-eye error {t} mm {r} deg");
        let v = gate(
            std::slice::from_ref(&reg),
            &sol,
            None,
            &GateThresholds::default(),
        );
        assert!(v.passed(), "{v:?}");
        assert!(reg.depth_scale.is_some_and(|s| (s - 1.0015).abs() < 0.001));
    }
}

#[cfg(test)]
mod controller_kinematics_tests {
    use super::*;
    use crate::calib::{solve, FrameInput, Mount, SolveOptions};
    use crate::sim::{simulate_scan, Intrinsics, Placement, ScanRequest, SimSettings};
    use crate::testutil::shared_robots;

    /// `flange_from_camera` from one registration and the reported flange pose: its errors
    /// against `mount` (mm, degrees), as `bench::run_trial` measures them.
    fn hand_eye_error(
        reg: &Registration,
        model_from_flange_reported: Isometry3<f64>,
        mount: &Isometry3<f64>,
    ) -> (f64, f64) {
        let frame = FrameInput {
            view: 0,
            camera_from_model: reg.camera_from_model,
            model_from_flange: Some(model_from_flange_reported),
        };
        let sol = solve(Mount::EyeInHand, &[frame], &SolveOptions::default()).expect("solved");
        let t = (sol.estimate.translation.vector - mount.translation.vector).norm() * 1e3;
        let r = (mount.inverse() * sol.estimate)
            .rotation
            .angle()
            .to_degrees();
        (t, r)
    }

    fn median(mut v: Vec<f64>) -> f64 {
        v.sort_by(f64::total_cmp);
        let n = v.len();
        if n % 2 == 1 {
            v[n / 2]
        } else {
            0.5 * (v[n / 2 - 1] + v[n / 2])
        }
    }

    /// The posed model's flange is the controller's (DH forward kinematics in the model frame).
    #[test]
    fn the_posed_flange_is_the_controllers() {
        let Some(root) = shared_robots() else { return };
        let model = RobotModel::load(&root.join("ur/ur5e/ur5e.urdf")).expect("ur5e loads");
        let dh = handeye_hal::ur_dh::PhysicalArm::factory(handeye_hal::ur_dh::UrModel::Ur5e, 4)
            .controller_dh();
        assert!(
            dh.d[1].abs() > 1.0,
            "a real controller's parallel-axis DH: {:?}",
            dh.d
        );
        let q = [0.4, -1.3, 1.5, -2.0, -1.4, 0.7];
        let posed = posed_model_with_controller_kinematics(&model, &q, &dh).expect("posed");
        let want = model.frame_pose("base", &q).expect("base") * dh.forward(&q);
        let got = posed.model_from_flange.expect("flange");
        assert!((got.to_homogeneous() - want.to_homogeneous()).norm() < 1e-9);
        assert_eq!(posed.joints.len(), 6);
        assert!(matches!(
            posed_model_with_controller_kinematics(&model, &q[..5], &dh),
            Err(CalibError::JointCountMismatch { .. })
        ));
        // Another arm's kinematics (a UR5's on a UR5e model, as `model = "ur5"` on a UR5e
        // controller would give) are refused, naming the link.
        let ur5 = handeye_hal::ur_dh::PhysicalArm::factory(handeye_hal::ur_dh::UrModel::Ur5, 4)
            .controller_dh();
        let e = posed_model_with_controller_kinematics(&model, &q, &ur5).expect_err("a UR5's");
        assert!(matches!(e, CalibError::KinematicsNotThisArm { .. }), "{e}");
        assert!(e.to_string().contains("robot.model"), "{e}");
    }

    /// Issue 26: a fitted link posed where the arm has none (as by kinematics that are not the
    /// arm's, which still leave it in view): the fitted links disagree, the scan sees through
    /// one of them where the model puts it beside the others, and the gate says so; posed by
    /// the arm's own DH, every fitted link is supported.
    #[test]
    fn a_link_posed_where_the_arm_has_none_shows_in_its_support() {
        let Some((model, mount, mut views)) = super::sim_tests::ur5e_views(1, 21) else {
            return;
        };
        let intrinsics = Intrinsics::compact_1280x960();
        let ur = model.ur_model().expect("UR");
        let q = views.remove(0);
        let arm = handeye_hal::ur_dh::PhysicalArm::factory(ur, 2);
        let req = ScanRequest::new(
            &model,
            q.clone(),
            Placement::EyeInHand {
                flange_from_camera: mount,
            },
            intrinsics,
            &SimSettings::default(),
            7,
        )
        .with_arm(arm);
        let scan = simulate_scan(&req).expect("simulated");
        let truth = scan.truth.camera_from_model;
        let posed = posed_model_with_controller_kinematics(&model, &q, &arm.controller_dh())
            .expect("posed");
        let opts = RegisterOptions::default();
        let right = register_posed(&scan.cloud, &posed, Some(truth), &opts).expect("registered");
        let support = right.quality.link_support;
        assert!(
            support.iter().all(|s| s.is_some_and(|s| s > 0.9)),
            "{support:?}"
        );
        // The upper arm 2 cm off along the model's z.
        let mut wrong = posed.clone();
        for part in wrong.parts.iter_mut().filter(|p| p.chain_depth == 2) {
            part.model_from_link = Isometry3::translation(0.0, 0.0, 0.02) * part.model_from_link;
        }
        let reg = register_posed(&scan.cloud, &wrong, Some(truth), &opts).expect("registered");
        let support = reg.quality.link_support;
        eprintln!(
            "link support: right {:?}, upper arm off {support:?}",
            right.quality.link_support
        );
        // The fit follows the shoulder and the upper arm; the base, where the model puts it
        // beside them, is seen through.
        assert!(
            support.iter().any(|s| s.is_some_and(|s| s < 0.5)),
            "{support:?}"
        );
        let frame = FrameInput {
            view: 0,
            camera_from_model: reg.camera_from_model,
            model_from_flange: Some(scan.truth.model_from_flange_reported),
        };
        let sol = solve(Mount::EyeInHand, &[frame], &SolveOptions::default()).expect("solved");
        let verdict =
            crate::calib::gate(&[reg], &sol, None, &crate::calib::GateThresholds::default());
        assert!(
            verdict
                .reasons
                .iter()
                .any(|r| r.contains("fitted links disagree")),
            "{verdict:?}"
        );
    }

    /// Physical UR5e arms (every joint off by a factory-size error; the controller reports the
    /// flange and publishes the exact, parallel-axis DH): the same scans registered against the
    /// nominal URDF and against the URDF posed by the controller's DH. Posed nominally, the
    /// shoulder and upper arm sit where the physical arm's are not, and the round base takes
    /// its yaw from them.
    #[test]
    fn controller_kinematics_beat_the_nominal_model_on_a_calibrated_arm() {
        let Some((model, mount, views)) = super::sim_tests::ur5e_views(SCANS, 21) else {
            return;
        };
        let intrinsics = Intrinsics::compact_1280x960();
        let settings = SimSettings::default();
        let (mut nominal, mut trusting, mut controller) = (Vec::new(), Vec::new(), Vec::new());
        let (mut ratios, mut controller_ratios) = (Vec::new(), Vec::new());
        for (k, q) in views.iter().enumerate() {
            let arm = handeye_hal::ur_dh::PhysicalArm::factory(
                model.ur_model().expect("UR"),
                k as u64 + 1,
            );
            let calibrated = arm.controller_dh();
            let req = ScanRequest::new(
                &model,
                q.clone(),
                Placement::EyeInHand {
                    flange_from_camera: mount,
                },
                intrinsics,
                &settings,
                100 + k as u64,
            )
            .with_arm(arm);
            let scan = simulate_scan(&req).expect("simulated");
            let reported = scan.truth.model_from_flange_reported;

            let posed = posed_model(&model, q).expect("posed");
            let reg = register_posed(&scan.cloud, &posed, None, &RegisterOptions::default())
                .expect("registered nominally");
            let e = hand_eye_error(&reg, reported, &mount);
            ratios.push(e.0 / reg.uncertainty.translation_mm);
            nominal.push(e);
            // The nominal links trusted as if they were the arm's.
            let exact = RegisterOptions {
                kinematic_error: KinematicError::none(),
                ..RegisterOptions::default()
            };
            let reg = register_posed(&scan.cloud, &posed, None, &exact).expect("registered");
            trusting.push(hand_eye_error(&reg, reported, &mount));

            let posed =
                posed_model_with_controller_kinematics(&model, q, &calibrated).expect("posed");
            let reg = register_posed(&scan.cloud, &posed, None, &RegisterOptions::default())
                .expect("registered with the controller's kinematics");
            let e = hand_eye_error(&reg, reported, &mount);
            controller_ratios.push(e.0 / reg.uncertainty.translation_mm);
            controller.push(e);
        }
        let medians = |e: &[(f64, f64)]| {
            (
                median(e.iter().map(|e| e.0).collect()),
                median(e.iter().map(|e| e.1).collect()),
            )
        };
        let (n, t, c) = (medians(&nominal), medians(&trusting), medians(&controller));
        eprintln!(
            "calibrated UR5e, {SCANS} scans, median flange_from_camera error: nominal URDF \
             {:.3} mm {:.4} deg (its links trusted: {:.3} mm {:.4} deg), controller kinematics \
             {:.3} mm {:.4} deg; error / σ nominal {ratios:.2?}, controller \
             {controller_ratios:.2?}",
            n.0, n.1, t.0, t.1, c.0, c.1
        );
        eprintln!("per scan (mm, deg): nominal {nominal:.3?}\n controller {controller:.3?}");
        // Measured (2026-11-26, physical arms with general joint errors): 0.19–0.21 mm 0.013°
        // nominal (1.22 mm 0.094° trusting its links), 0.060–0.067 mm 0.0065–0.0069° with the
        // controller's parallel-axis DH; error / σ 0.25–0.91.
        // Estimating the links' displacements recovers most of what trusting them loses, and
        // the reported σ covers what is left.
        assert!(n.0 < 0.6 * t.0, "nominal {n:?} vs trusting the links {t:?}");
        assert!(ratios.iter().all(|r| *r < 3.0), "beyond 3σ: {ratios:?}");
        assert!(
            controller_ratios.iter().all(|r| *r < 3.0),
            "beyond 3σ: {controller_ratios:?}"
        );
        // The controller's DH halves the error (bench medians 0.080 against 0.165 mm, 0.0076°
        // against 0.017°); six scans scatter about that.
        assert!(
            c.0 < 0.7 * n.0,
            "translation: controller {c:?} vs nominal {n:?}"
        );
        assert!(
            c.1 < 0.7 * n.1,
            "rotation: controller {c:?} vs nominal {n:?}"
        );
    }

    const SCANS: usize = 6;
}

/// Regression tests of issue 3 (registration robustness, `issues show 3`), on
/// single benchmark trials that failed; the inputs are those `handeye bench` drew.
#[cfg(test)]
mod issue_3_tests {
    use crate::bench::{run_trial, BenchConfig};
    use crate::model::RobotModel;
    use crate::testutil::shared_robots;
    use nalgebra::{Isometry3, Vector3};

    fn robot(name: &str) -> Option<RobotModel> {
        let root = shared_robots()?;
        Some(RobotModel::load(&root.join(format!("ur/{name}/{name}.urdf"))).expect("model loads"))
    }

    fn trial(name: &str, mount: ([f64; 3], [f64; 3]), q: &[f64], seed: u64) -> Option<String> {
        trial_with(name, mount, q, seed, true)
    }

    fn trial_with(
        name: &str,
        mount: ([f64; 3], [f64; 3]),
        q: &[f64],
        seed: u64,
        must_accept: bool,
    ) -> Option<String> {
        let model = robot(name)?;
        let mount = Isometry3::new(Vector3::from(mount.0), Vector3::from(mount.1));
        let cfg = BenchConfig {
            views: 1,
            scans_per_view: 1,
            ..BenchConfig::default()
        };
        // The scene each case was found in: per-joint origin errors drawn from the settings.
        let t = run_trial(&model, mount, q, None, &cfg, seed, 0, 0);
        let verdict = format!(
            "{} {:.3} mm {:.4}° {:?}",
            t.outcome, t.translation_error_mm, t.rotation_error_deg, t.reasons
        );
        eprintln!("{verdict}");
        assert!(
            t.outcome != crate::calib::Outcome::Accepted || !t.is_wrong(),
            "wrong result accepted: {verdict}"
        );
        if must_accept {
            assert_eq!(t.outcome, crate::calib::Outcome::Accepted, "{verdict}");
        }
        Some(verdict)
    }

    /// Camera above the robot: the shoulder hides the top of the base, only a sliver of the
    /// base wall is seen. The old base-outline Hough found no centre ("robot not found").
    #[test]
    fn issue_3_base_hidden_under_the_shoulder_is_found() {
        trial(
            "ur10e",
            (
                [
                    0.017024649958345562,
                    -0.07760373830260564,
                    0.03328818696828123,
                ],
                [
                    -0.3282688532443324,
                    -0.03262789139620691,
                    0.19634024615838627,
                ],
            ),
            &[
                1.841520018942978,
                -2.508226280339803,
                1.7388401684914347,
                -0.8428688358657164,
                -1.610794378406026,
                -1.02034943008284,
            ],
            12505768744661124083,
        );
        trial(
            "ur3e",
            (
                [
                    -0.0028810087386851903,
                    -0.09297655799224627,
                    0.030182070459895474,
                ],
                [
                    -0.29996126170846155,
                    -0.20556013650916924,
                    1.1892203564317414,
                ],
            ),
            &[
                1.01125748706664,
                -2.214635629144152,
                0.3931362763051549,
                0.2088470340562898,
                -1.896604237527975,
                0.657713618151559,
            ],
            16269386524308615842,
        );
    }

    /// UR5e view 8 of `bench --robots ur5e --views 10 --scans-per-view 1`: every coarse
    /// hypothesis is wrong; the 7-parameter fit of one of them let the depth scale run away
    /// (≈ 1e10, the model shrunk to a point, 0% coverage) and that contender won. The scale is
    /// now bounded (fixed-scale fallback) and a contender without coverage never wins.
    #[test]
    fn issue_3_depth_scale_never_diverges() {
        let Some(model) = robot("ur5e") else { return };
        let mount = Isometry3::new(
            Vector3::new(
                -0.0028810087386851903,
                -0.09297655799224627,
                0.030182070459895474,
            ),
            Vector3::new(
                -0.29996126170846155,
                -0.20556013650916924,
                1.1892203564317414,
            ),
        );
        let q = [
            -0.04654666433660193,
            -2.7480082498628247,
            -0.5569720092694217,
            3.13483663614967,
            1.5202967421021762,
            0.15131520111973806,
        ];
        let cfg = BenchConfig::default();
        let req = cfg.scan_request(&model, &q, mount, 3583974858498588681);
        let scan = crate::sim::simulate_scan(&req).expect("simulated");
        match crate::calib::register(&scan.cloud, &model, &q, None, &cfg.register) {
            Ok(reg) => {
                eprintln!("{:?} scale {:?}", reg.quality, reg.depth_scale);
                assert!(
                    reg.depth_scale.is_none_or(|s| (s - 1.0).abs() <= 0.051),
                    "depth scale {:?}",
                    reg.depth_scale
                );
                assert!(reg.quality.coverage >= cfg.register.min_coverage_found);
            }
            Err(e) => assert!(
                matches!(e, crate::calib::CalibError::RobotNotFound { .. }),
                "{e}"
            ),
        }
    }

    /// UR30 seen from low and the side: base and shoulder only, nearly symmetric under yaw.
    /// The coarse search ranked the robot turned by half a turn first and the result was
    /// accepted 882 mm / 180° off; later it was rejected as ambiguous. Every close contender
    /// is fitted exactly; coverage counts only surface seen at < 70° incidence (grazing
    /// dropouts no longer penalise the right pose) and the ambiguity compares the misfit
    /// `1 − sharpness`, so the right pose now wins clearly and is accepted.
    #[test]
    fn issue_3_nearly_symmetric_view_is_never_accepted_wrong() {
        trial("ur30", UR30_MOUNT, &UR30_VIEW_8, 11691332368916842821);
        // Same view, another scan (bench ur30 view 8 scan 1): was rejected at ambiguity 0.93.
        trial("ur30", UR30_MOUNT, &UR30_VIEW_8, 14492284240672669312);
    }

    /// Bench ur20 view 15 (seed 1): base and shoulder in view, the upper arm hidden.
    const UR20_VIEW_15: [f64; 6] = [
        2.4318900301437685,
        -1.0812787968493711,
        2.4685533589860373,
        0.7615851273215046,
        2.078448972545978,
        2.3748683377956112,
    ];
    /// The bench's ur20 mount (seed 1).
    const UR20_MOUNT: ([f64; 3], [f64; 3]) = (
        [
            0.014035037769203586,
            -0.06118441823228681,
            0.030595748856561727,
        ],
        [
            -0.30689963953109106,
            -0.16614573860406345,
            0.9827748531382114,
        ],
    );

    /// Bench ur30 view 8 (seed 1): base and shoulder seen nearly symmetric.
    const UR30_VIEW_8: [f64; 6] = [
        -1.7536992237882687,
        -1.1392800167851371,
        2.1870020863781665,
        -1.8322472766976885,
        -1.9574479952552761,
        -2.934359053160009,
    ];
    const UR30_MOUNT: ([f64; 3], [f64; 3]) = (
        [
            -0.019814541625342165,
            -0.09867346889274019,
            0.052627821301179295,
        ],
        [
            -0.09856286639241339,
            -0.21131294184973173,
            2.2607799500043075,
        ],
    );
    const UR3E_MOUNT: ([f64; 3], [f64; 3]) = (
        [
            -0.0028810087386851903,
            -0.09297655799224627,
            0.030182070459895474,
        ],
        [
            -0.29996126170846155,
            -0.20556013650916924,
            1.1892203564317414,
        ],
    );

    /// Bench ur3e view 5: the right pose lost to the half-turn on coverage (its upper arm
    /// seen at grazing incidence had dropouts), and was rejected as ambiguous.
    #[test]
    fn issue_3_grazing_dropouts_do_not_favour_the_half_turn() {
        trial(
            "ur3e",
            UR3E_MOUNT,
            &[
                -0.9486424353626872,
                -2.6218216721402317,
                -0.25186366419189943,
                -2.5396965650040637,
                1.7529440675959007,
                -2.459447135005716,
            ],
            16459834182766065353,
        );
    }

    /// Bench ur3e view 8: no coarse hypothesis was near the right pose (all half a turn or
    /// a quarter turn off); the half-turn of the best one is now always a contender.
    #[test]
    fn issue_3_right_pose_missing_from_the_hough_peaks_is_recovered() {
        trial(
            "ur3e",
            UR3E_MOUNT,
            &[
                1.9362024509638864,
                -1.8324158424635866,
                -0.2210039229321854,
                -3.079274083029552,
                1.545052186302363,
                -0.06376318352959531,
            ],
            17477797223697526275,
        );
    }

    /// Bench ur30 view 6 scan 1: right pose, rejected at ambiguity 0.84 (60°/120° turns of
    /// the round base scored 0.80 sharpness against the right pose's 0.95).
    #[test]
    fn issue_3_round_base_turned_by_a_sixth_is_told_apart() {
        trial(
            "ur30",
            UR30_MOUNT,
            &[
                -2.258889512527647,
                -0.4543318346660503,
                1.4887279922144279,
                1.7480771059970266,
                1.46835090151321,
                -1.0979994422207788,
            ],
            13496969583169898396,
        );
    }
    /// Bench ur5e view 15 scan 1 (seed 1): a clutter box's side scored the robot lying on it
    /// above the floor's peaks (the right pose on the 15 mm / 5° Hough grid scores below its
    /// polished value) and took every hypothesis slot: "robot not found". The planes now take
    /// turns.
    #[test]
    fn issue_3_a_clutter_plane_does_not_crowd_the_floor_out() {
        trial(
            "ur5e",
            (
                [
                    -0.006798429886489581,
                    -0.08228249917545548,
                    0.05910353462012781,
                ],
                [
                    -0.0735060845311369,
                    0.13844783192740404,
                    -2.1619190486463666,
                ],
            ),
            &[
                -0.9410676072524775,
                -1.7624661203726348,
                1.6630299615255213,
                1.9495470375888582,
                1.6392986479997331,
                -2.9278545061263386,
            ],
            10670561925635720219,
        );
    }

    /// Bench ur20 view 15 and ur3e view 17 (seed 1): only the base and the shoulder in view,
    /// the upper arm hidden. Turns of the base by 60°/90° fitted it as well as the right pose
    /// (ambiguity 0.87–0.88, rejected); on the shoulder alone their misfit is 2–8× the right
    /// pose's.
    #[test]
    fn issue_3_the_shoulder_tells_a_turned_round_base_apart() {
        trial("ur20", UR20_MOUNT, &UR20_VIEW_15, 11925489354492944206);
        trial(
            "ur3e",
            UR3E_MOUNT,
            &[
                -0.28493224540135786,
                -2.9111384334550214,
                0.28614273122614176,
                -2.8408387308271417,
                1.9995126857949526,
                -1.8077360986200657,
            ],
            18081708939740349926,
        );
    }

    /// Bench ur3e view 10 scan 1 (seed 1): camera above the robot, the base under the
    /// shoulder; every Hough peak on the floor was the half-turn ("robot not found").
    #[test]
    fn issue_3_camera_above_the_robot_is_not_half_turned() {
        trial(
            "ur3e",
            UR3E_MOUNT,
            &[
                2.0165167528802037,
                -1.9443608113509248,
                -0.5698673167863735,
                -2.5696771462716144,
                1.69924825158229,
                -0.6315774446764304,
            ],
            8270097040764791721,
        );
    }
    const UR3E_MOUNT_SEED_2: ([f64; 3], [f64; 3]) = (
        [
            -0.0015746921741231282,
            -0.08016887146484214,
            0.027687421668222807,
        ],
        [
            -0.013795328030691457,
            0.2499905610410588,
            -3.021357550178925,
        ],
    );

    /// Bench seed 2, ur3e view 12 scan 1: every Hough peak sat on the base at a wrong turn
    /// (35°–120°), the right one among none of them, and the 90° turn was *accepted* 507 mm off
    /// (ambiguity 0.62 against the other wrong turns). The sweep of the best candidate's turn
    /// now brings the right pose in, and it wins clearly.
    #[test]
    fn issue_3_a_wrong_turn_is_not_accepted_when_the_right_one_is_missing() {
        trial(
            "ur3e",
            UR3E_MOUNT_SEED_2,
            &[
                -2.8611054956657878,
                -0.668576032285932,
                -0.03818063272891825,
                -0.33351006408923967,
                -1.5860976542643088,
                1.7488074469360244,
            ],
            15737112210666434618,
        );
    }

    /// Bench seed 2, ur3e view 8 scan 0: the floor peak near the right pose (13 mm / 2.4° off
    /// on the Hough grid) scored 15 against a wrong plane's 111 under the tight tolerance and was
    /// never polished ("robot not found").
    #[test]
    fn issue_3_a_slightly_off_hough_peak_is_still_polished() {
        trial(
            "ur3e",
            UR3E_MOUNT_SEED_2,
            &[
                2.8220044661453816,
                -0.8493413275849413,
                -0.3875804895024575,
                -3.0568533873960257,
                1.5463589408257068,
                -1.936691471971793,
            ],
            14903361556771446440,
        );
    }
    /// Bench ur30 view 8 scan 0 (seed 1): the polished candidates were the 60°, 120° and 180°
    /// turns of the base; the sweep kept two more turns, both wrong, and the 60° turn was
    /// rejected as ambiguous. Keeping four turns brings the right one in.
    #[test]
    fn issue_3_six_near_equal_turns_are_all_compared() {
        trial("ur30", UR30_MOUNT, &UR30_VIEW_8, 6970261747485719572);
    }

    /// Bench seed 2, ur20 view 10 scan 0: the camera is level with the base, 6 cm above its
    /// mounting face; the floor is seen edge-on (nothing measured), and every plane of the scan
    /// is a tangent plane of the UR20's own cylinders, with the floor behind it ("robot not
    /// found"). The mounting plane derived from the base cylinder's axis finds it.
    #[test]
    fn issue_3_a_camera_level_with_the_base_finds_it_without_a_floor() {
        trial(
            "ur20",
            (
                [
                    0.0050790953065904185,
                    -0.07935803549462878,
                    0.05836297545372256,
                ],
                [
                    -0.3139453533438121,
                    -0.11567349428681195,
                    0.6995968553992749,
                ],
            ),
            &[
                0.9518609032884902,
                -1.0731357827413492,
                2.23269754136033,
                -1.4046781550195588,
                -1.6595593445369001,
                -0.8287494854608144,
            ],
            16510074904163851837,
        );
    }

    /// Bench seed 2, ur3e view 9 scan 1: the right pose was polished (0.2 mm off) but a wrong
    /// pose showing more of the model out-scored it by far (152 against 89) and was the only
    /// contender; it failed the fine alignment ("robot not found"). The candidate with the best
    /// coverage is always a contender now.
    ///
    /// The scene is no longer the one the case was found in: since the simulated arm has
    /// general joint errors (issue 26) the draws differ, and in this marginal view (little of
    /// the base's outline on the floor) the search now finds no hypothesis on the floor plane
    /// and reports the robot not found. What stays asserted: no wrong pose is accepted.
    #[test]
    fn issue_3_the_best_covering_candidate_is_always_a_contender() {
        trial_with(
            "ur3e",
            UR3E_MOUNT_SEED_2,
            &[
                -0.21382774721386655,
                -1.7157795316474476,
                0.33438874419427256,
                0.1249485719861787,
                -1.6828660518677563,
                1.5285408244036462,
            ],
            15306023974058585794,
            false,
        );
    }

    /// Bench ur30 view 8 scan 2 (seed 1): the 60°, 120° and 180° turns of the base and a
    /// second 180° candidate 6° from the first took the four contender slots; the right pose
    /// (polished, 0.6 mm off, coverage 0.99) had none and the 60° turn was rejected as
    /// ambiguous. Candidates that would converge to the same fit share one slot now.
    #[test]
    fn issue_3_near_duplicate_candidates_share_a_contender_slot() {
        trial("ur30", UR30_MOUNT, &UR30_VIEW_8, 3022027304964649981);
    }

    /// Bench ur20 view 15 scan 1 (seed 1): the 60°, 120° and 180° turns of the base (and the
    /// −60° one) took every contender slot, the right pose (0.5 mm off) scoring just below
    /// them; rejected as ambiguous. Its short fit hugs the shoulder best (sharpness 0.99
    /// against ≤ 0.98), which now earns it a slot.
    #[test]
    fn issue_3_the_tightest_short_fit_is_always_a_contender() {
        trial("ur20", UR20_MOUNT, &UR20_VIEW_15, 16056022761727771937);
    }

    /// Bench seed 2, ur20 view 6 scan 1: clutter boxes fill the view, the floor is edge-on;
    /// the robot flipped upside down 223 mm away took the contender slot and was stopped only
    /// by its uncertainty (1.01 mm against a 1.00 mm limit), the right pose never polished.
    /// The camera rides on the flange: hypotheses that put it far from the flange are dropped
    /// before they are polished, and the right pose gets its slot.
    #[test]
    fn issue_3_hypotheses_far_from_the_flange_make_way() {
        trial(
            "ur20",
            UR20_MOUNT_SEED_2,
            &UR20_VIEW_6_SEED_2,
            13507425662540616718,
        );
    }

    /// Bench seed 2's ur20 mount.
    const UR20_MOUNT_SEED_2: ([f64; 3], [f64; 3]) = (
        [0.005_079_095, -0.079_358_035, 0.058_362_975],
        [-0.313_945_353, -0.115_673_494, 0.699_596_855],
    );

    /// Bench seed 2, ur20 view 6: the camera 6 cm above the mounting face, beside clutter.
    const UR20_VIEW_6_SEED_2: [f64; 6] = [
        0.951_860_903,
        -1.073_135_783,
        2.232_697_541,
        -1.404_678_155,
        -1.659_559_345,
        -0.828_749_485,
    ];

    /// Bench seed 2, ur20 view 6 scan 2: no plane the robot could stand on in view, and the
    /// heights derived by matching the robot's surface were 20 cm off (a standing robot's
    /// side-facing surface matches at almost any height); the robot flipped upside down 223
    /// mm away was the result, rejected only by its free-space violations (5.1 %). The lowest
    /// curved surface in view (the base's foot) is tried as the mounting height too now.
    #[test]
    fn issue_3_seen_from_the_side_the_lowest_surface_gives_the_mounting_height() {
        trial(
            "ur20",
            UR20_MOUNT_SEED_2,
            &UR20_VIEW_6_SEED_2,
            18300494614736989160,
        );
    }

    /// Bench seed 3's ur5e mount.
    const UR5E_MOUNT_SEED_3: ([f64; 3], [f64; 3]) = (
        [-0.009_397_569, -0.096_819_534, 0.023_698_454],
        [-0.127_744_502, 0.071_663_635, -1.020_750_719],
    );

    /// Bench seed 2 ur10e view 28 scan 2 and seed 3 ur5e views 14 and 24 (scan 0): clutter
    /// boxes fill most of the view (80 % of the points) and no plane the robot could stand on
    /// is seen. The mounting height derived along the base's axis matched the boxes, 15 cm
    /// off; a wrong pose was rejected or the robot not found. Points on the scan's planes
    /// are left out of the height match now, and the two best heights are tried.
    #[test]
    fn issue_3_clutter_does_not_mislead_the_derived_mounting_height() {
        trial(
            "ur10e",
            (
                [-0.015_617_442, -0.076_602_789, 0.026_320_634],
                [-0.265_510_398, -0.133_993_126, 0.928_135_481],
            ),
            &[
                -2.402_951_107,
                -0.795_289_289,
                1.489_999_214,
                -0.858_664_270,
                -1.661_276_743,
                -0.667_814_309,
            ],
            12019160954132144742,
        );
        trial(
            "ur5e",
            UR5E_MOUNT_SEED_3,
            &[
                -0.168_672_290,
                -2.607_295_238,
                -1.140_247_600,
                0.869_143_045,
                -1.523_076_424,
                -2.711_656_811,
            ],
            7883475844213637492,
        );
        trial(
            "ur5e",
            UR5E_MOUNT_SEED_3,
            &[
                -3.053_050_336,
                -0.654_191_826,
                1.265_181_957,
                -0.321_229_331,
                -1.758_850_640,
                -0.620_012_543,
            ],
            5999345711917701832,
        );
    }

    /// Bench seed 1, ur30 view 27 scan 1 (with an intermediate version): 18 derived mounting
    /// planes took turns for 8 hypothesis slots, and the right one had none ("robot not
    /// found"). Each derived plane gets a slot now, the plausible ones first.
    #[test]
    fn issue_3_every_derived_mounting_plane_is_searched() {
        trial(
            "ur30",
            UR30_MOUNT,
            &[
                -0.390_439_755,
                -2.606_811_375,
                -1.041_516_437,
                -2.636_526_557,
                1.547_406_525,
                -0.807_597_464,
            ],
            888766242438752922,
        );
    }
}
