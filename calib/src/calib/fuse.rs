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
//! Each view's registration estimated its camera pose and the link parameters it sees with
//! the links' prior `z ~ N(0, I)`, and kept what its scan alone tells of them: their robust
//! information and information vector, the prior left out ([`LinkFit`],
//! [`super::links::ScanInformation`]). Here each view's is carried to the shared parameters —
//! the mount's small turn and shift in the flange frame, and the union of the link parameters
//! — summed over the views, and the prior added once. One view alone gives back its own
//! estimate. The frames of one view (captured without moving) share their errors: together
//! they count as one view.
//!
//! Each view's flange pose is the controller's from its joint readings, which are off by the
//! encoders' errors and the arm's sag ([`FlangeError`]). Those errors are parameters of the
//! fit too, one per view and joint, with a prior that correlates two views by how far apart
//! they hold each joint ([`reading_correlation`]): views that barely turn the base share its
//! reading's error, which only moves the base's housing, while the wrist turned far between
//! them gives independent errors that the views average. One parameter scales the run's sag.

use std::collections::BTreeMap;

use nalgebra::{DMatrix, DVector, Isometry3, Matrix6, Translation3, UnitQuaternion};

use super::links::{LinkFit, LinkParam};
use super::register::covariance::{position_sigma_m, rotation_sigma_deg};
use super::{FrameInput, HandEyeSolution, Mount, Registration, Uncertainty};
use crate::frames::adjoint;
use crate::model::reading::FlangeError;

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
    /// Which view of the run (its frames share it).
    pub(crate) view: usize,
    /// How many frames the view has (each counts `1 / frames`).
    pub(crate) frames: usize,
    /// How `model_from_flange` is off (its joint readings' errors); `None`: exact.
    pub(crate) flange_error: Option<&'a FlangeError>,
}

/// How one joint's reading errors at two views of a run correlate, by the angle `delta`
/// between the joint's readings (radians; 1 for a view with itself): a third independent from
/// view to view (the arm's repeatability, anything not periodic in the angle), a third the
/// encoder's once-per-turn error, a third its twice-per-turn error (see
/// [`crate::model::reading`]). Views that barely turn a joint share most of its error, which
/// the views together cannot average away; the base housing's offset absorbs what they share.
fn reading_correlation(same_view: bool, delta: f64) -> f64 {
    let periodic = (delta.cos() + (2.0 * delta).cos()) / 3.0;
    if same_view {
        1.0
    } else {
        periodic
    }
}

/// The joint readings' errors of a run's views as parameters of the joint fit: per view and
/// joint one, in units of the reading's 1σ, correlated between views by
/// [`reading_correlation`]; and one for the run's sag (its size, 1σ the configured
/// deflection's), since the arm sags alike where it stands alike.
struct Readings<'a> {
    /// The views' errors, in order of their parameters.
    views: Vec<(usize, &'a FlangeError)>,
    dof: usize,
    /// Whether there is a sag parameter (after the views' readings).
    sag: bool,
}

impl<'a> Readings<'a> {
    fn new(views: &[View<'a>]) -> Self {
        let mut by_view: BTreeMap<usize, &'a FlangeError> = BTreeMap::new();
        for v in views {
            if let Some(e) = v.flange_error {
                by_view.entry(v.view).or_insert(e);
            }
        }
        let views: Vec<(usize, &FlangeError)> = by_view.into_iter().collect();
        let sigma = views.iter().any(|(_, e)| e.reading_sigma_rad > 0.0);
        let dof = if sigma {
            views
                .iter()
                .map(|(_, e)| e.columns.len())
                .max()
                .unwrap_or(0)
        } else {
            0
        };
        let sag = views
            .iter()
            .any(|(_, e)| e.sag_rad.iter().any(|s| *s != 0.0));
        Self { views, dof, sag }
    }

    fn len(&self) -> usize {
        self.views.len() * self.dof + usize::from(self.sag)
    }

    /// The columns (of `n`, from `first`) by which view `view`'s flange error moves its pose.
    fn columns(&self, view: usize, first: usize, j: &mut DMatrix<f64>) {
        let Some(slot) = self.views.iter().position(|(v, _)| *v == view) else {
            return;
        };
        let e = self.views[slot].1;
        for (k, c) in e.columns.iter().enumerate().take(self.dof) {
            j.view_mut((0, first + slot * self.dof + k), (6, 1))
                .copy_from(&(c * e.reading_sigma_rad));
        }
        if self.sag {
            let sag: nalgebra::Vector6<f64> =
                e.columns.iter().zip(&e.sag_rad).map(|(c, s)| c * *s).sum();
            j.view_mut((0, first + self.views.len() * self.dof), (6, 1))
                .copy_from(&sag);
        }
    }

    /// Adds their prior information to `h` (parameters from `first`).
    fn add_prior(&self, first: usize, h: &mut DMatrix<f64>) -> Option<()> {
        let n = self.views.len();
        for k in 0..self.dof {
            let angle = |slot: usize| self.views[slot].1.joints.get(k).copied().unwrap_or(0.0);
            let r = DMatrix::from_fn(n, n, |a, b| {
                reading_correlation(a == b, angle(a) - angle(b))
            });
            let info = r.try_inverse()?;
            for a in 0..n {
                for b in 0..n {
                    h[(first + a * self.dof + k, first + b * self.dof + k)] += info[(a, b)];
                }
            }
        }
        if self.sag {
            let i = first + n * self.dof;
            h[(i, i)] += 1.0;
        }
        Some(())
    }
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
    let readings = Readings::new(views);
    let first_reading = 6 + q + frame_columns;
    let n = first_reading + readings.len();
    // Each view's data information and information vector, in its own parameters.
    let mut mount = *start;
    let mut covariance = Matrix6::zeros();
    for _ in 0..ROUNDS {
        let mut h = DMatrix::<f64>::zeros(n, n);
        let mut g = DVector::<f64>::zeros(n);
        for v in views {
            let (d, b) = (&v.fit.information, &v.fit.information_vector);
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
            readings.columns(v.view, first_reading, &mut j);
            let predicted = v.model_from_flange * mount;
            let step = predicted * v.fit.model_from_camera.inverse();
            let mut c = DVector::<f64>::zeros(6 + p);
            c.rows_mut(0, 3).copy_from(&step.translation.vector);
            c.rows_mut(3, 3).copy_from(&step.rotation.scaled_axis());
            h += j.transpose() * d * &j * weight;
            g += j.transpose() * (b - d * c) * weight;
        }
        for k in 6..first_reading {
            h[(k, k)] += 1.0;
        }
        readings.add_prior(first_reading, &mut h)?;
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
                view: inputs[i].view,
                frames: per_view[&inputs[i].view],
                flange_error: registrations.get(i)?.flange_error.as_ref(),
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
    let (camera_mm2, camera_deg2) = (camera(|u| u.translation_mm), camera(|u| u.rotation_deg));
    tracing::debug!(
        fit_mm,
        fit_deg,
        camera_mm = camera_mm2.sqrt(),
        camera_deg = camera_deg2.sqrt(),
        "fused views' σ"
    );
    let uncertainty = Uncertainty {
        translation_mm: (fit_mm.powi(2) + camera_mm2 + floor(model_accuracy.0 * 1e3)).sqrt(),
        rotation_deg: (fit_deg.powi(2) + camera_deg2 + floor(model_accuracy.1.to_degrees())).sqrt(),
        workspace: None,
    };
    Some((fused.flange_from_camera, uncertainty))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    /// A view's fit with a pose covariance and two link parameters correlated with it (the
    /// links' prior included).
    fn fit(model_from_camera: Isometry3<f64>, z: [f64; 2]) -> LinkFit {
        let mut cov = DMatrix::<f64>::identity(8, 8) * 1e-8;
        for k in 0..6 {
            cov[(k, k)] = 1e-8 * (k + 1) as f64;
        }
        cov[(6, 6)] = 0.5;
        cov[(7, 7)] = 0.8;
        cov[(0, 6)] = 2e-5;
        cov[(6, 0)] = 2e-5;
        let posterior = cov.try_inverse().expect("positive definite");
        let mut information = posterior.clone();
        for k in 6..8 {
            information[(k, k)] -= 1.0;
        }
        let mean = DVector::from_row_slice(&[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, z[0], z[1]]);
        LinkFit {
            params: vec![
                LinkParam::Housing { depth: 0, index: 0 },
                LinkParam::Housing { depth: 0, index: 1 },
            ],
            z: DVector::from_row_slice(&z),
            information,
            information_vector: posterior * mean,
            model_from_camera,
        }
    }

    /// The pose block of a view's covariance, its links' prior included (model frame).
    fn pose_covariance(f: &LinkFit) -> Matrix6<f64> {
        f.posterior_information()
            .try_inverse()
            .expect("covariance")
            .fixed_view::<6, 6>(0, 0)
            .into_owned()
    }

    /// A model-frame pose covariance of a view at `model_from_flange`, in the flange frame.
    fn in_flange_frame(cov: &Matrix6<f64>, model_from_flange: &Isometry3<f64>) -> Matrix6<f64> {
        let inv = adjoint(model_from_flange)
            .try_inverse()
            .expect("invertible");
        inv * cov * inv.transpose()
    }

    /// A flange pose's error of covariance `cov` (six joints, a reading error of 1σ each,
    /// every joint at `angle`).
    fn flange_error(cov: &Matrix6<f64>, angle: f64) -> FlangeError {
        let l = cov.cholesky().expect("positive definite").l();
        FlangeError {
            joints: vec![angle; 6],
            columns: (0..6).map(|k| l.column(k).into_owned()).collect(),
            reading_sigma_rad: 1.0,
            sag_rad: vec![0.0; 6],
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
                view: 0,
                frames: 1,
                flange_error: None,
            }],
            &(off * mount),
            None,
        )
        .expect("fused");
        let d = fused.flange_from_camera.inverse() * mount;
        assert!(d.translation.vector.norm() < 1e-9, "{d:?}");
        assert!(d.rotation.angle() < 1e-9, "{d:?}");
        let want = in_flange_frame(&pose_covariance(&f), &model_from_flange);
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
        let error = flange_error(&flange, 0.0);
        let view = View {
            model_from_flange,
            fit: &f,
            view: 0,
            frames: 1,
            flange_error: Some(&error),
        };
        let fused = fuse_views(&[view], &mount, None).expect("fused");
        let want = in_flange_frame(&(pose_covariance(&f) + flange), &model_from_flange);
        assert!(
            (fused.covariance - want).norm() < 1e-6 * want.norm(),
            "{} vs {}",
            fused.covariance,
            want
        );
        // Two views whose flange poses are off by more than their scans' σ, their joints
        // turned so far that their readings' errors are independent: the fused covariance
        // keeps about half of one view's flange error.
        let flange2 = Isometry3::new(Vector3::new(-0.2, 0.3, 0.4), Vector3::new(-0.6, 0.8, 1.0));
        let f2 = fit(flange2 * mount, [0.2, -0.1]);
        let error2 = flange_error(&flange, std::f64::consts::FRAC_PI_3);
        let second = View {
            model_from_flange: flange2,
            fit: &f2,
            view: 1,
            flange_error: Some(&error2),
            ..view
        };
        let honest = fuse_views(&[view, second], &mount, None).expect("fused");
        let trusting = fuse_views(
            &[
                View {
                    flange_error: None,
                    ..view
                },
                View {
                    flange_error: None,
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
            view: 0,
            frames: 2,
            flange_error: None,
        };
        let two = fuse_views(&[view, view], &mount, None).expect("fused");
        let one = fuse_views(&[View { frames: 1, ..view }], &mount, None).expect("fused");
        assert!((two.covariance - one.covariance).norm() < 1e-9 * one.covariance.norm());
    }
}
