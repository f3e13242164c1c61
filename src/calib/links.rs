//! The fitted moving links' kinematic error as parameters of the fit.
//!
//! The shoulder and upper arm are posed by the model's kinematics, and a real arm differs from
//! its URDF by its factory calibration (tenths of a millimetre and milliradian per joint). The
//! reported flange pose is the controller's, of the true arm; the model's links are not. A fit
//! that trusts the nominal links follows their error (a round base cannot hold the yaw), so the
//! links' small displacements are estimated alongside the camera pose, each with a prior of the
//! size the arm's calibration has: the base carries what it knows, the moving links what they
//! know beyond their kinematic error, and the covariance of the result includes what neither
//! can tell apart.
//!
//! Parameters `z ~ N(0, I)`: the links of chain depth `d` are displaced (model frame, a point
//! `x` moves by `t + ω × x`) by `(t, ω) = A_d · z`.

use nalgebra::{Matrix6xX, Vector3};

use super::surface::PosedModel;
use crate::model::KinematicError;

/// `A_d` for the chain depths `1..=fit_depth` (entry `d − 1`), one column per kinematic
/// parameter of the joints that move the fitted links, scaled by its prior 1σ; columns of
/// parameters with σ = 0 are left out, so an arm known exactly has none.
///
/// UR arms posed by a DH set take the DH terms of a UR calibration (θ: joint offset σ, d and a:
/// link length σ, α: axis misalignment σ of `error`); other arms take per-joint origin errors
/// (a length error along the link vector, a zero offset about the joint axis and a
/// misalignment about the two axes perpendicular to it), as [`KinematicError::sample`] draws
/// them.
pub(crate) fn link_error_model(
    model: &PosedModel,
    fit_depth: usize,
    error: &KinematicError,
) -> Vec<Matrix6xX<f64>> {
    // Only chain joints move links: a UR's DH set has six, another arm as many as its chain.
    let depths = match &model.dh_sensitivity {
        Some(dh) => fit_depth.min(dh.len()),
        None => fit_depth.min(model.joints.len()),
    };
    let sigma = |kind: usize| match kind {
        0 => error.joint_offset_sigma_rad,
        1 | 2 => error.link_length_sigma_m,
        _ => error.axis_misalignment_sigma_rad,
    };
    // (depth the parameter starts to move, 6-vector per depth ≥ it, σ) per parameter.
    let mut columns: Vec<(Vec<[f64; 6]>, f64)> = Vec::new();
    if let Some(dh) = &model.dh_sensitivity {
        for kind in 0..4 {
            for joint in 0..depths {
                let s = sigma(kind);
                if s <= 0.0 {
                    continue;
                }
                let col = 6 * kind + joint;
                let per_depth = (1..=depths)
                    .map(|d| std::array::from_fn(|r| dh[d - 1][(r, col)]))
                    .collect();
                columns.push((per_depth, s));
            }
        }
    } else {
        for (k, joint) in model.joints.iter().enumerate().take(depths) {
            let rotation = joint.model_from_joint.rotation;
            let origin = joint.model_from_joint.translation.vector;
            let axis = joint.axis.into_inner();
            let u1 = crate::model::kinematic::perpendicular(&axis);
            let u2 = axis.cross(&u1);
            let link = joint.parent_from_joint.rotation.inverse()
                * joint.parent_from_joint.translation.vector;
            let turn = |w: Vector3<f64>| {
                let w = rotation * w;
                let t = origin.cross(&w);
                [t.x, t.y, t.z, w.x, w.y, w.z]
            };
            let mut params: Vec<([f64; 6], f64)> = vec![
                (turn(axis), error.joint_offset_sigma_rad),
                (turn(u1), error.axis_misalignment_sigma_rad),
                (turn(u2), error.axis_misalignment_sigma_rad),
            ];
            if let Some(along) = link.try_normalize(1e-9) {
                let t = rotation * along;
                params.push(([t.x, t.y, t.z, 0.0, 0.0, 0.0], error.link_length_sigma_m));
            }
            for (v, s) in params {
                if s <= 0.0 {
                    continue;
                }
                let per_depth = (1..=depths)
                    .map(|d| if d > k { v } else { [0.0; 6] })
                    .collect();
                columns.push((per_depth, s));
            }
        }
    }
    (0..depths)
        .map(|d| {
            let mut a = Matrix6xX::zeros(columns.len());
            for (c, (per_depth, s)) in columns.iter().enumerate() {
                for r in 0..6 {
                    a[(r, c)] = per_depth[d][r] * s;
                }
            }
            a
        })
        .collect()
}

/// The prior covariance of the links' displacements, `A · Aᵀ` of every fitted depth stacked
/// (6·depths square): what the fitted links may be off by before the scan is seen.
#[cfg(test)]
pub(crate) fn prior_covariance(a: &[Matrix6xX<f64>]) -> nalgebra::DMatrix<f64> {
    let n = a.first().map_or(0, |m| m.ncols());
    let mut stacked = nalgebra::DMatrix::zeros(6 * a.len(), n);
    for (d, m) in a.iter().enumerate() {
        stacked.view_mut((6 * d, 0), (6, n)).copy_from(m);
    }
    &stacked * stacked.transpose()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::testutil::toy_robot;
    use crate::calib::{posed_model, posed_model_with_controller_kinematics};
    use crate::model::RobotModel;
    use handeye_hal::ur_dh::DhParams;
    use nalgebra::Isometry3;

    fn ur5e() -> Option<RobotModel> {
        let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("../shared/robots/ur/ur5e/ur5e.urdf");
        RobotModel::load(&path).ok()
    }

    #[test]
    fn the_dh_columns_move_the_links_as_a_calibrated_arm_does() {
        let Some(model) = ur5e() else {
            crate::testutil::skip("no ../shared/robots/ur/ur5e");
            return;
        };
        let q = [0.4, -1.2, 1.1, -1.3, -1.5, 0.2];
        let posed = posed_model(&model, &q).expect("posed");
        let error = KinematicError::default();
        let a = link_error_model(&posed, 2, &error);
        assert_eq!(a.len(), 2);
        // θ, d, a, α of joints 1 and 2.
        assert_eq!(a[0].ncols(), 8);
        // A real calibration delta moves the shoulder and upper arm as A predicts (to first
        // order): draw z, make the DH delta, pose the calibrated arm, compare.
        let ur = model.ur_model().expect("a UR");
        let z = [0.7, -1.1, 0.4, 1.3, -0.6, 0.9, -1.4, 0.2];
        let mut delta = DhParams {
            a: [0.0; 6],
            d: [0.0; 6],
            alpha: [0.0; 6],
            theta: [0.0; 6],
        };
        // Columns: kind-major (θ, d, a, α), joints 1 and 2 within.
        for (c, zc) in z.iter().enumerate() {
            let (kind, joint) = (c / 2, c % 2);
            let s = match kind {
                0 => error.joint_offset_sigma_rad,
                1 | 2 => error.link_length_sigma_m,
                _ => error.axis_misalignment_sigma_rad,
            };
            let field = match kind {
                0 => &mut delta.theta,
                1 => &mut delta.d,
                2 => &mut delta.a,
                _ => &mut delta.alpha,
            };
            field[joint] = zc * s;
        }
        let calibrated = posed_model_with_controller_kinematics(&model, &q, &ur.dh().plus(&delta))
            .expect("posed");
        for depth in 1..=2 {
            let zv = nalgebra::DVector::from_column_slice(&z);
            let tw = &a[depth - 1] * zv;
            let predicted = Isometry3::new(
                Vector3::new(tw[0], tw[1], tw[2]),
                Vector3::new(tw[3], tw[4], tw[5]),
            );
            let (nominal, actual) = posed
                .parts
                .iter()
                .zip(&calibrated.parts)
                .find(|(p, _)| p.chain_depth == depth)
                .map(|(p, c)| (p.model_from_link, c.model_from_link))
                .expect("a link at this depth");
            let moved = predicted * nominal;
            let dt = (moved.translation.vector - actual.translation.vector).norm();
            let dr = (moved.rotation.inverse() * actual.rotation).angle();
            // The displacement is ~1 mm / 1 mrad; second-order terms are ~1e-4 of it.
            assert!(dt < 2e-7 && dr < 2e-7, "depth {depth}: {dt:e} m {dr:e} rad");
        }
    }

    #[test]
    fn an_arm_known_exactly_has_no_link_parameters() {
        let posed = toy_robot(&[0.3, -0.8, 0.5]);
        let a = link_error_model(&posed, 2, &KinematicError::none());
        assert!(a.iter().all(|m| m.ncols() == 0));
    }

    #[test]
    fn joint_errors_reproduce_the_simulators_covariance() {
        // Per-joint origin errors: the prior of the shoulder's displacement is
        // KinematicError::joint_covariance (joint frame) carried to the model frame.
        let posed = toy_robot(&[0.4, 0.0, 0.0]);
        let error = KinematicError::default();
        let a = link_error_model(&posed, 2, &error);
        let prior = prior_covariance(&a);
        let j = &posed.joints[0];
        let r = j
            .model_from_joint
            .rotation
            .to_rotation_matrix()
            .into_inner();
        let o = j.model_from_joint.translation.vector;
        let mut ad = nalgebra::Matrix6::zeros();
        ad.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
        ad.fixed_view_mut::<3, 3>(0, 3)
            .copy_from(&(o.cross_matrix() * r));
        ad.fixed_view_mut::<3, 3>(3, 3).copy_from(&r);
        let expected = ad * error.joint_covariance(&j.axis, &j.parent_from_joint) * ad.transpose();
        let got = prior.view((0, 0), (6, 6));
        for r in 0..6 {
            for c in 0..6 {
                assert!(
                    (got[(r, c)] - expected[(r, c)]).abs() < 1e-15,
                    "({r},{c}): {} vs {}",
                    got[(r, c)],
                    expected[(r, c)]
                );
            }
        }
        // The upper arm also carries the second joint's error: its prior is larger.
        assert!(prior[(8, 8)] + prior[(6, 6)] > prior[(2, 2)] + prior[(0, 0)]);
    }
}
