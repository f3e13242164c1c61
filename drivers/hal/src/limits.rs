//! Checks for values that come from outside the program (files, command lines, peers): one
//! place for each kind of bound, shared by the core, the drivers and the binary.
//!
//! - [`duration_from_secs`]: the one checked conversion from a number of seconds a user gave to a
//!   [`Duration`] (`Duration::from_secs_f64` panics on huge, negative or NaN values).
//! - [`check_xml_nesting`]: refuses XML nested deeper than a bound *before* a recursive parser
//!   (roxmltree's tokenizer, urdf-rs, cameleon-genapi) sees it, so a hostile file is an error
//!   instead of a stack overflow.
//! - [`check_range`]: a number with its flag or key, unit, range and reason.
//! - [`check_regular_file`]: an input path is a regular file of bounded size (a FIFO would
//!   block the reader forever) before it is opened; [`read_text_file`] reads one so checked.
//! - [`Quoted`]: how an input token is echoed in an error message: bounded in length, control
//!   characters escaped, so a 10 MB token or terminal escape sequences never reach stderr raw;
//!   [`sanitize_message`] does the same for a whole message (the binary's last line of defence).

use std::fmt;
use std::time::Duration;

/// How many characters of an echoed token an error message shows ([`Quoted`]).
pub const MAX_ECHOED_CHARS: usize = 80;

/// Deepest element nesting accepted in any XML we read (URDF, Collada, GenApi). Real files
/// nest fewer than 20 levels; the recursive parsers behind them stay far from the stack limit
/// of a 2 MiB worker thread at this depth.
pub const MAX_XML_DEPTH: usize = 128;

/// A number of seconds given by a user (`what` names the flag or key, e.g. `--timeout-s`) as a
/// [`Duration`]: it must be finite, at least `min` and at most `max` seconds. The error says
/// which flag, the range and the unit.
pub fn duration_from_secs(
    what: &str,
    seconds: f64,
    min: f64,
    max: f64,
) -> Result<Duration, String> {
    let refused = || format!("{what} = {seconds:?}: expected {min} <= seconds <= {max}");
    if seconds.is_finite() && seconds >= min && seconds <= max {
        // Checked even in range: a caller's `max` may exceed what a Duration holds.
        Duration::try_from_secs_f64(seconds.max(0.0)).map_err(|_| refused())
    } else {
        Err(refused())
    }
}

/// A number a user gave (flag or key `what`, `unit` e.g. "m" or "rad") that must lie in
/// `[min, max]` and be finite. The error names `what`, the range, the unit and `why` (what the
/// range stands for, e.g. "a depth noise of metres is no camera").
pub fn check_range(
    what: &str,
    value: f64,
    min: f64,
    max: f64,
    unit: &str,
    why: &str,
) -> Result<f64, String> {
    if value.is_finite() && value >= min && value <= max {
        Ok(value)
    } else {
        let unit = if unit.is_empty() {
            String::new()
        } else {
            format!(" {unit}")
        };
        let why = if why.is_empty() {
            String::new()
        } else {
            format!(" ({why})")
        };
        Err(format!(
            "{what} = {value:?}: expected {min} <= value <= {max}{unit}{why}"
        ))
    }
}

/// An input token echoed in a message: at most [`MAX_ECHOED_CHARS`] characters (then `…` and
/// how many bytes were left out), control characters and other non-printing characters
/// escaped as `\u{..}` (`\n`, `\t`, `\r` as such). Use it for every piece of input an error
/// repeats.
#[derive(Debug, Clone, Copy)]
pub struct Quoted<'a>(pub &'a str);

impl fmt::Display for Quoted<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write_bounded(f, self.0, MAX_ECHOED_CHARS)
    }
}

/// Longest word [`sanitize_message`] leaves whole: long enough for any real path, short
/// enough that a 10 MB token becomes a line.
pub const MAX_MESSAGE_WORD_CHARS: usize = 1024;

/// Writes `s` escaped, cut after `max` characters (then `…` and how many bytes were left out).
fn write_bounded(f: &mut impl fmt::Write, s: &str, max: usize) -> fmt::Result {
    for (shown, (i, c)) in s.char_indices().enumerate() {
        if shown == max {
            return write!(f, "… ({} more bytes)", s.len() - i);
        }
        match c {
            '\n' => f.write_str("\\n")?,
            '\r' => f.write_str("\\r")?,
            '\t' => f.write_str("\\t")?,
            c if c.is_control() || is_invisible(c) => write!(f, "\\u{{{:x}}}", c as u32)?,
            c => f.write_char(c)?,
        }
    }
    Ok(())
}

/// Characters that change how a terminal shows text without being control characters:
/// bidirectional overrides and zero-width characters.
fn is_invisible(c: char) -> bool {
    matches!(c, '\u{200b}'..='\u{200f}' | '\u{202a}'..='\u{202e}' | '\u{2066}'..='\u{2069}' | '\u{feff}')
}

/// A whole message made safe for a terminal and bounded: every run of non-whitespace longer
/// than [`MAX_MESSAGE_WORD_CHARS`] is cut as [`Quoted`] cuts it and control characters (other than
/// newlines) are escaped. For messages that may already contain raw input (a library's error
/// text, clap's), where the token cannot be wrapped at the source.
pub fn sanitize_message(message: &str) -> String {
    let mut out = String::with_capacity(message.len().min(4096));
    let mut rest = message;
    while !rest.is_empty() {
        // Split off the next line (keeping the newline out of the escaping).
        let (line, tail) = match rest.find('\n') {
            Some(i) => (&rest[..i], Some(&rest[i + 1..])),
            None => (rest, None),
        };
        let mut first = true;
        for word in line.split(' ') {
            if !first {
                out.push(' ');
            }
            first = false;
            // Writing to a String cannot fail.
            let _ = write_bounded(&mut out, word, MAX_MESSAGE_WORD_CHARS);
        }
        match tail {
            Some(t) => {
                out.push('\n');
                rest = t;
            }
            None => rest = "",
        }
    }
    out
}

/// Checks that `path` is a regular file (not a FIFO, socket, device or directory, whose
/// reading could block forever or never end) of at most `max_bytes`, before it is opened;
/// returns its size. The error (kind `InvalidInput` for what the file is, else the I/O error)
/// does not repeat the path: the caller names it.
pub fn check_regular_file(path: &std::path::Path, max_bytes: u64) -> std::io::Result<u64> {
    use std::io::{Error, ErrorKind};
    let meta = std::fs::metadata(path)?;
    let ft = meta.file_type();
    if !ft.is_file() {
        let what = if ft.is_dir() {
            "a directory"
        } else {
            kind_of_special(&ft)
        };
        return Err(Error::new(
            ErrorKind::InvalidInput,
            format!("it is {what}, not a regular file"),
        ));
    }
    if meta.len() > max_bytes {
        return Err(Error::new(
            ErrorKind::InvalidInput,
            format!(
                "it is {} bytes, more than the {max_bytes} accepted",
                meta.len()
            ),
        ));
    }
    Ok(meta.len())
}

/// The text of `path` after [`check_regular_file`] (same errors, and those of reading it as
/// UTF-8): how every bounded input file of text is read.
pub fn read_text_file(path: &std::path::Path, max_bytes: u64) -> std::io::Result<String> {
    check_regular_file(path, max_bytes)?;
    std::fs::read_to_string(path)
}

#[cfg(unix)]
fn kind_of_special(ft: &std::fs::FileType) -> &'static str {
    use std::os::unix::fs::FileTypeExt;
    if ft.is_fifo() {
        "a FIFO (named pipe)"
    } else if ft.is_socket() {
        "a socket"
    } else if ft.is_block_device() || ft.is_char_device() {
        "a device"
    } else {
        "a special file"
    }
}

#[cfg(not(unix))]
fn kind_of_special(_: &std::fs::FileType) -> &'static str {
    "a special file"
}

/// Most attributes of one XML element. The XML parser checks each attribute against every
/// earlier one of its element (quadratic: 100 000 attributes took a minute of CPU); real files
/// have at most a few tens (a GenICam description's root element about 15).
pub const MAX_XML_ATTRIBUTES: usize = 256;

/// Refuses XML whose elements nest deeper than `max_depth` or have more than
/// [`MAX_XML_ATTRIBUTES`] attributes, scanning the text once, without
/// recursion (comments, CDATA sections, processing instructions and quoted attribute values
/// are skipped). A document type declaration is refused: none of the formats we read uses one,
/// and its entities could hide markup from this scan. Not a validator: malformed XML is left
/// for the real parser to report.
pub fn check_xml_nesting(text: &str, max_depth: usize) -> Result<(), String> {
    let b = text.as_bytes();
    let find = |from: usize, pat: &[u8]| -> usize {
        b[from.min(b.len())..]
            .windows(pat.len())
            .position(|w| w == pat)
            .map_or(b.len(), |p| from + p + pat.len())
    };
    let mut depth = 0usize;
    let mut i = 0;
    while i < b.len() {
        if b[i] != b'<' {
            i += 1;
            continue;
        }
        let rest = &b[i..];
        if rest.starts_with(b"<!--") {
            i = find(i + 4, b"-->");
        } else if rest.starts_with(b"<![CDATA[") {
            i = find(i + 9, b"]]>");
        } else if rest.starts_with(b"<?") {
            i = find(i + 2, b"?>");
        } else if rest.starts_with(b"<!") {
            return Err(
                "it has a document type declaration (<!DOCTYPE …>), which is not supported".into(),
            );
        } else if rest.starts_with(b"</") {
            depth = depth.saturating_sub(1);
            i = find(i + 2, b">");
        } else {
            // A start tag: to its `>`, past quoted attribute values.
            let mut j = i + 1;
            let mut quote = None;
            let mut attributes = 0usize;
            while j < b.len() {
                match (quote, b[j]) {
                    (None, b'"' | b'\'') => quote = Some(b[j]),
                    (Some(q), c) if c == q => quote = None,
                    (None, b'>') => break,
                    (None, b'=') => attributes += 1,
                    _ => {}
                }
                j += 1;
            }
            if attributes > MAX_XML_ATTRIBUTES {
                return Err(format!(
                    "an element has {attributes} attributes (line {}), more than the \
                     {MAX_XML_ATTRIBUTES} accepted; no valid file has that many",
                    1 + b[..i].iter().filter(|&&c| c == b'\n').count()
                ));
            }
            let self_closing = j > i + 1 && j < b.len() && b[j - 1] == b'/';
            if !self_closing {
                depth += 1;
                if depth > max_depth {
                    return Err(format!(
                        "elements are nested more than {max_depth} deep (line {}); no valid file nests that deep",
                        1 + b[..i].iter().filter(|&&c| c == b'\n').count()
                    ));
                }
            }
            i = j + 1;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn durations_are_checked_not_panicking() {
        assert_eq!(
            duration_from_secs("--timeout-s", 1.5, 0.0, 10.0),
            Ok(Duration::from_millis(1500))
        );
        assert!(duration_from_secs("--x", 1e300, 0.0, f64::MAX).is_err());
        for bad in [1e300, -1.0, f64::NAN, f64::INFINITY, 11.0] {
            let e = duration_from_secs("--timeout-s", bad, 0.0, 10.0).expect_err("refused");
            assert!(
                e.starts_with("--timeout-s = ") && e.contains("seconds"),
                "{e}"
            );
        }
    }

    #[test]
    fn ranges_name_the_flag_the_unit_and_why() {
        assert_eq!(check_range("--x", 0.5, 0.0, 1.0, "m", ""), Ok(0.5));
        let e = check_range(
            "noise.depth_sigma_at_1m_m",
            -1.0,
            0.0,
            0.05,
            "m",
            "a camera",
        )
        .expect_err("negative");
        assert_eq!(
            e,
            "noise.depth_sigma_at_1m_m = -1.0: expected 0 <= value <= 0.05 m (a camera)"
        );
        assert!(check_range("--x", f64::NAN, 0.0, 1.0, "", "").is_err());
    }

    #[test]
    fn quoted_tokens_are_bounded_and_escaped() {
        let long = "x".repeat(10_000_000);
        let shown = Quoted(&long).to_string();
        assert!(shown.len() < 200, "{}", shown.len());
        assert!(shown.ends_with("… (9999920 more bytes)"), "{shown}");
        assert_eq!(Quoted("a\u{1b}[31mb\n").to_string(), "a\\u{1b}[31mb\\n");
        assert_eq!(Quoted("a\u{202e}b").to_string(), "a\\u{202e}b");
        let msg = format!("error: invalid value '{long}\u{1b}[2J' for '--joints'\n\nFor more");
        let clean = sanitize_message(&msg);
        assert!(clean.len() < 1200 && !clean.contains('\u{1b}'), "{clean}");
        // Real paths stay whole.
        let path = format!("/tmp/{}/scan.ply", "d".repeat(300));
        assert_eq!(sanitize_message(&path), path);
        assert!(clean.ends_with("for '--joints'\n\nFor more"), "{clean}");
    }

    #[test]
    fn xml_nesting_is_bounded_without_recursion() {
        let ok = "<?xml version=\"1.0\"?><!-- <a><a><a> --><r a=\"x>y\"><b/><c><![CDATA[<d><d>]]></c></r>";
        assert_eq!(check_xml_nesting(ok, 2), Ok(()));
        assert!(check_xml_nesting(ok, 1).is_err());
        let n = 1_000_000;
        let deep = format!("{}{}", "<a>".repeat(n), "</a>".repeat(n));
        let e = check_xml_nesting(&deep, MAX_XML_DEPTH).expect_err("too deep");
        assert!(e.contains("more than 128 deep"), "{e}");
        // Siblings do not add up.
        let wide = format!("<r>{}</r>", "<a><b/></a>".repeat(100_000));
        assert_eq!(check_xml_nesting(&wide, 3), Ok(()));
        assert!(check_xml_nesting("<!DOCTYPE r [<!ENTITY e \"<a>\">]><r/>", 8).is_err());
        // Unterminated constructs end the scan instead of looping.
        for t in ["<", "<a", "<!--", "<a b=\"", "</", "<?x"] {
            assert!(check_xml_nesting(t, 8).is_ok(), "{t}");
        }
    }

    /// Issue 46: an element with 100 000 attributes (1.1 MB) is refused at once, in one linear
    /// scan (the parser's duplicate check made it a minute of CPU); `=` inside quoted values
    /// does not count.
    #[test]
    fn issue_46_elements_with_absurd_attribute_counts_are_refused_fast() {
        let many: String = (0..100_000).map(|i| format!(" a{i}=\"1\"")).collect();
        let xml = format!("<?xml version=\"1.0\"?>\n<r{many}/>");
        assert!(xml.len() > 1_000_000);
        let t = std::time::Instant::now();
        let e = check_xml_nesting(&xml, MAX_XML_DEPTH).expect_err("too many");
        assert!(
            t.elapsed() < std::time::Duration::from_millis(500),
            "{:?}",
            t.elapsed()
        );
        assert!(
            e.contains("an element has 100000 attributes (line 2)"),
            "{e}"
        );
        let ok: String = (0..MAX_XML_ATTRIBUTES)
            .map(|i| format!(" a{i}='x=y'"))
            .collect();
        assert_eq!(check_xml_nesting(&format!("<r{ok}/>"), 8), Ok(()));
    }
}
