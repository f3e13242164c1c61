//! Fine alignment: robust point-to-plane ICP of scan points against the exact model triangles,
//! optionally with the camera's depth scale as a 7th parameter, and the information matrix of
//! the result.
//!
//! Correspondences go scan → model: the nearest surface sample of *any* link gives the triangle;
//! a point whose nearest link is beyond the fitted chain depth is explained by the rest of the
//! arm and dropped, as are points whose normal disagrees with the triangle's (floor next to the
//! base, edges). The residual is the signed distance to the triangle's plane at its closest
//! point; a Cauchy kernel down-weights CAD mismatch, cables, bolts and flying pixels.
//!
//! Parameters: `model_from_camera` is updated by a left perturbation `exp(δ)` in the model frame,
//! `δ = (ρ, φ)` (metres, radians); scan points are multiplied by `κ` (true = κ · measured).

use nalgebra::{
    Isometry3, Matrix6, Point3, SMatrix, SVector, Translation3, UnitQuaternion, Vector3,
};
use rayon::prelude::*;

use super::coarse::Oriented;
use super::surface::ModelSurface;

type Mat7 = SMatrix<f64, 7, 7>;
/// Residual scale of [`IcpResult::sharpness`], metres.
const SHARP_M: f64 = 0.0005;
type Vec7 = SVector<f64, 7>;
/// Scan points on the moving links below which [`IcpResult::sharpness_moving`] says nothing.
const MIN_MOVING_POINTS: usize = 30;
/// Largest depth-scale error the 7-parameter fit may estimate (real cameras are within a few
/// percent); beyond it the fit is ill-conditioned (too little depth relief in the
/// correspondences) and the scale is pinned to 1 for the rest of the run.
pub(crate) const MAX_SCALE_ERROR: f64 = 0.05;

/// One stage of the ICP schedule.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Stage {
    /// Correspondence gate, metres.
    pub(crate) gate_m: f64,
    /// Cauchy kernel scale, metres.
    pub(crate) kernel_m: f64,
    /// Whether the depth scale is a free parameter in this stage.
    pub(crate) scale: bool,
    /// Iteration cap.
    pub(crate) iterations: usize,
    /// Weight of correspondences on the moving links (chain depth ≥ 1) relative to the base.
    pub(crate) moving_weight: f64,
}

/// Result of [`icp`].
#[derive(Debug, Clone)]
pub(crate) struct IcpResult {
    pub(crate) model_from_camera: Isometry3<f64>,
    /// True depth = `kappa` × measured depth.
    pub(crate) kappa: f64,
    /// Whether `kappa` was estimated (false when no stage freed it or the fit fell back to
    /// a fixed scale because it left `1 ± MAX_SCALE_ERROR`).
    pub(crate) scale_estimated: bool,
    /// Information matrix of the 6 pose parameters (scale marginalised out when estimated),
    /// weighted, not yet scaled by the residual variance.
    pub(crate) info6: Matrix6<f64>,
    /// Covariance of the 6 pose parameters (model-frame left perturbation), m² / rad².
    pub(crate) cov6: Matrix6<f64>,
    /// Weighted centroid of the correspondences, model frame (metres).
    pub(crate) centroid: Point3<f64>,
    /// RMS distance of the correspondences from their centroid, metres.
    pub(crate) spread_m: f64,
    /// Correspondences accepted in the last iteration.
    pub(crate) n_used: usize,
    /// RMS of residuals of correspondences within 3 kernel scales, metres.
    pub(crate) rmse_m: f64,
    /// Fraction of scan points (inside the model's neighbourhood) within 3 kernel scales.
    pub(crate) inlier_fraction: f64,
    /// Mean over the scan points in the model's neighbourhood of `1 / (1 + (r / 0.5 mm)²)`
    /// (0 for points without a correspondence): how tightly the scan hugs the model, 0–1.
    /// Tells a right pose from a nearly symmetric wrong one whose fit is merely good.
    pub(crate) sharpness: f64,
    /// [`Self::sharpness`] of the scan points whose nearest model surface is on a moving link
    /// (shoulder, upper arm): the parts that break the base's rotational symmetry. Equal to
    /// `sharpness` when fewer than `MIN_MOVING_POINTS` scan points lie on them.
    pub(crate) sharpness_moving: f64,
}

#[derive(Debug, Clone, Copy, Default)]
struct Acc {
    h: Mat7,
    g: Vec7,
    wsum: f64,
    wr2: f64,
    n: usize,
    close: usize,
    r2_close: f64,
    near: usize,
    sharp: f64,
    near_moving: usize,
    sharp_moving: f64,
    /// Σ w·x and Σ w·|x|² of the model-frame points (centroid and spread).
    wx: Vector3<f64>,
    wxx: f64,
}

impl Acc {
    fn add(mut self, o: Acc) -> Acc {
        self.h += o.h;
        self.g += o.g;
        self.wsum += o.wsum;
        self.wr2 += o.wr2;
        self.n += o.n;
        self.close += o.close;
        self.r2_close += o.r2_close;
        self.near += o.near;
        self.sharp += o.sharp;
        self.near_moving += o.near_moving;
        self.sharp_moving += o.sharp_moving;
        self.wx += o.wx;
        self.wxx += o.wxx;
        self
    }
}

fn accumulate(
    pts: &[Oriented],
    surface: &ModelSurface,
    t: &Isometry3<f64>,
    kappa: f64,
    st: &Stage,
) -> Acc {
    let cos_min = 0.5;
    let one = |o: &Oriented| -> Acc {
        let mut a = Acc::default();
        let rp = t.rotation * o.p.coords;
        let x = Point3::from(rp * kappa + t.translation.vector);
        let Some(s) = surface.nearest(&x, st.gate_m.max(0.01)) else {
            return a;
        };
        if s.depth as usize > surface.fit_depth {
            return a;
        }
        a.near = 1;
        a.near_moving = usize::from(s.depth >= 1);
        let tri = &surface.triangles[s.tri as usize];
        let c = tri.closest_point(&x);
        if (x - c).norm() > st.gate_m {
            return a;
        }
        if (t.rotation * o.n).dot(&tri.n) < cos_min {
            return a;
        }
        let n = tri.n;
        let r = n.dot(&(x - c));
        a.sharp = 1.0 / (1.0 + (r / SHARP_M).powi(2));
        if s.depth >= 1 {
            a.sharp_moving = a.sharp;
        }
        let u = r / st.kernel_m;
        let w = if s.depth >= 1 { st.moving_weight } else { 1.0 } / (1.0 + u * u);
        let mut j = Vec7::zeros();
        j.fixed_rows_mut::<3>(0).copy_from(&n);
        j.fixed_rows_mut::<3>(3).copy_from(&x.coords.cross(&n));
        j[6] = n.dot(&rp);
        a.h = j * j.transpose() * w;
        a.g = j * (w * r);
        a.wsum = w;
        a.wr2 = w * r * r;
        a.n = 1;
        a.wx = x.coords * w;
        a.wxx = w * x.coords.norm_squared();
        if r.abs() < 3.0 * st.kernel_m {
            a.close = 1;
            a.r2_close = r * r;
        }
        a
    };
    if pts.len() > 2000 {
        pts.par_chunks(1024)
            .map(|c| c.iter().map(one).fold(Acc::default(), Acc::add))
            .reduce(Acc::default, Acc::add)
    } else {
        pts.iter().map(one).fold(Acc::default(), Acc::add)
    }
}

/// Robust point-to-plane ICP from `init` (`model_from_camera`) through the `stages`.
pub(crate) fn icp(
    pts: &[Oriented],
    surface: &ModelSurface,
    init: &Isometry3<f64>,
    kappa0: f64,
    stages: &[Stage],
) -> Option<IcpResult> {
    let mut t = *init;
    let mut kappa = kappa0;
    let mut last: Option<(Acc, bool, f64, f64)> = None;
    let mut scale_ok = true;
    for st in stages {
        for it in 0..st.iterations {
            let free_scale = st.scale && scale_ok;
            let a = accumulate(pts, surface, &t, kappa, st);
            if a.n < 12 {
                return None;
            }
            let mut h = a.h;
            let mut g = a.g;
            if !free_scale {
                // Pin the scale: zero its row/column, unit diagonal.
                for k in 0..7 {
                    h[(6, k)] = 0.0;
                    h[(k, 6)] = 0.0;
                }
                h[(6, 6)] = 1.0;
                g[6] = 0.0;
            }
            // Light Levenberg damping for robustness far from the optimum.
            let mut hd = h;
            for k in 0..7 {
                hd[(k, k)] += 1e-9 + 1e-6 * h[(k, k)];
            }
            let chol = hd.cholesky()?;
            let mut delta = -chol.solve(&g);
            if free_scale && (kappa + delta[6] - 1.0).abs() > MAX_SCALE_ERROR {
                // Ill-conditioned scale: fall back to the fixed nominal scale.
                scale_ok = false;
                kappa = 1.0;
                for k in 0..7 {
                    hd[(6, k)] = 0.0;
                    hd[(k, 6)] = 0.0;
                }
                hd[(6, 6)] = 1.0;
                g[6] = 0.0;
                delta = -hd.cholesky()?.solve(&g);
            }
            let rho = Vector3::new(delta[0], delta[1], delta[2]);
            let phi = Vector3::new(delta[3], delta[4], delta[5]);
            let step = Isometry3::from_parts(
                Translation3::from(rho),
                UnitQuaternion::from_scaled_axis(phi),
            );
            t = step * t;
            kappa += delta[6];
            last = Some((a, free_scale, st.kernel_m, st.moving_weight));
            let small = rho.norm() < 2e-7 && phi.norm() < 2e-7 && delta[6].abs() < 1e-7;
            if small && it > 0 {
                break;
            }
        }
    }
    let (_, scaled, kernel, last_moving) = last?;
    // Final information at the converged pose.
    let st = Stage {
        gate_m: 3.0 * kernel.max(0.001),
        kernel_m: kernel,
        scale: scaled,
        iterations: 1,
        moving_weight: last_moving,
    };
    let a = accumulate(pts, surface, &t, kappa, &st);
    if a.n < 12 {
        return None;
    }
    let dof = if scaled { 7.0 } else { 6.0 };
    let sigma2 = a.wr2 / a.wsum * (a.n as f64 / (a.n as f64 - dof).max(1.0));
    let h66: Matrix6<f64> = a.h.fixed_view::<6, 6>(0, 0).into_owned();
    let h6: nalgebra::Vector6<f64> = a.h.fixed_view::<6, 1>(0, 6).into_owned();
    let h77 = a.h[(6, 6)];
    let info6 = if scaled && h77 > 0.0 {
        h66 - h6 * h6.transpose() / h77
    } else {
        h66
    };
    let cov6 = info6
        .try_inverse()
        .map(|m| m * sigma2)
        .unwrap_or_else(|| Matrix6::identity() * 1e6);
    Some(IcpResult {
        model_from_camera: t,
        kappa,
        scale_estimated: scaled,
        info6,
        cov6,
        centroid: Point3::from(a.wx / a.wsum),
        spread_m: (a.wxx / a.wsum - (a.wx / a.wsum).norm_squared())
            .max(0.0)
            .sqrt(),
        n_used: a.n,
        rmse_m: if a.close > 0 {
            (a.r2_close / a.close as f64).sqrt()
        } else {
            f64::INFINITY
        },
        inlier_fraction: if a.near > 0 {
            a.close as f64 / a.near as f64
        } else {
            0.0
        },
        sharpness: if a.near > 0 {
            a.sharp / a.near as f64
        } else {
            0.0
        },
        sharpness_moving: if a.near_moving >= MIN_MOVING_POINTS {
            a.sharp_moving / a.near_moving as f64
        } else if a.near > 0 {
            a.sharp / a.near as f64
        } else {
            0.0
        },
    })
}
