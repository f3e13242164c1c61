//! Joint motion with speed/acceleration limits, linear tool moves (numeric IK on the simulated
//! DH) and controlled stops: the motions themselves, without the controller's state
//! ([`super::control`] advances them).

use handeye_hal::ur_dh::DhParams;
use nalgebra::{Isometry3, SMatrix, SVector};

use crate::UrPose;

/// Trapezoidal profile over a path of length `len` (any unit), speed `v`, acceleration `a`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Profile {
    /// Path length.
    pub(crate) len: f64,
    v: f64,
    a: f64,
    t_acc: f64,
    /// Duration, s.
    pub(crate) total: f64,
}

impl Profile {
    pub(crate) fn new(len: f64, v: f64, a: f64) -> Self {
        let (v, a) = (v.max(1e-6), a.max(1e-6));
        if len * a < v * v {
            let t_acc = (len / a).sqrt();
            Profile {
                len,
                v: a * t_acc,
                a,
                t_acc,
                total: 2.0 * t_acc,
            }
        } else {
            Profile {
                len,
                v,
                a,
                t_acc: v / a,
                total: len / v + v / a,
            }
        }
    }

    /// Distance and speed at time t.
    pub(crate) fn at(&self, t: f64) -> (f64, f64) {
        let t = t.clamp(0.0, self.total);
        if t < self.t_acc {
            (0.5 * self.a * t * t, self.a * t)
        } else if t <= self.total - self.t_acc {
            (
                0.5 * self.a * self.t_acc * self.t_acc + self.v * (t - self.t_acc),
                self.v,
            )
        } else {
            let r = self.total - t;
            (self.len - 0.5 * self.a * r * r, self.a * r)
        }
    }
}

/// What the arm is doing.
#[derive(Debug, Clone)]
pub(crate) enum Motion {
    Joint {
        start: [f64; 6],
        goal: [f64; 6],
        profile: Profile,
        t: f64,
    },
    Linear {
        start: Isometry3<f64>,
        goal: Isometry3<f64>,
        profile: Profile,
        t: f64,
    },
    Stop {
        decel: f64,
    },
    /// `speedj` (joint speeds, rad/s) or `speedl` (TCP twist in `base`: m/s, rad/s): the speed
    /// ramps towards `target` at `accel` and holds until the next command or a stop.
    Speed {
        joint: bool,
        target: [f64; 6],
        accel: f64,
        /// The speed reached (joint speeds or twist), before the speed slider.
        current: [f64; 6],
    },
    /// `servoj`: go to `target` (rad) in a straight joint-space line arriving `time` s after the
    /// command (`left` s from now), no faster than the joints can; then hold it.
    Servo {
        target: [f64; 6],
        time: f64,
        left: f64,
    },
}

impl Motion {
    pub(crate) fn joint(start: [f64; 6], goal: [f64; 6], v: f64, a: f64) -> Self {
        let len = start
            .iter()
            .zip(&goal)
            .map(|(s, g)| (g - s).abs())
            .fold(0.0, f64::max);
        Motion::Joint {
            start,
            goal,
            profile: Profile::new(len, v, a),
            t: 0.0,
        }
    }

    pub(crate) fn linear(start: Isometry3<f64>, goal: Isometry3<f64>, v: f64, a: f64) -> Self {
        let len = path_len(&start, &goal);
        Motion::Linear {
            start,
            goal,
            profile: Profile::new(len, v, a),
            t: 0.0,
        }
    }

    pub(crate) fn stop(_qd: [f64; 6], decel: f64) -> Self {
        Motion::Stop { decel }
    }

    /// A `speedj`/`speedl` that starts from the speed the arm has (a running speed command
    /// keeps its ramp; anything else starts from rest).
    pub(crate) fn speed(
        previous: Option<&Motion>,
        joint: bool,
        target: [f64; 6],
        accel: f64,
    ) -> Self {
        let current = match previous {
            Some(Motion::Speed {
                joint: j, current, ..
            }) if *j == joint => *current,
            _ => [0.0; 6],
        };
        Motion::Speed {
            joint,
            target,
            accel,
            current,
        }
    }
}

/// Moves `current` towards `target` by at most `accel * dt` (the whole vector, so the
/// direction of motion is kept).
pub(crate) fn ramp(current: &mut [f64; 6], target: &[f64; 6], accel: f64, dt: f64) {
    let diff: Vec<f64> = current.iter().zip(target).map(|(c, t)| t - c).collect();
    let n = diff.iter().map(|d| d * d).sum::<f64>().sqrt();
    let k = if n > accel * dt { accel * dt / n } else { 1.0 };
    for (c, d) in current.iter_mut().zip(diff) {
        *c += k * d;
    }
}

/// Linear path length: metres plus 0.1 m per radian of rotation (so pure rotations move too).
fn path_len(a: &Isometry3<f64>, b: &Isometry3<f64>) -> f64 {
    (b.translation.vector - a.translation.vector)
        .norm()
        .max(0.1 * a.rotation.angle_to(&b.rotation))
}

/// Damped-least-squares IK from `seed`; `None` if it does not converge to 1e-7 m / rad.
pub(crate) fn inverse(
    dh: &DhParams,
    target: &Isometry3<f64>,
    seed: &[f64; 6],
    iters: usize,
) -> Option<[f64; 6]> {
    let mut q = SVector::<f64, 6>::from_column_slice(seed);
    let err = |q: &SVector<f64, 6>| -> SVector<f64, 6> {
        let qa: [f64; 6] = (*q).into();
        let cur = dh.forward(&qa);
        let dp = target.translation.vector - cur.translation.vector;
        let dr = (target.rotation * cur.rotation.inverse()).scaled_axis();
        SVector::<f64, 6>::new(dp.x, dp.y, dp.z, dr.x, dr.y, dr.z)
    };
    for _ in 0..iters {
        let e = err(&q);
        if e.norm() < 1e-9 {
            return Some(q.into());
        }
        let mut j = SMatrix::<f64, 6, 6>::zeros();
        let h = 1e-7;
        for c in 0..6 {
            let mut qh = q;
            qh[c] += h;
            // e decreases as FK approaches target: J = -(e(q+h) - e(q)) / h
            j.set_column(c, &(-(err(&qh) - e) / h));
        }
        let lambda = 1e-4;
        let jt = j.transpose();
        let a = j * jt + SMatrix::<f64, 6, 6>::identity() * lambda;
        let dq = jt * a.lu().solve(&e)?;
        let n = dq.norm();
        q += if n > 0.5 { dq * (0.5 / n) } else { dq };
    }
    (err(&q).norm() < 1e-7).then(|| q.into())
}

/// `base_from_flange` target for a TCP pose target.
pub(crate) fn flange_target(tcp_target: &UrPose, tcp: &UrPose) -> Isometry3<f64> {
    Isometry3::from(*tcp_target) * Isometry3::from(*tcp).inverse()
}

#[cfg(test)]
mod tests {
    use super::*;
    use handeye_hal::ur_dh::UrModel;

    #[test]
    fn profile_reaches_the_end_with_limited_speed() {
        for (len, v, a) in [(1.0, 0.5, 1.0), (0.01, 1.0, 1.0), (0.0, 1.0, 1.0)] {
            let p = Profile::new(len, v, a);
            let (d, s) = p.at(p.total);
            assert!((d - len).abs() < 1e-12 && s.abs() < 1e-9);
            let mut t = 0.0;
            while t < p.total {
                assert!(p.at(t).1 <= v + 1e-9);
                t += 0.01;
            }
        }
    }

    #[test]
    fn ik_recovers_joint_angles() {
        let dh = UrModel::Ur5e.dh();
        let q = [0.3, -1.2, 1.4, -1.6, -1.5, 0.4];
        let target = dh.forward(&q);
        let seed = [0.25, -1.1, 1.3, -1.5, -1.4, 0.3];
        let sol = inverse(&dh, &target, &seed, 200).expect("converges");
        let got = dh.forward(&sol);
        assert!((got.translation.vector - target.translation.vector).norm() < 1e-7);
    }
}
