//! Stage 3, `fine` (first part): contender selection. The best candidate and distinct
//! runners-up are fitted exactly against the fitted links' triangles (the depth scale a 7th
//! parameter when enabled) and judged; how close the best other pose comes is the result's
//! ambiguity.

use nalgebra::{Isometry3, Point3};

use super::prepare::Prepared;
use super::{probe_err, Candidate, RegisterOptions};
use crate::calib::fine::{icp, DepthCorrection, IcpResult, Stage};
use crate::calib::range::RangeImage;
use crate::calib::surface::{ModelSurface, Sample};
use crate::calib::verify::{evidence, score, Evidence, Tolerances};
use crate::calib::CalibError;

/// Candidates fitted exactly and compared.
const MAX_CONTENDERS: usize = 4;

/// The winning contender, fitted exactly.
#[derive(Debug)]
pub(super) struct Judged {
    /// Its fit (trusting the posed links).
    pub(super) fine: IcpResult,
    /// `camera_from_model`.
    pub(super) pose: Isometry3<f64>,
    /// Its dense evidence.
    pub(super) e: Evidence,
    /// See [`super::Quality::ambiguity`].
    pub(super) ambiguity: f64,
}

/// The verification's tolerances for this scan.
pub(super) fn tolerances(p: &Prepared<'_>, opts: &RegisterOptions) -> Tolerances {
    Tolerances {
        matched_m: p.m(opts.match_tolerance_m),
        free_m: p.m(opts.free_space_tolerance_m),
    }
}

/// Stage 3: the contenders among `cands` (best first, as [`super::candidates`] ranks them)
/// fitted and judged. Errors when none survives the exact fit.
pub(super) fn judge(
    p: &Prepared<'_>,
    cands: &[Candidate],
    opts: &RegisterOptions,
) -> Result<Judged, CalibError> {
    let fine_stages = [
        Stage {
            gate_m: p.m(0.01),
            kernel_m: p.m(0.003),
            scale: None,
            offset: false,
            iterations: 8,
        },
        Stage {
            gate_m: p.m(0.005),
            kernel_m: p.m(0.0015),
            scale: opts.free_depth_scale(),
            offset: opts.estimate_depth_offset,
            iterations: 10,
        },
        Stage {
            gate_m: p.m(0.004),
            kernel_m: p.m(0.001),
            scale: opts.free_depth_scale(),
            offset: opts.estimate_depth_offset,
            iterations: 15,
        },
    ];
    let tol = tolerances(p, opts);
    let Some(best) = cands.first() else {
        return Err(CalibError::RobotNotFound {
            detail: "no pose hypothesis converged".into(),
        });
    };
    // Contenders: the best candidate and distinct runners-up that score almost as well. Each
    // is fitted exactly and judged on dense evidence times sharpness: a nearly symmetric wrong
    // pose covers the scan about as well, but its residuals are several times larger.
    let best_score = score(&best.e);
    let mut contenders: Vec<Isometry3<f64>> = vec![best.pose];
    for c in cands.iter().skip(1) {
        if contenders.len() >= MAX_CONTENDERS || score(&c.e) < 0.7 * best_score {
            break;
        }
        if contenders.iter().all(|o| !same_basin(o, &c.pose)) {
            contenders.push(c.pose);
        }
    }
    // Whatever their score, the candidate covering the most of its expected surface (a wrong
    // pose that shows more of the model can out-score the right one by far while covering less
    // of what it expects) and the one its short fit hugs most tightly (the turns of a round
    // base with a 6-fold bolt pattern score alike; five or more can crowd the right one out of
    // the slots above, but their shoulders fit worse).
    let plausible: Vec<&Candidate> = cands.iter().filter(|c| score(&c.e) > 0.0).collect();
    let by_coverage = plausible
        .iter()
        .max_by(|a, b| a.e.coverage().total_cmp(&b.e.coverage()));
    let by_fit = plausible.iter().max_by(|a, b| a.fit.total_cmp(&b.fit));
    for c in by_coverage.into_iter().chain(by_fit) {
        if contenders.iter().all(|o| !same_basin(o, &c.pose)) {
            contenders.push(c.pose);
        }
    }
    // Fits `c` exactly on up to `points` scan points through `stages`; `None` if the fit fails
    // or leaves too little of the model covered.
    let fit = |c: &Isometry3<f64>, points: usize, stages: &[Stage]| {
        let pts = p
            .pool
            .select(&p.range, &p.surface, c, points, p.m(0.01), p.m(0.003));
        let fine = icp(
            &pts,
            &p.surface,
            &c.inverse(),
            DepthCorrection::NONE,
            stages,
        )?;
        let pose = fine.model_from_camera.inverse();
        // The verification looks at the scan as measured: the model is seen through the
        // depth correction's inverse.
        let e = evidence_measured(&p.range, &p.surface, &pose, &fine.depth, tol);
        if e.coverage() < opts.min_coverage_found
            || e.violation_fraction() > opts.max_violation_found
        {
            return None;
        }
        let key =
            e.coverage() * fine.sharpness * fine.sharpness_moving - 3.0 * e.violation_fraction();
        Some((fine, pose, e, key))
    };
    // Several contenders are judged on a quarter of the points (their misfits differ by
    // several times; the full set only sharpens the winner's estimate), the winner refitted.
    let judge_points = if contenders.len() > 1 {
        opts.max_icp_points / 4
    } else {
        opts.max_icp_points
    };
    let fitted: Vec<(IcpResult, Isometry3<f64>, Evidence, f64)> = contenders
        .iter()
        .filter_map(|c| fit(c, judge_points, &fine_stages))
        .collect();
    // A pose whose expected surface is mostly hidden (behind a link close to the camera) can
    // cover much of the little it expects while explaining a fraction of what the others do:
    // support below half the best counts against it in proportion. On a noisy scan every key
    // can be below zero (its free-space violations outweigh its fit), and scaling a negative
    // key down would favour the pose with less support: the shortfall is taken off the key's
    // size either way.
    let most_matched = fitted.iter().map(|f| f.2.matched).fold(0.0, f64::max);
    let judged_key = |f: &(IcpResult, Isometry3<f64>, Evidence, f64)| {
        supported_key(f.3, f.2.matched, most_matched)
    };
    let Some(win) = (0..fitted.len())
        .max_by(|&a, &b| judged_key(&fitted[a]).total_cmp(&judged_key(&fitted[b])))
    else {
        return Err(CalibError::RobotNotFound {
            detail: "no hypothesis survived the fine alignment with enough coverage".into(),
        });
    };
    // Ambiguity: a different pose is as good as the result only if it covers about as much of
    // the expected surface *and* hugs the scan about as tightly, both overall and on the moving
    // links alone. Tightness is compared on the misfit 1 − sharpness (noise and CAD mismatch
    // give a right pose a floor of ~0.05–0.1, the asymmetric details a nearly symmetric wrong
    // pose misses add to it). The moving links are what breaks the symmetry of a round base:
    // a pose turned about the base's axis fits the base as well as the right one, and only the
    // shoulder's misfit (several times the right pose's) tells them apart.
    let misfit = |f: &IcpResult| (1.0 - f.sharpness, 1.0 - f.sharpness_moving);
    let (win_cov, (win_misfit, win_misfit_moving)) =
        (fitted[win].2.coverage(), misfit(&fitted[win].0));
    let ambiguity = fitted
        .iter()
        .enumerate()
        .filter(|(k, f)| *k != win && !same_pose(&f.1, &fitted[win].1))
        .map(|(_, f)| {
            let (m, mm) = misfit(&f.0);
            let by_cov = f.2.coverage() / win_cov.max(1e-9);
            let by_fit = win_misfit / m.max(1e-9);
            let by_fit_moving = win_misfit_moving / mm.max(1e-9);
            by_cov.min(by_fit).min(by_fit_moving).clamp(0.0, 1.0)
        })
        .fold(0.0, f64::max);
    if tracing::enabled!(tracing::Level::DEBUG) {
        for f in &fitted {
            let loose = Tolerances {
                matched_m: p.m(0.01),
                free_m: p.m(0.02),
            };
            let all = evidence(&p.range, &p.surface.samples, &f.1, 255, loose);
            let fitd = evidence(&p.range, &p.surface.samples, &f.1, p.surface.fit_depth, tol);
            tracing::debug!(
                err = probe_err(&f.1),
                ?all,
                ?fitd,
                "contender evidence (all links loose / fitted links)"
            );
        }
    }
    tracing::debug!(
        keys = ?fitted.iter().map(|f| (f.3, f.0.sharpness, f.0.sharpness_moving, f.2.coverage(), f.2.violation_fraction(), probe_err(&f.1))).collect::<Vec<_>>(),
        ambiguity,
        "fine contenders"
    );
    let Some(judged) = fitted.into_iter().nth(win) else {
        return Err(CalibError::RobotNotFound {
            detail: "fine alignment found too few correspondences".into(),
        });
    };
    let (fine, camera_from_model, e, _) = if judge_points < opts.max_icp_points {
        fit(&judged.1, opts.max_icp_points, &fine_stages[1..]).unwrap_or(judged)
    } else {
        judged
    };
    Ok(Judged {
        fine,
        pose: camera_from_model,
        e,
        ambiguity,
    })
}

/// A contender's `key` with its support counted: `matched` scan points against the
/// `most_matched` of any contender, below half of that in proportion, taken off the key's size
/// whatever its sign.
fn supported_key(key: f64, matched: f64, most_matched: f64) -> f64 {
    let support = (matched / (0.5 * most_matched).max(1.0)).min(1.0);
    key - key.abs() * (1.0 - support)
}

/// Whether two `camera_from_model` poses are the same result (camera within 2 mm and 0.3°).
pub(super) fn same_pose(a: &Isometry3<f64>, b: &Isometry3<f64>) -> bool {
    let d = a.inverse() * b;
    (a.inverse().translation.vector - b.inverse().translation.vector).norm() < 0.002
        && d.rotation.angle() < 0.3f64.to_radians()
}

/// Whether two polished candidates would converge to the same fine fit (model origin within
/// 2 cm, rotation within 10°): one contender stands for both.
fn same_basin(a: &Isometry3<f64>, b: &Isometry3<f64>) -> bool {
    crate::calib::within(a, b, 0.02, 10.0)
}

/// Evidence on the dense samples of the fitted links, for a camera whose depths need `depth`
/// to be true: the model is placed with `camera_from_model` and its camera-frame samples moved
/// to where the camera measures them ([`DepthCorrection::measured`]) before projection.
fn evidence_measured(
    range: &RangeImage<'_>,
    surface: &ModelSurface,
    camera_from_model: &Isometry3<f64>,
    depth: &DepthCorrection,
    tol: Tolerances,
) -> Evidence {
    if *depth == DepthCorrection::NONE {
        return evidence(
            range,
            &surface.samples,
            camera_from_model,
            surface.fit_depth,
            tol,
        );
    }
    let measured_samples: Vec<Sample> = surface
        .samples
        .iter()
        .filter(|x| x.depth as usize <= surface.fit_depth)
        .map(|x| {
            let mut y = *x;
            let pc = camera_from_model * x.p;
            y.p = camera_from_model.inverse() * Point3::from(depth.measured(&pc.coords));
            y
        })
        .collect();
    evidence(
        range,
        &measured_samples,
        camera_from_model,
        surface.fit_depth,
        tol,
    )
}

#[cfg(test)]
mod tests {
    use super::supported_key;

    /// Less support never helps a contender: with keys below zero (a noisy scan's violations
    /// outweigh every fit) the pose explaining a ninth of the points had won by its key being
    /// scaled towards zero.
    #[test]
    fn less_support_ranks_lower_whatever_the_keys_sign() {
        for key in [0.3, -0.2] {
            assert_eq!(supported_key(key, 1000.0, 1000.0), key);
            assert_eq!(supported_key(key, 600.0, 1000.0), key);
            assert!(supported_key(key, 100.0, 1000.0) < key);
        }
        assert!(supported_key(-0.13, 1942.0, 16859.0) < -0.13 * 1.7);
    }
}
