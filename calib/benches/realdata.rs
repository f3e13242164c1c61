//! Registration speed on real frames: `cargo bench -p handeye-calib --bench realdata`.
//!
//! The five RealSense frames of `../shared/realdata/xarm7_realsense` (1280×720, a UFACTORY
//! xArm7 1.3 m from the camera among a second arm and clutter), each calibrated as `handeye
//! solve --eye-to-hand --base-frame link_base --sensor active-stereo` does: without a guess
//! (the global search) and with the data authors' reference as the guess. The scans are read
//! before timing; what is timed is the registration, the hand-eye solve and the gate of one
//! frame. Needs `../shared`.
use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use handeye_calib::calib::pipeline::calibrate_frames;

fn bench(c: &mut Criterion) {
    let Some(set) = handeye_calib::testutil::real_set() else {
        return;
    };
    let mut g = c.benchmark_group("realdata");
    g.sample_size(10);
    for guess in [false, true] {
        let opts = set.options(guess);
        for frame in &set.frames {
            let name = format!(
                "{}/{}",
                if guess { "guess" } else { "no-guess" },
                frame.source
            );
            g.bench_function(name, |b| {
                b.iter(|| {
                    black_box(calibrate_frames(
                        &set.model,
                        std::slice::from_ref(frame),
                        &opts,
                    ))
                })
            });
        }
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
