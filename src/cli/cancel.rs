//! `handeye cancel --config FILE`: asks the running daemon (`POST /api/cancel` at
//! `daemon.listen`, with the API token the daemon reads) to cancel the run in progress — the arm
//! is stopped, the run recorded as aborted — and the queued ones. Exit 0 when the daemon
//! answered (whether or not a run was going), 2 otherwise.

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
    let api = Api::from_config(&cfg)?;
    let token = api.token().context(
        "no API token is configured (daemon.token_file), and the daemon refuses a cancel \
         without one; stop the arm on the pendant, or configure a token and restart the daemon",
    )?;
    let addr = reachable(cfg.daemon.listen);
    let (code, body) =
        http_request(addr, "POST", "/api/cancel", Some(token)).with_context(|| {
            format!(
                "no daemon answers at {addr}; start it with `handeye daemon --config {}`",
                args.config.display()
            )
        })?;
    if code != 200 {
        let msg = serde_json::from_slice::<ErrorBody>(&body)
            .map_or_else(|_| "no reason given".to_string(), |b| b.error);
        anyhow::bail!("the daemon at {addr} answered {code}: {msg}");
    }
    let answer: serde_json::Value = serde_json::from_slice(&body)
        .with_context(|| format!("the daemon at {addr} answered something other than JSON"))?;
    if answer["cancelled"] == true {
        println!("cancelled: the run in progress was told to stop (the arm is stopped) and the queued ones dropped; `handeye status` shows when it has ended");
    } else {
        println!("nothing to cancel: no run is going");
    }
    Ok(ExitCode::SUCCESS)
}
