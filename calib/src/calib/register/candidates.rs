//! Stage 2, `coarse`: polished candidate poses — from the prior when it checks out, else from
//! the global search (supporting planes → Hough → the best one's turns about the robot's
//! axis), each polished by a short fit and ranked by its projective evidence.

use nalgebra::{Isometry3, Vector3};
use rayon::prelude::*;

use super::prepare::Prepared;
use super::{probe_err, Candidate, RegisterOptions};
use crate::calib::coarse;
use crate::calib::range::RangeImage;
use crate::calib::surface::ModelSurface;
use crate::calib::verify::{evidence, score, Tolerances};
use crate::calib::CalibError;

/// Planes of the scan the Hough vote searches for the robot, most plausible first.
const SUPPORT_PLANES: usize = 3;

/// Fraction of the scan points that may lie behind a plane the robot stands on (flying
/// pixels, past its edge).
const MAX_BEHIND_SUPPORT: f64 = 0.01;

/// Below this coverage of its best polished hypothesis, the search on the scan's planes has
/// not found the robot, and planes derived from its shape are searched too (right poses cover
/// 0.9 or more).
const FALLBACK_COVERAGE: f64 = 0.85;

/// Turns of the best coarse candidate polished after the sweep.
const SWEEP_KEEP: usize = 4;

/// Strongest Hough hypotheses whose half-turn is polished too.
const HALF_TURN_SEEDS: usize = 3;

/// The polished candidates, best first.
#[derive(Debug)]
pub(super) struct Candidates {
    pub(super) ranked: Vec<Candidate>,
    /// Whether they came from the prior (no global search).
    pub(super) from_prior: bool,
    /// Whether the search stopped at the objects on the planes (see [`candidates`]'s `thorough`).
    pub(super) shortcut: bool,
    /// Hypotheses polished.
    pub(super) hypotheses: usize,
}

/// Stage 2. Errors when no candidate covers enough of the model to be the robot. Not
/// `thorough`, a camera fixed in the cell whose objects on the planes show the arm skips the
/// Hough vote and the derived planes; thorough, every search runs (when the shortcut's
/// candidates all fail the fine alignment).
pub(super) fn candidates(
    p: &Prepared<'_>,
    prior: Option<Isometry3<f64>>,
    opts: &RegisterOptions,
    thorough: bool,
) -> Result<Candidates, CalibError> {
    let polish = |c: &Isometry3<f64>| p.polish(c);
    let plausible_seed = |c: &Isometry3<f64>| p.plausible_seed(c);
    // Polished candidates; the prior first when it has one.
    let mut cands: Vec<Candidate> = Vec::new();
    let mut from_prior = false;
    let mut n_hyp = 0;
    if let Some(prior) = prior {
        n_hyp += 1;
        if let Some(c) = polish(&prior) {
            if c.e.coverage() >= opts.min_coverage_prior && c.e.violation_fraction() <= 0.1 {
                from_prior = true;
                // A nearly symmetric robot (round base, shoulder without the upper arm in
                // view) also fits turned by half a turn about its axis: compare that too.
                let flipped = half_turn(&c.pose);
                n_hyp += 1;
                cands.extend(polish(&flipped));
            }
            cands.push(c);
        }
    }
    let mut planes_found = 0;
    let mut found_object = false;
    let covered = |cands: &[Candidate]| cands.iter().map(|c| c.e.coverage()).fold(0.0, f64::max);
    if !from_prior {
        let pts = coarse::oriented_subsample(&p.range, 30_000, p.m(0.008));
        // Hough hypotheses on `planes`, each polished (the strongest also half-turned).
        let search = |planes: &[coarse::Plane], max_out: usize| {
            let hyps =
                coarse::hypotheses(&p.range, &p.surface, &pts, planes, max_out, &plausible_seed);
            tracing::debug!(
                hyps = ?hyps.iter().map(|h| (h.1, probe_err(&h.0))).collect::<Vec<_>>(),
                "coarse hypotheses"
            );
            // The strongest hypotheses are also polished turned by half a turn about the
            // robot's axis: when the visible base and shoulder are nearly symmetric, the Hough
            // vote can rank the half-turned pose above the right one and lose the right one
            // altogether.
            let mut seeds: Vec<Isometry3<f64>> = hyps.iter().map(|h| h.0).collect();
            for (h, _) in hyps.iter().take(HALF_TURN_SEEDS) {
                let flipped = half_turn(h);
                if seeds.iter().all(|c| !near_pose(c, &flipped)) {
                    seeds.push(flipped);
                }
            }
            let polished: Vec<Candidate> = seeds.par_iter().filter_map(&polish).collect();
            (polished, seeds.len())
        };
        let ranked = coarse::support_planes(&pts, opts.seed, p.m(coarse::PLANE_TOLERANCE_M));
        planes_found = ranked.len();
        // A floor, table or wall the robot is mounted on has (almost) nothing behind it.
        let plausible = ranked
            .first()
            .is_some_and(|r| r.0 as f64 <= MAX_BEHIND_SUPPORT * pts.len() as f64);
        let planes: Vec<coarse::Plane> = ranked.iter().take(SUPPORT_PLANES).map(|r| r.1).collect();
        // A camera fixed in the cell sees the whole arm as an object of its own on the plane;
        // its normals, 1–2 m away, may be too poor for the Hough vote (see `coarse::objects`),
        // which is left out when the objects show the arm.
        if p.reach.is_none() {
            let tol = Tolerances {
                matched_m: p.m(0.015),
                free_m: p.m(0.03),
            };
            let seeds: Vec<Isometry3<f64>> = planes
                .iter()
                .flat_map(|pl| {
                    coarse::objects::hypotheses(
                        &p.range,
                        &p.surface,
                        &pts,
                        pl,
                        tol,
                        p.m(0.01),
                        opts.max_hypotheses,
                    )
                })
                .map(|h| h.0)
                .collect();
            tracing::debug!(seeds = seeds.len(), "object hypotheses");
            n_hyp += seeds.len();
            let polished: Vec<Candidate> = seeds.par_iter().filter_map(&polish).collect();
            found_object = !thorough && covered(&polished) >= FALLBACK_COVERAGE;
            cands.extend(polished);
        }
        if !found_object {
            let (polished, n) = search(&planes, opts.max_hypotheses);
            n_hyp += n;
            cands.extend(polished);
        }
        // No plane the robot could stand on (the floor beyond the camera's range or seen
        // edge-on by a camera level with the base), or none on which it was found: derive
        // mounting planes from the robot's own cylinders.
        // An arm found as an object on a plane needs no derived planes, whether or not the
        // plane looks like its support (a table's edge shows the floor behind it).
        if (!plausible && !found_object) || covered(&cands) < FALLBACK_COVERAGE {
            let flat: Vec<coarse::Plane> = ranked.iter().map(|r| r.1).collect();
            let derived = coarse::derived_planes(&pts, &flat, &p.surface, opts.seed);
            planes_found += derived.len();
            // Up to 18 planes (3 axes, both ways, 3 heights): each gets a hypothesis slot.
            let (polished, n) = search(&derived, opts.max_hypotheses.max(derived.len()));
            n_hyp += n;
            cands.extend(polished);
        }
        cands.sort_by(|a, b| score(&b.e).total_cmp(&score(&a.e)));
        // The base is nearly round: the Hough peaks may all sit at the right place but at wrong
        // turns of it (bolt patterns repeat every 60° or 90°), the right turn among none of
        // them. Sweep the best candidate's turn about the robot's axis and polish the turns
        // that explain the scan best.
        if let Some(best) = cands.first() {
            let turns = yaw_sweep(&p.range, &p.surface, &best.pose, &cands, &plausible_seed);
            n_hyp += turns.len();
            let polished: Vec<Candidate> = turns.par_iter().filter_map(&polish).collect();
            cands.extend(polished);
        }
    }
    cands.sort_by(|a, b| score(&b.e).total_cmp(&score(&a.e)));
    tracing::debug!(
        cands = ?cands.iter().map(|c| (score(&c.e), c.e.coverage(), c.fit, probe_err(&c.pose))).collect::<Vec<_>>(),
        "polished coarse candidates"
    );
    let Some(best) = cands.first() else {
        let detail = match p.reach {
            Some((r, _)) => format!(
                "{planes_found} supporting planes, no pose hypothesis converged with the camera within {r:.2} m of the flange (raise the maximum camera-flange distance for a camera mounted farther out)"
            ),
            None => format!("{planes_found} supporting planes, no pose hypothesis converged"),
        };
        return Err(CalibError::RobotNotFound { detail });
    };
    if best.e.coverage() < opts.min_coverage_found
        || best.e.violation_fraction() > opts.max_violation_found
    {
        return Err(CalibError::RobotNotFound {
            detail: format!(
                "best hypothesis covers {:.0}% of the expected surface with {:.0}% free-space violations",
                100.0 * best.e.coverage(),
                100.0 * best.e.violation_fraction()
            ),
        });
    }
    Ok(Candidates {
        ranked: cands,
        from_prior,
        shortcut: found_object,
        hypotheses: n_hyp,
    })
}

/// Turns of `best` about the model's z axis (10° steps) that explain the scan best, up to
/// [`SWEEP_KEEP`], at least 20° apart and away from every candidate in `cands`.
fn yaw_sweep(
    range: &RangeImage<'_>,
    surface: &ModelSurface,
    best: &Isometry3<f64>,
    cands: &[Candidate],
    admissible: &(dyn Fn(&Isometry3<f64>) -> bool + Sync),
) -> Vec<Isometry3<f64>> {
    // Loose, like the Hough peaks' scoring: a turn 5° off the right one moves the shoulder's
    // samples by ~10 mm.
    let tol = Tolerances {
        matched_m: 0.015,
        free_m: 0.03,
    };
    let step = 10f64.to_radians();
    let mut turns: Vec<(Isometry3<f64>, f64)> = (1..36)
        .into_par_iter()
        .map(|k| best * Isometry3::rotation(Vector3::z() * (k as f64 * step)))
        .filter(|pose| admissible(pose))
        .map(|pose| {
            let e = evidence(range, &surface.coarse, &pose, surface.fit_depth, tol);
            (pose, score(&e))
        })
        .collect();
    turns.sort_by(|a, b| b.1.total_cmp(&a.1));
    let top = turns.first().map_or(0.0, |t| t.1);
    let apart = |a: &Isometry3<f64>, b: &Isometry3<f64>, deg: f64| {
        (a.inverse() * b).rotation.angle() > deg.to_radians()
    };
    let mut out: Vec<Isometry3<f64>> = Vec::new();
    for (pose, sc) in turns {
        if out.len() >= SWEEP_KEEP || sc < 0.5 * top || sc <= 0.0 {
            break;
        }
        if cands.iter().all(|c| apart(&c.pose, &pose, 10.0))
            && out.iter().all(|o| apart(o, &pose, 20.0))
        {
            out.push(pose);
        }
    }
    out
}

/// `camera_from_model` turned by half a turn about the model's z axis (the robot's first axis).
pub(super) fn half_turn(camera_from_model: &Isometry3<f64>) -> Isometry3<f64> {
    camera_from_model * Isometry3::rotation(Vector3::z() * std::f64::consts::PI)
}

/// Whether two `camera_from_model` seeds are the same hypothesis (model origin within 1 cm,
/// rotation within 2°): both would polish to the same candidate.
fn near_pose(a: &Isometry3<f64>, b: &Isometry3<f64>) -> bool {
    crate::calib::within(a, b, 0.01, 2.0)
}
