//! `handeye simulate-scan`: render a simulated 3D scan (PLY) and its ground truth (JSON).

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;
use nalgebra::Isometry3;

use handeye::cloud::{write_ply, write_png, PlyEncoding};
use handeye::frames::to_row_major;
use handeye::model::RobotModel;
use handeye::sim::{simulate_scan, Intrinsics, Placement, ScanRequest, SimSettings, SimulatedScan};
use handeye_hal::ur_dh::PhysicalArm;

use handeye_hal::UrPose;

use super::args::{
    check_joint_limits, check_mount, check_pose_distance, parse_joints, parse_pose, resolve_robot,
    JointList, MAX_CELL_CAMERA_DISTANCE_M,
};

/// Render a simulated scan of a robot seen by a 3D camera.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Robot: a URDF (meshes resolved relative to it) or a robot name (`ur5e`) under the
    /// robots directory.
    #[arg(long)]
    robot: PathBuf,
    /// Joint angles in radians, comma-separated, URDF chain order.
    #[arg(long, value_parser = parse_joints, allow_hyphen_values = true)]
    joints: JointList,
    /// Eye-in-hand: `flange_from_camera` as x,y,z,rx,ry,rz (metres, rotation vector).
    #[arg(long, value_parser = parse_pose, allow_hyphen_values = true, conflicts_with = "camera_pose")]
    mount: Option<Isometry3<f64>>,
    /// Eye-to-hand: `model_from_camera` (camera pose in the URDF root link) as x,y,z,rx,ry,rz.
    #[arg(long, value_parser = parse_pose, allow_hyphen_values = true)]
    camera_pose: Option<Isometry3<f64>>,
    /// Camera preset: `zivid2-m60` (2448×2048) or `compact` (1280×960), structured light;
    /// `realsense-d435` (1280×720), active stereo; `helios2` (640×480), time of flight (the
    /// preset's noise unless `--settings` gives one).
    #[arg(long, default_value = "zivid2-m60")]
    camera: String,
    /// TOML file with `[noise]`, `[cell]` and `[kinematic_error]` tables (see config/simulator.example.toml).
    #[arg(long)]
    settings: Option<PathBuf>,
    /// A perfect sensor in empty space: no noise, no cell, no kinematic error.
    #[arg(long)]
    ideal: bool,
    /// Seed for every random draw.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// UR arms: the true arm is a physical arm (every joint off by a factory-size error and
    /// every link's housing off its frame, drawn from this seed, as `sim robot
    /// --factory-calibration SEED` simulates it) and the
    /// controller reports its flange; the `[kinematic_error]` draw is not applied. The exact DH
    /// its controller publishes goes into the ground truth as `controller_dh`.
    #[arg(long, value_name = "SEED")]
    factory_calibration: Option<u64>,
    /// Output PLY (binary); the ground truth goes beside it as `<stem>.gt.json`, and a camera
    /// with a colour image (`realsense-d435`) writes it as `<stem>.png`, pixel for pixel (for
    /// `solve --image`).
    #[arg(long)]
    out: PathBuf,
}

pub(crate) fn run(args: Args) -> anyhow::Result<ExitCode> {
    let urdf = resolve_robot(&args.robot.to_string_lossy()).map_err(anyhow::Error::msg)?;
    let model = RobotModel::load(&urdf)?;
    let intrinsics = Intrinsics::preset_or_error(&args.camera).map_err(anyhow::Error::msg)?;
    if model.dof() == args.joints.0.len() {
        check_joint_limits("--joints", &model, &args.joints.0).map_err(anyhow::Error::msg)?;
    }
    let placement = match (args.mount, args.camera_pose) {
        (Some(flange_from_camera), None) => {
            check_mount("--mount", &flange_from_camera).map_err(anyhow::Error::msg)?;
            Placement::EyeInHand { flange_from_camera }
        }
        (None, Some(model_from_camera)) => {
            check_pose_distance(
                "--camera-pose",
                &model_from_camera,
                MAX_CELL_CAMERA_DISTANCE_M,
                "a camera in the robot's cell",
            )
            .map_err(anyhow::Error::msg)?;
            Placement::EyeToHand { model_from_camera }
        }
        _ => anyhow::bail!("give either --mount (eye-in-hand) or --camera-pose (eye-to-hand)"),
    };
    let settings = match (&args.settings, args.ideal) {
        (_, true) => SimSettings::ideal(),
        (Some(path), false) => SimSettings::load(path)?,
        (None, false) => SimSettings::for_camera(&args.camera),
    };
    let mut req = ScanRequest::new(
        &model,
        args.joints.0.clone(),
        placement,
        intrinsics,
        &settings,
        args.seed,
    );
    if let Some(seed) = args.factory_calibration {
        let ur = model.ur_model().with_context(|| {
            format!(
                "--factory-calibration needs a UR arm; `{}` is not one (its file or robot name \
                 must name the model, e.g. ur5e)",
                model.name()
            )
        })?;
        req = req.with_arm(PhysicalArm::factory(ur, seed));
    }
    let scan = simulate_scan(&req)?;
    write_ply(&args.out, &scan.cloud, PlyEncoding::BinaryLittleEndian)
        .with_context(|| format!("writing {}", args.out.display()))?;
    let gt_path = gt_path(&args.out);
    let gt = ground_truth_json(&model, &req, &scan, &settings);
    std::fs::write(&gt_path, serde_json::to_string_pretty(&gt)?)
        .with_context(|| format!("writing {}", gt_path.display()))?;
    let png_path = match &scan.image {
        Some(image) => {
            let path = args.out.with_extension("png");
            write_png(&path, image).with_context(|| format!("writing {}", path.display()))?;
            format!(" and its colour image {}", path.display())
        }
        None => String::new(),
    };
    let seen = base_in_view(&model, &scan);
    println!(
        "wrote {} ({}×{}, {} valid points; the robot's base and shoulder cover {:.1} % of the image){png_path} and {}",
        args.out.display(),
        scan.cloud.width,
        scan.cloud.height,
        scan.cloud.valid_count(),
        100.0 * seen,
        gt_path.display()
    );
    if seen < MIN_BASE_IN_VIEW {
        eprintln!(
            "warning: the robot's base and shoulder cover {:.2} % of the image (less than {} %): \
             `solve` registers the base and the first links and will not find the robot in this \
             scan; choose joints from which the camera looks at the base from 0.4–0.8 m",
            100.0 * seen,
            100.0 * MIN_BASE_IN_VIEW
        );
    }
    Ok(ExitCode::SUCCESS)
}

/// Below this fraction of the image showing the base and shoulder (measured points),
/// `simulate-scan` warns that the robot is not in view.
const MIN_BASE_IN_VIEW: f64 = 0.01;

/// Fraction of the image's pixels with a measured point on the robot's base or shoulder
/// (links at chain depth 0 or 1): what registration needs to see.
fn base_in_view(model: &RobotModel, scan: &SimulatedScan) -> f64 {
    let is_base: Vec<bool> = scan
        .objects
        .iter()
        .map(|o| {
            o.strip_prefix("link:")
                .and_then(|l| model.chain_depth(l))
                .is_some_and(|d| d <= 1)
        })
        .collect();
    let n = scan
        .labels
        .iter()
        .zip(&scan.cloud.points)
        .filter(|(l, p)| {
            is_base.get(**l as usize).copied().unwrap_or(false)
                && p.coords.iter().all(|c| c.is_finite())
        })
        .count();
    n as f64 / scan.labels.len().max(1) as f64
}

/// `scan.ply` → `scan.gt.json`.
pub(crate) fn gt_path(out: &Path) -> PathBuf {
    let stem = out
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "scan".into());
    out.with_file_name(format!("{stem}.gt.json"))
}

/// The ground-truth document written beside a simulated scan.
pub(crate) fn ground_truth_json(
    model: &RobotModel,
    req: &ScanRequest<'_>,
    scan: &SimulatedScan,
    settings: &SimSettings,
) -> serde_json::Value {
    let t = &scan.truth;
    let mut doc = serde_json::json!({
        "robot": model.name(),
        "urdf": model.urdf_path().display().to_string(),
        "base_frame": t.model_frame,
        "flange_frame": t.flange_frame,
        "units": "metres; 4x4 matrices row-major; <to>_from_<from>",
        "base_from_camera": to_row_major(&t.model_from_camera),
        "camera_from_base": to_row_major(&t.camera_from_model),
        "base_from_flange_reported": to_row_major(&t.model_from_flange_reported),
        "base_from_flange_nominal": to_row_major(&t.model_from_flange_nominal),
        // Where the flange really is: the joints are read with error (the camera hangs here).
        "base_from_flange_physical": to_row_major(&t.model_from_flange_physical),
        "physical_joints_rad": t.physical_joints,
        // The same as `solve --flange-pose` takes it (in `base_frame`, the URDF root).
        "flange_pose": UrPose::from(&t.model_from_flange_reported).to_string(),
        "flange_from_camera": t.flange_from_camera.as_ref().map(to_row_major),
        "joints_rad": t.joints,
        "intrinsics": req.intrinsics,
        "noise": settings.noise,
        "cell": settings.cell,
        // Not applied when the arm is posed by the controller's DH.
        "kinematic_error": t.controller_dh.is_none().then_some(settings.kinematic_error),
        "controller_dh": t.controller_dh,
        "joint_origin_errors": t.joint_origin_errors.iter().map(to_row_major).collect::<Vec<_>>(),
        "seed": req.seed,
    });
    if model.ur_model().is_some() {
        // UR poses are reported in the controller's `base` (base_link turned by π about z).
        if let Ok(model_from_base) = model.frame_pose("base", &t.joints) {
            doc["controller_base_frame"] = "base".into();
            doc["controller_base_from_camera"] = serde_json::json!(to_row_major(
                &(model_from_base.inverse() * t.model_from_camera)
            ));
            // What the controller reports: `solve --flange-pose … --base-frame base`.
            doc["controller_flange_pose"] =
                UrPose::from(&(model_from_base.inverse() * t.model_from_flange_reported))
                    .to_string()
                    .into();
        }
    }
    doc
}

#[cfg(test)]
mod tests {
    use clap::Parser as _;

    use super::*;

    #[derive(Debug, clap::Parser)]
    struct Cli {
        #[command(flatten)]
        args: Args,
    }

    fn parse(args: &[&str]) -> Args {
        Cli::try_parse_from(["simulate-scan"].iter().chain(args))
            .expect("parses")
            .args
    }

    #[test]
    fn factory_calibration_poses_the_arm_by_the_controllers_dh() {
        let Some(dir) = super::super::args::robots_dir_or_skip(
            "factory_calibration_poses_the_arm_by_the_controllers_dh",
        ) else {
            return;
        };
        let tmp = std::env::temp_dir().join(format!("handeye-simscan-{}", std::process::id()));
        std::fs::create_dir_all(&tmp).expect("temp dir");
        let out = tmp.join("scan.ply");
        let urdf = dir.join("ur/ur5e/ur5e.urdf");
        let model = RobotModel::load(&urdf).expect("ur5e loads");
        let mount = Isometry3::new(
            nalgebra::Vector3::new(0.0, -0.08, 0.03),
            nalgebra::Vector3::new(-0.26, 0.0, 0.0),
        );
        let planner = handeye::plan::ViewPlanner::new(
            &model,
            mount,
            Intrinsics::compact_1280x960(),
            handeye::plan::ViewConstraints::default(),
        );
        let q = planner.generate(1, 5).expect("a view").remove(0);
        let joints = q.iter().map(f64::to_string).collect::<Vec<_>>().join(",");
        let common = |urdf: &Path| {
            vec![
                "--robot".to_string(),
                urdf.display().to_string(),
                format!("--joints={joints}"),
                "--mount=0,-0.08,0.03,-0.26,0,0".into(),
                "--camera=compact".into(),
                "--ideal".into(),
                "--factory-calibration=3".into(),
                "--out".into(),
                out.display().to_string(),
            ]
        };
        let argv = common(&urdf);
        let argv: Vec<&str> = argv.iter().map(String::as_str).collect();
        assert_eq!(run(parse(&argv)).expect("runs"), ExitCode::SUCCESS);
        let gt: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(gt_path(&out)).expect("gt written"))
                .expect("json");
        let dh: handeye_hal::ur_dh::DhParams =
            serde_json::from_value(gt["controller_dh"].clone()).expect("dh");
        let want = PhysicalArm::factory(handeye_hal::ur_dh::UrModel::Ur5e, 3).controller_dh();
        // The JSON round trip keeps a value to its last bit or so (d of a kilometre).
        let close = |a: &[f64; 6], b: &[f64; 6]| {
            a.iter()
                .zip(b)
                .all(|(x, y)| (x - y).abs() <= 1e-14 * y.abs().max(1.0))
        };
        assert!(
            close(&dh.a, &want.a)
                && close(&dh.d, &want.d)
                && close(&dh.alpha, &want.alpha)
                && close(&dh.theta, &want.theta),
            "{dh:?} vs {want:?}"
        );
        let ply =
            handeye::cloud::read_ply(&std::fs::read(&out).expect("scan written")).expect("a PLY");
        assert!(ply.valid_count() > 10_000, "the robot is in view");
        assert!(gt["kinematic_error"].is_null(), "not applied: {gt}");
        let at = |key: &str| -> [f64; 3] {
            std::array::from_fn(|r| gt[key][r][3].as_f64().expect("number"))
        };
        let (reported, nominal) = (
            at("base_from_flange_reported"),
            at("base_from_flange_nominal"),
        );
        let off = (0..3)
            .map(|i| (reported[i] - nominal[i]).powi(2))
            .sum::<f64>()
            .sqrt();
        assert!(off > 1e-5 && off < 5e-3, "calibrated flange moved {off} m");

        // Not a UR arm: a clear error, nothing written.
        let franka = dir.join("franka_fr3/franka_fr3.urdf");
        if franka.is_file() {
            let argv = common(&franka);
            let mut argv: Vec<&str> = argv.iter().map(String::as_str).collect();
            argv[2] = "--joints=0,0,0,-1.5,0,1.5,0.7";
            let e = run(parse(&argv)).expect_err("not a UR arm");
            assert!(format!("{e:#}").contains("needs a UR arm"), "{e:#}");
        }
        let _ = std::fs::remove_dir_all(&tmp);
    }
}
