//! Synthetic data for the calibration unit tests: a UR-like robot built from cylinders and
//! boxes, and a ray-cast organized scan of it standing on a floor.

use std::f64::consts::PI;
use std::sync::Arc;

use handeye_hal::PointCloud;
use nalgebra::{Isometry3, Matrix6, Point3, Translation3, Unit, UnitQuaternion, Vector3};
use parry3d_f64::query::{Ray, RayCast};
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

use super::register::{Quality, Registration, StageTimings, Uncertainty};
use super::surface::{PosedJoint, PosedModel, PosedPart};
use crate::model::TriMesh;

/// Closed cylinder along z, radius `r`, from `z0` to `z1`.
pub(crate) fn cylinder(r: f64, z0: f64, z1: f64, segments: u32) -> TriMesh {
    let mut m = TriMesh::default();
    for i in 0..segments {
        let a = 2.0 * PI * i as f64 / segments as f64;
        m.vertices.push(Point3::new(r * a.cos(), r * a.sin(), z0));
        m.vertices.push(Point3::new(r * a.cos(), r * a.sin(), z1));
    }
    let bottom = m.vertices.len() as u32;
    m.vertices.push(Point3::new(0.0, 0.0, z0));
    m.vertices.push(Point3::new(0.0, 0.0, z1));
    for i in 0..segments {
        let j = (i + 1) % segments;
        let (b0, t0, b1, t1) = (2 * i, 2 * i + 1, 2 * j, 2 * j + 1);
        m.triangles.push([b0, b1, t1]);
        m.triangles.push([b0, t1, t0]);
        m.triangles.push([bottom, b1, b0]);
        m.triangles.push([bottom + 1, t0, t1]);
    }
    m
}

/// Axis-aligned box.
pub(crate) fn cuboid(lo: Point3<f64>, hi: Point3<f64>) -> TriMesh {
    let mut m = TriMesh::default();
    for i in 0..8 {
        m.vertices.push(Point3::new(
            if i & 1 == 0 { lo.x } else { hi.x },
            if i & 2 == 0 { lo.y } else { hi.y },
            if i & 4 == 0 { lo.z } else { hi.z },
        ));
    }
    let faces = [
        [0, 2, 6, 4],
        [1, 5, 7, 3],
        [0, 4, 5, 1],
        [2, 3, 7, 6],
        [0, 1, 3, 2],
        [4, 6, 7, 5],
    ];
    for f in faces {
        m.triangles.push([f[0], f[1], f[2]]);
        m.triangles.push([f[0], f[2], f[3]]);
    }
    m
}

fn merge(a: TriMesh, b: &TriMesh, b_pose: &Isometry3<f64>) -> TriMesh {
    let mut m = a;
    let off = m.vertices.len() as u32;
    m.vertices.extend(b.vertices.iter().map(|v| b_pose * v));
    m.triangles.extend(
        b.triangles
            .iter()
            .map(|t| [t[0] + off, t[1] + off, t[2] + off]),
    );
    m
}

/// A UR5e-sized arm: base cylinder, shoulder, upper arm, forearm, posed at `q` (3 joints used).
pub(crate) fn toy_robot(q: &[f64]) -> PosedModel {
    let base = cylinder(0.0755, 0.0, 0.099, 256);
    let shoulder_mesh = merge(
        cylinder(0.06, -0.065, 0.06, 40),
        &cylinder(0.06, 0.0, 0.13, 40),
        &Isometry3::rotation(Vector3::x() * (-PI / 2.0)),
    );
    let upper = merge(
        cylinder(0.06, -0.06, 0.06, 40),
        &cylinder(0.045, 0.0, 0.425, 32),
        &Isometry3::rotation(Vector3::y() * (PI / 2.0)),
    );
    let fore = cuboid(
        Point3::new(0.0, -0.035, -0.035),
        Point3::new(0.39, 0.035, 0.035),
    );
    let model_from_shoulder = Isometry3::from_parts(
        Translation3::new(0.0, 0.0, 0.1625),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), q[0]),
    );
    let model_from_upper = model_from_shoulder
        * Isometry3::from_parts(
            Translation3::new(0.0, 0.138, 0.0),
            UnitQuaternion::from_axis_angle(&Vector3::y_axis(), q[1]),
        );
    let model_from_fore = model_from_upper
        * Isometry3::from_parts(
            Translation3::new(0.425, -0.131, 0.0),
            UnitQuaternion::from_axis_angle(&Vector3::y_axis(), q[2]),
        );
    let part = |link: &str, d, pose, mesh| PosedPart {
        link: link.into(),
        chain_depth: d,
        model_from_link: pose,
        mesh: Arc::new(mesh),
    };
    // Each joint's frame before its motion: the link's pose with the joint at zero; its
    // origin in the parent is the step from the parent's pose.
    let joint =
        |parent: Isometry3<f64>, pose: Isometry3<f64>, axis: Unit<Vector3<f64>>, angle: f64| {
            let model_from_joint = pose * Isometry3::rotation(axis.into_inner() * -angle);
            PosedJoint {
                model_from_joint,
                axis,
                parent_from_joint: parent.inverse() * model_from_joint,
            }
        };
    PosedModel {
        parts: vec![
            part("base", 0, Isometry3::identity(), base),
            part("shoulder", 1, model_from_shoulder, shoulder_mesh),
            part("upper_arm", 2, model_from_upper, upper),
            part("forearm", 3, model_from_fore, fore),
        ],
        joints: vec![
            joint(
                Isometry3::identity(),
                model_from_shoulder,
                Vector3::z_axis(),
                q[0],
            ),
            joint(
                model_from_shoulder,
                model_from_upper,
                Vector3::y_axis(),
                q[1],
            ),
            joint(model_from_upper, model_from_fore, Vector3::y_axis(), q[2]),
        ],
        model_from_flange: None,
        link_axes: None,
        chain_link_frames: vec![
            Isometry3::identity(),
            model_from_shoulder,
            model_from_upper,
            model_from_fore,
        ],
    }
}

/// Only the base cylinder (rotation about its axis is unobservable).
pub(crate) fn base_only() -> PosedModel {
    let mut m = toy_robot(&[0.0, 0.0, 0.0]);
    m.parts.truncate(1);
    m
}

/// `camera_from_model` for a camera at `eye` (model frame) looking at `target`.
pub(crate) fn look_at(eye: Point3<f64>, target: Point3<f64>) -> Isometry3<f64> {
    let z = (target - eye).normalize();
    let up = if z.cross(&Vector3::z()).norm() < 1e-3 {
        Vector3::x()
    } else {
        Vector3::z()
    };
    let x = z.cross(&(-up)).normalize();
    let y = z.cross(&x);
    let rot = nalgebra::Rotation3::from_basis_unchecked(&[x, y, z]);
    let model_from_camera = Isometry3::from_parts(
        Translation3::from(eye.coords),
        UnitQuaternion::from_rotation_matrix(&rot),
    );
    model_from_camera.inverse()
}

/// Scene options for [`render`].
#[derive(Debug, Clone)]
pub(crate) struct Scene {
    pub(crate) width: u32,
    pub(crate) height: u32,
    pub(crate) f: f64,
    pub(crate) floor: bool,
    pub(crate) noise_m: f64,
    pub(crate) seed: u64,
}

impl Default for Scene {
    fn default() -> Self {
        Scene {
            width: 320,
            height: 240,
            f: 260.0,
            floor: true,
            noise_m: 0.0003,
            seed: 1,
        }
    }
}

/// Ray-casts an organized scan (camera frame) of `model` (+ floor at z = 0) seen from
/// `camera_from_model`.
pub(crate) fn render(
    model: &PosedModel,
    camera_from_model: &Isometry3<f64>,
    s: &Scene,
) -> PointCloud {
    let meshes: Vec<parry3d_f64::shape::TriMesh> = model
        .parts
        .iter()
        .map(|p| {
            let v = p
                .mesh
                .vertices
                .iter()
                .map(|v| p.model_from_link * v)
                .collect();
            parry3d_f64::shape::TriMesh::new(v, p.mesh.triangles.clone()).expect("valid mesh")
        })
        .collect();
    let model_from_camera = camera_from_model.inverse();
    let mut rng = rand::rngs::StdRng::seed_from_u64(s.seed);
    let noise = Normal::new(0.0, s.noise_m.max(1e-12)).expect("sigma");
    let (cx, cy) = (s.width as f64 / 2.0 - 0.5, s.height as f64 / 2.0 - 0.5);
    let mut points = Vec::with_capacity((s.width * s.height) as usize);
    for v in 0..s.height {
        for u in 0..s.width {
            let d_cam = Vector3::new((u as f64 - cx) / s.f, (v as f64 - cy) / s.f, 1.0);
            let ray = Ray::new(
                model_from_camera * Point3::origin(),
                model_from_camera * d_cam,
            );
            let mut best = f64::INFINITY;
            for m in &meshes {
                if let Some(t) = m.cast_local_ray(&ray, 10.0, false) {
                    best = best.min(t);
                }
            }
            if s.floor && ray.dir.z < 0.0 {
                let t = -ray.origin.z / ray.dir.z;
                if t > 0.0 && t < 3.0 {
                    best = best.min(t);
                }
            }
            if best.is_finite() {
                let z = best + noise.sample(&mut rng);
                points.push((d_cam * z).map(|c| c as f32).into());
            } else {
                points.push(Point3::new(f32::NAN, f32::NAN, f32::NAN));
            }
        }
    }
    PointCloud {
        width: s.width,
        height: s.height,
        points,
        intensity: None,
        confidence: None,
    }
}

/// A registration every gate threshold passes (0.6 m from the base, σ 0.2 mm / 0.02°).
pub(crate) fn good_registration() -> Registration {
    Registration {
        camera_from_model: Isometry3::new(Vector3::new(0.0, 0.0, 0.6), Vector3::new(3.0, 0.0, 0.0)),
        covariance_6x6: Matrix6::identity() * 1e-8,
        uncertainty: Uncertainty {
            translation_mm: 0.2,
            rotation_deg: 0.02,
            workspace: None,
        },
        camera_error: Uncertainty::default(),
        camera_error_columns: nalgebra::Matrix6x4::zeros(),
        quality: Quality {
            noise_mm: None,
            coverage: 0.9,
            free_space_violations: 0.01,
            rmse_mm: 0.3,
            inlier_fraction: 0.9,
            points_used: 5000,
            visible_samples: 20000,
            hypotheses: 3,
            from_prior: false,
            ambiguity: 0.2,
            link_support: [Some(0.95), Some(0.9), Some(0.85)],
        },
        degenerate_directions: vec![],
        depth_scale: Some(1.001),
        depth_offset_m: Some(0.001),
        timings_ms: StageTimings::default(),
        link_fit: None,
        flange_error: None,
    }
}

/// A fixed camera's bench draw for the robot at `relative` under `../shared/robots`: the
/// eye-to-hand bench configuration with `views` views of one scan each, drawn from `seed`, and
/// its plan (camera pose, arm configurations, scan seeds); `None` without the robots.
pub(crate) fn eye_to_hand_plan(
    relative: &str,
    views: usize,
    seed: u64,
) -> Option<(
    Arc<crate::model::RobotModel>,
    crate::bench::BenchConfig,
    crate::bench::TrialPlan,
)> {
    let model = crate::testutil::shared_robot(relative)?;
    let cfg = crate::bench::BenchConfig {
        views,
        scans_per_view: 1,
        seed,
        ..crate::bench::BenchConfig::new(super::Mount::EyeToHand)
    };
    let plan = crate::bench::plan_trials(&model, &cfg).expect("views");
    Some((model, cfg, plan))
}
