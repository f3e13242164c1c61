//! Real-time interface (30003): a fixed-layout packet of big-endian doubles at the control rate
//! (125 Hz CB3, 500 Hz e-Series), and URScript accepted like on 30002.

use std::sync::Arc;
use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};

use super::script::ScriptReceiver;
use super::Shared;

/// Packet size of PolyScope 3.10+/5.4+.
const SIZE: usize = 1116;

pub(crate) async fn serve(listener: TcpListener, shared: Arc<Shared>) {
    super::accept_loop(listener, shared, "real-time", |sock, shared| async move {
        connection(sock, &shared).await
    })
    .await;
}

fn packet(shared: &Shared, out: &mut Vec<u8>) {
    out.clear();
    out.resize(SIZE, 0);
    let put = |out: &mut Vec<u8>, off: usize, vals: &[f64]| {
        for (k, v) in vals.iter().enumerate() {
            out[off + 8 * k..off + 8 * k + 8].copy_from_slice(&v.to_be_bytes());
        }
    };
    out[..4].copy_from_slice(&(SIZE as i32).to_be_bytes());
    let s = shared.lock();
    put(out, 4, &[s.timestamp()]);
    put(out, 12, &s.target_q);
    put(out, 252, &s.q);
    put(out, 300, &s.qd);
    let tcp = s.tcp_pose().0;
    put(out, 444, &tcp);
    put(out, 588, &tcp);
    put(out, 756, &[f64::from(s.robot_mode as i32)]);
    put(out, 812, &[f64::from(s.safety_mode as i32)]);
    put(out, 940, &[1.0]);
    put(out, 1052, &[f64::from(s.runtime_state)]);
}

async fn connection(sock: TcpStream, shared: &Arc<Shared>) -> std::io::Result<()> {
    let (mut r, mut w) = sock.into_split();
    let opened_remote = shared.lock().remote_control;
    let period = if shared.config.model.is_cb3() {
        Duration::from_millis(8)
    } else {
        Duration::from_millis(2)
    };
    // The packets are written by their own task, so a client that only sends scripts (and
    // never reads) still has them read and run: once its buffers are full, only its stream
    // stalls.
    let stream_shared = shared.clone();
    let writer = tokio::spawn(async move {
        let mut tick = tokio::time::interval(period);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
        let mut pkt = Vec::with_capacity(SIZE);
        loop {
            tick.tick().await;
            packet(&stream_shared, &mut pkt);
            if w.write_all(&pkt).await.is_err() {
                return;
            }
        }
    });
    let _writer = super::AbortOnDrop(writer);
    let mut rx = ScriptReceiver::default();
    let mut buf = vec![0u8; 8192];
    loop {
        let n = r.read(&mut buf).await?;
        if n == 0 {
            return Ok(());
        }
        // 30003 has no robot messages: errors go to the primary stream only.
        let _ = rx.feed(&buf[..n], shared, opened_remote);
        if rx.overflowed {
            return Ok(());
        }
    }
}
