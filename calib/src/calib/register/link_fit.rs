//! Stage 3, `fine` (second part): the winner refitted with the fitted links' kinematic error
//! as parameters of the fit, each with a prior of the arm's calibration size
//! ([`crate::calib::links`]): the base holds what it can, the moving links add what they know
//! beyond their kinematic error.

use nalgebra::Isometry3;

use super::contenders::Judged;
use super::prepare::Prepared;
use super::RegisterOptions;
use crate::calib::fine::{icp_with_links, IcpResult, LinkPrior, Stage};
use crate::calib::links::link_error_model;
use crate::calib::links::LinkFit;
use crate::calib::surface::PosedModel;
use crate::calib::CalibError;

/// The judged winner refitted with the links' kinematic error: its `camera_from_model`, fit
/// and link parameters (`None` when the links are trusted as posed). The contenders were
/// judged on the fit that trusts the posed links, and a refinement that wanders off is not
/// trusted: an error rather than a covariance that leaves the links' error out.
pub(super) fn refine_with_links(
    p: &Prepared<'_>,
    model: &PosedModel,
    judged: &Judged,
    opts: &RegisterOptions,
) -> Result<(Isometry3<f64>, IcpResult, Option<LinkFit>), CalibError> {
    let (fine, camera_from_model) = (&judged.fine, judged.pose);
    // The scan's residual variance that weighs the links' prior is the even fit's effective
    // one (its sandwich over its information).
    let links = link_error_model(model, p.surface.fit_depth, &opts.kinematic_error);
    let link_prior = LinkPrior {
        a: links.a,
        params: links.params,
        residual_var: (fine.cov6 * fine.info6).trace() / 6.0,
    };
    if link_prior.params() == 0 {
        return Ok((camera_from_model, fine.clone(), None));
    }
    let pts = p.pool.select(
        &p.range,
        &p.surface,
        &camera_from_model,
        opts.max_icp_points,
        p.m(0.01),
        p.m(0.003),
    );
    let stage = Stage {
        gate_m: p.m(0.004),
        kernel_m: p.m(0.001),
        scale: fine.scale_estimated.then_some(opts.max_depth_scale_error),
        offset: fine.offset_estimated,
        iterations: 15,
    };
    // How far the refit may move the pose: the scan's noise widens it.
    let (allowed_m, allowed_deg) = (p.m(0.01), 2.0 * p.k);
    match icp_with_links(
        &pts,
        &p.surface,
        &fine.model_from_camera,
        fine.depth,
        &[stage],
        &link_prior,
    ) {
        Some((r, fit))
            if crate::calib::within(
                &r.model_from_camera.inverse(),
                &camera_from_model,
                allowed_m,
                allowed_deg,
            ) =>
        {
            tracing::debug!(z = ?fit.z.as_slice(), "link parameters (prior 1σ units)");
            Ok((r.model_from_camera.inverse(), r, Some(fit)))
        }
        Some((r, _)) => {
            let moved = r.model_from_camera * camera_from_model;
            Err(CalibError::RobotNotFound {
                detail: format!(
                    "the fit with the arm's kinematic error moved {:.0} mm / {:.1}° from the best pose, more than the {:.0} mm / {:.1}° this scan's noise allows: on this scan the links' error cannot be told from the pose (depth bent by the camera, or too little of the arm in view)",
                    moved.translation.vector.norm() * 1e3,
                    moved.rotation.angle().to_degrees(),
                    allowed_m * 1e3,
                    allowed_deg
                ),
            })
        }
        None => Err(CalibError::RobotNotFound {
            detail: "the fit with the arm's kinematic error did not converge near the best pose"
                .into(),
        }),
    }
}
