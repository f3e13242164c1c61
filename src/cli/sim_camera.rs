//! `handeye sim camera`: a simulated GigE Vision 3D camera on a given address.

use std::process::ExitCode;

use anyhow::Context as _;
use handeye_gige::sim::{SimCamera, SimOptions};
use handeye_gige::GvcpClient;
use handeye_sim_scene::SceneArgs;
use tokio_util::sync::CancellationToken;

/// Arguments of this subcommand.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Address to serve GVCP on, `IP` or `IP:PORT` (default port 3956).
    #[arg(long, value_name = "ADDR")]
    bind: String,
    /// Fraction of stream packets to drop (the camera resends them on request).
    #[arg(long, default_value_t = 0.0)]
    loss: f64,
    #[command(flatten)]
    scene: SceneArgs,
}

/// Serves until `shutdown` is cancelled (Ctrl-C or SIGTERM), then stops the camera and prints
/// what it served.
pub(crate) async fn run(args: Args, shutdown: CancellationToken) -> anyhow::Result<ExitCode> {
    // Loading meshes, planning the view and binding sockets block: keep them off the workers.
    let cam = tokio::task::spawn_blocking(move || start(args))
        .await
        .context("the simulator start-up thread failed")??;
    shutdown.cancelled().await;
    let s = cam.stats();
    // Dropping joins the camera's threads.
    tokio::task::spawn_blocking(move || drop(cam))
        .await
        .context("stopping the simulated camera")?;
    eprintln!(
        "served {} frames, dropped {} packets, resent {}",
        s.frames, s.dropped_packets, s.resent_packets
    );
    Ok(ExitCode::SUCCESS)
}

/// Builds the frame source and starts serving (blocking).
fn start(args: Args) -> anyhow::Result<SimCamera> {
    if !(0.0..1.0).contains(&args.loss) {
        anyhow::bail!("--loss must be in [0, 1)");
    }
    let bind = GvcpClient::parse_address(&args.bind)?;
    let (source, scene) = args.scene.frame_source()?;
    let opts = SimOptions {
        loss_ratio: args.loss,
        ..args.scene.options()
    };
    let cam = SimCamera::spawn(bind, source, opts)?;
    eprintln!(
        "simulated GigE Vision 3D camera on {} ({}x{}, {scene}); Ctrl-C to stop",
        cam.addr(),
        args.scene.width,
        args.scene.height
    );
    Ok(cam)
}
