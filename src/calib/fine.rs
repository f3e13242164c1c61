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
    DMatrix, Isometry3, Matrix6, Point3, SMatrix, SVector, Translation3, UnitQuaternion, Vector3,
};
use rayon::prelude::*;

use super::coarse::Oriented;
use super::surface::ModelSurface;

type Mat7 = SMatrix<f64, 7, 7>;
/// Residual scale of [`IcpResult::sharpness`], metres.
const SHARP_M: f64 = 0.0005;
type Vec7 = SVector<f64, 7>;
/// Edge of the model-frame cubes whose residuals [`Reliability::meat`] treats as one error,
/// metres.
const PATCH_M: f64 = 0.03;
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
    /// Cluster-robust covariance of the 6 pose parameters (model-frame left perturbation),
    /// m² / rad².
    pub(crate) cov6: Matrix6<f64>,
    /// How the pose parameters follow small kinematic errors `e` of the arm (see
    /// [`Reliability::kinematic`]): they move by `gain · e`, 6 × 6·joints.
    pub(crate) kinematic_gain: DMatrix<f64>,
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

/// One scan point's correspondence with the model at the current estimate.
struct Correspondence {
    /// Model-frame point.
    x: Point3<f64>,
    /// Normal of the model triangle it fits.
    n: Vector3<f64>,
    /// Jacobian of the residual in (ρ, φ, κ).
    j: Vec7,
    /// Signed point-to-plane residual, metres.
    r: f64,
    /// Robust weight.
    w: f64,
    /// Sharpness term `1 / (1 + (r / SHARP_M)²)`.
    sharp: f64,
    /// Chain depth of the link the point fits.
    depth: u8,
}

/// Where a scan point stands against the model: not near the fitted links, near them but
/// without a usable correspondence (`Err(depth)`), or a correspondence.
fn correspond(
    o: &Oriented,
    surface: &ModelSurface,
    t: &Isometry3<f64>,
    kappa: f64,
    st: &Stage,
) -> Option<Result<Correspondence, u8>> {
    let cos_min = 0.5;
    let rp = t.rotation * o.p.coords;
    let x = Point3::from(rp * kappa + t.translation.vector);
    let s = surface.nearest(&x, st.gate_m.max(0.01))?;
    if s.depth as usize > surface.fit_depth {
        return None;
    }
    let tri = &surface.triangles[s.tri as usize];
    let c = tri.closest_point(&x);
    if (x - c).norm() > st.gate_m || (t.rotation * o.n).dot(&tri.n) < cos_min {
        return Some(Err(s.depth));
    }
    let n = tri.n;
    let r = n.dot(&(x - c));
    let u = r / st.kernel_m;
    let w = if s.depth >= 1 { st.moving_weight } else { 1.0 } / (1.0 + u * u);
    let mut j = Vec7::zeros();
    j.fixed_rows_mut::<3>(0).copy_from(&n);
    j.fixed_rows_mut::<3>(3).copy_from(&x.coords.cross(&n));
    j[6] = n.dot(&rp);
    Some(Ok(Correspondence {
        x,
        n,
        j,
        r,
        w,
        sharp: 1.0 / (1.0 + (r / SHARP_M).powi(2)),
        depth: s.depth,
    }))
}

fn accumulate(
    pts: &[Oriented],
    surface: &ModelSurface,
    t: &Isometry3<f64>,
    kappa: f64,
    st: &Stage,
) -> Acc {
    let one = |o: &Oriented| -> Acc {
        let mut a = Acc::default();
        let Some(found) = correspond(o, surface, t, kappa, st) else {
            return a;
        };
        let depth = match &found {
            Ok(c) => c.depth,
            Err(d) => *d,
        };
        a.near = 1;
        a.near_moving = usize::from(depth >= 1);
        let Ok(c) = found else { return a };
        a.sharp = c.sharp;
        if c.depth >= 1 {
            a.sharp_moving = c.sharp;
        }
        a.h = c.j * c.j.transpose() * c.w;
        a.g = c.j * (c.w * c.r);
        a.wsum = c.w;
        a.n = 1;
        a.wx = c.x.coords * c.w;
        a.wxx = c.w * c.x.coords.norm_squared();
        if c.r.abs() < 3.0 * st.kernel_m {
            a.close = 1;
            a.r2_close = c.r * c.r;
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

/// What the converged fit's correspondences say about the reliability of the pose, beyond
/// the formal information matrix (one pass over the points at the final estimate).
struct Reliability {
    /// Σ over patches of `ψ ψᵀ`, where `ψ` sums the weighted scores `w r J` of a patch's
    /// correspondences: the "meat" of a cluster-robust sandwich covariance. Residuals of
    /// neighbouring points are not independent (a CAD deviation or a depth bias moves a whole
    /// patch together); a covariance that counts them as independent evidence is overconfident
    /// by the square root of the points per patch. Summing per patch lets a shared error count
    /// once.
    meat: Mat7,
    patches: usize,
    /// `Σ w J (∂r/∂e)ᵀ`, 7 × 6·joints: how the normal equations respond to a small error `e`
    /// (translation, rotation in the joint frame) of each joint that moves fitted links. The
    /// model poses the shoulder and upper arm with the nominal kinematics; the real arm's
    /// zero offsets and link lengths move them, and the fit follows them where the base
    /// cannot hold it (its yaw, for a round base).
    kinematic: DMatrix<f64>,
}

fn reliability(
    pts: &[Oriented],
    surface: &ModelSurface,
    t: &Isometry3<f64>,
    kappa: f64,
    st: &Stage,
) -> Reliability {
    let joints = &surface.joint_frames;
    let mut patches: std::collections::HashMap<(i32, i32, i32, u8), Vec7> =
        std::collections::HashMap::new();
    let mut kinematic = DMatrix::zeros(7, 6 * joints.len());
    for o in pts {
        let Some(Ok(c)) = correspond(o, surface, t, kappa, st) else {
            continue;
        };
        let key = (
            (c.x.x / PATCH_M).floor() as i32,
            (c.x.y / PATCH_M).floor() as i32,
            (c.x.z / PATCH_M).floor() as i32,
            c.depth,
        );
        *patches.entry(key).or_insert_with(Vec7::zeros) += c.j * (c.w * c.r);
        // Joint k moves the parts beyond it: a translation e_t (joint frame) moves the point by
        // R e_t, a rotation e_r by (R e_r) × (x − o); the residual changes by n · that.
        for (k, frame) in joints.iter().enumerate().take(c.depth as usize) {
            let rt = frame.rotation.inverse();
            let lever = c.x - Point3::from(frame.translation.vector);
            let d_trans = rt * c.n;
            let d_rot = rt * lever.cross(&c.n);
            for a in 0..3 {
                let mut col = kinematic.column_mut(6 * k + a);
                col += c.j * (c.w * d_trans[a]);
                let mut col = kinematic.column_mut(6 * k + 3 + a);
                col += c.j * (c.w * d_rot[a]);
            }
        }
    }
    Reliability {
        meat: patches.values().map(|psi| psi * psi.transpose()).sum(),
        patches: patches.len(),
        kinematic,
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
    let h66: Matrix6<f64> = a.h.fixed_view::<6, 6>(0, 0).into_owned();
    let h6: nalgebra::Vector6<f64> = a.h.fixed_view::<6, 1>(0, 6).into_owned();
    let h77 = a.h[(6, 6)];
    let info6 = if scaled && h77 > 0.0 {
        h66 - h6 * h6.transpose() / h77
    } else {
        h66
    };
    // Cluster-robust ("sandwich") covariance H⁻¹ M H⁻¹, the scale marginalised by taking the
    // pose block of the full inverse; and the gain of the kinematic errors, H⁻¹ B.
    let rel = reliability(pts, surface, &t, kappa, &st);
    let dim = if scaled { 7 } else { 6 };
    let h_inv = a.h.view((0, 0), (dim, dim)).into_owned().try_inverse()?;
    let small_sample = rel.patches as f64 / (rel.patches as f64 - dof).max(1.0);
    let meat = rel.meat.view((0, 0), (dim, dim)).into_owned();
    let cov6: Matrix6<f64> = (&h_inv * meat * &h_inv * small_sample)
        .fixed_view::<6, 6>(0, 0)
        .into_owned();
    let kinematic_gain = (&h_inv * rel.kinematic.rows(0, dim))
        .rows(0, 6)
        .into_owned();
    Some(IcpResult {
        model_from_camera: t,
        kappa,
        scale_estimated: scaled,
        info6,
        cov6,
        kinematic_gain,
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
