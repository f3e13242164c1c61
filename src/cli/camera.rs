//! `handeye camera`: probe a GigE Vision 3D camera or a GenTL producer's cameras and capture
//! point clouds from them, or from the file (`--file`) and external-command (`--exec`) backends.

use anyhow::Context;
use handeye_gige::{ControlConfig, GigeCamera, GvcpClient};
use handeye_hal::limits;
use std::path::PathBuf;
use std::process::ExitCode;
use tokio_util::sync::CancellationToken;

mod xml;

/// Arguments of this subcommand.
#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    #[command(subcommand)]
    command: CameraCommand,
}

#[derive(Debug, clap::Subcommand)]
enum CameraCommand {
    /// Identify the camera: vendor, model, serial, firmware, size, pixel formats, and the
    /// settings a user would make (`[camera.features]`, `camera.user_set`); with --gentl, list
    /// the producer's interfaces and devices, or with --device identify that one.
    #[command(group(clap::ArgGroup::new("source").required(true).args(["gige", "gentl"])))]
    Probe {
        /// Camera address, `IP` or `IP:PORT` (GVCP, default port 3956).
        #[arg(long, value_name = "ADDR")]
        gige: Option<String>,
        /// A GenTL producer (the vendor's `.cti`): list its interfaces and devices.
        #[arg(long, value_name = "FILE.cti")]
        gentl: Option<PathBuf>,
        /// With --gentl: the camera to identify, by serial number, model, GenTL id or index in
        /// the listing (without it the devices are listed).
        #[arg(long, requires = "gentl")]
        device: Option<String>,
        /// With --gentl: each producer call's deadline (camera.call_timeout_s).
        #[arg(long, default_value_t = 10.0, value_name = "SECONDS")]
        call_timeout_s: f64,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
    },
    /// Capture point clouds and print frame statistics.
    #[command(group(clap::ArgGroup::new("source").required(true).args(["gige", "gentl", "file", "exec"])))]
    Capture {
        /// Camera address, `IP` or `IP:PORT` (GVCP, default port 3956).
        #[arg(long, value_name = "ADDR")]
        gige: Option<String>,
        /// Capture through this GenTL producer (the vendor's `.cti`).
        #[arg(long, value_name = "FILE.cti")]
        gentl: Option<PathBuf>,
        /// With --gentl: the camera's serial number, model, GenTL id or index (`camera probe
        /// --gentl` lists them) [default: the first device].
        #[arg(long, value_name = "ID")]
        device: Option<String>,
        /// Replay this PLY/PCD file instead of a camera (repeat for several; frames cycle
        /// through them in order).
        #[arg(long, value_name = "PATH")]
        file: Vec<PathBuf>,
        /// Run this command once per frame (split like a shell would, no shell involved; `{out}`
        /// = the file it must write, `{frame}` = the frame index; also in $HANDEYE_OUTPUT and
        /// $HANDEYE_FRAME), e.g. "python3 config/zivid_capture.py {out}".
        #[arg(long, value_name = "CMD")]
        exec: Option<String>,
        /// With --exec: kill the command (and its process group) if one frame takes longer.
        #[arg(long, default_value_t = 60.0, value_name = "SECONDS")]
        timeout_s: f64,
        /// Number of complete frames to capture [default: 1; with --file, the number of files].
        #[arg(long)]
        frames: Option<u32>,
        /// Write the clouds as binary PLY: one frame to this path, several to `<stem>_<i>.ply`
        /// beside it. Without it nothing is written (only the statistics are printed).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Print JSON (`frames`, `complete`, `incomplete`, `resent_packets`, …).
        #[arg(long)]
        json: bool,
        /// GigE only: GVSP packet size in bytes (whole IP datagram); 9000 on jumbo-frame
        /// networks.
        #[arg(long, default_value_t = 1500)]
        packet_size: u32,
        /// GigE and GenTL: give up on a frame after this many milliseconds.
        #[arg(long, default_value_t = 5000)]
        frame_timeout_ms: u64,
        /// GigE and GenTL: also stream the confidence component when the camera has one.
        #[arg(long)]
        confidence: bool,
        /// With --gentl: each producer call's deadline (EventGetData: the frame timeout + 1 s);
        /// past it the producer's process is killed and the capture fails naming the call.
        #[arg(long, default_value_t = 10.0, value_name = "SECONDS")]
        call_timeout_s: f64,
    },
    /// Check a camera's GenICam description offline (the .xml or .zip it serves, or a vendor's
    /// download): pixel formats, 3D components, Scan3d features, what is missing, and whether
    /// the driver could stream points from it. Exit 0 when it loads, 2 with the reason when not.
    Xml {
        /// The description, `.xml` or zipped (`.zip`).
        #[arg(value_name = "FILE")]
        file: PathBuf,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
    },
}

/// Most frames one `capture` takes (each is held in memory until written).
const MAX_FRAMES: u32 = 100;
/// GVSP packet sizes a GigE Vision link can carry, bytes (IP datagram).
const MIN_PACKET_SIZE: u32 = 576;
const MAX_PACKET_SIZE: u32 = 16_000;
/// Longest wait for one GigE Vision frame, seconds.
const MAX_FRAME_TIMEOUT_S: f64 = 600.0;
/// Shortest and longest time one `--exec` frame may take, seconds.
const MIN_EXEC_TIMEOUT_S: f64 = 0.1;
const MAX_EXEC_TIMEOUT_S: f64 = 3600.0;

fn connect(addr: &str) -> anyhow::Result<GigeCamera> {
    let addr = GvcpClient::parse_address(addr)?;
    GigeCamera::connect(addr, ControlConfig::default())
        .with_context(|| format!("connecting to the camera at {addr}"))
}

/// Runs one command until it ends or `shutdown` (Ctrl-C, SIGTERM) abandons it (exit 2,
/// "interrupted"). GigE Vision I/O is blocking and runs on tokio's blocking pool; an abandoned
/// capture is left to finish there (the process exits shortly after, see `main`). An abandoned
/// `--exec` capture kills its command.
pub(crate) async fn run(args: Args, shutdown: CancellationToken) -> anyhow::Result<ExitCode> {
    shutdown
        .run_until_cancelled(command(args.command))
        .await
        .unwrap_or_else(|| Err(anyhow::anyhow!("interrupted")))
}

async fn command(command: CameraCommand) -> anyhow::Result<ExitCode> {
    match command {
        // On the blocking pool: a shutdown signal ends the command at once (issue 46).
        CameraCommand::Xml { file, json } => blocking(move || xml::run(&file, json)).await,
        CameraCommand::Probe {
            gentl: Some(producer),
            device: Some(device),
            json,
            call_timeout_s,
            ..
        } => {
            let options = handeye_gentl::GentlOptions {
                device: Some(device),
                call_timeout: call_timeout(call_timeout_s)?,
                ..Default::default()
            };
            let (info, features) = handeye_gentl::probe_device(&producer, &options)
                .await
                .with_context(|| format!("probing the GenTL producer {}", producer.display()))?;
            emit_probe(info, features, json)
        }
        CameraCommand::Probe {
            gentl: Some(producer),
            json,
            call_timeout_s,
            ..
        } => {
            let options = handeye_gentl::GentlOptions {
                call_timeout: call_timeout(call_timeout_s)?,
                ..Default::default()
            };
            let list = handeye_gentl::list_devices(&producer, &options)
                .await
                .with_context(|| format!("probing the GenTL producer {}", producer.display()))?;
            if json {
                println!("{}", serde_json::to_string_pretty(&list)?);
            } else {
                let mut index = 0;
                for i in &list {
                    println!("interface {}", i.interface);
                    for d in &i.devices {
                        println!(
                            "  {index}: {} {} (serial {}, version {}, id {}, {})",
                            d.vendor, d.model, d.serial, d.version, d.id, d.tl_type
                        );
                        index += 1;
                    }
                }
                if index == 0 {
                    println!("no devices");
                } else {
                    println!("(--device N: what a device is and the settings it takes)");
                }
            }
            Ok(ExitCode::SUCCESS)
        }
        CameraCommand::Probe { gige, json, .. } => {
            let gige = gige.context("--gige or --gentl is required")?;
            let (info, features) = blocking(move || {
                let cam = connect(&gige)?;
                Ok((cam.info_blocking()?, cam.user_features_blocking()?))
            })
            .await?;
            emit_probe(info, features, json)
        }
        CameraCommand::Capture {
            gige,
            gentl,
            device,
            file,
            exec,
            timeout_s,
            frames,
            out,
            json,
            packet_size,
            frame_timeout_ms,
            confidence,
            call_timeout_s,
        } => {
            if device.is_some() && gentl.is_none() {
                anyhow::bail!(
                    "--device chooses among a GenTL producer's cameras: give --gentl FILE.cti too"
                );
            }
            let frames = frames.unwrap_or(if file.is_empty() {
                1
            } else {
                u32::try_from(file.len()).unwrap_or(u32::MAX)
            });
            if !(1..=MAX_FRAMES).contains(&frames) {
                anyhow::bail!("--frames = {frames}: expected 1 to {MAX_FRAMES} frames");
            }
            if !(MIN_PACKET_SIZE..=MAX_PACKET_SIZE).contains(&packet_size) {
                anyhow::bail!(
                    "--packet-size = {packet_size}: expected {MIN_PACKET_SIZE} to {MAX_PACKET_SIZE} bytes (1500 on ordinary Ethernet, 9000 with jumbo frames)"
                );
            }
            let frame_timeout = limits::duration_from_secs(
                "--frame-timeout-ms (as seconds)",
                frame_timeout_ms as f64 / 1000.0,
                0.001,
                MAX_FRAME_TIMEOUT_S,
            )
            .map_err(anyhow::Error::msg)?;
            let (clouds, stats) = if let Some(gige) = gige {
                // Not the driver's `DepthCamera::capture`: that drops the stream statistics
                // printed here.
                let (clouds, stats) = blocking(move || {
                    let mut cam = connect(&gige)?;
                    cam.options.packet_size = packet_size;
                    cam.options.confidence = confidence;
                    Ok(cam.capture_blocking(frames, frame_timeout)?)
                })
                .await?;
                let stats = serde_json::json!({
                    "complete": stats.complete,
                    "incomplete": stats.incomplete,
                    "resent_packets": stats.resent_packets,
                    "stream": stats.stream,
                });
                (clouds, Some(stats))
            } else if let Some(producer) = gentl {
                let options = handeye_gentl::GentlOptions {
                    device,
                    confidence,
                    call_timeout: call_timeout(call_timeout_s)?,
                    ..Default::default()
                };
                let cam = super::wiring::connect_gentl(&producer, options).await?;
                let settings = handeye_hal::CaptureSettings {
                    frames,
                    frame_timeout,
                    ..handeye_hal::CaptureSettings::default()
                };
                let (clouds, stats) = cam.capture_with_stats(&settings).await?;
                let stats = serde_json::json!({
                    "complete": stats.complete,
                    "incomplete": stats.incomplete,
                });
                (clouds, Some(stats))
            } else {
                (capture_local(file, exec, timeout_s, frames).await?, None)
            };
            report(&clouds, stats, json, out.as_deref())?;
            Ok(ExitCode::SUCCESS)
        }
    }
}

/// `camera probe --gige` (or `--gentl --device`): what the camera is and the features a user
/// would set, as JSON or [`probe_text`].
fn emit_probe(
    info: handeye_hal::CameraInfo,
    features: Vec<handeye_gige::genicam::FeatureState>,
    json: bool,
) -> anyhow::Result<ExitCode> {
    if json {
        #[derive(serde::Serialize)]
        struct Probe {
            #[serde(flatten)]
            info: handeye_hal::CameraInfo,
            features: Vec<handeye_gige::genicam::FeatureState>,
        }
        super::emit(&(serde_json::to_string_pretty(&Probe { info, features })? + "\n"))?;
    } else {
        super::emit(&probe_text(&info, &features))?;
    }
    Ok(ExitCode::SUCCESS)
}

/// `camera probe --gige`'s text: what the camera is, then the features a user would set
/// (`[camera.features]`, `camera.user_set`) with their value, range or entries and access.
fn probe_text(
    info: &handeye_hal::CameraInfo,
    features: &[handeye_gige::genicam::FeatureState],
) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let _ = writeln!(s, "vendor:        {}", info.vendor);
    let _ = writeln!(s, "model:         {}", info.model);
    let _ = writeln!(s, "serial:        {}", info.serial);
    let _ = writeln!(s, "firmware:      {}", info.firmware);
    let _ = writeln!(s, "size:          {} x {}", info.width, info.height);
    let _ = writeln!(s, "pixel formats: {}", info.pixel_formats.join(", "));
    let _ = writeln!(s, "settings ([camera.features], camera.user_set):");
    for f in features {
        let by = handeye_hal::set_by_handeye(&f.name)
            .map(|k| format!("; set by handeye: {k}"))
            .unwrap_or_default();
        let _ = writeln!(
            s,
            "  {} = {} ({}, {}{}{by})",
            f.name,
            f.value.as_deref().unwrap_or("?"),
            f.kind,
            f.access,
            f.allowed
                .as_deref()
                .map(|a| format!(", {a}"))
                .unwrap_or_default()
        );
    }
    s
}

/// Runs blocking camera I/O on tokio's blocking pool, off the runtime's workers.
/// `--call-timeout-s` checked as `camera.call_timeout_s` is.
fn call_timeout(seconds: f64) -> anyhow::Result<std::time::Duration> {
    limits::duration_from_secs("--call-timeout-s", seconds, 0.001, 600.0)
        .map_err(anyhow::Error::msg)
}

async fn blocking<T: Send + 'static>(
    f: impl FnOnce() -> anyhow::Result<T> + Send + 'static,
) -> anyhow::Result<T> {
    tokio::task::spawn_blocking(f)
        .await
        .context("the camera I/O thread failed")?
}

/// Captures from the file or exec backend (whichever was given).
async fn capture_local(
    file: Vec<PathBuf>,
    exec: Option<String>,
    timeout_s: f64,
    frames: u32,
) -> anyhow::Result<Vec<handeye_hal::PointCloud>> {
    use handeye_hal::{CaptureSettings, DepthCamera as _};
    let settings = CaptureSettings {
        frames,
        ..CaptureSettings::default()
    };
    let clouds = if let Some(exec) = exec {
        let argv = shlex::split(&exec).with_context(|| {
            format!(
                "cannot split --exec `{}`: unbalanced quotes?",
                limits::Quoted(&exec)
            )
        })?;
        let timeout = limits::duration_from_secs(
            "--timeout-s",
            timeout_s,
            MIN_EXEC_TIMEOUT_S,
            MAX_EXEC_TIMEOUT_S,
        )
        .map_err(anyhow::Error::msg)?;
        let cam = handeye::camera::ExecCamera::new(argv, timeout)?;
        cam.capture(&settings).await
    } else {
        let cam = handeye::camera::FileCamera::new(file)?;
        cam.capture(&settings).await
    };
    Ok(clouds?)
}

/// Prints frame statistics (`stats`: backend-specific JSON fields, GigE's stream counters,
/// GenTL's complete and incomplete buffers) and
/// writes the clouds to `out`.
fn report(
    clouds: &[handeye_hal::PointCloud],
    stats: Option<serde_json::Value>,
    json: bool,
    out: Option<&std::path::Path>,
) -> anyhow::Result<()> {
    let valid: Vec<usize> = clouds.iter().map(|c| c.valid_count()).collect();
    if json {
        let mut v = serde_json::json!({
            "frames": clouds.len(),
            "width": clouds.first().map_or(0, |c| c.width),
            "height": clouds.first().map_or(0, |c| c.height),
            "valid_points": valid,
        });
        match (&mut v, stats) {
            (serde_json::Value::Object(v), Some(serde_json::Value::Object(stats))) => {
                v.extend(stats);
            }
            (serde_json::Value::Object(v), _) => {
                // Replayed or externally captured frames are all complete.
                v.insert("complete".to_owned(), clouds.len().into());
            }
            _ => {}
        }
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else if let Some(stats) = stats {
        // GigE Vision counts resent packets; a GenTL producer does not tell.
        let resent = stats
            .get("resent_packets")
            .map(|r| format!(", {r} packets resent"))
            .unwrap_or_default();
        println!(
            "{} frames ({} complete, {} incomplete dropped{resent}); valid points per frame: {:?}",
            clouds.len(),
            stats["complete"],
            stats["incomplete"],
            valid
        );
    } else {
        println!(
            "{} frames; valid points per frame: {:?}",
            clouds.len(),
            valid
        );
    }
    if out.is_none() {
        eprintln!("no --out given: the clouds were not written");
    }
    if let Some(path) = out {
        // Several frames go to `<stem>_<i>.ply`; one frame to the path given.
        for (i, cloud) in clouds.iter().enumerate() {
            let file = if clouds.len() == 1 {
                path.to_path_buf()
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
    Ok(())
}

#[cfg(test)]
mod tests {
    use clap::Parser as _;

    use super::*;

    #[derive(Debug, clap::Parser)]
    struct Cli {
        #[command(subcommand)]
        command: CameraCommand,
    }

    fn parse(args: &[&str]) -> Result<CameraCommand, clap::Error> {
        Cli::try_parse_from(["camera"].iter().chain(args)).map(|c| c.command)
    }

    #[test]
    fn exactly_one_source() {
        assert!(parse(&["capture"]).is_err());
        assert!(parse(&["capture", "--gentl", "a.cti", "--gige", "127.0.0.1"]).is_err());
        assert!(parse(&["capture", "--gentl", "a.cti", "--device", "0"]).is_ok());
        assert!(parse(&["probe"]).is_err());
        assert!(parse(&["probe", "--gentl", "a.cti"]).is_ok());
        assert!(parse(&["capture", "--gige", "127.0.0.1", "--file", "a.ply"]).is_err());
        assert!(parse(&["capture", "--exec", "true", "--file", "a.ply"]).is_err());
        assert!(parse(&["capture", "--gige", "127.0.0.1"]).is_ok());
        let Ok(CameraCommand::Capture { file, frames, .. }) =
            parse(&["capture", "--file", "a.ply", "--file", "b.pcd"])
        else {
            panic!("--file twice parses");
        };
        assert_eq!(file.len(), 2);
        assert_eq!(frames, None);
    }

    #[tokio::test]
    async fn device_needs_a_gentl_producer() {
        let cmd = parse(&["capture", "--gige", "127.0.0.1", "--device", "0"]).expect("parses");
        let err = command(cmd).await.expect_err("refused").to_string();
        assert!(err.contains("give --gentl FILE.cti too"), "{err}");
    }

    #[tokio::test]
    async fn file_and_exec_captures_share_the_output_path() {
        let dir = std::env::temp_dir().join(format!("handeye-cli-camera-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("dir");
        let src = dir.join("src.ply");
        let cloud = handeye_hal::PointCloud::from_points(vec![
            nalgebra::Point3::new(0.0, 0.0, 1.0),
            nalgebra::Point3::new(0.1, 0.0, 1.0),
        ]);
        handeye::cloud::write_ply(&src, &cloud, handeye::cloud::PlyEncoding::Ascii).expect("write");

        let clouds = capture_local(vec![src.clone()], None, 1.0, 2)
            .await
            .expect("file capture");
        assert_eq!(clouds.len(), 2);
        let cmd = format!("cp {} {{out}}", src.display());
        let clouds2 = capture_local(Vec::new(), Some(cmd), 10.0, 1)
            .await
            .expect("exec capture");
        assert_eq!(clouds2.len(), 1);

        let out = dir.join("scan.ply");
        report(&clouds, None, true, Some(&out)).expect("report");
        for name in ["scan_0.ply", "scan_1.ply"] {
            let back = handeye::cloud::read_cloud(&dir.join(name)).expect("read back");
            assert_eq!(back.points, cloud.points);
        }
        let err = capture_local(Vec::new(), Some("true".into()), 0.0, 1)
            .await
            .expect_err("bad timeout");
        assert!(err.to_string().contains("--timeout-s"), "{err}");
        for bad in [1e300, f64::NAN, -1.0] {
            let err = capture_local(Vec::new(), Some("true".into()), bad, 1)
                .await
                .expect_err("bad timeout");
            assert!(err.to_string().starts_with("--timeout-s = "), "{err}");
        }
        std::fs::remove_dir_all(&dir).expect("cleanup");
    }
}
