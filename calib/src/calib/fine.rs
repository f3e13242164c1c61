//! Fine alignment: robust point-to-plane ICP of scan points against the exact model triangles,
//! optionally with the camera's depth scale and range offset as parameters, and the information
//! matrix of the result.
//!
//! Correspondences go scan → model: the nearest surface sample of *any* link gives the triangle;
//! a point whose nearest link is beyond the fitted chain depth is explained by the rest of the
//! arm and dropped, as are points whose normal disagrees with the triangle's (floor next to the
//! base, edges). The residual is the signed distance to the triangle's plane at its closest
//! point; a Cauchy kernel down-weights CAD mismatch, cables, bolts and flying pixels.
//!
//! Parameters: `model_from_camera` is updated by a left perturbation `exp(δ)` in the model frame,
//! `δ = (ρ, φ)` (metres, radians); scan points are corrected by [`DepthCorrection`] (true =
//! κ · measured + ε · the pixel's unit ray). Parameter order: ρ, φ, κ, ε, then the links'.

use nalgebra::{
    DMatrix, DVector, Isometry3, Matrix6, Matrix6xX, Point3, SMatrix, SVector, Translation3,
    UnitQuaternion, Vector3,
};
use rayon::prelude::*;

use super::coarse::Oriented;
use super::links::{LinkFit, LinkParam, ScanInformation};
use super::surface::ModelSurface;

/// Parameters of the fit before the links': the pose (ρ, φ), the depth scale κ and the range
/// correction ε.
const NP: usize = 8;
/// Index of κ and ε among the parameters.
const SCALE: usize = 6;
const OFFSET: usize = 7;
type MatP = SMatrix<f64, NP, NP>;
/// Residual scale of [`IcpResult::sharpness`], metres.
const SHARP_M: f64 = 0.0005;
type VecP = SVector<f64, NP>;
/// Edge of the model-frame cubes whose residuals [`patch_scores`] treats as one error,
/// metres.
const PATCH_M: f64 = 0.06;
/// Correspondence gate of [`IcpResult::residual_spread_m`], in kernel scales: wide enough that
/// a spread of a few kernel scales is measured, not cut off.
const SPREAD_GATE_KERNELS: f64 = 12.0;
/// Scan points on the moving links below which [`IcpResult::sharpness_moving`] says nothing.
const MIN_MOVING_POINTS: usize = 30;
/// Largest depth-scale error a fit may estimate unless the camera's class says less (real
/// cameras are within a few percent); beyond it the fit is ill-conditioned (too little depth
/// relief in the correspondences) and the scale is pinned to 1 for the rest of the run.
pub(crate) const MAX_SCALE_ERROR: f64 = 0.05;
/// Largest range offset the fit may estimate, metres (a time-of-flight camera's uncalibrated
/// systematic error is up to about a centimetre); beyond it the offset is pinned to 0, as the
/// scale is beyond [`MAX_SCALE_ERROR`].
pub(crate) const MAX_RANGE_OFFSET_M: f64 = 0.02;

/// How the camera's depths are corrected before they meet the model: true point =
/// `kappa` × measured point + `range_m` × the pixel's unit ray (camera frame). A depth-scale
/// error (triangulation) is `kappa`; a constant range offset (time of flight: every pixel's
/// distance off by the same length along its ray) is `range_m`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct DepthCorrection {
    /// True depth = `kappa` × measured depth (before `range_m`).
    pub(crate) kappa: f64,
    /// Added along each pixel's ray, metres: the measured range is `range_m` short.
    pub(crate) range_m: f64,
}

impl DepthCorrection {
    /// No correction.
    pub(crate) const NONE: DepthCorrection = DepthCorrection {
        kappa: 1.0,
        range_m: 0.0,
    };

    /// The corrected camera-frame point of the measured `p`.
    pub(crate) fn apply(&self, p: &Vector3<f64>) -> Vector3<f64> {
        p * self.kappa + unit_ray(p) * self.range_m
    }

    /// The measured camera-frame point of the true `p` (the inverse of [`Self::apply`]).
    pub(crate) fn measured(&self, p: &Vector3<f64>) -> Vector3<f64> {
        (p - unit_ray(p) * self.range_m) / self.kappa
    }

    /// The camera's depth scale (measured / true distance).
    pub(crate) fn depth_scale(&self) -> f64 {
        1.0 / self.kappa
    }

    /// The camera's range offset (measured − true distance), metres.
    pub(crate) fn range_offset_m(&self) -> f64 {
        -self.range_m / self.kappa
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn depth_correction_moves_points_along_their_rays_and_back() {
        let c = DepthCorrection {
            kappa: 0.999,
            range_m: -0.003,
        };
        let measured = Vector3::new(0.2, -0.1, 0.6);
        let truth = c.apply(&measured);
        // Along the ray: the same direction, 3 mm shorter after the scale.
        assert!(truth.normalize().cross(&measured.normalize()).norm() < 1e-12);
        assert!((truth.norm() - (0.999 * measured.norm() - 0.003)).abs() < 1e-12);
        assert!((c.measured(&truth) - measured).norm() < 1e-12);
        // The camera's ranges are long: a positive offset, in mm after the scale.
        assert!((c.range_offset_m() - 0.003 / 0.999).abs() < 1e-12);
        assert!((c.depth_scale() - 1.0 / 0.999).abs() < 1e-12);
        assert_eq!(DepthCorrection::NONE.apply(&measured), measured);
    }

    /// A point the ICP skips because its last search found nothing near it is one a search
    /// would not find either: over twenty small moves of the pose, every point's answer with
    /// what it carries from the move before is the answer of a fresh search, and most points
    /// off the model are skipped.
    #[test]
    fn a_point_skipped_as_far_from_the_model_is_one_a_search_would_not_find() {
        use rand::{Rng, SeedableRng};
        let surface = ModelSurface::new(
            &crate::calib::testutil::toy_robot(&[0.3, -0.8, 0.6]),
            2,
            0.002,
            0.012,
        );
        let mut rng = rand::rngs::StdRng::seed_from_u64(5);
        let pts: Vec<Oriented> = (0..3000)
            .map(|_| Oriented {
                p: Point3::new(
                    rng.random_range(-0.25..0.25),
                    rng.random_range(-0.25..0.25),
                    rng.random_range(-0.05..0.45),
                ),
                n: Vector3::z(),
            })
            .collect();
        let st = Stage {
            gate_m: 0.01,
            kernel_m: 0.003,
            scale: None,
            offset: false,
            iterations: 1,
        };
        let answer = |found: Option<Result<Correspondence, u8>>| {
            found.map(|f| f.map(|c| (c.x, c.r, c.w, c.depth)))
        };
        let mut clear = vec![Clearance::default(); pts.len()];
        let mut t = Isometry3::identity();
        let (mut skipped, mut found) = (0, 0);
        for _ in 0..20 {
            t = Isometry3::new(
                Vector3::new(0.0004, -0.0003, 0.0002),
                Vector3::new(0.001, 0.0, -0.0005),
            ) * t;
            for (o, c) in pts.iter().zip(&mut clear) {
                if c.rules_out(&(t * o.p), st.gate_m) {
                    skipped += 1;
                }
                let carried = correspond(o, &surface, &t, &DepthCorrection::NONE, &st, &[], c);
                let fresh = correspond(
                    o,
                    &surface,
                    &t,
                    &DepthCorrection::NONE,
                    &st,
                    &[],
                    &mut Clearance::default(),
                );
                found += usize::from(fresh.is_some());
                assert_eq!(answer(carried), answer(fresh), "point {:?}", o.p);
            }
        }
        assert!(found > 500, "{found} correspondences");
        assert!(skipped > 20 * 1000, "{skipped} skipped");
    }
}

/// `p / |p|` (zero at the origin).
fn unit_ray(p: &Vector3<f64>) -> Vector3<f64> {
    p.try_normalize(1e-12).unwrap_or_else(Vector3::zeros)
}

/// One stage of the ICP schedule.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Stage {
    /// Correspondence gate, metres.
    pub(crate) gate_m: f64,
    /// Cauchy kernel scale, metres.
    pub(crate) kernel_m: f64,
    /// Whether the depth scale is a free parameter in this stage: `Some(largest error)` it may
    /// reach before it is taken as ill-conditioned and pinned to 1 for the rest of the run.
    pub(crate) scale: Option<f64>,
    /// Whether the range offset is a free parameter in this stage.
    pub(crate) offset: bool,
    /// Iteration cap.
    pub(crate) iterations: usize,
}

/// Result of [`icp`].
#[derive(Debug, Clone)]
pub(crate) struct IcpResult {
    pub(crate) model_from_camera: Isometry3<f64>,
    /// The depths' correction.
    pub(crate) depth: DepthCorrection,
    /// Whether `depth.kappa` was estimated (false when no stage freed it or the fit fell back
    /// to a fixed scale because it left the stage's bound).
    pub(crate) scale_estimated: bool,
    /// Whether `depth.range_m` was estimated (false when no stage freed it or the fit fell
    /// back to none because it left `± MAX_RANGE_OFFSET_M`).
    pub(crate) offset_estimated: bool,
    /// How the pose moves per unit error of each depth parameter the fit did *not* estimate
    /// (entry 0 the scale κ, 1 the range correction ε, metres): `δ = −H⁻¹ ∂g` over the
    /// parameters in use, model-frame left perturbation; zero for an estimated one. An error
    /// of that parameter the fit left out moves the pose by this much, unseen by the residuals.
    pub(crate) pose_per_fixed_depth: [nalgebra::Vector6<f64>; 2],
    /// How the pose moves per unit (1/m) of a depth error that grows across the image, which
    /// no fit estimates: measured depth = true × (1 + z · g · x/z) (entry 0) or
    /// (1 + z · g · y/z) (entry 1), x/z and y/z the pixel's normalized image coordinates. A
    /// stereo camera whose imagers are turned slightly against their calibration measures so
    /// (a disparity bias that varies across the image); over the arm it looks like a turn of
    /// the pose, so the residuals cannot tell it. Same convention as
    /// [`Self::pose_per_fixed_depth`].
    pub(crate) pose_per_depth_gradient: [nalgebra::Vector6<f64>; 2],
    /// Information matrix of the 6 pose parameters (estimated depth parameters marginalised
    /// out), weighted, not yet scaled by the residual variance.
    pub(crate) info6: Matrix6<f64>,
    /// Cluster-robust covariance of the 6 pose parameters (model-frame left perturbation),
    /// m² / rad².
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
    /// Robust spread (1.4826 × the median absolute deviation) of the signed residuals of the
    /// scan points within [`SPREAD_GATE_KERNELS`] kernel scales of the converged model, metres:
    /// the scan's error against the model as the fit sees it, smooth depth errors included
    /// (which the scan's per-pixel noise does not show).
    pub(crate) residual_spread_m: f64,
    /// The scan's per-pixel noise, metres (the registration sets it from the range image; 0
    /// when unknown): the part of [`Self::residual_spread_m`] that each point has on its own.
    pub(crate) pixel_noise_m: f64,
    /// Mean over the scan points in the model's neighbourhood of `1 / (1 + (r / 0.5 mm)²)`
    /// (0 for points without a correspondence): how tightly the scan hugs the model, 0–1.
    /// Tells a right pose from a nearly symmetric wrong one whose fit is merely good.
    pub(crate) sharpness: f64,
    /// [`Self::sharpness`] of the scan points whose nearest model surface is on a moving link
    /// (shoulder, upper arm): the parts that break the base's rotational symmetry. Equal to
    /// `sharpness` when fewer than `MIN_MOVING_POINTS` scan points lie on them.
    pub(crate) sharpness_moving: f64,
}

#[derive(Debug, Clone, Default)]
struct Acc {
    h: MatP,
    g: VecP,
    /// `(Σ w J Jᵀ, Σ w r J)` per chain depth of the fitted link (0..=fit depth), when asked for:
    /// the links' displacements enter the normal equations through them.
    by_depth: Vec<(MatP, VecP)>,
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
    fn new(depths: usize) -> Acc {
        Acc {
            by_depth: vec![(MatP::zeros(), VecP::zeros()); depths],
            ..Acc::default()
        }
    }

    fn merge(mut self, o: Acc) -> Acc {
        self.h += o.h;
        self.g += o.g;
        for (a, b) in self.by_depth.iter_mut().zip(o.by_depth) {
            a.0 += b.0;
            a.1 += b.1;
        }
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

    /// Adds one scan point's standing against the model (see [`correspond`]).
    fn add(&mut self, found: Result<Correspondence, u8>, kernel_m: f64) {
        let depth = match &found {
            Ok(c) => c.depth,
            Err(d) => *d,
        };
        self.near += 1;
        self.near_moving += usize::from(depth >= 1);
        let Ok(c) = found else { return };
        self.sharp += c.sharp;
        if c.depth >= 1 {
            self.sharp_moving += c.sharp;
        }
        let h = c.j * c.j.transpose() * c.w;
        let g = c.j * (c.w * c.r);
        self.h += h;
        self.g += g;
        // Links deeper than the displaced ones stay where they are posed: the last slot.
        let slot = (c.depth as usize).min(self.by_depth.len().saturating_sub(1));
        if let Some(d) = self.by_depth.get_mut(slot) {
            d.0 += h;
            d.1 += g;
        }
        self.wsum += c.w;
        self.n += 1;
        self.wx += c.x.coords * c.w;
        self.wxx += c.w * c.x.coords.norm_squared();
        if c.r.abs() < 3.0 * kernel_m {
            self.close += 1;
            self.r2_close += c.r * c.r;
        }
    }
}

/// One scan point's correspondence with the model at the current estimate.
struct Correspondence {
    /// Model-frame point.
    x: Point3<f64>,
    /// Jacobian of the residual in (ρ, φ, κ, ε).
    j: VecP,
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
/// `links[d]` is the estimated displacement of the links at chain depth `d` (see
/// [`super::links`]); the model surface there is taken as moved by it (empty: as posed).
/// `clear`: what the point's previous search found (see [`Clearance`]), updated.
fn correspond(
    o: &Oriented,
    surface: &ModelSurface,
    t: &Isometry3<f64>,
    depth: &DepthCorrection,
    st: &Stage,
    links: &[Isometry3<f64>],
    clear: &mut Clearance,
) -> Option<Result<Correspondence, u8>> {
    let cos_min = 0.5;
    let rp = t.rotation * o.p.coords;
    let x = Point3::from(t.rotation * depth.apply(&o.p.coords) + t.translation.vector);
    let radius = st.gate_m.max(0.01);
    if clear.rules_out(&x, radius) {
        return None;
    }
    let found = surface.nearest_with_distance(&x, radius + CLEARANCE_SLACK_M);
    *clear = Clearance {
        at: x,
        m: found.map_or(radius + CLEARANCE_SLACK_M, |(_, d)| d),
    };
    let (s, s_m) = found.filter(|(_, d)| *d <= radius)?;
    // Multipath: where the model faces other surface the scan's depths are biased; those
    // points are not used, as if they were not near the fitted links.
    if s.depth as usize > surface.fit_depth || s.biased {
        return None;
    }
    // The point against the link as posed: undo the link's displacement, and look again from
    // there (near an edge a millimetre decides the triangle). The sample nearest `back` is no
    // farther than `s` is from it, so the search needs no wider radius than that.
    let (s, on_posed) = match links.get(s.depth as usize) {
        Some(m) => {
            let back = m.inverse_transform_point(&x);
            let moved = (back - x).norm();
            if moved == 0.0 {
                (s, back)
            } else {
                let r = (s_m + moved + 1e-6).min(st.gate_m.max(0.01));
                match surface.nearest(&back, r) {
                    Some(b) if b.depth == s.depth => (b, back),
                    _ => (s, back),
                }
            }
        }
        None => (s, x),
    };
    let tri = &surface.triangles[s.tri as usize];
    let c = tri.closest_point(&on_posed);
    if (on_posed - c).norm() > st.gate_m || (t.rotation * o.n).dot(&tri.n) < cos_min {
        return Some(Err(s.depth));
    }
    let n = tri.n;
    let r = n.dot(&(on_posed - c));
    let u = r / st.kernel_m;
    let w = 1.0 / (1.0 + u * u);
    let mut j = VecP::zeros();
    j.fixed_rows_mut::<3>(0).copy_from(&n);
    j.fixed_rows_mut::<3>(3).copy_from(&x.coords.cross(&n));
    j[SCALE] = n.dot(&rp);
    j[OFFSET] = n.dot(&unit_ray(&rp));
    Some(Ok(Correspondence {
        x,
        j,
        r,
        w,
        sharp: 1.0 / (1.0 + (r / SHARP_M).powi(2)),
        depth: s.depth,
    }))
}

/// The normal equations and fit statistics of `pts` at `t`, `depth`, the links displaced by
/// `links` (see [`correspond`]); when `links` is not empty, also per chain depth
/// `0..links.len()` and one slot for deeper links (not displaced).
/// `clear`: per point, what its previous search found ([`correspond`]).
fn accumulate(
    pts: &[Oriented],
    surface: &ModelSurface,
    t: &Isometry3<f64>,
    depth: &DepthCorrection,
    st: &Stage,
    links: &[Isometry3<f64>],
    clear: &mut [Clearance],
) -> Acc {
    // One slot past the displaced depths for points the links do not move.
    let depths = if links.is_empty() { 0 } else { links.len() + 1 };
    let chunk = |(c, clear): (&[Oriented], &mut [Clearance])| {
        let mut a = Acc::new(depths);
        for (o, clear) in c.iter().zip(clear) {
            if let Some(found) = correspond(o, surface, t, depth, st, links, clear) {
                a.add(found, st.kernel_m);
            }
        }
        a
    };
    if pts.len() > 2000 {
        // Summed in the chunks' order, not as the threads finish: the same scan gives the same
        // result to the last bit, however the work was shared.
        pts.par_chunks(1024)
            .zip(clear.par_chunks_mut(1024))
            .map(chunk)
            .collect::<Vec<Acc>>()
            .into_iter()
            .fold(Acc::new(depths), Acc::merge)
    } else {
        chunk((pts, clear))
    }
}

/// What a scan point's last search of the model found: no sample within `m` metres of `at`
/// (where the point was). The pose moves little between iterations, so a point far from the
/// model stays far, and its search is skipped while it cannot have come within the radius.
/// `Default`: nothing known, the point is searched.
#[derive(Debug, Clone, Copy, Default)]
struct Clearance {
    at: Point3<f64>,
    m: f64,
}

impl Clearance {
    /// Whether no sample can be within `radius` of `x`: none was within `m` of where the point
    /// was, and it has moved less than the difference.
    fn rules_out(&self, x: &Point3<f64>, radius: f64) -> bool {
        self.m - (x - self.at).norm() > radius
    }
}

/// How much farther than the radius a point's search looks, metres: what it finds beyond the
/// radius is not used, but it lets the next iterations skip the point while it moves less.
const CLEARANCE_SLACK_M: f64 = 0.003;

/// The scores of the converged fit's correspondences summed per 6 cm patch of the model (and
/// chain depth): `ψ = Σ w r J` of each patch. Residuals of neighbouring points are not
/// independent (a CAD deviation or a depth bias moves a whole patch together); a covariance
/// that counts them as independent evidence is overconfident by the square root of the points
/// per patch. `Σ ψ ψᵀ` is the "meat" of a cluster-robust sandwich covariance, in which a shared
/// error counts once.
///
/// From the same correspondences, per chain depth (`depths` of them, deeper links with the
/// base), `Σ w J ∂r/∂g` of the two depth gradients of [`IcpResult::pose_per_depth_gradient`]:
/// a relative depth error z · g · x/z (or y/z) moves the point along its ray as the scale
/// does, by that fraction.
fn patch_scores(
    pts: &[Oriented],
    surface: &ModelSurface,
    t: &Isometry3<f64>,
    depth: &DepthCorrection,
    st: &Stage,
    links: &[Isometry3<f64>],
    depths: usize,
) -> (Vec<(u8, VecP)>, Vec<SMatrix<f64, NP, 2>>) {
    // Ordered by key: the patches' scores are summed in the same order on every run.
    let mut patches: std::collections::BTreeMap<(i32, i32, i32, u8), VecP> =
        std::collections::BTreeMap::new();
    let mut gradients = vec![SMatrix::<f64, NP, 2>::zeros(); depths.max(1)];
    for o in pts {
        let Some(Ok(c)) = correspond(o, surface, t, depth, st, links, &mut Clearance::default())
        else {
            continue;
        };
        let key = (
            (c.x.x / PATCH_M).floor() as i32,
            (c.x.y / PATCH_M).floor() as i32,
            (c.x.z / PATCH_M).floor() as i32,
            c.depth,
        );
        *patches.entry(key).or_insert_with(VecP::zeros) += c.j * (c.w * c.r);
        let along = nalgebra::RowVector2::new(o.p.x, o.p.y) * c.j[SCALE];
        let d = (c.depth as usize).min(gradients.len() - 1);
        gradients[d] += c.j * (c.w * along);
    }
    (
        patches.into_iter().map(|(k, psi)| (k.3, psi)).collect(),
        gradients,
    )
}

/// 1.4826 × the median absolute deviation of the signed residuals of `pts` (see
/// [`IcpResult::residual_spread_m`]); 0 without correspondences.
fn residual_spread(
    pts: &[Oriented],
    surface: &ModelSurface,
    t: &Isometry3<f64>,
    depth: &DepthCorrection,
    st: &Stage,
    links: &[Isometry3<f64>],
) -> f64 {
    let wide = Stage {
        gate_m: SPREAD_GATE_KERNELS * st.kernel_m,
        ..*st
    };
    let mut r: Vec<f64> = pts
        .par_iter()
        .filter_map(|o| {
            match correspond(
                o,
                surface,
                t,
                depth,
                &wide,
                links,
                &mut Clearance::default(),
            ) {
                Some(Ok(c)) => Some(c.r),
                _ => None,
            }
        })
        .collect();
    if r.is_empty() {
        return 0.0;
    }
    let mid = r.len() / 2;
    let median = *r.select_nth_unstable_by(mid, f64::total_cmp).1;
    for x in &mut r {
        *x = (*x - median).abs();
    }
    1.4826 * *r.select_nth_unstable_by(mid, f64::total_cmp).1
}

/// The columns of the normal equations (pose, depth and `prior`'s link parameters) of the two
/// depth gradients, from their per-depth sums (see [`patch_scores`]).
fn gradient_columns(by_depth: &[SMatrix<f64, NP, 2>], prior: &LinkPrior) -> DMatrix<f64> {
    let p = prior.params();
    let mut cols = DMatrix::zeros(NP + p, 2);
    for (d, m) in by_depth.iter().enumerate() {
        let mut top = cols.view_mut((0, 0), (NP, 2));
        top += m;
        if let Some(a) = prior.a.get(d) {
            let mut rest = cols.view_mut((NP, 0), (p, 2));
            rest -= a.transpose() * m.fixed_view::<6, 2>(0, 0);
        }
    }
    cols
}

/// Robust point-to-plane ICP from `init` (`model_from_camera`) through the `stages`.
pub(crate) fn icp(
    pts: &[Oriented],
    surface: &ModelSurface,
    init: &Isometry3<f64>,
    depth0: DepthCorrection,
    stages: &[Stage],
) -> Option<IcpResult> {
    icp_with_links(pts, surface, init, depth0, stages, &LinkPrior::none()).map(|(r, _)| r)
}

/// The fitted links' displacements as parameters of the fit (see [`super::links`]): the
/// displacement of depth `d` (0: the base) is `a[d] · z` with `z ~ N(0, I)`, weighed against the scan's
/// residuals as if their variance were `residual_var` (m²; the effective variance of the fit
/// without them, which counts a patch's shared error once).
#[derive(Debug, Clone)]
pub(crate) struct LinkPrior {
    pub(crate) a: Vec<Matrix6xX<f64>>,
    /// What each column of `a` is.
    pub(crate) params: Vec<LinkParam>,
    pub(crate) residual_var: f64,
}

impl LinkPrior {
    /// No link parameters: the links are where the model is posed.
    pub(crate) fn none() -> Self {
        Self {
            a: Vec::new(),
            params: Vec::new(),
            residual_var: 0.0,
        }
    }

    /// How many link parameters there are (0: the links are trusted as posed).
    pub(crate) fn params(&self) -> usize {
        self.a.first().map_or(0, |m| m.ncols())
    }

    /// The displacements of depths `0..` at `z`, as isometries.
    fn displacements(&self, z: &DVector<f64>) -> Vec<Isometry3<f64>> {
        self.a
            .iter()
            .map(|a| {
                let tw = a * z;
                Isometry3::new(
                    Vector3::new(tw[0], tw[1], tw[2]),
                    Vector3::new(tw[3], tw[4], tw[5]),
                )
            })
            .collect()
    }

    /// The normal equations of pose, depth and link parameters from the per-depth sums (the
    /// residual's derivative by `z` at depth `d` is `−J₆ᵀ a[d]`) and the prior at `z`.
    fn normal_equations(
        &self,
        by_depth: &[(MatP, VecP)],
        z: &DVector<f64>,
    ) -> (DMatrix<f64>, DVector<f64>) {
        let p = self.params();
        let n = NP + p;
        let mut h = DMatrix::zeros(n, n);
        let mut g = DVector::zeros(n);
        for (d, (hd, gd)) in by_depth.iter().enumerate() {
            let mut hv = h.view_mut((0, 0), (NP, NP));
            hv += hd;
            let mut gv = g.rows_mut(0, NP);
            gv += gd;
            let Some(a) = self.a.get(d) else {
                continue;
            };
            // ∂r/∂z = −a ᵀ J₆: cross terms −H₈₆ a, link block aᵀ H₆₆ a, gradient −aᵀ g₆.
            let hp6 = hd.fixed_view::<NP, 6>(0, 0);
            let cross = -(hp6 * a);
            let mut hv = h.view_mut((0, NP), (NP, p));
            hv += &cross;
            let mut hv = h.view_mut((NP, 0), (p, NP));
            hv += cross.transpose();
            let h66 = hd.fixed_view::<6, 6>(0, 0);
            let mut hv = h.view_mut((NP, NP), (p, p));
            hv += a.transpose() * h66 * a;
            let mut gv = g.rows_mut(NP, p);
            gv -= a.transpose() * gd.fixed_rows::<6>(0);
        }
        for k in 0..p {
            h[(NP + k, NP + k)] += self.residual_var;
            g[NP + k] += self.residual_var * z[k];
        }
        (h, g)
    }
}

/// [`icp`] with the fitted links' displacements estimated alongside (see [`LinkPrior`]);
/// returns the fit and the link parameters with their covariance. The fit's covariance is the
/// pose block of the joint sandwich: what the links' prior leaves undetermined is in it.
pub(crate) fn icp_with_links(
    pts: &[Oriented],
    surface: &ModelSurface,
    init: &Isometry3<f64>,
    depth0: DepthCorrection,
    stages: &[Stage],
    prior: &LinkPrior,
) -> Option<(IcpResult, LinkFit)> {
    let p = prior.params();
    let with_links = p > 0;
    let mut t = *init;
    let mut depth = depth0;
    let mut z = DVector::zeros(p);
    let mut last: Option<(Stage, f64)> = None;
    let (mut scale_ok, mut offset_ok) = (true, true);
    // Pins parameter `k` (row and column zeroed, unit diagonal) in a system of any size.
    let pin = |k: usize, h: &mut DMatrix<f64>, g: &mut DVector<f64>| {
        h.row_mut(k).fill(0.0);
        h.column_mut(k).fill(0.0);
        h[(k, k)] = 1.0;
        g[k] = 0.0;
    };
    // The fit as it stood before a depth parameter was first freed: an estimate that leaves
    // its bound has dragged the pose along, and the fit starts again from there without it.
    let mut before_depth: Option<(Isometry3<f64>, DVector<f64>)> = None;
    let mut clear = vec![Clearance::default(); pts.len()];
    for st in stages {
        let mut it = 0;
        while it < st.iterations {
            let free = Stage {
                scale: st.scale.filter(|_| scale_ok),
                offset: st.offset && offset_ok,
                ..*st
            };
            let links = prior.displacements(&z);
            let a = accumulate(pts, surface, &t, &depth, st, &links, &mut clear);
            if a.n < 12 {
                return None;
            }
            let (mut h, mut g) = if with_links {
                prior.normal_equations(&a.by_depth, &z)
            } else {
                (
                    DMatrix::from_column_slice(NP, NP, a.h.as_slice()),
                    DVector::from_column_slice(a.g.as_slice()),
                )
            };
            for (k, is_free) in [(SCALE, free.scale.is_some()), (OFFSET, free.offset)] {
                if !is_free {
                    pin(k, &mut h, &mut g);
                }
            }
            // Light Levenberg damping for robustness far from the optimum.
            let mut hd = h.clone();
            for k in 0..hd.nrows() {
                hd[(k, k)] += 1e-9 + 1e-6 * h[(k, k)];
            }
            let mut delta = -hd.clone().cholesky()?.solve(&g);
            // An ill-conditioned depth parameter (too little depth relief in the
            // correspondences) falls back to none for the rest of the run.
            let scale_wild = free
                .scale
                .is_some_and(|max| (depth.kappa + delta[SCALE] - 1.0).abs() > max);
            let offset_wild =
                free.offset && (depth.range_m + delta[OFFSET]).abs() > MAX_RANGE_OFFSET_M;
            if scale_wild || offset_wild {
                if scale_wild {
                    scale_ok = false;
                    depth.kappa = 1.0;
                    pin(SCALE, &mut hd, &mut g);
                }
                if offset_wild {
                    offset_ok = false;
                    depth.range_m = 0.0;
                    pin(OFFSET, &mut hd, &mut g);
                }
                if let Some((t0, z0)) = before_depth.take() {
                    (t, z) = (t0, z0);
                    depth = DepthCorrection::NONE;
                    it = 0;
                    continue;
                }
                delta = -hd.cholesky()?.solve(&g);
            }
            if before_depth.is_none() && (free.scale.is_some() || free.offset) {
                before_depth = Some((t, z.clone()));
            }
            let rho = Vector3::new(delta[0], delta[1], delta[2]);
            let phi = Vector3::new(delta[3], delta[4], delta[5]);
            let step = Isometry3::from_parts(
                Translation3::from(rho),
                UnitQuaternion::from_scaled_axis(phi),
            );
            t = step * t;
            depth.kappa += delta[SCALE];
            depth.range_m += delta[OFFSET];
            z += delta.rows(NP, p);
            last = Some((
                Stage {
                    scale: free.scale.filter(|_| scale_ok),
                    offset: free.offset && offset_ok,
                    ..*st
                },
                st.kernel_m,
            ));
            let links_small = delta.rows(NP, p).amax() < 1e-3;
            let small = rho.norm() < 2e-7
                && phi.norm() < 2e-7
                && delta[SCALE].abs() < 1e-7
                && delta[OFFSET].abs() < 1e-7;
            if small && links_small && it > 0 {
                break;
            }
            it += 1;
        }
    }
    let (fin, kernel) = last?;
    // Final information at the converged pose.
    let st = Stage {
        gate_m: 3.0 * kernel.max(0.001),
        kernel_m: kernel,
        iterations: 1,
        ..fin
    };
    let links = prior.displacements(&z);
    let a = accumulate(pts, surface, &t, &depth, &st, &links, &mut clear);
    if a.n < 12 {
        return None;
    }
    // The estimated depth parameters, and the pinned ones.
    let free_depth: Vec<usize> = [(SCALE, st.scale.is_some()), (OFFSET, st.offset)]
        .iter()
        .filter_map(|&(k, f)| f.then_some(k))
        .collect();
    let h66: Matrix6<f64> = a.h.fixed_view::<6, 6>(0, 0).into_owned();
    let info6 = if free_depth.is_empty() {
        h66
    } else {
        // Schur complement: the estimated depth parameters marginalised out.
        let hpp = DMatrix::from_column_slice(NP, NP, a.h.as_slice());
        let hdd = hpp.select_rows(&free_depth).select_columns(&free_depth);
        let hpd = hpp.view((0, 0), (6, NP)).select_columns(&free_depth);
        match hdd.try_inverse() {
            Some(inv) => {
                let m = &hpd * inv * hpd.transpose();
                h66 - Matrix6::from_iterator(m.iter().copied())
            }
            None => h66,
        }
    };
    // Cluster-robust ("sandwich") covariance H⁻¹ M H⁻¹ over the parameters in use (pose, the
    // estimated depth parameters, the link parameters), the rest marginalised by taking the
    // pose block of the full inverse. The links' prior adds its own information to H and, as
    // the variance of its score, to M.
    let (h, _) = if with_links {
        prior.normal_equations(&a.by_depth, &z)
    } else {
        (
            DMatrix::from_column_slice(NP, NP, a.h.as_slice()),
            DVector::zeros(NP),
        )
    };
    let used: Vec<usize> = (0..NP + p)
        .filter(|&k| (k != SCALE || st.scale.is_some()) && (k != OFFSET || st.offset))
        .collect();
    let (patches, gradients) =
        patch_scores(pts, surface, &t, &depth, &st, &links, prior.a.len() + 1);
    let residual_spread_m = residual_spread(pts, surface, &t, &depth, &st, &links);
    let mut meat = DMatrix::zeros(NP + p, NP + p);
    for (d, psi) in &patches {
        let mut full = DVector::zeros(NP + p);
        full.rows_mut(0, NP).copy_from(psi);
        if let Some(a) = prior.a.get(*d as usize) {
            let psi6 = psi.fixed_rows::<6>(0);
            full.rows_mut(NP, p).copy_from(&(-(a.transpose() * psi6)));
        }
        meat += &full * full.transpose();
    }
    for k in 0..p {
        meat[(NP + k, NP + k)] += prior.residual_var.powi(2);
    }
    // Degrees of freedom the fit spends on the scan: the pose, the depth parameters, and of the
    // link parameters only what the scan determines beyond their prior,
    // tr(H_data (H_data + s²I)⁻¹).
    let link_dof = if with_links {
        let prior_info = DMatrix::identity(p, p) * prior.residual_var;
        let data = h.view((NP, NP), (p, p)) - &prior_info;
        (data.clone() + prior_info)
            .try_inverse()
            .map_or(p as f64, |inv| (data * inv).trace())
    } else {
        0.0
    };
    let dof = 6.0 + free_depth.len() as f64 + link_dof;
    let h_used = h.select_rows(&used).select_columns(&used);
    let meat_used = meat.select_rows(&used).select_columns(&used);
    let h_inv = h_used.clone().try_inverse()?;
    let small_sample = patches.len() as f64 / (patches.len() as f64 - dof).max(1.0);
    // The pose block of the sandwich (the link parameters' is the scan information's below).
    let pose_rows = h_inv.rows(0, 6);
    let cov = pose_rows * &meat_used * pose_rows.transpose() * small_sample;
    let cov6: Matrix6<f64> = cov.fixed_view::<6, 6>(0, 0).into_owned();
    // The pose and the link parameters (the depth parameters marginalised).
    let pose_and_links: Vec<usize> = used
        .iter()
        .enumerate()
        .filter(|&(_, &k)| !(6..NP).contains(&k))
        .map(|(i, _)| i)
        .collect();
    let link_prior: Vec<(usize, f64)> = used
        .iter()
        .enumerate()
        .filter(|&(_, &k)| k >= NP)
        .map(|(i, _)| (i, prior.residual_var))
        .collect();
    // The fit's estimate where it was linearised: the pose and depth at zero, the links at z.
    let at = DVector::from_iterator(
        used.len(),
        used.iter().map(|&k| if k >= NP { z[k - NP] } else { 0.0 }),
    );
    let scan = ScanInformation::new(
        &h_used,
        &meat_used,
        &link_prior,
        &at,
        &pose_and_links,
        small_sample,
    )?;
    // An error of a depth parameter the fit does not estimate shifts the gradient by its
    // column of H: the pose follows by −H⁻¹ of that column over the parameters in use.
    let pose_shift = |col: nalgebra::DVectorView<'_, f64>| {
        let shift = -(&h_inv * col.select_rows(&used));
        nalgebra::Vector6::from_iterator(shift.rows(0, 6).iter().copied())
    };
    let pose_per_fixed_depth = [SCALE, OFFSET].map(|k| {
        if used.contains(&k) {
            return nalgebra::Vector6::zeros();
        }
        pose_shift(h.column(k))
    });
    let gradient_columns = gradient_columns(&gradients, prior);
    let pose_per_depth_gradient = [0, 1].map(|k| pose_shift(gradient_columns.column(k)));
    Some((
        IcpResult {
            model_from_camera: t,
            pose_per_depth_gradient,
            depth,
            scale_estimated: st.scale.is_some(),
            offset_estimated: st.offset,
            pose_per_fixed_depth,
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
            residual_spread_m,
            pixel_noise_m: 0.0,
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
        },
        LinkFit {
            params: prior.params.clone(),
            z,
            information: scan.information,
            information_vector: scan.vector,
            model_from_camera: t,
        },
    ))
}
