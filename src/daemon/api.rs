//! The daemon's HTTP API (axum) and its web page: the [`Frontend`] `handeye daemon` starts
//! with its handle.
//!
//! JSON everywhere; every error is `{"error": "..."}` saying what to do. Reading is open to
//! whoever can reach `daemon.listen` (localhost by default); anything that moves the arm
//! (`/api/calibrate`, `/api/check`) or stops it (`/api/cancel`) needs
//! `Authorization: Bearer <token>` with the token from `daemon.token_file` (or the systemd
//! credential `token`). Without a configured token those requests are refused outright. A
//! client refused 20 times in 10 s (`AuthLimit`) gets 429 for them
//! until the window ends. The local CLI's cancel does not depend on this API at all
//! ([`crate::daemon::control`]).
//!
//! | route | what |
//! |---|---|
//! | `GET /api/status` | what the daemon is doing ([`crate::daemon::Status`]) |
//! | `POST /api/calibrate`, `POST /api/check` | token; 202 `{"run_id"}`, 409 when busy |
//! | `POST /api/cancel` | token; `{"cancelled": bool}` |
//! | `GET /api/runs?limit=N&before=UNIX_S` | the history, newest first |
//! | `GET /api/runs/{id}` | one run's record |
//! | `GET /api/latest` | the record of the latest accepted calibration |
//! | `GET /api/runs/{id}/report.png` | the run's report picture |
//! | `GET /api/runs/{id}/exports` | the run's result as ROS arguments, URDF joint, tf YAML |
//! | `GET /api/drift`, `GET /api/drift.png` | every check's drift and the thresholds; as a chart |
//! | `GET /metrics` | Prometheus text format |
//! | `GET /` (and `/app.js`, `/app.css`, `/favicon.svg`) | the web page, embedded in the binary |

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use crate::calib::export::{ExportMeta, Exports};
use crate::config::Config;
use crate::daemon::listener::{AuthLimit, RateLimit};
use crate::daemon::{DaemonHandle, Frontend, Refusal};
use crate::record::Trigger;
use crate::report::{DriftLimits, DriftPoint};
use crate::run::{Outcome, RunMode};
use crate::store::{RunStatus, Store, StoredRun};
use anyhow::{bail, Context};
use axum::extract::{ConnectInfo, DefaultBodyLimit, Path as UrlPath, RawQuery, Request, State};
use axum::http::{header, HeaderMap, HeaderValue, Method, StatusCode, Uri};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use serde_json::json;
use tokio_util::sync::CancellationToken;

/// Largest request body accepted, bytes. No route reads a body; this only stops a client from
/// making the server buffer one.
const BODY_LIMIT: usize = 4096;
/// `GET /api/runs` without `limit`.
const DEFAULT_RUNS: usize = 50;
/// Most runs one `GET /api/runs` returns.
const MAX_RUNS: usize = 1000;
/// The refusal when no token is configured.
const NO_TOKEN: &str =
    "no API token configured (daemon.token_file); nothing that moves the arm is accepted";

/// Most checks the drift chart and `GET /api/drift` show (the newest).
const DRIFT_RUNS: usize = 1000;
/// Largest drift chart `GET /api/drift.png` draws, px.
const MAX_CHART: usize = 2000;
/// The shortest API token accepted (a short one is guessed by trying).
pub const MIN_TOKEN_CHARS: usize = 16;
/// Drift charts drawn at once (the others wait).
const CHARTS_AT_ONCE: usize = 2;

/// The web page and its assets, compiled into the binary (cells are offline: nothing comes
/// from elsewhere).
const INDEX_HTML: &str = include_str!("web/index.html");
const APP_JS: &str = include_str!("web/app.js");
const APP_CSS: &str = include_str!("web/app.css");
const FAVICON_SVG: &str = include_str!("web/favicon.svg");
/// The page loads only its own scripts, styles and pictures.
const CSP: &str = "default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self'; \
                   connect-src 'self'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'";

/// What the page and the pictures read besides the daemon: the run folders and the drift
/// thresholds.
#[derive(Debug, Clone)]
pub struct Site {
    /// `storage.dir`: run folders hold the report pictures (`runs/<id>/report.png`).
    storage: Option<PathBuf>,
    /// `[check]`'s thresholds, drawn in the drift chart.
    drift_limits: DriftLimits,
}

impl Default for Site {
    fn default() -> Site {
        Site {
            storage: None,
            drift_limits: DriftLimits {
                translation_mm: 1.0,
                rotation_deg: 0.2,
            },
        }
    }
}

/// The HTTP API: where it listens and the token that requests which move the arm must carry.
pub struct Api {
    listen: SocketAddr,
    token: Option<String>,
    site: Site,
}

impl std::fmt::Debug for Api {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Api")
            .field("listen", &self.listen)
            .field("token", &self.token.as_ref().map(|_| "<redacted>"))
            .field("site", &self.site)
            .finish()
    }
}

impl Api {
    /// The API on `listen`; `token: None` refuses everything that moves the arm.
    pub fn new(listen: SocketAddr, token: Option<String>) -> Api {
        Api {
            listen,
            token,
            site: Site::default(),
        }
    }

    /// The same API serving the report pictures from `storage` (the configuration's
    /// `storage.dir`) and drawing `drift_limits` in the drift chart.
    pub fn with_site(mut self, storage: PathBuf, drift_limits: DriftLimits) -> Api {
        self.site = Site {
            storage: Some(storage),
            drift_limits,
        };
        self
    }

    /// The API as configured: `daemon.listen`, and the token from `$CREDENTIALS_DIRECTORY/token`
    /// when systemd passes one (`LoadCredential=token:/etc/handeye/token`), else from
    /// `daemon.token_file`. Refuses an empty token, or (Unix) a token file that group or others
    /// can access.
    pub fn from_config(cfg: &Config) -> anyhow::Result<Api> {
        let credentials = std::env::var_os("CREDENTIALS_DIRECTORY").map(PathBuf::from);
        Api::from_config_with(cfg, credentials.as_deref())
    }

    /// The token that authorises requests that move or stop the arm (`handeye cancel` sends
    /// it); `None` when none is configured.
    pub fn token(&self) -> Option<&str> {
        self.token.as_deref()
    }

    /// [`Api::from_config`] with the credentials directory given (tests).
    fn from_config_with(cfg: &Config, credentials: Option<&Path>) -> anyhow::Result<Api> {
        let listen = cfg.daemon.listen;
        // systemd makes its credentials readable by the service alone (mode 0400, or an ACL
        // that shows as group bits), so only the configured file's mode is checked.
        let credential = credentials
            .map(|dir| dir.join("token"))
            .filter(|p| p.exists());
        let (path, check_mode) = match (credential, &cfg.daemon.token_file) {
            (Some(p), _) => (Some(p), false),
            (None, file) => (file.clone(), true),
        };
        let token = match &path {
            Some(p) => Some(read_token(p, check_mode)?),
            None => None,
        };
        match &path {
            Some(p) => tracing::info!("API token from {}", p.display()),
            None => tracing::warn!(
                "{NO_TOKEN}: POST /api/calibrate, /api/check and /api/cancel are refused"
            ),
        }
        if !listen.ip().is_loopback() {
            tracing::warn!(
                "the HTTP API listens on {listen}, reachable from the network (daemon.listen)"
            );
        }
        Ok(Api::new(listen, token).with_site(
            cfg.storage.dir.clone(),
            DriftLimits {
                translation_mm: cfg.check.max_drift_translation_mm,
                rotation_deg: cfg.check.max_drift_rotation_deg,
            },
        ))
    }
}

/// The token in `path`, trimmed. Refuses an empty token, one that cannot go in an HTTP header
/// as one word, and (Unix, `check_mode`) a file that group or others can access.
fn read_token(path: &Path, check_mode: bool) -> anyhow::Result<String> {
    let shown = path.display();
    #[cfg(unix)]
    if check_mode {
        use std::os::unix::fs::PermissionsExt;
        let meta = std::fs::metadata(path)
            .with_context(|| format!("reading the API token file {shown} (daemon.token_file)"))?;
        let mode = meta.permissions().mode() & 0o777;
        if mode & 0o077 != 0 {
            bail!(
                "the API token file {shown} is accessible by group or others (mode {mode:04o}); \
                 run `chmod 600 {shown}` and make the daemon's user its owner"
            );
        }
    }
    #[cfg(not(unix))]
    let _ = check_mode;
    // A regular file of bounded size, read as the configuration is: a FIFO or a device would
    // block or never end.
    let text = handeye_hal::limits::read_text_file(path, crate::config::MAX_CONFIG_BYTES)
        .with_context(|| format!("reading the API token file {shown} (daemon.token_file)"))?;
    let token = text.trim();
    if token.is_empty() {
        bail!(
            "the API token file {shown} is empty; put a long random token in it, e.g. \
             `openssl rand -hex 32 > {shown}; chmod 600 {shown}`"
        );
    }
    if token.len() < MIN_TOKEN_CHARS {
        bail!(
            "the API token in {shown} has {} characters; use at least {MIN_TOKEN_CHARS} random ones, e.g. `openssl rand -hex 32 > {shown}; chmod 600 {shown}`",
            token.len()
        );
    }
    if !token.bytes().all(|b| b.is_ascii_graphic()) {
        bail!(
            "the API token in {shown} must be one word of printable ASCII (it travels in an \
             HTTP header), e.g. `openssl rand -hex 32`"
        );
    }
    Ok(token.to_string())
}

impl Frontend for Api {
    async fn serve(self, handle: DaemonHandle, shutdown: CancellationToken) {
        let listener = match tokio::net::TcpListener::bind(self.listen).await {
            Ok(l) => l,
            Err(e) => {
                let hint = if e.kind() == std::io::ErrorKind::AddrInUse {
                    "another program (another handeye daemon?) uses that port; stop it or set \
                     another daemon.listen"
                } else {
                    "check daemon.listen"
                };
                tracing::error!(
                    "cannot serve the HTTP API on {}: {e}; {hint}. The daemon runs on without \
                     its API and web page",
                    self.listen
                );
                return;
            }
        };
        match listener.local_addr() {
            Ok(addr) => tracing::info!("HTTP API on http://{addr}/"),
            Err(e) => tracing::warn!("HTTP API listening, address unknown: {e}"),
        }
        let app = router(handle, self.token, self.site);
        super::listener::serve(listener, app, shutdown).await;
    }
}

/// What every handler shares.
#[derive(Clone)]
struct AppState {
    handle: DaemonHandle,
    token: Option<Arc<str>>,
    site: Arc<Site>,
    /// Each client's allowance on the routes that read files or draw ([`rate_limited`]).
    rate: Arc<RateLimit>,
    /// Each client's refused tokens ([`authorize`]).
    auth: Arc<AuthLimit>,
    /// Charts drawn at once (each holds its pixels: up to 16 MB at the largest size).
    charts: Arc<tokio::sync::Semaphore>,
}

/// The API's routes over `handle`; `token: None` refuses everything that moves the arm.
pub fn router(handle: DaemonHandle, token: Option<String>, site: Site) -> Router {
    let state = AppState {
        handle,
        token: token.map(Arc::from),
        site: Arc::new(site),
        rate: Arc::new(RateLimit::default()),
        auth: Arc::new(AuthLimit::default()),
        charts: Arc::new(tokio::sync::Semaphore::new(CHARTS_AT_ONCE)),
    };
    // The routes that read a run's files, the history or draw: limited per client.
    let expensive = Router::new()
        .route("/api/runs/{id}/report.png", get(report_picture))
        .route("/api/runs/{id}/exports", get(exports))
        .route("/api/drift", get(drift))
        .route("/api/drift.png", get(drift_png))
        .route_layer(axum::middleware::from_fn_with_state(
            state.clone(),
            rate_limited,
        ));
    Router::new()
        .route("/", get(index))
        .route("/app.js", get(app_js))
        .route("/app.css", get(app_css))
        .route("/favicon.svg", get(favicon))
        .merge(expensive)
        .route("/api/status", get(status))
        .route("/api/calibrate", post(calibrate))
        .route("/api/calibrate/accept-change", post(accept_change))
        .route("/api/check", post(check))
        .route("/api/cancel", post(cancel))
        .route("/api/runs", get(runs))
        .route("/api/runs/{id}", get(run_record))
        .route("/api/latest", get(latest))
        .route("/metrics", get(metrics))
        .fallback(not_found)
        .method_not_allowed_fallback(method_not_allowed)
        .layer(DefaultBodyLimit::max(BODY_LIMIT))
        .layer(axum::middleware::from_fn(refuse_large_bodies))
        .with_state(state)
}

/// The body of every error answer: what went wrong and what to do.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct ErrorBody {
    /// One sentence for the operator.
    pub error: String,
}

/// An error answer: `{"error": message}` with a status.
#[derive(Debug)]
struct ApiError {
    status: StatusCode,
    message: String,
    /// `WWW-Authenticate` value for 401s.
    challenge: Option<&'static str>,
    /// `Retry-After`, s.
    retry_after_s: Option<u64>,
}

impl ApiError {
    fn new(status: StatusCode, message: impl Into<String>) -> ApiError {
        ApiError {
            status,
            message: message.into(),
            challenge: None,
            retry_after_s: None,
        }
    }

    fn unauthorized(message: &str, challenge: &'static str) -> ApiError {
        ApiError {
            challenge: Some(challenge),
            ..ApiError::new(StatusCode::UNAUTHORIZED, message)
        }
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let body = ErrorBody {
            error: self.message,
        };
        let mut resp = (self.status, Json(body)).into_response();
        if let Some(c) = self.challenge {
            resp.headers_mut()
                .insert(header::WWW_AUTHENTICATE, HeaderValue::from_static(c));
        }
        if let Some(s) = self.retry_after_s {
            if let Ok(v) = HeaderValue::from_str(&s.to_string()) {
                resp.headers_mut().insert(header::RETRY_AFTER, v);
            }
        }
        resp
    }
}

/// Whether `given` is `expected`, in time that depends only on `expected`'s length.
fn token_matches(expected: &[u8], given: &[u8]) -> bool {
    let mut diff = u8::from(expected.len() != given.len());
    for (i, e) in expected.iter().enumerate() {
        diff |= e ^ given.get(i).copied().unwrap_or(0);
    }
    std::hint::black_box(diff) == 0
}

/// Lets a request that moves (or stops) the arm through only with the right bearer token.
/// Refusals are logged at warn with the peer and the reason, never the token, once per
/// window and client; a client refused [`AuthLimit::MAX_FAILURES`] times in a window gets
/// 429 (with `Retry-After`) without its token being looked at until the window ends.
fn authorize(
    state: &AppState,
    headers: &HeaderMap,
    peer: SocketAddr,
    what: &str,
) -> Result<(), ApiError> {
    let Some(expected) = &state.token else {
        tracing::warn!(%peer, "refused {what}: no API token configured");
        return Err(ApiError::new(StatusCode::FORBIDDEN, NO_TOKEN));
    };
    if let Err(wait_s) = state.auth.check(peer.ip()) {
        return Err(ApiError {
            retry_after_s: Some(wait_s.ceil().max(1.0) as u64),
            ..ApiError::new(
                StatusCode::TOO_MANY_REQUESTS,
                format!(
                    "too many refused tokens from {}; wait {wait_s:.0} s, then send the token from daemon.token_file",
                    peer.ip()
                ),
            )
        });
    }
    let refuse = |reason: &str| {
        if let Some(more) = state.auth.failed(peer.ip()) {
            tracing::warn!(%peer, "refused {what}: {reason}{more}");
        }
    };
    let Some(value) = headers.get(header::AUTHORIZATION) else {
        refuse("no Authorization header");
        return Err(ApiError::unauthorized(
            "this request moves the arm: send `Authorization: Bearer <token>` with the token \
             from daemon.token_file",
            "Bearer realm=\"handeye\"",
        ));
    };
    let given = value.as_bytes();
    let bearer = given
        .get(..7)
        .is_some_and(|s| s.eq_ignore_ascii_case(b"bearer "));
    if !bearer {
        refuse("Authorization is not a Bearer token");
        return Err(ApiError::unauthorized(
            "the Authorization header must be `Bearer <token>` with the token from \
             daemon.token_file",
            "Bearer realm=\"handeye\"",
        ));
    }
    let given = given[7..].trim_ascii();
    if !token_matches(expected.as_bytes(), given) {
        refuse("wrong token");
        return Err(ApiError::unauthorized(
            "wrong token; use the one in daemon.token_file",
            "Bearer realm=\"handeye\", error=\"invalid_token\"",
        ));
    }
    Ok(())
}

/// Answers 429 (with `Retry-After`) when the client has used its allowance on the expensive
/// routes ([`RateLimit`]: a burst of 8, then 2 a second).
async fn rate_limited(
    State(state): State<AppState>,
    ConnectInfo(peer): ConnectInfo<SocketAddr>,
    req: Request,
    next: Next,
) -> Response {
    if let Err(wait_s) = state.rate.take(peer.ip()) {
        let mut answer = ApiError::new(
            StatusCode::TOO_MANY_REQUESTS,
            format!(
                "too many requests for pictures, charts and exports from {}; wait {wait_s:.1} s",
                peer.ip()
            ),
        )
        .into_response();
        let secs = wait_s.ceil().max(1.0) as u64;
        if let Ok(v) = HeaderValue::from_str(&secs.to_string()) {
            answer.headers_mut().insert(header::RETRY_AFTER, v);
        }
        return answer;
    }
    next.run(req).await
}

/// Refuses a request announcing a body larger than [`BODY_LIMIT`] before any handler runs.
async fn refuse_large_bodies(req: Request, next: Next) -> Response {
    let too_large = req
        .headers()
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| {
            v.trim()
                .parse::<u64>()
                .map_or(true, |n| n > BODY_LIMIT as u64)
        });
    if too_large {
        return ApiError::new(
            StatusCode::PAYLOAD_TOO_LARGE,
            format!("request bodies are limited to {BODY_LIMIT} bytes; no route needs one"),
        )
        .into_response();
    }
    next.run(req).await
}

/// An embedded asset with its type; the page is re-read on every load (`no-cache`), so a new
/// binary's page is never mixed with an old script.
fn asset(content_type: &'static str, body: &'static str) -> Response {
    (
        [
            (header::CONTENT_TYPE, HeaderValue::from_static(content_type)),
            (header::CACHE_CONTROL, HeaderValue::from_static("no-cache")),
            (
                header::X_CONTENT_TYPE_OPTIONS,
                HeaderValue::from_static("nosniff"),
            ),
            (
                header::CONTENT_SECURITY_POLICY,
                HeaderValue::from_static(CSP),
            ),
        ],
        body,
    )
        .into_response()
}

async fn index() -> Response {
    asset("text/html; charset=utf-8", INDEX_HTML)
}

async fn app_js() -> Response {
    asset("text/javascript; charset=utf-8", APP_JS)
}

async fn app_css() -> Response {
    asset("text/css; charset=utf-8", APP_CSS)
}

async fn favicon() -> Response {
    asset("image/svg+xml", FAVICON_SVG)
}

/// A PNG answer; pictures of finished runs never change, charts do (`no-cache`).
fn png(bytes: Vec<u8>) -> Response {
    (
        [
            (header::CONTENT_TYPE, HeaderValue::from_static("image/png")),
            (header::CACHE_CONTROL, HeaderValue::from_static("no-cache")),
        ],
        bytes,
    )
        .into_response()
}

async fn report_picture(
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
async fn exports(
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

/// Every check's drift (oldest first) and the accepted calibrations' times, from the history.
async fn drift_data(state: &AppState) -> Result<(Vec<(String, DriftPoint)>, Vec<f64>), ApiError> {
    let runs = with_store(state, |s| Ok(s.list(DRIFT_RUNS, None)?)).await?;
    let mut checks = Vec::new();
    let mut calibrations = Vec::new();
    for r in runs.iter().rev() {
        match (r.mode, r.outcome) {
            (RunMode::Check, _) => {
                if let (Some(t), Some(d)) = (r.drift_translation_mm, r.drift_rotation_deg) {
                    checks.push((
                        r.run_id.clone(),
                        DriftPoint {
                            unix_s: r.started_unix_s,
                            translation_mm: t,
                            rotation_deg: d,
                            drifted: r.drifted.unwrap_or(false),
                        },
                    ));
                }
            }
            (RunMode::Calibrate, RunStatus::Ended(Outcome::Accepted)) => {
                calibrations.push(r.started_unix_s)
            }
            _ => {}
        }
    }
    Ok((checks, calibrations))
}

async fn drift(State(state): State<AppState>) -> Result<Response, ApiError> {
    let (checks, calibrations) = drift_data(&state).await?;
    let limits = state.site.drift_limits;
    let checks: Vec<_> = checks
        .iter()
        .map(|(id, p)| {
            json!({
                "run_id": id,
                "unix_s": p.unix_s,
                "translation_mm": p.translation_mm,
                "rotation_deg": p.rotation_deg,
                "drifted": p.drifted,
            })
        })
        .collect();
    Ok(Json(json!({
        "max_translation_mm": limits.translation_mm,
        "max_rotation_deg": limits.rotation_deg,
        "checks": checks,
        "calibrations_unix_s": calibrations,
    }))
    .into_response())
}

/// `width` and `height` of `GET /api/drift.png` (defaults 900×340).
fn chart_size(query: Option<&str>) -> Result<(usize, usize), String> {
    let (mut w, mut h) = (900, 340);
    for pair in query.unwrap_or("").split('&').filter(|p| !p.is_empty()) {
        let (key, value) = pair.split_once('=').unwrap_or((pair, ""));
        let n = value
            .parse::<usize>()
            .ok()
            .filter(|n| (240..=MAX_CHART).contains(n));
        match (key, n) {
            ("width", Some(n)) => w = n.max(320),
            ("height", Some(n)) => h = n,
            ("t", _) => {} // cache buster of the page
            _ => {
                return Err(format!(
                    "{pair}: use width=N and height=N (240..{MAX_CHART} pixels)"
                ))
            }
        }
    }
    Ok((w, h))
}

async fn drift_png(
    State(state): State<AppState>,
    RawQuery(query): RawQuery,
) -> Result<Response, ApiError> {
    let (w, h) =
        chart_size(query.as_deref()).map_err(|m| ApiError::new(StatusCode::BAD_REQUEST, m))?;
    let (checks, calibrations) = drift_data(&state).await?;
    let limits = state.site.drift_limits;
    let points: Vec<DriftPoint> = checks.into_iter().map(|(_, p)| p).collect();
    // At most CHARTS_AT_ONCE charts in memory; the others wait their turn.
    let Ok(_drawing) = state.charts.acquire().await else {
        return Err(ApiError::new(
            StatusCode::SERVICE_UNAVAILABLE,
            "the daemon is stopping",
        ));
    };
    let drawn = tokio::task::spawn_blocking(move || {
        crate::report::drift_chart(&points, &calibrations, limits, w, h)
    })
    .await;
    match drawn {
        Ok(Ok(bytes)) => Ok(png(bytes)),
        Ok(Err(e)) => {
            tracing::error!("drift chart: {e}");
            Err(ApiError::new(
                StatusCode::INTERNAL_SERVER_ERROR,
                "cannot draw the drift chart; see the daemon's log",
            ))
        }
        Err(e) => {
            tracing::error!("drift chart: {e}");
            Err(ApiError::new(
                StatusCode::INTERNAL_SERVER_ERROR,
                "cannot draw the drift chart; see the daemon's log",
            ))
        }
    }
}

async fn status(State(state): State<AppState>) -> Response {
    Json(state.handle.status()).into_response()
}

async fn calibrate(
    State(state): State<AppState>,
    ConnectInfo(peer): ConnectInfo<SocketAddr>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    start(&state, &headers, peer, RunMode::Calibrate, None)
}

/// `POST /api/calibrate/accept-change`: a calibration that accepts a result beyond
/// `gate.max_change_*` (the camera was remounted on purpose). The record says who: `web page
/// (ADDR)` when the page sent it (header `X-Handeye-Client: page`), else `api client ADDR`.
async fn accept_change(
    State(state): State<AppState>,
    ConnectInfo(peer): ConnectInfo<SocketAddr>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    let from_page = headers
        .get("x-handeye-client")
        .is_some_and(|v| v.as_bytes() == b"page");
    let by = if from_page {
        format!("web page ({})", peer.ip())
    } else {
        format!("api client {}", peer.ip())
    };
    start(&state, &headers, peer, RunMode::Calibrate, Some(by))
}

async fn check(
    State(state): State<AppState>,
    ConnectInfo(peer): ConnectInfo<SocketAddr>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    start(&state, &headers, peer, RunMode::Check, None)
}

/// `POST /api/calibrate` and `/api/check`: 202 with the run id, 409 when a run is going.
fn start(
    state: &AppState,
    headers: &HeaderMap,
    peer: SocketAddr,
    mode: RunMode,
    accept_change: Option<String>,
) -> Result<Response, ApiError> {
    let what = match (mode, &accept_change) {
        (RunMode::Calibrate, Some(_)) => "POST /api/calibrate/accept-change",
        (RunMode::Calibrate, None) => "POST /api/calibrate",
        (RunMode::Check, _) => "POST /api/check",
    };
    authorize(state, headers, peer, what)?;
    let asked = match accept_change {
        Some(by) => state.handle.request_accepting_change(Trigger::Api, by),
        None => state.handle.request(mode, Trigger::Api),
    };
    match asked {
        Ok(run_id) => {
            tracing::info!(%peer, run_id = %run_id, "{what}: run accepted");
            Ok((StatusCode::ACCEPTED, Json(json!({ "run_id": run_id }))).into_response())
        }
        Err(e @ (Refusal::Busy { .. } | Refusal::QueueFull { .. })) => {
            Err(ApiError::new(StatusCode::CONFLICT, e.to_string()))
        }
        Err(e @ Refusal::StorageUnusable(_)) => Err(ApiError::new(
            StatusCode::INSUFFICIENT_STORAGE,
            e.to_string(),
        )),
        Err(e) => Err(ApiError::new(
            StatusCode::SERVICE_UNAVAILABLE,
            e.to_string(),
        )),
    }
}

async fn cancel(
    State(state): State<AppState>,
    ConnectInfo(peer): ConnectInfo<SocketAddr>,
    headers: HeaderMap,
) -> Result<Response, ApiError> {
    authorize(&state, &headers, peer, "POST /api/cancel")?;
    let cancelled = state.handle.cancel();
    if cancelled {
        tracing::warn!(%peer, "run cancelled through the API");
    }
    Ok(Json(json!({ "cancelled": cancelled })).into_response())
}

/// Runs a (blocking, SQLite) store call off the runtime's workers.
async fn with_store<T: Send + 'static>(
    state: &AppState,
    call: impl FnOnce(&Store) -> anyhow::Result<T> + Send + 'static,
) -> Result<T, ApiError> {
    let store = Arc::clone(state.handle.store());
    match tokio::task::spawn_blocking(move || call(&store)).await {
        Ok(Ok(v)) => Ok(v),
        Ok(Err(e)) => {
            tracing::error!("history: {e:#}");
            Err(ApiError::new(
                StatusCode::INTERNAL_SERVER_ERROR,
                format!("cannot read the history: {e:#}; see the daemon's log"),
            ))
        }
        Err(e) => {
            tracing::error!("history query failed: {e}");
            Err(ApiError::new(
                StatusCode::INTERNAL_SERVER_ERROR,
                "the history query failed; see the daemon's log",
            ))
        }
    }
}

/// `limit` and `before` of `GET /api/runs`.
fn runs_query(query: Option<&str>) -> Result<(usize, Option<f64>), String> {
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

async fn runs(
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

async fn run_record(
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

async fn latest(State(state): State<AppState>) -> Result<Response, ApiError> {
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

async fn metrics(State(state): State<AppState>) -> Response {
    (
        [(
            header::CONTENT_TYPE,
            HeaderValue::from_static("text/plain; version=0.0.4; charset=utf-8"),
        )],
        state.handle.metrics(),
    )
        .into_response()
}

async fn not_found(method: Method, uri: Uri) -> ApiError {
    ApiError::new(
        StatusCode::NOT_FOUND,
        format!("no route {method} {}; GET / lists the API", uri.path()),
    )
}

async fn method_not_allowed(method: Method, uri: Uri) -> ApiError {
    let hint = match uri.path() {
        "/api/calibrate" | "/api/check" | "/api/cancel" => "use POST",
        _ => "use GET",
    };
    ApiError::new(
        StatusCode::METHOD_NOT_ALLOWED,
        format!("{method} is not allowed on {}; {hint}", uri.path()),
    )
}

#[cfg(test)]
mod tests {
    use std::f64::consts::FRAC_PI_2;
    use std::net::{IpAddr, Ipv4Addr, TcpListener};
    use std::sync::OnceLock;
    use std::time::Duration;

    use crate::config::{self, RobotPorts, ViewTargets};
    use crate::model::RobotModel;
    use handeye_hal::fake::{FakeCamera, FakeRobot};
    use handeye_hal::ur_dh::UrModel;
    use handeye_hal::{CameraInfo, CaptureSettings, DepthCamera, HalError, PointCloud};
    use serde_json::Value;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    use tokio::sync::Semaphore;

    use super::*;

    /// The UR home pose: upright, clear of everything; the arm starts and looks from here.
    const HOME: [f64; 6] = [0.0, -FRAC_PI_2, FRAC_PI_2, -FRAC_PI_2, -FRAC_PI_2, 0.0];
    const TOKEN: &str = "0123456789abcdef0123456789abcdef";

    fn model() -> Option<Arc<RobotModel>> {
        static MODEL: OnceLock<Option<Arc<RobotModel>>> = OnceLock::new();
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/robots/ur/ur5e/ur5e.urdf");
        let m = MODEL
            .get_or_init(|| {
                path.exists()
                    .then(|| Arc::new(RobotModel::load(&path).expect("UR5e model loads")))
            })
            .clone();
        if m.is_none() {
            assert!(
                std::env::var_os("CI").is_none(),
                "{} is missing and CI is set",
                path.display()
            );
            crate::skips::record(
                "daemon::api::tests",
                &format!("{} not found; the API tests need it", path.display()),
            );
        }
        m
    }

    fn scratch(tag: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("handeye-api-{}-{tag}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("scratch dir");
        dir
    }

    fn free_port() -> SocketAddr {
        TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .expect("a free port")
    }

    fn test_config(storage: &Path) -> Config {
        let mut cfg = config::sim_rig(
            IpAddr::V4(Ipv4Addr::LOCALHOST),
            RobotPorts::UR_STANDARD,
            "127.0.0.1".into(),
            storage.to_path_buf(),
        );
        // A view away from the start (a view at the start joints needs no move at all).
        let mut view = HOME;
        view[0] += 0.3;
        cfg.views.targets = ViewTargets::Joints(vec![view]);
        cfg.camera.settle = Duration::from_millis(10);
        cfg
    }

    /// A camera with nothing to replay whose captures wait for a permit, so a test decides
    /// when the run in progress ends.
    #[derive(Debug, Clone)]
    struct GatedCamera {
        inner: FakeCamera,
        gate: Arc<Semaphore>,
    }

    impl DepthCamera for GatedCamera {
        async fn info(&self) -> Result<CameraInfo, HalError> {
            self.inner.info().await
        }

        async fn capture(&self, settings: &CaptureSettings) -> Result<Vec<PointCloud>, HalError> {
            let _permit = self.gate.acquire().await;
            self.inner.capture(settings).await
        }
    }

    /// A daemon over the fakes with the API on a free port, as a test sees it.
    struct Rig {
        addr: SocketAddr,
        robot: FakeRobot,
        /// Permits for the camera's captures (none at first: a run waits at its capture).
        gate: Arc<Semaphore>,
    }

    /// Runs `body` against a daemon over the fakes (the API on a free port with `token`), then
    /// stops the daemon and waits for it. The daemon runs on the test's task, joined with the
    /// body: its future need not be `Send`.
    async fn with_rig<F, Fut>(tag: &str, token: Option<&str>, body: F)
    where
        F: FnOnce(Rig) -> Fut,
        Fut: std::future::Future<Output = ()>,
    {
        let Some(model) = model() else {
            return;
        };
        let dir = scratch(tag);
        let cfg = test_config(&dir);
        let store = Arc::new(Store::open(&dir.join("history.sqlite")).expect("store"));
        let robot = FakeRobot::new(UrModel::Ur5e, HOME);
        let gate = Arc::new(Semaphore::new(0));
        let camera = GatedCamera {
            inner: FakeCamera::new(Vec::new()),
            gate: Arc::clone(&gate),
        };
        let addr = free_port();
        let api = Api::new(addr, token.map(String::from));
        let shutdown = CancellationToken::new();
        let daemon = crate::daemon::run(
            cfg,
            model,
            robot.clone(),
            camera,
            store,
            api,
            shutdown.clone(),
            |_| {},
        );
        let test = async {
            let mut listening = false;
            for _ in 0..200 {
                if tokio::net::TcpStream::connect(addr).await.is_ok() {
                    listening = true;
                    break;
                }
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
            assert!(listening, "the API never listened on {addr}");
            body(Rig {
                addr,
                robot,
                gate: Arc::clone(&gate),
            })
            .await;
            gate.add_permits(100);
            shutdown.cancel();
        };
        tokio::time::timeout(Duration::from_secs(120), async {
            tokio::join!(daemon, test)
        })
        .await
        .expect("the test and the daemon's stop take less than 2 min");
    }

    impl Rig {
        async fn get(&self, path: &str) -> Answer {
            http(self.addr, "GET", path, &[]).await
        }

        async fn post(&self, path: &str, token: Option<&str>) -> Answer {
            match token {
                Some(t) => {
                    let bearer = format!("Bearer {t}");
                    http(self.addr, "POST", path, &[("Authorization", &bearer)]).await
                }
                None => http(self.addr, "POST", path, &[]).await,
            }
        }

        /// Waits for the daemon to be idle again; its status.
        async fn idle(&self) -> Value {
            for _ in 0..200 {
                let st = self.get("/api/status").await.json();
                if st["state"] == "idle" {
                    return st;
                }
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
            panic!("the run never ended");
        }
    }

    /// Issue 23: charts, pictures and exports are limited per client: a burst, then 429 with
    /// `Retry-After`; the other routes and the other clients are not affected.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn issue_23_expensive_routes_are_rate_limited_per_client() {
        with_rig("rate-limit", None, |rig| async move {
            let burst = crate::daemon::listener::RateLimit::BURST as usize;
            for k in 0..burst {
                // (JSON: this client reads answers as text.)
                let a = rig.get("/api/drift").await;
                assert_eq!(a.code, 200, "request {k}: {}", a.body);
            }
            let a = rig.get("/api/drift.png?width=2000&height=2000").await;
            assert_eq!(a.code, 429, "{}", a.body);
            assert!(a.header("retry-after").is_some(), "{}", a.head);
            assert!(a.json()["error"].as_str().unwrap_or("").contains("wait"));
            assert_eq!(rig.get("/api/drift").await.code, 429);
            assert_eq!(rig.get("/api/status").await.code, 200);
            tokio::time::sleep(Duration::from_secs_f64(
                1.1 / crate::daemon::listener::RateLimit::PER_SECOND,
            ))
            .await;
            assert_eq!(rig.get("/api/drift").await.code, 200, "refilled");
        })
        .await;
    }

    #[derive(Debug)]
    struct Answer {
        code: u16,
        head: String,
        body: String,
    }

    impl Answer {
        fn json(&self) -> Value {
            serde_json::from_str(&self.body)
                .unwrap_or_else(|e| panic!("not JSON ({e}): {}", self.body))
        }

        fn header(&self, name: &str) -> Option<&str> {
            self.head.lines().find_map(|l| {
                let (n, v) = l.split_once(':')?;
                n.eq_ignore_ascii_case(name).then(|| v.trim())
            })
        }
    }

    /// One HTTP/1.1 request without a body on a fresh connection (`Content-Length: 0` unless
    /// `headers` say otherwise).
    async fn http(addr: SocketAddr, method: &str, path: &str, headers: &[(&str, &str)]) -> Answer {
        let mut s = tokio::net::TcpStream::connect(addr).await.expect("connect");
        let mut req = format!("{method} {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n");
        if !headers
            .iter()
            .any(|(n, _)| n.eq_ignore_ascii_case("content-length"))
        {
            req += "Content-Length: 0\r\n";
        }
        for (name, value) in headers {
            req += &format!("{name}: {value}\r\n");
        }
        req += "\r\n";
        s.write_all(req.as_bytes()).await.expect("send");
        let mut raw = String::new();
        tokio::time::timeout(Duration::from_secs(10), s.read_to_string(&mut raw))
            .await
            .expect("answer in time")
            .expect("read");
        let (head, body) = raw.split_once("\r\n\r\n").expect("HTTP answer");
        let code = head
            .split(' ')
            .nth(1)
            .and_then(|c| c.parse().ok())
            .expect("status code");
        Answer {
            code,
            head: head.to_string(),
            body: body.to_string(),
        }
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn api_moves_the_arm_only_with_the_token_one_run_at_a_time() {
        with_rig("token", Some(TOKEN), |rig| async move {
            let st = rig.get("/api/status").await;
            assert_eq!(st.code, 200, "{st:?}");
            assert_eq!(st.json()["state"], "idle");

            // No token, a wrong one, another scheme: 401 with a challenge, nothing moves.
            for token in [None, Some("wrong"), Some(&TOKEN[..TOKEN.len() - 1])] {
                let a = rig.post("/api/calibrate", token).await;
                assert_eq!(a.code, 401, "{a:?}");
                assert!(a
                    .header("www-authenticate")
                    .is_some_and(|v| v.starts_with("Bearer")));
                assert!(a.json()["error"]
                    .as_str()
                    .is_some_and(|e| e.contains("token")));
                let a = rig.post("/api/check", token).await;
                assert_eq!(a.code, 401, "{a:?}");
                let a = rig.post("/api/cancel", token).await;
                assert_eq!(a.code, 401, "{a:?}");
            }
            let basic = http(
                rig.addr,
                "POST",
                "/api/calibrate",
                &[("Authorization", "Basic dTpw")],
            )
            .await;
            assert_eq!(basic.code, 401, "{basic:?}");
            // A body larger than the limit is refused before any handler runs.
            let big = http(
                rig.addr,
                "POST",
                "/api/calibrate",
                &[("Content-Length", "100000")],
            )
            .await;
            assert_eq!(big.code, 413, "{big:?}");
            assert!(rig.robot.moves().is_empty(), "moved without a token");
            assert_eq!(rig.get("/api/status").await.json()["state"], "idle");

            // The token: accepted; a second trigger at once is refused busy.
            let a = rig.post("/api/calibrate", Some(TOKEN)).await;
            assert_eq!(a.code, 202, "{a:?}");
            let run_id = a.json()["run_id"].as_str().expect("run id").to_string();
            let busy = rig.post("/api/check", Some(TOKEN)).await;
            assert_eq!(busy.code, 409, "{busy:?}");
            let msg = busy.json()["error"].as_str().expect("error").to_string();
            assert!(msg.contains("busy") && msg.contains(&run_id), "{msg}");
            let st = rig.get("/api/status").await.json();
            assert_eq!(st["state"], "running");
            assert_eq!(st["current"]["run_id"], run_id.as_str());
            assert_eq!(st["current"]["trigger"], "api");

            // The capture fails (no clouds): the run ends in error and is in the history.
            rig.gate.add_permits(1);
            let st = rig.idle().await;
            assert_eq!(st["last"]["run_id"], run_id.as_str());
            assert_eq!(st["last"]["outcome"], "error");
            assert!(
                !rig.robot.moves().is_empty(),
                "the accepted run moved the arm"
            );

            let runs = rig.get("/api/runs").await;
            assert_eq!(runs.code, 200, "{runs:?}");
            let runs = runs.json();
            let listed = runs["runs"].as_array().expect("runs");
            assert_eq!(listed.len(), 1, "{runs}");
            assert_eq!(listed[0]["run_id"], run_id.as_str());
            assert_eq!(listed[0]["outcome"], "error");
            assert_eq!(
                listed[0]["verdict"], "error",
                "the one word every view uses"
            );
            let record = rig.get(&format!("/api/runs/{run_id}")).await;
            assert_eq!(record.code, 200, "{record:?}");
            assert_eq!(record.json()["run_id"], run_id.as_str());
            assert_eq!(rig.get("/api/runs/nope").await.code, 404);
            // No accepted calibration yet.
            let latest = rig.get("/api/latest").await;
            assert_eq!(latest.code, 404, "{latest:?}");
            assert!(latest.json()["error"].as_str().is_some());

            // Paging and bad numbers.
            let page = rig.get("/api/runs?limit=1&before=1").await.json();
            assert_eq!(page["runs"].as_array().map(Vec::len), Some(0));
            for bad in [
                "limit=0",
                "limit=1001",
                "limit=x",
                "before=-1",
                "before=nan",
                "lmit=3",
            ] {
                let a = rig.get(&format!("/api/runs?{bad}")).await;
                assert_eq!(a.code, 400, "{bad}: {a:?}");
                assert!(a.json()["error"].is_string());
            }

            // Cancel with nothing running.
            let a = rig.post("/api/cancel", Some(TOKEN)).await;
            assert_eq!(a.code, 200, "{a:?}");
            assert_eq!(a.json()["cancelled"], false);

            let m = rig.get("/metrics").await;
            assert_eq!(m.code, 200);
            assert!(m
                .header("content-type")
                .is_some_and(|c| c.starts_with("text/plain; version=0.0.4")));
            assert!(
                m.body
                    .contains("handeye_runs_total{trigger=\"api\",outcome=\"error\"} 1"),
                "{}",
                m.body
            );

            let page = rig.get("/").await;
            assert_eq!(page.code, 200);
            assert!(page
                .header("content-type")
                .is_some_and(|c| c.starts_with("text/html")));
            assert!(page.header("content-security-policy").is_some());
            assert!(page.body.contains("/app.js"), "{}", page.body);
            for asset in ["/app.js", "/app.css", "/favicon.svg"] {
                assert_eq!(rig.get(asset).await.code, 200, "{asset}");
            }
            let drift = rig.get("/api/drift").await.json();
            assert_eq!(drift["checks"], json!([]), "{drift}");
            assert_eq!(drift["max_translation_mm"], 1.0);
            // No storage behind this API, and a run that ended in error has no result.
            let a = rig.get(&format!("/api/runs/{run_id}/report.png")).await;
            assert_eq!(a.code, 404, "{a:?}");
            assert_eq!(rig.get("/api/runs/..%2F..%2Fx/report.png").await.code, 404);
            let a = rig.get(&format!("/api/runs/{run_id}/exports")).await;
            assert_eq!(a.code, 404, "{a:?}");
            assert!(a.json()["error"]
                .as_str()
                .is_some_and(|e| e.contains("no result")));
            assert_eq!(rig.get("/api/drift.png?width=5").await.code, 400);
            let a = rig.get("/api/nothing").await;
            assert_eq!(a.code, 404);
            assert!(a.json()["error"].is_string());
            let a = rig.get("/api/calibrate").await;
            assert_eq!(a.code, 405);
            assert!(a.json()["error"]
                .as_str()
                .is_some_and(|e| e.contains("POST")));
        })
        .await;
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn api_cancels_the_run_in_progress() {
        with_rig("cancel", Some(TOKEN), |rig| async move {
            let a = rig.post("/api/check", Some(TOKEN)).await;
            assert_eq!(a.code, 202, "{a:?}");
            let a = rig.post("/api/cancel", Some(TOKEN)).await;
            assert_eq!(a.json()["cancelled"], true);
            let st = rig.idle().await;
            assert_eq!(st["last"]["mode"], "check");
            assert_eq!(st["last"]["outcome"], "aborted", "{st}");
        })
        .await;
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn without_a_token_nothing_moves_the_arm() {
        with_rig("no-token", None, |rig| async move {
            for path in ["/api/calibrate", "/api/check", "/api/cancel"] {
                for token in [None, Some(TOKEN)] {
                    let a = rig.post(path, token).await;
                    assert_eq!(a.code, 403, "{path}: {a:?}");
                    assert_eq!(a.json()["error"], NO_TOKEN);
                }
            }
            assert_eq!(rig.get("/api/status").await.json()["state"], "idle");
            assert!(rig.robot.moves().is_empty());
        })
        .await;
    }

    /// Issue 36: wrong tokens are limited per client (14 500 tries/s were answered before);
    /// past the limit even the right token waits for the next window.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn issue_36_wrong_tokens_are_rate_limited_per_client() {
        with_rig("auth-limit", Some(TOKEN), |rig| async move {
            let wrong = "not-the-token-0123456789";
            for k in 0..AuthLimit::MAX_FAILURES {
                let a = rig.post("/api/cancel", Some(wrong)).await;
                assert_eq!(a.code, 401, "try {k}: {a:?}");
            }
            for token in [wrong, TOKEN] {
                let a = rig.post("/api/cancel", Some(token)).await;
                assert_eq!(a.code, 429, "{a:?}");
                assert!(a.header("retry-after").is_some(), "{}", a.head);
            }
            assert_eq!(rig.get("/api/status").await.code, 200);
        })
        .await;
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_taken_port_is_reported_and_serve_returns() {
        let Some(model) = model() else {
            return;
        };
        let taken = TcpListener::bind("127.0.0.1:0").expect("bind");
        let addr = taken.local_addr().expect("addr");
        let dir = scratch("taken");
        let store = Arc::new(Store::open(&dir.join("history.sqlite")).expect("store"));
        let shutdown = CancellationToken::new();
        let (tx, rx) = tokio::sync::oneshot::channel();
        let daemon = crate::daemon::run(
            test_config(&dir),
            model,
            FakeRobot::new(UrModel::Ur5e, HOME),
            FakeCamera::new(Vec::new()),
            store,
            Api::new(addr, Some(TOKEN.into())),
            shutdown.clone(),
            move |h| {
                let _ = tx.send(h.clone());
            },
        );
        let test = async {
            let handle = rx.await.expect("ready");
            // The daemon runs on without its API.
            tokio::time::sleep(Duration::from_millis(300)).await;
            assert_eq!(handle.status().state, crate::daemon::DaemonState::Idle);
            assert!(handle.request(RunMode::Check, Trigger::Api).is_ok());
            shutdown.cancel();
        };
        tokio::time::timeout(Duration::from_secs(60), async {
            tokio::join!(daemon, test)
        })
        .await
        .expect("the daemon stops");
        drop(taken);
    }

    #[test]
    fn tokens_compare_whole() {
        assert!(token_matches(b"abc", b"abc"));
        assert!(!token_matches(b"abc", b"abd"));
        assert!(!token_matches(b"abc", b"ab"));
        assert!(!token_matches(b"abc", b"abcd"));
        assert!(!token_matches(b"abc", b""));
    }

    #[test]
    fn report_paths_and_chart_sizes_are_checked() {
        assert_eq!(chart_size(None), Ok((900, 340)));
        assert_eq!(
            chart_size(Some("width=1200&height=400&t=17")),
            Ok((1200, 400))
        );
        assert!(chart_size(Some("width=100")).is_err());
        assert!(chart_size(Some("height=99999")).is_err());
        assert!(chart_size(Some("depth=3")).is_err());
    }

    #[test]
    fn runs_query_defaults_and_bounds() {
        assert_eq!(runs_query(None), Ok((DEFAULT_RUNS, None)));
        assert_eq!(runs_query(Some("")), Ok((DEFAULT_RUNS, None)));
        assert_eq!(
            runs_query(Some("limit=1000&before=1700000000.5")),
            Ok((1000, Some(1_700_000_000.5)))
        );
        assert!(runs_query(Some("limit=1001")).is_err_and(|e| e.contains("1 to 1000")));
        assert!(runs_query(Some("before=x")).is_err_and(|e| e.contains("unix time")));
    }

    #[cfg(unix)]
    #[test]
    fn token_files_are_checked() {
        use std::os::unix::fs::PermissionsExt;
        let dir = scratch("token-files");
        let mut cfg = test_config(&dir);
        let file = dir.join("token");
        let write = |text: &str, mode: u32| {
            std::fs::write(&file, text).expect("write");
            std::fs::set_permissions(&file, std::fs::Permissions::from_mode(mode)).expect("chmod");
        };

        // None configured: the API runs, refusing what moves the arm.
        let api = Api::from_config_with(&cfg, None).expect("no token is allowed");
        assert!(api.token.is_none());

        cfg.daemon.token_file = Some(file.clone());
        write(&format!("  {TOKEN}\n"), 0o600);
        let api = Api::from_config_with(&cfg, None).expect("a private token file");
        assert_eq!(api.token.as_deref(), Some(TOKEN));
        assert!(!format!("{api:?}").contains(TOKEN), "Debug shows the token");

        write(TOKEN, 0o644);
        let e = format!(
            "{:#}",
            Api::from_config_with(&cfg, None).expect_err("0644 is refused")
        );
        assert!(
            e.contains("chmod 600") && e.contains(&file.display().to_string()),
            "{e}"
        );
        write(TOKEN, 0o640);
        assert!(Api::from_config_with(&cfg, None).is_err());

        write(" \n", 0o600);
        let e = format!(
            "{:#}",
            Api::from_config_with(&cfg, None).expect_err("empty")
        );
        assert!(e.contains("empty"), "{e}");
        write("two words, both long enough", 0o600);
        assert!(Api::from_config_with(&cfg, None).is_err());
        // Issue 23: a 1-character token is refused, saying how long and how to make one.
        write("x", 0o600);
        let e = format!(
            "{:#}",
            Api::from_config_with(&cfg, None).expect_err("short")
        );
        assert!(
            e.contains("at least 16 random ones, e.g.") && e.contains("openssl rand"),
            "{e}"
        );
        // Issue 23: a FIFO as token file is refused at once, not waited on.
        let fifo = dir.join("token.fifo");
        let made = std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .expect("mkfifo runs");
        assert!(made.success());
        std::fs::set_permissions(&fifo, std::fs::Permissions::from_mode(0o600)).expect("chmod");
        cfg.daemon.token_file = Some(fifo.clone());
        let t = std::time::Instant::now();
        let e = format!("{:#}", Api::from_config_with(&cfg, None).expect_err("FIFO"));
        assert!(e.contains("FIFO"), "{e}");
        assert!(t.elapsed() < Duration::from_secs(1), "{:?}", t.elapsed());
        cfg.daemon.token_file = Some(file.clone());

        cfg.daemon.token_file = Some(dir.join("missing"));
        assert!(Api::from_config_with(&cfg, None).is_err());

        // systemd's credential wins over the file; its mode is systemd's business (an ACL
        // shows as group bits).
        let creds = dir.join("credentials");
        std::fs::create_dir_all(&creds).expect("dir");
        let cred = creds.join("token");
        std::fs::write(&cred, "from-systemd-0123456789\n").expect("write");
        std::fs::set_permissions(&cred, std::fs::Permissions::from_mode(0o440)).expect("chmod");
        let api = Api::from_config_with(&cfg, Some(&creds)).expect("credential");
        assert_eq!(api.token.as_deref(), Some("from-systemd-0123456789"));
        // A credentials directory without `token` falls back to the file.
        cfg.daemon.token_file = Some(file.clone());
        write(TOKEN, 0o600);
        let api = Api::from_config_with(&cfg, Some(&dir.join("other"))).expect("file");
        assert_eq!(api.token.as_deref(), Some(TOKEN));
    }
}
