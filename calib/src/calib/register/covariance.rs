//! Stage 4, `verify` (its covariance): the result's covariance in the camera frame, its 1-σ
//! summary and the directions the visible geometry leaves unconstrained.

use nalgebra::{Isometry3, Matrix3, Matrix3x6, Matrix6, Matrix6x4, Vector3, Vector6};

use super::{RegisterOptions, Uncertainty, WorkspaceSigma};
use crate::calib::fine::IcpResult;
use crate::frames::adjoint;

/// The residual spread ([`IcpResult::residual_spread_m`]) of the scans the registration was
/// tuned on and the uncertainty checked against: the simulator's structured-light camera leaves
/// 0.02–0.09 mm against a nominal model.
const TUNED_RESIDUAL_SPREAD_M: f64 = 0.15e-3;

/// Share of the scan's residual spread beyond [`TUNED_RESIDUAL_SPREAD_M`] that may move the pose
/// as a whole, fitted on the simulator's active-stereo class (whose smooth depth errors match
/// the real frames', see `calib/tests/realdata.rs`): without it the reported σ there was 1.4×
/// too small and 27 of 810 wrong results passed the gate; with it error / σ has a median of
/// 0.85 in translation and 0.66 in rotation (`handeye bench --camera realsense-d435`).
const SMOOTH_ERROR_SHARE: f64 = 0.6;

/// The covariance a smooth depth error adds, in the fit's parameters (`cov6`'s: model-frame
/// translation and rotation). A sensor whose depth is bent in blobs and waves wider than the
/// fit's patches, or across the whole image (stereo matching on weakly textured surfaces, a
/// depth-scale or a low-order distortion), moves every patch together: the cluster-robust
/// covariance cannot see it, the residual spread can. Its excess over the tuned spread, times
/// [`SMOOTH_ERROR_SHARE`], is taken as a shift of that size and a turn of that size over the
/// correspondences' extent, about their centroid, in any direction. Zero for scans as clean as
/// the structured-light camera's. With [`RegisterOptions::smooth_error_beyond_pixel_noise`] the
/// excess is over the scan's per-pixel noise when that is larger.
pub(super) fn smooth_depth_error(estimate: &IcpResult, opts: &RegisterOptions) -> Matrix6<f64> {
    // The per-pixel noise is in the spread too; where it is not shared, the residuals' patch
    // sums already count it.
    let own = if opts.smooth_error_beyond_pixel_noise {
        TUNED_RESIDUAL_SPREAD_M.max(estimate.pixel_noise_m)
    } else {
        TUNED_RESIDUAL_SPREAD_M
    };
    let excess = (estimate.residual_spread_m.powi(2) - own.powi(2))
        .max(0.0)
        .sqrt()
        * SMOOTH_ERROR_SHARE;
    let turn = excess / estimate.spread_m.max(0.01);
    let about_centroid = isotropic(excess, turn);
    // A turn φ about the centroid c is the turn φ about the origin and a shift c × φ.
    let mut to_origin = Matrix6::identity();
    to_origin
        .fixed_view_mut::<3, 3>(0, 3)
        .copy_from(&estimate.centroid.coords.cross_matrix());
    to_origin * about_centroid * to_origin.transpose()
}

/// The covariance the depth parameters the fit did not estimate add, in the fit's parameters:
/// each one's 1σ ([`RegisterOptions::fixed_depth_error`],
/// [`RegisterOptions::depth_gradient_error`]) times how far it moves the pose
/// ([`IcpResult::pose_per_fixed_depth`], [`IcpResult::pose_per_depth_gradient`]).
fn fixed_depth_error(estimate: &IcpResult, opts: &RegisterOptions) -> Matrix6x4<f64> {
    let (scale, offset_m) = opts.fixed_depth_error;
    let [by_scale, by_offset] = estimate.pose_per_fixed_depth;
    let [by_x, by_y] = estimate.pose_per_depth_gradient;
    let g = opts.depth_gradient_error;
    Matrix6x4::from_columns(&[by_scale * scale, by_offset * offset_m, by_x * g, by_y * g])
}

/// The covariance of a shift of `metres` and a turn of `radians` (each the 1σ length of the
/// 3-vector), in any direction.
fn isotropic(metres: f64, radians: f64) -> Matrix6<f64> {
    let (t, r) = (metres.powi(2) / 3.0, radians.powi(2) / 3.0);
    Matrix6::from_diagonal(&Vector6::new(t, t, t, r, r, r))
}

/// Root-sum-square 1-σ (metres) of the position of the point `p` (camera frame, metres) under
/// the pose covariance `cov` (a left perturbation `(ρ, φ)` in the camera frame, as
/// [`super::Registration::covariance_6x6`]): the point moves by `ρ + φ × p = J·(ρ, φ)` with
/// `J = [I, −[p]×]`, so its covariance is `J·cov·Jᵀ`. At `p = 0` the camera origin's σ.
pub(crate) fn position_sigma_m(cov: &Matrix6<f64>, p: &Vector3<f64>) -> f64 {
    let mut j = Matrix3x6::zeros();
    j.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&Matrix3::identity());
    j.fixed_view_mut::<3, 3>(0, 3).copy_from(&-p.cross_matrix());
    rss(&(j * cov * j.transpose())).sqrt()
}

/// The 1σ of a pose covariance's rotation (a left perturbation `(ρ, φ)`, rad²): the
/// root-sum-square of its rotation block, degrees.
pub(crate) fn rotation_sigma_deg(cov: &Matrix6<f64>) -> f64 {
    rss(&cov.fixed_view::<3, 3>(3, 3).into_owned())
        .sqrt()
        .to_degrees()
}

/// Trace of a 3×3 covariance (the root-sum-square variance), clamped at 0.
fn rss(cov: &Matrix3<f64>) -> f64 {
    cov.trace().max(0.0)
}

/// The 1-σ summary of a camera-frame pose covariance `cov` (see
/// [`super::Registration::covariance_6x6`]); `base` is the model origin in the camera frame.
pub(crate) fn summary(cov: &Matrix6<f64>, base: &Vector3<f64>) -> Uncertainty {
    Uncertainty {
        translation_mm: position_sigma_m(cov, &Vector3::zeros()) * 1000.0,
        rotation_deg: rotation_sigma_deg(cov),
        workspace: Some(WorkspaceSigma {
            translation_mm: position_sigma_m(cov, base) * 1000.0,
            distance_m: base.norm(),
        }),
    }
}

/// Covariance in the camera frame (inflated), how the camera's own depth errors move the pose
/// (camera frame, one column per error at its 1σ: [`super::Registration::camera_error_columns`]),
/// its 1-σ summary, the summary of the part the
/// camera's own depth errors give ([`super::Registration::camera_error`]) and the degenerate
/// directions.
///
/// `estimate` is the fit whose pose is returned (its covariance is the result's, plus the
/// model's accuracy); `even` is the fit that trusts the posed links, whose information tells
/// which directions the visible geometry constrains.
pub(super) fn uncertainty(
    estimate: &IcpResult,
    even: &IcpResult,
    camera_from_model: &Isometry3<f64>,
    opts: &RegisterOptions,
) -> (
    Matrix6<f64>,
    Matrix6x4<f64>,
    Uncertainty,
    Uncertainty,
    Vec<Vector6<f64>>,
) {
    let r: Matrix3<f64> = camera_from_model.rotation.to_rotation_matrix().into_inner();
    let ad = adjoint(camera_from_model);
    let (floor_m, floor_rad) = opts.model_accuracy;
    let floor = isotropic(floor_m, floor_rad);
    let columns = ad * fixed_depth_error(estimate, opts);
    let camera = columns * columns.transpose();
    let cov =
        ad * (estimate.cov6 + smooth_depth_error(estimate, opts)) * ad.transpose() + camera + floor;
    let base = camera_from_model.translation.vector;
    let (unc, camera_error) = (summary(&cov, &base), summary(&camera, &base));
    // Degeneracy: eigen-decomposition of the information about the correspondences' centroid
    // c (so rotations and translations decouple), rotations scaled by their spread L.
    // ρ = ρ' + [c]× φ maps the centred parameters to the model-origin ones.
    let c = even.centroid.coords;
    let mut a = Matrix6::identity();
    a.fixed_view_mut::<3, 3>(0, 3).copy_from(&c.cross_matrix());
    let l = even.spread_m.max(0.01);
    let s = Matrix6::from_diagonal(&Vector6::new(1.0, 1.0, 1.0, 1.0 / l, 1.0 / l, 1.0 / l));
    let to_origin = a * s;
    let info = to_origin.transpose() * even.info6 * to_origin;
    let eig = info.symmetric_eigen();
    let lmax = eig.eigenvalues.max();
    tracing::debug!(ratios = ?eig.eigenvalues.iter().map(|e| e / lmax).collect::<Vec<_>>(), "information eigenvalues");
    let mut degenerate = Vec::new();
    for k in 0..6 {
        if eig.eigenvalues[k] < opts.degeneracy_ratio * lmax {
            let v = eig.eigenvectors.column(k);
            let mut dc = Vector6::zeros();
            dc.fixed_rows_mut::<3>(0)
                .copy_from(&(r * v.fixed_rows::<3>(0)));
            dc.fixed_rows_mut::<3>(3)
                .copy_from(&(r * v.fixed_rows::<3>(3)));
            degenerate.push(dc.normalize());
        }
    }
    (cov, columns, unc, camera_error, degenerate)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Matrix6x3;
    use rand::SeedableRng;
    use rand_distr::{Distribution, StandardNormal};

    /// A fixed camera that only turns about the robot base 1.5 m away (σ 0.03° per axis):
    /// the base stays where it is, the camera origin moves by the turn times the lever.
    #[test]
    fn a_turn_about_a_point_leaves_it_in_place_and_moves_the_camera_origin() {
        let p = Vector3::new(0.3, -0.2, 1.5);
        let s = 0.03f64.to_radians();
        // δ = (ρ, φ) with ρ = −φ × p = [p]× φ: a turn φ about p.
        let mut a = Matrix6x3::zeros();
        a.fixed_view_mut::<3, 3>(0, 0).copy_from(&p.cross_matrix());
        a.fixed_view_mut::<3, 3>(3, 0)
            .copy_from(&Matrix3::identity());
        let cov = a * Matrix3::identity() * s.powi(2) * a.transpose();
        assert!(
            position_sigma_m(&cov, &p) < 1e-9,
            "{}",
            position_sigma_m(&cov, &p)
        );
        // [p]× has the singular values |p|, |p|, 0.
        let at_origin = position_sigma_m(&cov, &Vector3::zeros());
        assert!(
            (at_origin - s * p.norm() * 2f64.sqrt()).abs() < 1e-12,
            "{at_origin}"
        );
        // A pure shift is the same everywhere.
        let shift = isotropic(0.2e-3, 0.0);
        assert!((position_sigma_m(&shift, &p) - 0.2e-3).abs() < 1e-15);
        assert!((position_sigma_m(&shift, &Vector3::zeros()) - 0.2e-3).abs() < 1e-15);
    }

    /// The point-moved σ matches the spread of the point under poses drawn from a correlated
    /// covariance (Monte Carlo, 20 000 draws).
    #[test]
    fn the_point_sigma_matches_a_monte_carlo_of_the_pose() {
        // A correlated covariance: L·Lᵀ of a fixed lower-triangular L (metres, radians).
        let l = Matrix6::from_fn(|i, j| {
            let scale = |k: usize| if k < 3 { 0.3e-3 } else { 0.4e-3 };
            match i.cmp(&j) {
                std::cmp::Ordering::Less => 0.0,
                std::cmp::Ordering::Equal => scale(i),
                std::cmp::Ordering::Greater => 0.5 * scale(i) * ((i * 7 + j * 3) % 5) as f64 / 4.0,
            }
        });
        let cov = l * l.transpose();
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        let p = nalgebra::Point3::new(-0.4, 0.25, 1.8);
        for point in [nalgebra::Point3::origin(), p] {
            let n = 20_000;
            let mut sum_sq = 0.0;
            for _ in 0..n {
                let z = Vector6::from_fn(|_, _| StandardNormal.sample(&mut rng));
                let d = l * z;
                let pose = Isometry3::new(
                    d.fixed_rows::<3>(0).into_owned(),
                    d.fixed_rows::<3>(3).into_owned(),
                );
                sum_sq += (pose * point - point).norm_squared();
            }
            let mc = (sum_sq / n as f64).sqrt();
            let analytic = position_sigma_m(&cov, &point.coords);
            assert!(
                (mc / analytic - 1.0).abs() < 0.03,
                "at {point}: Monte Carlo {mc}, analytic {analytic}"
            );
        }
    }
}
