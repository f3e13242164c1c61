//! View generation: joint configurations from which the camera sees the robot base.
//!
//! A view is accepted when the joints are within limits, the arm is free of self-collision and
//! of the floor (convex hulls of the collision meshes, parry), the base is in the image at the
//! requested distance, and the base and shoulder are not hidden by the arm itself (checked by
//! rendering the posed robot at low resolution).

use std::f64::consts::PI;

use nalgebra::{Isometry3, Point3};
use parry3d_f64::shape::ConvexPolyhedron;
use rand::{Rng, SeedableRng};

use crate::geometry::raycast::{raycast, SceneMesh};
use crate::model::{GeometryKind, ModelError, RobotModel};
use crate::sim::Intrinsics;

/// What a good calibration view must satisfy.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ViewConstraints {
    /// Nearest allowed camera-to-base distance, metres.
    pub min_distance_m: f64,
    /// Farthest allowed camera-to-base distance, metres.
    pub max_distance_m: f64,
    /// The base centre must project at least this fraction of the image size from the border.
    pub image_margin_fraction: f64,
    /// Fraction of the base and shoulder pixels that must not be hidden by the rest of the arm.
    pub min_unoccluded_fraction: f64,
    /// Fraction of the base's own pixels that must not be hidden by the shoulder and the rest of
    /// the arm (seen from above, the shoulder can hide the whole base).
    pub min_base_visible_fraction: f64,
    /// Every link beyond the shoulder and the camera stay this high above the mounting plane, m.
    pub floor_clearance_m: f64,
    /// Between two generated views at least one joint changes by this much, radians.
    pub min_joint_change_rad: f64,
}

impl Default for ViewConstraints {
    fn default() -> Self {
        Self {
            min_distance_m: 0.4,
            max_distance_m: 0.8,
            image_margin_fraction: 0.2,
            min_unoccluded_fraction: 0.8,
            min_base_visible_fraction: 0.25,
            floor_clearance_m: 0.03,
            min_joint_change_rad: 20f64.to_radians(),
        }
    }
}

/// Why a view was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum ViewRejection {
    /// A joint is outside its limits.
    #[error("joint {joint} at {value_rad:.3} rad is outside its limits [{lower:.3}, {upper:.3}]")]
    JointLimit {
        /// Joint name.
        joint: String,
        /// Requested angle.
        value_rad: f64,
        /// Lower limit.
        lower: f64,
        /// Upper limit.
        upper: f64,
    },
    /// Two links collide.
    #[error("links {a} and {b} collide")]
    SelfCollision {
        /// First link.
        a: String,
        /// Second link.
        b: String,
    },
    /// A link or the camera is too close to the floor.
    #[error("{what} comes within {clearance_m:.3} m of the mounting plane")]
    Floor {
        /// The link or "camera".
        what: String,
        /// The height reached.
        clearance_m: f64,
    },
    /// A link or the camera meets a configured obstacle.
    #[error("{what} meets the obstacle `{obstacle}`")]
    Obstacle {
        /// The link or "camera".
        what: String,
        /// The obstacle's configured name.
        obstacle: String,
    },
    /// The base is not in the image, or at the wrong distance.
    #[error("the base is not in view ({0})")]
    NotInView(String),
    /// The planning was cancelled (the run was told to stop) before the check finished.
    #[error("planning was cancelled")]
    Cancelled,
    /// The arm hides the base, or the base and shoulder.
    #[error("only {percent:.0}% of the {what} is visible", percent = visible_fraction * 100.0)]
    Occluded {
        /// "base" or "base and shoulder".
        what: &'static str,
        /// The visible fraction.
        visible_fraction: f64,
    },
}

/// Errors of view generation.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PlanError {
    /// The model refused a request.
    #[error(transparent)]
    Model(#[from] ModelError),
    /// Not enough views were found.
    #[error("found only {found} of {wanted} views after {tries} tries; widen the distance range or check the camera mount")]
    NotEnoughViews {
        /// Views found.
        found: usize,
        /// Views wanted.
        wanted: usize,
        /// Random configurations tried.
        tries: usize,
    },
    /// The planning was cancelled (the run was told to stop).
    #[error("planning was cancelled")]
    Cancelled,
}

/// Asked between the planner's checks (every path sample, every generated candidate): whether
/// to stop, so a cancelled run or a SIGTERM never waits for a long plan.
#[derive(Clone)]
pub struct CancelCheck(std::sync::Arc<dyn Fn() -> bool + Send + Sync>);

impl CancelCheck {
    /// Stop when `cancelled` says so.
    pub fn new(cancelled: impl Fn() -> bool + Send + Sync + 'static) -> Self {
        Self(std::sync::Arc::new(cancelled))
    }
}

impl std::fmt::Debug for CancelCheck {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("CancelCheck")
    }
}

/// A posed mesh for the occlusion check: (1 base, 2 shoulder, 0 the rest; vertices in model
/// frame; triangles).
type PosedHull<'a> = (u32, Vec<Point3<f64>>, &'a [[u32; 3]]);

/// How much of the base, and of the base and shoulder, the rest of the arm leaves visible.
#[derive(Debug, Clone, Copy, PartialEq)]
struct VisibleFractions {
    /// Visible base pixels over the base's pixels rendered alone.
    pub base: f64,
    /// Visible base and shoulder pixels over theirs rendered without the rest of the arm.
    pub base_and_shoulder: f64,
}

/// A box in the cell the arm must not touch (a table edge, a fixture, a fence).
#[derive(Debug, Clone, PartialEq)]
pub struct Obstacle {
    /// Name used in messages.
    pub name: String,
    /// Pose of the box centre in the model frame (URDF root link).
    pub model_from_box: Isometry3<f64>,
    /// Half the box's edge lengths, metres.
    pub half_extents_m: nalgebra::Vector3<f64>,
}

/// How a joint-space path was checked.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PathCheck {
    /// Configurations checked along the path (both ends included).
    pub samples: usize,
    /// Largest joint change between two checked configurations, radians.
    pub max_step_rad: f64,
}

/// Checks views of one robot with one camera mount.
#[derive(Debug)]
pub struct ViewPlanner<'a> {
    model: &'a RobotModel,
    flange_from_camera: Isometry3<f64>,
    intrinsics: Intrinsics,
    constraints: ViewConstraints,
    /// Per link (index into `model.link_names()`): convex hull of its collision geometry.
    hulls: Vec<Option<ConvexPolyhedron>>,
    /// Per link: how high above the mounting plane its hull must stay — the clearance, or
    /// less for a link that comes closer already in the home pose (all joints 0): a CB3 UR5's
    /// upper-arm joint housing sits 2.9 cm above the plane whatever the joints do.
    floor_clearance_m: Vec<f64>,
    /// Where the base is: centre of the base (chain depth 0) geometry, model frame.
    base_centre: Point3<f64>,
    /// Boxes in the cell no link and not the camera may touch.
    obstacles: Vec<(Obstacle, parry3d_f64::shape::Cuboid)>,
    /// Whether to stop planning.
    cancel: Option<CancelCheck>,
}

impl<'a> ViewPlanner<'a> {
    /// A planner for a camera at `flange_from_camera` with intrinsics `intrinsics`.
    pub fn new(
        model: &'a RobotModel,
        flange_from_camera: Isometry3<f64>,
        intrinsics: Intrinsics,
        constraints: ViewConstraints,
    ) -> Self {
        let names = model.link_names();
        let mut points: Vec<Vec<Point3<f64>>> = vec![Vec::new(); names.len()];
        for g in model.geometry(GeometryKind::Collision) {
            if let Some(i) = names.iter().position(|l| *l == g.link) {
                points[i].extend(g.mesh.vertices.iter().copied());
            }
        }
        let hulls: Vec<Option<ConvexPolyhedron>> = points
            .iter()
            .map(|p| {
                (p.len() >= 4)
                    .then(|| ConvexPolyhedron::from_convex_hull(p))
                    .flatten()
            })
            .collect();
        let zero = vec![0.0; model.dof()];
        let home = model.link_poses(&zero).ok();
        let floor_clearance_m = hulls
            .iter()
            .enumerate()
            .map(|(i, hull)| {
                let home_low = match (hull, home.as_ref().and_then(|h| h.get(i))) {
                    (Some(hull), Some(pose)) => lowest(hull, pose),
                    _ => f64::INFINITY,
                };
                constraints.floor_clearance_m.min(home_low.max(0.0))
            })
            .collect();
        let mut lo = Point3::new(f64::INFINITY, f64::INFINITY, f64::INFINITY);
        let mut hi = -lo;
        if let Ok(posed) = model.posed_geometry(&zero, GeometryKind::Visual) {
            for (t, g) in posed
                .iter()
                .filter(|(_, g)| model.chain_depth(&g.link) == Some(0))
            {
                for v in &g.mesh.vertices {
                    let p = t * v;
                    lo = lo.inf(&p);
                    hi = hi.sup(&p);
                }
            }
        }
        let base_centre = if lo.x.is_finite() {
            nalgebra::center(&lo, &hi)
        } else {
            Point3::origin()
        };
        Self {
            model,
            flange_from_camera,
            intrinsics,
            constraints,
            hulls,
            floor_clearance_m,
            base_centre,
            obstacles: Vec::new(),
            cancel: None,
        }
    }

    /// The same planner that also keeps every link (beyond the base) and the camera out of
    /// `obstacles`.
    pub fn with_obstacles(mut self, obstacles: Vec<Obstacle>) -> Self {
        self.obstacles = obstacles
            .into_iter()
            .map(|o| {
                let cuboid = parry3d_f64::shape::Cuboid::new(o.half_extents_m);
                (o, cuboid)
            })
            .collect();
        self
    }

    /// Whether the arm may be at `q` at all: joint limits, floor, self-collision and the
    /// configured obstacles (not whether the view is good; see [`Self::check`]).
    pub fn check_motion(&self, q: &[f64]) -> Result<Result<(), ViewRejection>, ModelError> {
        if self.is_cancelled() {
            return Ok(Err(ViewRejection::Cancelled));
        }
        if let Err(r) = self.within_limits(q) {
            return Ok(Err(r));
        }
        self.collision_free(q)
    }

    /// This planner, stopping with [`ViewRejection::Cancelled`] / [`PlanError::Cancelled`] as
    /// soon as `cancel` says so.
    pub fn with_cancel(mut self, cancel: CancelCheck) -> Self {
        self.cancel = Some(cancel);
        self
    }

    fn is_cancelled(&self) -> bool {
        self.cancel.as_ref().is_some_and(|c| (c.0)())
    }

    /// Checks the straight joint-space path of a `movej` from `from` to `to` (both ends
    /// included) with [`Self::check_motion`] every `max_step_rad` of the largest joint change.
    pub fn check_path(
        &self,
        from: &[f64],
        to: &[f64],
        max_step_rad: f64,
    ) -> Result<Result<PathCheck, ViewRejection>, ModelError> {
        let span = joint_span(from, to);
        let steps = ((span / max_step_rad.max(1e-3)).ceil() as usize).clamp(1, 10_000);
        for k in 0..=steps {
            let t = k as f64 / steps as f64;
            let q: Vec<f64> = from.iter().zip(to).map(|(a, b)| a + t * (b - a)).collect();
            if let Err(r) = self.check_motion(&q)? {
                return Ok(Err(r));
            }
        }
        Ok(Ok(PathCheck {
            samples: steps + 1,
            max_step_rad: span / steps as f64,
        }))
    }

    fn within_limits(&self, q: &[f64]) -> Result<(), ViewRejection> {
        let m = self.model;
        for ((name, lim), &v) in m.joint_names().iter().zip(m.joint_limits()).zip(q) {
            if v < lim.lower || v > lim.upper {
                return Err(ViewRejection::JointLimit {
                    joint: name.clone(),
                    value_rad: v,
                    lower: lim.lower,
                    upper: lim.upper,
                });
            }
        }
        Ok(())
    }

    /// Checks one joint configuration: joint limits, floor and self-collision first, then that
    /// the base is in view and not hidden by the arm. `Ok` carries the camera-to-base distance
    /// in metres.
    pub fn check(&self, q: &[f64]) -> Result<Result<f64, ViewRejection>, ModelError> {
        if let Err(r) = self.within_limits(q) {
            return Ok(Err(r));
        }
        if let Err(r) = self.collision_free(q)? {
            return Ok(Err(r));
        }
        let distance = match self.base_in_view(q)? {
            Ok(d) => d,
            Err(r) => return Ok(Err(r)),
        };
        Ok(self.unoccluded(q)?.map(|()| distance))
    }

    /// The camera pose in the model frame at joints `q`.
    pub fn model_from_camera(&self, q: &[f64]) -> Result<Isometry3<f64>, ModelError> {
        Ok(self.model.frame_pose(self.model.flange_link(), q)? * self.flange_from_camera)
    }

    /// Whether the base centre is in the image at the allowed distance (cheap).
    fn base_in_view(&self, q: &[f64]) -> Result<Result<f64, ViewRejection>, ModelError> {
        let c = self.model_from_camera(q)?.inverse() * self.base_centre;
        let distance = c.coords.norm();
        if distance < self.constraints.min_distance_m || distance > self.constraints.max_distance_m
        {
            return Ok(Err(ViewRejection::NotInView(format!(
                "base at {distance:.2} m"
            ))));
        }
        let margin = self.constraints.image_margin_fraction
            * f64::from(self.intrinsics.width.min(self.intrinsics.height));
        Ok(match self.intrinsics.project(&c) {
            Some((u, v)) if self.intrinsics.contains(u, v, margin) => Ok(distance),
            _ => Err(ViewRejection::NotInView(
                "base centre outside the image".into(),
            )),
        })
    }

    /// Floor clearance of the camera and of every link beyond the shoulder; self-collision of
    /// non-adjacent links (convex hulls).
    fn collision_free(&self, q: &[f64]) -> Result<Result<(), ViewRejection>, ModelError> {
        let m = self.model;
        let poses = m.link_poses(q)?;
        let camera_z = self.model_from_camera(q)?.translation.z;
        if camera_z < self.constraints.floor_clearance_m {
            return Ok(Err(ViewRejection::Floor {
                what: "camera".into(),
                clearance_m: camera_z,
            }));
        }
        let names = m.link_names();
        let depth: Vec<Option<usize>> = names.iter().map(|l| m.chain_depth(l)).collect();
        if !self.obstacles.is_empty() {
            let camera = self.model_from_camera(q)?;
            // The camera body: a 6 cm ball around its optical origin.
            let ball = parry3d_f64::shape::Ball::new(0.03);
            for (o, cuboid) in &self.obstacles {
                if self.is_cancelled() {
                    return Ok(Err(ViewRejection::Cancelled));
                }
                let hit = |pose: &Isometry3<f64>, shape: &dyn parry3d_f64::shape::Shape| {
                    parry3d_f64::query::intersection_test(&o.model_from_box, cuboid, pose, shape)
                        .unwrap_or(true)
                };
                if hit(&camera, &ball) {
                    return Ok(Err(ViewRejection::Obstacle {
                        what: "camera".into(),
                        obstacle: o.name.clone(),
                    }));
                }
                for (i, hull) in self.hulls.iter().enumerate() {
                    let (Some(hull), Some(d)) = (hull, depth[i]) else {
                        continue;
                    };
                    if d >= 1 && hit(&poses[i], hull) {
                        return Ok(Err(ViewRejection::Obstacle {
                            what: names[i].clone(),
                            obstacle: o.name.clone(),
                        }));
                    }
                }
            }
        }
        for (i, hull) in self.hulls.iter().enumerate() {
            let (Some(hull), Some(d)) = (hull, depth[i]) else {
                continue;
            };
            if d >= 2 {
                let low = lowest(hull, &poses[i]);
                if low < self.floor_clearance_m[i] {
                    return Ok(Err(ViewRejection::Floor {
                        what: names[i].clone(),
                        clearance_m: low,
                    }));
                }
            }
            for (j, other) in self.hulls.iter().enumerate().skip(i + 1) {
                let (Some(other), Some(dj)) = (other, depth[j]) else {
                    continue;
                };
                if d.abs_diff(dj) < 2 {
                    continue; // adjacent links touch by design
                }
                if parry3d_f64::query::intersection_test(&poses[i], hull, &poses[j], other)
                    .unwrap_or(false)
                {
                    return Ok(Err(ViewRejection::SelfCollision {
                        a: names[i].clone(),
                        b: names[j].clone(),
                    }));
                }
            }
        }
        Ok(Ok(()))
    }

    /// Renders the arm at low resolution and compares, with and without the rest of the arm in
    /// front of them, the base and shoulder pixels together and the base's own pixels (a
    /// shoulder seen from above can hide all of the base: the scan then shows too little to
    /// register).
    fn unoccluded(&self, q: &[f64]) -> Result<Result<(), ViewRejection>, ModelError> {
        let seen = self.visible_fractions(q)?;
        let c = &self.constraints;
        Ok(if seen.base_and_shoulder < c.min_unoccluded_fraction {
            Err(ViewRejection::Occluded {
                what: "base and shoulder",
                visible_fraction: seen.base_and_shoulder,
            })
        } else if seen.base < c.min_base_visible_fraction {
            Err(ViewRejection::Occluded {
                what: "base",
                visible_fraction: seen.base,
            })
        } else {
            Ok(())
        })
    }

    /// Fractions of the base's pixels and of the base and shoulder pixels that the whole arm
    /// leaves visible (0 when they are not in the image).
    fn visible_fractions(&self, q: &[f64]) -> Result<VisibleFractions, ModelError> {
        const BASE: u32 = 1;
        const SHOULDER: u32 = 2;
        let m = self.model;
        let low = self
            .intrinsics
            .scaled(160.0 / f64::from(self.intrinsics.width));
        let posed = m.posed_geometry(q, GeometryKind::Collision)?;
        let world: Vec<PosedHull<'_>> = posed
            .iter()
            .map(|(t, g)| {
                let object = match m.chain_depth(&g.link) {
                    Some(0) => BASE,
                    Some(1) => SHOULDER,
                    _ => 0,
                };
                (
                    object,
                    g.mesh.vertices.iter().map(|v| t * v).collect(),
                    g.mesh.triangles.as_slice(),
                )
            })
            .collect();
        let camera_from_model = self.model_from_camera(q)?.inverse();
        // (base pixels, base + shoulder pixels) of a render of the objects `shown`.
        let render = |shown: &dyn Fn(u32) -> bool| -> (usize, usize) {
            let meshes: Vec<SceneMesh<'_>> = world
                .iter()
                .filter(|(o, _, _)| shown(*o))
                .map(|(o, v, t)| SceneMesh {
                    vertices: v,
                    triangles: t,
                    object: *o,
                })
                .collect();
            let hits = raycast(&meshes, &camera_from_model, &low).object;
            let base = hits.iter().filter(|&&o| o == BASE).count();
            let near = hits.iter().filter(|&&o| o == BASE || o == SHOULDER).count();
            (base, near)
        };
        let (base_alone, _) = render(&|o| o == BASE);
        let (_, near_alone) = render(&|o| o == BASE || o == SHOULDER);
        let (base_seen, near_seen) = render(&|_| true);
        let ratio = |seen: usize, alone: usize| {
            if alone == 0 {
                0.0
            } else {
                seen as f64 / alone as f64
            }
        };
        Ok(VisibleFractions {
            base: ratio(base_seen, base_alone),
            base_and_shoulder: ratio(near_seen, near_alone),
        })
    }

    /// `count` random views (seeded), each at least `min_joint_change_rad` away from the others
    /// in some joint.
    pub fn generate(&self, count: usize, seed: u64) -> Result<Vec<Vec<f64>>, PlanError> {
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        let mut views: Vec<Vec<f64>> = Vec::new();
        let max_tries = 200_000 + 20_000 * count;
        let mut tries = 0;
        while views.len() < count && tries < max_tries {
            if self.is_cancelled() {
                return Err(PlanError::Cancelled);
            }
            tries += 1;
            let q = random_joints(self.model, &mut rng);
            let far_enough = differs_from_all(&views, &q, self.constraints.min_joint_change_rad);
            if far_enough && self.base_in_view(&q)?.is_ok() && self.check(&q)?.is_ok() {
                views.push(q);
            }
        }
        if views.len() < count {
            return Err(PlanError::NotEnoughViews {
                found: views.len(),
                wanted: count,
                tries,
            });
        }
        Ok(views)
    }
}

/// How far the other views of a run move each joint from its first view at most, radians
/// ([`ViewPlanner::nearby`]): the base and the upper arm a little (the base stays in view, the
/// moves stay short), the wrist far (what turns the flange, and so separates the mount from
/// the base's housing).
pub const NEARBY_SPAN_RAD: [f64; 6] = [0.5, 0.3, 0.3, 0.9, 0.9, 1.6];

/// Largest joint change between two configurations checked along a path, rad.
pub const PATH_STEP_RAD: f64 = 0.02;

/// A base housing's turn off joint 1's axis (1σ, 0.3 mrad) over a view's error of the flange
/// turn (its joint readings', ~0.1 mrad): how much the views must turn the flange to separate
/// the mount from it ([`ViewPlanner::mount_turn_spread`]).
pub const HOUSING_OVER_VIEW: f64 = 3.0;

/// Rounds of candidates [`ViewPlanner::extend_run`] draws for a view before it gives up.
pub const RUN_VIEW_ROUNDS: usize = 8;
/// Candidates drawn near a run's first view in each round.
pub const RUN_VIEW_CANDIDATES: usize = 12;

/// How far a run's first view moves each joint from where the arm stands at most, radians
/// ([`ViewPlanner::nearby`]): the base a quarter turn, the rest anywhere within their limits.
pub const FIRST_VIEW_SPAN_RAD: [f64; 6] = [std::f64::consts::FRAC_PI_2, PI, PI, PI, PI, PI];

impl ViewPlanner<'_> {
    /// Up to `want` views near `anchor` (joint `k` within `span_rad[k]` of it, uniformly,
    /// seeded), each passing [`Self::check`]; gives up after `max_draws` draws.
    pub fn nearby(
        &self,
        anchor: &[f64],
        span_rad: &[f64],
        want: usize,
        max_draws: usize,
        seed: u64,
    ) -> Result<Vec<Vec<f64>>, PlanError> {
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        let mut found = Vec::new();
        for _ in 0..max_draws {
            if found.len() >= want {
                break;
            }
            if self.is_cancelled() {
                return Err(PlanError::Cancelled);
            }
            let q: Vec<f64> = anchor
                .iter()
                .enumerate()
                .map(|(k, a)| {
                    let span = span_rad.get(k).copied().unwrap_or(0.0);
                    a + rng.random_range(-span..=span)
                })
                .collect();
            if self.base_in_view(&q)?.is_ok() && self.check(&q)?.is_ok() {
                found.push(q);
            }
        }
        Ok(found)
    }

    /// Extends a run's `views` (its first view at least) to `count` wrist-camera views near the
    /// first ([`Self::nearby`] within [`NEARBY_SPAN_RAD`]: the base and upper arm turn a little,
    /// the wrist far), each the one that best separates the mount from the base's housing with
    /// the views before it ([`Self::mount_turn_spread`]) among those `safe` admits on the path
    /// from the view before. Draws from `seed` on; a view none
    /// of [`RUN_VIEW_ROUNDS`] rounds finds is [`PlanError::NotEnoughViews`].
    pub fn extend_run(
        &self,
        views: &mut Vec<Vec<f64>>,
        count: usize,
        seed: u64,
        mut safe: impl FnMut(&[f64], &[f64]) -> Result<bool, PlanError>,
    ) -> Result<(), PlanError> {
        let Some(first) = views.first().cloned() else {
            return Err(PlanError::NotEnoughViews {
                found: 0,
                wanted: count,
                tries: 0,
            });
        };
        let mut next_seed = seed;
        while views.len() < count {
            let mut picked = None;
            for _ in 0..RUN_VIEW_ROUNDS {
                let candidates = self.nearby(
                    &first,
                    &NEARBY_SPAN_RAD,
                    RUN_VIEW_CANDIDATES,
                    20 * RUN_VIEW_CANDIDATES,
                    next_seed,
                )?;
                next_seed = next_seed.wrapping_add(1);
                let mut scored = Vec::new();
                for q in candidates {
                    if !differs_from_all(views, &q, self.constraints.min_joint_change_rad) {
                        continue;
                    }
                    let mut with = views.clone();
                    with.push(q.clone());
                    scored.push((self.mount_turn_spread(&with)?, q));
                }
                scored.sort_by(|a, b| a.0.total_cmp(&b.0));
                let from = views.last().cloned().unwrap_or_default();
                for (_, q) in scored {
                    if safe(&from, &q)? {
                        picked = Some(q);
                        break;
                    }
                }
                if picked.is_some() {
                    break;
                }
            }
            let Some(q) = picked else {
                return Err(PlanError::NotEnoughViews {
                    found: views.len(),
                    wanted: count,
                    tries: RUN_VIEW_ROUNDS * 20 * RUN_VIEW_CANDIDATES,
                });
            };
            views.push(q);
        }
        Ok(())
    }

    /// How well `views` fitted together separate the mount's turn from the base housing's
    /// (smaller is better): each view sees the mount's turn `ε` (flange frame) plus the
    /// housing's `δ` (model frame) carried to the flange, `ε + Rᵢᵀ δ`, with the same error
    /// each; the housing's prior is [`HOUSING_OVER_VIEW`] times a view's error. The trace of
    /// `ε`'s covariance in units of a view's error²: 1/n when the flange turns about every
    /// axis between the views, up to 1 + the prior's when it never turns.
    pub fn mount_turn_spread(&self, views: &[Vec<f64>]) -> Result<f64, ModelError> {
        let mut info = nalgebra::Matrix6::<f64>::zeros();
        for q in views {
            let r = self
                .model
                .frame_pose(self.model.flange_link(), q)?
                .rotation
                .to_rotation_matrix()
                .into_inner();
            let mut a = nalgebra::Matrix3x6::<f64>::zeros();
            a.fixed_view_mut::<3, 3>(0, 0)
                .copy_from(&nalgebra::Matrix3::identity());
            a.fixed_view_mut::<3, 3>(0, 3).copy_from(&r.transpose());
            info += a.transpose() * a;
        }
        for k in 3..6 {
            info[(k, k)] += HOUSING_OVER_VIEW.powi(-2);
        }
        Ok(info
            .try_inverse()
            .map_or(f64::INFINITY, |c| c.fixed_view::<3, 3>(0, 0).trace()))
    }

    /// The angle between the flange's orientations at joints `a` and `b`, radians.
    pub fn flange_turn(&self, a: &[f64], b: &[f64]) -> Result<f64, ModelError> {
        let fa = self.model.frame_pose(self.model.flange_link(), a)?;
        let fb = self.model.frame_pose(self.model.flange_link(), b)?;
        Ok(fa.rotation.angle_to(&fb.rotation))
    }
}

/// A random joint configuration within `model`'s limits (each joint within ±π), one uniform
/// draw per joint in chain order.
pub fn random_joints(model: &RobotModel, rng: &mut impl Rng) -> Vec<f64> {
    model
        .joint_limits()
        .iter()
        .map(|l| rng.random_range(l.lower.max(-PI)..=l.upper.min(PI)))
        .collect()
}

/// The largest joint change between `a` and `b`, radians: what a `movej`'s duration and its
/// path's sampling follow (every joint arrives together).
pub fn joint_span(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (y - x).abs())
        .fold(0.0, f64::max)
}

/// Whether `q` differs from each of `views` by at least `min_change_rad` in some joint.
pub fn differs_from_all(views: &[Vec<f64>], q: &[f64], min_change_rad: f64) -> bool {
    views.iter().all(|v| {
        v.iter()
            .zip(q)
            .any(|(a, b)| (a - b).abs() >= min_change_rad)
    })
}

/// The lowest point (model z) of `hull` posed at `pose`.
fn lowest(hull: &ConvexPolyhedron, pose: &Isometry3<f64>) -> f64 {
    hull.points()
        .iter()
        .map(|p| (pose * p).z)
        .fold(f64::INFINITY, f64::min)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::shared_robot;
    use nalgebra::Vector3;

    /// A wrist camera 8 cm off the tool axis, looking along it, tilted 15° towards it.
    pub(crate) fn nominal_mount() -> Isometry3<f64> {
        Isometry3::new(
            Vector3::new(0.0, -0.08, 0.03),
            Vector3::new(-15f64.to_radians(), 0.0, 0.0),
        )
    }

    /// A 1280×960 wrist camera on `nominal_mount` under `constraints`.
    fn wrist_planner(model: &RobotModel, constraints: ViewConstraints) -> ViewPlanner<'_> {
        ViewPlanner::new(
            model,
            nominal_mount(),
            Intrinsics::compact_1280x960(),
            constraints,
        )
    }

    /// Any distance, anywhere in the image: only limits, collisions and the floor count.
    fn loose() -> ViewConstraints {
        ViewConstraints {
            min_distance_m: 0.0,
            max_distance_m: 10.0,
            image_margin_fraction: -10.0,
            ..ViewConstraints::default()
        }
    }

    #[test]
    fn generated_views_see_the_base_and_differ_by_20_degrees() {
        let Some(model) = shared_robot("ur/ur5e/ur5e.urdf") else {
            return;
        };
        let planner = wrist_planner(&model, ViewConstraints::default());
        let views = planner.generate(6, 11).expect("views");
        assert_eq!(views.len(), 6);
        for (i, a) in views.iter().enumerate() {
            let d = planner.check(a).expect("fk").expect("accepted");
            assert!((0.4..=0.8).contains(&d));
            for b in &views[i + 1..] {
                assert!(a
                    .iter()
                    .zip(b)
                    .any(|(x, y)| (x - y).abs() >= 20f64.to_radians()));
            }
        }
    }

    #[test]
    fn bad_views_are_refused_with_the_reason() {
        let Some(model) = shared_robot("ur/ur5e/ur5e.urdf") else {
            return;
        };
        let planner = wrist_planner(&model, ViewConstraints::default());
        // beyond the joint limits
        let r = planner.check(&[0.0, 0.0, 4.0, 0.0, 0.0, 0.0]).expect("fk");
        assert!(matches!(r, Err(ViewRejection::JointLimit { .. })), "{r:?}");
        // arm pointing straight up, camera looking at the sky
        let r = planner
            .check(&[0.0, -1.57, 0.0, -1.57, 0.0, 0.0])
            .expect("fk");
        assert!(matches!(r, Err(ViewRejection::NotInView(_))), "{r:?}");
        // the arm folded down through the floor
        let p = wrist_planner(&model, loose());
        let r = p.check(&[0.0, 0.6, 0.0, 0.0, 0.0, 0.0]).expect("fk");
        assert!(matches!(r, Err(ViewRejection::Floor { .. })), "{r:?}");
        // forearm folded back onto the upper arm
        let r = p.check(&[0.0, -1.57, 3.0, 0.0, 0.0, 0.0]).expect("fk");
        assert!(
            matches!(r, Err(ViewRejection::SelfCollision { .. })),
            "{r:?}"
        );
    }

    #[test]
    fn a_view_where_the_shoulder_hides_the_base_is_refused() {
        // Bench seed 3, ur20 view 4 (planned before the base had to be visible): the camera
        // looks down onto the shoulder, the scan shows floor, plate and shoulder, no base.
        let Some(model) = shared_robot("ur/ur20/ur20.urdf") else {
            return;
        };
        let mount = Isometry3::new(
            Vector3::new(0.010_119_6, -0.091_501_2, 0.040_630_1),
            Vector3::new(-0.039_561_4, -0.158_934_6, 2.649_511_5),
        );
        let q = [
            -2.065_258, -0.306_393, -2.679_933, -1.520_331, 2.107_118, 3.052_489,
        ];
        let planner = ViewPlanner::new(
            &model,
            mount,
            Intrinsics::compact_1280x960(),
            ViewConstraints::default(),
        );
        let r = planner.check(&q).expect("fk");
        assert!(
            matches!(r, Err(ViewRejection::Occluded { what: "base", .. })),
            "{r:?}"
        );
        // The base and shoulder together were visible enough: only the base check refuses it.
        let old = ViewPlanner::new(
            &model,
            mount,
            Intrinsics::compact_1280x960(),
            ViewConstraints {
                min_base_visible_fraction: 0.0,
                ..ViewConstraints::default()
            },
        );
        assert!(old.check(&q).expect("fk").is_ok());
    }

    #[test]
    fn a_low_shoulder_joint_is_not_a_floor_collision() {
        // The CB3 UR5's upper-arm joint housing sits 2.9 cm above the mounting plane whatever
        // the joints do: with the 3 cm clearance applied to it, 800 000 random tries found 2
        // views. The link may stay as low as it is at home; below that it still collides.
        let Some(model) = shared_robot("ur/ur5/ur5.urdf") else {
            return;
        };
        let planner = wrist_planner(&model, ViewConstraints::default());
        let views = planner.generate(6, 11).expect("views of a UR5");
        assert_eq!(views.len(), 6);
        let p = wrist_planner(&model, loose());
        let r = p.check(&[0.0, 0.6, 0.0, 0.0, 0.0, 0.0]).expect("fk");
        assert!(matches!(r, Err(ViewRejection::Floor { .. })), "{r:?}");
    }

    #[test]
    fn paths_are_checked_against_obstacles_and_the_floor() {
        let Some(model) = shared_robot("ur/ur5e/ur5e.urdf") else {
            return;
        };
        let home = [0.0, -PI / 2.0, PI / 2.0, -PI / 2.0, -PI / 2.0, 0.0];
        let mut turned = home;
        turned[0] = PI / 2.0;
        let free = wrist_planner(&model, loose());
        let ok = free
            .check_path(&home, &turned, 0.02)
            .expect("fk")
            .expect("free path");
        assert!(ok.samples >= 78 && ok.max_step_rad <= 0.02, "{ok:?}");
        // A post where the wrist sweeps through at 45°: the ends are free, the path is not.
        let elbow = model
            .link_poses(&{
                let mut q = home;
                q[0] = PI / 4.0;
                q
            })
            .expect("fk")[model.link_index("wrist_1_link").expect("wrist 1")]
        .translation
        .vector;
        let post = Obstacle {
            name: "post".into(),
            model_from_box: Isometry3::translation(elbow.x, elbow.y, elbow.z),
            half_extents_m: Vector3::new(0.03, 0.03, 0.03),
        };
        let blocked = wrist_planner(&model, loose()).with_obstacles(vec![post]);
        let r0 = blocked.check_motion(&home).expect("fk");
        assert!(r0.is_ok(), "{r0:?} post at {elbow}");
        assert!(blocked.check_motion(&turned).expect("fk").is_ok());
        let r = blocked.check_path(&home, &turned, 0.02).expect("fk");
        assert!(
            matches!(&r, Err(ViewRejection::Obstacle { obstacle, .. }) if obstacle == "post"),
            "{r:?}"
        );
        // Down through the floor: the path is refused even though the target is reached
        // by a short move.
        let mut low = home;
        low[1] = 0.6;
        let r = free.check_path(&home, &low, 0.02).expect("fk");
        assert!(matches!(r, Err(ViewRejection::Floor { .. })), "{r:?}");
    }
}
