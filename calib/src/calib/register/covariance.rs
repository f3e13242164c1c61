//! Stage 4, `verify` (its covariance): the result's covariance in the camera frame, its 1-σ
//! summary and the directions the visible geometry leaves unconstrained.

use nalgebra::{Isometry3, Matrix3, Matrix6, Vector6};

use super::{RegisterOptions, Uncertainty};
use crate::calib::fine::IcpResult;

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
/// the structured-light camera's.
fn smooth_depth_error(estimate: &IcpResult) -> Matrix6<f64> {
    // The per-pixel noise is in the spread too, but not shared: the residuals' patch sums
    // already count it.
    let own = TUNED_RESIDUAL_SPREAD_M.max(estimate.pixel_noise_m);
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
/// each one's 1σ ([`RegisterOptions::fixed_depth_error`]) times how far it moves the pose
/// ([`IcpResult::pose_per_fixed_depth`]).
fn fixed_depth_error(estimate: &IcpResult, opts: &RegisterOptions) -> Matrix6<f64> {
    let (scale, offset_m) = opts.fixed_depth_error;
    let [by_scale, by_offset] = estimate.pose_per_fixed_depth;
    by_scale * by_scale.transpose() * scale.powi(2)
        + by_offset * by_offset.transpose() * offset_m.powi(2)
}

/// The covariance of a shift of `metres` and a turn of `radians` (each the 1σ length of the
/// 3-vector), in any direction.
fn isotropic(metres: f64, radians: f64) -> Matrix6<f64> {
    let (t, r) = (metres.powi(2) / 3.0, radians.powi(2) / 3.0);
    Matrix6::from_diagonal(&Vector6::new(t, t, t, r, r, r))
}

/// Covariance in the camera frame (inflated), its 1-σ summary and the degenerate directions.
///
/// `estimate` is the fit whose pose is returned (its covariance is the result's, plus the
/// model's accuracy); `even` is the fit that trusts the posed links, whose information tells
/// which directions the visible geometry constrains.
pub(super) fn uncertainty(
    estimate: &IcpResult,
    even: &IcpResult,
    camera_from_model: &Isometry3<f64>,
    opts: &RegisterOptions,
) -> (Matrix6<f64>, Uncertainty, Vec<Vector6<f64>>) {
    let r: Matrix3<f64> = camera_from_model.rotation.to_rotation_matrix().into_inner();
    let t = camera_from_model.translation.vector;
    let mut ad = Matrix6::zeros();
    ad.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
    ad.fixed_view_mut::<3, 3>(0, 3)
        .copy_from(&(t.cross_matrix() * r));
    ad.fixed_view_mut::<3, 3>(3, 3).copy_from(&r);
    let (floor_m, floor_rad) = opts.model_accuracy;
    let floor = isotropic(floor_m, floor_rad);
    let cov = ad
        * (estimate.cov6 + smooth_depth_error(estimate) + fixed_depth_error(estimate, opts))
        * ad.transpose()
        + floor;
    let tr = |k: usize| {
        (cov[(k, k)] + cov[(k + 1, k + 1)] + cov[(k + 2, k + 2)])
            .max(0.0)
            .sqrt()
    };
    let unc = Uncertainty {
        translation_mm: tr(0) * 1000.0,
        rotation_deg: tr(3).to_degrees(),
    };
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
    (cov, unc, degenerate)
}
