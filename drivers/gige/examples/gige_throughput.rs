//! Throughput benchmark (not a test): the simulated camera streams 2560×2048 Coord3D_ABC32f
//! frames (5.2 M points, 63 MB) over loopback, paced so the GVSP payload runs at
//! PAYLOAD_MBIT (default 1000 Mbit/s; the datagrams with their IP/UDP/GVSP headers run a bit
//! faster); our receiver must get every frame complete (incomplete frames are counted, not
//! fatal). The simulator reports how far a busy host held it behind its pace, which explains
//! a rate below the target without loss.
//! `cargo run --release -p handeye-gige --example gige_throughput [FRAMES [PACKET_SIZE [PAYLOAD_MBIT [LOSS]]]]`
//! (LOSS: fraction of packets the simulator drops on first transmission, to exercise resend)
//!
//! The rate is measured at the receiver from the first to the last complete frame (steady
//! state, without the start-up latency of acquisition and the first render).

use std::net::Ipv4Addr;
use std::time::{Duration, Instant};

use handeye_gige::gvsp::{Header, StreamConfig, StreamReceiver, IP_UDP_HEADERS};
use handeye_gige::sim::{SceneSource, SimCamera, SimOptions};
use handeye_gige::{ControlConfig, GigeCamera};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let frames: u32 = args.get(1).map_or(Ok(10), |s| s.parse()).expect("FRAMES");
    let packet_size: u32 = args
        .get(2)
        .map_or(Ok(9000), |s| s.parse())
        .expect("PACKET_SIZE");
    let payload_mbit: f64 = args
        .get(3)
        .map_or(Ok(1000.0), |s| s.parse())
        .expect("PAYLOAD_MBIT");
    let loss_ratio: f64 = args.get(4).map_or(Ok(0.0), |s| s.parse()).expect("LOSS");
    let (w, h) = (2560, 2048);
    let datagram = f64::from(packet_size);
    let payload_per_packet = datagram - (IP_UDP_HEADERS + Header::len(false)) as f64;
    let frame_bits = f64::from(w * h) * 96.0;
    let opts = SimOptions {
        // Free-running faster than the link: the pacing sets the rate, frames go back to back.
        frame_rate: 2.0 * payload_mbit * 1e6 / frame_bits,
        bandwidth_bps: Some(payload_mbit * 1e6 * datagram / payload_per_packet),
        loss_ratio,
        ..SimOptions::default()
    };
    let probe = StreamReceiver::bind(
        Ipv4Addr::LOCALHOST,
        "127.0.0.1:9".parse().expect("addr"),
        StreamConfig::default(),
    )
    .expect("bind");
    let rcvbuf = probe.recv_buffer_size();
    drop(probe);
    let sim = SimCamera::spawn(
        "127.0.0.1:0".parse().expect("addr"),
        Box::new(SceneSource::new(w, h)),
        opts,
    )
    .expect("sim");
    let mut cam = GigeCamera::connect(sim.addr(), ControlConfig::default()).expect("connect");
    cam.options.packet_size = packet_size;
    // Count lost frames instead of aborting on the first one.
    cam.options.max_incomplete = frames;
    let t = Instant::now();
    let (raw, stats) = cam
        .capture_raw_blocking(frames, Duration::from_secs(10))
        .expect("capture");
    let secs = t.elapsed().as_secs_f64();
    let frame_bytes =
        |f: &handeye_gige::gvsp::Frame| f.parts.iter().map(|p| p.1.len()).sum::<usize>();
    let bytes: usize = raw.iter().map(frame_bytes).sum();
    let steady = match (raw.first(), raw.last()) {
        (Some(a), Some(b)) if raw.len() > 1 => {
            let s = b.received.duration_since(a.received).as_secs_f64();
            let bits = raw[1..].iter().map(frame_bytes).sum::<usize>() as f64 * 8.0;
            format!("{:.0} Mbit/s", bits / s / 1e6)
        }
        _ => "n/a".into(),
    };
    let sim_stats = sim.stats();
    println!(
        "{} frames of {}x{} Coord3D_ABC32f ({:.1} MB each), packet size {packet_size}, paced at {payload_mbit:.0} Mbit/s payload, receive buffer {:.1} MiB: payload {steady} (steady state; {:.0} Mbit/s over the whole {:.2} s capture), complete {}, incomplete {}, resent packets {} ({} asked for), sim dropped {}; sim behind its pace {:.0} ms, link idle waiting for renders {:.0} ms",
        raw.len(),
        w,
        h,
        bytes as f64 / raw.len().max(1) as f64 / 1e6,
        rcvbuf as f64 / f64::from(1 << 20),
        bytes as f64 * 8.0 / secs / 1e6,
        secs,
        stats.complete,
        stats.incomplete,
        stats.resent_packets,
        stats.stream.resend_requested,
        sim_stats.dropped_packets,
        sim_stats.pacing_lag_us as f64 / 1e3,
        sim_stats.render_wait_us as f64 / 1e3,
    );
}
