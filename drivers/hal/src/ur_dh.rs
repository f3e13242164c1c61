//! Nominal Denavit–Hartenberg kinematics of Universal Robots arms (standard DH, metres,
//! radians), from UR's `default_kinematics.yaml` files (see `shared/ref/ur-interfaces.md` §8).
//!
//! These are the kinematics the UR controller uses *before* factory calibration; the URDFs in
//! `shared/robots/ur` are generated from the same numbers. Both the core (to cross-check URDFs)
//! and the UR controller simulator use this one table.

use std::f64::consts::FRAC_PI_2;
use std::fmt;
use std::str::FromStr;

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

/// A Universal Robots arm model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[allow(missing_docs)]
pub enum UrModel {
    Ur3,
    Ur5,
    Ur10,
    Ur3e,
    Ur5e,
    Ur7e,
    Ur10e,
    Ur12e,
    Ur16e,
    Ur15,
    Ur20,
    Ur30,
}

impl UrModel {
    /// Every model in the table.
    pub const ALL: [UrModel; 12] = [
        UrModel::Ur3,
        UrModel::Ur5,
        UrModel::Ur10,
        UrModel::Ur3e,
        UrModel::Ur5e,
        UrModel::Ur7e,
        UrModel::Ur10e,
        UrModel::Ur12e,
        UrModel::Ur16e,
        UrModel::Ur15,
        UrModel::Ur20,
        UrModel::Ur30,
    ];

    /// Lower-case name as used on the command line and in `shared/robots/ur/<name>`.
    pub fn name(self) -> &'static str {
        match self {
            UrModel::Ur3 => "ur3",
            UrModel::Ur5 => "ur5",
            UrModel::Ur10 => "ur10",
            UrModel::Ur3e => "ur3e",
            UrModel::Ur5e => "ur5e",
            UrModel::Ur7e => "ur7e",
            UrModel::Ur10e => "ur10e",
            UrModel::Ur12e => "ur12e",
            UrModel::Ur16e => "ur16e",
            UrModel::Ur15 => "ur15",
            UrModel::Ur20 => "ur20",
            UrModel::Ur30 => "ur30",
        }
    }

    /// The name a controller answers to dashboard `get robot model` for this arm: the family
    /// in upper case without the e-Series `e` (`UR5` for a UR5 and a UR5e).
    pub fn controller_name(self) -> String {
        self.name().trim_end_matches('e').to_ascii_uppercase()
    }

    /// Whether a controller that names its arm `reported` (dashboard `get robot model`) can be
    /// this model: the same family, with or without the `e` (`UR5`, `UR5e` and `ur5e` all fit
    /// a UR5e; only the kinematics tell a UR5 from a UR5e).
    pub fn fits_reported_name(self, reported: &str) -> bool {
        let family = reported.trim().trim_end_matches(['e', 'E']);
        family.eq_ignore_ascii_case(&self.controller_name())
    }

    /// Whether this is a CB3-generation arm (UR3, UR5, UR10) rather than e-Series or newer.
    pub fn is_cb3(self) -> bool {
        matches!(self, UrModel::Ur3 | UrModel::Ur5 | UrModel::Ur10)
    }

    /// Nominal DH parameters of this model.
    pub fn dh(self) -> DhParams {
        // (d1, a2, a3, d4, d5, d6)
        let (d1, a2, a3, d4, d5, d6) = match self {
            UrModel::Ur3 => (0.1519, -0.24365, -0.21325, 0.11235, 0.08535, 0.0819),
            UrModel::Ur5 => (0.089159, -0.425, -0.39225, 0.10915, 0.09465, 0.0823),
            UrModel::Ur10 => (0.1273, -0.612, -0.5723, 0.163941, 0.1157, 0.0922),
            UrModel::Ur3e => (0.15185, -0.24355, -0.2132, 0.13105, 0.08535, 0.0921),
            UrModel::Ur5e | UrModel::Ur7e => (0.1625, -0.425, -0.3922, 0.1333, 0.0997, 0.0996),
            UrModel::Ur10e | UrModel::Ur12e => {
                (0.1807, -0.6127, -0.57155, 0.17415, 0.11985, 0.11655)
            }
            UrModel::Ur16e => (0.1807, -0.4784, -0.36, 0.17415, 0.11985, 0.11655),
            UrModel::Ur15 => (0.2186, -0.6475, -0.5164, 0.1824, 0.1361, 0.1434),
            UrModel::Ur20 => (0.2363, -0.862, -0.7287, 0.201, 0.1593, 0.1543),
            UrModel::Ur30 => (0.2363, -0.637, -0.5037, 0.201, 0.1593, 0.1543),
        };
        DhParams {
            a: [0.0, a2, a3, 0.0, 0.0, 0.0],
            d: [d1, 0.0, 0.0, d4, d5, d6],
            alpha: [FRAC_PI_2, 0.0, 0.0, FRAC_PI_2, -FRAC_PI_2, 0.0],
            theta: [0.0; 6],
        }
    }
}

#[cfg(test)]
mod name_tests {
    use super::*;

    #[test]
    fn reported_names_fit_their_family_only() {
        assert_eq!(UrModel::Ur5e.controller_name(), "UR5");
        assert_eq!(UrModel::Ur16e.controller_name(), "UR16");
        assert_eq!(UrModel::Ur30.controller_name(), "UR30");
        for name in ["UR5", "UR5e", "ur5e", " UR5 "] {
            assert!(UrModel::Ur5e.fits_reported_name(name), "{name}");
            assert!(UrModel::Ur5.fits_reported_name(name), "{name}");
        }
        assert!(!UrModel::Ur10e.fits_reported_name("UR5"));
        assert!(!UrModel::Ur5e.fits_reported_name("UR15"));
        assert!(!UrModel::Ur3.fits_reported_name("UR30"));
        assert!(!UrModel::Ur5e.fits_reported_name(""));
    }
}

impl UrModel {
    /// The models whose nominal kinematics `dh` (a controller's published DH) can be a
    /// calibration of, nearest first: the flange at a few joint configurations within
    /// [`MAX_CALIBRATION_FLANGE_M`] of the model's nominal flange (a calibration moves it by
    /// millimetres; another model by tens of centimetres). Models with the same nominal DH (UR5e
    /// and UR7e, UR10e and UR12e) both match.
    pub fn matching(dh: &DhParams) -> Vec<(UrModel, f64)> {
        let mut out: Vec<(UrModel, f64)> = UrModel::ALL
            .into_iter()
            .map(|m| (m, m.dh().flange_distance(dh)))
            .filter(|(_, d)| *d <= MAX_CALIBRATION_FLANGE_M)
            .collect();
        out.sort_by(|a, b| a.1.total_cmp(&b.1));
        out
    }
}

/// Farthest a calibration moves a UR's flange from the nominal kinematics', metres.
pub const MAX_CALIBRATION_FLANGE_M: f64 = 0.02;

impl fmt::Display for UrModel {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// An unknown model name.
#[derive(Debug, Clone, thiserror::Error)]
#[error("unknown UR model `{0}`; expected one of ur3, ur5, ur10, ur3e, ur5e, ur7e, ur10e, ur12e, ur16e, ur15, ur20, ur30")]
pub struct UnknownModel(pub String);

impl FromStr for UrModel {
    type Err = UnknownModel;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let lower = s.trim().to_ascii_lowercase();
        UrModel::ALL
            .into_iter()
            .find(|m| m.name() == lower)
            .ok_or_else(|| UnknownModel(s.to_string()))
    }
}

/// Standard DH parameters for a 6-joint arm: `T_i = Rz(θ_i + q_i)·Tz(d_i)·Tx(a_i)·Rx(α_i)`.
///
/// `theta` holds joint offsets (zero nominally; factory calibration makes them small non-zero
/// values, as do the other fields).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct DhParams {
    /// Link lengths along x_i, metres.
    pub a: [f64; 6],
    /// Offsets along z_{i-1}, metres.
    pub d: [f64; 6],
    /// Link twists about x_i, radians.
    pub alpha: [f64; 6],
    /// Joint-angle offsets, radians.
    pub theta: [f64; 6],
}

/// The kinematics a robot controller reports for its own arm (UR: the primary interface's
/// KinematicsInfo, robot-state sub-package 5): the factory-calibrated DH set the controller
/// uses for `actual_TCP_pose`, `get_forward_kin` and every pose it reports.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ControllerKinematics {
    /// The controller's DH parameters (absolute values, not deltas), UR `base` frame.
    pub dh: DhParams,
    /// Per-joint checksums the controller publishes.
    pub checksum: [u32; 6],
    /// Whether the controller says the arm is factory calibrated (calibration_status).
    pub calibrated: bool,
}

impl ControllerKinematics {
    /// Whether every DH value is finite (a controller never sends NaN; a corrupt package might).
    pub fn is_finite(&self) -> bool {
        let d = &self.dh;
        d.a.iter()
            .chain(&d.d)
            .chain(&d.alpha)
            .chain(&d.theta)
            .all(|v| v.is_finite())
    }
}

/// A seeded stream of standard normal draws: SplitMix64 + Box–Muller, no dependency,
/// identical on every platform (the same seed gives the same arm everywhere).
fn gaussian_stream(seed: u64) -> impl FnMut() -> f64 {
    let mut state = seed ^ 0x9e37_79b9_7f4a_7c15;
    let mut uniform = move || {
        state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^= z >> 31;
        ((z >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    };
    move || {
        let (u1, u2) = (uniform(), uniform());
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    }
}

impl DhParams {
    /// `base_from_link_i` for i = 1..=6 (frame 6 is UR's flange/`tool0` with zero TCP),
    /// in UR's `base` frame (URDF `base_link` turned by π about z).
    pub fn link_poses(&self, q: &[f64; 6]) -> [Isometry3<f64>; 6] {
        let mut t = Isometry3::identity();
        let mut out = [Isometry3::identity(); 6];
        for i in 0..6 {
            t *= Self::joint_transform(self.theta[i] + q[i], self.d[i], self.a[i], self.alpha[i]);
            out[i] = t;
        }
        out
    }

    /// The largest distance between this set's flange and `other`'s over
    /// [`SPANNING_JOINTS`], metres.
    pub fn flange_distance(&self, other: &DhParams) -> f64 {
        SPANNING_JOINTS
            .iter()
            .map(|q| {
                (self.forward(q).translation.vector - other.forward(q).translation.vector).norm()
            })
            .fold(0.0, f64::max)
    }

    /// `base_from_flange` (UR `base` frame, zero TCP offset) at joint angles `q`.
    pub fn forward(&self, q: &[f64; 6]) -> Isometry3<f64> {
        self.link_poses(q)[5]
    }

    fn joint_transform(theta: f64, d: f64, a: f64, alpha: f64) -> Isometry3<f64> {
        let rz = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), theta);
        let rx = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), alpha);
        // Rz(θ)·Tz(d)·Tx(a)·Rx(α) = translation Rz(θ)·(a, 0, d), rotation Rz(θ)·Rx(α).
        let t = rz * Vector3::new(a, 0.0, d);
        Isometry3::from_parts(Translation3::from(t), rz * rx)
    }
}

/// 1σ sizes of a physical arm's per-joint errors (see [`PhysicalArm`]).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct JointErrorSizes {
    /// Rotation of each joint about its own axis (zero offset), radians.
    pub zero_offset_rad: f64,
    /// Displacement of each joint along each of three axes, metres.
    pub translation_m: f64,
    /// Rotation of each joint's axis about each of the two directions perpendicular to it,
    /// radians.
    pub misalignment_rad: f64,
    /// Displacement of each link's housing (its casting and covers, what a camera sees) from
    /// the link's kinematic frame along each of three axes, metres.
    #[serde(default)]
    pub housing_translation_m: f64,
    /// Rotation of each link's housing about each of three axes through its frame's origin,
    /// radians.
    #[serde(default)]
    pub housing_rotation_rad: f64,
}

impl JointErrorSizes {
    /// A manufactured UR arm: what its factory calibration finds (0.3 mrad and 0.3 mm per
    /// joint and axis), and housings off their links' frames by the same sizes (castings
    /// machined and covers assembled to a few tenths of a millimetre; no controller knows them).
    pub const FACTORY: JointErrorSizes = JointErrorSizes {
        zero_offset_rad: 3e-4,
        translation_m: 3e-4,
        misalignment_rad: 3e-4,
        housing_translation_m: 3e-4,
        housing_rotation_rad: 3e-4,
    };
}

/// A physical UR arm: the nominal DH chain with a small rigid error at every joint, as a real
/// arm is built. Joint `k`'s error `E_k` sits between DH frame `k − 1` and the joint's
/// rotation: `F_k(q) = F_{k−1}(q) · E_k · Rz(θ_k + q_k) · Tz(d_k) · Tx(a_k) · Rx(α_k)` with the
/// nominal `θ, d, a, α`, so link `k` is rigid with `F_k` and turns about the `z` axis of
/// `F_{k−1} · E_k`. Joint 1's error is only a turn about and a shift along its axis: a
/// controller's base frame is joint 1's axis by construction (standard DH), so the axis' tilt
/// and offset belong to the base frame, not to the arm. Joints 2–6 take a general 6-DOF error.
///
/// The controller of such an arm publishes [`PhysicalArm::controller_dh`]: the exact standard
/// DH set of its axes, whose forward kinematics are the physical flange; with nearly parallel
/// joints 2–4 it has huge compensating `d` and `θ`, as every real UR's has.
///
/// What a camera sees of link `k` (chain depth `k`, 0 the base) is its housing, which sits off
/// the link's kinematic frame by a small rigid `housings[k]`, expressed in the link's own frame
/// (the robot description's link frame: its origin on the joint that moves it, the base's at
/// the foot of joint 1's axis). The base housing off joint 1's axis is one of them. Neither the
/// controller's DH nor its flange poses know these: they change what a scan shows, not what
/// the controller reports.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PhysicalArm {
    /// The DH set the arm was built to.
    pub nominal: DhParams,
    /// `E_k` per joint, in DH frame `k − 1` (metres, radians).
    pub joint_errors: [Isometry3<f64>; 6],
    /// `link_from_housing` per chain depth 0..=6 (base, the six moving links).
    pub housings: [Isometry3<f64>; 7],
}

impl PhysicalArm {
    /// The arm built exactly to `nominal`.
    pub fn exact(nominal: DhParams) -> Self {
        Self {
            nominal,
            joint_errors: [Isometry3::identity(); 6],
            housings: [Isometry3::identity(); 7],
        }
    }

    /// A deterministic pseudo-random arm with joint errors of the 1σ `sizes`; the same `seed`
    /// gives the same arm everywhere (simulators of the controller, the camera and the
    /// benchmark agree on it).
    pub fn draw(nominal: DhParams, sizes: &JointErrorSizes, seed: u64) -> Self {
        let mut gauss = gaussian_stream(seed);
        let joint_errors = std::array::from_fn(|k| {
            let mut g = [0.0; 6];
            g.iter_mut().for_each(|v| *v = gauss());
            let (rotation, translation) = if k == 0 {
                (
                    Vector3::new(0.0, 0.0, g[2] * sizes.zero_offset_rad),
                    Vector3::new(0.0, 0.0, g[5] * sizes.translation_m),
                )
            } else {
                (
                    Vector3::new(
                        g[0] * sizes.misalignment_rad,
                        g[1] * sizes.misalignment_rad,
                        g[2] * sizes.zero_offset_rad,
                    ),
                    Vector3::new(g[3], g[4], g[5]) * sizes.translation_m,
                )
            };
            Isometry3::from_parts(
                Translation3::from(translation),
                UnitQuaternion::from_scaled_axis(rotation),
            )
        });
        // Their own stream: the joints (and so the controller's DH) of a seed stay what they
        // were without housings.
        let mut gauss = gaussian_stream(seed ^ HOUSING_SEED);
        let housings = std::array::from_fn(|_| {
            let mut g = [0.0; 6];
            g.iter_mut().for_each(|v| *v = gauss());
            Isometry3::new(
                Vector3::new(g[0], g[1], g[2]) * sizes.housing_translation_m,
                Vector3::new(g[3], g[4], g[5]) * sizes.housing_rotation_rad,
            )
        });
        Self {
            nominal,
            joint_errors,
            housings,
        }
    }

    /// [`draw`](Self::draw) for `model` with [`JointErrorSizes::FACTORY`]: a factory-calibrated
    /// arm, as the simulators' `--factory-calibration SEED` builds it.
    pub fn factory(model: UrModel, seed: u64) -> Self {
        Self::draw(model.dh(), &JointErrorSizes::FACTORY, seed)
    }

    /// `base_from_frame_k` for k = 0..=6 at joints `q` (rad): frame 0 is the base (identity),
    /// frame `k` is rigid with link `k`, frame 6 is the flange (zero TCP).
    pub fn frames(&self, q: &[f64; 6]) -> [Isometry3<f64>; 7] {
        let n = &self.nominal;
        let mut out = [Isometry3::identity(); 7];
        for k in 0..6 {
            out[k + 1] = out[k]
                * self.joint_errors[k]
                * DhParams::joint_transform(n.theta[k] + q[k], n.d[k], n.a[k], n.alpha[k]);
        }
        out
    }

    /// `base_from_flange` at joints `q` (rad): what the controller reports (zero TCP).
    pub fn flange(&self, q: &[f64; 6]) -> Isometry3<f64> {
        self.frames(q)[6]
    }

    /// The standard DH set a controller computes for this arm ([`DhParams::from_axes`] of its
    /// joint axes and flange at zero joints): its forward kinematics are
    /// [`flange`](Self::flange) at every `q`.
    pub fn controller_dh(&self) -> DhParams {
        let zero = [0.0; 6];
        let frames = self.frames(&zero);
        let axes: [Line; 6] = std::array::from_fn(|k| {
            let joint = frames[k] * self.joint_errors[k];
            Line {
                point: joint.translation.vector,
                direction: joint.rotation * Vector3::z(),
            }
        });
        DhParams::from_axes(&axes, &frames[6], &self.nominal)
    }
}

/// Mixed into a seed for its housings' draws ([`PhysicalArm::draw`], the scan simulator's
/// arms without a DH set), so a seed's other draws stay what they were without housings.
pub const HOUSING_SEED: u64 = 0x686f_7573_696e_6773;

/// A directed line: a joint axis (metres; unit direction, the sense the joint turns about).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Line {
    /// A point on the line.
    pub point: Vector3<f64>,
    /// Unit direction.
    pub direction: Vector3<f64>,
}

impl Line {
    /// The point of the line nearest `p`.
    pub fn nearest(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.point + self.direction * (p - self.point).dot(&self.direction)
    }

    /// Parameters `(s, t)` of the common normal's feet, `self.point + s·self.direction` and
    /// `other.point + t·other.direction`; `None` when the lines are parallel to rounding.
    fn common_normal(&self, other: &Line) -> Option<(f64, f64)> {
        let (u, v) = (self.direction, other.direction);
        let w = u.cross(&v);
        let n2 = w.norm_squared();
        if n2 < 1e-24 {
            return None;
        }
        let r = other.point - self.point;
        Some((r.cross(&v).dot(&w) / n2, r.cross(&u).dot(&w) / n2))
    }
}

/// Below this sine of the angle between two joint axes they are taken as parallel (UR joints
/// 2–4, a few mrad apart on a real arm) rather than crossing (the others, at right angles).
pub const PARALLEL_SINE: f64 = 0.1;

/// A frame on `own` (z along it) whose x points to `next`: at the common normal's foot with
/// x along it when the axes cross at an angle; when they are nearly parallel, at the point of
/// `own` nearest `reference`, x towards `next` (the common normal of nearly parallel axes is
/// far away, and where along them the link sits is not in the axes).
fn axis_frame(own: &Line, next: &Line, reference: &Vector3<f64>) -> Isometry3<f64> {
    let z = own.direction;
    let (origin, x) = match own.common_normal(next) {
        Some((s, _)) if z.cross(&next.direction).norm() > PARALLEL_SINE => {
            (own.point + z * s, z.cross(&next.direction))
        }
        _ => {
            let o = own.nearest(reference);
            let v = next.nearest(&o) - o;
            (o, v - z * v.dot(&z))
        }
    };
    let x = x.normalize();
    let rotation = nalgebra::Rotation3::from_basis_unchecked(&[x, z.cross(&x), z]);
    Isometry3::from_parts(
        Translation3::from(origin),
        UnitQuaternion::from_rotation_matrix(&rotation),
    )
}

impl DhParams {
    /// The exact standard DH set of an arm given its six joint axes (`axes[k]` for joint
    /// `k + 1`, base frame, at zero joints, directed the way each joint turns) and its flange
    /// (`base_from_flange` at zero joints: z along joint 6's axis, origin on it): how a
    /// controller computes the kinematics of its calibrated arm. Joint 1's axis must be the
    /// base's z axis (standard DH's frame 0). Frame `k` has z on joint `k + 1`'s axis and x
    /// along the common normal from joint `k`'s; where two axes are exactly parallel (a
    /// nominal arm), the normal is taken through the previous frame's origin. Of the two senses
    /// of each normal, the one closer to `nominal`'s x axis is taken, so an exact arm gives
    /// back `nominal`. Nearly parallel axes give huge compensating `d` and `θ` (a real UR10e:
    /// d₂ = 439 m, d₃ = −446 m): the forward kinematics stay exact.
    pub fn from_axes(
        axes: &[Line; 6],
        base_from_flange: &Isometry3<f64>,
        nominal: &DhParams,
    ) -> Self {
        let reference = nominal.link_poses(&[0.0; 6]);
        let mut dh = DhParams {
            a: [0.0; 6],
            d: [0.0; 6],
            alpha: [0.0; 6],
            theta: [0.0; 6],
        };
        let (mut origin, mut x, mut z) = (Vector3::zeros(), Vector3::x(), Vector3::z());
        for i in 0..6 {
            let previous = Line {
                point: origin,
                direction: z,
            };
            let (foot, next_origin, next_x, next_z) = if i == 5 {
                let o = base_from_flange.translation.vector;
                let x6 = base_from_flange.rotation * Vector3::x();
                (
                    previous.nearest(&o),
                    o,
                    x6,
                    base_from_flange.rotation * Vector3::z(),
                )
            } else {
                let next = &axes[i + 1];
                let want = reference[i].rotation * Vector3::x();
                match previous.common_normal(next) {
                    Some((s, t)) => {
                        let w = z.cross(&next.direction).normalize();
                        let w = if w.dot(&want) < 0.0 { -w } else { w };
                        (
                            origin + z * s,
                            next.point + next.direction * t,
                            w,
                            next.direction,
                        )
                    }
                    None => {
                        let on_next = next.nearest(&origin);
                        let v = on_next - origin;
                        let w = v - z * v.dot(&z);
                        let w = match w.try_normalize(1e-12) {
                            Some(w) if w.dot(&want) < 0.0 => -w,
                            Some(w) => w,
                            None => want - z * want.dot(&z),
                        };
                        (origin, on_next, w, next.direction)
                    }
                }
            };
            dh.d[i] = (foot - origin).dot(&z);
            dh.a[i] = (next_origin - foot).dot(&next_x);
            dh.theta[i] = x.cross(&next_x).dot(&z).atan2(x.dot(&next_x));
            dh.alpha[i] = z.cross(&next_z).dot(&next_x).atan2(z.dot(&next_z));
            (origin, x, z) = (next_origin, next_x, next_z);
        }
        dh
    }

    /// Frames rigid with the links of the arm this DH set describes, placed where the
    /// physical links are as far as the axes tell (`base_from_frame_k`, k = 0..=6, frame 0 the
    /// base, frame 6 the flange; `nominal`'s DH frames for `nominal` itself). Each link `k`
    /// lies on its joint axis: where two consecutive axes cross, at the common normal's foot,
    /// turned towards the next axis; where they are nearly parallel (UR joints 2–4, whose DH
    /// frames a real controller places hundreds of metres away), at the point of its axis
    /// nearest where the nominal arm has it, turned towards the next axis (as ur_calibration's
    /// correctChain does). The flange's link is rigid with the flange.
    ///
    /// What the axes cannot tell is left to the caller: each link may sit a little further
    /// along, and turned a little about, its own axis (a joint's displacement is the same axes
    /// as the next joint's), most of all along the common direction of nearly parallel joints.
    pub fn link_frames(&self, nominal: &DhParams, q: &[f64; 6]) -> [Isometry3<f64>; 7] {
        let poses = self.link_poses(q);
        let reference = nominal.link_poses(q);
        let (calibrated, nominal_axes) = (axes_of(&poses), axes_of(&reference));
        let mut out = [Isometry3::identity(); 7];
        for k in 1..6 {
            let at = nominal_axes[k - 1].point;
            let nominal_frame = axis_frame(&nominal_axes[k - 1], &nominal_axes[k], &at);
            let frame = axis_frame(&calibrated[k - 1], &calibrated[k], &at);
            out[k] = frame * nominal_frame.inverse() * reference[k - 1];
        }
        out[6] = poses[5];
        out
    }

    /// A kinematic chain equivalent to this DH set at zero joints whose frames stay near the
    /// arm: `parent_from_joint_k` for k = 1..=6 such that the flange is
    /// `E_1·Rz(q_1)·E_2·Rz(q_2)···E_6·Rz(q_6)`. Joint `k`'s frame has z on its axis where
    /// [`link_frames`](Self::link_frames) puts the link (at the common normal of crossing axes,
    /// nearest the `nominal` joint along parallel ones), x towards the next axis in the sense of
    /// the DH frame after it; joint 6's is the flange. For `nominal` itself these are the DH
    /// steps `Tx(a)·Rx(α)·Tz(d)·Rz(θ)`, the file ur_description ships. This is what ur_calibration's correctChain
    /// makes of a controller's DH (no entry hundreds of metres long), and
    /// [`from_axes`](Self::from_axes) reads it back.
    pub fn near_chain(&self, nominal: &DhParams) -> [Isometry3<f64>; 6] {
        let zero = [0.0; 6];
        let (axes, nominal_axes) = (self.axes(&zero), nominal.axes(&zero));
        let links = self.link_frames(nominal, &zero);
        let mut frames = [Isometry3::identity(); 6];
        for k in 0..5 {
            let frame = axis_frame(&axes[k], &axes[k + 1], &nominal_axes[k].point);
            // The x sense of the DH frame after the joint (a UR's a₂, a₃ are negative).
            let hint = links[k + 1].rotation * Vector3::x();
            frames[k] = if (frame.rotation * Vector3::x()).dot(&hint) < 0.0 {
                frame * UnitQuaternion::from_axis_angle(&Vector3::z_axis(), std::f64::consts::PI)
            } else {
                frame
            };
        }
        frames[5] = links[6];
        std::array::from_fn(|k| {
            if k == 0 {
                frames[0]
            } else {
                frames[k - 1].inverse() * frames[k]
            }
        })
    }

    /// The six joint axes at joints `q` (rad), base frame: joint `k + 1` turns about the z axis
    /// of DH frame `k`.
    pub fn axes(&self, q: &[f64; 6]) -> [Line; 6] {
        axes_of(&self.link_poses(q))
    }
}

/// The six joint axes of the DH frames `link_poses` (frames 1–6; joint 1 turns about the
/// base's z axis).
fn axes_of(link_poses: &[Isometry3<f64>; 6]) -> [Line; 6] {
    std::array::from_fn(|k| {
        let f = if k == 0 {
            Isometry3::identity()
        } else {
            link_poses[k - 1]
        };
        Line {
            point: f.translation.vector,
            direction: f.rotation * Vector3::z(),
        }
    })
}

/// A few joint configurations spanning a UR's workspace (rad).
pub const SPANNING_JOINTS: [[f64; 6]; 4] = [
    [0.0; 6],
    [0.4, -1.2, 1.1, -1.3, -1.5, 0.2],
    [-2.0, -0.3, -2.1, 0.7, 1.9, -3.0],
    [3.0, -2.6, 0.4, -2.2, 0.3, 1.0],
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ur5e_zero_pose_matches_the_published_check_vector() {
        let t = UrModel::Ur5e.dh().forward(&[0.0; 6]);
        let p = t.translation.vector;
        assert!(
            (p - Vector3::new(-0.8172, -0.2329, 0.0628)).norm() < 1e-9,
            "{p}"
        );
        let expected = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), FRAC_PI_2);
        assert!(t.rotation.angle_to(&expected) < 1e-9);
    }

    #[test]
    fn every_model_follows_the_closed_form_zero_pose() {
        for m in UrModel::ALL {
            let dh = m.dh();
            let p = dh.forward(&[0.0; 6]).translation.vector;
            let want = Vector3::new(dh.a[1] + dh.a[2], -(dh.d[3] + dh.d[5]), dh.d[0] - dh.d[4]);
            assert!((p - want).norm() < 1e-12, "{m}: {p} vs {want}");
        }
    }

    /// ur_calibration's documentation (`ur_calibration/doc/algorithm.rst`): a real arm's
    /// published DH, joints 2 and 3 placed 439 m and 446 m off along their nearly parallel axes.
    /// The documentation calls it a UR10; its d₁, a₃, d₅ and d₆ are a UR10e's.
    fn documented_ur10() -> DhParams {
        DhParams {
            theta: [
                -2.4147806894359e-07,
                1.60233952386695,
                -1.68607190752171,
                0.0837331147700119,
                -1.01260355871158e-07,
                3.91986209186124e-08,
            ],
            a: [
                2.12234865571206e-05,
                0.0193171326277006,
                -0.569251663611088,
                -4.61409023720934e-05,
                -6.39280053471802e-05,
                0.0,
            ],
            d: [
                0.180539811714259,
                439.140974079901,
                -446.027059806332,
                7.0603368964236,
                0.119811341150314,
                0.115670917257426,
            ],
            alpha: [
                1.57014608044242,
                0.0013941666682559,
                0.00693818880325995,
                1.56998468543761,
                -1.57038520649543,
                0.0,
            ],
        }
    }

    #[test]
    fn an_exact_arm_has_its_nominal_dh() {
        for m in UrModel::ALL {
            let dh = PhysicalArm::exact(m.dh()).controller_dh();
            let nominal = m.dh();
            for (got, want) in [
                (dh.a, nominal.a),
                (dh.d, nominal.d),
                (dh.alpha, nominal.alpha),
                (dh.theta, nominal.theta),
            ] {
                for (g, w) in got.iter().zip(&want) {
                    assert!((g - w).abs() < 1e-12, "{m}: {got:?} vs {want:?}");
                }
            }
            for q in SPANNING_JOINTS {
                for (f, n) in dh
                    .link_frames(&nominal, &q)
                    .iter()
                    .zip(std::iter::once(Isometry3::identity()).chain(nominal.link_poses(&q)))
                {
                    assert!((f.translation.vector - n.translation.vector).norm() < 1e-12);
                    assert!(f.rotation.angle_to(&n.rotation) < 1e-12);
                }
            }
        }
    }

    #[test]
    fn housings_are_drawn_apart_from_the_joints_at_their_sizes() {
        let bare = JointErrorSizes {
            housing_translation_m: 0.0,
            housing_rotation_rad: 0.0,
            ..JointErrorSizes::FACTORY
        };
        let (mut t2, mut r2, mut n) = (0.0, 0.0, 0.0);
        for seed in 0..200 {
            let arm = PhysicalArm::factory(UrModel::Ur5e, seed);
            let without = PhysicalArm::draw(UrModel::Ur5e.dh(), &bare, seed);
            // The housings change what a camera sees, not the joints or what the controller
            // publishes.
            assert_eq!(arm.joint_errors, without.joint_errors);
            assert_eq!(arm.controller_dh(), without.controller_dh());
            assert!(without.housings.iter().all(|h| *h == Isometry3::identity()));
            for h in &arm.housings {
                t2 += h.translation.vector.norm_squared();
                r2 += h.rotation.scaled_axis().norm_squared();
                n += 3.0;
            }
        }
        let (t, r) = ((t2 / n).sqrt(), (r2 / n).sqrt());
        assert!((t - 3e-4).abs() < 0.2e-4, "housing shift {t} m per axis");
        assert!((r - 3e-4).abs() < 0.2e-4, "housing turn {r} rad per axis");
    }

    #[test]
    fn a_physical_arm_publishes_parallel_axis_dh_whose_kinematics_are_exact() {
        let mut huge = 0;
        for m in UrModel::ALL {
            for seed in 0..8 {
                let arm = PhysicalArm::factory(m, seed);
                assert_eq!(arm, PhysicalArm::factory(m, seed));
                let dh = arm.controller_dh();
                if dh.d[1].abs() > 10.0 {
                    huge += 1;
                }
                for q in SPANNING_JOINTS {
                    let (got, want) = (dh.forward(&q), arm.flange(&q));
                    let dt = (got.translation.vector - want.translation.vector).norm();
                    assert!(dt < 1e-9, "{m} seed {seed}: {dt} m, d = {:?}", dh.d);
                    assert!(got.rotation.angle_to(&want.rotation) < 1e-9);
                }
            }
        }
        // Tilts of 0.3 mrad make the common normals of joints 2–4 tens to thousands of metres
        // long on almost every arm.
        assert!(huge > 80, "{huge} of 96 arms with |d2| > 10 m");
    }

    #[test]
    fn the_documented_ur10_links_sit_near_their_nominal_places() {
        let (real, nominal) = (documented_ur10(), UrModel::Ur10e.dh());
        for q in SPANNING_JOINTS {
            let frames = real.link_frames(&nominal, &q);
            assert!(
                (frames[6].translation.vector - real.forward(&q).translation.vector).norm() < 1e-12
            );
            for (k, (f, n)) in frames
                .iter()
                .skip(1)
                .zip(nominal.link_poses(&q))
                .enumerate()
            {
                let off = (f.translation.vector - n.translation.vector).norm();
                let turn = f.rotation.angle_to(&n.rotation);
                // The arm's axes 3 and 4 are 7 mrad apart (α₃): the wrist turns by as much.
                assert!(
                    off < 5e-3 && turn < 1e-2,
                    "link {}: {off} m, {turn} rad",
                    k + 1
                );
            }
        }
    }

    /// Where the axes put each link against where the physical arm has it: on the same axis
    /// to rounding, turned about and slid along it by no more than its neighbours' errors
    /// allow.
    #[test]
    fn links_posed_by_the_published_dh_sit_on_the_physical_axes() {
        let mut worst_slide = [0.0f64; 6];
        let mut worst_turn = [0.0f64; 6];
        for m in UrModel::ALL {
            for seed in 0..6 {
                let arm = PhysicalArm::factory(m, 100 + seed);
                let dh = arm.controller_dh();
                for q in SPANNING_JOINTS {
                    let physical = arm.frames(&q);
                    let posed = dh.link_frames(&m.dh(), &q);
                    let axes = dh.axes(&q);
                    for k in 1..=6 {
                        let d = posed[k] * physical[k].inverse();
                        let (w, t) = (d.rotation.scaled_axis(), d.translation.vector);
                        if k == 6 {
                            assert!(t.norm() < 1e-9 && w.norm() < 1e-9, "flange {t} {w}");
                            continue;
                        }
                        let axis = &axes[k - 1];
                        let u = axis.direction;
                        // A screw about the axis: the turn is about u, a point on the axis
                        // stays on it.
                        assert!(w.cross(&u).norm() < 1e-9, "{m} link {k}: turn {w}");
                        let p = axis.nearest(&physical[k].translation.vector);
                        let moved = d * nalgebra::Point3::from(p);
                        assert!((axis.nearest(&moved.coords) - moved.coords).norm() < 1e-9);
                        worst_slide[k - 1] = worst_slide[k - 1].max((moved.coords - p).norm());
                        worst_turn[k - 1] = worst_turn[k - 1].max(w.norm());
                    }
                }
            }
        }
        // 0.3 mm / 0.3 mrad 1σ per joint: a few σ at most over 72 arms.
        for k in 0..5 {
            assert!(
                worst_slide[k] < 2e-3,
                "link {}: slide {}",
                k + 1,
                worst_slide[k]
            );
            assert!(
                worst_turn[k] < 6e-3,
                "link {}: turn {}",
                k + 1,
                worst_turn[k]
            );
        }
    }

    #[test]
    fn a_controllers_dh_names_its_model() {
        for m in UrModel::ALL {
            let dh = PhysicalArm::factory(m, 11).controller_dh();
            let found = UrModel::matching(&dh);
            assert!(found.iter().any(|(f, _)| *f == m), "{m}: {found:?}");
            // Only models with the same nominal DH match too.
            assert!(
                found.iter().all(|(f, _)| f.dh() == m.dh()),
                "{m}: {found:?}"
            );
        }
        assert!(UrModel::matching(&documented_ur10())
            .iter()
            .any(|(m, _)| *m == UrModel::Ur10e));
    }

    #[test]
    fn model_names_round_trip_and_reject_unknown() {
        for m in UrModel::ALL {
            assert_eq!(m.name().parse::<UrModel>().ok(), Some(m));
        }
        assert!("UR5E".parse::<UrModel>().is_ok());
        let err = "ur99".parse::<UrModel>().expect_err("unknown");
        assert!(err.to_string().contains("ur99"));
    }
}
