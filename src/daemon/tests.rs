//! The daemon's state and queue, without a robot: busy requests, the history replayed at a
//! restart.

use super::*;
use crate::config::{WhenBusy, QUEUE_LIMIT};

fn store(tag: &str) -> (Arc<Store>, std::path::PathBuf) {
    let dir = std::env::temp_dir().join(format!("handeye-daemon-{}-{tag}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("dir");
    let s = Store::open(&dir.join("history.sqlite")).expect("store");
    (Arc::new(s), dir)
}

#[test]
fn a_busy_daemon_refuses_or_queues_as_configured() {
    let (s, dir) = store("refuse");
    let h = handle(s, WhenBusy::Refuse, CancellationToken::new());
    let first = h
        .request(RunMode::Check, Trigger::Api)
        .expect("idle: accepted");
    let e = h
        .request(RunMode::Calibrate, Trigger::Pendant)
        .expect_err("busy");
    assert!(
        matches!(&e, Refusal::Busy { run_id, .. } if *run_id == first),
        "{e}"
    );
    assert!(e.to_string().starts_with("busy: check run "), "{e}");
    // Since when, in ISO 8601 UTC: `since 2026-11-26T19:40:00Z; cancel it`.
    let text = e.to_string();
    let since = text.split("since ").nth(1).unwrap_or("");
    assert!(
        since.len() > 20 && since.as_bytes()[10] == b'T' && since[19..].starts_with("Z; cancel it"),
        "{e}"
    );
    let _ = std::fs::remove_dir_all(dir);

    let (s, dir) = store("queue");
    let h = handle(s, WhenBusy::Queue, CancellationToken::new());
    let running = h
        .request(RunMode::Calibrate, Trigger::Api)
        .expect("accepted");
    let queued: Vec<String> = (0..QUEUE_LIMIT)
        .map(|_| {
            h.request(RunMode::Check, Trigger::Schedule)
                .expect("queued")
        })
        .collect();
    let e = h
        .request(RunMode::Check, Trigger::Api)
        .expect_err("queue full");
    assert!(
        matches!(
            e,
            Refusal::QueueFull {
                queued: QUEUE_LIMIT,
                ..
            }
        ),
        "{e}"
    );
    let st = h.status();
    assert_eq!(st.current.as_ref().map(|c| &c.run_id), Some(&running));
    let ids: Vec<&String> = st.queued.iter().map(|c| &c.run_id).collect();
    assert_eq!(ids, queued.iter().collect::<Vec<_>>());

    // The worker takes the first; once it is finished, the next is the current one.
    let job = h.next_job().expect("running job");
    assert_eq!(job.entry.run_id, running);
    assert_eq!(h.next_job().map(|j| j.entry.run_id), Some(running.clone()));
    let mut record = RunRecord::starting(running.clone(), RunMode::Calibrate, false, "test".into());
    record.outcome = Outcome::Rejected;
    h.finished(&job, &record);
    let st = h.status();
    assert_eq!(st.current.as_ref().map(|c| &c.run_id), Some(&queued[0]));
    assert_eq!(st.queued.len(), QUEUE_LIMIT - 1);

    assert_eq!(
        h.next_job().map(|j| j.entry.run_id),
        Some(queued[0].clone())
    );

    // Cancel stops the running one and every queued one.
    let waiting: Vec<Job> = h.lock().runs.iter().cloned().collect();
    assert_eq!(waiting.len(), QUEUE_LIMIT);
    assert!(waiting.iter().all(|j| !j.cancel.is_cancelled()));
    assert!(h.cancel());
    assert!(waiting.iter().all(|j| j.cancel.is_cancelled()));
    let _ = std::fs::remove_dir_all(dir);
}

/// Issue 24: a check's warning (the calibration was made on another arm) is in the status,
/// and still there after a restart: the history keeps no warnings, the run's record does.
#[test]
fn a_check_s_warning_survives_a_restart() {
    let (s, dir) = store("warnings");
    let run_id = "20261124T142300Z-3f9a";
    let mut record = RunRecord::starting(run_id.into(), RunMode::Check, false, "test".into());
    record.outcome = Outcome::Accepted;
    record.drift = Some(crate::record::DriftRecord {
        reference: "result of run X".into(),
        reference_pose: crate::frames::to_row_major(&nalgebra::Isometry3::identity()),
        translation_mm: 0.1,
        rotation_deg: 0.01,
        max_translation_mm: 1.0,
        max_rotation_deg: 0.2,
        drifted: false,
    });
    let warning = "the current calibration was made on arm 20205500001; this controller is \
                   20205500002: recalibrate";
    record.warnings.push(warning.into());
    s.rebuild(std::slice::from_ref(&record)).expect("history");
    let run_dir = crate::storage::run_dir(&dir, run_id).expect("a run id");
    std::fs::create_dir_all(&run_dir).expect("run folder");
    crate::storage::write_record(&run_dir, &record).expect("record.json");

    let restarted = handle(s, WhenBusy::Refuse, CancellationToken::new());
    restarted.restore_from_history(&dir).expect("restored");
    let st = restarted.status();
    let check = st.last_check.as_ref().expect("the last check");
    assert_eq!(check.run_id, run_id);
    assert_eq!(check.warnings, [warning]);
    assert_eq!(
        st.last.as_ref().map(|f| f.warnings.clone()),
        Some(vec![warning.to_string()])
    );
    let _ = std::fs::remove_dir_all(dir);
}

/// A finished run of `mode` with `outcome`, dated `started` (unix s), recorded in `s`.
fn recorded(s: &Store, run_id: &str, mode: RunMode, outcome: Outcome, started: f64) {
    let mut record = RunRecord::starting(run_id.into(), mode, false, "test".into());
    record.outcome = outcome;
    record.started_unix_s = started;
    s.finish(Trigger::Api, &record).expect("history");
}

/// Issue 46: a calibration made with the clock ten years ahead (then set right), or a day
/// behind, is still the daemon's last calibration after a restart, and `/api/latest`'s: the
/// history's sequence orders runs, not their dates (the latest was the superseded one).
#[test]
fn issue_46_the_last_calibration_is_the_last_made_whatever_the_clock_said() {
    let now = crate::calendar::unix_now();
    for (tag, skew) in [("ahead", 10.0 * 365.25 * 86_400.0), ("behind", -86_400.0)] {
        let (s, dir) = store(tag);
        recorded(
            &s,
            "20261124T100000Z-0001",
            RunMode::Calibrate,
            Outcome::Accepted,
            now - 3_600.0,
        );
        recorded(
            &s,
            "20261124T110000Z-0002",
            RunMode::Calibrate,
            Outcome::Accepted,
            now + skew,
        );
        // The clock set right again: a check follows.
        recorded(
            &s,
            "20261124T120000Z-0003",
            RunMode::Check,
            Outcome::Accepted,
            now,
        );
        let latest = s
            .latest(Some(RunMode::Calibrate), Some(Outcome::Accepted))
            .expect("latest")
            .map(|r| r.run_id);
        assert_eq!(latest.as_deref(), Some("20261124T110000Z-0002"), "{tag}");
        let restarted = handle(Arc::clone(&s), WhenBusy::Refuse, CancellationToken::new());
        restarted.restore_from_history(&dir).expect("restored");
        let st = restarted.status();
        let calibration = st.last_calibration.as_ref().map(|f| f.run_id.as_str());
        assert_eq!(calibration, Some("20261124T110000Z-0002"), "{tag}");
        assert_eq!(
            st.last.as_ref().map(|f| f.run_id.as_str()),
            Some("20261124T120000Z-0003"),
            "{tag}"
        );
        let _ = std::fs::remove_dir_all(dir);
    }
}

/// Issue 44: a camera that refuses a configured setting answers the health check (a run's
/// preflight then says what it refuses); one that times out or fails otherwise does not.
#[test]
fn issue_44_a_camera_refusing_a_setting_still_answers_the_health_check() {
    use handeye_hal::{CameraInfo, HalError};
    let info = CameraInfo {
        vendor: "v".into(),
        model: "m".into(),
        serial: "s".into(),
        firmware: "f".into(),
        width: 4,
        height: 3,
        pixel_formats: Vec::new(),
    };
    let refused = HalError::Refused {
        device: "camera".into(),
        request: "camera.features.PixelFormat = Coord3D_C32f".into(),
        reason: "not an entry".into(),
    };
    assert!(camera_answers::<()>(&Ok(Ok(info))));
    assert!(camera_answers::<()>(&Ok(Err(refused))));
    assert!(!camera_answers::<()>(&Ok(Err(HalError::Timeout {
        what: "camera info".into(),
        timeout: std::time::Duration::from_secs(1),
    }))));
    assert!(!camera_answers(&Err(())));
}
