//! Projective checks of a pose hypothesis against the range image: for every model sample the
//! camera should see (front-facing, inside the image), compare the measured depth along its ray
//! with the model's depth.
//!
//! - matched: the scan has a surface within tolerance of the model surface;
//! - violation (free space): the scan saw *past* the model surface, i.e. through where the robot
//!   would be; a wrong pose produces many, a right one almost none;
//! - occluded: something (another link, clutter, the model itself) is in front: no evidence;
//! - missing: no measurement on that ray.
//!
//! Unlike ICP fitness this cannot be satisfied by sliding the model along the scan.

use nalgebra::Isometry3;
use rayon::prelude::*;

use super::range::RangeImage;
use super::surface::Sample;

/// Counts of the projective classification (weighted by sample count).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct Evidence {
    pub(crate) matched: f64,
    pub(crate) violated: f64,
    pub(crate) occluded: f64,
    pub(crate) missing: f64,
}

impl Evidence {
    /// Fraction of the expected visible model surface with scan points on it.
    pub(crate) fn coverage(&self) -> f64 {
        let d = self.matched + self.violated + self.missing;
        if d > 0.0 {
            self.matched / d
        } else {
            0.0
        }
    }

    /// Fraction of the expected visible model surface where the scan sees through the model.
    pub(crate) fn violation_fraction(&self) -> f64 {
        let d = self.matched + self.violated + self.missing;
        if d > 0.0 {
            self.violated / d
        } else {
            1.0
        }
    }

    fn add(self, o: Evidence) -> Evidence {
        Evidence {
            matched: self.matched + o.matched,
            violated: self.violated + o.violated,
            occluded: self.occluded + o.occluded,
            missing: self.missing + o.missing,
        }
    }
}

/// Tolerances of the classification, metres along the surface normal.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Tolerances {
    pub(crate) matched_m: f64,
    pub(crate) free_m: f64,
}

/// Classifies `samples` (model frame) with `camera_from_model`; `max_depth` filters parts.
pub(crate) fn evidence(
    range: &RangeImage<'_>,
    samples: &[Sample],
    camera_from_model: &Isometry3<f64>,
    max_depth: usize,
    tol: Tolerances,
) -> Evidence {
    evidence_where(range, samples, camera_from_model, |d| d <= max_depth, tol)
}

/// [`evidence`] of each chain depth `0..=max_depth` on its own: whether each fitted link is
/// where the posed model has it.
pub(crate) fn evidence_per_depth(
    range: &RangeImage<'_>,
    samples: &[Sample],
    camera_from_model: &Isometry3<f64>,
    max_depth: usize,
    tol: Tolerances,
) -> Vec<Evidence> {
    (0..=max_depth)
        .map(|depth| evidence_where(range, samples, camera_from_model, |d| d == depth, tol))
        .collect()
}

/// [`evidence`] of the samples whose chain depth passes `keep`.
fn evidence_where(
    range: &RangeImage<'_>,
    samples: &[Sample],
    camera_from_model: &Isometry3<f64>,
    keep: impl Fn(usize) -> bool + Sync,
    tol: Tolerances,
) -> Evidence {
    let classify = |s: &Sample| -> Evidence {
        let mut e = Evidence::default();
        if !keep(s.depth as usize) {
            return e;
        }
        let p = camera_from_model * s.p;
        let n = camera_from_model * s.n;
        let dist = p.coords.norm();
        let cos = -n.dot(&p.coords) / dist;
        // Surface seen at more than ~70° incidence is where depth sensors drop out: it is
        // neither evidence for (coverage) nor against a pose.
        if cos < 0.35 {
            return e;
        }
        let Some(i) = range.cam.pixel_index(&p) else {
            return e;
        };
        // Depth difference along the ray, converted to distance along the normal.
        let along_normal = |z: f64| (z - p.z) * (dist / p.z) * cos;
        let z = range.depth(i) as f64;
        if !z.is_finite() {
            // A pixel without a depth next to pixels that see this surface is a dropout at an
            // edge or a mixed pixel the camera removed, not the surface missing.
            if !seen_nearby(range, i, |z| along_normal(z).abs() <= tol.matched_m) {
                e.missing = 1.0;
            }
            return e;
        }
        let d = along_normal(z);
        if d.abs() <= tol.matched_m {
            e.matched = 1.0;
        } else if d > tol.free_m {
            e.violated = 1.0;
        } else if d < -tol.matched_m {
            e.occluded = 1.0;
        }
        e
    };
    if samples.len() > 20_000 {
        samples
            .par_chunks(4096)
            .map(|c| {
                c.iter()
                    .map(classify)
                    .fold(Evidence::default(), Evidence::add)
            })
            .reduce(Evidence::default, Evidence::add)
    } else {
        samples
            .iter()
            .map(classify)
            .fold(Evidence::default(), Evidence::add)
    }
}

/// Pixels either side of a pixel without depth that [`evidence`] looks at.
const DROPOUT_REACH_PX: usize = 3;

/// Whether a pixel within [`DROPOUT_REACH_PX`] of pixel `i` (along its row or column) has a
/// depth that `fits`.
fn seen_nearby(range: &RangeImage<'_>, i: usize, fits: impl Fn(f64) -> bool) -> bool {
    let w = range.cam.width as usize;
    let n = range.points.len();
    let (x, y) = (i % w, i / w);
    (1..=DROPOUT_REACH_PX).any(|k| {
        [
            (x >= k).then(|| i - k),
            (x + k < w).then(|| i + k),
            (y >= k).then(|| i - k * w),
            (i + k * w < n).then(|| i + k * w),
        ]
        .into_iter()
        .flatten()
        .any(|j| {
            let z = range.depth(j) as f64;
            z.is_finite() && fits(z)
        })
    })
}

/// Hypothesis score for the coarse search: matched minus penalised violations.
pub(crate) fn score(e: &Evidence) -> f64 {
    e.matched - 3.0 * e.violated
}
