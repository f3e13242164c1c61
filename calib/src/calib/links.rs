//! The fitted moving links' kinematic error as parameters of the fit.
//!
//! The shoulder and upper arm are posed by the model's kinematics, and a real arm differs from
//! its URDF by small errors of every joint (tenths of a millimetre and milliradian). The
//! reported flange pose is the controller's, of the true arm; the model's links are not. A fit
//! that trusts the links follows their error (a round base cannot hold the yaw), so the
//! links' small displacements are estimated alongside the camera pose, each with a prior of the
//! size the arm's errors have: the base carries what it knows, the moving links what they
//! know beyond their error, and the covariance of the result includes what neither can tell
//! apart.
//!
//! Two cases:
//! - posed by the nominal model: every joint up to the fitted depth may be off by a small
//!   rigid error (as [`KinematicError::sample`] draws it: a zero offset, a displacement along
//!   three axes, a misalignment about two; the first joint only about and along its axis),
//!   which moves every link beyond it;
//! - posed by a controller's DH (its kinematics or a calibration file): each link is on its
//!   calibrated axis, but the axes cannot tell how far along and how far turned about its own
//!   axis a link sits (a joint's displacement there is the same axes as the next joint's; see
//!   [`DhParams::link_frames`](handeye_hal::ur_dh::DhParams::link_frames)): two parameters per
//!   link, that link alone.
//!
//! Both cases: what a camera sees of each fitted link, the base's included, is its housing,
//! which sits off the link's kinematic frame by a small rigid error no controller knows (the
//! base's off joint 1's axis); six parameters per fitted link. The base's are what make the
//! fit weigh the base against the shoulder and upper arm, which turn on joint 1's axis, and
//! what the scan cannot tell apart from the camera pose stays in the covariance.
//!
//! Parameters `z ~ N(0, I)`: the links of chain depth `d` (0: the base) are displaced (model
//! frame, a point `x` moves by `t + ω × x`) by `(t, ω) = A_d · z`.

use handeye_hal::ur_dh::PARALLEL_SINE;
use nalgebra::{DMatrix, DVector, Isometry3, Matrix6xX, Point3, Vector3};

use super::surface::PosedModel;
use crate::model::KinematicError;

/// A registration's link parameters and their joint covariance with its camera pose: what
/// fitting the views of one arm together needs ([`super::Registration::link_fit`]).
#[derive(Debug, Clone, PartialEq)]
pub struct LinkFit {
    /// What each parameter is.
    pub(crate) params: Vec<LinkParam>,
    /// Their estimates, prior 1σ units.
    pub(crate) z: DVector<f64>,
    /// What the scan alone tells of the pose (a left perturbation `(ρ, φ)` of
    /// `model_from_camera` in the model frame: a point `x` moves by `ρ + φ × x`) and of `z`:
    /// its information, `6 + z.len()` square, the links' prior (`I` on `z`) not included
    /// ([`ScanInformation`]).
    pub(crate) information: DMatrix<f64>,
    /// The information vector that goes with it: the information times where the scan alone
    /// puts the pose and `z` (relative to this fit's pose).
    pub(crate) information_vector: DVector<f64>,
    /// The registration's camera pose in the model frame.
    pub(crate) model_from_camera: Isometry3<f64>,
}

impl LinkFit {
    /// The information with the links' prior: [`Self::information`] plus `I` on `z`.
    #[cfg(test)]
    pub(crate) fn posterior_information(&self) -> DMatrix<f64> {
        let mut info = self.information.clone();
        for k in 6..info.nrows() {
            info[(k, k)] += 1.0;
        }
        info
    }

    /// The pose moved by a further error of covariance `noise` (model frame, as the pose's
    /// perturbation) that the scan cannot tell: the scan's estimate stays, its information
    /// is that of the estimate with the noise added (`(D⁻¹ + E N Eᵀ)⁻¹ = D − D E V (I + Vᵀ Eᵀ
    /// D E V)⁻¹ Vᵀ Eᵀ D` with `N = V Vᵀ`, which needs no inverse of `D`).
    pub(crate) fn add_pose_noise(&mut self, noise: &nalgebra::Matrix6<f64>) {
        let eig = ((noise + noise.transpose()) / 2.0).symmetric_eigen();
        let n = self.information.nrows();
        let mut v = DMatrix::<f64>::zeros(n, 6);
        for k in 0..6 {
            let scale = eig.eigenvalues[k].max(0.0).sqrt();
            v.view_mut((0, k), (6, 1))
                .copy_from(&(eig.eigenvectors.column(k) * scale));
        }
        let dv = &self.information * &v;
        let inner = DMatrix::<f64>::identity(6, 6) + v.transpose() * &dv;
        if let Some(inv) = inner.try_inverse() {
            let gain = &dv * inv;
            self.information -= &gain * dv.transpose();
            self.information = (&self.information + self.information.transpose()) / 2.0;
            self.information_vector -= gain * (v.transpose() * &self.information_vector);
        }
    }
}

/// Relative size below which a direction of the scan's score variance counts as none (the
/// parameters scaled to unit information first).
const SINGULAR_RATIO: f64 = 1e-10;

/// What a scan alone tells about a fit's parameters, robustly: its information and
/// information vector.
///
/// The fit's normal matrix `H` and score variance `M` (the "meat") hold the links' prior: `s`
/// on a link parameter's diagonal of `H` (`prior`: index, `s`), `s²` on the meat's. Without it,
/// `H_d` and `M_d`, the data's sandwich information is `H_d M_d⁺ H_d` over `small_sample`:
/// positive semi-definite by construction (a scan whose residuals scatter more than the fit
/// assumed tells less, never less than nothing), `H_d / s` with residuals as the fit assumed
/// (`M_d = s H_d`), the prior's units. The fit stopped where its data's gradient balances the
/// prior's pull, `g_d = −P x̂`; the data alone would go on to `x_d = x̂ + H_d⁻¹ P x̂`, whose
/// information vector is the information times `x_d`.
pub(crate) struct ScanInformation {
    /// The information over the kept parameters, the others marginalised.
    pub(crate) information: DMatrix<f64>,
    /// The information vector over the kept parameters.
    pub(crate) vector: DVector<f64>,
}

impl ScanInformation {
    /// From the fit's `h` and `meat` at its estimate `at` (its parameters relative to where
    /// they were linearised: zero but the links'), keeping parameters `keep` (indices into
    /// `h`). `None` when the scaled score variance has no pseudo-inverse.
    pub(crate) fn new(
        h: &DMatrix<f64>,
        meat: &DMatrix<f64>,
        prior: &[(usize, f64)],
        at: &DVector<f64>,
        keep: &[usize],
        small_sample: f64,
    ) -> Option<Self> {
        let n = h.nrows();
        let (mut hd, mut md) = (h.clone(), meat.clone());
        let mut pull = DVector::<f64>::zeros(n);
        for &(k, s) in prior {
            hd[(k, k)] -= s;
            md[(k, k)] -= s * s;
            pull[k] = s * at[k];
        }
        // Scaled so that every parameter has unit information with its prior (metres, radians
        // and prior units alike), so the pseudo-inverse's cut is relative.
        let d = DVector::from_fn(n, |k, _| 1.0 / h[(k, k)].max(f64::MIN_POSITIVE).sqrt());
        let scale = |m: &DMatrix<f64>| DMatrix::from_fn(n, n, |a, b| m[(a, b)] * d[a] * d[b]);
        let (hs, ms) = (scale(&hd), scale(&md));
        let ms = (&ms + ms.transpose()) / 2.0;
        let cut = ms.amax() * SINGULAR_RATIO;
        let hm = &hs * ms.pseudo_inverse(cut).ok()? / small_sample;
        let info = &hm * &hs;
        let info = (&info + info.transpose()) / 2.0;
        let at_s = at.component_div(&d);
        let vector = &info * at_s + hm * pull.component_mul(&d);
        let rest: Vec<usize> = (0..n).filter(|k| !keep.contains(k)).collect();
        let kk = info.select_rows(keep).select_columns(keep);
        let vk = vector.select_rows(keep);
        let (marginal, vk) = if rest.is_empty() {
            (kk, vk)
        } else {
            let rr = info.select_rows(&rest).select_columns(&rest);
            let kr = info.select_rows(keep).select_columns(&rest);
            let cut = rr.amax() * SINGULAR_RATIO;
            let gain = &kr * rr.pseudo_inverse(cut).ok()?;
            (
                kk - &gain * kr.transpose(),
                vk - gain * vector.select_rows(&rest),
            )
        };
        let unscaled = DMatrix::from_fn(keep.len(), keep.len(), |a, b| {
            marginal[(a, b)] / (d[keep[a]] * d[keep[b]])
        });
        Some(Self {
            information: (&unscaled + unscaled.transpose()) / 2.0,
            vector: DVector::from_fn(keep.len(), |a, _| vk[a] / d[keep[a]]),
        })
    }
}

/// Which of the arm's parameters a column of [`LinkModel::a`] is. Each is a constant of the
/// arm, expressed in frames that move with it (a joint's axis or its parent link, a link's own
/// frame), so the same parameter has the same value in every view of one arm: what lets the
/// views of a run be fitted together ([`super::fuse`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub(crate) enum LinkParam {
    /// Error `index` of chain joint `depth − 1`, which moves the link of chain depth `depth`
    /// (and, posed by the nominal model, every link beyond it).
    Joint { depth: usize, index: usize },
    /// The housing of chain depth `depth` off its link's frame: a shift along (`index` even)
    /// or a turn about (odd) the link frame's axis `index / 2`.
    Housing { depth: usize, index: usize },
}

/// The links' displacements as linear functions of the arm's parameters.
#[derive(Debug, Clone, Default)]
pub(crate) struct LinkModel {
    /// `A_d` for the chain depths `0..=fit_depth` (entry `d`; depth 0 is the base), one column
    /// per parameter, scaled by its prior 1σ.
    pub(crate) a: Vec<Matrix6xX<f64>>,
    /// What each column is.
    pub(crate) params: Vec<LinkParam>,
}

/// The links' error model for the chain depths `0..=fit_depth`, one column per kinematic
/// parameter of the links' displacements, scaled by its prior 1σ; columns of parameters with
/// σ = 0 are left out, so an arm known exactly has none.
pub(crate) fn link_error_model(
    model: &PosedModel,
    fit_depth: usize,
    error: &KinematicError,
) -> LinkModel {
    // (6-vector per depth, σ, what it is) per parameter.
    let mut columns: Vec<(Vec<[f64; 6]>, f64, LinkParam)> = Vec::new();
    let twist = |t: Vector3<f64>, w: Vector3<f64>| [t.x, t.y, t.z, w.x, w.y, w.z];
    // A turn about the line through `p` along `u`: a point x moves by (p × u) + u × x.
    let turn = |p: &Point3<f64>, u: Vector3<f64>| twist(p.coords.cross(&u), u);
    let depths = match &model.link_axes {
        Some(axes) => fit_depth.min(axes.len()),
        None => fit_depth.min(model.joints.len()),
    };
    // Moves the links of depth `k` alone, or (`beyond`) every fitted depth past `k`.
    let at = |k: usize, v: [f64; 6], beyond: bool| {
        (0..=depths)
            .map(|d| {
                if d == k || (beyond && d > k) {
                    v
                } else {
                    [0.0; 6]
                }
            })
            .collect::<Vec<_>>()
    };
    match &model.link_axes {
        Some(axes) => {
            for k in 1..=depths {
                let (p, u) = (Point3::from(axes[k - 1].point), axes[k - 1].direction);
                // How far turned: the next axis' displacement over its lever when the axes
                // are parallel (the turn is read from where the next axis is), else the
                // next axis' misalignment.
                let turn_sigma = match axes.get(k) {
                    Some(next) if u.cross(&next.direction).norm() < PARALLEL_SINE => {
                        let r = next.point - p.coords;
                        let lever = (r - u * r.dot(&u)).norm();
                        error.link_length_sigma_m / lever.max(error.link_length_sigma_m.max(1e-3))
                    }
                    _ => error.axis_misalignment_sigma_rad,
                };
                let param = |index| LinkParam::Joint { depth: k, index };
                columns.push((at(k, turn(&p, u), false), turn_sigma, param(0)));
                columns.push((
                    at(k, twist(u, Vector3::zeros()), false),
                    error.link_length_sigma_m,
                    param(1),
                ));
            }
        }
        None => {
            for (k, joint) in model.joints.iter().enumerate().take(depths) {
                let rotation = joint.model_from_joint.rotation;
                let origin = Point3::from(joint.model_from_joint.translation.vector);
                let axis = joint.axis.into_inner();
                let u1 = crate::model::kinematic::perpendicular(&axis);
                let u2 = axis.cross(&u1);
                let along = |v: Vector3<f64>| twist(rotation * v, Vector3::zeros());
                let mut params = vec![
                    (turn(&origin, rotation * axis), error.joint_offset_sigma_rad),
                    (along(axis), error.link_length_sigma_m),
                ];
                if k > 0 {
                    params.extend([
                        (
                            turn(&origin, rotation * u1),
                            error.axis_misalignment_sigma_rad,
                        ),
                        (
                            turn(&origin, rotation * u2),
                            error.axis_misalignment_sigma_rad,
                        ),
                        (along(u1), error.link_length_sigma_m),
                        (along(u2), error.link_length_sigma_m),
                    ]);
                }
                for (index, (v, s)) in params.into_iter().enumerate() {
                    // Joint k moves every link beyond it: depths k + 1 and on.
                    let param = LinkParam::Joint {
                        depth: k + 1,
                        index,
                    };
                    columns.push((at(k + 1, v, true), s, param));
                }
            }
        }
    }
    // Each fitted link's housing off its frame, the base's included: a shift along and a turn
    // about each axis of the link's own frame through its origin (the root's for the base, the
    // link's that its joint moves for the others), as the simulators draw it
    // (`RobotModel::with_housings`).
    for d in 0..=depths {
        // Without the links' frames (a model assembled by hand), the joint's origin and the
        // model's axes.
        let frame = model.chain_link_frames.get(d).copied().unwrap_or_else(|| {
            match d.checked_sub(1).and_then(|k| model.joints.get(k)) {
                Some(joint) => Isometry3::from(joint.model_from_joint.translation),
                None => Isometry3::identity(),
            }
        });
        let origin = Point3::from(frame.translation.vector);
        for (axis, e) in [Vector3::x(), Vector3::y(), Vector3::z()]
            .into_iter()
            .enumerate()
        {
            let e = frame.rotation * e;
            let param = |index| LinkParam::Housing { depth: d, index };
            columns.push((
                at(d, twist(e, Vector3::zeros()), false),
                error.housing_translation_sigma_m,
                param(2 * axis),
            ));
            columns.push((
                at(d, turn(&origin, e), false),
                error.housing_rotation_sigma_rad,
                param(2 * axis + 1),
            ));
        }
    }
    columns.retain(|(_, s, _)| *s > 0.0);
    let a = (0..=depths)
        .map(|d| {
            let mut a = Matrix6xX::zeros(columns.len());
            for (c, (per_depth, s, _)) in columns.iter().enumerate() {
                for r in 0..6 {
                    a[(r, c)] = per_depth[d][r] * s;
                }
            }
            a
        })
        .collect();
    LinkModel {
        a,
        params: columns.into_iter().map(|(_, _, p)| p).collect(),
    }
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
    use crate::calib::posed_model_with_controller_kinematics;
    use crate::calib::testutil::toy_robot;
    use crate::testutil::shared_robot;
    use handeye_hal::ur_dh::PhysicalArm;
    use rand::SeedableRng;

    /// A data normal matrix over a pose-like parameter, a nuisance (a depth parameter) and two
    /// link parameters, one of which the scan barely sees.
    fn data_normal() -> DMatrix<f64> {
        let j = DMatrix::from_row_slice(
            5,
            4,
            &[
                1.0, 0.2, 0.5, 1e-3, //
                0.3, 1.0, 0.1, 0.0, //
                -0.4, 0.6, 0.9, 2e-3, //
                0.8, -0.1, 0.3, 0.0, //
                0.1, 0.4, -0.7, 1e-3,
            ],
        );
        j.transpose() * j * 1e4
    }

    /// The fit's normal matrix and score variance with the links' prior (`s` on their
    /// diagonal, its square in the meat), the data's score variance `inflation` times what
    /// the fit assumed.
    fn with_prior(hd: &DMatrix<f64>, s: f64, inflation: f64) -> (DMatrix<f64>, DMatrix<f64>) {
        let (mut h, mut meat) = (hd.clone(), hd * (s * inflation));
        for k in 2..4 {
            h[(k, k)] += s;
            meat[(k, k)] += s * s;
        }
        (h, meat)
    }

    /// Residuals as the fit assumed: the scan's information is `H_d / s` (the prior's units)
    /// and its vector `(H_d + P) x̂ / s` (the data's gradient balanced the prior's pull at
    /// the estimate `x̂`), the nuisance marginalised by the Schur complement; residuals that
    /// scatter twice as far tell a quarter; a direction the scan barely sees never gets less
    /// than none (the sandwich's posterior covariance less the prior had given its inflation
    /// there as negative information).
    #[test]
    fn the_scan_s_information_is_its_own_and_never_negative() {
        let hd = data_normal();
        let s = 1.0;
        let prior = [(2, s), (3, s)];
        let at = DVector::from_row_slice(&[0.0, 0.0, 0.4, -0.7]);
        let keep = [0, 2, 3];
        let rest = [1];
        let schur = |info: &DMatrix<f64>, v: &DVector<f64>| {
            let kk = info.select_rows(&keep).select_columns(&keep);
            let kr = info.select_rows(&keep).select_columns(&rest);
            let gain = &kr / info[(1, 1)];
            (
                kk - &gain * kr.transpose(),
                v.select_rows(&keep) - gain * v[1],
            )
        };
        for inflation in [1.0, 4.0] {
            let (h, meat) = with_prior(&hd, s, inflation);
            let got =
                ScanInformation::new(&h, &meat, &prior, &at, &keep, 1.0).expect("information");
            let info = &hd / (s * inflation);
            let mut pull = DVector::zeros(4);
            for &(k, s) in &prior {
                pull[k] = s * at[k];
            }
            let (want, want_v) = schur(&info, &((&hd * &at + pull) / (s * inflation)));
            assert!(
                (&got.information - &want).norm() < 1e-6 * want.norm(),
                "{inflation}: {} vs {want}",
                got.information
            );
            assert!(
                (&got.vector - &want_v).norm() < 1e-6 * want_v.norm(),
                "{inflation}: {} vs {want_v}",
                got.vector
            );
            assert!(got.information.symmetric_eigen().eigenvalues.min() > -1e-9 * want.norm());
        }
        // The sandwich's posterior less the prior: negative where the scan barely sees.
        let (h, meat) = with_prior(&hd, s, 4.0);
        let h_inv = h.clone().try_inverse().expect("invertible");
        let cov = &h_inv * meat * &h_inv;
        let cov = cov.select_rows(&keep).select_columns(&keep);
        let mut posterior_less_prior = cov.try_inverse().expect("invertible");
        for k in 1..3 {
            posterior_less_prior[(k, k)] -= 1.0;
        }
        assert!(posterior_less_prior.symmetric_eigen().eigenvalues.min() < 0.0);
    }

    /// A further pose error the scan cannot tell adds its covariance to the pose estimate's;
    /// the estimate stays.
    #[test]
    fn pose_noise_adds_to_the_pose_s_covariance() {
        let mut info = DMatrix::<f64>::identity(7, 7) * 1e6;
        info[(0, 6)] = 2e5;
        info[(6, 0)] = 2e5;
        info[(6, 6)] = 3.0;
        let estimate = DVector::from_row_slice(&[1e-4, 0.0, -2e-4, 1e-3, 0.0, 0.0, 0.5]);
        let mut fit = LinkFit {
            params: vec![LinkParam::Housing { depth: 0, index: 0 }],
            z: DVector::zeros(1),
            information: info.clone(),
            information_vector: &info * &estimate,
            model_from_camera: Isometry3::identity(),
        };
        let mut noise = nalgebra::Matrix6::<f64>::zeros();
        noise[(0, 0)] = 4e-7;
        noise[(3, 3)] = 1e-7;
        noise[(0, 3)] = 1e-7;
        noise[(3, 0)] = 1e-7;
        fit.add_pose_noise(&noise);
        let mut cov = info.try_inverse().expect("invertible");
        let mut pose = cov.view_mut((0, 0), (6, 6));
        pose += noise;
        let want = cov.try_inverse().expect("invertible");
        assert!(
            (&fit.information - &want).norm() < 1e-8 * want.norm(),
            "{} vs {}",
            fit.information,
            want
        );
        let v = want * estimate;
        assert!((&fit.information_vector - &v).norm() < 1e-8 * v.norm());
    }

    /// Posed by a controller's DH, what is left of each fitted link's error is a turn about
    /// and a slide along its calibrated axis; over many physical arms their spread is what the
    /// prior says (the registration's σ stands on it).
    #[test]
    fn the_axis_freedoms_prior_matches_what_physical_arms_leave() {
        let Some(model) = shared_robot("ur/ur5e/ur5e.urdf") else {
            return;
        };
        let ur = model.ur_model().expect("a UR");
        let error = KinematicError::default();
        let q = [0.4, -1.2, 1.1, -1.3, -1.5, 0.2];
        let shoulder = model.link_index("shoulder_link").expect("shoulder");
        let upper = model.link_index("upper_arm_link").expect("upper arm");
        let (mut turns, mut slides) = ([Vec::new(), Vec::new()], [Vec::new(), Vec::new()]);
        let mut priors = Vec::new();
        for seed in 0..300 {
            let arm = PhysicalArm::draw(ur.dh(), &error.joint_sizes(), seed);
            let dh = arm.controller_dh();
            let posed = posed_model_with_controller_kinematics(&model, &q, &dh).expect("posed");
            if seed == 0 {
                let a = link_error_model(&posed, 2, &error.without_housings()).a;
                assert_eq!(a.len(), 3, "the base and two moving links");
                assert_eq!(a[0].ncols(), 4, "two per fitted moving link");
                assert_eq!(a[0].norm(), 0.0, "the base is not on a moving axis");
                // Column σ: the turn and slide of each link (only its own depth moves).
                priors = (0..4)
                    .map(|c| {
                        let depth = c / 2 + 1;
                        let v = a[depth].column(c);
                        assert!(a[3 - depth].column(c).norm() == 0.0);
                        if c % 2 == 0 {
                            v.fixed_rows::<3>(3).norm()
                        } else {
                            v.fixed_rows::<3>(0).norm()
                        }
                    })
                    .collect::<Vec<_>>();
            }
            let physical = model.link_poses_of_arm(&q, &arm).expect("physical");
            let by_dh = model.link_poses_with_controller_dh(&q, &dh).expect("posed");
            let axes = model.dh_axes(&q, &dh).expect("axes");
            for (i, (link, axis)) in [(shoulder, 0), (upper, 1)].into_iter().enumerate() {
                let d = by_dh[link] * physical[link].inverse();
                let (p, u) = (
                    nalgebra::Point3::from(axes[axis].point),
                    axes[axis].direction,
                );
                turns[i].push(d.rotation.scaled_axis().dot(&u));
                slides[i].push(((d * p) - p).dot(&u));
            }
        }
        let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt();
        for i in 0..2 {
            let (turn, slide) = (rms(&turns[i]), rms(&slides[i]));
            let (pt, ps) = (priors[2 * i], priors[2 * i + 1]);
            eprintln!(
                "link {}: turn rms {:.3} mrad (prior {:.3}), slide rms {:.3} mm (prior {:.3})",
                i + 1,
                turn * 1e3,
                pt * 1e3,
                slide * 1e3,
                ps * 1e3
            );
            assert!(turn > 0.6 * pt && turn < 1.4 * pt, "link {}: turn", i + 1);
            assert!(
                slide > 0.6 * ps && slide < 1.4 * ps,
                "link {}: slide",
                i + 1
            );
        }
    }

    #[test]
    fn an_arm_known_exactly_has_no_link_parameters() {
        let posed = toy_robot(&[0.3, -0.8, 0.5]);
        let a = link_error_model(&posed, 2, &KinematicError::none());
        assert!(a.params.is_empty());
        assert!(a.a.iter().all(|m| m.ncols() == 0));
    }

    #[test]
    fn joint_errors_reproduce_the_simulators_covariance() {
        // Per-joint origin errors: the prior of the shoulder's displacement is
        // KinematicError::joint_covariance (joint frame) carried to the model frame.
        let posed = toy_robot(&[0.4, 0.0, 0.0]);
        let error = KinematicError::default().without_housings();
        let a = link_error_model(&posed, 2, &error).a;
        let prior = prior_covariance(&a);
        assert_eq!(
            prior.view((0, 0), (6, 6)).norm(),
            0.0,
            "the base is not moved"
        );
        let prior = prior.view((6, 6), (12, 12));
        let j = &posed.joints[0];
        let ad = crate::frames::adjoint(&j.model_from_joint);
        let expected = ad * error.joint_covariance(&j.axis, true) * ad.transpose();
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

    /// The housings' prior, the base's included, is the spread of the housings the simulators
    /// draw: the displacement of every fitted link's surface over many drawn arms has the
    /// covariance the fit assumes (the reported σ stands on it).
    #[test]
    fn the_housings_prior_matches_what_the_simulators_draw() {
        let Some(model) = shared_robot("ur/ur5e/ur5e.urdf") else {
            return;
        };
        let q = [0.4, -1.2, 1.1, -1.3, -1.5, 0.2];
        let error = KinematicError {
            housing_translation_sigma_m: 3e-4,
            housing_rotation_sigma_rad: 2e-4,
            ..KinematicError::none()
        };
        let posed = crate::calib::posed_model(&model, &q).expect("posed");
        let prior = prior_covariance(&link_error_model(&posed, 2, &error).a);
        assert_eq!(prior.nrows(), 18, "base, shoulder, upper arm");
        let poses = model.link_poses(&q).expect("poses");
        let links = ["base_link_inertia", "shoulder_link", "upper_arm_link"]
            .map(|l| model.link_index(l).expect(l));
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        let n = 4000;
        let mut cov = nalgebra::DMatrix::<f64>::zeros(18, 18);
        for _ in 0..n {
            let housed = model.with_housings(&poses, &error.sample_housings(&model, &mut rng));
            let mut v = nalgebra::DVector::<f64>::zeros(18);
            for (d, &l) in links.iter().enumerate() {
                // The displacement as a twist: a point x moves by t + ω × x.
                let m = housed[l] * poses[l].inverse();
                let w = m.rotation.scaled_axis();
                v.fixed_rows_mut::<3>(6 * d)
                    .copy_from(&m.translation.vector);
                v.fixed_rows_mut::<3>(6 * d + 3).copy_from(&w);
            }
            cov += &v * v.transpose() / n as f64;
        }
        for d in 0..3 {
            for (k, sigma) in [(0, 3e-4), (3, 2e-4)] {
                let block =
                    |c: &nalgebra::DMatrix<f64>| c.view((6 * d + k, 6 * d + k), (3, 3)).trace();
                let (want, got) = (block(&prior), block(&cov));
                assert!(
                    (got / want - 1.0).abs() < 0.08,
                    "depth {d} {}: drawn {got:.3e}, prior {want:.3e}",
                    if k == 0 { "shift" } else { "turn" }
                );
                if k == 3 {
                    assert!((want / 3.0 - sigma * sigma).abs() < 1e-15);
                }
            }
        }
        // Independent links: no correlation between depths.
        assert!(cov.view((0, 6), (6, 12)).amax() < 0.1 * 3e-4 * 3e-4);
    }
}
