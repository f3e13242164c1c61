//! `handeye simulate-scan`: render a simulated 3D scan (PLY) and its ground truth (JSON).

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;
use nalgebra::Isometry3;

use handeye::cloud::{write_ply, PlyEncoding};
use handeye::frames::to_row_major;
use handeye::model::RobotModel;
use handeye::sim::{simulate_scan, Intrinsics, Placement, ScanRequest, SimSettings, SimulatedScan};

use super::args::{parse_joints, parse_pose, JointList};

/// Render a simulated scan of a robot seen by a 3D camera.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Robot URDF (meshes resolved relative to it).
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
    /// Camera preset: `zivid2-m60` (2448×2048) or `compact` (1280×960).
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
    /// Output PLY (binary); the ground truth goes beside it as `<stem>.gt.json`.
    #[arg(long)]
    out: PathBuf,
}

pub(crate) fn run(args: Args) -> anyhow::Result<ExitCode> {
    let model = RobotModel::load(&args.robot)?;
    let intrinsics = Intrinsics::preset(&args.camera).with_context(|| {
        format!(
            "unknown camera preset `{}`; use zivid2-m60 or compact",
            args.camera
        )
    })?;
    let placement = match (args.mount, args.camera_pose) {
        (Some(flange_from_camera), None) => Placement::EyeInHand { flange_from_camera },
        (None, Some(model_from_camera)) => Placement::EyeToHand { model_from_camera },
        _ => anyhow::bail!("give either --mount (eye-in-hand) or --camera-pose (eye-to-hand)"),
    };
    let settings = match (&args.settings, args.ideal) {
        (_, true) => SimSettings::ideal(),
        (Some(path), false) => SimSettings::load(path)?,
        (None, false) => SimSettings::default(),
    };
    let req = ScanRequest::new(
        &model,
        args.joints.0.clone(),
        placement,
        intrinsics,
        &settings,
        args.seed,
    );
    let scan = simulate_scan(&req)?;
    write_ply(&args.out, &scan.cloud, PlyEncoding::BinaryLittleEndian)
        .with_context(|| format!("writing {}", args.out.display()))?;
    let gt_path = gt_path(&args.out);
    let gt = ground_truth_json(&model, &req, &scan, &settings);
    std::fs::write(&gt_path, serde_json::to_string_pretty(&gt)?)
        .with_context(|| format!("writing {}", gt_path.display()))?;
    println!(
        "wrote {} ({}×{}, {} valid points) and {}",
        args.out.display(),
        scan.cloud.width,
        scan.cloud.height,
        scan.cloud.valid_count(),
        gt_path.display()
    );
    Ok(ExitCode::SUCCESS)
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
        "flange_from_camera": t.flange_from_camera.as_ref().map(to_row_major),
        "joints_rad": t.joints,
        "intrinsics": req.intrinsics,
        "noise": settings.noise,
        "cell": settings.cell,
        "kinematic_error": settings.kinematic_error,
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
        }
    }
    doc
}
