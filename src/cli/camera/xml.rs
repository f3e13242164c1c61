//! `handeye camera xml FILE`: check a camera's GenICam description offline (the XML or the ZIP
//! a camera serves, or a vendor's download) and say what the driver would use.

use std::fmt::Write as _;
use std::path::Path;
use std::process::ExitCode;

use anyhow::Context;
use handeye_gige::describe::{describe, Description};
use handeye_gige::genicam::{xml_text, NodeMap, MAX_XML_BYTES};
use handeye_hal::limits;

/// Loads `path` and describes it; an error when the driver could not load it.
pub(super) fn check(path: &Path) -> anyhow::Result<Description> {
    limits::check_regular_file(path, MAX_XML_BYTES as u64)
        .with_context(|| format!("reading {}", path.display()))?;
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    let mut nm = xml_text(&bytes)
        .and_then(|text| NodeMap::from_xml(&text))
        .with_context(|| format!("{} does not load", path.display()))?;
    Ok(describe(&mut nm))
}

/// The report as text.
pub(super) fn text(d: &Description) -> String {
    let mut s = String::new();
    let list = |v: &[String]| {
        if v.is_empty() {
            "(none)".to_owned()
        } else {
            v.join(", ")
        }
    };
    let _ = writeln!(s, "description:   {} {} (loads)", d.vendor, d.model);
    let _ = writeln!(s, "pixel formats: {}", list(&d.pixel_formats));
    let _ = writeln!(s, "3D formats:    {}", list(&d.range_formats));
    let _ = writeln!(s, "usable:        {}", list(&d.usable));
    let _ = writeln!(s, "components:    {}", list(&d.components));
    if d.multipart {
        let _ = writeln!(
            s,
            "               (Range offered: the driver asks for a multi-part payload)"
        );
    }
    if !d.output_modes.is_empty() {
        let _ = writeln!(s, "output modes:  {}", d.output_modes.join(", "));
    }
    for (name, value) in &d.scan3d {
        let v = value.as_deref().unwrap_or("read from the camera");
        let _ = writeln!(s, "{name}: {v}");
    }
    if let Some(k) = &d.tl_params_locked {
        let _ = writeln!(s, "TLParamsLocked: {k}");
    }
    for (name, effect) in &d.missing {
        let _ = writeln!(s, "missing {name}: {effect}");
    }
    for setting in &d.settings {
        let _ = writeln!(s, "to do: {setting}");
    }
    match &d.verdict {
        Ok(()) => {
            let _ = writeln!(s, "verdict: the driver can stream points from this camera");
        }
        Err(why) => {
            let _ = writeln!(s, "verdict: would not work: {why}");
        }
    }
    s
}

/// Runs the subcommand: exit 0 when the description loads (the verdict is printed), an error
/// (exit 2) with the reason when it does not.
pub(super) fn run(path: &Path, json: bool) -> anyhow::Result<ExitCode> {
    let d = check(path)?;
    // `| head -1` closes the pipe early: not an error (println! would panic).
    if json {
        super::super::emit(&(serde_json::to_string_pretty(&d)? + "\n"))?;
    } else {
        super::super::emit(&text(&d))?;
    }
    Ok(ExitCode::SUCCESS)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn corpus() -> Vec<std::path::PathBuf> {
        let dir =
            Path::new(env!("CARGO_MANIFEST_DIR")).join("drivers/gige/tests/data/genicam-corpus");
        let mut v: Vec<_> = std::fs::read_dir(dir)
            .expect("corpus")
            .map(|e| e.expect("entry").path())
            .filter(|p| p.extension().is_some_and(|x| x == "zip"))
            .collect();
        v.sort();
        v
    }

    /// Issue 35: every real description in the corpus (all of which the EMVA reference loads,
    /// see drivers/gige/tests/genapi_corpus.rs) loads, and the report names its verdict.
    #[test]
    fn every_corpus_description_loads() {
        let files = corpus();
        assert!(files.len() >= 80, "{}", files.len());
        let mut work = Vec::new();
        for f in &files {
            let d = check(f).unwrap_or_else(|e| panic!("{}: {e:#}", f.display()));
            let t = text(&d);
            assert!(t.contains("verdict: "), "{t}");
            if d.verdict.is_ok() {
                work.push(f.file_name().expect("name").to_string_lossy().into_owned());
            }
        }
        // Nerian's SceneScan/Scarlet (Coord3D_ABC32f, Range component, no Scan3dDistanceUnit):
        // the only 3D camera in the corpus.
        assert_eq!(work, ["Nerian_remote.zip"], "{work:?}");
        let nerian = check(
            &files
                .iter()
                .find(|f| f.ends_with("Nerian_remote.zip"))
                .expect("nerian")
                .clone(),
        )
        .expect("nerian");
        assert!(nerian.multipart);
        assert!(
            nerian
                .missing
                .iter()
                .any(|(f, e)| f == "Scan3dDistanceUnit" && e.contains("millimetres")),
            "{nerian:?}"
        );
    }

    #[test]
    fn a_broken_description_is_an_error_with_the_reason() {
        let dir = std::env::temp_dir().join(format!("handeye-camera-xml-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("dir");
        let f = dir.join("bad.xml");
        std::fs::write(&f, "<RegisterDescription><Integer Name=").expect("write");
        let e = format!("{:#}", check(&f).expect_err("broken"));
        assert!(
            e.contains("does not load") && e.contains("GenICam XML"),
            "{e}"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }
}
