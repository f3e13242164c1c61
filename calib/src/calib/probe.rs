//! Diagnostics of single benchmark trials (ignored tests, run by hand):
//! `PROBE_ROBOTS=ur3e,ur5e PROBE_VIEWS=10 PROBE_SPV=2 PROBE_ONLY=ur3e:5:0 PROBE_SEED=1 RUST_LOG=handeye=debug
//! cargo test --release -p handeye-calib --lib calib::probe -- --ignored --nocapture` replays the trials of
//! `handeye bench` (same seeds) and prints each contender against the truth.

use std::path::PathBuf;

use crate::bench::{plan_trials, run_trial, BenchConfig};
use crate::model::RobotModel;
use crate::sim::Intrinsics;

fn env(name: &str, default: &str) -> String {
    std::env::var(name).unwrap_or_else(|_| default.to_string())
}

#[test]
#[ignore = "diagnostics, run by hand"]
fn probe_bench_trials() {
    let _ = tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::from_default_env())
        .with_test_writer()
        .try_init();
    let Some(root) = crate::testutil::shared_robots() else {
        return;
    };
    let robots = env("PROBE_ROBOTS", "ur3e,ur5e,ur10e,ur16e,ur20,ur30");
    let views: usize = env("PROBE_VIEWS", "10").parse().expect("PROBE_VIEWS");
    let spv: usize = env("PROBE_SPV", "2").parse().expect("PROBE_SPV");
    let only = env("PROBE_ONLY", "");
    let camera = env("PROBE_CAMERA", "compact");
    let paths = crate::model::find_urdfs(&root);
    let chosen: Vec<PathBuf> = if robots == "all" {
        paths
    } else {
        robots
            .split(',')
            .filter_map(|name| {
                paths
                    .iter()
                    .find(|p| p.file_stem().and_then(|s| s.to_str()) == Some(name))
                    .cloned()
            })
            .collect()
    };
    for (i, path) in chosen.iter().enumerate() {
        let model = RobotModel::load(path).expect("loads");
        let name = model.name().to_string();
        if !only.is_empty() && !only.split(',').any(|o| o.starts_with(&format!("{name}:"))) {
            continue;
        }
        // The camera's noise and the registration tuned for its class, as `handeye bench`.
        let cfg = BenchConfig {
            views,
            scans_per_view: spv,
            intrinsics: Intrinsics::preset(&camera).expect("camera"),
            settings: crate::sim::SimSettings::for_camera(&camera),
            seed: env("PROBE_SEED", "1")
                .parse::<u64>()
                .expect("PROBE_SEED")
                .wrapping_add(i as u64 * 7919),
            ..BenchConfig::default()
        }
        .tuned_for_camera(&camera);
        let plan = plan_trials(&model, &cfg).expect("views");
        let mount = plan.mount;
        for (v, (q, seeds)) in plan.views.iter().zip(&plan.scan_seeds).enumerate() {
            for (s, &seed) in seeds.iter().enumerate() {
                let key = format!("{name}:{v}:{s}");
                if !only.is_empty() && !only.split(',').any(|o| o == key) {
                    continue;
                }
                eprintln!(
                    "=== {key} mount (translation, rotation vector) ({:?}, {:?})\n q {q:?} seed {seed}",
                    mount.translation.vector.as_slice(),
                    mount.rotation.scaled_axis().as_slice()
                );
                let mut req = cfg.scan_request(&model, q, mount, seed);
                if let Some(arm) = cfg.true_arm(&model, seeds[0]) {
                    req = req.with_arm(arm);
                }
                let sim = crate::sim::simulate_scan(&req).expect("sim");
                let mut seen = std::collections::BTreeMap::<&str, usize>::new();
                for (l, p) in sim.labels.iter().zip(&sim.cloud.points) {
                    if let (Some(name), true) = (sim.objects.get(*l as usize), p.z.is_finite()) {
                        *seen.entry(name.as_str()).or_default() += 1;
                    }
                }
                eprintln!("=== {key} scan points per object: {seen:?}");
                let truth = sim.truth;
                super::register::PROBE_TRUTH.with(|c| c.set(Some(truth.camera_from_model)));
                let up = truth.camera_from_model.rotation * nalgebra::Vector3::z();
                eprintln!(
                    "=== {key} truth mounting plane: normal {:?} offset {:.3} m",
                    up.as_slice(),
                    -up.dot(&truth.camera_from_model.translation.vector)
                );
                if std::env::var_os("PROBE_PRIOR").is_some() {
                    // The prior path: the truth off by 1 cm and 1°, as a last calibration is.
                    let prior = nalgebra::Isometry3::new(
                        nalgebra::Vector3::new(0.006, -0.005, 0.006),
                        nalgebra::Vector3::new(0.01, -0.01, 0.01),
                    ) * truth.camera_from_model;
                    let scan = crate::sim::simulate_scan(&req).expect("sim").cloud;
                    let r = super::register(&scan, &model, q, Some(prior), &cfg.register);
                    eprintln!(
                        "=== {key} prior: {:?}",
                        r.map(|r| (r.quality.from_prior, r.timings_ms.total, probe_err(&r)))
                    );
                }
                let t = run_trial(
                    &model,
                    mount,
                    q,
                    cfg.true_arm(&model, seeds[0]),
                    &cfg,
                    seed,
                    v,
                    s,
                );
                eprintln!(
                    "=== {key}: {} {:.3} mm {:.4}° reg {:.0} ms (coarse {:.0} fine {:.0}) {:?}",
                    t.outcome,
                    t.translation_error_mm,
                    t.rotation_error_deg,
                    t.register_ms,
                    t.coarse_ms,
                    t.fine_ms,
                    t.reasons
                );
            }
        }
    }
}

fn probe_err(r: &super::Registration) -> String {
    let t = super::register::PROBE_TRUTH.with(|c| c.get());
    t.map(|t| {
        let a = r.camera_from_model;
        let mm = (a.inverse().translation.vector - t.inverse().translation.vector).norm() * 1e3;
        format!(
            "{mm:.2}mm/{:.3}deg",
            (a.inverse() * t).rotation.angle().to_degrees()
        )
    })
    .unwrap_or_default()
}
