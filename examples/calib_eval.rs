//! Accuracy and timing of registration + hand-eye closure on simulated scans (not the official
//! benchmark, which is `handeye bench`).
//!
//! `cargo run --release --example calib_eval -- [robot.urdf ...] [--preset compact|zivid]
//! [--views N] [--scans-per-view K]`
//! Robots default to ../shared/robots/ur/ur5e and ur10e. Eye-in-hand, no prior, default
//! (realistic) noise, cell and kinematic error.

use std::path::PathBuf;
use std::time::Instant;

use handeye::calib::{
    gate, posed_model_with_kinematics, register_posed, solve, FrameInput, GateThresholds, Mount,
    RegisterOptions, SolveOptions,
};
use handeye::model::RobotModel;
use handeye::plan::{ViewConstraints, ViewPlanner};
use handeye::sim::{
    simulate_scan, CellOptions, Intrinsics, KinematicError, Placement, ScanNoise, ScanRequest,
};
use nalgebra::{Isometry3, Vector3};

fn pct(v: &mut [f64], p: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(|a, b| a.total_cmp(b));
    v[((v.len() - 1) as f64 * p).round() as usize]
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut robots = Vec::new();
    let mut preset = "compact".to_string();
    let mut views = 10usize;
    let mut per_view = 1usize;
    let mut i = 0;
    while i < args.len() {
        match args[i].as_str() {
            "--preset" => {
                preset = args[i + 1].clone();
                i += 1;
            }
            "--views" => {
                views = args[i + 1].parse()?;
                i += 1;
            }
            "--scans-per-view" => {
                per_view = args[i + 1].parse()?;
                i += 1;
            }
            s => robots.push(PathBuf::from(s)),
        }
        i += 1;
    }
    if robots.is_empty() {
        let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/robots/ur");
        robots = vec![root.join("ur5e/ur5e.urdf"), root.join("ur10e/ur10e.urdf")];
    }
    let mut kin = KinematicError::default();
    let mut cell = CellOptions::default();
    let intrinsics = match preset.as_str() {
        "zivid" => Intrinsics::zivid2_plus_m60(),
        _ => Intrinsics::compact_1280x960(),
    };
    let mut opts = RegisterOptions::default();
    if let Ok(v) = std::env::var("FIT_DEPTH") {
        opts.fit_chain_depth = v.parse()?;
    }
    if std::env::var("NO_SCALE").is_ok() {
        opts.estimate_depth_scale = false;
    }
    if std::env::var("NO_KIN").is_ok() {
        kin = KinematicError::none();
    }
    if std::env::var("NO_CELL").is_ok() {
        cell = CellOptions::none();
        cell.floor = true;
    }
    let mount = Isometry3::new(
        Vector3::new(0.0, -0.08, 0.03),
        Vector3::new(-15f64.to_radians(), 0.0, 0.0),
    );
    for robot in &robots {
        let model = RobotModel::load(robot)?;
        let planner = ViewPlanner::new(&model, mount, intrinsics, ViewConstraints::default());
        let qs = planner.generate(views, 7)?;
        let (mut et, mut er, mut ht, mut hr) = (vec![], vec![], vec![], vec![]);
        let (mut tp, mut tc, mut tf, mut tv, mut tt) = (vec![], vec![], vec![], vec![], vec![]);
        let (mut ok, mut passed, mut wrong_accepted, mut total) = (0, 0, 0, 0);
        for (v, q) in qs.iter().enumerate() {
            for k in 0..per_view {
                total += 1;
                let req = ScanRequest {
                    model: &model,
                    joints: q.clone(),
                    placement: Placement::EyeInHand {
                        flange_from_camera: mount,
                    },
                    intrinsics,
                    noise: ScanNoise::default(),
                    cell,
                    kinematic_error: kin,
                    seed: 1000 * v as u64 + k as u64,
                };
                let t0 = Instant::now();
                let scan = simulate_scan(&req)?;
                let sim_ms = t0.elapsed().as_secs_f64() * 1e3;
                let truth = &scan.truth;
                // CALIBRATED=1: pose the model with the controller's calibration (the truth's
                // joint-origin errors), as a product reading the factory calibration would.
                let errs = std::env::var("CALIBRATED")
                    .is_ok()
                    .then_some(&truth.joint_origin_errors[..]);
                let posed = posed_model_with_kinematics(&model, q, errs)?;
                let reg = match register_posed(&scan.cloud, &posed, None, &opts) {
                    Ok(r) => r,
                    Err(e) => {
                        println!("view {v} scan {k}: registration failed: {e}");
                        continue;
                    }
                };
                ok += 1;
                let c_est = reg.camera_from_model.inverse();
                let c_true = truth.camera_from_model.inverse();
                let t_err = (c_est.translation.vector - c_true.translation.vector).norm() * 1e3;
                let r_err = c_est.rotation.angle_to(&c_true.rotation).to_degrees();
                let frame = FrameInput {
                    view: 0,
                    camera_from_model: reg.camera_from_model,
                    model_from_flange: Some(truth.model_from_flange_reported),
                };
                let sol = solve(Mount::EyeInHand, &[frame], &SolveOptions::default())?;
                let f_true = truth.flange_from_camera.unwrap_or(mount);
                let h_t =
                    (sol.estimate.translation.vector - f_true.translation.vector).norm() * 1e3;
                let h_r = sol
                    .estimate
                    .rotation
                    .angle_to(&f_true.rotation)
                    .to_degrees();
                let verdict = gate(
                    std::slice::from_ref(&reg),
                    &sol,
                    None,
                    &GateThresholds::default(),
                );
                if verdict.passed {
                    passed += 1;
                    if h_t > 2.0 || h_r > 0.5 {
                        wrong_accepted += 1;
                    }
                }
                println!(
                    "view {v} scan {k}: reg {t_err:.3} mm {r_err:.4}°  hand-eye {h_t:.3} mm {h_r:.4}°  cov {:.3} viol {:.4} rmse {:.3} unc {:.3} mm {:.4}° scale {:.5} (true {:.5}) {} | pre {:.0} coarse {:.0} fine {:.0} verify {:.0} total {:.0} ms (sim {sim_ms:.0}) {}",
                    reg.quality.coverage,
                    reg.quality.free_space_violations,
                    reg.quality.rmse_mm,
                    reg.uncertainty.translation_mm,
                    reg.uncertainty.rotation_deg,
                    reg.depth_scale.unwrap_or(1.0),
                    1.0 + ScanNoise::default().depth_scale_error,
                    if verdict.passed { "PASS" } else { "REJECT" },
                    reg.timings_ms.preprocess,
                    reg.timings_ms.coarse,
                    reg.timings_ms.fine,
                    reg.timings_ms.verify,
                    reg.timings_ms.total,
                    verdict.reasons.join("; ")
                );
                et.push(t_err);
                er.push(r_err);
                ht.push(h_t);
                hr.push(h_r);
                tp.push(reg.timings_ms.preprocess);
                tc.push(reg.timings_ms.coarse);
                tf.push(reg.timings_ms.fine);
                tv.push(reg.timings_ms.verify);
                tt.push(reg.timings_ms.total);
            }
        }
        println!(
            "\n{} {preset}: registered {ok}/{total}, gate passed {passed}, wrong accepted {wrong_accepted}",
            model.name()
        );
        println!(
            "  registration error: median {:.3} mm {:.4}°, p95 {:.3} mm {:.4}°, max {:.3} mm {:.4}°",
            pct(&mut et, 0.5), pct(&mut er, 0.5), pct(&mut et, 0.95), pct(&mut er, 0.95), pct(&mut et, 1.0), pct(&mut er, 1.0)
        );
        println!(
            "  hand-eye error:     median {:.3} mm {:.4}°, p95 {:.3} mm {:.4}°, max {:.3} mm {:.4}°",
            pct(&mut ht, 0.5), pct(&mut hr, 0.5), pct(&mut ht, 0.95), pct(&mut hr, 0.95), pct(&mut ht, 1.0), pct(&mut hr, 1.0)
        );
        println!(
            "  time median ms: preprocess {:.0}, coarse {:.0}, fine {:.0}, verify {:.0}, total {:.0} (p95 total {:.0})",
            pct(&mut tp, 0.5), pct(&mut tc, 0.5), pct(&mut tf, 0.5), pct(&mut tv, 0.5), pct(&mut tt, 0.5), pct(&mut tt, 0.95)
        );
    }
    Ok(())
}
