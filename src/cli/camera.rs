//! `handeye camera`: probe a GigE Vision 3D camera and capture point clouds from it.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::Context;
use handeye_gige::{ControlConfig, GigeCamera, GvcpClient};

/// Arguments of this subcommand.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    #[command(subcommand)]
    command: CameraCommand,
}

#[derive(Debug, clap::Subcommand)]
enum CameraCommand {
    /// Identify the camera: vendor, model, serial, firmware, size, pixel formats.
    Probe {
        /// Camera address, `IP` or `IP:PORT` (GVCP, default port 3956).
        #[arg(long, value_name = "ADDR")]
        gige: String,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
    },
    /// Capture point clouds and print frame statistics.
    Capture {
        /// Camera address, `IP` or `IP:PORT` (GVCP, default port 3956).
        #[arg(long, value_name = "ADDR")]
        gige: String,
        /// Number of complete frames to capture.
        #[arg(long, default_value_t = 1)]
        frames: u32,
        /// Write the (first) cloud to this PLY file.
        #[arg(long)]
        out: Option<PathBuf>,
        /// Print JSON (`frames`, `complete`, `incomplete`, `resent_packets`, …).
        #[arg(long)]
        json: bool,
        /// GVSP packet size in bytes (whole IP datagram); 9000 on jumbo-frame networks.
        #[arg(long, default_value_t = 1500)]
        packet_size: u32,
        /// Give up on a frame after this many milliseconds.
        #[arg(long, default_value_t = 5000)]
        frame_timeout_ms: u64,
        /// Also stream the confidence component when the camera has one.
        #[arg(long)]
        confidence: bool,
    },
}

fn connect(addr: &str) -> anyhow::Result<GigeCamera> {
    let addr = GvcpClient::parse_address(addr)?;
    GigeCamera::connect(addr, ControlConfig::default())
        .with_context(|| format!("connecting to the camera at {addr}"))
}

pub(crate) fn run(args: Args) -> anyhow::Result<ExitCode> {
    match args.command {
        CameraCommand::Probe { gige, json } => {
            let cam = connect(&gige)?;
            let info = cam.info_blocking()?;
            if json {
                println!("{}", serde_json::to_string_pretty(&info)?);
            } else {
                println!("vendor:        {}", info.vendor);
                println!("model:         {}", info.model);
                println!("serial:        {}", info.serial);
                println!("firmware:      {}", info.firmware);
                println!("size:          {} x {}", info.width, info.height);
                println!("pixel formats: {}", info.pixel_formats.join(", "));
            }
            Ok(ExitCode::SUCCESS)
        }
        CameraCommand::Capture {
            gige,
            frames,
            out,
            json,
            packet_size,
            frame_timeout_ms,
            confidence,
        } => {
            if frames == 0 {
                anyhow::bail!("--frames must be at least 1");
            }
            let mut cam = connect(&gige)?;
            cam.options.packet_size = packet_size;
            cam.options.confidence = confidence;
            let (clouds, stats) =
                cam.capture_blocking(frames, Duration::from_millis(frame_timeout_ms))?;
            let valid: Vec<usize> = clouds.iter().map(|c| c.valid_count()).collect();
            if json {
                let v = serde_json::json!({
                    "frames": clouds.len(),
                    "complete": stats.complete,
                    "incomplete": stats.incomplete,
                    "resent_packets": stats.resent_packets,
                    "width": clouds.first().map_or(0, |c| c.width),
                    "height": clouds.first().map_or(0, |c| c.height),
                    "valid_points": valid,
                    "stream": stats.stream,
                });
                println!("{}", serde_json::to_string_pretty(&v)?);
            } else {
                println!(
                    "{} frames ({} complete, {} incomplete dropped, {} packets resent); valid points per frame: {:?}",
                    clouds.len(),
                    stats.complete,
                    stats.incomplete,
                    stats.resent_packets,
                    valid
                );
            }
            if let Some(path) = out {
                // Several frames go to `<stem>_<i>.ply`; one frame to the path given.
                for (i, cloud) in clouds.iter().enumerate() {
                    let file = if clouds.len() == 1 {
                        path.clone()
                    } else {
                        let stem = path
                            .file_stem()
                            .map(|s| s.to_string_lossy().into_owned())
                            .unwrap_or_default();
                        path.with_file_name(format!("{stem}_{i}.ply"))
                    };
                    handeye::cloud::write_ply(
                        &file,
                        cloud,
                        handeye::cloud::PlyEncoding::BinaryLittleEndian,
                    )
                    .map_err(|e| anyhow::anyhow!("writing {}: {e}", file.display()))?;
                    eprintln!("wrote {}", file.display());
                }
            }
            Ok(ExitCode::SUCCESS)
        }
    }
}
