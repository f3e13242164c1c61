//! `handeye solve`: calibrate from recorded scans — a run's kept capture (`--capture
//! capture.json`: its scans, joints, the controller's flange poses and kinematics), or scans
//! given one by one with their joints (and flange poses). It goes through the same pipeline as
//! a run (`handeye::calib::pipeline::calibrate_frames`).
//!
//! With `--scan`, each scan is one frame; `--joints` (and `--flange-pose`) are given once for
//! all frames or once per frame. Frames with identical joints form one view. Poses on the
//! command line are UR-style `x,y,z,rx,ry,rz` (metres, rotation vector) in `--base-frame`
//! (default: the URDF root link).

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{bail, Context};
use handeye::calib::pipeline::{calibrate_frames, fixed_frame, Frame, PipelineOptions};
use handeye::calib::{CalibError, Mount};
use handeye::geometry::SensorClass;
use handeye::model::{KinematicError, RobotModel, UrCalibration};
use handeye::storage::load_capture;
use handeye_hal::ur_dh::DhParams;
use nalgebra::Isometry3;

use super::args::{
    check_joint_limits, check_pose_distance, parse_distance, parse_joints, parse_kinematic_error,
    parse_max_uncertainty, parse_pose, resolve_robot, MAX_CELL_CAMERA_DISTANCE_M,
    MAX_MOUNT_DISTANCE_M,
};

/// Arguments of this subcommand.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// A run's kept capture (`runs/<id>/capture.json` in the storage folder): replays its
    /// scans with the joints, flange poses and kinematics recorded with them.
    #[arg(long, value_name = "FILE", conflicts_with_all = ["scan", "joints", "flange_pose"])]
    capture: Option<PathBuf>,
    /// With `--capture`: pose the model by the nominal URDF instead of the controller's
    /// calibrated kinematics recorded in the capture.
    #[arg(long, requires = "capture")]
    nominal_kinematics: bool,
    /// The arm's calibrated kinematics from UR's ROS calibration tool (`ur_calibration`'s
    /// YAML, `kinematics: {shoulder: {x, y, z, roll, pitch, yaw}, …, hash}`): the six joint
    /// origins replace the URDF's, so every link is posed as the calibrated arm. Used unless
    /// the capture holds the controller's own kinematics (those take precedence).
    #[arg(long, value_name = "FILE.yaml")]
    calibration: Option<PathBuf>,
    /// Robot description: a URDF (meshes relative to it) or a robot name (`ur5e`) under the
    /// robots directory; with `--capture` the default is the capture's model.
    #[arg(long)]
    robot: Option<PathBuf>,
    /// Joint angles at capture, radians, comma-separated, URDF order (once, or once per scan).
    #[arg(long, allow_hyphen_values = true)]
    joints: Vec<String>,
    /// Scan file (PLY or PCD, camera frame, metres); repeat for several frames/views.
    #[arg(long)]
    scan: Vec<PathBuf>,
    /// The colour (or intensity) image registered to each scan, pixel for pixel (PNG, 8- or
    /// 16-bit, grey or RGB): once per `--scan`, in the same order. A fixed camera's result then
    /// fits the arm's outline in it beside the depth (active stereo: the tilt its depth bends).
    #[arg(long, value_name = "FILE.png")]
    image: Vec<PathBuf>,
    /// Flange pose reported by the controller, `x,y,z,rx,ry,rz` in `--base-frame` (once, or
    /// once per scan). Without it the model's own forward kinematics is used.
    #[arg(long, allow_hyphen_values = true)]
    flange_pose: Vec<String>,
    /// Frame of the poses on the command line and of the reported `base_from_camera`
    /// (a link of the URDF, e.g. `base` for UR controller poses). Default: the URDF root link
    /// (`base` with `--capture`).
    #[arg(long)]
    base_frame: Option<String>,
    /// Guess of the camera on the flange, `x,y,z,rx,ry,rz` (speeds up and safeguards the search).
    #[arg(long, allow_hyphen_values = true)]
    guess_flange_from_camera: Option<String>,
    /// Guess of the fixed camera in `--base-frame` (eye-to-hand), `x,y,z,rx,ry,rz`.
    #[arg(long, allow_hyphen_values = true)]
    guess_base_from_camera: Option<String>,
    /// How the real arm differs from the URDF, per joint (1σ): zero offset (mrad), link length
    /// (mm), axis misalignment (mrad); for UR arms the DH θ, d and a, α; optionally each link
    /// housing's shift (mm) and turn (mrad) off its frame, the base's off joint 1's axis
    /// included. The base's, shoulder's and upper arm's displacements are estimated with this
    /// as their prior and the reported uncertainty carries what the scan cannot tell apart from
    /// them. Default: a manufactured UR arm (0.3,0.3,0.3,0.3,0.3); `0,0,0` when the URDF is
    /// the arm's calibrated kinematics (posed by the controller's kinematics or a calibration
    /// file only the housings and each link's place along its axis remain).
    #[arg(long, value_parser = parse_kinematic_error)]
    kinematic_error: Option<KinematicError>,
    /// Eye-in-hand: the camera is at most this far from the flange origin, metres (default
    /// 0.3). Poses farther out are not considered; raise it for a camera on a long tool.
    #[arg(long, value_name = "METRES", value_parser = parse_distance)]
    max_camera_flange_distance: Option<f64>,
    /// The camera is fixed in the cell (solve `base_from_camera`), not on the flange.
    #[arg(long)]
    eye_to_hand: bool,
    /// How the camera measures depth: `structured-light` (default: the depth scale is
    /// estimated), `active-stereo` (a RealSense D4xx class: the depth scale is estimated
    /// within Intel's documented 2 %, beyond which it is left at 1 with its 1 % in the
    /// uncertainty, and a depth error growing across the image is in the uncertainty),
    /// `time-of-flight` (the range offset is estimated and scan points in the model's concave
    /// corners, where multipath biases the range, are left out).
    #[arg(long, value_parser = parse_sensor)]
    sensor: Option<SensorClass>,
    /// The gate's largest 1σ per frame, `mm,degrees` (default `1.5,0.2`; the position eye-to-hand
    /// at the robot base): as `max_uncertainty_translation_mm` / `max_uncertainty_rotation_deg`
    /// in a cell config's `[gate]`. Raise it when a camera's own depth errors keep its σ above
    /// the default and that accuracy is enough for the cell.
    #[arg(long, value_name = "MM,DEG", value_parser = parse_max_uncertainty)]
    max_uncertainty: Option<(f64, f64)>,
    /// Print one JSON object instead of a summary.
    #[arg(long)]
    json: bool,
    /// Also write the report picture (PNG): the first scan as the camera saw it, coloured by
    /// distance to the posed model, with the model's outline, the residuals and the numbers.
    #[arg(long, value_name = "FILE")]
    report: Option<PathBuf>,
}

/// `--sensor`: a [`SensorClass`] by its kebab-case name.
fn parse_sensor(s: &str) -> Result<SensorClass, String> {
    match s {
        "structured-light" => Ok(SensorClass::StructuredLight),
        "active-stereo" => Ok(SensorClass::ActiveStereo),
        "time-of-flight" => Ok(SensorClass::TimeOfFlight),
        _ => Err(format!(
            "`{s}` is not a sensor class; use structured-light, active-stereo or time-of-flight"
        )),
    }
}

/// Picks the value for frame `i` from a list given once or once per frame.
fn per_frame<'a>(
    list: &'a [String],
    i: usize,
    what: &str,
    n: usize,
) -> anyhow::Result<Option<&'a String>> {
    match list.len() {
        0 => Ok(None),
        1 => Ok(list.first()),
        k if k == n => Ok(list.get(i)),
        k => bail!("{k} values of --{what} for {n} scans: give one, or one per --scan"),
    }
}

/// What to solve: the model, the frames and how they were taken.
struct Inputs {
    model: RobotModel,
    /// The run's prior (capture): `flange_from_camera` or `base_from_camera` in `base_frame`.
    prior: Option<Isometry3<f64>>,
    frames: Vec<Frame>,
    mount: Mount,
    base_frame: String,
    controller_dh: Option<DhParams>,
    /// The flange poses were given on the command line (from anywhere: a ROS `world`, a URDF
    /// root), not recorded from the controller in its `base`.
    poses_from_elsewhere: bool,
}

/// The frames of a run's capture file.
fn from_capture(path: &Path, args: &Args) -> anyhow::Result<Inputs> {
    let capture = load_capture(path).map_err(anyhow::Error::msg)?;
    let urdf = resolve_robot(
        &args
            .robot
            .as_ref()
            .map_or(capture.model.clone(), |p| p.to_string_lossy().into_owned()),
    )
    .map_err(anyhow::Error::msg)?;
    let model =
        RobotModel::load(&urdf).with_context(|| format!("loading robot {}", urdf.display()))?;
    let (frames, prior) = capture_frames(&capture, path, &model)?;
    Ok(Inputs {
        model,
        prior,
        frames,
        mount: capture.mount,
        base_frame: args.base_frame.clone().unwrap_or(capture.base_frame),
        controller_dh: if args.nominal_kinematics {
            None
        } else {
            capture.controller_dh
        },
        poses_from_elsewhere: false,
    })
}

/// A capture's frames, read and checked against `model` (scan count, joints, flange poses,
/// scan paths), and its prior. `path` is the capture file's (its scans are beside it).
fn capture_frames(
    capture: &handeye::storage::CaptureFile,
    path: &Path,
    model: &RobotModel,
) -> anyhow::Result<(Vec<Frame>, Option<Isometry3<f64>>)> {
    check_capture(capture, path, model).with_context(|| format!("capture {}", path.display()))
}

/// [`capture_frames`] without the file's name on its errors.
fn check_capture(
    capture: &handeye::storage::CaptureFile,
    path: &Path,
    model: &RobotModel,
) -> anyhow::Result<(Vec<Frame>, Option<Isometry3<f64>>)> {
    // A capture holds the controller's flange poses, which are in its `base`: a label naming
    // another frame (a ROS `world`, the URDF root) does not move them there, it only makes
    // the result 180° off (quoted: the name reaches the terminal).
    if capture.base_frame != "base" {
        bail!(
            "the capture labels its flange poses in `{}`: a capture's flange poses must be in \
             the controller's `base` frame (whose z is joint 1's axis; `base_link` turned by π \
             about z), as `handeye calibrate` records them; give the poses the controller \
             reports, or convert them (base_from_flange = base_from_<frame> · \
             <frame>_from_flange), and set \"base_frame\": \"base\"",
            handeye_hal::limits::Quoted(&capture.base_frame)
        );
    }
    let model_from_base = fixed_frame(model, &capture.base_frame)
        .with_context(|| format!("the capture's base frame `{}`", capture.base_frame))?;
    let dir = path.parent().unwrap_or(Path::new("."));
    // A capture is input like any other: as many scans as `--scan` takes, joints this model
    // can take, flange poses that belong to them, scans in the capture's own folder.
    let listed: usize = capture.views.iter().map(|v| v.frames.len()).sum();
    if listed > MAX_SCANS {
        bail!(
            "{}: {listed} frames listed: at most {MAX_SCANS} (every scan is held in memory)",
            path.display()
        );
    }
    let mut frames = Vec::new();
    for view in &capture.views {
        let what = format!("{}: view {}", path.display(), view.view);
        let base_from_flange = handeye::frames::from_row_major(&view.base_from_flange)
            .with_context(|| format!("{what}: the flange pose is not a rigid transform"))?;
        if view.joints.len() != model.dof() {
            return Err(CalibError::JointCountMismatch {
                expected: model.dof(),
                got: view.joints.len(),
            })
            .with_context(|| what.clone());
        }
        check_joint_limits(&format!("{what}: joints"), model, &view.joints)
            .map_err(anyhow::Error::msg)?;
        check_flange_pose(
            model,
            &view.joints,
            &(model_from_base * base_from_flange),
            (&capture.base_frame, &model_from_base),
            capture
                .controller_dh
                .as_ref()
                .filter(|_| capture.dh_from_controller),
            &format!("{what}: the flange pose"),
        )?;
        for f in &view.frames {
            let Some(p) = &f.path else {
                bail!("{what}: a frame was not kept (storage.keep_captures = false)");
            };
            // A run names its scans `view-…-frame-….ply`: no control character (it would
            // reach the operator's terminal in every message naming the file).
            if !Path::new(p)
                .components()
                .all(|c| matches!(c, std::path::Component::Normal(_)))
                || p.chars().any(char::is_control)
            {
                bail!(
                    "{what}: scan `{}` is not a file in the capture's folder",
                    handeye_hal::limits::Quoted(p)
                );
            }
            let p = dir.join(p);
            let cloud = handeye::cloud::read_cloud(&p)
                .with_context(|| format!("reading scan {}", p.display()))?;
            frames.push(Frame {
                view: view.view,
                cloud,
                joints: view.joints.clone(),
                model_from_flange: Some(model_from_base * base_from_flange),
                source: p.display().to_string(),
                image: None,
            });
        }
    }
    let prior = capture
        .prior
        .as_ref()
        .map(|m| {
            handeye::frames::from_row_major(m)
                .context("the capture's prior is not a rigid transform")
        })
        .transpose()?;
    Ok((frames, prior))
}

/// Most scans one solve takes.
const MAX_SCANS: usize = 100;

/// Refuses a reported flange pose (`model_from_flange`, `what` in messages) that cannot belong
/// to `joints`: by the controller's DH when `dh` is the controller's own (it computed the
/// pose), else by the nominal URDF ([`handeye::model::reported`]). `model_from_base` places
/// `base_frame`, the frame the pose was reported in.
fn check_flange_pose(
    model: &RobotModel,
    joints: &[f64],
    reported: &Isometry3<f64>,
    (base_frame, model_from_base): (&str, &Isometry3<f64>),
    dh: Option<&DhParams>,
    what: &str,
) -> anyhow::Result<()> {
    use handeye::model::reported::{check_reported_flange, FlangeReference};
    let reference = match dh {
        Some(dh) => FlangeReference::ControllerDh {
            dh,
            model_from_base,
        },
        None => FlangeReference::Nominal,
    };
    if let Err(m) = check_reported_flange(model, joints, reported, reference)? {
        bail!(
            "{what} {m} ({} in `{base_frame}`): give the controller's flange pose (not the \
             TCP) for these joints, in --base-frame (`base` for UR controller poses), for this \
             robot model",
            handeye_hal::UrPose::from(&(model_from_base.inverse() * m.computed)),
        );
    }
    Ok(())
}

/// The frames given scan by scan on the command line.
fn from_scans(args: &Args) -> anyhow::Result<Inputs> {
    let robot = args
        .robot
        .as_ref()
        .context("--robot is required with --scan (or replay a run with --capture)")?;
    if args.scan.is_empty() {
        bail!("give --scan (with --joints) or --capture");
    }
    if args.scan.len() > MAX_SCANS {
        bail!(
            "{} --scan files: at most {MAX_SCANS} (every scan is held in memory)",
            args.scan.len()
        );
    }
    let urdf = &resolve_robot(&robot.to_string_lossy()).map_err(anyhow::Error::msg)?;
    let model =
        RobotModel::load(urdf).with_context(|| format!("loading robot {}", urdf.display()))?;
    let base_frame = args
        .base_frame
        .clone()
        .unwrap_or_else(|| model.root_link().to_string());
    let model_from_base =
        fixed_frame(&model, &base_frame).with_context(|| format!("--base-frame `{base_frame}`"))?;
    let n = args.scan.len();
    if !args.image.is_empty() && args.image.len() != n {
        bail!(
            "{} --image files for {n} scans: give one per --scan, in the same order",
            args.image.len()
        );
    }
    let mut view_keys: Vec<String> = Vec::new();
    let mut frames = Vec::new();
    for (i, scan_path) in args.scan.iter().enumerate() {
        let joints_text =
            per_frame(&args.joints, i, "joints", n)?.context("--joints is required")?;
        let joints = parse_joints(joints_text)
            .map_err(|e| anyhow::anyhow!("--joints: {e}"))?
            .0;
        if joints.len() != model.dof() {
            return Err(CalibError::JointCountMismatch {
                expected: model.dof(),
                got: joints.len(),
            })
            .with_context(|| format!("scan {}", scan_path.display()));
        }
        check_joint_limits("--joints", &model, &joints).map_err(anyhow::Error::msg)?;
        let model_from_flange = per_frame(&args.flange_pose, i, "flange-pose", n)?
            .map(|p| parse_pose(p).map(|p| model_from_base * p))
            .transpose()
            .map_err(|e| anyhow::anyhow!("--flange-pose: {e}"))?;
        if let Some(reported) = &model_from_flange {
            check_flange_pose(
                &model,
                &joints,
                reported,
                (&base_frame, &model_from_base),
                None,
                "--flange-pose",
            )
            .with_context(|| format!("scan {}", scan_path.display()))?;
        }
        let cloud = handeye::cloud::read_cloud(scan_path)
            .with_context(|| format!("reading scan {}", scan_path.display()))?;
        let view = match view_keys.iter().position(|k| k == joints_text) {
            Some(v) => v,
            None => {
                view_keys.push(joints_text.clone());
                view_keys.len() - 1
            }
        };
        frames.push(Frame {
            view,
            cloud,
            joints,
            model_from_flange,
            source: scan_path.display().to_string(),
            image: args
                .image
                .get(i)
                .map(|p| {
                    handeye::cloud::read_png(p)
                        .map(std::sync::Arc::new)
                        .with_context(|| format!("reading image {}", p.display()))
                })
                .transpose()?,
        });
    }
    Ok(Inputs {
        model,
        prior: None,
        frames,
        mount: if args.eye_to_hand {
            Mount::EyeToHand
        } else {
            Mount::EyeInHand
        },
        base_frame,
        controller_dh: None,
        poses_from_elsewhere: !args.flange_pose.is_empty(),
    })
}

/// Runs the solve; with `--json` a failure is also one JSON object on stdout,
/// `{"status": "error", "error": "<message>"}` (exit 2), so a script always gets an object.
pub(crate) fn run(args: Args) -> anyhow::Result<ExitCode> {
    let json = args.json;
    match solve(args) {
        Err(e) if json => {
            let message = super::args::error_text(&e);
            println!(
                "{}",
                serde_json::json!({"status": "error", "outcome": "error", "error": message})
            );
            eprintln!("error: {message}");
            Ok(ExitCode::from(2))
        }
        other => other,
    }
}

/// Poses the model by `--calibration`'s DH set unless the controller's kinematics are there, and
/// says which kinematics pose the model (the `kinematics` object of the JSON output).
fn choose_kinematics(inputs: &mut Inputs, args: &Args) -> anyhow::Result<serde_json::Value> {
    let used = match (&inputs.controller_dh, &args.calibration) {
        (Some(_), Some(file)) => serde_json::json!({
            "source": "controller",
            "note": format!(
                "the controller's kinematics recorded in the capture take precedence over \
                 --calibration {}",
                file.display()
            ),
        }),
        (Some(_), None) => serde_json::json!({"source": "controller"}),
        (None, Some(file)) => {
            let calibration = UrCalibration::load(file)?;
            // The file's DH set poses the model exactly as the controller's would.
            let ur_model = inputs.model.ur_model().ok_or_else(|| {
                anyhow::anyhow!(
                    "--calibration: {} is not a UR arm (its file or robot name must name the \
                     model, e.g. ur5e)",
                    inputs.model.name()
                )
            })?;
            let dh = calibration
                .dh(&ur_model.dh())
                .map_err(|e| anyhow::anyhow!("--calibration: {e}"))?;
            // As the run's preflight does: the file must calibrate this model's arm.
            handeye::run::check_model_matches(
                ur_model,
                None,
                Some((&dh, handeye::run::KinematicsOrigin::File)),
            )
            .map_err(|e| anyhow::anyhow!("--calibration {}: {e}", file.display()))?;
            inputs.controller_dh = Some(dh);
            serde_json::json!({
                "source": "file",
                "file": file.display().to_string(),
                "hash": calibration.hash,
            })
        }
        (None, None) => serde_json::json!({"source": "nominal"}),
    };
    eprintln!("kinematics: {used}");
    Ok(used)
}

fn solve(args: Args) -> anyhow::Result<ExitCode> {
    let mut inputs = match &args.capture {
        Some(path) => from_capture(path, &args)?,
        None => from_scans(&args)?,
    };
    let kinematics = choose_kinematics(&mut inputs, &args)?;
    let model = &inputs.model;
    let model_from_base = fixed_frame(model, &inputs.base_frame)?;
    let mut opts = PipelineOptions::new(inputs.mount);
    opts.base_frame = Some(inputs.base_frame.clone());
    opts.controller_dh = inputs.controller_dh;
    // Posed by the controller's or the file's kinematics, the pipeline covers no kinematic
    // error; otherwise the nominal model's.
    if let Some(k) = args.kinematic_error {
        opts.register.kinematic_error = k;
    }
    // Poses from elsewhere than the controller, posed by the nominal URDF: nothing ties their
    // frame to joint 1's axis closer than the arm's build, so the views estimate it.
    if inputs.poses_from_elsewhere && opts.controller_dh.is_none() {
        let arm = &opts.register.kinematic_error;
        opts.pose_frame = Some((
            arm.housing_translation_sigma_m,
            arm.housing_rotation_sigma_rad,
        ));
    }
    if let Some(class) = args.sensor {
        opts.register = opts.register.for_sensor(class);
        opts.gate = handeye::calib::GateThresholds::for_sensor(class);
    }
    if let Some((mm, deg)) = args.max_uncertainty {
        opts.gate.max_uncertainty_translation_mm = mm;
        opts.gate.max_uncertainty_rotation_deg = deg;
    }
    if inputs.mount == Mount::EyeInHand {
        if let Some(d) = args.max_camera_flange_distance {
            opts.register.max_camera_flange_distance_m = Some(d);
        }
    }
    let guess = |flag: &str, text: &Option<String>| -> anyhow::Result<Option<Isometry3<f64>>> {
        let pose = text
            .as_deref()
            .map(parse_pose)
            .transpose()
            .map_err(|e| anyhow::anyhow!("--{flag}: {e}"))?;
        if let Some(p) = &pose {
            let (max, what) = match inputs.mount {
                Mount::EyeInHand => (MAX_MOUNT_DISTANCE_M, "a camera on the flange"),
                Mount::EyeToHand => (MAX_CELL_CAMERA_DISTANCE_M, "a camera in the robot's cell"),
            };
            check_pose_distance(&format!("--{flag}"), p, max, what).map_err(anyhow::Error::msg)?;
        }
        Ok(pose)
    };
    // A guess of the other mount's unknown would be ignored: refuse it instead.
    let wrong_guess = match inputs.mount {
        Mount::EyeInHand => args.guess_base_from_camera.as_ref().map(|_| {
            (
                "--guess-base-from-camera",
                "an eye-in-hand solve",
                "--guess-flange-from-camera",
            )
        }),
        Mount::EyeToHand => args.guess_flange_from_camera.as_ref().map(|_| {
            (
                "--guess-flange-from-camera",
                "--eye-to-hand",
                "--guess-base-from-camera",
            )
        }),
    };
    if let Some((given, mount, right)) = wrong_guess {
        bail!("{given} is a guess of the other mount's unknown and {mount} would ignore it; give {right}");
    }
    // A guess on the command line, else the one the run registered with.
    opts.prior = match inputs.mount {
        Mount::EyeInHand => {
            guess("guess-flange-from-camera", &args.guess_flange_from_camera)?.or(inputs.prior)
        }
        Mount::EyeToHand => guess("guess-base-from-camera", &args.guess_base_from_camera)?
            .or(inputs.prior)
            .map(|bc| model_from_base * bc),
    };
    let calibration = calibrate_frames(model, &inputs.frames, &opts)?;
    if args.json {
        let mut out = serde_json::to_value(&calibration.report)?;
        if let Some(o) = out.as_object_mut() {
            o.insert("kinematics".into(), kinematics);
        }
        println!("{}", serde_json::to_string_pretty(&out)?);
    } else {
        print!("{}", calibration.report.summary());
    }
    if let Some(path) = &args.report {
        write_report(path, &inputs, &opts, &calibration)?;
    }
    Ok(if calibration.verdict.passed() {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    })
}

/// `--report`: the picture of the first frame and the result.
fn write_report(
    path: &Path,
    inputs: &Inputs,
    opts: &PipelineOptions,
    calibration: &handeye::run::Calibration,
) -> anyhow::Result<()> {
    let t = std::time::Instant::now();
    let (Some(frame), Some(registration)) =
        (inputs.frames.first(), calibration.registrations.first())
    else {
        bail!("no frame to draw in {}", path.display());
    };
    let caption = format!(
        "view {}, frame 1 of {}: {}",
        frame.view + 1,
        inputs.frames.len(),
        frame.source
    );
    let view = handeye::report::scan_view(
        &inputs.model,
        &frame.joints,
        opts.controller_dh.as_ref(),
        &frame.cloud,
        registration,
        &caption,
        1,
    )?;
    let name = Path::new(&frame.source)
        .file_name()
        .map_or(frame.source.clone(), |n| n.to_string_lossy().into_owned());
    let summary = handeye::report::Summary::from_report(&calibration.report, &name);
    let png = handeye::report::render(&summary, std::slice::from_ref(&view))?;
    std::fs::write(path, png)
        .with_context(|| format!("writing the report picture {}", path.display()))?;
    eprintln!(
        "report picture: {} ({:.0} ms)",
        path.display(),
        t.elapsed().as_secs_f64() * 1e3
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use handeye::sim::{
        simulate_scan, CellOptions, Intrinsics, KinematicError, Placement, ScanNoise, ScanRequest,
    };
    use nalgebra::Vector3;

    fn args(robot: PathBuf, joints: &str, scan: PathBuf, flange: Option<String>) -> Args {
        Args {
            capture: None,
            nominal_kinematics: false,
            calibration: None,
            robot: Some(robot),
            joints: vec![joints.to_string()],
            scan: vec![scan],
            image: vec![],
            flange_pose: flange.into_iter().collect(),
            base_frame: Some("base".into()),
            guess_flange_from_camera: None,
            guess_base_from_camera: None,
            kinematic_error: None,
            max_camera_flange_distance: None,
            eye_to_hand: false,
            sensor: None,
            max_uncertainty: None,
            json: true,
            report: None,
        }
    }

    #[test]
    fn solve_command_on_a_simulated_scan_and_bad_inputs() {
        let Some(dir) = super::super::args::robots_dir_or_skip(
            "solve_command_on_a_simulated_scan_and_bad_inputs",
        ) else {
            return;
        };
        let urdf = dir.join("ur/ur5e/ur5e.urdf");
        let model = RobotModel::load(&urdf).expect("ur5e loads");
        let mount = Isometry3::new(
            Vector3::new(0.0, -0.08, 0.03),
            Vector3::new(-15f64.to_radians(), 0.0, 0.0),
        );
        let intr = Intrinsics::compact_1280x960();
        let planner = handeye::plan::ViewPlanner::new(
            &model,
            mount,
            intr,
            handeye::plan::ViewConstraints::default(),
        );
        let q = planner.generate(1, 5).expect("a view").remove(0);
        let req = ScanRequest {
            model: &model,
            joints: q.clone(),
            placement: Placement::EyeInHand {
                flange_from_camera: mount,
            },
            intrinsics: intr,
            noise: ScanNoise::default(),
            cell: CellOptions::default(),
            kinematic_error: KinematicError::none(),
            arm: None,
            seed: 2,
        };
        let sim = simulate_scan(&req).expect("simulated");
        let tmp = std::env::temp_dir().join(format!("handeye-solve-{}", std::process::id()));
        std::fs::create_dir_all(&tmp).expect("temp dir");
        let ply = tmp.join("scan.ply");
        handeye::cloud::write_ply(&ply, &sim.cloud, Default::default()).expect("written");
        let joints = q
            .iter()
            .map(|v| format!("{v}"))
            .collect::<Vec<_>>()
            .join(",");
        // Flange pose as the UR controller reports it, in `base`.
        let base_from_flange =
            handeye::frames::ur_base_from_base_link() * sim.truth.model_from_flange_reported;
        // As URScript prints it: `p[x,y,z,rx,ry,rz]`, which `--flange-pose` reads too.
        let flange = handeye_hal::UrPose::from(&base_from_flange).to_script();
        let code = run(args(urdf.clone(), &joints, ply.clone(), Some(flange))).expect("runs");
        assert_eq!(code, ExitCode::SUCCESS);
        // Joint count mismatch and an unreadable scan are errors (exit 2 in main).
        let short = q[..5]
            .iter()
            .map(|v| format!("{v}"))
            .collect::<Vec<_>>()
            .join(",");
        let e = solve(args(urdf.clone(), &short, ply.clone(), None)).expect_err("mismatch");
        assert!(format!("{e:#}").contains("joint"), "{e:#}");
        let e =
            solve(args(urdf.clone(), &joints, tmp.join("missing.ply"), None)).expect_err("no scan");
        assert!(format!("{e:#}").contains("missing.ply"), "{e:#}");
        // With --json a failure is an exit code 2 (and one JSON object on stdout).
        let code = run(args(urdf.clone(), &short, ply.clone(), None)).expect("json error");
        assert_eq!(code, ExitCode::from(2));
        // Issue 16: robot names as `demo` and `bench` take them.
        let e = solve(args("ur5e".into(), &short, ply.clone(), None)).expect_err("mismatch");
        assert!(format!("{e:#}").contains("joint"), "{e:#}");
        // Issue 16: a flange pose metres (or degrees) away from the joints' forward kinematics
        // is refused, naming both.
        let mut far = base_from_flange;
        far.translation.vector.x += 5.0;
        for wrong in [
            far,
            base_from_flange * Isometry3::rotation(Vector3::new(0.0, 0.0, 10f64.to_radians())),
        ] {
            let flange = handeye_hal::UrPose::from(&wrong).to_string();
            let e = solve(args(urdf.clone(), &joints, ply.clone(), Some(flange)))
                .expect_err("flange pose of other joints");
            let text = format!("{e:#}");
            assert!(
                text.contains("--flange-pose is")
                    && text.contains("from the flange pose the nominal URDF gives for its joints"),
                "{text}"
            );
        }
        // Issue 25: the gate's σ limit is the user's: a limit below the scan's σ rejects the
        // same scan (exit 1), the default accepts it.
        let mut strict = args(urdf.clone(), &joints, ply.clone(), None);
        strict.max_uncertainty = Some((0.001, 0.0001));
        assert_eq!(run(strict).expect("runs"), ExitCode::from(1));
        // Issue 25: a guess of the other mount's unknown is refused, not ignored.
        let mut wrong_guess = args(urdf.clone(), &joints, ply.clone(), None);
        wrong_guess.guess_base_from_camera = Some("0.5,0,0.5,0,0,0".into());
        let e = solve(wrong_guess).expect_err("a base guess for an eye-in-hand solve");
        assert!(
            format!("{e:#}").contains("--guess-flange-from-camera"),
            "{e:#}"
        );
        // Issue 35: a calibration file of another arm (a UR10e's for this UR5e) is refused as
        // the run's preflight refuses it; this arm's file is taken.
        use handeye_hal::ur_dh::UrModel;
        for (arm, refused) in [(UrModel::Ur10e, true), (UrModel::Ur5e, false)] {
            let file = tmp.join(format!("{arm}_calibration.yaml"));
            let yaml = handeye::model::ur_calibration_yaml(&arm.dh(), &arm.dh(), "calib_35");
            std::fs::write(&file, yaml).expect("calibration file");
            let mut with_file = args(urdf.clone(), &joints, ply.clone(), None);
            with_file.calibration = Some(file);
            let r = solve(with_file);
            if refused {
                let text = format!("{:#}", r.expect_err("another arm's calibration"));
                assert!(
                    text.contains("--calibration")
                        && text.contains("the calibration file's kinematics are a ur10e"),
                    "{text}"
                );
            } else {
                r.expect("this arm's calibration");
            }
        }
        let _ = std::fs::remove_dir_all(&tmp);
    }

    /// Issue 23 (found by the `capture` fuzz target): a scan path with a control character
    /// was echoed raw in the error (the file does not exist); now refused by name, escaped.
    #[test]
    fn issue_23_capture_scan_path_with_control_character_is_refused() {
        let capture: handeye::storage::CaptureFile = serde_json::from_str(
            r#"{"model":"ur5e","mount":"eye_in_hand","base_frame":"base","views":[{"view":0,
            "joints":[0,0,0,0,0,0],"base_from_flange":[[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]],
            "unix_time_s":0,"joint_change_during_capture_rad":0,
            "frames":[{"path":"scan-1\u007f","width":2,"height":2,"valid_points":4}]}]}"#,
        )
        .expect("parses");
        let Some(dir) = super::super::args::robots_dir_or_skip(
            "issue_23_capture_scan_path_with_control_character_is_refused",
        ) else {
            return;
        };
        let model = RobotModel::load(&dir.join("ur/ur5e/ur5e.urdf")).expect("ur5e loads");
        // Joints at zero and a flange pose that is their forward kinematics.
        let mut capture = capture;
        let fk = fixed_frame(&model, "base").expect("base").inverse()
            * model
                .frame_pose(model.flange_link(), &[0.0; 6])
                .expect("fk");
        capture.views[0].base_from_flange = handeye::frames::to_row_major(&fk);
        let e = capture_frames(&capture, Path::new("/nowhere/capture.json"), &model)
            .expect_err("refused");
        let msg = format!("{e:#}");
        assert!(
            msg.contains("is not a file in the capture's folder"),
            "{msg}"
        );
        assert!(!msg.chars().any(char::is_control), "{msg:?}");
    }

    /// Issue 46: a capture whose flange poses (the controller's, in `base`) are labelled in
    /// another frame — `world`, the UR5e URDF's root, sits on `base_link`, π about z from
    /// `base` — was solved 812 mm / 180° off; now it is refused, saying which frame the poses
    /// must be in and how to get them there. The same capture labelled `base` passes that
    /// check (its scan is missing, which is the next error).
    #[test]
    fn issue_46_a_capture_labelled_in_another_frame_than_base_is_refused() {
        let Some(dir) = super::super::args::robots_dir_or_skip(
            "issue_46_a_capture_labelled_in_another_frame_than_base_is_refused",
        ) else {
            return;
        };
        let model = RobotModel::load(&dir.join("ur/ur5e/ur5e.urdf")).expect("ur5e loads");
        let q = [0.3, -1.2, 1.4, -1.6, -1.5, 0.2];
        let base_from_flange = fixed_frame(&model, "base").expect("base").inverse()
            * model.frame_pose(model.flange_link(), &q).expect("fk");
        let capture = |frame: &str| {
            let text = format!(
                r#"{{"model":"ur5e","mount":"eye_in_hand","base_frame":"{frame}","views":[{{"view":0,
                "joints":{q:?},"base_from_flange":{:?},
                "unix_time_s":0,"joint_change_during_capture_rad":0,
                "frames":[{{"path":"scan.ply","width":2,"height":2,"valid_points":4}}]}}]}}"#,
                handeye::frames::to_row_major(&base_from_flange)
            );
            serde_json::from_str::<handeye::storage::CaptureFile>(&text).expect("parses")
        };
        let at = Path::new("/nowhere/capture.json");
        for frame in ["world", "base_link", "Base", "base\\u0007"] {
            let e = capture_frames(&capture(frame), at, &model).expect_err("refused");
            let msg = format!("{e:#}");
            assert!(
                msg.contains("must be in the controller's `base` frame (whose z is joint 1's axis")
                    && msg.contains("set \"base_frame\": \"base\""),
                "{frame}: {msg}"
            );
            assert!(!msg.chars().any(char::is_control), "{msg:?}");
        }
        let e = capture_frames(&capture("base"), at, &model).expect_err("no scan");
        assert!(format!("{e:#}").contains("scan.ply"), "{e:#}");
    }

    /// Fuzz target `capture` (hal::fuzz): mutations of capture files a run writes (eye-in-hand
    /// with a prior and the controller's calibrated kinematics; two views) — numbers replaced
    /// by extreme ones, poses, joints and paths spliced, structure broken — are parsed and
    /// checked against the UR5e (scan count, joints within limits, flange pose against the
    /// joints' forward kinematics, scans in the capture's folder) and give frames or an error
    /// naming the capture file.
    #[test]
    fn fuzz_capture() {
        use handeye::record::{CaptureRecord, FrameRecord};
        use handeye::storage::{parse_capture, CaptureFile};
        let Some(dir) = super::super::args::robots_dir_or_skip("fuzz_capture") else {
            return;
        };
        let model = RobotModel::load(&dir.join("ur/ur5e/ur5e.urdf")).expect("ur5e loads");
        let tmp = std::env::temp_dir().join(format!("handeye-fuzz-capture-{}", std::process::id()));
        std::fs::create_dir_all(&tmp).expect("temp dir");
        let cloud = handeye_hal::PointCloud {
            width: 2,
            height: 2,
            points: vec![nalgebra::Point3::new(0.1f32, 0.2, 0.9); 4],
            ..Default::default()
        };
        for name in ["scan-0.ply", "scan-1.ply"] {
            handeye::cloud::write_ply(&tmp.join(name), &cloud, Default::default()).expect("ply");
        }
        let base_from_model = fixed_frame(&model, "base").expect("base").inverse();
        let view = |view: usize, q: Vec<f64>, scans: &[&str]| CaptureRecord {
            view,
            base_from_flange: handeye::frames::to_row_major(
                &(base_from_model
                    * model
                        .frame_pose(model.flange_link(), &q)
                        .expect("forward kinematics")),
            ),
            joints: q,
            unix_time_s: 1.8e9,
            joint_change_during_capture_rad: 1e-5,
            frames: scans
                .iter()
                .map(|s| FrameRecord {
                    path: Some((*s).to_string()),
                    width: 2,
                    height: 2,
                    valid_points: 4,
                })
                .collect(),
        };
        let one = CaptureFile {
            model: "ur5e".into(),
            mount: Mount::EyeInHand,
            base_frame: "base".into(),
            prior: Some(handeye::frames::to_row_major(&Isometry3::new(
                nalgebra::Vector3::new(0.0, -0.08, 0.03),
                nalgebra::Vector3::new(-0.26, 0.0, 0.0),
            ))),
            controller_dh: Some(handeye_hal::ur_dh::UrModel::Ur5e.dh()),
            dh_from_controller: true,
            views: vec![view(
                0,
                vec![0.1, -1.2, 1.0, -1.4, -1.5, 0.2],
                &["scan-0.ply"],
            )],
        };
        let two = CaptureFile {
            prior: None,
            controller_dh: None,
            views: vec![
                view(
                    0,
                    vec![-0.3, -1.6, 1.4, -1.2, -1.6, 0.0],
                    &["scan-0.ply", "scan-1.ply"],
                ),
                view(1, vec![0.4, -1.0, 0.9, -1.9, -1.4, 0.5], &["scan-1.ply"]),
            ],
            ..one.clone()
        };
        let seeds = [one, two]
            .iter()
            .map(|c| serde_json::to_vec_pretty(c).expect("json"))
            .collect();
        let path = tmp.join("capture.json");
        handeye_hal::fuzz::Target::new("capture", seeds).run(|b| {
            let capture = parse_capture(&String::from_utf8_lossy(b), &path)?;
            let (frames, _) = capture_frames(&capture, &path, &model).map_err(|e| {
                let msg = format!("{e:#}");
                assert!(
                    msg.contains("capture.json") || msg.contains("scan"),
                    "{msg}"
                );
                msg
            })?;
            assert!(frames.len() <= MAX_SCANS);
            Ok::<(), String>(())
        });
        let _ = std::fs::remove_dir_all(&tmp);
    }
}
