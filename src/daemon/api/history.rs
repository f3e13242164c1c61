//! The routes that read the history: the list of runs, one run's record, the latest accepted
//! calibration, and a run's report picture and exports.

use std::path::Path;

use axum::extract::{Path as UrlPath, RawQuery, State};
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde_json::json;

use super::{png, with_store, ApiError, AppState};
use crate::calib::export::{ExportMeta, Exports};
use crate::run::{Outcome, RunMode};
use crate::store::StoredRun;

/// `GET /api/runs` without `limit`.
pub(super) const DEFAULT_RUNS: usize = 50;
/// Most runs one `GET /api/runs` returns.
const MAX_RUNS: usize = 1000;

pub(super) async fn report_picture(
    State(state): State<AppState>,
    UrlPath(id): UrlPath<String>,
) -> Result<Response, ApiError> {
    let missing = || {
        ApiError::new(
            StatusCode::NOT_FOUND,
            format!(
                "no report picture for run `{id}`: it is still running, it predates report \
                 pictures, or its folder was removed; GET /api/runs/{id} has its record"
            ),
        )
    };
    let Some((storage, path)) = (state.site.storage.as_deref()).and_then(|storage| {
        crate::storage::report_picture_path(storage, &id).map(|p| (storage.to_path_buf(), p))
    }) else {
        return Err(missing());
    };
    // Beneath the storage folder, no link followed, a regular file of bounded size.
    let rel = path
        .strip_prefix(&storage)
        .map(Path::to_path_buf)
        .unwrap_or_default();
    let read = tokio::task::spawn_blocking(move || {
        crate::storage::read_beneath(&storage, &rel, crate::storage::MAX_PICTURE_BYTES)
    })
    .await
    .unwrap_or_else(|e| Err(std::io::Error::other(e)));
    match read {
        Ok(bytes) => Ok(png(bytes)),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Err(missing()),
        Err(e) => {
            tracing::error!("reading {}: {e}", path.display());
            Err(ApiError::new(
                StatusCode::INTERNAL_SERVER_ERROR,
                format!("cannot read the report picture of run `{id}`; see the daemon's log"),
            ))
        }
    }
}

/// `GET /api/runs/{id}/exports`: the run's result as the files an accepted calibration writes
/// (ROS 1/2 `static_transform_publisher` arguments, the URDF joint, tf YAML), from its record.
pub(super) async fn exports(
    State(state): State<AppState>,
    UrlPath(id): UrlPath<String>,
) -> Result<Response, ApiError> {
    let key = id.clone();
    let Some(record) = with_store(&state, move |s| Ok(s.get(&key)?)).await? else {
        return Err(ApiError::new(
            StatusCode::NOT_FOUND,
            format!("no run `{id}` in the history; GET /api/runs lists them"),
        ));
    };
    let no_result = || {
        ApiError::new(
            StatusCode::NOT_FOUND,
            format!("run `{id}` has no result to export (see its outcome and reasons)"),
        )
    };
    let StoredRun::Complete(record) = record else {
        return Err(no_result());
    };
    let result = record.result.as_ref().ok_or_else(no_result)?;
    let pose = result.estimate().ok_or_else(no_result)?;
    let parent = result.mount.parent_frame();
    let meta = ExportMeta {
        run_id: id.clone(),
        outcome: record.outcome.name().to_string(),
        uncertainty_translation_mm: result.uncertainty.translation_mm,
        uncertainty_rotation_deg: result.uncertainty.rotation_deg,
        timestamp: id.clone(),
    };
    let e = Exports::new(&pose, parent, "camera", meta);
    Ok(Json(json!({
        "run_id": id,
        "outcome": record.outcome,
        "transform": e.result().transform,
        "static_transform_publisher": e.static_transform_publisher(),
        "urdf_joint": e.urdf_joint(),
        "tf_yaml": e.tf_yaml(),
    }))
    .into_response())
}

/// `limit` and `before` of `GET /api/runs`.
pub(super) fn runs_query(query: Option<&str>) -> Result<(usize, Option<f64>), String> {
    let mut limit = DEFAULT_RUNS;
    let mut before = None;
    for pair in query.unwrap_or("").split('&').filter(|p| !p.is_empty()) {
        let (key, value) = pair.split_once('=').unwrap_or((pair, ""));
        match key {
            "limit" => {
                limit = value
                    .parse()
                    .ok()
                    .filter(|n| (1..=MAX_RUNS).contains(n))
                    .ok_or_else(|| {
                        format!("limit={value}: expected a whole number from 1 to {MAX_RUNS}")
                    })?;
            }
            "before" => {
                let t = value
                    .parse::<f64>()
                    .ok()
                    .filter(|t| t.is_finite() && *t >= 0.0)
                    .ok_or_else(|| {
                        format!(
                            "before={value}: expected a unix time in seconds (runs that started \
                             earlier are listed)"
                        )
                    })?;
                before = Some(t);
            }
            other => {
                return Err(format!(
                    "unknown query parameter `{other}`; use limit=N (1..{MAX_RUNS}) and \
                     before=UNIX_S"
                ))
            }
        }
    }
    Ok((limit, before))
}

pub(super) async fn runs(
    State(state): State<AppState>,
    RawQuery(query): RawQuery,
) -> Result<Response, ApiError> {
    let (limit, before) =
        runs_query(query.as_deref()).map_err(|m| ApiError::new(StatusCode::BAD_REQUEST, m))?;
    let runs = with_store(&state, move |s| Ok(s.list(limit, before)?)).await?;
    // Each run with its verdict, the word every view uses (`drifted`, `within limits`, …).
    let runs: Vec<serde_json::Value> = runs
        .iter()
        .map(|r| {
            let mut v = json!(r);
            v["verdict"] = json!(r.verdict());
            v
        })
        .collect();
    Ok(Json(json!({ "runs": runs })).into_response())
}

pub(super) async fn run_record(
    State(state): State<AppState>,
    UrlPath(id): UrlPath<String>,
) -> Result<Response, ApiError> {
    let key = id.clone();
    match with_store(&state, move |s| Ok(s.get(&key)?)).await? {
        Some(record) => Ok(Json(record).into_response()),
        None => Err(ApiError::new(
            StatusCode::NOT_FOUND,
            format!("no run `{id}` in the history; GET /api/runs lists them"),
        )),
    }
}

pub(super) async fn latest(State(state): State<AppState>) -> Result<Response, ApiError> {
    let record = with_store(&state, |s| {
        match s.latest(Some(RunMode::Calibrate), Some(Outcome::Accepted))? {
            Some(run) => Ok(s.get(&run.run_id)?),
            None => Ok(None),
        }
    })
    .await?;
    match record {
        Some(record) => Ok(Json(record).into_response()),
        None => Err(ApiError::new(
            StatusCode::NOT_FOUND,
            "no accepted calibration in the history yet; POST /api/calibrate runs one",
        )),
    }
}
