//! Throughput benchmark (not a test): the simulated camera streams 2560×2048 Coord3D_ABC32f
//! frames (5.2 M points, 63 MB) paced at 1 Gbit/s over loopback; our receiver must get every
//! frame complete. `cargo run --release -p handeye-gige --example gige_throughput [FRAMES [PACKET_SIZE]]`

use std::time::{Duration, Instant};

use handeye_gige::sim::{SceneSource, SimCamera, SimOptions};
use handeye_gige::{ControlConfig, GigeCamera};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let frames: u32 = args.get(1).map_or(Ok(10), |s| s.parse()).expect("FRAMES");
    let packet_size: u32 = args
        .get(2)
        .map_or(Ok(9000), |s| s.parse())
        .expect("PACKET_SIZE");
    let (w, h) = (2560, 2048);
    let opts = SimOptions {
        frame_rate: 1e9 / (f64::from(w * h) * 96.0),
        bandwidth_bps: Some(1e9),
        ..SimOptions::default()
    };
    let sim = SimCamera::spawn(
        "127.0.0.1:0".parse().expect("addr"),
        Box::new(SceneSource::new(w, h)),
        opts,
    )
    .expect("sim");
    let mut cam = GigeCamera::connect(sim.addr(), ControlConfig::default()).expect("connect");
    cam.options.packet_size = packet_size;
    cam.options.max_incomplete = 0;
    let t = Instant::now();
    let (raw, stats) = cam
        .capture_raw_blocking(frames, Duration::from_secs(10))
        .expect("capture");
    let secs = t.elapsed().as_secs_f64();
    let bytes: usize = raw
        .iter()
        .map(|f| f.parts.iter().map(|p| p.1.len()).sum::<usize>())
        .sum();
    println!(
        "{} frames of {}x{} Coord3D_ABC32f ({:.1} MB each), packet size {packet_size}: {:.2} s, {:.0} Mbit/s payload, complete {}, incomplete {}, resent packets {}, sim dropped {}",
        raw.len(),
        w,
        h,
        bytes as f64 / raw.len().max(1) as f64 / 1e6,
        secs,
        bytes as f64 * 8.0 / secs / 1e6,
        stats.complete,
        stats.incomplete,
        stats.resent_packets,
        sim.stats().dropped_packets
    );
}
