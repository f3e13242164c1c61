//! What a real arm's joint readings leave out: the encoders' own error and the links' sag
//! under gravity. The controller reports joint angles and computes its flange pose from them;
//! the physical arm stands elsewhere by
//!
//! - **the encoder error** of each joint: a periodic function of the joint's angle (the
//!   eccentricity and interpolation errors of an angle encoder repeat once and twice per
//!   turn), the same at the same angle, different at another — so two views of one arm are off
//!   by different amounts, and the same pose is off by the same amount each time (it does not
//!   show in the arm's repeatability);
//! - **the sag** under gravity that no controller's DH models (links bending, the part of the
//!   joints' compliance the output encoders do not see): each joint turns in the direction of
//!   the gravity torque about its axis, in proportion to its moment arm to the flange.
//!
//! Both are pose-dependent errors of the reported flange pose. The simulators render the arm
//! at [`physical_joints`] while the controller reports the joints it was given; the solver
//! carries them as the flange pose's covariance ([`flange_covariance`]).

use nalgebra::{Matrix6, Vector3, Vector6};
use rand::SeedableRng;

use super::RobotModel;

/// Seed of the encoder errors' own random stream (xor'ed with an arm's seed).
pub const READING_SEED: u64 = 0x656e_636f_6465_7273;

/// One joint's encoder error: `a₁ sin(q + φ₁) + a₂ sin(2q + φ₂)`, radians.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Harmonics {
    a1: f64,
    phi1: f64,
    a2: f64,
    phi2: f64,
}

/// The encoder errors of one arm's joints (see the module's doc).
#[derive(Debug, Clone, PartialEq)]
pub struct EncoderErrors {
    joints: Vec<Harmonics>,
}

impl EncoderErrors {
    /// The encoders of an arm with `dof` joints whose errors have a standard deviation of
    /// `sigma_rad` over all angles (each of the two harmonics carries half the variance);
    /// the same `seed` gives the same encoders.
    pub fn draw(dof: usize, sigma_rad: f64, seed: u64) -> Self {
        use rand::Rng;
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed ^ READING_SEED);
        // A sine of amplitude a has variance a²/2: two of amplitude σ give σ².
        let joints = (0..dof)
            .map(|_| Harmonics {
                a1: sigma_rad * rng.random_range(0.6..1.4),
                phi1: rng.random_range(0.0..std::f64::consts::TAU),
                a2: sigma_rad * rng.random_range(0.6..1.4),
                phi2: rng.random_range(0.0..std::f64::consts::TAU),
            })
            .collect();
        Self { joints }
    }

    /// Encoders without error.
    pub fn none(dof: usize) -> Self {
        Self::draw(dof, 0.0, 0)
    }

    /// The error of each reading at joint angles `q` (reading − physical), radians.
    pub fn at(&self, q: &[f64]) -> Vec<f64> {
        q.iter()
            .zip(&self.joints)
            .map(|(q, h)| h.a1 * (q + h.phi1).sin() + h.a2 * (2.0 * q + h.phi2).sin())
            .collect()
    }
}

/// Each joint's sag under gravity at joint angles `q`, radians (physical − reading): the
/// joint turns in the direction of the torque a weight at the flange exerts about its axis,
/// `deflection_rad` when the moment arm is the arm's reach (stretched horizontally). The
/// model's root frame has gravity along −z (a floor-mounted arm). Zero for a joint whose axis
/// is vertical, and for every joint when `deflection_rad` is 0 or the model cannot pose `q`.
pub fn gravity_sag(model: &RobotModel, q: &[f64], deflection_rad: f64) -> Vec<f64> {
    let dof = model.dof();
    if deflection_rad <= 0.0 {
        return vec![0.0; dof];
    }
    let (Ok(frames), Ok(flange)) = (
        model.joint_frames(q),
        model.frame_pose(model.flange_link(), q),
    ) else {
        return vec![0.0; dof];
    };
    let reach = reach_m(model);
    let p = flange.translation.vector;
    frames
        .iter()
        .zip(model.joint_axes())
        .map(|(f, axis)| {
            let a = f.rotation * axis.into_inner();
            let r = p - f.translation.vector;
            deflection_rad * a.dot(&r.cross(&-Vector3::z())) / reach
        })
        .collect()
}

/// The arm's reach: the length of its chain from the second joint to the flange, metres (the
/// moment arm of the flange about the shoulder, stretched).
fn reach_m(model: &RobotModel) -> f64 {
    let zero = vec![0.0; model.dof()];
    let (Ok(frames), Ok(flange)) = (
        model.joint_frames(&zero),
        model.frame_pose(model.flange_link(), &zero),
    ) else {
        return 1.0;
    };
    let mut points: Vec<Vector3<f64>> = frames
        .iter()
        .skip(1)
        .map(|f| f.translation.vector)
        .collect();
    points.push(flange.translation.vector);
    points
        .windows(2)
        .map(|w| (w[1] - w[0]).norm())
        .sum::<f64>()
        .max(0.1)
}

/// Where the physical arm's joints are when its controller reports `reported`: the readings
/// less their encoder error, plus the sag under gravity.
pub fn physical_joints(
    model: &RobotModel,
    reported: &[f64],
    encoders: &EncoderErrors,
    deflection_rad: f64,
) -> Vec<f64> {
    let error = encoders.at(reported);
    let sag = gravity_sag(model, reported, deflection_rad);
    reported
        .iter()
        .zip(error.iter().zip(&sag))
        .map(|(q, (e, s))| q - e + s)
        .collect()
}

/// How a reported flange pose is off: each joint reading's error moves it along that joint's
/// column of the arm's Jacobian. What the solver knows of it: the joints, the columns, the
/// readings' 1σ and each joint's sag at this pose for the configured deflection (see the
/// module's doc).
#[derive(Debug, Clone, PartialEq)]
pub struct FlangeError {
    /// The joint readings, radians.
    pub joints: Vec<f64>,
    /// Per joint: how a reading error of one radian moves the flange pose (a left perturbation
    /// `(ρ, φ)` in the model frame: a point `x` moves by `ρ + φ × x`).
    pub columns: Vec<Vector6<f64>>,
    /// 1σ of each reading's encoder error, radians.
    pub reading_sigma_rad: f64,
    /// Each joint's sag at these joints ([`gravity_sag`]), radians.
    pub sag_rad: Vec<f64>,
}

impl FlangeError {
    /// The error of the flange pose `model` computes at readings `q`, for encoder errors of
    /// 1σ `reading_sigma_rad` and a sag of `deflection_rad` stretched; `None` when the model
    /// cannot pose `q`.
    pub fn at(
        model: &RobotModel,
        q: &[f64],
        reading_sigma_rad: f64,
        deflection_rad: f64,
    ) -> Option<Self> {
        let at = model.frame_pose(model.flange_link(), q).ok()?;
        const STEP: f64 = 1e-6;
        let columns = (0..q.len())
            .map(|k| {
                let mut moved = q.to_vec();
                moved[k] += STEP;
                let d = model.frame_pose(model.flange_link(), &moved).ok()? * at.inverse();
                let mut column = Vector6::zeros();
                column
                    .fixed_rows_mut::<3>(0)
                    .copy_from(&(d.translation.vector / STEP));
                column
                    .fixed_rows_mut::<3>(3)
                    .copy_from(&(d.rotation.scaled_axis() / STEP));
                Some(column)
            })
            .collect::<Option<Vec<_>>>()?;
        Some(Self {
            joints: q.to_vec(),
            columns,
            reading_sigma_rad,
            sag_rad: gravity_sag(model, q, deflection_rad),
        })
    }

    /// The covariance of the flange pose (the left perturbation of [`Self::columns`], m² and
    /// rad²) when each reading is off by an independent error of its 1σ plus its sag: what
    /// one view alone is off by.
    pub fn covariance(&self) -> Matrix6<f64> {
        self.columns
            .iter()
            .zip(&self.sag_rad)
            .map(|(c, sag)| c * c.transpose() * (self.reading_sigma_rad.powi(2) + sag.powi(2)))
            .sum()
    }

    /// Whether the flange pose is taken as exact (no reading error and no sag).
    pub fn is_exact(&self) -> bool {
        self.reading_sigma_rad == 0.0 && self.sag_rad.iter().all(|s| *s == 0.0)
    }
}

/// The covariance of a reported flange pose ([`FlangeError::covariance`]) at readings `q`.
/// `None` when the model cannot pose `q`.
pub fn flange_covariance(
    model: &RobotModel,
    q: &[f64],
    reading_sigma_rad: f64,
    deflection_rad: f64,
) -> Option<Matrix6<f64>> {
    FlangeError::at(model, q, reading_sigma_rad, deflection_rad).map(|e| e.covariance())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::shared_robot;

    #[test]
    fn encoder_errors_repeat_at_an_angle_and_have_their_sigma() {
        let e = EncoderErrors::draw(6, 1e-4, 7);
        let q = [0.3, -1.2, 1.0, -0.5, 1.5, 2.0];
        assert_eq!(e.at(&q), e.at(&q), "the same angle, the same error");
        assert_eq!(
            e,
            EncoderErrors::draw(6, 1e-4, 7),
            "the same seed, the same arm"
        );
        // Over all angles of one joint: a standard deviation near σ.
        let n = 3600;
        let var = (0..n)
            .map(|i| {
                let a = i as f64 / n as f64 * std::f64::consts::TAU;
                e.at(&[a; 6])[2].powi(2)
            })
            .sum::<f64>()
            / n as f64;
        let sigma = var.sqrt();
        assert!((0.5e-4..1.5e-4).contains(&sigma), "{sigma}");
        assert!(EncoderErrors::none(6).at(&q).iter().all(|v| *v == 0.0));
    }

    /// A UR5e stretched horizontally sags most at the shoulder, not at all at the base; held
    /// up vertically it does not sag.
    #[test]
    fn an_arm_sags_with_its_moment_arm() {
        let Some(model) = shared_robot("ur/ur5e/ur5e.urdf") else {
            return;
        };
        let stretched = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        let sag = gravity_sag(&model, &stretched, 1e-4);
        assert_eq!(sag[0], 0.0);
        assert!(sag[1].abs() > 0.7e-4 && sag[1].abs() <= 1e-4, "{sag:?}");
        assert!(
            sag[1].abs() > sag[2].abs() && sag[2].abs() > sag[3].abs(),
            "{sag:?}"
        );
        let upright = [
            0.0,
            -std::f64::consts::FRAC_PI_2,
            0.0,
            -std::f64::consts::FRAC_PI_2,
            0.0,
            0.0,
        ];
        let sag = gravity_sag(&model, &upright, 1e-4);
        assert!(sag[1].abs() < 2e-5, "{sag:?}");
        // The sag lowers the flange.
        let p = |q: &[f64]| {
            model
                .frame_pose(model.flange_link(), q)
                .expect("pose")
                .translation
                .z
        };
        let physical = physical_joints(&model, &stretched, &EncoderErrors::none(6), 1e-3);
        assert!(p(&physical) < p(&stretched) - 5e-4, "sags down");
    }

    /// The flange covariance is what the readings' errors do to the flange, measured by
    /// drawing them.
    #[test]
    fn the_flange_covariance_matches_drawn_reading_errors() {
        let Some(model) = shared_robot("ur/ur5e/ur5e.urdf") else {
            return;
        };
        let q = [0.4, -1.2, 1.1, -1.3, -1.5, 0.2];
        let sigma = 1e-4;
        let cov = flange_covariance(&model, &q, sigma, 0.0).expect("posed");
        let at = model.frame_pose(model.flange_link(), &q).expect("pose");
        let mut sum = 0.0;
        let n = 400;
        for seed in 0..n {
            let e = EncoderErrors::draw(6, sigma, seed);
            let moved = physical_joints(&model, &q, &e, 0.0);
            let d = model.frame_pose(model.flange_link(), &moved).expect("pose") * at.inverse();
            sum += d.translation.vector.norm_squared();
        }
        let drawn = (sum / n as f64).sqrt();
        let predicted = cov.fixed_view::<3, 3>(0, 0).trace().sqrt();
        assert!(
            (drawn / predicted - 1.0).abs() < 0.2,
            "drawn {drawn} m, predicted {predicted} m"
        );
    }
}
