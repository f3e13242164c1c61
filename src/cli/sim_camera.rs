//! `handeye sim camera`: a simulated GigE Vision 3D camera on a given address.

use std::process::ExitCode;

use handeye_gige::sim::{SceneSource, SimCamera, SimOptions};
use handeye_gige::GvcpClient;

/// Arguments of this subcommand.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Address to serve GVCP on, `IP` or `IP:PORT` (default port 3956).
    #[arg(long, value_name = "ADDR")]
    bind: String,
    /// Follow this robot over RTDE and render the robot from the camera mount.
    #[arg(long, value_name = "ROBOT_ADDR")]
    robot: Option<String>,
    /// Robot model of the rendered scene.
    #[arg(long, default_value = "ur5e")]
    model: String,
    /// Camera mount `x,y,z,rx,ry,rz` (m, axis-angle rad) on the flange.
    #[arg(long, value_name = "POSE", allow_hyphen_values = true)]
    mount: Option<String>,
    /// Sensor width in pixels.
    #[arg(long, default_value_t = 640)]
    width: u32,
    /// Sensor height in pixels.
    #[arg(long, default_value_t = 480)]
    height: u32,
    /// Frames per second while acquiring.
    #[arg(long, default_value_t = 10.0)]
    frame_rate: f64,
    /// Fraction of stream packets to drop (the camera resends them on request).
    #[arg(long, default_value_t = 0.0)]
    loss: f64,
    /// Serial number to report.
    #[arg(long, default_value = "SIM0001")]
    serial: String,
}

pub(crate) fn run(args: Args) -> anyhow::Result<ExitCode> {
    if args.robot.is_some() || args.mount.is_some() {
        anyhow::bail!(
            "--robot/--mount (rendering the {} from the scan simulator) are not wired yet; run without them for the built-in test scene",
            args.model
        );
    }
    if !(0.0..1.0).contains(&args.loss) {
        anyhow::bail!("--loss must be in [0, 1)");
    }
    let bind = GvcpClient::parse_address(&args.bind)?;
    let opts = SimOptions {
        loss_ratio: args.loss,
        frame_rate: args.frame_rate,
        serial: args.serial,
        ..SimOptions::default()
    };
    let source = SceneSource::new(args.width, args.height);
    let cam = SimCamera::spawn(bind, Box::new(source), opts)?;
    eprintln!(
        "simulated GigE Vision 3D camera on {} ({}x{}, built-in plane + sphere test scene); Ctrl-C to stop",
        cam.addr(),
        args.width,
        args.height
    );
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?
        .block_on(tokio::signal::ctrl_c())?;
    let s = cam.stats();
    eprintln!(
        "served {} frames, dropped {} packets, resent {}",
        s.frames, s.dropped_packets, s.resent_packets
    );
    Ok(ExitCode::SUCCESS)
}
