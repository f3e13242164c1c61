//! Time of flight end to end: the trials `handeye bench --camera helios2` once accepted wrong.

use crate::bench::{plan_trials, run_trial, BenchConfig, BenchKinematics};
use crate::calib::Outcome;
use crate::model::RobotModel;
use crate::sim::{Intrinsics, SimSettings};

/// Replays view `view` of `urdf` (under `../shared/robots`) as `handeye bench --camera helios2
/// --views 10 --seed SEED` draws it, and checks each of its three scans: rejected, or right and
/// within `max_sigmas` of its σ.
fn replay_view(urdf: &str, seed: u64, kinematics: BenchKinematics, view: usize, max_sigmas: f64) {
    let Some(root) = crate::testutil::shared_robots() else {
        return;
    };
    let model = RobotModel::load(&root.join(urdf)).expect("the robot loads");
    let cfg = BenchConfig {
        views: 10,
        scans_per_view: 3,
        intrinsics: Intrinsics::preset("helios2").expect("helios2"),
        settings: SimSettings::for_camera("helios2"),
        seed,
        kinematics,
        ..BenchConfig::default()
    }
    .tuned_for_camera("helios2");
    let plan = plan_trials(&model, &cfg).expect("views");
    let (q, seeds) = (&plan.views[view], &plan.scan_seeds[view]);
    for (s, &scan_seed) in seeds.iter().enumerate() {
        let t = run_trial(
            &model,
            plan.mount,
            q,
            cfg.true_arm(&model, seeds[0]),
            &cfg,
            scan_seed,
            view,
            s,
        );
        eprintln!(
            "scan {s}: {} {:.2} mm {:.3}° σ {:.2} mm {:.3}° {:?}",
            t.outcome,
            t.translation_error_mm,
            t.rotation_error_deg,
            t.uncertainty_translation_mm,
            t.uncertainty_rotation_deg,
            t.reasons
        );
        if t.outcome == Outcome::Accepted {
            assert!(!t.is_wrong(), "scan {s} accepted wrong: {t:?}");
            assert!(
                t.translation_error_mm < max_sigmas * t.uncertainty_translation_mm,
                "scan {s}: {} mm with σ {} mm",
                t.translation_error_mm,
                t.uncertainty_translation_mm
            );
        }
    }
}

/// Issue 45: `handeye bench --camera helios2 --kinematics unknown` accepted UR3 view 8 (its
/// views drawn from seed 47515, `--robots ur3 --seed 47515 --views 10` replays them) 3.6 and
/// 4.5 mm / 0.6–0.7° off with σ 0.8–0.9 mm: the simulator pushed the shoulder's small concave
/// fillets 1.1 mm long (8 mm times the share of facing neighbours, whatever the bounce's path),
/// which neither the model's corners nor any evidence covered. With multipath grown from the
/// bounce's extra path and the scan's own concave geometry left out, its three scans are
/// rejected or right within 2σ.
#[test]
fn issue_45_the_ur3_view_the_time_of_flight_bench_accepted_wrong_is_right_within_its_sigma() {
    replay_view("ur/ur3/ur3.urdf", 47515, BenchKinematics::Unknown, 8, 2.0);
}

/// Issue 45: `handeye bench --camera helios2 --kinematics known` accepted UR30 view 9 (its
/// views drawn from seed 39596, `--robots ur30 --seed 39596 --views 10` replays them), scan 0
/// 2.03 mm off with σ 0.91 mm (2.2σ), its other scans 1.13 and 0.87 mm: most of its error is
/// the view's (a far view, 1 900 points on the fitted links), the rest each scan's per-pixel
/// noise. With the noise grown by incidence as the amplitude falls (1/√cos, not 1/cos) its
/// three scans are right (under 2 mm), each within 2.5σ. Where the fit ends on one scan
/// depends on the candidate it starts from (the scan points near the model there are the ones
/// it fits): scan 0 ends 1.00 mm off (1.2σ) or 1.64 mm off (2.05σ, since the scans' noise is
/// measured over patches spreading beyond 2 cm, which moved it by 0.02 % and reordered the
/// candidates), scan 1 1.07 or 1.27 mm; a bound of 1.5σ held for one start, not for the view.
#[test]
fn issue_45_the_ur30_view_the_known_kinematics_bench_accepted_wrong_is_right_within_its_sigma() {
    replay_view("ur/ur30/ur30.urdf", 39596, BenchKinematics::Known, 9, 2.5);
}
