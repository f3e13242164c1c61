//! Diagnostics of single benchmark trials (ignored tests, run by hand):
//! `PROBE_ROBOTS=ur3e,ur5e PROBE_VIEWS=10 PROBE_SPV=2 PROBE_ONLY=ur3e:5:0 RUST_LOG=handeye=debug
//! cargo test --release --lib calib::probe -- --ignored --nocapture` replays the trials of
//! `handeye bench` (same seeds) and prints each contender against the truth.

use std::path::PathBuf;

use rand::{Rng, SeedableRng};

use crate::bench::{random_mount, run_trial, BenchConfig};
use crate::model::RobotModel;
use crate::plan::{ViewConstraints, ViewPlanner};
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
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/robots");
    let robots = env("PROBE_ROBOTS", "ur3e,ur5e,ur10e,ur16e,ur20,ur30");
    let views: usize = env("PROBE_VIEWS", "10").parse().expect("PROBE_VIEWS");
    let spv: usize = env("PROBE_SPV", "2").parse().expect("PROBE_SPV");
    let only = env("PROBE_ONLY", "");
    let camera = env("PROBE_CAMERA", "compact");
    let paths = crate::model::find_urdfs(&root);
    for (i, name) in robots.split(',').enumerate() {
        let Some(path) = paths
            .iter()
            .find(|p| p.file_stem().and_then(|s| s.to_str()) == Some(name))
        else {
            eprintln!("{name}: not found");
            continue;
        };
        let model = RobotModel::load(path).expect("loads");
        let cfg = BenchConfig {
            views,
            scans_per_view: spv,
            intrinsics: Intrinsics::preset(&camera).expect("camera"),
            seed: 1u64.wrapping_add(i as u64 * 7919),
            ..BenchConfig::default()
        };
        let mut rng = rand::rngs::StdRng::seed_from_u64(cfg.seed);
        let mount = random_mount(&mut rng);
        let planner = ViewPlanner::new(&model, mount, cfg.intrinsics, ViewConstraints::default());
        let qs = planner.generate(cfg.views, rng.random()).expect("views");
        for (v, q) in qs.iter().enumerate() {
            for s in 0..spv {
                let seed: u64 = rng.random();
                let key = format!("{name}:{v}:{s}");
                if !only.is_empty() && !only.split(',').any(|o| o == key) {
                    continue;
                }
                eprintln!("=== {key} mount {mount:?}\n q {q:?} seed {seed}");
                let req = crate::sim::ScanRequest::new(
                    &model,
                    q.clone(),
                    crate::sim::Placement::EyeInHand {
                        flange_from_camera: mount,
                    },
                    cfg.intrinsics,
                    &cfg.settings,
                    seed,
                );
                let truth = crate::sim::simulate_scan(&req).expect("sim").truth;
                super::register::PROBE_TRUTH.with(|c| c.set(Some(truth.camera_from_model)));
                let t = run_trial(&model, mount, q, &cfg, seed, v, s);
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
