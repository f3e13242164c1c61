//! What the motion guard pays per move: `cargo bench -p handeye-calib --bench plan`.
//!
//! The guard (`handeye::guard::Cell::check_path`) builds a `ViewPlanner` for every move (the
//! convex hulls of the arm's collision meshes, the obstacles) and then checks the straight
//! joint-space path every 0.02 rad. This measures both on a UR5e with the camera mount of the
//! simulated rig and one obstacle box: the rebuild alone, and the check of a typical move
//! from the home pose to a generated view of the base. Needs `../shared/robots`.
use std::f64::consts::FRAC_PI_2;
use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use handeye_calib::plan::{Obstacle, ViewConstraints, ViewPlanner};
use handeye_calib::sim::Intrinsics;
use handeye_hal::nalgebra::{Isometry3, Vector3};

/// The guard's path step, rad (`handeye::guard::PATH_STEP_RAD`).
const PATH_STEP_RAD: f64 = 0.02;

fn bench(c: &mut Criterion) {
    let Some(model) = handeye_calib::testutil::shared_robot("ur/ur5e/ur5e.urdf") else {
        return;
    };
    let mount = Isometry3::new(
        Vector3::new(0.0, -0.08, 0.04),
        Vector3::new(-0.26, 0.0, 0.0),
    );
    let obstacles = vec![Obstacle {
        name: "fixture".into(),
        model_from_box: Isometry3::translation(0.6, 0.4, 0.1),
        half_extents_m: Vector3::new(0.1, 0.1, 0.1),
    }];
    let planner = || {
        ViewPlanner::new(
            &model,
            mount,
            Intrinsics::compact_1280x960(),
            ViewConstraints::default(),
        )
        .with_obstacles(obstacles.clone())
    };
    let home = [0.0, -FRAC_PI_2, FRAC_PI_2, -FRAC_PI_2, -FRAC_PI_2, 0.0];
    let built = planner();
    let view = (1..=12)
        .filter_map(|seed| built.generate(1, seed).ok()?.into_iter().next())
        .find(|q| matches!(built.check_path(&home, q, PATH_STEP_RAD), Ok(Ok(_))))
        .expect("a view reachable from home");
    c.bench_function("guard_planner_rebuild_ur5e", |b| {
        b.iter(|| black_box(planner()))
    });
    c.bench_function("guard_path_check_ur5e_home_to_view", |b| {
        b.iter(|| black_box(built.check_path(&home, &view, PATH_STEP_RAD)))
    });
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(10);
    targets = bench
}
criterion_main!(benches);
