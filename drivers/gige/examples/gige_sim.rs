//! Run the simulated 3D camera: `gige_sim BIND_ADDR [WIDTH HEIGHT [LOSS_RATIO]]`
//! (e.g. `gige_sim 127.0.0.1:3956 640 480 0.01`). Runs until killed.

use handeye_gige::sim::{SceneSource, SimCamera, SimOptions};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let bind = args
        .get(1)
        .map_or("127.0.0.1:3956", String::as_str)
        .parse()
        .expect("BIND_ADDR like 127.0.0.1:3956");
    let w = args.get(2).map_or(Ok(320), |s| s.parse()).expect("WIDTH");
    let h = args.get(3).map_or(Ok(240), |s| s.parse()).expect("HEIGHT");
    let loss = args
        .get(4)
        .map_or(Ok(0.0), |s| s.parse())
        .expect("LOSS_RATIO");
    let opts = SimOptions {
        loss_ratio: loss,
        ..SimOptions::default()
    };
    let cam = SimCamera::spawn(bind, Box::new(SceneSource::new(w, h)), opts)
        .expect("start the simulated camera");
    eprintln!("simulated GigE Vision 3D camera on {}", cam.addr());
    cam.wait(&std::sync::atomic::AtomicBool::new(false));
}
