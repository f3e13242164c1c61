//! The manual (README.md and the mdBook in docs/) holds together: every page is in
//! `docs/src/SUMMARY.md` and every entry there exists, every internal link and picture points
//! at a file that exists (and at a heading that exists, for `page.md#anchor`), and every error
//! message the troubleshooting page quotes still occurs in the source code. CI also builds the
//! book with mdbook (`.ci/run`), which does not check links itself.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// `docs/src/*.md`, sorted.
fn pages() -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(root().join("docs/src"))
        .expect("docs/src")
        .map(|e| e.expect("entry").path())
        .filter(|p| p.extension().is_some_and(|e| e == "md"))
        .collect();
    v.sort();
    v
}

/// The text outside fenced code blocks and inline code spans, line by line.
fn prose(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut fenced = false;
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            fenced = !fenced;
            continue;
        }
        if fenced {
            continue;
        }
        // Drop code spans (a run of n backticks closes with a run of n).
        let mut kept = String::new();
        let b = line.as_bytes();
        let mut i = 0;
        while i < b.len() {
            if b[i] == b'`' {
                let n = b[i..].iter().take_while(|&&c| c == b'`').count();
                let fence = "`".repeat(n);
                match line[i + n..].find(&fence) {
                    Some(end) => i += n + end + n,
                    None => i += n,
                }
            } else {
                let ch = line[i..].chars().next().expect("char");
                kept.push(ch);
                i += ch.len_utf8();
            }
        }
        out.push(kept);
    }
    out
}

/// The targets of the Markdown links and pictures `[text](target)` in `text`.
pub(crate) fn links(text: &str) -> Vec<String> {
    let mut v = Vec::new();
    for line in prose(text) {
        let mut rest = line.as_str();
        while let Some(at) = rest.find("](") {
            let after = &rest[at + 2..];
            match after.find(')') {
                Some(end) => {
                    v.push(after[..end].trim().to_string());
                    rest = &after[end..];
                }
                None => break,
            }
        }
    }
    v
}

/// mdBook's id for a heading: lower case, letters, digits, `-` and `_` kept, spaces to `-`.
fn slug(heading: &str) -> String {
    heading
        .trim()
        .to_lowercase()
        .chars()
        .filter_map(|c| match c {
            ' ' => Some('-'),
            c if c.is_alphanumeric() || c == '-' || c == '_' => Some(c),
            _ => None,
        })
        .collect()
}

fn anchors(text: &str) -> BTreeSet<String> {
    let mut fenced = false;
    let mut v = BTreeSet::new();
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            fenced = !fenced;
        } else if !fenced && line.starts_with('#') {
            v.insert(slug(line.trim_start_matches('#')));
        }
    }
    v
}

/// Every page of docs/src is in SUMMARY.md, every entry there exists, and no page is listed
/// twice.
#[test]
fn every_page_is_in_the_summary_and_every_entry_exists() {
    let summary = std::fs::read_to_string(root().join("docs/src/SUMMARY.md")).expect("SUMMARY.md");
    let listed: Vec<String> = links(&summary);
    let unique: BTreeSet<&String> = listed.iter().collect();
    assert_eq!(
        unique.len(),
        listed.len(),
        "a page listed twice: {listed:?}"
    );
    for entry in &listed {
        assert!(
            root().join("docs/src").join(entry).is_file(),
            "SUMMARY.md lists {entry}, which does not exist"
        );
    }
    for page in pages() {
        let name = page
            .file_name()
            .expect("name")
            .to_string_lossy()
            .to_string();
        if name != "SUMMARY.md" {
            assert!(
                listed.contains(&name),
                "docs/src/{name} is not in SUMMARY.md: mdbook would leave it out of the book"
            );
        }
    }
}

/// Internal links and pictures of the README and the book point at files and headings that
/// exist.
#[test]
fn internal_links_resolve() {
    let mut files = pages();
    files.push(root().join("README.md"));
    let mut broken = Vec::new();
    for file in &files {
        let text = std::fs::read_to_string(file).expect("page");
        for target in links(&text) {
            if target.contains("://") || target.starts_with("mailto:") {
                continue;
            }
            let (path, anchor) = match target.split_once('#') {
                Some((p, a)) => (p, Some(a)),
                None => (target.as_str(), None),
            };
            let dest = if path.is_empty() {
                file.clone()
            } else {
                file.parent().expect("dir").join(path)
            };
            if !dest.exists() {
                broken.push(format!("{}: {target} (no such file)", file.display()));
                continue;
            }
            if let Some(anchor) = anchor {
                let page = std::fs::read_to_string(&dest).unwrap_or_default();
                if !anchors(&page).contains(anchor) {
                    broken.push(format!("{}: {target} (no such heading)", file.display()));
                }
            }
        }
    }
    assert!(broken.is_empty(), "broken links:\n{}", broken.join("\n"));
}

#[test]
fn links_are_found_outside_code_only() {
    let text = "see [a](a.md) and `[b](b.md)` and ![p](images/p.png)\n```\n[c](c.md)\n```\n";
    assert_eq!(links(text), ["a.md", "images/p.png"]);
    assert_eq!(slug("Write-back"), "write-back");
    assert_eq!(
        slug("The simulated rig: `handeye sim rig`"),
        "the-simulated-rig-handeye-sim-rig"
    );
}

/// The source code of the workspace (`.rs` files), with Rust's `\`-newline string
/// continuations joined as the compiler joins them.
fn source_text() -> String {
    let mut out = String::new();
    let mut dirs = vec![
        root().join("src"),
        root().join("calib/src"),
        root().join("drivers"),
    ];
    while let Some(dir) = dirs.pop() {
        for e in std::fs::read_dir(&dir).expect("dir") {
            let p = e.expect("entry").path();
            if p.is_dir() {
                dirs.push(p);
            } else if p.extension().is_some_and(|e| e == "rs") {
                let text = std::fs::read_to_string(&p).expect("source");
                let mut lines = text.lines().peekable();
                while let Some(line) = lines.next() {
                    match line.strip_suffix('\\') {
                        Some(head) => {
                            out.push_str(head);
                            if let Some(next) = lines.peek_mut() {
                                *next = next.trim_start();
                            }
                        }
                        None => {
                            out.push_str(line);
                            out.push('\n');
                        }
                    }
                }
            }
        }
    }
    out
}

/// The messages in the first column of the troubleshooting page's tables.
fn troubleshooting_messages(text: &str) -> Vec<String> {
    text.lines()
        .filter(|l| l.starts_with("| `"))
        .filter_map(|l| l.split(" | ").next())
        .map(|cell| {
            cell.trim_start_matches('|')
                .trim()
                .trim_matches('`')
                .trim()
                .to_string()
        })
        .collect()
}

/// Every error message the troubleshooting page quotes (`…` for what changes) is still
/// printed by the code: each piece between the `…` occurs in the source.
#[test]
fn troubleshooting_messages_occur_in_the_source() {
    let page = std::fs::read_to_string(root().join("docs/src/troubleshooting.md")).expect("page");
    let messages = troubleshooting_messages(&page);
    assert!(messages.len() >= 20, "{messages:?}");
    let source = source_text();
    let missing: Vec<&String> = messages
        .iter()
        .filter(|m| {
            m.split('…')
                .map(str::trim_end)
                .filter(|piece| piece.trim().len() >= 3)
                .any(|piece| !source.contains(piece))
        })
        .collect();
    assert!(
        missing.is_empty(),
        "docs/src/troubleshooting.md quotes messages the code no longer prints: {missing:#?}"
    );
}

/// Issue 42 (item 6): one pass bound everywhere. Every page that says how close to the truth a
/// simulated calibration must land (`within 1.5 mm / 0.25° of the truth`, `accepted and ≤ …`)
/// quotes the code's bound (`handeye::bench::PASS_TRANSLATION_MM` / `PASS_ROTATION_DEG`); the
/// benchmark's own `success` column (a looser bound of the bench) is not this one.
#[test]
fn issue_42_the_pages_quote_the_codes_pass_bound() {
    let want = format!(
        "{} mm / {}°",
        handeye::bench::PASS_TRANSLATION_MM,
        handeye::bench::PASS_ROTATION_DEG
    );
    let mut pages = vec![root().join("README.md")];
    let mut docs: Vec<_> = std::fs::read_dir(root().join("docs/src"))
        .expect("docs/src")
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|x| x == "md"))
        .collect();
    docs.sort();
    pages.extend(docs);
    let mut wrong = Vec::new();
    let mut found = 0;
    for page in &pages {
        let text = std::fs::read_to_string(page).expect("page");
        let text = text.split_whitespace().collect::<Vec<_>>().join(" ");
        for lead in ["within ", "≤ "] {
            for (at, _) in text.match_indices(lead) {
                let rest = &text[at + lead.len()..];
                let Some(mm) = rest.find(" mm / ") else {
                    continue;
                };
                let t = &rest[..mm];
                let tail = &rest[mm + " mm / ".len()..];
                let Some(deg) = tail.find('°') else { continue };
                let r = &tail[..deg];
                let number =
                    |s: &str| !s.is_empty() && s.chars().all(|c| c.is_ascii_digit() || c == '.');
                if !number(t) || !number(r) {
                    continue;
                }
                let mut from = at.saturating_sub(40);
                while !text.is_char_boundary(from) {
                    from -= 1;
                }
                let before = &text[from..at];
                let after: String = tail[deg..].chars().take(20).collect();
                let is_pass = (before.contains("accepted and") || after.contains("of the truth"))
                    && !before.contains("`success` =");
                if !is_pass {
                    continue;
                }
                found += 1;
                let quoted = format!("{t} mm / {r}°");
                if quoted != want {
                    wrong.push(format!("{}: …{before}{lead}{quoted}…", page.display()));
                }
            }
        }
    }
    assert!(
        found >= 5,
        "the pass bound is quoted only {found} times: has the wording changed?"
    );
    assert!(
        wrong.is_empty(),
        "pages that quote another pass bound than {want}: {wrong:#?}"
    );
}
