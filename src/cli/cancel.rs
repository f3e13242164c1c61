//! `handeye cancel --config FILE`: asks the running daemon to cancel the run in progress — the
//! arm is stopped, the run recorded as aborted — and the queued ones: through its control
//! socket (`<storage.dir>/daemon.sock`, [`handeye::daemon::control`]) when this user can reach
//! it, which no number of HTTP connections can lock out; else `POST /api/cancel` at
//! `daemon.listen` with the API token the daemon reads. Exit 0 when the daemon answered
//! (whether or not a run was going), 2 otherwise; the error tells a daemon that does not
//! answer over its limits from no daemon at all.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use handeye::config::Config;
use handeye::daemon::api::{Api, ErrorBody};

use super::status::{http_request, reachable};

/// Arguments of this subcommand.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// The cell's configuration: `daemon.listen` and the token (`daemon.token_file`, or
    /// systemd's `$CREDENTIALS_DIRECTORY/token`).
    #[arg(long, value_name = "FILE")]
    config: PathBuf,
}

pub(crate) fn run(args: Args) -> anyhow::Result<ExitCode> {
    let cfg = Config::load(&args.config)?;
    let socket = handeye::daemon::control::socket_path(&cfg.storage.dir);
    match handeye::daemon::control::request(&cfg.storage.dir, "cancel") {
        Ok(answer) => {
            let answer: serde_json::Value = serde_json::from_str(&answer).with_context(|| {
                format!(
                    "the daemon's control socket {} answered something other than JSON",
                    socket.display()
                )
            })?;
            return report(&answer);
        }
        // No socket (another user, an older daemon, none running): the HTTP API.
        Err(e) => tracing::debug!("control socket {}: {e}", socket.display()),
    }
    let api = Api::from_config(&cfg)?;
    let token = api.token().context(
        "no API token is configured (daemon.token_file), and the daemon refuses a cancel \
         without one; stop the arm on the pendant, or configure a token and restart the daemon",
    )?;
    let addr = reachable(cfg.daemon.listen);
    let (code, body) = match http_request(addr, "POST", "/api/cancel", Some(token)) {
        Ok(answer) => answer,
        Err(e) if refused(&e) => {
            return Err(e.context(format!(
                "no daemon answers at {addr}; start it with `handeye daemon --config {}`",
                args.config.display()
            )))
        }
        Err(e) => {
            return Err(e.context(format!(
                "the daemon at {addr} is busy or over its connection limits (it took the connection and closed it without answering; {} is not reachable by this user); stop the arm on the pendant if it must stop now, then retry",
                socket.display()
            )))
        }
    };
    if code != 200 {
        let msg = serde_json::from_slice::<ErrorBody>(&body)
            .map_or_else(|_| "no reason given".to_string(), |b| b.error);
        anyhow::bail!("the daemon at {addr} answered {code}: {msg}");
    }
    let answer: serde_json::Value = serde_json::from_slice(&body)
        .with_context(|| format!("the daemon at {addr} answered something other than JSON"))?;
    report(&answer)
}

/// Whether `e` says nothing listens (connection refused, no route): no daemon at all.
fn refused(e: &anyhow::Error) -> bool {
    e.chain()
        .filter_map(|c| c.downcast_ref::<std::io::Error>())
        .any(|io| {
            matches!(
                io.kind(),
                std::io::ErrorKind::ConnectionRefused
                    | std::io::ErrorKind::AddrNotAvailable
                    | std::io::ErrorKind::HostUnreachable
                    | std::io::ErrorKind::NetworkUnreachable
            )
        })
}

/// Prints the daemon's answer to a cancel.
fn report(answer: &serde_json::Value) -> anyhow::Result<ExitCode> {
    if let Some(e) = answer["error"].as_str() {
        anyhow::bail!("the daemon refused the cancel: {e}");
    }
    if answer["cancelled"] == true {
        println!("cancelled: the run in progress was told to stop (the arm is stopped) and the queued ones dropped; `handeye status` shows when it has ended");
    } else {
        println!("nothing to cancel: no run is going");
    }
    Ok(ExitCode::SUCCESS)
}
