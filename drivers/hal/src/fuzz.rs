//! The fuzz harness every parser's fuzz target runs on (feature `fuzz`, enabled from
//! dev-dependencies only).
//!
//! A target is a set of valid inputs (the seeds: files the simulators and the writers produce,
//! real meshes from `../shared/robots`) and a function that parses one input. The harness
//! checks that every seed parses, then mutates seeds — bit flips, random bytes, numbers
//! replaced by extreme ones (`4294967295`, `-1`, `nan`, `1e309`, …), chunks dropped,
//! duplicated, spliced from another seed, lines doubled or dropped, structural tokens (`<`,
//! `]`, `"`, `=`) inserted, truncation — for a bounded time, and asserts for each mutated
//! input:
//!
//! - no panic (caught; the input is saved and shrunk, see below);
//! - no hang: an input taking longer than [`HANG_LIMIT`] ends the process with a message
//!   naming the saved input (a watchdog thread, since a hung parser cannot be interrupted);
//! - bounded memory: with [`TrackingAlloc`] installed as the test binary's global allocator,
//!   no single allocation made by the parsing thread beyond the target's cap (by default
//!   64 bytes per input byte + 1 MiB);
//! - an invalid input is an `Err` whose message is not empty, at most 2 KiB and free of
//!   control characters (input bytes are never echoed raw to a terminal).
//!
//! At the end it asserts that the mutations reached the error paths (some inputs failed) and,
//! unless the target says otherwise, that some still parsed.
//!
//! Bounds: [`Target::run`] mutates for `HANDEYE_FUZZ_SECS` seconds (default 2 s; a fractional
//! value is allowed) or `HANDEYE_FUZZ_ITERS` inputs, whichever comes first, from the seed
//! `HANDEYE_FUZZ_SEED` (default fixed, so CI explores the same inputs first). It is a seeded
//! random mutator, not coverage-guided: it does not see which branches an input reached. The
//! coverage-guided engines need instrumented builds and extra tooling (libFuzzer through
//! `cargo fuzz`, whose default sanitizer build needs a nightly compiler, or `cargo bolero`,
//! whose `bolero` crate pins old `toml` crates into the lock file; see the README). A target's
//! body is a function of the input bytes, so it can be moved under such an engine.
//!
//! A failing input is written to `target/fuzz-failures/<target>-<n>.bin`, shrunk (chunks
//! removed while it still fails) to `…-min.bin`, and named in the panic message so it can
//! become a regression test.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::fmt::Display;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Longest one input may take before the harness calls it a hang (debug builds, a loaded
/// 2-core machine; every parser here answers in milliseconds).
pub const HANG_LIMIT: Duration = Duration::from_secs(20);

/// Default time budget per target when `HANDEYE_FUZZ_SECS` is not set.
pub const DEFAULT_SECS: f64 = 2.0;

const DEFAULT_SEED: u64 = 0x5eed_f022_2023;

/// Extreme numbers written over a number of the input.
const NUMBERS: [&[u8]; 12] = [
    b"4294967295",
    b"4294967296",
    b"18446744073709551615",
    b"99999999999999999999999",
    b"0",
    b"-1",
    b"65536",
    b"2147483648",
    b"nan",
    b"inf",
    b"-1e309",
    b"1e300",
];

/// Tokens that break or nest structure in the text formats (XML, TOML, URScript, PLY headers).
const TOKENS: [&[u8]; 16] = [
    b"<", b">", b"\"", b"'", b"[", b"]", b"{", b"}", b"=", b"\n", b"#", b"\\", b"</", b"(", b")",
    b"\0",
];

// ---------------------------------------------------------------- allocation tracking

/// A global allocator for test binaries: passes every request to [`System`] unchanged and
/// records the largest single allocation made on a thread while that thread is inside
/// [`largest_allocation`] (the harness turns it on around each parse).
///
/// Install it once per test binary:
/// `#[cfg(test)] #[global_allocator] static ALLOC: handeye_hal::fuzz::TrackingAlloc = handeye_hal::fuzz::TrackingAlloc;`
#[derive(Debug)]
pub struct TrackingAlloc;

thread_local! {
    /// On while this thread parses a fuzz input: its panics are reported by the harness.
    static QUIET: Cell<bool> = const { Cell::new(false) };
    /// Where the last quiet panic happened.
    static PANIC_AT: std::cell::RefCell<String> = const { std::cell::RefCell::new(String::new()) };
    static TRACK: Cell<bool> = const { Cell::new(false) };
    static LARGEST: Cell<usize> = const { Cell::new(0) };
}

static INSTALLED: AtomicBool = AtomicBool::new(false);

fn note(size: usize) {
    if TRACK.try_with(Cell::get).unwrap_or(false) {
        let _ = LARGEST.try_with(|l| l.set(l.get().max(size)));
    }
}

// SAFETY: forwards to `System` unchanged; the bookkeeping only touches const-initialised
// thread-locals and an atomic (no allocation, no destructor).
unsafe impl GlobalAlloc for TrackingAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        note(layout.size());
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        note(layout.size());
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        note(new_size);
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

/// Runs `f` and returns its result with the largest single allocation it made on this thread
/// (`None` when [`TrackingAlloc`] is not the global allocator).
pub fn largest_allocation<T>(f: impl FnOnce() -> T) -> (T, Option<usize>) {
    LARGEST.with(|l| l.set(0));
    TRACK.with(|t| t.set(true));
    // Probe: an allocation made while tracking shows whether the allocator is ours.
    if !INSTALLED.load(Ordering::Relaxed) {
        let probe = std::hint::black_box(vec![0u8; 1]);
        drop(probe);
        if LARGEST.with(Cell::get) > 0 {
            INSTALLED.store(true, Ordering::Relaxed);
        }
        LARGEST.with(|l| l.set(0));
    }
    let r = f();
    TRACK.with(|t| t.set(false));
    let largest = LARGEST.with(Cell::get);
    (r, INSTALLED.load(Ordering::Relaxed).then_some(largest))
}

/// Installs (once per process) a panic hook that stays silent for a panic on a thread parsing
/// a fuzz input — the harness reports it with the input; a parser that catches panics of a
/// library it calls (the GenICam node-map builder does) then costs no backtrace — and passes
/// every other panic to the hook it replaced.
fn quiet_panics_while_parsing() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if QUIET.try_with(Cell::get).unwrap_or(false) {
                let at = info
                    .location()
                    .map(|l| format!("{}:{}", l.file(), l.line()))
                    .unwrap_or_default();
                let _ = PANIC_AT.try_with(|p| *p.borrow_mut() = at);
            } else {
                previous(info);
            }
        }));
    });
}

/// Runs `f` with this thread's panics left to the harness.
fn quietly<T>(f: impl FnOnce() -> T) -> std::thread::Result<T> {
    QUIET.with(|q| q.set(true));
    let r = catch_unwind(AssertUnwindSafe(f));
    QUIET.with(|q| q.set(false));
    r
}

// ---------------------------------------------------------------- random numbers

/// xorshift64*: small, seedable, good enough to pick mutations.
#[derive(Debug, Clone)]
struct Rng(u64);

impl Rng {
    fn new(seed: u64) -> Self {
        Rng(seed.max(1))
    }
    fn next(&mut self) -> u64 {
        let mut x = self.0;
        x ^= x >> 12;
        x ^= x << 25;
        x ^= x >> 27;
        self.0 = x;
        x.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    /// Uniform in `0..n` (0 when `n` is 0).
    fn below(&mut self, n: usize) -> usize {
        if n == 0 {
            0
        } else {
            (self.next() % n as u64) as usize
        }
    }
    fn byte(&mut self) -> u8 {
        (self.next() >> 56) as u8
    }
}

// ---------------------------------------------------------------- mutation

/// Applies 1–4 random edits to a copy of `seeds[i]` (another seed may donate a chunk).
fn mutate(rng: &mut Rng, seeds: &[Vec<u8>], max_len: usize) -> Vec<u8> {
    let mut b = seeds[rng.below(seeds.len())].clone();
    for _ in 0..=rng.below(4) {
        if b.is_empty() {
            b.push(rng.byte());
            continue;
        }
        let at = rng.below(b.len());
        let len = (1 + rng.below(32)).min(b.len() - at);
        match rng.below(11) {
            0 => b[at] ^= 1 << rng.below(8),
            1 => b[at] = rng.byte(),
            2 => {
                // Overwrite a little-endian word with an extreme value (binary formats).
                let v: u32 = [0, 1, 0x7fff_ffff, 0xffff_ffff, 0x8000_0000, 0xffff][rng.below(6)];
                for (k, byte) in v.to_le_bytes().into_iter().enumerate() {
                    if let Some(slot) = b.get_mut(at + k) {
                        *slot = byte;
                    }
                }
            }
            3 => {
                // Replace the next number with an extreme one.
                if let Some(d) = b[at..].iter().position(u8::is_ascii_digit) {
                    let s = at + d;
                    let e = s + b[s..]
                        .iter()
                        .take_while(|c| c.is_ascii_digit() || **c == b'.' || **c == b'e')
                        .count();
                    b.splice(s..e, NUMBERS[rng.below(NUMBERS.len())].iter().copied());
                }
            }
            4 => {
                let t = TOKENS[rng.below(TOKENS.len())];
                b.splice(at..at, t.iter().copied());
            }
            5 => {
                b.drain(at..at + len);
            }
            6 => {
                let chunk = b[at..at + len].to_vec();
                let to = rng.below(b.len() + 1);
                b.splice(to..to, chunk);
            }
            7 => {
                // Splice a chunk of another seed.
                let other = &seeds[rng.below(seeds.len())];
                if !other.is_empty() {
                    let s = rng.below(other.len());
                    let e = (s + 1 + rng.below(64)).min(other.len());
                    b.splice(at..at, other[s..e].iter().copied());
                }
            }
            8 => {
                // Double or drop a line.
                let s = b[..at]
                    .iter()
                    .rposition(|&c| c == b'\n')
                    .map_or(0, |p| p + 1);
                let e = at
                    + b[at..]
                        .iter()
                        .position(|&c| c == b'\n')
                        .map_or(b.len() - at, |p| p + 1);
                if rng.below(2) == 0 {
                    let line = b[s..e].to_vec();
                    b.splice(s..s, line);
                } else {
                    b.drain(s..e);
                }
            }
            9 => {
                let extra: Vec<u8> = (0..1 + rng.below(16)).map(|_| rng.byte()).collect();
                b.splice(at..at, extra);
            }
            _ => b.truncate(at),
        }
    }
    b.truncate(max_len);
    b
}

// ---------------------------------------------------------------- the target

/// One fuzz target: a parser and the valid inputs its mutations start from.
#[derive(Debug)]
pub struct Target {
    name: String,
    seeds: Vec<Vec<u8>>,
    alloc_per_byte: usize,
    alloc_base: usize,
    max_len: usize,
    must_parse_some: bool,
}

/// What one run found: how many inputs, how many parsed, and how long it took.
#[derive(Debug, Clone, Copy)]
pub struct Report {
    /// Mutated inputs tried.
    pub inputs: usize,
    /// Of these, how many parsed.
    pub parsed: usize,
    /// Wall time of the mutation loop.
    pub elapsed: Duration,
}

impl Target {
    /// A target named `name` (used for saved inputs) mutating `seeds`, each of which must parse.
    pub fn new(name: &str, seeds: Vec<Vec<u8>>) -> Self {
        assert!(!seeds.is_empty(), "fuzz target {name}: no seeds");
        let longest = seeds.iter().map(Vec::len).max().unwrap_or(0);
        Target {
            name: name.to_owned(),
            seeds,
            alloc_per_byte: 64,
            alloc_base: 1 << 20,
            max_len: longest * 2 + 4096,
            must_parse_some: true,
        }
    }

    /// The largest single allocation parsing an input of `len` bytes may make:
    /// `per_byte × len + base` (checked when [`TrackingAlloc`] is installed).
    pub fn allocation_cap(mut self, per_byte: usize, base: usize) -> Self {
        self.alloc_per_byte = per_byte;
        self.alloc_base = base;
        self
    }

    /// For parsers whose valid inputs are so constrained (checksums, exact sizes) that a
    /// mutated one rarely parses: do not require that some mutated input parsed.
    pub fn mostly_invalid(mut self) -> Self {
        self.must_parse_some = false;
        self
    }

    /// Checks every seed, then mutates for the configured time (see the module docs), calling
    /// `parse` on each input; panics (failing the test) on a seed that does not parse, on a
    /// panic, an over-large allocation or a bad error message, naming the saved input.
    pub fn run<E: Display>(self, mut parse: impl FnMut(&[u8]) -> Result<(), E>) -> Report {
        for (i, seed) in self.seeds.iter().enumerate() {
            if let Err(e) = parse(seed) {
                panic!("fuzz target {}: seed {i} does not parse: {e}", self.name);
            }
        }
        let secs = env_f64("HANDEYE_FUZZ_SECS").unwrap_or(DEFAULT_SECS);
        let budget = Duration::from_secs_f64(secs.max(0.0));
        let max_inputs = env_f64("HANDEYE_FUZZ_ITERS").map_or(usize::MAX, |n| n as usize);
        let seed = match std::env::var("HANDEYE_FUZZ_SEED") {
            Ok(v) => v
                .trim()
                .parse::<u64>()
                .unwrap_or_else(|_| panic!("HANDEYE_FUZZ_SEED={v:?}: expected a whole number")),
            Err(_) => DEFAULT_SEED,
        };
        let mut rng = Rng::new(seed ^ fnv(self.name.as_bytes()));
        quiet_panics_while_parsing();
        let watchdog = Watchdog::start(&self.name);
        let started = Instant::now();
        let (mut inputs, mut parsed) = (0usize, 0usize);
        while inputs < max_inputs && started.elapsed() < budget {
            let input = mutate(&mut rng, &self.seeds, self.max_len);
            inputs += 1;
            watchdog.begin(&input);
            let outcome =
                quietly(|| largest_allocation(|| parse(&input).map_err(|e| e.to_string())));
            watchdog.end();
            let problem = match outcome {
                Err(panic) => Some(format!(
                    "panicked at {}: {}",
                    PANIC_AT.with(|p| p.borrow().clone()),
                    panic_text(&panic)
                )),
                Ok((result, largest)) => {
                    let cap = self.alloc_per_byte * input.len() + self.alloc_base;
                    match (result, largest) {
                        (_, Some(l)) if l > cap => Some(format!(
                            "allocated {l} bytes at once for a {}-byte input (cap {cap})",
                            input.len()
                        )),
                        (Ok(()), _) => {
                            parsed += 1;
                            None
                        }
                        (Err(msg), _) => bad_message(&msg),
                    }
                }
            };
            if let Some(problem) = problem {
                let saved = self.save(inputs, &input, &mut parse);
                panic!(
                    "fuzz target {}: input {inputs} (HANDEYE_FUZZ_SEED={seed}) {problem}; {saved}",
                    self.name
                );
            }
        }
        let report = Report {
            inputs,
            parsed,
            elapsed: started.elapsed(),
        };
        eprintln!(
            "fuzz target {}: {} inputs in {:.1} s, {} parsed, {} refused",
            self.name,
            report.inputs,
            report.elapsed.as_secs_f64(),
            report.parsed,
            report.inputs - report.parsed
        );
        if inputs >= 50 {
            assert!(
                parsed < inputs,
                "fuzz target {}: all {inputs} mutated inputs parsed; the mutations reach no error path",
                self.name
            );
            assert!(
                !self.must_parse_some || parsed > 0,
                "fuzz target {}: none of {inputs} mutated inputs parsed; the mutations never reach past the first check",
                self.name
            );
        }
        report
    }

    /// Writes the failing input and a shrunk one under `target/fuzz-failures/`; returns a
    /// sentence naming them.
    fn save<E: Display>(
        &self,
        n: usize,
        input: &[u8],
        parse: &mut impl FnMut(&[u8]) -> Result<(), E>,
    ) -> String {
        let fails = |parse: &mut dyn FnMut(&[u8]) -> Result<(), E>, b: &[u8]| match quietly(|| {
            parse(b).map_err(|e| e.to_string())
        }) {
            Err(_) => true,
            Ok(Err(msg)) => bad_message(&msg).is_some(),
            Ok(Ok(())) => false,
        };
        let mut min = input.to_vec();
        let deadline = Instant::now() + Duration::from_secs(10);
        let mut chunk = min.len() / 2;
        while chunk >= 1 && Instant::now() < deadline {
            let mut at = 0;
            let mut shrunk = false;
            while at + chunk <= min.len() && Instant::now() < deadline {
                let mut candidate = min.clone();
                candidate.drain(at..at + chunk);
                if fails(parse, &candidate) {
                    min = candidate;
                    shrunk = true;
                } else {
                    at += chunk;
                }
            }
            if !shrunk {
                chunk /= 2;
            }
        }
        let dir = failure_dir();
        let full = dir.join(format!("{}-{n}.bin", self.name));
        let small = dir.join(format!("{}-{n}-min.bin", self.name));
        let written = std::fs::create_dir_all(&dir)
            .and_then(|()| std::fs::write(&full, input))
            .and_then(|()| std::fs::write(&small, &min));
        let preview = String::from_utf8_lossy(&min[..min.len().min(300)])
            .escape_debug()
            .to_string();
        match written {
            Ok(()) => format!(
                "input saved to {}, shrunk to {} bytes in {}: \"{preview}\"",
                full.display(),
                min.len(),
                small.display()
            ),
            Err(e) => format!("could not save the input ({e}); shrunk: \"{preview}\""),
        }
    }
}

/// `Some(problem)` when an error message is unfit for an operator's terminal.
fn bad_message(msg: &str) -> Option<String> {
    if msg.trim().is_empty() {
        Some("refused it with an empty error message".into())
    } else if msg.len() > 2048 {
        Some(format!(
            "refused it with a {}-byte error message",
            msg.len()
        ))
    } else if msg.chars().any(|c| c.is_control() && c != '\n') {
        Some(format!(
            "refused it with control characters in the message: {msg:?}"
        ))
    } else {
        None
    }
}

fn panic_text(panic: &Box<dyn std::any::Any + Send>) -> String {
    panic
        .downcast_ref::<String>()
        .cloned()
        .or_else(|| panic.downcast_ref::<&str>().map(|s| (*s).to_owned()))
        .unwrap_or_else(|| "(no message)".into())
}

fn env_f64(name: &str) -> Option<f64> {
    let v = std::env::var(name).ok()?;
    match v.trim().parse::<f64>() {
        Ok(x) if x.is_finite() && x >= 0.0 => Some(x),
        _ => panic!("{name}={v:?}: expected a non-negative number"),
    }
}

fn fnv(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| {
        (h ^ u64::from(b)).wrapping_mul(0x100_0000_01b3)
    })
}

/// `target/fuzz-failures` of the workspace being tested (`CARGO_TARGET_DIR` when set).
fn failure_dir() -> PathBuf {
    let target = std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .or_else(|| {
            // The test binary lives in target/<profile>/deps/.
            let exe = std::env::current_exe().ok()?;
            Some(exe.parent()?.parent()?.parent()?.to_path_buf())
        })
        .unwrap_or_else(std::env::temp_dir);
    target.join("fuzz-failures")
}

// ---------------------------------------------------------------- hang watchdog

/// Ends the process when one input takes longer than [`HANG_LIMIT`], after saving it: a hung
/// parser cannot be interrupted from its own thread.
#[derive(Debug)]
struct Watchdog {
    shared: Arc<WatchShared>,
}

#[derive(Debug)]
struct WatchShared {
    /// Milliseconds since `epoch` when the current input started; 0 = idle.
    started_ms: AtomicU64,
    stop: AtomicBool,
    epoch: Instant,
    input: std::sync::Mutex<Vec<u8>>,
}

impl Watchdog {
    fn start(name: &str) -> Self {
        let shared = Arc::new(WatchShared {
            started_ms: AtomicU64::new(0),
            stop: AtomicBool::new(false),
            epoch: Instant::now(),
            input: std::sync::Mutex::new(Vec::new()),
        });
        let watched = Arc::clone(&shared);
        let name = name.to_owned();
        std::thread::spawn(move || {
            while !watched.stop.load(Ordering::Relaxed) {
                std::thread::sleep(Duration::from_millis(200));
                let s = watched.started_ms.load(Ordering::Relaxed);
                let now = watched.epoch.elapsed().as_millis() as u64;
                if s > 0 && now.saturating_sub(s) > HANG_LIMIT.as_millis() as u64 {
                    let input = watched.input.lock().map(|i| i.clone()).unwrap_or_default();
                    let path = failure_dir().join(format!("{name}-hang.bin"));
                    let _ = std::fs::create_dir_all(failure_dir());
                    let _ = std::fs::write(&path, &input);
                    eprintln!(
                        "fuzz target {name}: one input ran over {} s (a hang); saved to {}",
                        HANG_LIMIT.as_secs(),
                        path.display()
                    );
                    std::process::abort();
                }
            }
        });
        Watchdog { shared }
    }

    fn begin(&self, input: &[u8]) {
        if let Ok(mut i) = self.shared.input.lock() {
            i.clear();
            i.extend_from_slice(input);
        }
        let now = self.shared.epoch.elapsed().as_millis() as u64;
        self.shared.started_ms.store(now.max(1), Ordering::Relaxed);
    }

    fn end(&self) {
        self.shared.started_ms.store(0, Ordering::Relaxed);
    }
}

impl Drop for Watchdog {
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::Relaxed);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The harness finds a planted bug: a parser that panics on a byte pattern the
    /// mutations make (a number replaced by an extreme one) fails the run, naming the input.
    #[test]
    fn a_planted_panic_is_found_and_saved() {
        let seeds = vec![b"count 12\nvalues 1 2 3\n".to_vec()];
        let r = catch_unwind(|| {
            Target::new("planted", seeds).run(|b| {
                let text = std::str::from_utf8(b).map_err(|_| "not UTF-8")?;
                if text.contains("4294967295") {
                    panic!("planted bug");
                }
                if text.starts_with("count ") {
                    Ok(())
                } else {
                    Err("no count")
                }
            })
        });
        let msg = panic_text(&r.expect_err("the planted bug must be found"));
        assert!(
            msg.contains("planted bug") && msg.contains("shrunk to"),
            "{msg}"
        );
    }

    #[test]
    fn a_seed_that_does_not_parse_fails_the_run() {
        let r = catch_unwind(|| Target::new("bad-seed", vec![b"x".to_vec()]).run(|_| Err("no")));
        assert!(panic_text(&r.expect_err("must fail")).contains("seed 0 does not parse"));
    }

    #[test]
    fn mutations_stay_within_the_length_cap_and_change_the_input() {
        let seeds = vec![b"ply\nformat ascii 1.0\nelement vertex 3\nend_header\n".to_vec()];
        let mut rng = Rng::new(7);
        let mut changed = 0;
        for _ in 0..1000 {
            let m = mutate(&mut rng, &seeds, 100);
            assert!(m.len() <= 100);
            changed += usize::from(m != seeds[0]);
        }
        assert!(changed > 900, "{changed}");
    }

    #[test]
    fn control_characters_and_empty_messages_are_problems() {
        assert!(bad_message("").is_some());
        assert!(bad_message("bad \x1b[31m").is_some());
        assert!(bad_message(&"x".repeat(3000)).is_some());
        assert!(bad_message("line 3: expected a number").is_none());
    }
}
