//! The run's views: the planner with the configured constraints and obstacles, generated
//! views for a wrist camera (near the start, the flange turned between them), every target
//! and path checked before the first motion, and the dry run's forecast.

use super::*;

/// Generated candidates tried per automatic view before the plan gives up.
const AUTO_VIEW_TRIES: usize = 8;
/// Of this many first views drawn within a quarter turn of the base, the one nearest to the
/// start on a safe path.
const FIRST_VIEW_CANDIDATES: usize = 4;
/// Draws for them (most random poses do not see the base).
const FIRST_VIEW_DRAWS: usize = 200_000;

impl<R: Robot, C: DepthCamera> Context<'_, R, C> {
    pub(super) fn planner(&self) -> ViewPlanner<'_> {
        let constraints = ViewConstraints {
            floor_clearance_m: self.cfg.views.floor_clearance_m,
            ..match &self.cfg.views.targets {
                ViewTargets::Auto {
                    min_distance_m,
                    max_distance_m,
                    ..
                } => ViewConstraints {
                    min_distance_m: *min_distance_m,
                    max_distance_m: *max_distance_m,
                    ..ViewConstraints::default()
                },
                ViewTargets::Joints(_) => ViewConstraints::default(),
            }
        };
        let flange_from_camera = guard::configured_flange_from_camera(self.cfg);
        let obstacles = guard::configured_obstacles(self.cfg, &self.model_from_base);
        let cancel = self.cancel.clone();
        ViewPlanner::new(
            self.model,
            flange_from_camera,
            Intrinsics::compact_1280x960(),
            constraints,
        )
        .with_obstacles(obstacles)
        .with_cancel(CancelCheck::new(move || cancel.is_cancelled()))
    }

    /// A wrist camera's views, generated: the first, of a few that see the base and are
    /// reached on a safe path, the one nearest to where the arm stands; the others near the
    /// first, each the one that best separates the mount from the base's housing with the
    /// views before it, on a safe path from the view before and (returning to the start) back
    /// to the start ([`ViewPlanner::extend_run`], as the bench plans its runs). Short moves,
    /// the flange turned between views.
    pub(super) fn auto_views(
        &self,
        planner: &ViewPlanner<'_>,
        start: &[f64],
        count: usize,
        seed: u64,
    ) -> Result<Vec<Vec<f64>>, Failure> {
        let stage = Stage::Plan;
        let plan_error = |e: PlanError| match e {
            PlanError::Cancelled => Failure::cancelled(stage),
            e => Failure::error(
                stage,
                format!("{}; configure joint targets under [views]", error_chain(&e)),
            ),
        };
        let mut last_refusal = None;
        // Whether the path from `from` to `to` is safe (a refusal is remembered for the error).
        let mut safe = |from: &[f64], to: &[f64]| -> Result<bool, PlanError> {
            match planner.check_path(from, to, PATH_STEP_RAD)? {
                Ok(_) => Ok(true),
                Err(ViewRejection::Cancelled) => Err(PlanError::Cancelled),
                Err(r) => {
                    last_refusal = Some(r.to_string());
                    Ok(false)
                }
            }
        };
        let mut next_seed = seed;
        // The first view: of a few within a quarter turn of the base, the nearest on a safe path.
        let mut first: Option<Vec<f64>> = None;
        for _ in 0..AUTO_VIEW_TRIES {
            let mut candidates = planner
                .nearby(
                    start,
                    &FIRST_VIEW_SPAN_RAD,
                    FIRST_VIEW_CANDIDATES,
                    FIRST_VIEW_DRAWS,
                    next_seed,
                )
                .map_err(plan_error)?;
            next_seed = next_seed.wrapping_add(1);
            candidates.sort_by(|a, b| joint_span(start, a).total_cmp(&joint_span(start, b)));
            for q in candidates {
                let is_safe = safe(start, &q).map_err(|e| match e {
                    PlanError::Model(e) => Failure::error(stage, error_chain(&e)),
                    e => plan_error(e),
                })?;
                if is_safe {
                    first = Some(q);
                    break;
                }
            }
            if first.is_some() {
                break;
            }
        }
        let not_found = |n: usize, last_refusal: Option<String>| {
            Failure::error(
                stage,
                format!(
                    "no generated view {n} of {count} is reachable on a safe path ({}); move the arm to a free start pose or configure joint targets",
                    last_refusal.unwrap_or_else(|| "views too alike".into())
                ),
            )
        };
        let Some(first) = first else {
            return Err(not_found(1, last_refusal));
        };
        let mut views = vec![first];
        // A view is reached from the one before, and left for the start: at the end of the
        // run, or from wherever a stopped run stands.
        let back = self.cfg.views.return_to_start.then_some(start);
        let extended = planner.extend_run(&mut views, count, next_seed, |from, to| {
            for (a, b) in std::iter::once((from, to)).chain(back.map(|s| (to, s))) {
                if !safe(a, b)? {
                    return Ok(false);
                }
            }
            Ok(true)
        });
        match extended {
            Ok(()) => {}
            Err(PlanError::NotEnoughViews { found, .. }) => {
                return Err(not_found(found + 1, last_refusal))
            }
            Err(e) => return Err(plan_error(e)),
        }
        Ok(views)
    }

    /// Chooses the views and checks every target and path (out, between views and back).
    pub(super) fn plan(&mut self) -> Result<(), Failure> {
        let stage = Stage::Plan;
        let planner = self.planner();
        let start = self.start_joints().unwrap_or_default();
        let targets: Vec<Vec<f64>> = match (&self.cfg.views.targets, self.cfg.mount.mount) {
            (ViewTargets::Joints(list), _) => list.iter().map(|q| q.to_vec()).collect(),
            // A camera fixed in the cell: measure from where the arm stands (no motion); give
            // joint targets to show it the base and first links from a better pose.
            (ViewTargets::Auto { .. }, Mount::EyeToHand) => vec![start.clone()],
            (ViewTargets::Auto { count, seed, .. }, Mount::EyeInHand) => {
                self.auto_views(&planner, &start, *count, *seed)?
            }
        };
        let mut from = start.clone();
        let mut views = Vec::new();
        let fk = |e: crate::model::ModelError| Failure::error(stage, error_chain(&e));
        for (i, q) in targets.iter().enumerate() {
            let path = planner
                .check_path(&from, q, PATH_STEP_RAD)
                .map_err(fk)?
                .map_err(|r| match r {
                    ViewRejection::Cancelled => Failure::cancelled(stage),
                    r => Failure::error(
                        stage,
                        format!(
                            "the path to view {} is not safe: {r}; change the view's joints or the obstacles",
                            i + 1
                        ),
                    ),
                })?;
            let seen = match (self.cfg.mount.mount, self.cfg.mount.prior) {
                (Mount::EyeInHand, Some(_)) => Some(planner.check(q).map_err(fk)?),
                _ => None,
            };
            views.push(PlannedView {
                joints: q.clone(),
                distance_to_base_m: seen.as_ref().and_then(|s| s.as_ref().ok().copied()),
                path,
                not_seeing_base: seen.and_then(|s| s.err()).map(|r| r.to_string()),
            });
            from = q.clone();
        }
        if self.cfg.views.return_to_start {
            planner
                .check_path(&from, &start, PATH_STEP_RAD)
                .map_err(fk)?
                .map_err(|r| match r {
                    ViewRejection::Cancelled => Failure::cancelled(stage),
                    r => Failure::error(
                        stage,
                        format!("the path back to the start is not safe: {r}; move the arm to a free start pose"),
                    ),
                })?;
        }
        self.progress.stage(
            stage,
            &format!(
                "{} view(s); every target and path checked for limits and collisions",
                views.len()
            ),
        );
        self.record.views = views;
        Ok(())
    }

    /// A dry run's forecast of the run it planned ([`forecast`]): the σ of its views simulated
    /// at the mount prior (a wrist camera) and its time at the configured caps.
    pub(super) async fn forecast(&mut self) -> Result<(), Failure> {
        let start = self.start_joints().unwrap_or_default();
        let views = self.planned_joints();
        let model = Arc::clone(self.model);
        let cfg = self.cfg;
        let (limits, settle, frames, back, sensor) = (
            cfg.robot.limits,
            cfg.camera.settle.as_secs_f64(),
            cfg.camera.capture.frames as usize,
            cfg.views.return_to_start,
            cfg.camera.sensor,
        );
        let prior = match cfg.mount.mount {
            Mount::EyeInHand => cfg.mount.prior,
            Mount::EyeToHand => None,
        };
        self.progress.stage(
            Stage::Plan,
            "forecast: the views simulated at the mount prior, the moves timed",
        );
        let f = cancellable(self.cancel, Stage::Plan, async move {
            tokio::task::spawn_blocking(move || {
                forecast::forecast(
                    &model, &start, &views, back, &limits, settle, frames, prior, sensor,
                )
            })
            .await
            .map_err(|e| Failure::error(Stage::Plan, format!("the forecast panicked: {e}")))
        })
        .await?;
        self.record.forecast = Some(f);
        Ok(())
    }

    /// Checks, before the first move, that the storage has room for everything the run keeps
    /// (its raw scans at the camera's resolution × frames × views, when kept).
    pub(super) fn check_room(&self) -> Result<(), Failure> {
        let (width, height) = self
            .record
            .preflight
            .as_ref()
            .map_or((0, 0), |p| (p.camera.width, p.camera.height));
        let frames = self.record.views.len() * self.cfg.camera.capture.frames as usize;
        let needed = storage::run_bytes(width, height, frames, self.cfg.storage.keep_captures);
        // Blocking I/O of a few ms (one small file flushed), like the run's other small writes.
        storage::check_room(&self.cfg.storage.dir, needed).map_err(|e| {
            Failure::error(
                Stage::Preflight,
                format!("{e}; nothing moved and nothing was written to the controller"),
            )
        })
    }
}
