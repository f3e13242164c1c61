//! The robot model: URDF, meshes (visual and collision), forward kinematics, joint limits.
//!
//! [`RobotModel::load`] reads a URDF with `urdf-rs`, its STL and OBJ meshes with `mesh-loader`
//! and its Collada meshes with our own reader (module `collada`, because mesh-loader 0.1.13 composes
//! nested Collada transforms in the wrong order). Mesh paths are relative to the URDF file, or
//! absolute; `package://` URIs are rejected (expand them first). Every mesh is returned in the
//! frame of the link that carries it, with the URDF `<origin>` and `<mesh scale>` applied.
//!
//! Frames: the URDF root link is the frame called `model`; every pose this module returns is
//! `model_from_<link>`. For UR arms the controller's `base` is a link of the URDF (`base_link`
//! turned by π about z, see [`crate::frames::ur_base_from_base_link`]).

mod collada;
pub(crate) mod kinematic;
mod load;
mod mesh;
mod primitives;
pub mod reading;
pub mod reported;
#[cfg(test)]
mod tests;
mod ur_calibration;

use std::collections::{HashMap, VecDeque};
use std::f64::consts::TAU;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use handeye_hal::limits;
use handeye_hal::ur_dh::{DhParams, Line, PhysicalArm, UrModel};
use nalgebra::{Isometry3, Matrix4, Translation3, Unit, UnitQuaternion, Vector3};
use rayon::prelude::*;

pub use kinematic::{
    KinematicError, MAX_KINEMATIC_SIGMA, UR_DEFLECTION_RAD, UR_JOINT_READING_SIGMA_RAD,
};
pub use load::find_urdfs;
pub use mesh::TriMesh;
pub use ur_calibration::{
    ur_calibration_yaml, UrCalibration, UrCalibrationError, MAX_UR_CALIBRATION_BYTES,
    UR_CALIBRATION_JOINTS,
};

/// Largest URDF file read (a UR URDF is ~20 kB).
pub const MAX_URDF_BYTES: u64 = 16 << 20;
/// Largest mesh file read (the largest mesh of the 21 reference robots is ~10 MB).
pub const MAX_MESH_FILE_BYTES: u64 = 512 << 20;
/// Most triangles one mesh file may produce (after Collada instancing) and a whole model may
/// hold, per kind (visual, collision); the UR5e has 129 k.
pub const MAX_MODEL_TRIANGLES: usize = 20_000_000;
/// Largest coordinate of any geometry in its link's frame, metres (after `<origin>` and
/// `<mesh scale>`): no robot link reaches that far from its joint.
pub const MAX_LINK_EXTENT_M: f64 = 20.0;

/// Largest joint limit (and mimic multiplier or offset) accepted, radians or metres.
pub const MAX_JOINT_LIMIT: f64 = 1000.0;

/// Which of a link's geometries: what it looks like (`<visual>`, use it to synthesise and
/// register scans) or its simplified hull (`<collision>`, use it for collision checks).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum GeometryKind {
    /// `<visual>` elements.
    Visual,
    /// `<collision>` elements.
    Collision,
}

/// Limits of one movable joint.
///
/// Revolute joints: radians and rad/s, from the URDF `<limit>`. Continuous joints (no position
/// limit in the URDF) get `lower = −2π`, `upper = +2π`, which is what UR controllers allow and
/// keeps samplers finite. Prismatic joints: metres and m/s.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointLimit {
    /// Lowest position, rad (m for prismatic joints).
    pub lower: f64,
    /// Highest position, rad (m for prismatic joints).
    pub upper: f64,
    /// Highest speed, rad/s (m/s for prismatic joints).
    pub velocity: f64,
}

/// The merged geometry of one kind of one link.
#[derive(Debug, Clone)]
pub struct LinkGeometry {
    /// Name of the link that carries the mesh.
    pub link: String,
    /// All the link's `<visual>` (or `<collision>`) elements merged, vertices in the link frame.
    pub mesh: Arc<TriMesh>,
}

/// Why a robot model could not be loaded or evaluated.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ModelError {
    /// The URDF file could not be read.
    #[error("cannot read URDF {path}: {source}; check the path and its permissions")]
    ReadUrdf {
        /// The URDF file.
        path: PathBuf,
        /// The I/O error.
        #[source]
        source: std::io::Error,
    },
    /// The URDF is not valid (XML, structure, numbers, tree).
    #[error(
        "malformed URDF {path}: {reason}; fix the file (a plain URDF, xacro already expanded)"
    )]
    MalformedUrdf {
        /// The URDF file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// A mesh file named by the URDF does not exist or cannot be read.
    #[error(
        "mesh {path} of link `{link}` cannot be read ({reason}); mesh paths are relative to the \
         URDF file: copy the mesh there or fix the path"
    )]
    MissingMesh {
        /// Link whose geometry names the mesh.
        link: String,
        /// Resolved path.
        path: PathBuf,
        /// The I/O error, as text.
        reason: String,
    },
    /// A mesh URI we do not resolve (`package://`, `http://`, …).
    #[error(
        "mesh URI `{uri}` of link `{link}` is not supported; use a path relative to the URDF file \
         or an absolute path (expand package:// URIs first)"
    )]
    UnsupportedMeshUri {
        /// Link whose geometry names the mesh.
        link: String,
        /// The URI as written in the URDF.
        uri: String,
    },
    /// A mesh file whose format we do not read.
    #[error("mesh {path} of link `{link}` has an unsupported format; convert it to STL, OBJ or Collada (.dae)")]
    UnsupportedMeshFormat {
        /// Link whose geometry names the mesh.
        link: String,
        /// The mesh file.
        path: PathBuf,
    },
    /// A mesh file that could not be parsed.
    #[error("mesh {path} of link `{link}` is malformed: {reason}; re-export it from the CAD tool")]
    MalformedMesh {
        /// Link whose geometry names the mesh.
        link: String,
        /// The mesh file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// A joint vector of the wrong length.
    #[error("robot `{robot}` has {expected} joints ({joints}), got {got} joint values")]
    JointCount {
        /// Robot name.
        robot: String,
        /// Number of movable chain joints.
        expected: usize,
        /// Length of the vector given.
        got: usize,
        /// The joint names, comma-separated.
        joints: String,
    },
    /// A NaN or infinite joint value.
    #[error("joint value {index} (`{joint}`) is {value}; joint values must be finite")]
    NonFiniteJoint {
        /// Index in the joint vector.
        index: usize,
        /// Joint name.
        joint: String,
        /// The value given.
        value: f64,
    },
    /// The controller's DH parameters were given for a robot that is not a 6-joint UR arm.
    #[error(
        "robot `{robot}` cannot be posed by a UR controller's DH parameters: {reason}; use a UR \
         URDF (the file or robot name must say which model, e.g. ur5e) or the nominal kinematics"
    )]
    NotUrArm {
        /// Robot name.
        robot: String,
        /// Why.
        reason: String,
    },
    /// A frame name that is not a link of the robot.
    #[error("unknown frame `{name}` in robot `{robot}`; {hint}")]
    UnknownFrame {
        /// The name asked for.
        name: String,
        /// Robot name.
        robot: String,
        /// Close names, or all names.
        hint: String,
    },
}

/// How a link moves relative to its parent, after the fixed joint origin.
#[derive(Debug, Clone, Copy)]
enum Motion {
    Fixed,
    Revolute {
        axis: Unit<Vector3<f64>>,
        q: QSource,
    },
    Prismatic {
        axis: Unit<Vector3<f64>>,
        q: QSource,
    },
}

impl Motion {
    /// The chain joint this motion is (its index and axis), when a chain value drives it
    /// directly; `None` for fixed, mimic and held joints.
    fn chain_joint(self) -> Option<(usize, Unit<Vector3<f64>>)> {
        match self {
            Motion::Fixed => None,
            Motion::Revolute { axis, q } | Motion::Prismatic { axis, q } => {
                q.chain_index().map(|i| (i, axis))
            }
        }
    }
}

/// Where a movable joint's value comes from.
#[derive(Debug, Clone, Copy)]
enum QSource {
    /// Index into the chain joint vector.
    Chain(usize),
    /// `multiplier · q[index] + offset` (URDF `<mimic>` of a chain joint).
    Mimic {
        index: usize,
        multiplier: f64,
        offset: f64,
    },
    /// Not in the chain: held at zero.
    Zero,
}

impl QSource {
    /// The chain joint this is driven by directly (not through a mimic).
    fn chain_index(self) -> Option<usize> {
        match self {
            QSource::Chain(i) => Some(i),
            _ => None,
        }
    }

    fn value(self, q: &[f64]) -> f64 {
        match self {
            QSource::Chain(i) => q[i],
            QSource::Mimic {
                index,
                multiplier,
                offset,
            } => multiplier * q[index] + offset,
            QSource::Zero => 0.0,
        }
    }
}

#[derive(Debug, Clone)]
struct LinkNode {
    parent: Option<usize>,
    parent_from_joint: Isometry3<f64>,
    motion: Motion,
    chain_depth: usize,
}

/// A robot loaded from a URDF: kinematic tree, chain joints, limits and meshes.
#[derive(Debug, Clone)]
pub struct RobotModel {
    name: String,
    urdf_path: PathBuf,
    link_names: Vec<String>,
    link_index: HashMap<String, usize>,
    links: Vec<LinkNode>,
    /// Link indices, parents before children.
    order: Vec<usize>,
    root: usize,
    flange: usize,
    joint_names: Vec<String>,
    joint_limits: Vec<JointLimit>,
    /// Per chain joint: continuous (no position limit in the URDF; `joint_limits` holds ±2π).
    continuous: Vec<bool>,
    visual: Vec<LinkGeometry>,
    collision: Vec<LinkGeometry>,
}

impl RobotModel {
    /// The URDF robot name (`<robot name>`).
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The URDF file this model was loaded from.
    pub fn urdf_path(&self) -> &Path {
        &self.urdf_path
    }

    /// The URDF root link: the frame called `model`.
    pub fn root_link(&self) -> &str {
        &self.link_names[self.root]
    }

    /// The flange link: `tool0` if present, else `flange`, else the chain tip (the first link
    /// with the most movable joints between it and the root).
    pub fn flange_link(&self) -> &str {
        &self.link_names[self.flange]
    }

    /// The movable joints (revolute, continuous, prismatic) from the root to the flange, in
    /// chain order: the order of every joint vector `q`. Other movable joints are held at zero
    /// (or follow their `<mimic>` chain joint); floating, planar and spherical joints are fixed.
    pub fn joint_names(&self) -> &[String] {
        &self.joint_names
    }

    /// Number of chain joints.
    pub fn dof(&self) -> usize {
        self.joint_names.len()
    }

    /// Limits of the chain joints, in [`joint_names`](Self::joint_names) order.
    pub fn joint_limits(&self) -> &[JointLimit] {
        &self.joint_limits
    }

    /// Whether chain joint `i` is continuous (any angle; its [`JointLimit`] is ±2π only to
    /// keep samplers finite). `false` for an index out of range.
    pub fn joint_is_continuous(&self, i: usize) -> bool {
        self.continuous.get(i).copied().unwrap_or(false)
    }

    /// Every link, in URDF document order.
    pub fn link_names(&self) -> &[String] {
        &self.link_names
    }

    /// Position of `link` in [`link_names`](Self::link_names) (and in
    /// [`link_poses`](Self::link_poses)), or `None` for an unknown link.
    pub fn link_index(&self, link: &str) -> Option<usize> {
        self.link_index.get(link).copied()
    }

    /// Number of chain joints between the root and `link` (base links 0, shoulder 1, upper
    /// arm 2, …), or `None` for an unknown link.
    pub fn chain_depth(&self, link: &str) -> Option<usize> {
        self.link_index
            .get(link)
            .map(|&l| self.links[l].chain_depth)
    }

    fn check_q(&self, q: &[f64]) -> Result<(), ModelError> {
        if q.len() != self.dof() {
            return Err(ModelError::JointCount {
                robot: self.name.clone(),
                expected: self.dof(),
                got: q.len(),
                joints: self.joint_names.join(", "),
            });
        }
        if let Some((index, &value)) = q.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(ModelError::NonFiniteJoint {
                index,
                joint: self.joint_names[index].clone(),
                value,
            });
        }
        Ok(())
    }

    /// `model_from_link` of every link at joint values `q` (rad, m for prismatic joints), in
    /// [`link_names`](Self::link_names) order.
    pub fn link_poses(&self, q: &[f64]) -> Result<Vec<Isometry3<f64>>, ModelError> {
        self.poses(q, None)
    }

    /// Like [`link_poses`](Self::link_poses) for an arm that differs from this nominal model:
    /// `joint_origin_errors[i]` (one per chain joint, see [`joint_axes`](Self::joint_axes)) is
    /// inserted between chain joint `i`'s nominal origin and its motion. This is how the scan
    /// simulator poses the "true" arm of a robot whose controller has factory calibration.
    pub fn link_poses_with_errors(
        &self,
        q: &[f64],
        joint_origin_errors: &[Isometry3<f64>],
    ) -> Result<Vec<Isometry3<f64>>, ModelError> {
        if joint_origin_errors.len() != self.dof() {
            return Err(ModelError::JointCount {
                robot: self.name.clone(),
                expected: self.dof(),
                got: joint_origin_errors.len(),
                joints: self.joint_names.join(", "),
            });
        }
        self.poses(q, Some(joint_origin_errors))
    }

    /// `model_from_link` of every link at joint values `q` (rad), in
    /// [`link_names`](Self::link_names) order, for a UR arm whose controller uses the DH
    /// parameters `calibrated` (absolute values in UR's `base` frame, e.g. its factory
    /// calibration as the primary interface's KinematicsInfo reports it, or a ur_calibration
    /// file): the arm as the controller knows it, which is also the frame its reported flange
    /// poses are in.
    ///
    /// A real controller's DH set places the frames of the nearly parallel joints 2–4 hundreds
    /// of metres away; no link is rigid with those. Each link is put on its calibrated joint
    /// axis where [`DhParams::link_frames`] says (at the common normal of crossing axes, or
    /// nearest its nominal place along parallel ones); the flange's link is rigid with the
    /// flange. With the nominal parameters this is [`link_poses`](Self::link_poses).
    ///
    /// Errors: [`ModelError::NotUrArm`] unless [`ur_model`](Self::ur_model) detects the arm and
    /// it has 6 chain joints; the errors of [`link_poses`](Self::link_poses).
    pub fn link_poses_with_controller_dh(
        &self,
        q: &[f64],
        calibrated: &DhParams,
    ) -> Result<Vec<Isometry3<f64>>, ModelError> {
        let (ur, q6) = self.ur_joints(q)?;
        self.link_poses_with_dh_frames(q, &calibrated.link_frames(&ur.dh(), &q6))
    }

    /// `model_from_link` of every link at joint values `q` (rad) of the physical UR arm `arm`
    /// (its links rigid with its frames, [`PhysicalArm::frames`]): how the scan simulator poses
    /// a real arm, whose controller publishes [`PhysicalArm::controller_dh`].
    ///
    /// Errors: those of [`link_poses_with_controller_dh`](Self::link_poses_with_controller_dh).
    pub fn link_poses_of_arm(
        &self,
        q: &[f64],
        arm: &PhysicalArm,
    ) -> Result<Vec<Isometry3<f64>>, ModelError> {
        let (_, q6) = self.ur_joints(q)?;
        self.link_poses_with_dh_frames(q, &arm.frames(&q6))
    }

    /// The six joint axes of a UR arm with the DH set `dh` at joints `q` (rad), model frame
    /// (joint `k + 1` turns about entry `k`; the point is the one nearest
    /// the nominal arm's joint, not the DH frame's origin hundreds of metres away).
    ///
    /// Errors: those of [`link_poses_with_controller_dh`](Self::link_poses_with_controller_dh).
    pub fn dh_axes(&self, q: &[f64], dh: &DhParams) -> Result<Vec<Line>, ModelError> {
        let (ur, q6) = self.ur_joints(q)?;
        let model_from_base = self.model_from_ur_base(&self.link_poses(q)?)?;
        let nominal = ur.dh().axes(&q6);
        Ok(dh
            .axes(&q6)
            .iter()
            .zip(&nominal)
            .map(|(l, n)| Line {
                point: model_from_base
                    .transform_point(&l.nearest(&n.point).into())
                    .coords,
                direction: model_from_base * l.direction,
            })
            .collect())
    }

    /// The UR model and the six joint values, or [`ModelError::NotUrArm`].
    fn ur_joints(&self, q: &[f64]) -> Result<(UrModel, [f64; 6]), ModelError> {
        self.check_q(q)?;
        let not_ur = |reason: String| ModelError::NotUrArm {
            robot: self.name.clone(),
            reason,
        };
        let ur = self
            .ur_model()
            .ok_or_else(|| not_ur("no UR model name in the robot or URDF file name".into()))?;
        let q6: [f64; 6] = q
            .try_into()
            .map_err(|_| not_ur(format!("it has {} chain joints, not 6", self.dof())))?;
        Ok((ur, q6))
    }

    /// `model_from_base` (UR's controller frame) from the links' poses: the `base` link, or
    /// `base_link` turned by π about z.
    fn model_from_ur_base(&self, poses: &[Isometry3<f64>]) -> Result<Isometry3<f64>, ModelError> {
        match self.link_index.get("base") {
            Some(&l) => Ok(poses[l]),
            None => {
                let &l = self
                    .link_index
                    .get("base_link")
                    .ok_or_else(|| ModelError::NotUrArm {
                        robot: self.name.clone(),
                        reason: "it has neither a `base` nor a `base_link`".into(),
                    })?;
                Ok(poses[l] * crate::frames::ur_base_from_base_link().inverse())
            }
        }
    }

    /// `model_from_link` of every link of a UR arm whose link of chain depth `k` is rigid with
    /// `frames[k]` (`base_from_frame_k`, UR `base` frame, k = 0..=6): the nominal URDF follows
    /// the nominal DH frames `N_k(q)`, so with `M` = `model_from_base` a link moves to
    /// `M · frames[k] · N_k(q)⁻¹ · M⁻¹ · model_from_link(q)`.
    fn link_poses_with_dh_frames(
        &self,
        q: &[f64],
        frames: &[Isometry3<f64>; 7],
    ) -> Result<Vec<Isometry3<f64>>, ModelError> {
        let (ur, q6) = self.ur_joints(q)?;
        let nominal_poses = self.link_poses(q)?;
        let model_from_base = self.model_from_ur_base(&nominal_poses)?;
        let base_from_model = model_from_base.inverse();
        let nominal = ur.dh().link_poses(&q6);
        let mut corrections = [Isometry3::identity(); 7];
        for k in 1..=6 {
            corrections[k] =
                model_from_base * frames[k] * nominal[k - 1].inverse() * base_from_model;
        }
        Ok(nominal_poses
            .iter()
            .zip(&self.links)
            .map(|(pose, node)| corrections[node.chain_depth.min(6)] * pose)
            .collect())
    }

    /// The nominal origin of each chain joint in its parent link (`parent_from_joint`), chain
    /// order: its translation is the link vector that a link-length error scales.
    pub fn joint_origins(&self) -> Vec<Isometry3<f64>> {
        let mut origins = vec![Isometry3::identity(); self.dof()];
        for node in &self.links {
            if let Some((i, _)) = node.motion.chain_joint() {
                origins[i] = node.parent_from_joint;
            }
        }
        origins
    }

    /// `model_from_joint` of each chain joint at joint values `q`: the frame after the joint's
    /// nominal origin, before its motion, chain order. A kinematic error of the arm enters here
    /// (see [`link_poses_with_errors`](Self::link_poses_with_errors)) and moves every link
    /// beyond the joint.
    pub fn joint_frames(&self, q: &[f64]) -> Result<Vec<Isometry3<f64>>, ModelError> {
        Ok(self.joint_frames_of(&self.link_poses(q)?))
    }

    /// `model_from_joint` of each chain joint given every link's `model_from_link` (in
    /// [`link_names`](Self::link_names) order, e.g. from
    /// [`link_poses_with_errors`](Self::link_poses_with_errors)): the parent link's pose times
    /// the joint's nominal origin, chain order.
    ///
    /// # Panics
    /// If `link_poses` has fewer entries than the model has links.
    pub fn joint_frames_of(&self, link_poses: &[Isometry3<f64>]) -> Vec<Isometry3<f64>> {
        let poses = link_poses;
        let mut frames = vec![Isometry3::identity(); self.dof()];
        for node in &self.links {
            if let (Some(p), Some((i, _))) = (node.parent, node.motion.chain_joint()) {
                frames[i] = poses[p] * node.parent_from_joint;
            }
        }
        frames
    }

    /// The frame of each chain depth's link given every link's `model_from_link` (in
    /// [`link_names`](Self::link_names) order): entry 0 the root's (identity), entry `d ≥ 1`
    /// the link chain joint `d − 1` moves, after its motion. A housing's offset is fixed in
    /// this frame ([`with_housings`](Self::with_housings)).
    ///
    /// # Panics
    /// If `link_poses` has fewer entries than the model has links.
    pub fn chain_link_frames(&self, link_poses: &[Isometry3<f64>]) -> Vec<Isometry3<f64>> {
        let mut frames = vec![Isometry3::identity(); self.dof() + 1];
        for (l, node) in self.links.iter().enumerate() {
            if let Some((i, _)) = node.motion.chain_joint() {
                frames[i + 1] = link_poses[l];
            }
        }
        frames
    }

    /// The poses of every link's housing (what a camera sees) given every link's
    /// `model_from_link` (in [`link_names`](Self::link_names) order) and `housings[d]`, the
    /// offset of chain depth `d`'s housing in its link's own frame (depth 0: the root's; depth
    /// `d ≥ 1`: the frame of the link chain joint `d − 1` moves): every link of depth `d` moves
    /// with it. Depths beyond `housings` stay as posed.
    ///
    /// # Panics
    /// If `link_poses` has fewer entries than the model has links.
    pub fn with_housings(
        &self,
        link_poses: &[Isometry3<f64>],
        housings: &[Isometry3<f64>],
    ) -> Vec<Isometry3<f64>> {
        let frames = self.chain_link_frames(link_poses);
        let moves: Vec<Isometry3<f64>> = frames
            .iter()
            .zip(housings)
            .map(|(f, h)| f * h * f.inverse())
            .collect();
        link_poses
            .iter()
            .zip(&self.links)
            .map(|(pose, node)| moves.get(node.chain_depth).map_or(*pose, |m| m * pose))
            .collect()
    }

    /// The axis of each chain joint (unit vector in the joint frame), chain order.
    pub fn joint_axes(&self) -> Vec<Unit<Vector3<f64>>> {
        let mut axes = vec![Vector3::z_axis(); self.dof()];
        for node in &self.links {
            if let Some((i, axis)) = node.motion.chain_joint() {
                axes[i] = axis;
            }
        }
        axes
    }

    fn poses(
        &self,
        q: &[f64],
        errors: Option<&[Isometry3<f64>]>,
    ) -> Result<Vec<Isometry3<f64>>, ModelError> {
        self.check_q(q)?;
        let mut poses = vec![Isometry3::identity(); self.links.len()];
        for &l in &self.order {
            let node = &self.links[l];
            let Some(p) = node.parent else { continue };
            let (motion, chain) = match node.motion {
                Motion::Fixed => (Isometry3::identity(), None),
                Motion::Revolute { axis, q: s } => (
                    Isometry3::from_parts(
                        Translation3::identity(),
                        UnitQuaternion::from_axis_angle(&axis, s.value(q)),
                    ),
                    s.chain_index(),
                ),
                Motion::Prismatic { axis, q: s } => (
                    Isometry3::from_parts(
                        Translation3::from(axis.into_inner() * s.value(q)),
                        UnitQuaternion::identity(),
                    ),
                    s.chain_index(),
                ),
            };
            let error = match (errors, chain) {
                (Some(e), Some(i)) => e[i],
                _ => Isometry3::identity(),
            };
            poses[l] = poses[p] * node.parent_from_joint * error * motion;
        }
        Ok(poses)
    }

    /// `model_from_<frame>` at joint values `q`, for any link name. For UR arms whose URDF lacks
    /// the controller's `base` link, `base` is derived from `base_link`.
    pub fn frame_pose(&self, frame: &str, q: &[f64]) -> Result<Isometry3<f64>, ModelError> {
        if let Some(&l) = self.link_index.get(frame) {
            return Ok(self.link_poses(q)?[l]);
        }
        if frame == "base" && self.ur_model().is_some() {
            if let Some(&l) = self.link_index.get("base_link") {
                let base_link_from_base = crate::frames::ur_base_from_base_link().inverse();
                return Ok(self.link_poses(q)?[l] * base_link_from_base);
            }
        }
        Err(self.unknown_frame(frame))
    }

    fn unknown_frame(&self, frame: &str) -> ModelError {
        let wanted = frame.to_ascii_lowercase();
        let mut scored: Vec<(usize, &str)> = self
            .link_names
            .iter()
            .map(|n| {
                let lower = n.to_ascii_lowercase();
                let d = if lower.contains(&wanted) || wanted.contains(&lower) {
                    0
                } else {
                    edit_distance(&wanted, &lower)
                };
                (d, n.as_str())
            })
            .collect();
        scored.sort();
        let limit = (wanted.len() / 2).max(2);
        let close: Vec<&str> = scored
            .iter()
            .filter(|(d, _)| *d <= limit)
            .take(5)
            .map(|(_, n)| *n)
            .collect();
        let hint = if close.is_empty() {
            format!("the frames are the links: {}", self.link_names.join(", "))
        } else {
            format!("did you mean {}?", close.join(", "))
        };
        ModelError::UnknownFrame {
            name: frame.to_string(),
            robot: self.name.clone(),
            hint,
        }
    }

    /// Geometry of one kind: one entry per link that has any, in link order, vertices in the
    /// link frame.
    pub fn geometry(&self, kind: GeometryKind) -> &[LinkGeometry] {
        match kind {
            GeometryKind::Visual => &self.visual,
            GeometryKind::Collision => &self.collision,
        }
    }

    /// Every geometry of one kind with its `model_from_link` at joint values `q`.
    pub fn posed_geometry(
        &self,
        q: &[f64],
        kind: GeometryKind,
    ) -> Result<Vec<(Isometry3<f64>, &LinkGeometry)>, ModelError> {
        let poses = self.link_poses(q)?;
        Ok(self
            .geometry(kind)
            .iter()
            .map(|g| (poses[self.link_index[&g.link]], g))
            .collect())
    }

    /// The Universal Robots model, detected from the robot name, else the URDF file name
    /// (`ur5e`, `UR10e_robot`, …; whole tokens only).
    pub fn ur_model(&self) -> Option<UrModel> {
        let stem = self
            .urdf_path
            .file_stem()
            .and_then(|s| s.to_str())
            .unwrap_or("");
        detect_ur(&self.name).or_else(|| detect_ur(stem))
    }
}

/// A UR model name appearing in `text` as a whole token (`ur5e`, `my_ur10e_cell`).
fn detect_ur(text: &str) -> Option<UrModel> {
    let lower = text.to_ascii_lowercase();
    let bytes = lower.as_bytes();
    let mut models = UrModel::ALL.to_vec();
    // Longest names first so `ur10e` wins over `ur10`.
    models.sort_by_key(|m| std::cmp::Reverse(m.name().len()));
    models.into_iter().find(|m| {
        lower.match_indices(m.name()).any(|(i, s)| {
            let before = i.checked_sub(1).map(|k| bytes[k]);
            let after = bytes.get(i + s.len()).copied();
            !before.is_some_and(|b| b.is_ascii_alphanumeric())
                && !after.is_some_and(|b| b.is_ascii_alphanumeric())
        })
    })
}

fn edit_distance(a: &str, b: &str) -> usize {
    let b: Vec<char> = b.chars().collect();
    let mut row: Vec<usize> = (0..=b.len()).collect();
    for (i, ca) in a.chars().enumerate() {
        let mut prev = row[0];
        row[0] = i + 1;
        for (j, &cb) in b.iter().enumerate() {
            let cur = row[j + 1];
            row[j + 1] = (prev + usize::from(ca != cb)).min(row[j] + 1).min(cur + 1);
            prev = cur;
        }
    }
    row[b.len()]
}
