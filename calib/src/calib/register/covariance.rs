//! Stage 4, `verify` (its covariance): the result's covariance in the camera frame, its 1-σ
//! summary and the directions the visible geometry leaves unconstrained.

use nalgebra::{Isometry3, Matrix3, Matrix6, Vector6};

use super::{RegisterOptions, Uncertainty};
use crate::calib::fine::IcpResult;

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
    let floor = Matrix6::from_diagonal(&Vector6::new(
        floor_m.powi(2) / 3.0,
        floor_m.powi(2) / 3.0,
        floor_m.powi(2) / 3.0,
        floor_rad.powi(2) / 3.0,
        floor_rad.powi(2) / 3.0,
        floor_rad.powi(2) / 3.0,
    ));
    let cov = ad * estimate.cov6 * ad.transpose() + floor;
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
