//! Stage 1, `preprocess`: the scan as a range image and its measured noise, the posed model
//! sampled, the pools ICP points are drawn from — and what the later stages do with them:
//! where the camera may be, and the short polishing fit of a hypothesis.

use handeye_hal::PointCloud;
use nalgebra::{Isometry3, Point3, Vector3};

use super::{Candidate, RegisterOptions};
use crate::calib::coarse::Oriented;
use crate::calib::fine::{icp, DepthCorrection, Stage};
use crate::calib::range::RangeImage;
use crate::calib::surface::{ModelSurface, PosedModel};
use crate::calib::verify::{evidence, Tolerances};
use crate::calib::CalibError;

/// The noise of the scans every distance of the registration was chosen for, metres: the
/// simulator's structured-light camera measures 0.02–0.15 mm by [`RangeImage::noise_m`] (its
/// documented 0.25 mm at 1 m is the upper end of its range).
const TUNED_NOISE_M: f64 = 0.25e-3;

/// How far a coarse hypothesis may put the camera beyond the flange reach before it is
/// polished: a 15 mm / 5° Hough cell moves a camera 0.8 m away by up to ~7 cm (metres).
const COARSE_CAMERA_SLACK_M: f64 = 0.1;

/// How much wider than tuned every distance of the registration is for a scan of this
/// measured noise: 1 for scans as precise as the tuning (or when the noise cannot be measured),
/// the noise over [`TUNED_NOISE_M`] for noisier ones (a consumer RGB-D camera at 1.3 m measures
/// about 0.7 mm: 2.9), at most 8.
pub(super) fn noise_scale(noise_m: Option<f64>) -> f64 {
    noise_m.map_or(1.0, |n| (n / TUNED_NOISE_M).clamp(1.0, 8.0))
}

/// What every stage works on.
#[derive(Debug)]
pub(super) struct Prepared<'a> {
    pub(super) range: RangeImage<'a>,
    pub(super) surface: ModelSurface,
    /// Dense pool of scan pixels for the exact fits.
    pub(super) pool: ScanPool,
    /// Sparse pool for polishing: 500 points per hypothesis drawn from it save transforming
    /// 150 000 points for each of a dozen hypotheses.
    pub(super) polish_pool: ScanPool,
    /// The scan's per-pixel noise, metres ([`RangeImage::noise_m`], measured once here).
    pub(super) noise_m: Option<f64>,
    /// Every distance's factor for that noise ([`noise_scale`]).
    pub(super) k: f64,
    /// Eye-in-hand: the camera is at most this far from the posed flange (see
    /// [`RegisterOptions::max_camera_flange_distance_m`]).
    pub(super) reach: Option<(f64, Isometry3<f64>)>,
}

/// Stage 1: checks the scan, measures its noise, samples the model and draws the pools.
pub(super) fn preprocess<'a>(
    scan: &'a PointCloud,
    model: &PosedModel,
    opts: &RegisterOptions,
) -> Result<Prepared<'a>, CalibError> {
    if scan.points.len() != scan.width as usize * scan.height as usize {
        return Err(CalibError::MalformedScan {
            width: scan.width,
            height: scan.height,
            points: scan.points.len(),
        });
    }
    let range = RangeImage::new(scan)?;
    // Every distance of the registration was chosen for scans as precise as the simulator's
    // structured-light camera; a noisier scan widens them in proportion to its own noise.
    let noise_m = range.noise_m();
    let k = noise_scale(noise_m);
    let mut surface = ModelSurface::new(
        model,
        opts.fit_chain_depth,
        opts.sample_spacing_m,
        opts.coarse_spacing_m,
    );
    if let Some(clearance_m) = opts.multipath_clearance_m {
        surface.mark_multipath(clearance_m);
    }
    if surface.coarse.is_empty() {
        return Err(CalibError::NoModelGeometry);
    }
    // Time of flight: the pixels the scan shows biased (multipath, dark surfaces) are not
    // drawn.
    let biased = if opts.multipath_clearance_m.is_some() {
        super::tof::biased_pixels(&range, scan)
    } else {
        Vec::new()
    };
    let pool = ScanPool::new(&range, 150_000, &biased);
    let polish_pool = ScanPool::new(&range, 20_000, &biased);
    Ok(Prepared {
        range,
        surface,
        pool,
        polish_pool,
        noise_m,
        k,
        reach: opts
            .max_camera_flange_distance_m
            .zip(model.model_from_flange),
    })
}

impl Prepared<'_> {
    /// `metres` widened for this scan's noise.
    pub(super) fn m(&self, metres: f64) -> f64 {
        metres * self.k
    }

    /// Whether `camera_from_model` puts the camera within the flange reach (plus `slack_m`).
    pub(super) fn camera_within(&self, camera_from_model: &Isometry3<f64>, slack_m: f64) -> bool {
        self.reach.is_none_or(|(r, model_from_flange)| {
            let camera = camera_from_model.inverse().translation.vector;
            (camera - model_from_flange.translation.vector).norm() <= r + slack_m
        })
    }

    /// Whether a coarse hypothesis is worth polishing (its camera near enough the flange).
    pub(super) fn plausible_seed(&self, camera_from_model: &Isometry3<f64>) -> bool {
        self.camera_within(camera_from_model, COARSE_CAMERA_SLACK_M)
    }

    /// The tolerances of the polishing fit's projective check.
    pub(super) fn quick_tolerances(&self) -> Tolerances {
        Tolerances {
            matched_m: self.m(0.004),
            free_m: self.m(0.008),
        }
    }

    /// A short robust fit of `camera_from_model` on 500 points and its projective evidence;
    /// `None` when it fails or leaves the camera out of the flange's reach.
    pub(super) fn polish(&self, camera_from_model: &Isometry3<f64>) -> Option<Candidate> {
        if !self.plausible_seed(camera_from_model) {
            return None;
        }
        let stages = [
            Stage {
                gate_m: self.m(0.03),
                kernel_m: self.m(0.01),
                scale: None,
                offset: false,
                iterations: 6,
            },
            Stage {
                gate_m: self.m(0.012),
                kernel_m: self.m(0.004),
                scale: None,
                offset: false,
                iterations: 5,
            },
            Stage {
                gate_m: self.m(0.006),
                kernel_m: self.m(0.002),
                scale: None,
                offset: false,
                iterations: 6,
            },
        ];
        let pts = self.polish_pool.select(
            &self.range,
            &self.surface,
            camera_from_model,
            500,
            self.m(0.03),
            self.m(0.003),
        );
        let r = icp(
            &pts,
            &self.surface,
            &camera_from_model.inverse(),
            DepthCorrection::NONE,
            &stages,
        )?;
        let pose = r.model_from_camera.inverse();
        if !self.camera_within(&pose, 0.0) {
            return None;
        }
        let e = evidence(
            &self.range,
            &self.surface.coarse,
            &pose,
            self.surface.fit_depth,
            self.quick_tolerances(),
        );
        Some(Candidate {
            pose,
            e,
            fit: r.sharpness * r.sharpness_moving,
        })
    }
}

/// A coarse grid of scan pixels from which ICP points are drawn per hypothesis.
#[derive(Debug)]
pub(super) struct ScanPool {
    idx: Vec<usize>,
}

impl ScanPool {
    /// About `target` pixels of `range` on a grid, none of those `left_out` marks (empty:
    /// none).
    pub(super) fn new(range: &RangeImage<'_>, target: usize, left_out: &[bool]) -> ScanPool {
        let idx = range
            .grid(target, 31)
            .filter(|&i| range.points[i].z > 0.0 && !left_out.get(i).copied().unwrap_or(false))
            .collect();
        ScanPool { idx }
    }

    /// Up to `n` scan points (with normals, from neighbours `normal_radius_m` away) near the
    /// fitted links posed by `camera_from_model`, `margin_m` around them.
    pub(super) fn select(
        &self,
        range: &RangeImage<'_>,
        surface: &ModelSurface,
        camera_from_model: &Isometry3<f64>,
        n: usize,
        margin_m: f64,
        normal_radius_m: f64,
    ) -> Vec<Oriented> {
        let (lo, hi) = surface.fit_bounds(margin_m);
        let model_from_camera = camera_from_model.inverse();
        let near: Vec<usize> = self
            .idx
            .iter()
            .copied()
            .filter(|&i| {
                let p = model_from_camera * range.points[i].cast::<f64>();
                p.x >= lo.x
                    && p.y >= lo.y
                    && p.z >= lo.z
                    && p.x <= hi.x
                    && p.y <= hi.y
                    && p.z <= hi.z
            })
            .collect();
        let step = (near.len() as f64 / n as f64).max(1.0);
        let mut out = Vec::with_capacity(n.min(near.len()));
        let mut k = 0.0;
        while (k as usize) < near.len() {
            let i = near[k as usize];
            if let (Some(p), Some(nn)) = (range.point(i), range.normal(i, normal_radius_m)) {
                out.push(Oriented {
                    p: p.cast::<f64>(),
                    n: nn,
                });
            }
            k += step;
        }
        out
    }
}

impl ModelSurface {
    /// Bounding box of the fitted links' samples (model frame), grown by `margin_m`.
    pub(crate) fn fit_bounds(&self, margin_m: f64) -> (Point3<f64>, Point3<f64>) {
        let mut lo = Point3::new(f64::INFINITY, f64::INFINITY, f64::INFINITY);
        let mut hi = Point3::new(f64::NEG_INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY);
        for s in self
            .coarse
            .iter()
            .filter(|s| s.depth as usize <= self.fit_depth)
        {
            lo = lo.inf(&s.p);
            hi = hi.sup(&s.p);
        }
        let m = Vector3::repeat(margin_m);
        (lo - m, hi + m)
    }
}
