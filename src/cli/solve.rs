//! `handeye solve`: calibrate from recorded scans and joint angles.
//!
//! Each `--scan` is one frame; `--joints` (and `--flange-pose`) are given once for all frames or
//! once per frame. Frames with identical joints form one view. Poses on the command line are
//! UR-style `x,y,z,rx,ry,rz` (metres, rotation vector) in `--base-frame` (default: the URDF
//! root link), parsed here with nalgebra (the `UrPose` type of `drivers/ur` is not used).

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{bail, Context};
use handeye::calib::{
    gate, posed_model, register_posed, solve, CalibError, CalibrationReport, FrameInput,
    GateThresholds, Mount, RegisterOptions, SolveOptions,
};
use handeye::model::{KinematicError, RobotModel};
use nalgebra::Isometry3;

use super::args::{parse_distance, parse_joints, parse_kinematic_error, parse_pose};

/// Arguments of this subcommand.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Robot description (URDF with meshes relative to it).
    #[arg(long)]
    robot: PathBuf,
    /// Joint angles at capture, radians, comma-separated, URDF order (once, or once per scan).
    #[arg(long, required = true, allow_hyphen_values = true)]
    joints: Vec<String>,
    /// Scan file (PLY or PCD, camera frame, metres); repeat for several frames/views.
    #[arg(long, required = true)]
    scan: Vec<PathBuf>,
    /// Flange pose reported by the controller, `x,y,z,rx,ry,rz` in `--base-frame` (once, or
    /// once per scan). Without it the model's own forward kinematics is used.
    #[arg(long, allow_hyphen_values = true)]
    flange_pose: Vec<String>,
    /// Frame of the poses on the command line and of the reported `base_from_camera`
    /// (a link of the URDF, e.g. `base` for UR controller poses). Default: the URDF root link.
    #[arg(long)]
    base_frame: Option<String>,
    /// Guess of the camera on the flange, `x,y,z,rx,ry,rz` (speeds up and safeguards the search).
    #[arg(long, allow_hyphen_values = true)]
    guess_flange_from_camera: Option<String>,
    /// Guess of the fixed camera in `--base-frame` (eye-to-hand), `x,y,z,rx,ry,rz`.
    #[arg(long, allow_hyphen_values = true)]
    guess_base_from_camera: Option<String>,
    /// How the real arm differs from the URDF, per joint (1σ): zero offset (mrad), link length
    /// (mm), axis misalignment (mrad). The reported uncertainty carries what it does to the
    /// result. Default: UR factory-calibration deltas (0.3,0.3,0.1); `0,0,0` when the URDF is
    /// the controller's calibrated kinematics.
    #[arg(long, value_parser = parse_kinematic_error)]
    kinematic_error: Option<KinematicError>,
    /// Eye-in-hand: the camera is at most this far from the flange origin, metres (default
    /// 0.3). Poses farther out are not considered; raise it for a camera on a long tool.
    #[arg(long, value_name = "METRES", value_parser = parse_distance)]
    max_camera_flange_distance: Option<f64>,
    /// The camera is fixed in the cell (solve `base_from_camera`), not on the flange.
    #[arg(long)]
    eye_to_hand: bool,
    /// Print one JSON object instead of a summary.
    #[arg(long)]
    json: bool,
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

pub(crate) fn run(args: Args) -> anyhow::Result<ExitCode> {
    let t0 = Instant::now();
    let model = RobotModel::load(&args.robot)
        .with_context(|| format!("loading robot {}", args.robot.display()))?;
    let base_frame = args
        .base_frame
        .clone()
        .unwrap_or_else(|| model.root_link().to_string());
    let n = args.scan.len();
    let mount = if args.eye_to_hand {
        Mount::EyeToHand
    } else {
        Mount::EyeInHand
    };
    let zero = vec![0.0; model.dof()];
    // base_from_model: the base frame is fixed to the root (no movable joint in between).
    let model_from_base = model
        .frame_pose(&base_frame, &zero)
        .with_context(|| format!("--base-frame `{base_frame}` is not a link of the robot"))?;
    if model.chain_depth(&base_frame).unwrap_or(0) != 0 {
        bail!("--base-frame `{base_frame}` moves with the joints; give a fixed frame such as the root link");
    }
    let base_from_model = model_from_base.inverse();

    let mut registrations = Vec::new();
    let mut frames = Vec::new();
    let mut sources = Vec::new();
    let mut view_keys: Vec<String> = Vec::new();
    let defaults = RegisterOptions::default();
    let opts = RegisterOptions {
        kinematic_error: args.kinematic_error.unwrap_or(defaults.kinematic_error),
        max_camera_flange_distance_m: match mount {
            Mount::EyeInHand => args
                .max_camera_flange_distance
                .or(defaults.max_camera_flange_distance_m),
            Mount::EyeToHand => None,
        },
        ..defaults
    };
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
        let model_from_flange = match per_frame(&args.flange_pose, i, "flange-pose", n)? {
            Some(p) => {
                model_from_base
                    * parse_pose(p).map_err(|e| anyhow::anyhow!("--flange-pose: {e}"))?
            }
            None => model.frame_pose(model.flange_link(), &joints)?,
        };
        let cloud = handeye::cloud::read_cloud(scan_path)
            .with_context(|| format!("reading scan {}", scan_path.display()))?;
        let prior: Option<Isometry3<f64>> = match mount {
            Mount::EyeInHand => args
                .guess_flange_from_camera
                .as_deref()
                .map(parse_pose)
                .transpose()
                .map_err(|e| anyhow::anyhow!("--guess-flange-from-camera: {e}"))?
                .map(|fc| (model_from_flange * fc).inverse()),
            Mount::EyeToHand => args
                .guess_base_from_camera
                .as_deref()
                .map(parse_pose)
                .transpose()
                .map_err(|e| anyhow::anyhow!("--guess-base-from-camera: {e}"))?
                .map(|bc| (model_from_base * bc).inverse()),
        };
        let posed = posed_model(&model, &joints)?;
        let reg = register_posed(&cloud, &posed, prior, &opts)
            .with_context(|| format!("registering scan {}", scan_path.display()))?;
        let view = match view_keys.iter().position(|k| k == joints_text) {
            Some(v) => v,
            None => {
                view_keys.push(joints_text.clone());
                view_keys.len() - 1
            }
        };
        frames.push(FrameInput {
            view,
            camera_from_model: reg.camera_from_model,
            model_from_flange: Some(model_from_flange),
        });
        registrations.push(reg);
        sources.push(scan_path.display().to_string());
    }
    let t_solve = Instant::now();
    let solution = solve(mount, &frames, &SolveOptions::default())?;
    let verdict = gate(&registrations, &solution, None, &GateThresholds::default());
    let solve_ms = t_solve.elapsed().as_secs_f64() * 1e3;
    let model_from_camera = solution
        .model_from_camera(frames.first().and_then(|f| f.model_from_flange.as_ref()))
        .context("no camera pose")?;
    let report = CalibrationReport::new(
        &solution,
        &registrations,
        &sources,
        &verdict,
        &base_frame,
        &(base_from_model * model_from_camera),
        solve_ms,
        t0.elapsed().as_secs_f64() * 1e3,
    );
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print!("{}", report.summary());
    }
    Ok(if verdict.passed {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    })
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
            robot,
            joints: vec![joints.to_string()],
            scan: vec![scan],
            flange_pose: flange.into_iter().collect(),
            base_frame: Some("base".into()),
            guess_flange_from_camera: None,
            guess_base_from_camera: None,
            kinematic_error: None,
            max_camera_flange_distance: None,
            eye_to_hand: false,
            json: true,
        }
    }

    #[test]
    fn solve_command_on_a_simulated_scan_and_bad_inputs() {
        let Some(dir) = super::super::args::robots_dir() else {
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
            controller_dh: None,
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
        let t = base_from_flange.translation.vector;
        let r = base_from_flange.rotation.scaled_axis();
        let flange = format!("{},{},{},{},{},{}", t.x, t.y, t.z, r.x, r.y, r.z);
        let code = run(args(urdf.clone(), &joints, ply.clone(), Some(flange))).expect("runs");
        assert_eq!(code, ExitCode::SUCCESS);
        // Joint count mismatch and an unreadable scan are errors (exit 2 in main).
        let short = q[..5]
            .iter()
            .map(|v| format!("{v}"))
            .collect::<Vec<_>>()
            .join(",");
        let e = run(args(urdf.clone(), &short, ply.clone(), None)).expect_err("mismatch");
        assert!(format!("{e:#}").contains("joint"), "{e:#}");
        let e =
            run(args(urdf.clone(), &joints, tmp.join("missing.ply"), None)).expect_err("no scan");
        assert!(format!("{e:#}").contains("missing.ply"), "{e:#}");
        let _ = std::fs::remove_dir_all(&tmp);
    }
}
