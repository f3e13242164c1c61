//! The wall clock watched between runs. The history orders runs by the sequence they began
//! in, never by their dates ([`crate::store::Store::latest`]), so a clock set wrong cannot
//! make an older run the latest; but a clock that stepped is worth a warning, naming both
//! times: a run's dates (its id, its record, the history) are the clock's.
//!
//! - Back: the previous run (by the history's sequence) began after this one, by more than
//!   [`MAX_CLOCK_AHEAD_S`]: the clock was ahead then, or is behind now.
//! - Forward or back within this process's life: the wall clock moved more (or less) than
//!   the monotonic clock since the last run, by more than [`MAX_STEP_S`].

use std::sync::Mutex;
use std::time::Instant;

use crate::calendar::{utc_text, MAX_CLOCK_AHEAD_S};
use crate::store::Store;

/// Largest difference between the wall clock's and the monotonic clock's time since the last
/// run that is not a step, s (NTP slews far less).
pub(crate) const MAX_STEP_S: f64 = 60.0;

/// The wall and the monotonic clock at the last run's start in this process.
static LAST: Mutex<Option<(f64, Instant)>> = Mutex::new(None);

/// Logs a warning when the clock stepped since the last run (see the module docs): the run
/// about to begin starts at `started_unix_s`; `store` is the history. Returns the warnings.
pub(crate) fn watch(store: Option<&Store>, started_unix_s: f64) -> Vec<String> {
    let mut said = Vec::new();
    if let Some(Ok(Some(previous))) = store.map(|s| s.latest(None, None)) {
        if let Some(w) = behind_previous(previous.started_unix_s, started_unix_s) {
            said.push(format!("{w} (run {})", previous.run_id));
        }
    }
    let now = Instant::now();
    let mut last = LAST.lock().unwrap_or_else(|e| e.into_inner());
    if let Some((wall, mono)) = *last {
        let elapsed = now.saturating_duration_since(mono).as_secs_f64();
        if let Some(w) = stepped(wall, elapsed, started_unix_s) {
            said.push(w);
        }
    }
    *last = Some((started_unix_s, now));
    for w in &said {
        tracing::warn!("{w}");
    }
    said
}

/// The warning when the previous run began at `previous` (unix s), after `now` by more than
/// [`MAX_CLOCK_AHEAD_S`].
fn behind_previous(previous: f64, now: f64) -> Option<String> {
    (previous > now + MAX_CLOCK_AHEAD_S).then(|| {
        format!(
            "the clock stepped back: this run starts at {}, before the previous run's start at \
             {}; the history keeps the order the runs began in, so the latest calibration is \
             still the last one made, but check the clock (NTP) and the dates of the runs",
            utc_text(now),
            utc_text(previous)
        )
    })
}

/// The warning when the wall clock said `wall` at the last run, `elapsed` s ago by the
/// monotonic clock, and says `now`: it moved by more than [`MAX_STEP_S`] besides.
fn stepped(wall: f64, elapsed: f64, now: f64) -> Option<String> {
    let step = (now - wall) - elapsed;
    (step.abs() > MAX_STEP_S).then(|| {
        format!(
            "the clock stepped {} by {:.0} s since the last run: it said {} then and says {} \
             now, {elapsed:.0} s later; the history keeps the order the runs began in, but \
             check the clock (NTP)",
            if step > 0.0 { "forward" } else { "back" },
            step.abs(),
            utc_text(wall),
            utc_text(now)
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Issue 46: a clock that steps back or forward between runs is logged, naming both times.
    #[test]
    fn issue_46_a_clock_step_between_runs_is_named_with_both_times() {
        let t = 1_767_225_600.0; // 2026-01-01T00:00:00Z
        let back = behind_previous(t + 86_400.0, t).expect("a day back");
        assert!(
            back.contains("2026-01-01T00:00:00Z") && back.contains("2026-01-02T00:00:00Z"),
            "{back}"
        );
        assert_eq!(
            behind_previous(t + 10.0, t),
            None,
            "a few seconds are no step"
        );
        let fwd = stepped(t, 100.0, t + 100.0 + 10.0 * 365.0 * 86_400.0).expect("forward");
        assert!(fwd.starts_with("the clock stepped forward by "), "{fwd}");
        assert!(fwd.contains("2026-01-01T00:00:00Z"), "{fwd}");
        let back = stepped(t, 100.0, t - 86_400.0).expect("back");
        assert!(
            back.starts_with("the clock stepped back by 86500 s"),
            "{back}"
        );
        assert_eq!(stepped(t, 100.0, t + 101.0), None);
    }
}
