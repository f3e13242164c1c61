//! Dates and times, one copy for the whole program: the wall clock ([`unix_now`]), civil
//! dates of unix days ([`civil_from_days`]), the UTC text of a time ([`utc_text`]), and the
//! calendar times of scheduled drift checks.
//!
//! Calendar times (`daemon.check_at = ["Mon-Fri 06:00", "22:30"]`): days of the week and a
//! time of day in the cell PC's local time (the system time zone, or `TZ`). The next
//! occurrence is found day by day, so daylight-saving changes and wall-clock jumps are handled
//! by asking again, not by sleeping for a precomputed interval.

use std::fmt;
use std::str::FromStr;

/// The wall clock as unix time, s (0 before 1970).
pub fn unix_now() -> f64 {
    std::time::SystemTime::now()
        .duration_since(std::time::SystemTime::UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

/// Gregorian date of a day count since 1970-01-01 (H. Hinnant's algorithm).
pub fn civil_from_days(z: i64) -> (i64, u32, u32) {
    let z = z + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let m = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    (yoe + era * 400 + i64::from(m <= 2), m, d)
}

/// How far a recorded run's start may lie after now, s (a clock set back a little since):
/// a run dated later is not one (a planted or forged record, a row of the history).
pub const MAX_CLOCK_AHEAD_S: f64 = 300.0;

/// UTC date and time of a unix time in whole seconds: `(year, month, day, hour, minute,
/// second)`.
pub fn utc_fields(unix_s: i64) -> (i64, u32, u32, i64, i64, i64) {
    let (days, rem) = (unix_s.div_euclid(86_400), unix_s.rem_euclid(86_400));
    let (y, m, d) = civil_from_days(days);
    (y, m, d, rem / 3600, rem % 3600 / 60, rem % 60)
}

/// `YYYYMMDDTHHMMSSZ` (ISO 8601 basic, UTC) of a unix time in whole seconds: the form in file
/// and folder names (run ids, a history or a journal set aside).
pub fn utc_stamp(unix_s: i64) -> String {
    let (y, m, d, hh, mm, ss) = utc_fields(unix_s);
    format!("{y:04}{m:02}{d:02}T{hh:02}{mm:02}{ss:02}Z")
}

/// `YYYY-MM-DDTHH:MM:SSZ` (ISO 8601, UTC) of a unix time, s: the one form every time a
/// person reads takes (CLI, journal, report pictures, history exports); `?` when not finite.
pub fn utc_text(unix_s: f64) -> String {
    if !unix_s.is_finite() {
        return "?".into();
    }
    let (y, m, d, hh, mm, ss) = utc_fields(unix_s.floor() as i64);
    format!("{y:04}-{m:02}-{d:02}T{hh:02}:{mm:02}:{ss:02}Z")
}

/// Weekday names, Monday first (ISO 8601 order).
const DAYS: [&str; 7] = ["Mon", "Tue", "Wed", "Thu", "Fri", "Sat", "Sun"];
/// Every day of the week.
const ALL_DAYS: u8 = 0b111_1111;

/// One calendar time: a set of weekdays and a minute of the day, local time.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CalendarTime {
    /// Bit `d` set: weekday `d` (0 = Monday).
    days: u8,
    /// Minutes after local midnight.
    minute: u16,
}

/// Why a calendar time does not parse.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}: expected \"HH:MM\" (every day) or days then \"HH:MM\", e.g. \"Mon-Fri 06:00\" or \"Sat,Sun 12:30\" (24-hour clock, the cell PC's local time)")]
pub struct CalendarError(String);

fn day_index(name: &str) -> Option<u8> {
    DAYS.iter()
        .position(|d| d.eq_ignore_ascii_case(name))
        .map(|i| i as u8)
}

impl FromStr for CalendarTime {
    type Err = CalendarError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let shown: String = s.chars().take(40).collect();
        let bad = |why: &str| CalendarError(format!("{why} in {shown:?}"));
        let mut parts = s.split_whitespace();
        let (days_text, time_text) = match (parts.next(), parts.next(), parts.next()) {
            (Some(t), None, None) => (None, t),
            (Some(d), Some(t), None) => (Some(d), t),
            _ => return Err(bad("not one time")),
        };
        let mut days = 0u8;
        match days_text {
            None => days = ALL_DAYS,
            Some(list) => {
                for item in list.split(',') {
                    let (from, to) = match item.split_once('-') {
                        Some((a, b)) => (a, b),
                        None => (item, item),
                    };
                    let (Some(a), Some(b)) = (day_index(from), day_index(to)) else {
                        return Err(bad("unknown day (Mon, Tue, Wed, Thu, Fri, Sat, Sun)"));
                    };
                    // A range may wrap over the week's end: "Sat-Mon".
                    let mut d = a;
                    loop {
                        days |= 1 << d;
                        if d == b {
                            break;
                        }
                        d = (d + 1) % 7;
                    }
                }
            }
        }
        let (h, m) = time_text.split_once(':').ok_or_else(|| bad("no HH:MM"))?;
        let digits = |t: &str| t.len() == 2 && t.bytes().all(|b| b.is_ascii_digit());
        if !digits(h) || !digits(m) {
            return Err(bad("time not HH:MM"));
        }
        let (h, m): (u16, u16) = (
            h.parse().map_err(|_| bad("hour"))?,
            m.parse().map_err(|_| bad("minute"))?,
        );
        if h > 23 || m > 59 {
            return Err(bad("time out of range 00:00..23:59"));
        }
        Ok(Self {
            days,
            minute: h * 60 + m,
        })
    }
}

impl fmt::Display for CalendarTime {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.days != ALL_DAYS {
            let names: Vec<&str> = (0..7)
                .filter(|d| self.days & (1 << d) != 0)
                .map(|d| DAYS[d])
                .collect();
            write!(f, "{} ", names.join(","))?;
        }
        write!(f, "{:02}:{:02}", self.minute / 60, self.minute % 60)
    }
}

/// The local time zone's offset east of UTC at unix time `t`, s (`localtime_r`'s `tm_gmtoff`;
/// 0 when the C library cannot tell).
pub fn local_offset_s(t: i64) -> i64 {
    let Some(t) = libc::time_t::try_from(t).ok() else {
        return 0;
    };
    // SAFETY: `localtime_r` writes only into `tm`, which lives on this stack frame, and reads
    // only `t`; a null return (time not representable) leaves `tm` unused.
    let mut tm: libc::tm = unsafe { std::mem::zeroed() };
    let r = unsafe { libc::localtime_r(&t, &mut tm) };
    if r.is_null() {
        return 0;
    }
    // `c_long`: i64 here, i32 on 32-bit targets.
    #[allow(clippy::useless_conversion)]
    i64::from(tm.tm_gmtoff)
}

/// The first occurrence of any of `times` strictly after unix time `now` (s), with the time
/// zone given by `offset` (seconds east of UTC at an instant). `None` when `times` is empty.
pub fn next_after(times: &[CalendarTime], now: i64, offset: impl Fn(i64) -> i64) -> Option<i64> {
    let local_now = now + offset(now);
    let today = local_now.div_euclid(86_400);
    let mut best: Option<i64> = None;
    // Eight days cover every weekday set from any starting day (and today's time if passed).
    for day in today..=today + 8 {
        // 1970-01-01 was a Thursday (index 3).
        let weekday = (day + 3).rem_euclid(7) as u8;
        for t in times {
            if t.days & (1 << weekday) == 0 {
                continue;
            }
            let local = day * 86_400 + i64::from(t.minute) * 60;
            // Local to UTC with the offset in force then (asked twice across a DST change).
            let guess = local - offset(local - offset(now));
            let at = local - offset(guess);
            if at > now && best.is_none_or(|b| at < b) {
                best = Some(at);
            }
        }
        if best.is_some() {
            break;
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    fn utc(_: i64) -> i64 {
        0
    }

    /// 2026-11-23 was a Monday; 00:00 UTC.
    const MONDAY: i64 = 1_795_392_000;

    fn parse(s: &str) -> CalendarTime {
        s.parse().unwrap_or_else(|e| panic!("{s}: {e}"))
    }

    #[test]
    fn civil_dates_and_utc_text() {
        assert_eq!(civil_from_days(0), (1970, 1, 1));
        assert_eq!(civil_from_days(20_416), (2025, 11, 24));
        assert_eq!(civil_from_days(11_016), (2000, 2, 29));
        assert_eq!(utc_text(0.0), "1970-01-01T00:00:00Z");
        assert_eq!(
            utc_text(20_416.0 * 86_400.0 + 14.0 * 3600.0 + 23.0 * 60.0 + 0.9),
            "2025-11-24T14:23:00Z"
        );
        assert_eq!(utc_text(-0.5), "1969-12-31T23:59:59Z");
        assert_eq!(utc_text(f64::NAN), "?");
    }

    #[test]
    fn parses_days_and_times_and_prints_them_back() {
        for (text, shown) in [
            ("06:00", "06:00"),
            ("Mon-Fri 18:30", "Mon,Tue,Wed,Thu,Fri 18:30"),
            ("sat,sun 00:05", "Sat,Sun 00:05"),
            ("Sat-Mon 23:59", "Mon,Sat,Sun 23:59"),
            ("Mon-Sun 12:00", "12:00"),
        ] {
            let t = parse(text);
            assert_eq!(t.to_string(), shown);
            assert_eq!(parse(shown), t, "{shown} round-trips");
        }
        for bad in [
            "",
            "6:00",
            "24:00",
            "12:60",
            "Mon",
            "Mon 06:00 x",
            "Mo 06:00",
            "Mon-Xyz 06:00",
            "06:00:00",
            "-1:00",
            "+1:00",
        ] {
            let e = bad.parse::<CalendarTime>().expect_err(bad).to_string();
            assert!(e.contains("expected \"HH:MM\""), "{bad}: {e}");
        }
    }

    #[test]
    fn next_occurrence_respects_days_and_never_returns_now() {
        let weekdays = [parse("Mon-Fri 06:00")];
        // Monday 05:00 → Monday 06:00.
        assert_eq!(
            next_after(&weekdays, MONDAY + 5 * 3600, utc),
            Some(MONDAY + 6 * 3600)
        );
        // Exactly at 06:00 → Tuesday's (a check that just fired is not due again).
        assert_eq!(
            next_after(&weekdays, MONDAY + 6 * 3600, utc),
            Some(MONDAY + 86_400 + 6 * 3600)
        );
        // Friday 07:00 → next Monday 06:00.
        assert_eq!(
            next_after(&weekdays, MONDAY + 4 * 86_400 + 7 * 3600, utc),
            Some(MONDAY + 7 * 86_400 + 6 * 3600)
        );
        // The earliest of several.
        let two = [parse("Sun 10:00"), parse("Mon-Fri 06:00")];
        assert_eq!(
            next_after(&two, MONDAY + 5 * 86_400, utc),
            Some(MONDAY + 6 * 86_400 + 10 * 3600)
        );
        assert_eq!(next_after(&[], MONDAY, utc), None);
    }

    #[test]
    fn local_time_is_the_zone_s_not_utc() {
        // A zone 2 h east of UTC: 06:00 local is 04:00 UTC.
        let east = |_| 7200;
        assert_eq!(
            next_after(&[parse("06:00")], MONDAY, east),
            Some(MONDAY + 4 * 3600)
        );
        // Across a change from +1 h to +2 h at Monday 01:00 UTC, Monday 06:00 local is
        // 04:00 UTC (the offset in force at the time, not the one now).
        let dst = |t: i64| if t < MONDAY + 3600 { 3600 } else { 7200 };
        assert_eq!(
            next_after(&[parse("06:00")], MONDAY - 3600, dst),
            Some(MONDAY + 4 * 3600)
        );
        // This machine's own zone gives a finite offset within ±14 h.
        assert!(local_offset_s(MONDAY).abs() <= 14 * 3600);
    }
}
