//! The accuracy benchmark of the paper's protocol on simulated scans: per robot, random views
//! that look at the base (joint changes ≥ 20° between them), several scans per view with
//! realistic imperfections, registration without any prior, the hand-eye solve and the gate;
//! errors against the simulator's ground truth. Eye-in-hand (a wrist camera, the views are the
//! arm's poses) or eye-to-hand (a camera fixed in the cell 0.8–2.0 m from the arm, the views
//! are random arm configurations in its field of view).

pub mod drift;

use std::time::Instant;

use nalgebra::{Isometry3, Point3, Vector3};
use rand::{Rng, SeedableRng};
use serde::Serialize;

use handeye_hal::ur_dh::PhysicalArm;

use crate::calib::pipeline::{calibrate_frames, Frame, PipelineOptions};
use crate::calib::register::elapsed_ms;
use crate::calib::solve::{distance, distance_at};
use crate::calib::{GateThresholds, Mount, Outcome, Quality, RegisterOptions};
use crate::model::{KinematicError, RobotModel};
use crate::plan::{
    differs_from_all, random_joints, PlanError, ViewConstraints, ViewPlanner, PATH_STEP_RAD,
};
use crate::sim::{look_at, simulate_scan, Intrinsics, Placement, ScanRequest, SimSettings};

/// A result off by more than this is wrong (and must have been rejected), mm: at the camera
/// origin for a wrist camera, at the robot base for a fixed camera (where it looks, see
/// [`Trial::workspace_distance_m`]).
pub const WRONG_TRANSLATION_MM: f64 = 2.0;
/// A result off by more than this is wrong (and must have been rejected), degrees.
pub const WRONG_ROTATION_DEG: f64 = 0.5;

/// A simulated calibration (the demo, the run's tests) passes when it is accepted and this
/// close to the truth, mm: a manufactured arm's housings, off their links' frames by tenths of
/// a millimetre that no controller knows, leave a median of about 0.45 mm on one scan and at
/// most about 1.1 mm (docs/src/benchmarks.md).
pub const PASS_TRANSLATION_MM: f64 = 1.5;
/// A simulated calibration passes when it is accepted and this close to the truth, degrees (a
/// median of about 0.035° on a manufactured arm, at most about 0.15°).
pub const PASS_ROTATION_DEG: f64 = 0.25;

/// What to run.
#[derive(Debug, Clone)]
pub struct BenchConfig {
    /// Views per robot (the paper uses 30).
    pub views: usize,
    /// Scans per view (new sensor noise each).
    pub scans_per_view: usize,
    /// Views per calibration run: 1, every scan is calibrated alone (each view a new arm);
    /// `n > 1`, consecutive views are grouped `n` at a time into the runs of one arm, and a
    /// trial calibrates from scan `s` of each view of the run together.
    pub views_per_run: usize,
    /// The camera.
    pub intrinsics: Intrinsics,
    /// Simulator knobs (realistic defaults).
    pub settings: SimSettings,
    /// Registration tuning.
    pub register: RegisterOptions,
    /// Pass/fail thresholds.
    pub gate: GateThresholds,
    /// Seed of the mount, views and scans.
    pub seed: u64,
    /// Whether the solver is given the arm's calibrated kinematics (UR arms).
    pub kinematics: BenchKinematics,
    /// Wrist camera (the unknown is `flange_from_camera`) or a camera fixed in the cell (the
    /// unknown is `base_from_camera`).
    pub mount: Mount,
    /// 1σ per axis of the shift (m) and turn (rad) of the frame the flange poses are handed in
    /// off the controller's `base` (a ROS `world`, a URDF root whose z is not joint 1's axis),
    /// drawn once per calibration run, and the solver told so
    /// ([`PipelineOptions::pose_frame`]); `(0, 0)`: the poses are in `base`.
    pub pose_frame: (f64, f64),
}

/// What the solver knows of the simulated arm's kinematics.
///
/// The true arm of a UR view is a physical arm ([`PhysicalArm`], one per view: every joint
/// off by a small rigid error of the settings' `kinematic_error` sizes, by default a factory
/// calibration's); the controller publishes its exact DH (nearly parallel joints 2–4 give `d`
/// of hundreds of metres) and reports its flange, as a real UR controller does; the scan shows
/// the physical arm. Other arms (no DH set) draw per-joint origin errors from the settings'
/// `kinematic_error` and report the true flange the same way. Settings whose
/// `kinematic_error` is zero make every arm exactly its URDF.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum BenchKinematics {
    /// The solver poses the nominal URDF (no calibration file, a controller that publishes
    /// none).
    Unknown,
    /// The solver poses the model by the calibrated DH set (the controller's kinematics or a
    /// `ur_calibration` file); arms without a DH set are solved as with `unknown`.
    Known,
}

impl BenchKinematics {
    /// Every value, as the command line and the JSON name them.
    pub const NAMES: [&'static str; 2] = ["unknown", "known"];
}

impl std::str::FromStr for BenchKinematics {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "unknown" => Ok(Self::Unknown),
            "known" => Ok(Self::Known),
            _ => Err(format!(
                "`{s}` is not a kinematics; use one of: {}",
                Self::NAMES.join(", ")
            )),
        }
    }
}

impl BenchConfig {
    /// The defaults for a camera mounted as `mount`, with the registration tuning the pipeline
    /// uses for it ([`PipelineOptions::new`]: eye-to-hand fits every link in view).
    pub fn new(mount: Mount) -> Self {
        Self {
            mount,
            register: PipelineOptions::new(mount).register,
            ..Self::default()
        }
    }

    /// This configuration with the registration tuned for camera preset `camera`'s sensor
    /// class ([`RegisterOptions::for_sensor`]: time of flight its range offset and multipath,
    /// active stereo its scale bound and depth gradient) and the gate's defaults for it
    /// ([`GateThresholds::for_sensor`]), as `handeye bench --camera` runs it; unchanged for a
    /// name that is no preset.
    pub fn tuned_for_camera(mut self, camera: &str) -> Self {
        if let Some(class) = Intrinsics::preset_class(camera) {
            self.register = self.register.for_sensor(class);
            self.gate = GateThresholds::for_sensor(class);
        }
        self
    }

    /// This configuration with the solver told the simulated arms' tolerances, as a cell's
    /// configuration says its arm's: the housings' and the joint readings' 1σ of the
    /// settings' `kinematic_error`.
    pub fn solver_told_the_arm(mut self) -> Self {
        let built = self.settings.kinematic_error;
        let told = &mut self.register.kinematic_error;
        told.housing_translation_sigma_m = built.housing_translation_sigma_m;
        told.housing_rotation_sigma_rad = built.housing_rotation_sigma_rad;
        told.joint_reading_sigma_rad = built.joint_reading_sigma_rad;
        told.deflection_rad = built.deflection_rad;
        self
    }

    /// The simulated scan of one trial: `model` at `joints`, the camera at `mount`
    /// (eye-in-hand: `flange_from_camera`; eye-to-hand: `model_from_camera`, see
    /// [`TrialPlan::mount`]), this configuration's camera and simulator settings.
    pub fn scan_request<'a>(
        &self,
        model: &'a RobotModel,
        joints: &[f64],
        mount: Isometry3<f64>,
        seed: u64,
    ) -> ScanRequest<'a> {
        let mut req = ScanRequest::new(
            model,
            joints.to_vec(),
            match self.mount {
                Mount::EyeInHand => Placement::EyeInHand {
                    flange_from_camera: mount,
                },
                Mount::EyeToHand => Placement::EyeToHand {
                    model_from_camera: mount,
                },
            },
            self.intrinsics,
            &self.settings,
            seed,
        );
        // The registration fits a colour image's outline for a fixed camera only: a wrist
        // camera's image is not rendered (its depth is the same either way).
        req.noise.colour_image &= self.mount == Mount::EyeToHand;
        req
    }

    /// The physical arm seen in the view whose first scan has seed `view_seed`: joint errors of
    /// the settings' `kinematic_error` sizes (by default a UR factory calibration's); `None`
    /// for arms without a DH set or settings that make the arm exactly its model.
    pub fn true_arm(&self, model: &RobotModel, view_seed: u64) -> Option<PhysicalArm> {
        let e = &self.settings.kinematic_error;
        if *e == KinematicError::none() {
            return None;
        }
        let ur = model.ur_model()?;
        Some(PhysicalArm::draw(
            ur.dh(),
            &e.joint_sizes(),
            view_seed ^ ARM_SEED,
        ))
    }
}

impl Default for BenchConfig {
    fn default() -> Self {
        Self {
            views: 30,
            scans_per_view: 3,
            views_per_run: 1,
            intrinsics: Intrinsics::compact_1280x960(),
            settings: SimSettings::default(),
            register: RegisterOptions::default(),
            gate: GateThresholds::default(),
            seed: 1,
            kinematics: BenchKinematics::Unknown,
            mount: Mount::EyeInHand,
            pose_frame: (0.0, 0.0),
        }
    }
}

/// Mixed into a view's first scan seed to draw its arm's calibration (so the plan's draws, and
/// every earlier benchmark's views and scans, stay as they were).
const ARM_SEED: u64 = 0x6b69_6e65_6d61_7469;

/// Mixed into a run's first scan seed to draw the frame its flange poses are handed in.
const POSE_FRAME_SEED: u64 = 0x776f_726c_645f_6672;

/// `model_from_handed`: where the frame the flange poses of the run whose first scan has seed
/// `seed` are handed in sits, off the model's own (1σ per axis `shift_m`, `turn_rad`); the
/// identity for `(0, 0)`.
pub fn pose_frame_offset((shift_m, turn_rad): (f64, f64), seed: u64) -> Isometry3<f64> {
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed ^ POSE_FRAME_SEED);
    let mut draw =
        |s: f64| Vector3::from_fn(|_, _| s * rng.sample::<f64, _>(rand_distr::StandardNormal));
    let shift = draw(shift_m);
    let turn = draw(turn_rad);
    Isometry3::new(shift, turn)
}

/// One registration + solve against ground truth.
#[derive(Debug, Clone, Serialize)]
pub struct Trial {
    /// View index.
    pub view: usize,
    /// Scan index within the view.
    pub scan: usize,
    /// Accepted, rejected or error.
    pub outcome: Outcome,
    /// Why it was rejected or failed.
    pub reasons: Vec<String>,
    /// Position error of the unknown (`flange_from_camera` eye-in-hand, `base_from_camera`
    /// eye-to-hand), mm (NaN on error): eye-in-hand at the camera origin, eye-to-hand at the
    /// robot base (how far from where it is the result puts the base the fixed camera sees).
    pub translation_error_mm: f64,
    /// Eye-to-hand: the distance of the robot base, where `translation_error_mm` and
    /// `uncertainty_translation_mm` are measured, from the camera, metres. `None`: both at the
    /// camera origin (eye-in-hand).
    pub workspace_distance_m: Option<f64>,
    /// Eye-to-hand: the camera origin's position error, mm (1–2 m from the arm, mostly the
    /// rotation error times that lever). `None` eye-in-hand (`translation_error_mm` is it).
    pub camera_origin_error_mm: Option<f64>,
    /// Camera rotation error of the unknown, degrees (NaN on error).
    pub rotation_error_deg: f64,
    /// Reported 1-σ position uncertainty where `translation_error_mm` is measured, mm (what
    /// the gate judges, [`crate::calib::Uncertainty::position_mm`]).
    pub uncertainty_translation_mm: f64,
    /// Reported 1-σ rotation uncertainty, degrees.
    pub uncertainty_rotation_deg: f64,
    /// Whether the solver posed the model by the arm's calibrated DH set.
    pub calibrated_kinematics: bool,
    /// Time to simulate the scan, ms (not part of calibration).
    pub simulate_ms: f64,
    /// Registration stages, ms.
    pub preprocess_ms: f64,
    /// Coarse (global) alignment, ms.
    pub coarse_ms: f64,
    /// Fine alignment, ms.
    pub fine_ms: f64,
    /// Verification and covariance, ms.
    pub verify_ms: f64,
    /// Whole registration, ms.
    pub register_ms: f64,
    /// Hand-eye solve and gate, ms.
    pub solve_ms: f64,
    /// What the gate judged (coverage, ambiguity, …); `None` when registration failed. The
    /// margins of right and wrong results to the gate's thresholds are read from here.
    pub quality: Option<Quality>,
    /// The unknown's error `truth⁻¹ · estimate`: translation (mm) then rotation vector
    /// (degrees); `None` without a result. Two trials of one run compare as a drift check
    /// compares a check with its calibration ([`drift`]).
    pub error_pose: Option<[f64; 6]>,
}

impl Trial {
    /// Scan `scan` of view `view` before anything is known: an error without a result (NaN
    /// errors and σ), no time spent.
    pub fn new(view: usize, scan: usize) -> Self {
        Self {
            view,
            scan,
            outcome: Outcome::Error,
            reasons: Vec::new(),
            translation_error_mm: f64::NAN,
            workspace_distance_m: None,
            camera_origin_error_mm: None,
            rotation_error_deg: f64::NAN,
            uncertainty_translation_mm: f64::NAN,
            uncertainty_rotation_deg: f64::NAN,
            calibrated_kinematics: false,
            simulate_ms: 0.0,
            preprocess_ms: 0.0,
            coarse_ms: 0.0,
            fine_ms: 0.0,
            verify_ms: 0.0,
            register_ms: 0.0,
            solve_ms: 0.0,
            quality: None,
            error_pose: None,
        }
    }

    /// Whether the result is off by more than the wrong-result thresholds.
    pub fn is_wrong(&self) -> bool {
        !(self.translation_error_mm <= WRONG_TRANSLATION_MM
            && self.rotation_error_deg <= WRONG_ROTATION_DEG)
    }

    /// Translation error over the reported 1σ (NaN without a result).
    pub fn translation_over_sigma(&self) -> f64 {
        self.translation_error_mm / self.uncertainty_translation_mm
    }

    /// Rotation error over the reported 1σ (NaN without a result).
    pub fn rotation_over_sigma(&self) -> f64 {
        self.rotation_error_deg / self.uncertainty_rotation_deg
    }
}

/// Mean, median, standard deviation and 95th percentile.
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct Stats {
    /// Mean.
    pub mean: f64,
    /// Median.
    pub median: f64,
    /// Standard deviation.
    pub std: f64,
    /// 95th percentile.
    pub p95: f64,
    /// Largest value.
    pub max: f64,
}

impl Stats {
    /// Statistics of the finite values (all NaN when there are none).
    pub fn of(values: impl IntoIterator<Item = f64>) -> Self {
        let mut v: Vec<f64> = values.into_iter().filter(|x| x.is_finite()).collect();
        if v.is_empty() {
            return Self {
                mean: f64::NAN,
                median: f64::NAN,
                std: f64::NAN,
                p95: f64::NAN,
                max: f64::NAN,
            };
        }
        v.sort_by(f64::total_cmp);
        let n = v.len() as f64;
        let mean = v.iter().sum::<f64>() / n;
        let std = (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n).sqrt();
        Self {
            mean,
            median: percentile(&v, 0.5),
            std,
            p95: percentile(&v, 0.95),
            max: v[v.len() - 1],
        }
    }
}

/// The value at fraction `p` (0–1) of `sorted` (ascending, not empty): the nearest rank.
pub(crate) fn percentile(sorted: &[f64], p: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

/// Everything measured for one robot.
#[derive(Debug, Clone, Serialize)]
pub struct RobotSummary {
    /// Robot name.
    pub robot: String,
    /// Trials run.
    pub trials: usize,
    /// Accepted and within 2 mm / 0.5°.
    pub correct: usize,
    /// Accepted but off by more than 2 mm or 0.5° (must be 0).
    pub wrong_accepted: usize,
    /// Rejected by the gate.
    pub rejected: usize,
    /// Registration errors (no robot found, …).
    pub errors: usize,
    /// `correct / trials`.
    pub success_rate: f64,
    /// Translation error of accepted results, mm.
    pub translation_mm: Stats,
    /// Rotation error of accepted results, degrees.
    pub rotation_deg: Stats,
    /// Translation error over the reported 1σ, accepted results (a calibrated 3-D Gaussian
    /// gives a median of 0.89 and a p95 of 1.6 in translation).
    pub translation_over_sigma: Stats,
    /// Rotation error over the reported 1σ, accepted results.
    pub rotation_over_sigma: Stats,
    /// Registration time, ms.
    pub register_ms: Stats,
    /// Coarse stage time, ms.
    pub coarse_ms: Stats,
    /// Fine stage time, ms.
    pub fine_ms: Stats,
    /// Every trial.
    pub details: Vec<Trial>,
}

impl RobotSummary {
    /// Summarises trials.
    pub fn new(robot: &str, details: Vec<Trial>) -> Self {
        let accepted: Vec<&Trial> = details
            .iter()
            .filter(|t| t.outcome == Outcome::Accepted)
            .collect();
        let correct = accepted.iter().filter(|t| !t.is_wrong()).count();
        let ok = |f: fn(&Trial) -> f64| Stats::of(accepted.iter().map(|t| f(t)));
        let all = |f: fn(&Trial) -> f64| Stats::of(details.iter().map(f));
        Self {
            robot: robot.to_string(),
            trials: details.len(),
            correct,
            wrong_accepted: accepted.len() - correct,
            rejected: details
                .iter()
                .filter(|t| t.outcome == Outcome::Rejected)
                .count(),
            errors: details
                .iter()
                .filter(|t| t.outcome == Outcome::Error)
                .count(),
            success_rate: if details.is_empty() {
                0.0
            } else {
                correct as f64 / details.len() as f64
            },
            translation_mm: ok(|t| t.translation_error_mm),
            rotation_deg: ok(|t| t.rotation_error_deg),
            translation_over_sigma: ok(Trial::translation_over_sigma),
            rotation_over_sigma: ok(Trial::rotation_over_sigma),
            register_ms: all(|t| t.register_ms),
            coarse_ms: all(|t| t.coarse_ms),
            fine_ms: all(|t| t.fine_ms),
            details,
        }
    }
}

/// A wrist camera mount for a robot: 8 cm off the flange axis, looking along it, with a
/// random tilt of up to 20° and a random roll (seeded), as a real bracket would be.
pub fn random_mount(rng: &mut impl Rng) -> Isometry3<f64> {
    let tilt = rng.random_range(5f64..20.0).to_radians();
    let roll = rng.random_range(-std::f64::consts::PI..std::f64::consts::PI);
    let off = Vector3::new(
        rng.random_range(-0.02..0.02),
        rng.random_range(-0.1..-0.06),
        rng.random_range(0.02..0.06),
    );
    Isometry3::new(off, Vector3::z() * roll) * Isometry3::rotation(Vector3::x() * -tilt)
}

/// Runs the protocol on one robot; `progress` is called after every trial.
pub fn run_robot(
    model: &RobotModel,
    cfg: &BenchConfig,
    mut progress: impl FnMut(&Trial),
) -> Result<RobotSummary, PlanError> {
    let plan = plan_trials(model, cfg)?;
    let mut trials = Vec::new();
    let per_run = cfg.views_per_run.max(1);
    for (run, seeds) in plan.scan_seeds.chunks(per_run).enumerate() {
        let first = run * per_run;
        // One arm per run: drawn from its first view's first scan (with one view per run,
        // each view's arm as always).
        let arm = cfg.true_arm(model, seeds[0][0]);
        for s in 0..cfg.scans_per_view {
            let views: Vec<(&[f64], u64)> = seeds
                .iter()
                .enumerate()
                .map(|(k, view_seeds)| (plan.views[first + k].as_slice(), view_seeds[s]))
                .collect();
            let t = run_views_trial(model, plan.mount, &views, arm, cfg, first, s);
            progress(&t);
            trials.push(t);
        }
    }
    Ok(RobotSummary::new(model.name(), trials))
}

/// One robot's trials as [`run_robot`] draws them from `cfg.seed`.
#[derive(Debug, Clone)]
pub struct TrialPlan {
    /// Where the camera is: eye-in-hand the wrist-camera mount (`flange_from_camera`),
    /// eye-to-hand the fixed camera (`model_from_camera`, model = URDF root link).
    pub mount: Isometry3<f64>,
    /// The views' joint angles.
    pub views: Vec<Vec<f64>>,
    /// `scan_seeds[v][s]`: the simulator seed of scan `s` of view `v`.
    pub scan_seeds: Vec<Vec<u64>>,
}

/// Draws the mount, the views and the scans' seeds of one robot from `cfg.seed` (what
/// [`run_robot`] runs; a diagnostic replays single trials from it).
pub fn plan_trials(model: &RobotModel, cfg: &BenchConfig) -> Result<TrialPlan, PlanError> {
    let mut rng = rand::rngs::StdRng::seed_from_u64(cfg.seed);
    let (mount, views) = match cfg.mount {
        Mount::EyeInHand => {
            let mount = random_mount(&mut rng);
            let planner =
                ViewPlanner::new(model, mount, cfg.intrinsics, ViewConstraints::default());
            (mount, wrist_views(&planner, cfg, &mut rng)?)
        }
        Mount::EyeToHand => {
            let camera = random_fixed_camera(model, &cfg.intrinsics, &mut rng);
            let views = arm_configurations_in_view(model, camera, cfg, rng.random())?;
            (camera, views)
        }
    };
    let scan_seeds = views
        .iter()
        .map(|_| (0..cfg.scans_per_view).map(|_| rng.random()).collect())
        .collect();
    Ok(TrialPlan {
        mount,
        views,
        scan_seeds,
    })
}

/// How many times the bench draws a run's first view again when no view near it is found.
const FIRST_VIEW_REDRAWS: usize = 10;

/// A wrist camera's views: one view per run, `cfg.views` random views; several, each run
/// planned as `calibrate` plans its views (a random first view, the others near it turning the
/// flange, [`ViewPlanner::extend_run`], on paths clear of the floor).
fn wrist_views(
    planner: &ViewPlanner<'_>,
    cfg: &BenchConfig,
    rng: &mut impl rand::Rng,
) -> Result<Vec<Vec<f64>>, PlanError> {
    let per_run = cfg.views_per_run.max(1);
    if per_run == 1 {
        return planner.generate(cfg.views, rng.random());
    }
    let firsts = planner.generate(cfg.views.div_ceil(per_run), rng.random())?;
    let mut views = Vec::with_capacity(firsts.len() * per_run);
    for first in firsts {
        // A first view with no safe view near it is drawn again, as a run would start from
        // elsewhere.
        let mut first = first;
        let mut redraws = 0;
        let run = loop {
            let mut run = vec![first.clone()];
            match planner.extend_run(&mut run, per_run, rng.random(), |from, to| {
                Ok(planner.check_path(from, to, PATH_STEP_RAD)?.is_ok())
            }) {
                Ok(()) => break run,
                Err(PlanError::NotEnoughViews { .. }) if redraws < FIRST_VIEW_REDRAWS => {
                    redraws += 1;
                    first = planner.generate(1, rng.random())?.remove(0);
                }
                Err(e) => return Err(e),
            }
        };
        views.extend(run);
    }
    views.truncate(cfg.views);
    Ok(views)
}

/// Nearest and farthest distance of the fixed camera of an eye-to-hand benchmark from the point
/// it looks at (a third of the arm's reach above the base), metres: a camera on a stand or the
/// cell's frame, seeing the whole arm.
pub const FIXED_CAMERA_DISTANCE_M: (f64, f64) = (0.8, 2.0);

/// How far the arm reaches from its base (metres): the farthest link origin at all-zero
/// joints (a UR arm lies stretched out there), at least 0.3 m.
fn reach(model: &RobotModel) -> f64 {
    model
        .link_poses(&vec![0.0; model.dof()])
        .map(|poses| {
            poses
                .iter()
                .map(|p| p.translation.vector.norm())
                .fold(0.0, f64::max)
        })
        .unwrap_or(0.0)
        .max(0.3)
}

/// A camera fixed in the cell (`model_from_camera`) for an eye-to-hand benchmark: at a random
/// azimuth, 15–45° above the base plane, [`FIXED_CAMERA_DISTANCE_M`] from the point a third of
/// the arm's reach above the base, looking at it; no nearer than where the image's half-height
/// holds 0.4 of the reach (a UR5e: 0.9 m, a UR30: 1.3 m with the `compact` camera).
pub fn random_fixed_camera(
    model: &RobotModel,
    intrinsics: &Intrinsics,
    rng: &mut impl Rng,
) -> Isometry3<f64> {
    let reach = reach(model);
    let (near, far) = FIXED_CAMERA_DISTANCE_M;
    // The image's half-height seen at distance d is d·tan(half vertical FOV).
    let half_fov = (0.5 * f64::from(intrinsics.height) / intrinsics.fy).atan();
    let needed = (0.4 * reach / half_fov.tan()).clamp(near, far);
    let distance = rng.random_range(needed..=far);
    let azimuth = rng.random_range(-std::f64::consts::PI..std::f64::consts::PI);
    let elevation = rng.random_range(15f64..45.0).to_radians();
    let target = Point3::new(0.0, 0.0, reach / 3.0);
    let eye = target
        + distance
            * Vector3::new(
                elevation.cos() * azimuth.cos(),
                elevation.cos() * azimuth.sin(),
                elevation.sin(),
            );
    look_at(&eye, &target, &-Vector3::z())
}

/// `cfg.views` random arm configurations (seeded) for the fixed camera `model_from_camera`:
/// within joint limits, clear of the floor and of itself (as the view planner checks motion),
/// the base and every link origin in the image (5 % from its border: the whole arm in view), no
/// link origin within 0.25 m of the camera, and each at least the planner's minimum joint change
/// from the others.
pub fn arm_configurations_in_view(
    model: &RobotModel,
    model_from_camera: Isometry3<f64>,
    cfg: &BenchConfig,
    seed: u64,
) -> Result<Vec<Vec<f64>>, PlanError> {
    let constraints = ViewConstraints::default();
    // The motion checks need no camera on the arm: the flange stands in for it.
    let planner = ViewPlanner::new(model, Isometry3::identity(), cfg.intrinsics, constraints);
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let camera_from_model = model_from_camera.inverse();
    let k = &cfg.intrinsics;
    let margin = 0.05 * f64::from(k.width.min(k.height));
    let in_image = |p: &Point3<f64>| {
        k.project(&(camera_from_model * p))
            .is_some_and(|(u, v)| k.contains(u, v, margin))
    };
    let eye = Point3::from(model_from_camera.translation.vector);
    let mut views: Vec<Vec<f64>> = Vec::new();
    let max_tries = 20_000 + 2_000 * cfg.views;
    let mut tries = 0;
    while views.len() < cfg.views && tries < max_tries {
        tries += 1;
        let q = random_joints(model, &mut rng);
        if !differs_from_all(&views, &q, constraints.min_joint_change_rad)
            || planner.check_motion(&q)?.is_err()
        {
            continue;
        }
        let origins: Vec<Point3<f64>> = model
            .link_poses(&q)?
            .iter()
            .map(|p| Point3::from(p.translation.vector))
            .collect();
        let clear_of_camera = origins.iter().all(|o| (o - eye).norm() > 0.25);
        if clear_of_camera && in_image(&Point3::origin()) && origins.iter().all(in_image) {
            views.push(q);
        }
    }
    if views.len() < cfg.views {
        return Err(PlanError::NotEnoughViews {
            found: views.len(),
            wanted: cfg.views,
            tries,
        });
    }
    Ok(views)
}

/// Simulates one scan of the arm `arm` (a physical UR arm, see
/// [`BenchConfig::true_arm`]; `None`: the settings' `kinematic_error`) and calibrates from it
/// without a prior, the model posed as `cfg.kinematics` says (known: by the DH the arm's
/// controller publishes). `mount` is where [`TrialPlan::mount`] says the camera is; errors are
/// measured on `flange_from_camera` (eye-in-hand) or `base_from_camera` in the model frame
/// (eye-to-hand).
#[allow(clippy::too_many_arguments)]
pub fn run_trial(
    model: &RobotModel,
    mount: Isometry3<f64>,
    joints: &[f64],
    arm: Option<PhysicalArm>,
    cfg: &BenchConfig,
    seed: u64,
    view: usize,
    scan_index: usize,
) -> Trial {
    run_views_trial(model, mount, &[(joints, seed)], arm, cfg, view, scan_index)
}

/// [`run_trial`] of a calibration run: one scan of each view (`(joints, seed)`) of the same
/// arm, calibrated together; the trial is numbered by its first view. Timings are the sums
/// over the scans, the uncertainty the fused result's.
pub fn run_views_trial(
    model: &RobotModel,
    mount: Isometry3<f64>,
    views: &[(&[f64], u64)],
    arm: Option<PhysicalArm>,
    cfg: &BenchConfig,
    view: usize,
    scan_index: usize,
) -> Trial {
    let mut trial = Trial {
        calibrated_kinematics: arm.is_some() && cfg.kinematics == BenchKinematics::Known,
        ..Trial::new(view, scan_index)
    };
    let t0 = Instant::now();
    let mut frames = Vec::with_capacity(views.len());
    let mut controller_dh = None;
    // Poses handed in another frame: each one is `handed_from_flange` = `handed_from_model` ·
    // `model_from_flange`, read by the solver as if the frame were the model's.
    let handed_from_model = pose_frame_offset(cfg.pose_frame, views[0].1).inverse();
    for (k, &(joints, seed)) in views.iter().enumerate() {
        let mut req = cfg.scan_request(model, joints, mount, seed);
        if let Some(arm) = arm {
            req = req.with_arm(arm);
        }
        let scan = match simulate_scan(&req) {
            Ok(s) => s,
            Err(e) => {
                trial.reasons.push(format!("simulation failed: {e}"));
                return trial;
            }
        };
        controller_dh = scan.truth.controller_dh;
        frames.push(Frame {
            view: k,
            cloud: scan.cloud,
            joints: joints.to_vec(),
            model_from_flange: Some(handed_from_model * scan.truth.model_from_flange_reported),
            source: format!("view {} scan {scan_index}", view + k),
            image: scan.image.map(std::sync::Arc::new),
        });
    }
    trial.simulate_ms = elapsed_ms(t0);
    let opts = PipelineOptions {
        register: cfg.register.clone(),
        gate: cfg.gate,
        controller_dh: controller_dh.filter(|_| trial.calibrated_kinematics),
        // Poses handed in another frame: the solver is told how far off it may be.
        pose_frame: (cfg.pose_frame != (0.0, 0.0)).then_some(cfg.pose_frame),
        ..PipelineOptions::new(cfg.mount)
    };
    let calibration = match calibrate_frames(model, &frames, &opts) {
        Ok(c) => c,
        Err(e) => {
            trial.reasons.push(e.to_string());
            return trial;
        }
    };
    let reg = &calibration.registrations[0];
    trial.quality = Some(reg.quality);
    for r in &calibration.registrations {
        let tm = r.timings_ms;
        trial.preprocess_ms += tm.preprocess;
        trial.coarse_ms += tm.coarse;
        trial.fine_ms += tm.fine;
        trial.verify_ms += tm.verify;
        trial.register_ms += tm.total;
    }
    trial.solve_ms = calibration.report.timings_ms.solve;
    let estimate = match cfg.mount {
        Mount::EyeInHand => calibration.solution.estimate,
        // The pipeline's base frame is the model root: `base_from_camera` is
        // `model_from_camera`.
        Mount::EyeToHand => calibration.base_from_camera,
    };
    let err = mount.inverse() * estimate;
    // One scan: its registration's σ; a run, or a scan whose colour image's outline was fitted
    // with its depth: the result's.
    let uncertainty = if views.len() == 1 && calibration.report.outline.is_none() {
        reg.uncertainty
    } else {
        calibration.report.uncertainty
    };
    let (sigma_mm, base_m) = uncertainty.position_mm(cfg.mount);
    // Eye-to-hand: the true robot base in the camera frame, where the σ is measured.
    let at = match base_m {
        Some(_) => Point3::from(mount.inverse().translation.vector),
        None => Point3::origin(),
    };
    trial.translation_error_mm = distance_at(&estimate, &mount, &at).0;
    if base_m.is_some() {
        trial.camera_origin_error_mm = Some(distance(&estimate, &mount).0);
    }
    trial.workspace_distance_m = base_m;
    trial.rotation_error_deg = err.rotation.angle().to_degrees();
    let (t, r) = (
        err.translation.vector * 1e3,
        err.rotation.scaled_axis().map(f64::to_degrees),
    );
    trial.error_pose = Some([t.x, t.y, t.z, r.x, r.y, r.z]);
    trial.uncertainty_translation_mm = sigma_mm;
    trial.uncertainty_rotation_deg = uncertainty.rotation_deg;
    trial.outcome = calibration.verdict.outcome;
    trial.reasons = calibration.verdict.reasons;
    trial
}

#[cfg(test)]
mod tests;
