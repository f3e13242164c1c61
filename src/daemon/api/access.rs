//! Who may do what: the API token (read from its file, compared in constant time, asked of
//! every request that moves or stops the arm), the per-client limit of the expensive routes
//! and the refusal of large bodies.

use std::net::SocketAddr;
use std::path::Path;

use anyhow::{bail, Context};
use axum::extract::{ConnectInfo, Request, State};
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};

use super::{ApiError, AppState, BODY_LIMIT, MIN_TOKEN_CHARS, NO_TOKEN};
#[cfg(doc)]
use crate::daemon::listener::{AuthLimit, RateLimit};

/// The token in `path`, trimmed. Refuses an empty token, one that cannot go in an HTTP header
/// as one word, and (Unix, `check_mode`) a file that group or others can access.
pub(super) fn read_token(path: &Path, check_mode: bool) -> anyhow::Result<String> {
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

/// Whether `given` is `expected`, in time that depends only on `expected`'s length.
pub(super) fn token_matches(expected: &[u8], given: &[u8]) -> bool {
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
pub(super) fn authorize(
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
pub(super) async fn rate_limited(
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
pub(super) async fn refuse_large_bodies(req: Request, next: Next) -> Response {
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
