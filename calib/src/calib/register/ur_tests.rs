use super::*;
use crate::calib::testutil::{look_at, render, Scene};
use crate::testutil::shared_robots;
use nalgebra::Point3;

/// Real UR5e meshes, ray-cast with the test renderer (floor, light noise), no prior.
#[test]
#[ignore = "slow in debug; run with --release -- --ignored"]
fn ur5e_real_meshes_without_prior() {
    let Some(root) = shared_robots() else { return };
    let model = RobotModel::load(&root.join("ur/ur5e/ur5e.urdf")).expect("ur5e loads");
    for (k, (q, eye)) in [
        (
            [0.3, -1.2, 1.4, -1.8, -1.5, 0.0],
            Point3::new(0.35, 0.35, 0.6),
        ),
        (
            [-2.0, -1.9, 1.9, -1.6, -1.6, 0.3],
            Point3::new(-0.5, 0.2, 0.55),
        ),
        (
            [1.2, -2.2, 2.0, -1.0, -1.5, 0.0],
            Point3::new(0.1, -0.55, 0.5),
        ),
    ]
    .iter()
    .enumerate()
    {
        let posed = posed_model(&model, q).expect("posed");
        let truth = look_at(*eye, Point3::new(0.0, 0.0, 0.12));
        let scene = Scene {
            width: 640,
            height: 480,
            f: 560.0,
            seed: k as u64,
            ..Scene::default()
        };
        let scan = render(&posed, &truth, &scene);
        let reg = register_posed(&scan, &posed, None, &RegisterOptions::default()).expect("found");
        let d = reg.camera_from_model.inverse() * truth;
        let t_mm = (reg.camera_from_model.inverse().translation.vector
            - truth.inverse().translation.vector)
            .norm()
            * 1000.0;
        eprintln!(
            "view {k}: {t_mm:.3} mm {:.4} deg  {:?} {:?} scale {:?} degenerate {}",
            d.rotation.angle().to_degrees(),
            reg.quality,
            reg.timings_ms,
            reg.depth_scale,
            reg.degenerate_directions.len()
        );
        assert!(t_mm < 1.0 && d.rotation.angle().to_degrees() < 0.2);
    }
}
