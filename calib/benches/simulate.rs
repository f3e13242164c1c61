//! Scan-simulator speed: `cargo bench -p handeye-calib --bench simulate`.
//!
//! A UR5e seen from a wrist camera (a generated view), at 2448×2048 and 1280×960: exact ray
//! casting alone, and a whole simulated scan (ray casting + sensor model + cell). Needs
//! `../shared/robots`.
use std::hint::black_box;
use std::path::Path;

use criterion::{criterion_group, criterion_main, Criterion};
use handeye_calib::geometry::raycast::{raycast, SceneMesh};
use handeye_calib::model::{GeometryKind, RobotModel, TriMesh};
use handeye_calib::plan::{ViewConstraints, ViewPlanner};
use handeye_calib::sim::{simulate_scan, Intrinsics, Placement, ScanRequest, SimSettings};
use handeye_hal::nalgebra::{Isometry3, Vector3};

fn bench(c: &mut Criterion) {
    let urdf = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/robots/ur/ur5e/ur5e.urdf");
    let Ok(model) = RobotModel::load(&urdf) else {
        eprintln!("SKIP: {} not found", urdf.display());
        return;
    };
    let mount = Isometry3::new(
        Vector3::new(0.0, -0.08, 0.04),
        Vector3::new(-0.26, 0.0, 0.0),
    );
    for (name, intr) in [
        ("2448x2048", Intrinsics::zivid2_plus_m60()),
        ("1280x960", Intrinsics::compact_1280x960()),
    ] {
        let planner = ViewPlanner::new(&model, mount, intr, ViewConstraints::default());
        let q = planner.generate(1, 3).expect("a view").remove(0);
        let posed: Vec<TriMesh> = model
            .posed_geometry(&q, GeometryKind::Visual)
            .expect("fk")
            .iter()
            .map(|(t, g)| g.mesh.transformed(t))
            .collect();
        let meshes = SceneMesh::indexed(&posed);
        let camera_from_model = planner.model_from_camera(&q).expect("fk").inverse();
        c.bench_function(&format!("raycast_ur5e_{name}"), |b| {
            b.iter(|| black_box(raycast(&meshes, &camera_from_model, &intr)))
        });
        let placement = Placement::EyeInHand {
            flange_from_camera: mount,
        };
        let req = ScanRequest::new(
            &model,
            q.clone(),
            placement,
            intr,
            &SimSettings::default(),
            1,
        );
        c.bench_function(&format!("simulate_scan_ur5e_{name}"), |b| {
            b.iter(|| black_box(simulate_scan(&req).expect("simulates")))
        });
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(10);
    targets = bench
}
criterion_main!(benches);
