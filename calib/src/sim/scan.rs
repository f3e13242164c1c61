//! One simulated scan: the true robot (nominal model + kinematic error, or a physical UR arm
//! whose controller publishes its exact DH) posed at the given joints, its cell around it, seen by a pinhole
//! 3D camera with realistic imperfections.

use nalgebra::{Isometry3, Point3, Vector3};
use rand::{Rng, SeedableRng};
use rayon::prelude::*;

use handeye_hal::ur_dh::{DhParams, PhysicalArm};
use handeye_hal::PointCloud;

use super::albedo::{albedo_image, amplitude, Surface};
use super::cell::{build_cell, CellOptions, CellPart};
use super::colour::colour_image;
use super::SimSettings;
use super::{Intrinsics, ScanNoise};
use crate::geometry::raycast::{raycast, DepthImage, SceneMesh};
use crate::model::reading::{physical_joints, EncoderErrors};
use crate::model::{GeometryKind, KinematicError, ModelError, RobotModel, TriMesh};

/// Where the camera is.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Placement {
    /// Camera rigidly mounted on the flange (`flange_from_camera`; flange = the model's
    /// [`RobotModel::flange_link`], `tool0` for UR).
    EyeInHand {
        /// Pose of the camera in the flange frame.
        flange_from_camera: Isometry3<f64>,
    },
    /// Camera fixed in the cell (`model_from_camera`, model = URDF root link).
    EyeToHand {
        /// Pose of the camera in the model frame.
        model_from_camera: Isometry3<f64>,
    },
}

/// Everything that defines a simulated scan.
#[derive(Debug, Clone)]
pub struct ScanRequest<'a> {
    /// The nominal robot model.
    pub model: &'a RobotModel,
    /// Joint angles (radians, model chain order) the controller reports.
    pub joints: Vec<f64>,
    /// Where the camera is.
    pub placement: Placement,
    /// The camera.
    pub intrinsics: Intrinsics,
    /// Sensor imperfections.
    pub noise: ScanNoise,
    /// Surroundings (CAD mismatch, background).
    pub cell: CellOptions,
    /// Real arm vs nominal model: a random draw per scan. Not applied when `arm` is given (the
    /// draw is still made, so a seed's cell and sensor noise stay the same).
    pub kinematic_error: KinematicError,
    /// The true arm is this physical UR arm (see [`RobotModel::link_poses_of_arm`]) and the
    /// controller reports its flange and publishes its exact DH
    /// ([`PhysicalArm::controller_dh`]), as a factory-calibrated UR controller does; `None`:
    /// nominal model + `kinematic_error`. Only for UR arms (else [`simulate_scan`] fails with
    /// `ModelError::NotUrArm`).
    pub arm: Option<PhysicalArm>,
    /// Seed for every random draw; the same request gives the same scan.
    pub seed: u64,
}

impl<'a> ScanRequest<'a> {
    /// A request with every simulator knob taken from `settings`.
    pub fn new(
        model: &'a RobotModel,
        joints: Vec<f64>,
        placement: Placement,
        intrinsics: Intrinsics,
        settings: &SimSettings,
        seed: u64,
    ) -> Self {
        Self {
            model,
            joints,
            placement,
            intrinsics,
            noise: settings.noise,
            cell: settings.cell,
            kinematic_error: settings.kinematic_error,
            arm: None,
            seed,
        }
    }

    /// This request with the true arm a physical UR arm (see [`ScanRequest::arm`]).
    pub fn with_arm(self, arm: PhysicalArm) -> Self {
        Self {
            arm: Some(arm),
            ..self
        }
    }

    /// The camera pose this request puts in the model frame for an exactly nominal arm
    /// (eye-in-hand: nominal FK · mount).
    pub fn placement_model_from_camera(&self) -> Isometry3<f64> {
        match self.placement {
            Placement::EyeInHand { flange_from_camera } => self
                .model
                .frame_pose(self.model.flange_link(), &self.joints)
                .map(|f| f * flange_from_camera)
                .unwrap_or(flange_from_camera),
            Placement::EyeToHand { model_from_camera } => model_from_camera,
        }
    }
}

/// The truth behind a simulated scan. Frames: `model` = URDF root link, `flange` =
/// [`RobotModel::flange_link`], `camera` = optical frame (OpenCV axes).
#[derive(Debug, Clone, serde::Serialize)]
pub struct GroundTruth {
    /// Name of the model frame (URDF root link).
    pub model_frame: String,
    /// Name of the flange frame.
    pub flange_frame: String,
    /// True camera pose in the model frame.
    pub model_from_camera: Isometry3<f64>,
    /// Its inverse: what registration should find.
    pub camera_from_model: Isometry3<f64>,
    /// The flange pose the controller reports (its calibrated = true kinematics; with a
    /// physical arm, its published DH's forward kinematics in the model frame).
    pub model_from_flange_reported: Isometry3<f64>,
    /// The flange pose of the nominal model at the same joints.
    pub model_from_flange_nominal: Isometry3<f64>,
    /// Where the physical flange is: the arm's true kinematics at its physical joints (the
    /// joints read with error, see `physical_joints`); a wrist camera hangs off it.
    pub model_from_flange_physical: Isometry3<f64>,
    /// True camera mount (eye-in-hand only).
    pub flange_from_camera: Option<Isometry3<f64>>,
    /// Joint angles the controller reports, radians.
    pub joints: Vec<f64>,
    /// Where the physical arm's joints are, radians: the readings less their encoder error,
    /// plus the sag under gravity ([`crate::model::reading::physical_joints`]); the arm in
    /// the scan stands here.
    pub physical_joints: Vec<f64>,
    /// Per-joint origin errors of the true arm (URDF joint frames); empty for a physical UR
    /// arm (whose errors are in DH frames, `arm_joint_errors`).
    pub joint_origin_errors: Vec<Isometry3<f64>>,
    /// The exact DH set the controller of a physical UR arm publishes, if any.
    pub controller_dh: Option<DhParams>,
    /// A physical UR arm's joint errors (DH frame `k − 1`, [`PhysicalArm::joint_errors`]).
    pub arm_joint_errors: Option<[Isometry3<f64>; 6]>,
    /// Each link housing's offset from its link's frame, per chain depth (see
    /// [`RobotModel::with_housings`]): what the scan shows beyond the kinematics.
    pub housings: Vec<Isometry3<f64>>,
}

/// A simulated scan with its truth.
#[derive(Debug, Clone)]
pub struct SimulatedScan {
    /// Organized cloud, camera frame, metres; NaN where nothing was measured.
    pub cloud: PointCloud,
    /// The truth.
    pub truth: GroundTruth,
    /// Per pixel: index into `objects` of what the ray hit, or `u32::MAX`.
    pub labels: Vec<u32>,
    /// Names of the scene objects (`link:<name>` for robot links, else the cell part).
    pub objects: Vec<String>,
    /// The colour image registered to the cloud, for a camera that has one
    /// ([`ScanNoise::colour_image`]).
    pub image: Option<crate::cloud::ColorImage>,
}

/// Errors of the simulator.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SimError {
    /// The robot model refused the request (wrong joint count, …).
    #[error(transparent)]
    Model(#[from] ModelError),
    /// A noise or cell knob is out of range.
    #[error("invalid simulator setting: {0}")]
    Setting(String),
}

/// Mixed into a scan's seed for its colour image's misalignment and noise.
const COLOUR_SEED: u64 = 0x434f_4c4f_5552;

/// Renders one scan.
pub fn simulate_scan(req: &ScanRequest<'_>) -> Result<SimulatedScan, SimError> {
    req.noise.validate().map_err(SimError::Setting)?;
    req.cell.validate().map_err(SimError::Setting)?;
    req.kinematic_error.validate().map_err(SimError::Setting)?;
    let model = req.model;
    let mut rng = rand::rngs::StdRng::seed_from_u64(req.seed);
    // Drawn even when unused, so the rest of the scan's draws do not depend on `controller_dh`.
    let errors = req.kinematic_error.sample(model, &mut rng);
    // The housings' own stream: the rest of the scan is drawn as without them.
    let mut housing_rng =
        rand::rngs::StdRng::seed_from_u64(req.seed ^ handeye_hal::ur_dh::HOUSING_SEED);
    // The joints read with error: the arm stands at its physical joints, the controller
    // reports the flange of the joints it reads. The encoders are the arm's (the same error at
    // the same angle in every scan of it).
    let reading_seed = req
        .arm
        .as_ref()
        .map_or_else(|| name_seed(model.name()), arm_seed);
    let encoders = EncoderErrors::draw(
        model.dof(),
        req.kinematic_error.joint_reading_sigma_rad,
        reading_seed,
    );
    let physical = physical_joints(
        model,
        &req.joints,
        &encoders,
        req.kinematic_error.deflection_rad,
    );
    let (true_poses, reported_poses, errors, housings) = match &req.arm {
        Some(arm) => (
            model.link_poses_of_arm(&physical, arm)?,
            model.link_poses_of_arm(&req.joints, arm)?,
            Vec::new(),
            arm.housings.to_vec(),
        ),
        None => (
            model.link_poses_with_errors(&physical, &errors)?,
            model.link_poses_with_errors(&req.joints, &errors)?,
            errors,
            req.kinematic_error.sample_housings(model, &mut housing_rng),
        ),
    };
    let housing_poses = model.with_housings(&true_poses, &housings);
    let flange_index = model
        .link_names()
        .iter()
        .position(|l| l == model.flange_link())
        .ok_or_else(|| {
            SimError::Setting(format!("flange link {} not found", model.flange_link()))
        })?;
    let model_from_flange_reported = reported_poses[flange_index];
    let model_from_flange_nominal = model.frame_pose(model.flange_link(), &req.joints)?;
    let (model_from_camera, flange_from_camera) = match req.placement {
        Placement::EyeInHand { flange_from_camera } => (
            true_poses[flange_index] * flange_from_camera,
            Some(flange_from_camera),
        ),
        Placement::EyeToHand { model_from_camera } => (model_from_camera, None),
    };

    // Posed scene: robot visual meshes (true kinematics) and the cell.
    let mut objects = Vec::new();
    let mut surfaces = Vec::new();
    let mut posed: Vec<TriMesh> = Vec::new();
    for g in model.geometry(GeometryKind::Visual) {
        let Some(i) = model.link_names().iter().position(|l| *l == g.link) else {
            continue;
        };
        posed.push(g.mesh.transformed(&housing_poses[i]));
        objects.push(format!("link:{}", g.link));
        surfaces.push(Surface::Link(housing_poses[i].rotation));
    }
    let base_radius = base_radius(model);
    for (part, mesh) in build_cell(&req.cell, base_radius, &mut rng) {
        objects.push(cell_part_name(part).to_string());
        surfaces.push(Surface::Cell(part));
        posed.push(mesh);
    }
    let meshes = SceneMesh::indexed(&posed);
    let camera_from_model = model_from_camera.inverse();
    let image = raycast(&meshes, &camera_from_model, &req.intrinsics);
    let albedo = if req.noise.reference_albedo > 0.0 {
        albedo_image(&image, &surfaces, &model_from_camera.rotation)
    } else {
        Vec::new()
    };
    let noise = req.noise.drifted(req.seed);
    let cloud = measure(&image, &req.intrinsics, &noise, &albedo, rng.random());
    // Its own stream: the depth is drawn as without it.
    let colour = req.noise.colour_image.then(|| {
        colour_image(
            &image,
            &surfaces,
            &model_from_camera.rotation,
            req.noise.colour_misalignment_px,
            req.seed ^ COLOUR_SEED,
        )
    });

    Ok(SimulatedScan {
        cloud,
        image: colour,
        labels: image.object,
        objects,
        truth: GroundTruth {
            model_frame: model.root_link().to_string(),
            flange_frame: model.flange_link().to_string(),
            model_from_camera,
            camera_from_model,
            model_from_flange_reported,
            model_from_flange_nominal,
            model_from_flange_physical: true_poses[flange_index],
            flange_from_camera,
            joints: req.joints.clone(),
            physical_joints: physical,
            joint_origin_errors: errors,
            controller_dh: req.arm.as_ref().map(PhysicalArm::controller_dh),
            arm_joint_errors: req.arm.map(|a| a.joint_errors),
            housings,
        },
    })
}

/// A stable seed for a physical arm's own random draws (its encoders): from its joint errors,
/// so that every simulator that builds the same arm draws the same encoders.
fn arm_seed(arm: &PhysicalArm) -> u64 {
    fnv1a(
        arm.joint_errors
            .iter()
            .flat_map(|e| e.translation.vector.iter().chain(e.rotation.coords.iter()))
            .map(|v| v.to_bits()),
    )
}

/// A stable seed from a model's name: the encoders of an arm simulated without a physical
/// arm's draw are the same in every scan of that model.
fn name_seed(name: &str) -> u64 {
    fnv1a(name.bytes().map(u64::from))
}

/// FNV-1a over `words`.
fn fnv1a(words: impl IntoIterator<Item = u64>) -> u64 {
    words.into_iter().fold(0xcbf2_9ce4_8422_2325_u64, |h, w| {
        (h ^ w).wrapping_mul(0x0100_0000_01b3)
    })
}

fn cell_part_name(p: CellPart) -> &'static str {
    match p {
        CellPart::Floor => "floor",
        CellPart::Plate => "mounting_plate",
        CellPart::BaseBolts => "base_bolts",
        CellPart::Cable => "cable",
        CellPart::Clutter => "clutter",
    }
}

/// Outer radius of the base (links at chain depth 0) in the xy plane of the model frame.
pub(crate) fn base_radius(model: &RobotModel) -> f64 {
    let zero = vec![0.0; model.dof()];
    let Ok(posed) = model.posed_geometry(&zero, GeometryKind::Visual) else {
        return 0.1;
    };
    posed
        .iter()
        .filter(|(_, g)| model.chain_depth(&g.link) == Some(0))
        .flat_map(|(t, g)| {
            g.mesh
                .vertices
                .iter()
                .map(move |v| (t * v).coords.xy().norm())
        })
        .fold(0.0, f64::max)
        .max(0.03)
}

/// Turns exact depths into what the sensor reports. `albedo`: every pixel's surface albedo
/// ([`ScanNoise::reference_albedo`]), empty when surfaces are all alike; with it the cloud
/// carries the camera's amplitude image as its intensity.
pub(super) fn measure(
    image: &DepthImage,
    intr: &Intrinsics,
    noise: &ScanNoise,
    albedo: &[f64],
    seed: u64,
) -> PointCloud {
    let (w, h) = (image.width, image.height);
    let depth = &image.depth;
    let ripple = &Ripple::new(noise, seed, w, h);
    let multipath = &multipath_shares(image, intr, noise, albedo);
    let measured: Vec<(Point3<f32>, f32)> = (0..h)
        .into_par_iter()
        .flat_map_iter(|v| {
            let mut rng = rand::rngs::StdRng::seed_from_u64(
                seed ^ (v as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15),
            );
            (0..w).map(move |u| {
                let i = v * w + u;
                let nan = (Point3::new(f32::NAN, f32::NAN, f32::NAN), f32::NAN);
                let z = depth[i];
                if !z.is_finite() {
                    return nan;
                }
                let ray = intr.ray(u as f64, v as f64);
                let n = image.normal[i];
                let cos_inc = (-(ray.normalize()).dot(&Vector3::new(
                    f64::from(n.x),
                    f64::from(n.y),
                    f64::from(n.z),
                )))
                .clamp(0.0, 1.0);
                let incidence = cos_inc.acos();
                if rng.random::<f64>() >= noise.grazing_survival(incidence)
                    || rng.random::<f64>() < noise.random_dropout_probability
                {
                    return nan;
                }
                let mut z = z + multipath
                    .get(i)
                    .map_or(0.0, |share| share * noise.multipath_m);
                if noise.flying_pixel_probability > 0.0 {
                    if let Some(other) =
                        edge_neighbour(depth, w, h, u, v, noise.flying_pixel_edge_m)
                    {
                        if rng.random::<f64>() < noise.flying_pixel_probability {
                            z += (other - z) * rng.random_range(0.1..0.9);
                        }
                    }
                }
                let z = z + ripple.at(u, v, z);
                let a = albedo.get(i).copied();
                let noisy = match a {
                    Some(a) => noise.noisy_depth_on(z, incidence, ray.norm(), a, &mut rng),
                    None => noise.noisy_depth(z, incidence, ray.norm(), &mut rng),
                };
                let z = noise.quantized(noisy * noise.gradient_factor(z, &ray));
                if z > noise.max_range_m {
                    return nan;
                }
                let p = ray * z;
                let amp = a.map_or(f32::NAN, |a| amplitude(a, cos_inc, p.norm()) as f32);
                (Point3::new(p.x as f32, p.y as f32, p.z as f32), amp)
            })
        })
        .collect();
    let intensity =
        (!albedo.is_empty()).then(|| measured.iter().map(|(_, a)| *a).collect::<Vec<f32>>());
    PointCloud {
        width: w as u32,
        height: h as u32,
        points: measured.into_iter().map(|(p, _)| p).collect(),
        intensity,
        confidence: None,
    }
}

/// The smooth depth error of [`ScanNoise::ripple_sigma_at_1m_m`]: a stationary Gaussian
/// random field across the image with covariance `exp(-r² / 2ℓ²)` (`ℓ` =
/// [`ScanNoise::ripple_correlation_px`]), drawn from the scan's seed as a sum of
/// [`RIPPLE_WAVES`] plane waves whose wave vectors come from the matching Gaussian spectrum —
/// the blobs of stereo matching on weakly textured surfaces, not one regular wave.
#[derive(Debug)]
struct Ripple {
    /// cos and sin of `ku·u` per column (`[u][wave]`).
    cols: Vec<[(f64, f64); RIPPLE_WAVES]>,
    /// cos and sin of `kv·v + phase` per row (`[v][wave]`).
    rows: Vec<[(f64, f64); RIPPLE_WAVES]>,
    sigma_at_1m_m: f64,
}

/// A plane wave of the ripple: wave vector along u and v (radians per pixel), phase.
type Wave = (f64, f64, f64);

/// Plane waves summed into the ripple field: enough for its values to look Gaussian and its
/// blobs irregular; each pixel costs two multiplications per wave.
const RIPPLE_WAVES: usize = 32;

impl Ripple {
    fn new(noise: &ScanNoise, seed: u64, width: usize, height: usize) -> Self {
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed ^ 0x5249_5050_4c45);
        let off = noise.ripple_sigma_at_1m_m == 0.0;
        // Wave vectors ~ N(0, 1/ℓ²) per axis give the covariance exp(-r²/2ℓ²).
        let per_axis = rand_distr::Normal::new(0.0, 1.0 / noise.ripple_correlation_px)
            .expect("validated: a positive correlation length");
        let waves: [Wave; RIPPLE_WAVES] = std::array::from_fn(|_| {
            (
                rng.sample(per_axis),
                rng.sample(per_axis),
                rng.random_range(0.0..std::f64::consts::TAU),
            )
        });
        // cos and sin of each wave's angle at every column (u) or row (v); none when off.
        let table = |n: usize, angle: &dyn Fn(f64, &Wave) -> f64| {
            let n = if off { 0 } else { n };
            (0..n)
                .map(|i| {
                    std::array::from_fn(|w| {
                        let (sin, cos) = angle(i as f64, &waves[w]).sin_cos();
                        (cos, sin)
                    })
                })
                .collect()
        };
        Self {
            cols: table(width, &|u, (ku, _, _)| ku * u),
            rows: table(height, &|v, (_, kv, phase)| kv * v + phase),
            sigma_at_1m_m: noise.ripple_sigma_at_1m_m,
        }
    }

    /// The ripple's depth error at pixel `(u, v)` for a true depth `z` (metres).
    fn at(&self, u: usize, v: usize, z: f64) -> f64 {
        if self.sigma_at_1m_m == 0.0 {
            return 0.0;
        }
        // cos(a + b) = cos a cos b − sin a sin b, from the column and row tables.
        let sum: f64 = self.cols[u]
            .iter()
            .zip(&self.rows[v])
            .map(|((ca, sa), (cb, sb))| ca * cb - sa * sb)
            .sum();
        // RIPPLE_WAVES unit cosines with independent phases: variance RIPPLE_WAVES / 2.
        self.sigma_at_1m_m * z * z * sum * (2.0 / RIPPLE_WAVES as f64).sqrt()
    }
}

/// Smallest cosine between a surface's normal and the direction to another surface for the two
/// to face each other (10° above the surface's plane): points of one plane never face each
/// other.
const MULTIPATH_FACING_COS: f64 = 0.17;

/// Extra round-trip path of a bounce at which it pushes the range by its full share, metres.
/// A continuous-wave camera measures the phase of the direct and the bounced light summed; for
/// paths far shorter than the modulation wavelength (metres) the bounced light moves the
/// phase by its strength times its extra path (Fuchs 2010), so a bounce off a fillet a few
/// millimetres away pushes by a few tenths of its share, one off the plate centimetres away
/// by all of it.
const MULTIPATH_FULL_PATH_M: f64 = 0.05;

/// Per pixel, the share of its neighbours within `multipath_window_px` (a sparse grid of at
/// most 9 × 9 samples) whose surfaces face its surface and that its surface faces, each weighed
/// by its albedo over the reference ([`ScanNoise::reference_albedo`]; 1 when surfaces are all
/// alike) and by its bounce's extra path ([`MULTIPATH_FULL_PATH_M`]), at most 1: the light
/// those surfaces bounce onto it is the multipath of [`ScanNoise::multipath_m`]. Empty when
/// `multipath_m` is 0 (nothing to compute).
fn multipath_shares(
    image: &DepthImage,
    intr: &Intrinsics,
    noise: &ScanNoise,
    albedo: &[f64],
) -> Vec<f64> {
    if noise.multipath_m == 0.0 {
        return Vec::new();
    }
    let window_px = noise.multipath_window_px;
    // Each facing surface bounces light by its albedo (over the reference's); 1 when surfaces
    // are all alike.
    let bounce = |j: usize| albedo.get(j).map_or(1.0, |a| a / noise.reference_albedo);
    let (w, h) = (image.width, image.height);
    let reach = window_px.round().max(1.0) as i64;
    let stride = (reach / 4).max(1);
    let point = |i: usize| {
        let z = image.depth[i];
        z.is_finite()
            .then(|| intr.ray((i % w) as f64, (i / w) as f64) * z)
    };
    let normal = |i: usize| image.normal[i].cast::<f64>();
    (0..h)
        .into_par_iter()
        .flat_map_iter(|v| {
            (0..w).map(move |u| {
                let i = v * w + u;
                let Some(p) = point(i) else {
                    return 0.0;
                };
                let n = normal(i);
                let (mut facing, mut seen) = (0.0f64, 0usize);
                for dv in (-reach..=reach).step_by(stride as usize) {
                    for du in (-reach..=reach).step_by(stride as usize) {
                        let (x, y) = (u as i64 + du, v as i64 + dv);
                        if (du, dv) == (0, 0) || x < 0 || y < 0 || x >= w as i64 || y >= h as i64 {
                            continue;
                        }
                        let j = y as usize * w + x as usize;
                        let Some(q) = point(j) else {
                            continue;
                        };
                        seen += 1;
                        let Some(d) = (q - p).try_normalize(1e-9) else {
                            continue;
                        };
                        if n.dot(&d) > MULTIPATH_FACING_COS
                            && -normal(j).dot(&d) > MULTIPATH_FACING_COS
                        {
                            // The bounce's extra round trip: camera → q → p → camera against
                            // camera → p → camera.
                            let extra = q.norm() + (q - p).norm() - p.norm();
                            facing += bounce(j) * (extra / MULTIPATH_FULL_PATH_M).clamp(0.0, 1.0);
                        }
                    }
                }
                if seen == 0 {
                    0.0
                } else {
                    (facing / seen as f64).min(1.0)
                }
            })
        })
        .collect()
}

/// The depth of a 4-neighbour across a depth edge (finite, differing by more than `edge_m`).
fn edge_neighbour(
    depth: &[f64],
    w: usize,
    h: usize,
    u: usize,
    v: usize,
    edge_m: f64,
) -> Option<f64> {
    let z = depth[v * w + u];
    let mut best: Option<f64> = None;
    for (du, dv) in [(-1i64, 0i64), (1, 0), (0, -1), (0, 1)] {
        let (x, y) = (u as i64 + du, v as i64 + dv);
        if x < 0 || y < 0 || x >= w as i64 || y >= h as i64 {
            continue;
        }
        let o = depth[y as usize * w + x as usize];
        if o.is_finite()
            && (o - z).abs() > edge_m
            && best.is_none_or(|b| (o - z).abs() > (b - z).abs())
        {
            best = Some(o);
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::look_at;
    use crate::testutil::shared_robot;
    use parry3d_f64::query::PointQuery;

    const UR5E: &str = "ur/ur5e/ur5e.urdf";

    fn eye_to_hand(
        model: &RobotModel,
        noise: ScanNoise,
        cell: CellOptions,
        seed: u64,
    ) -> (ScanRequest<'_>, SimulatedScan) {
        let req = ScanRequest {
            model,
            joints: vec![0.3, -1.9, 1.7, -1.2, -1.5, 0.0],
            placement: Placement::EyeToHand {
                model_from_camera: look_at(
                    &Point3::new(0.55, -0.25, 0.45),
                    &Point3::new(0.0, 0.0, 0.1),
                    &-Vector3::z(),
                ),
            },
            intrinsics: Intrinsics::compact_1280x960().scaled(0.5),
            noise,
            cell,
            kinematic_error: KinematicError::none(),
            arm: None,
            seed,
        };
        let scan = simulate_scan(&req).expect("simulates");
        (req, scan)
    }

    #[test]
    fn ideal_ray_cast_points_lie_on_the_posed_meshes() {
        let Some(model) = shared_robot(UR5E) else {
            return;
        };
        let (req, scan) = eye_to_hand(&model, ScanNoise::none(), CellOptions::default(), 1);
        let poses = model.link_poses(&req.joints).expect("fk");
        let mut shapes: std::collections::HashMap<String, parry3d_f64::shape::TriMesh> =
            std::collections::HashMap::new();
        let mut checked = 0;
        for (i, p) in scan.cloud.points.iter().enumerate().step_by(37) {
            let label = scan.labels[i];
            if label == u32::MAX {
                assert!(p.x.is_nan(), "a pixel without a hit has no point");
                continue;
            }
            let Some(link) = scan.objects[label as usize].strip_prefix("link:") else {
                continue;
            };
            let li = model.link_index(link).expect("link");
            let shape = shapes.entry(link.to_string()).or_insert_with(|| {
                let g = model
                    .geometry(GeometryKind::Visual)
                    .iter()
                    .find(|g| g.link == link)
                    .expect("geometry");
                parry3d_f64::shape::TriMesh::new(g.mesh.vertices.clone(), g.mesh.triangles.clone())
                    .expect("valid mesh")
            });
            let in_model = req.placement_model_from_camera()
                * Point3::new(f64::from(p.x), f64::from(p.y), f64::from(p.z));
            let d = shape.distance_to_point(&poses[li], &in_model, false);
            assert!(d < 1e-5, "point {in_model} is {d} m off link {link}");
            checked += 1;
        }
        assert!(
            checked > 200,
            "the robot fills part of the view ({checked} points checked)"
        );
        // the cell is there too, and the floor is at the plate's underside
        assert!(scan.objects.iter().any(|o| o == "floor"));
    }

    #[test]
    fn ground_truth_closes_the_chain_and_scans_are_reproducible() {
        let Some(model) = shared_robot(UR5E) else {
            return;
        };
        let mount = Isometry3::new(Vector3::new(0.0, 0.08, 0.04), Vector3::new(0.2, 0.0, 0.1));
        let q = vec![0.5, -1.2, 1.4, -2.4, -1.6, 0.3];
        let mut req = ScanRequest {
            model: &model,
            joints: q.clone(),
            placement: Placement::EyeInHand {
                flange_from_camera: mount,
            },
            intrinsics: Intrinsics::compact_1280x960().scaled(0.25),
            noise: ScanNoise::default(),
            cell: CellOptions::default(),
            kinematic_error: KinematicError::none(),
            arm: None,
            seed: 7,
        };
        let a = simulate_scan(&req).expect("simulates");
        let t = &a.truth;
        let nominal = model.frame_pose("tool0", &q).expect("fk");
        assert!(
            (t.model_from_flange_reported.to_homogeneous() - nominal.to_homogeneous()).norm()
                < 1e-12
        );
        assert!(
            ((t.model_from_flange_reported * mount).to_homogeneous()
                - t.model_from_camera.to_homogeneous())
            .norm()
                < 1e-12
        );
        assert!(
            ((t.camera_from_model * t.model_from_camera).to_homogeneous()
                - nalgebra::Matrix4::identity())
            .norm()
                < 1e-12
        );
        let b = simulate_scan(&req).expect("simulates");
        assert!(a
            .cloud
            .points
            .iter()
            .zip(&b.cloud.points)
            .all(|(p, q)| p == q || (p.x.is_nan() && q.x.is_nan())));
        // with kinematic error, the controller's (true) flange differs from the nominal model by ~mm
        req.kinematic_error = KinematicError::default().with_exact_readings();
        let c = simulate_scan(&req).expect("simulates");
        let off = (c.truth.model_from_flange_reported.translation.vector
            - nominal.translation.vector)
            .norm();
        assert!(off > 1e-4 && off < 0.01, "true vs nominal flange: {off} m");
        assert!(
            ((c.truth.model_from_flange_reported * mount).to_homogeneous()
                - c.truth.model_from_camera.to_homogeneous())
            .norm()
                < 1e-12
        );
        // Joints read with error (issue 43): the arm, and the camera on it, stand at the physical
        // joints, a few hundredths of a millimetre from the flange the controller reports.
        req.kinematic_error = KinematicError::default();
        let d = simulate_scan(&req).expect("simulates");
        assert_eq!(
            d.truth.joints, req.joints,
            "the readings are what was asked"
        );
        let reading = d
            .truth
            .joints
            .iter()
            .zip(&d.truth.physical_joints)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(reading > 1e-6 && reading < 1e-3, "{reading} rad");
        let camera_off =
            (d.truth.model_from_flange_reported * mount).inverse() * d.truth.model_from_camera;
        let off = camera_off.translation.vector.norm();
        assert!(
            off > 1e-6 && off < 5e-4,
            "reported vs physical camera: {off} m"
        );
        req.kinematic_error = KinematicError::default().with_exact_readings();
        // An exactly built arm is its URDF: the same scan as the exact arm.
        let dh = model.ur_model().expect("UR").dh();
        let exact = ScanRequest {
            kinematic_error: KinematicError::none(),
            ..req.clone()
        };
        let d = simulate_scan(&exact.with_arm(PhysicalArm::exact(dh))).expect("simulates");
        assert!(a
            .cloud
            .points
            .iter()
            .zip(&d.cloud.points)
            .all(|(p, q)| (p - q).norm() < 1e-6 || (p.x.is_nan() && q.x.is_nan())));
        // The random kinematic error is not applied on top of the physical arm.
        let d = simulate_scan(&req.clone().with_arm(PhysicalArm::exact(dh))).expect("simulates");
        assert!(d.truth.joint_origin_errors.is_empty());
        assert!(
            (d.truth.model_from_flange_reported.to_homogeneous() - nominal.to_homogeneous()).norm()
                < 1e-9
        );
        // A physical arm: the flange is the forward kinematics of the DH its controller
        // publishes.
        let arm = PhysicalArm::factory(model.ur_model().expect("UR"), 1);
        let calibrated = arm.controller_dh();
        assert!(
            calibrated.d[1].abs() > 1.0,
            "parallel-axis DH: {:?}",
            calibrated.d
        );
        let e = simulate_scan(&req.clone().with_arm(arm)).expect("simulates");
        let q6: [f64; 6] = q.as_slice().try_into().expect("6 joints");
        let reported = model.frame_pose("base", &q).expect("base") * calibrated.forward(&q6);
        assert!(
            (e.truth.model_from_flange_reported.to_homogeneous() - reported.to_homogeneous())
                .norm()
                < 1e-9
        );
        assert!(
            ((reported * mount).to_homogeneous() - e.truth.model_from_camera.to_homogeneous())
                .norm()
                < 1e-9
        );
        assert_eq!(e.truth.controller_dh, Some(calibrated));
    }

    /// Per pixel: (distance of the ideal point from the line x = z = 0, metres; how much
    /// farther `noise` measures it, metres) for a camera looking at the origin from above -x.
    fn depth_push(scene: &[TriMesh], noise: &ScanNoise) -> Vec<(f64, f64)> {
        let intr = Intrinsics::compact_1280x960().scaled(0.25);
        let model_from_camera = look_at(
            &Point3::new(-0.8, 0.1, 0.8),
            &Point3::new(0.0, 0.0, 0.0),
            &-Vector3::z(),
        );
        let image = raycast(
            &SceneMesh::indexed(scene),
            &model_from_camera.inverse(),
            &intr,
        );
        let ideal = measure(&image, &intr, &ScanNoise::none(), &[], 1);
        let measured = measure(&image, &intr, noise, &[], 1);
        ideal
            .points
            .iter()
            .zip(&measured.points)
            .filter(|(a, _)| a.x.is_finite())
            .map(|(a, b)| {
                let world = model_from_camera * a.cast::<f64>();
                (world.x.hypot(world.z), f64::from(b.z) - f64::from(a.z))
            })
            .collect()
    }

    #[test]
    fn multipath_pushes_depths_farther_at_a_concave_corner_and_not_on_a_flat_surface() {
        let [floor, wall] = crate::testutil::floor_and_wall();
        let noise = ScanNoise {
            multipath_m: 0.01,
            ..ScanNoise::none()
        };
        noise.validate().expect("valid");
        // The floor alone: open and flat, no multipath anywhere.
        let flat = depth_push(std::slice::from_ref(&floor), &noise);
        assert!(flat.len() > 10_000, "{}", flat.len());
        assert!(flat.iter().all(|(_, push)| *push == 0.0));
        // Floor meeting a wall: pushed farther near the corner, by a share of 1 cm; untouched
        // far from it; never nearer.
        let corner = depth_push(&[floor, wall], &noise);
        let mean = |near: &dyn Fn(f64) -> bool| {
            let v: Vec<f64> = corner
                .iter()
                .filter(|(d, _)| near(*d))
                .map(|(_, p)| *p)
                .collect();
            assert!(v.len() > 100, "{} pixels", v.len());
            v.iter().sum::<f64>() / v.len() as f64
        };
        let at_corner = mean(&|d| d < 0.02);
        let near = mean(&|d| (0.03..0.06).contains(&d));
        let far = mean(&|d| d > 0.15);
        // Each bounce pushes by its share times its extra path (full from 5 cm): within 2 cm of
        // the corner the bounces are short, a little farther they are longer (issue 45).
        assert!(
            (0.001..0.005).contains(&at_corner),
            "pushed {at_corner} m at the corner"
        );
        assert!(near > 0.0, "pushed {near} m 3–6 cm from the corner");
        assert!(far.abs() < 1e-9, "pushed {far} m far from the corner");
        assert!(corner.iter().all(|(_, push)| *push >= 0.0));
        assert!(corner.iter().all(|(_, push)| *push <= 0.01 + 1e-6));
    }

    #[test]
    fn depth_scale_error_scales_points_and_noise_perturbs_them() {
        let Some(model) = shared_robot(UR5E) else {
            return;
        };
        let (_, ideal) = eye_to_hand(&model, ScanNoise::none(), CellOptions::default(), 3);
        let scaled = ScanNoise {
            depth_scale_error: 0.01,
            ..ScanNoise::none()
        };
        let (_, s) = eye_to_hand(&model, scaled, CellOptions::default(), 3);
        for (a, b) in ideal
            .cloud
            .points
            .iter()
            .zip(&s.cloud.points)
            .filter(|(a, _)| a.x.is_finite())
            .step_by(101)
        {
            assert!((b.coords - a.coords * 1.01).norm() < 1e-5);
        }
        let (_, noisy) = eye_to_hand(&model, ScanNoise::default(), CellOptions::default(), 3);
        let valid = |c: &PointCloud| c.valid_count() as f64;
        assert!(
            valid(&noisy.cloud) < valid(&ideal.cloud),
            "dropouts remove points"
        );
        assert!(
            valid(&noisy.cloud) > 0.8 * valid(&ideal.cloud),
            "but not most of them"
        );
    }
}
