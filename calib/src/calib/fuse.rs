//! The views of one run fitted together (eye-in-hand).
//!
//! Every view of a run sees the same arm. Its links' housings and joint errors are constants
//! in frames that move with the arm ([`LinkParam`]), while the camera pose of each view is the
//! flange pose the controller reports times the one unknown mount. A single scan cannot tell a
//! housing's offset from the mount: both move the camera pose the same way, and only the
//! links' prior weighs them (the σ floor of a manufactured arm). Seen from several places they
//! separate: the base housing's offset is fixed in the base frame, the mount in the flange
//! frame, and the flange turns between views.
//!
//! Each view's registration estimated its camera pose and the link parameters it sees, with
//! their joint covariance, the links' prior `z ~ N(0, I)` included ([`LinkFit`]). Here each
//! view's information without the prior (its data alone) is carried to the shared parameters
//! — the mount's small turn and shift in the flange frame, and the union of the link
//! parameters — summed over the views, and the prior added once. One view alone gives back
//! its own estimate and covariance. The frames of one view (captured without moving) share
//! their errors: together they count as one view.

use std::collections::BTreeMap;

use nalgebra::{DMatrix, DVector, Isometry3, Matrix3, Matrix6, Translation3, UnitQuaternion};

use super::links::LinkParam;
use super::register::covariance::{position_sigma_m, rotation_sigma_deg};
use super::{FrameInput, HandEyeSolution, Mount, Registration, Uncertainty};

/// A registration's link parameters and their joint covariance with its camera pose: what
/// fitting the views of one arm together needs ([`super::Registration::link_fit`]).
#[derive(Debug, Clone, PartialEq)]
pub struct LinkFit {
    /// What each parameter is.
    pub(crate) params: Vec<LinkParam>,
    /// Their estimates, prior 1σ units.
    pub(crate) z: DVector<f64>,
    /// Covariance of the pose (a left perturbation `(ρ, φ)` of `model_from_camera` in the
    /// model frame: a point `x` moves by `ρ + φ × x`) and `z`, `6 + z.len()` square, the
    /// links' prior included.
    pub(crate) covariance: DMatrix<f64>,
    /// The registration's camera pose in the model frame.
    pub(crate) model_from_camera: Isometry3<f64>,
}

/// The mount fitted from several views.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Fused {
    /// The mount.
    pub(crate) flange_from_camera: Isometry3<f64>,
    /// Its covariance: a left perturbation `(α, β)` in the flange frame (a point `y` moves by
    /// `α + β × y`).
    pub(crate) covariance: Matrix6<f64>,
}

/// One view of the arm: where the controller put the flange, and the fits of the frames
/// captured there.
#[derive(Debug, Clone, Copy)]
pub(crate) struct View<'a> {
    /// `model_from_flange` as the controller reported it.
    pub(crate) model_from_flange: Isometry3<f64>,
    /// A frame's link fit.
    pub(crate) fit: &'a LinkFit,
    /// How many frames the view has (each counts `1 / frames`).
    pub(crate) frames: usize,
    /// The covariance of `model_from_flange` (a left perturbation in the model frame, its
    /// joint readings' errors); `None`: exact.
    pub(crate) flange_covariance: Option<Matrix6<f64>>,
}

/// Relinearisations of the joint fit (the views' estimates are within a millimetre of each
/// other: the first step lands, the second confirms).
const ROUNDS: usize = 3;

/// The mount and link parameters that best explain every view (see the module docs), started
/// at `start`; `None` when a view's covariance cannot be inverted. `pose_frame`: the flange
/// poses are in a frame known only to within this 1σ per axis (shift m, turn rad) of the
/// model's own, which the views estimate together with the mount (see [`fuse_solution`]).
pub(crate) fn fuse_views(
    views: &[View<'_>],
    start: &Isometry3<f64>,
    pose_frame: Option<(f64, f64)>,
) -> Option<Fused> {
    let mut index: BTreeMap<LinkParam, usize> = BTreeMap::new();
    for v in views {
        for p in &v.fit.params {
            let next = index.len();
            index.entry(*p).or_insert(next);
        }
    }
    let q = index.len();
    // The poses' frame off the model's: a left perturbation in the model frame shared by every
    // view, its prior 1σ per axis.
    let frame_columns = if pose_frame.is_some() { 6 } else { 0 };
    let n = 6 + q + frame_columns;
    // Each view's data information and information vector, in its own parameters.
    let data: Vec<(DMatrix<f64>, DVector<f64>)> = views
        .iter()
        .map(|v| {
            let (d, b) = data_information(v.fit)?;
            Some(match &v.flange_covariance {
                Some(f) => with_flange_error(&d, &b, f),
                None => (d, b),
            })
        })
        .collect::<Option<_>>()?;
    let mut mount = *start;
    let mut covariance = Matrix6::zeros();
    for _ in 0..ROUNDS {
        let mut h = DMatrix::<f64>::zeros(n, n);
        let mut g = DVector::<f64>::zeros(n);
        for (v, (d, b)) in views.iter().zip(&data) {
            let p = v.fit.params.len();
            let weight = 1.0 / v.frames.max(1) as f64;
            // x_v = J θ + c: the view's pose perturbation and parameters at θ = (η, z).
            let mut j = DMatrix::<f64>::zeros(6 + p, n);
            j.view_mut((0, 0), (6, 6))
                .copy_from(&adjoint(&v.model_from_flange));
            for (k, param) in v.fit.params.iter().enumerate() {
                j[(6 + k, 6 + index[param])] = 1.0;
            }
            if let Some((shift_m, turn_rad)) = pose_frame {
                for a in 0..3 {
                    j[(a, 6 + q + a)] = shift_m;
                    j[(3 + a, 6 + q + 3 + a)] = turn_rad;
                }
            }
            let predicted = v.model_from_flange * mount;
            let step = predicted * v.fit.model_from_camera.inverse();
            let mut c = DVector::<f64>::zeros(6 + p);
            c.rows_mut(0, 3).copy_from(&step.translation.vector);
            c.rows_mut(3, 3).copy_from(&step.rotation.scaled_axis());
            h += j.transpose() * d * &j * weight;
            g += j.transpose() * (b - d * c) * weight;
        }
        for k in 6..n {
            h[(k, k)] += 1.0;
        }
        let inv = h.try_inverse()?;
        let theta = &inv * g;
        let step = Isometry3::from_parts(
            Translation3::new(theta[0], theta[1], theta[2]),
            UnitQuaternion::from_scaled_axis(theta.fixed_rows::<3>(3).into_owned()),
        );
        mount = step * mount;
        covariance = inv.fixed_view::<6, 6>(0, 0).into_owned();
        if theta.rows(0, 6).amax() < 1e-9 {
            break;
        }
    }
    Some(Fused {
        flange_from_camera: mount,
        covariance: (covariance + covariance.transpose()) / 2.0,
    })
}

/// A view's information about its pose and link parameters without the links' prior, and its
/// information vector (both at its own estimate): the posterior's information less the
/// prior's identity, with what the sandwich covariance leaves below the prior clamped to none.
fn data_information(fit: &LinkFit) -> Option<(DMatrix<f64>, DVector<f64>)> {
    let n = fit.covariance.nrows();
    let cov = (&fit.covariance + fit.covariance.transpose()) / 2.0;
    let posterior = cov.try_inverse()?;
    let mut mean = DVector::<f64>::zeros(n);
    mean.rows_mut(6, n - 6).copy_from(&fit.z);
    let b = &posterior * mean;
    let mut d = posterior;
    for k in 6..n {
        d[(k, k)] -= 1.0;
    }
    let eig = ((&d + d.transpose()) / 2.0).symmetric_eigen();
    let clamped = eig.eigenvalues.map(|e| e.max(0.0));
    let d = &eig.eigenvectors * DMatrix::from_diagonal(&clamped) * eig.eigenvectors.transpose();
    Some((d, b))
}

/// A view's data information `d` and information vector `b` when the flange pose it was
/// predicted from is itself off by an error of covariance `flange` (a left perturbation in the
/// model frame, which moves the predicted camera pose by as much): the pose block's covariance
/// grows by `flange`, so the information about it shrinks (Woodbury, exact for a singular `d`):
/// `d' = d − d G K Gᵀ d`, `b' = b − d G K Gᵀ b`, `K = F (I + Gᵀ d G F)⁻¹`, `G` the pose's rows.
/// A direction the view alone pins to a micrometre is then worth what the flange pose is.
fn with_flange_error(
    d: &DMatrix<f64>,
    b: &DVector<f64>,
    flange: &Matrix6<f64>,
) -> (DMatrix<f64>, DVector<f64>) {
    let f = DMatrix::from_fn(6, 6, |r, c| flange[(r, c)]);
    let dg = d.columns(0, 6).into_owned();
    let gdg = dg.rows(0, 6).into_owned();
    let Some(inner) = (DMatrix::identity(6, 6) + &gdg * &f).try_inverse() else {
        return (d.clone(), b.clone());
    };
    let k = &f * inner;
    let d_out = d - &dg * &k * dg.transpose();
    let b_out = b - &dg * (&k * b.rows(0, 6));
    ((&d_out + d_out.transpose()) / 2.0, b_out)
}

/// How a left perturbation `(α, β)` in the frame of `model_from_frame` moves things in the
/// model frame: `ρ = R α + p × R β`, `φ = R β`.
pub(crate) fn adjoint(model_from_frame: &Isometry3<f64>) -> Matrix6<f64> {
    let r: Matrix3<f64> = model_from_frame.rotation.to_rotation_matrix().into_inner();
    let p = model_from_frame.translation.vector;
    let mut ad = Matrix6::zeros();
    ad.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
    ad.fixed_view_mut::<3, 3>(0, 3)
        .copy_from(&(p.cross_matrix() * r));
    ad.fixed_view_mut::<3, 3>(3, 3).copy_from(&r);
    ad
}

/// The mount of an eye-in-hand solution refitted from its used views together, and its 1σ:
/// the joint fit's, the camera's own depth errors (shared by every view, the frames' mean)
/// and the model's accuracy (`model_accuracy`: metres, radians) over the square root of the
/// views. A CAD surface off the real part by a rigid offset of the part is, to the scan, the
/// offset of that link's housing, which the views fitted together separate from the mount;
/// what is left moves each view's pose its own way. `None` unless two views or more were
/// used and every used frame's links were fitted.
///
/// `pose_frame` (1σ per axis, m and rad): the flange poses are in a frame known only to within
/// this of the model's ([`super::pipeline::PipelineOptions::pose_frame`]); the views estimate
/// it with the mount, whose σ then carries it. `None`: the poses are the controller's, in its
/// `base`.
pub(crate) fn fuse_solution(
    solution: &HandEyeSolution,
    inputs: &[FrameInput],
    registrations: &[Registration],
    model_accuracy: (f64, f64),
    pose_frame: Option<(f64, f64)>,
) -> Option<(Isometry3<f64>, Uncertainty)> {
    if solution.mount != Mount::EyeInHand {
        return None;
    }
    let used: Vec<usize> = (0..inputs.len())
        .filter(|&i| solution.frames.get(i).is_some_and(|r| r.used))
        .collect();
    let mut per_view: BTreeMap<usize, usize> = BTreeMap::new();
    for &i in &used {
        *per_view.entry(inputs[i].view).or_default() += 1;
    }
    if per_view.len() < 2 {
        return None;
    }
    let views = used
        .iter()
        .map(|&i| {
            Some(View {
                model_from_flange: inputs[i].model_from_flange?,
                fit: registrations.get(i)?.link_fit.as_ref()?,
                frames: per_view[&inputs[i].view],
                flange_covariance: registrations.get(i)?.flange_covariance,
            })
        })
        .collect::<Option<Vec<_>>>()?;
    let fused = fuse_views(&views, &solution.estimate, pose_frame)?;
    // The camera origin in the flange frame, where the position σ is measured.
    let origin = fused.flange_from_camera.translation.vector;
    let fit_mm = position_sigma_m(&fused.covariance, &origin) * 1e3;
    let fit_deg = rotation_sigma_deg(&fused.covariance);
    let n = used.len() as f64;
    let floor = |sigma: f64| sigma.powi(2) / per_view.len() as f64;
    let camera = |pick: fn(&Uncertainty) -> f64| {
        used.iter()
            .map(|&i| pick(&registrations[i].camera_error).powi(2))
            .sum::<f64>()
            / n
    };
    let uncertainty = Uncertainty {
        translation_mm: (fit_mm.powi(2)
            + camera(|u| u.translation_mm)
            + floor(model_accuracy.0 * 1e3))
        .sqrt(),
        rotation_deg: (fit_deg.powi(2)
            + camera(|u| u.rotation_deg)
            + floor(model_accuracy.1.to_degrees()))
        .sqrt(),
        workspace: None,
    };
    Some((fused.flange_from_camera, uncertainty))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    /// A view's fit with a pose covariance and two link parameters correlated with it.
    fn fit(model_from_camera: Isometry3<f64>, z: [f64; 2]) -> LinkFit {
        let mut cov = DMatrix::<f64>::identity(8, 8) * 1e-8;
        for k in 0..6 {
            cov[(k, k)] = 1e-8 * (k + 1) as f64;
        }
        cov[(6, 6)] = 0.5;
        cov[(7, 7)] = 0.8;
        cov[(0, 6)] = 2e-5;
        cov[(6, 0)] = 2e-5;
        LinkFit {
            params: vec![
                LinkParam::Housing { depth: 0, index: 0 },
                LinkParam::Housing { depth: 0, index: 1 },
            ],
            z: DVector::from_row_slice(&z),
            covariance: cov,
            model_from_camera,
        }
    }

    /// A flange pose and a wrist camera's mount.
    fn flange_and_mount() -> (Isometry3<f64>, Isometry3<f64>) {
        (
            Isometry3::new(Vector3::new(0.3, -0.2, 0.5), Vector3::new(0.4, -1.0, 0.3)),
            Isometry3::new(
                Vector3::new(0.0, -0.08, 0.03),
                Vector3::new(-0.26, 0.0, 0.0),
            ),
        )
    }

    /// One view alone gives back its own estimate and its pose covariance (carried to the
    /// flange frame): the prior is taken out and added back once.
    #[test]
    fn one_view_alone_is_its_own_estimate() {
        let (model_from_flange, mount) = flange_and_mount();
        let f = fit(model_from_flange * mount, [0.3, -0.4]);
        let off = Isometry3::new(
            Vector3::new(2e-4, -1e-4, 3e-4),
            Vector3::new(1e-3, 0.0, -2e-3),
        );
        let fused = fuse_views(
            &[View {
                model_from_flange,
                fit: &f,
                frames: 1,
                flange_covariance: None,
            }],
            &(off * mount),
            None,
        )
        .expect("fused");
        let d = fused.flange_from_camera.inverse() * mount;
        assert!(d.translation.vector.norm() < 1e-9, "{d:?}");
        assert!(d.rotation.angle() < 1e-9, "{d:?}");
        // The pose block of the view's covariance, in the flange frame.
        let ad = adjoint(&model_from_flange);
        let inv = ad.try_inverse().expect("invertible");
        let pose: Matrix6<f64> = f.covariance.fixed_view::<6, 6>(0, 0).into_owned();
        let want = inv * pose * inv.transpose();
        assert!(
            (fused.covariance - want).norm() < 1e-6 * want.norm(),
            "{} vs {}",
            fused.covariance,
            want
        );
    }

    /// Issue 43: a view predicted from a flange pose that is itself uncertain (its joint
    /// readings) is worth no more than that pose: alone, the mount's covariance is the view's
    /// plus the flange pose's; two views whose flange poses are off by far more than their
    /// scans' σ no longer pin the mount to the scans' σ.
    #[test]
    fn issue_43_a_view_is_worth_no_more_than_its_flange_pose() {
        let (model_from_flange, mount) = flange_and_mount();
        let f = fit(model_from_flange * mount, [0.3, -0.4]);
        let mut flange = Matrix6::<f64>::zeros();
        for k in 0..6 {
            flange[(k, k)] = if k < 3 { 1e-7 } else { 2e-7 };
        }
        flange[(0, 4)] = 1e-8;
        flange[(4, 0)] = 1e-8;
        let view = View {
            model_from_flange,
            fit: &f,
            frames: 1,
            flange_covariance: Some(flange),
        };
        let fused = fuse_views(&[view], &mount, None).expect("fused");
        let inv = adjoint(&model_from_flange)
            .try_inverse()
            .expect("invertible");
        let pose: Matrix6<f64> = f.covariance.fixed_view::<6, 6>(0, 0).into_owned();
        let want = inv * (pose + flange) * inv.transpose();
        assert!(
            (fused.covariance - want).norm() < 1e-6 * want.norm(),
            "{} vs {}",
            fused.covariance,
            want
        );
        // Two views whose flange poses are off by more than their scans' σ: the fused
        // covariance keeps about half of one view's flange error.
        let flange2 = Isometry3::new(Vector3::new(-0.2, 0.3, 0.4), Vector3::new(-0.6, 0.8, 1.0));
        let f2 = fit(flange2 * mount, [0.2, -0.1]);
        let second = View {
            model_from_flange: flange2,
            fit: &f2,
            flange_covariance: Some(flange),
            ..view
        };
        let honest = fuse_views(&[view, second], &mount, None).expect("fused");
        let trusting = fuse_views(
            &[
                View {
                    flange_covariance: None,
                    ..view
                },
                View {
                    flange_covariance: None,
                    ..second
                },
            ],
            &mount,
            None,
        )
        .expect("fused");
        let position = |c: &Matrix6<f64>| c.fixed_view::<3, 3>(0, 0).trace();
        assert!(position(&honest.covariance) > 1.5 * position(&trusting.covariance));
        assert!(position(&honest.covariance) > 0.4 * 3.0 * 1e-7);
    }

    /// Two frames of one view count as that view once: the same estimate and covariance as
    /// either alone.
    #[test]
    fn the_frames_of_one_view_count_once() {
        let (model_from_flange, mount) = flange_and_mount();
        let f = fit(model_from_flange * mount, [0.3, -0.4]);
        let view = View {
            model_from_flange,
            fit: &f,
            frames: 2,
            flange_covariance: None,
        };
        let two = fuse_views(&[view, view], &mount, None).expect("fused");
        let one = fuse_views(&[View { frames: 1, ..view }], &mount, None).expect("fused");
        assert!((two.covariance - one.covariance).norm() < 1e-9 * one.covariance.norm());
    }
}
