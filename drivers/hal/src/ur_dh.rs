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

impl DhParams {
    /// A deterministic pseudo-random calibration delta of the size a UR factory calibration
    /// has (1σ per joint: θ 0.3 mrad, a and d 0.3 mm, α 0.3 mrad), to add to nominal DH with
    /// [`DhParams::plus`]. Simulators use it to model a controller that knows its calibrated
    /// arm; the same `seed` gives the same delta everywhere.
    pub fn factory_calibration_delta(seed: u64) -> DhParams {
        Self::calibration_delta(seed, 3e-4, 3e-4, 3e-4)
    }

    /// [`factory_calibration_delta`](Self::factory_calibration_delta) with other 1σ sizes: θ
    /// `theta_rad`, a and d `length_m`, α `alpha_rad` (zero gives zero; the draws are the same
    /// for every size, so one seed scales).
    pub fn calibration_delta(seed: u64, theta_rad: f64, length_m: f64, alpha_rad: f64) -> DhParams {
        // SplitMix64 + Box–Muller: no dependency, identical on every platform.
        let mut state = seed ^ 0x9e37_79b9_7f4a_7c15;
        let mut uniform = move || {
            state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
            let mut z = state;
            z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
            z ^= z >> 31;
            ((z >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        let mut gauss = move |sigma: f64| {
            let (u1, u2) = (uniform(), uniform());
            sigma * (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
        };
        let mut draw = |sigma: f64| -> [f64; 6] { std::array::from_fn(|_| gauss(sigma)) };
        DhParams {
            theta: draw(theta_rad),
            a: draw(length_m),
            d: draw(length_m),
            alpha: draw(alpha_rad),
        }
    }

    /// These parameters with `delta` added field by field (nominal + calibration delta).
    pub fn plus(&self, delta: &DhParams) -> DhParams {
        let add = |x: &[f64; 6], y: &[f64; 6]| -> [f64; 6] { std::array::from_fn(|i| x[i] + y[i]) };
        DhParams {
            a: add(&self.a, &delta.a),
            d: add(&self.d, &delta.d),
            alpha: add(&self.alpha, &delta.alpha),
            theta: add(&self.theta, &delta.theta),
        }
    }

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

    #[test]
    fn factory_calibration_deltas_are_small_deterministic_and_seeded() {
        let a = DhParams::factory_calibration_delta(7);
        assert_eq!(a, DhParams::factory_calibration_delta(7));
        assert_ne!(a, DhParams::factory_calibration_delta(8));
        for v in a.a.iter().chain(&a.d).chain(&a.theta).chain(&a.alpha) {
            assert!(v.abs() < 2e-3 && *v != 0.0, "{v}");
        }
        let nominal = UrModel::Ur5e.dh();
        let calibrated = nominal.plus(&a);
        let moved = (calibrated.forward(&[0.3; 6]).translation.vector
            - nominal.forward(&[0.3; 6]).translation.vector)
            .norm();
        assert!(moved > 1e-5 && moved < 5e-3, "{moved}");
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
