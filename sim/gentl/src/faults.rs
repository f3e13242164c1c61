//! A hostile producer on demand, for the consumer's tests (issue 46): the environment
//! variable `HANDEYE_SIM_GENTL_FAULT` selects faults, comma-separated; when its value starts
//! with `/` it names a file holding them, read again at every point a fault can strike (so a
//! test changes the producer's behaviour under a running daemon). Without it the producer
//! behaves.
//!
//! | fault | what the producer does |
//! |---|---|
//! | `block:CALL` | `CALL` never returns (`load`: the library's constructor; `EventGetData`, `DSStartAcquisition`, `DSStopAcquisition`, `AcquisitionStart`: the remote device's register write) |
//! | `abort:CALL` | `CALL` calls `abort()` |
//! | `exit:CALL` | `CALL` calls `exit(0)` (`exit:load`: in the constructor, as `dlopen` runs it) |
//! | `overlapping-parts` | 64 parts, each covering the whole buffer |
//! | `lying-format` | the range part says `Coord3D_C16` over its `Coord3D_ABC32f` data |
//! | `short-part` | the range part's size is 4 bytes short of its width × height × format |
//! | `zero-width` | every part's width is 0 |
//! | `scale-zero` | `Scan3dCoordinateScale` reads 0 |
//! | `offset-1e30` | `Scan3dCoordinateOffset` reads 1e30 (mm) |
//! | `many-devices` | 2 interfaces (the same one) of 1 024 devices each (the same one) |

/// The environment variable.
pub(crate) const ENV: &str = "HANDEYE_SIM_GENTL_FAULT";

/// The faults selected now.
fn selected() -> Vec<String> {
    let Ok(v) = std::env::var(ENV) else {
        return Vec::new();
    };
    let text = if v.starts_with('/') {
        std::fs::read_to_string(&v).unwrap_or_default()
    } else {
        v
    };
    text.split([',', '\n'])
        .map(|f| f.trim().to_owned())
        .filter(|f| !f.is_empty())
        .collect()
}

/// Whether `fault` is selected.
pub(crate) fn on(fault: &str) -> bool {
    selected().iter().any(|f| f == fault)
}

/// The point `call` of the producer: block, abort or exit there when selected.
pub(crate) fn at(call: &str) {
    for f in selected() {
        match f.split_once(':') {
            Some(("block", c)) if c == call => loop {
                std::thread::sleep(std::time::Duration::from_secs(3600));
            },
            Some(("abort", c)) if c == call => std::process::abort(),
            // SAFETY: exit() as a misbehaving producer calls it.
            Some(("exit", c)) if c == call => unsafe { libc::exit(0) },
            _ => {}
        }
    }
}

/// The library's constructor: `dlopen` runs it.
extern "C" fn on_load() {
    at("load");
}

#[used]
#[link_section = ".init_array"]
static ON_LOAD: extern "C" fn() = on_load;
