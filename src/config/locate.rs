//! Where a key sits in a TOML text: dotted key paths ↔ byte offsets ↔ lines, so that every
//! configuration error names the key and its line.
//!
//! toml 0.8 reports byte spans but not which key a span belongs to, and nothing after parsing
//! knows where a value came from; this small scanner fills both gaps. It understands the TOML a
//! parser has already accepted (tables, arrays of tables, dotted and quoted keys, inline tables,
//! arrays, every string form, comments) and stops quietly at anything it does not follow, so a
//! message can lose its key path but never its line.

use std::collections::HashMap;

/// One key (or table header, or array element) and the bytes it covers.
#[derive(Debug, Clone)]
struct Entry {
    /// Dotted path; array elements and arrays of tables carry a 0-based `[i]`
    /// (`views.joints[1]`, `views.obstacles[0].size_m`).
    path: String,
    /// First byte of the key (or of the header's `[`, or of the element).
    start: usize,
    /// First byte of the value (the header's `[` for tables).
    value_start: usize,
    /// One past the last byte of the value (of the header's `]`).
    end: usize,
    /// Whether this is a `[table]` / `[[table]]` header.
    header: bool,
}

/// The keys of one TOML text with their positions.
#[derive(Debug, Clone)]
pub(super) struct KeyIndex {
    entries: Vec<Entry>,
    line_starts: Vec<usize>,
}

impl KeyIndex {
    /// Scans `text` (best effort: keys after something the scanner does not follow are missing).
    pub(super) fn new(text: &str) -> Self {
        let mut s = Scanner {
            b: text.as_bytes(),
            i: 0,
            entries: Vec::new(),
            depth: 0,
        };
        // `None` only means the scanner stopped early; what it found so far is still right.
        let _ = s.document();
        let line_starts = std::iter::once(0)
            .chain(text.match_indices('\n').map(|(i, _)| i + 1))
            .collect();
        KeyIndex {
            entries: s.entries,
            line_starts,
        }
    }

    /// 1-based line of a byte offset.
    pub(super) fn line_at(&self, offset: usize) -> usize {
        self.line_starts.partition_point(|&s| s <= offset).max(1)
    }

    /// 1-based column of a byte offset.
    pub(super) fn column_at(&self, offset: usize) -> usize {
        let line = self.line_at(offset);
        offset - self.line_starts[line - 1] + 1
    }

    /// The innermost key whose key or value covers `offset`.
    pub(super) fn path_at(&self, offset: usize) -> Option<&str> {
        self.entries
            .iter()
            .filter(|e| e.start <= offset && offset < e.end.max(e.start + 1))
            .min_by_key(|e| e.end - e.start)
            .map(|e| e.path.as_str())
    }

    /// The table whose header or inline value starts exactly at `offset` (toml reports a
    /// missing key with the span of its table); `None` for the top level.
    pub(super) fn table_starting_at(&self, offset: usize) -> Option<&str> {
        self.entries
            .iter()
            .find(|e| (e.header && e.start == offset) || (!e.header && e.value_start == offset))
            .map(|e| e.path.as_str())
    }

    /// 1-based line where `path` is written (a key, an element, or a table header).
    pub(super) fn line_of(&self, path: &str) -> Option<usize> {
        self.entries
            .iter()
            .find(|e| e.path == path)
            .map(|e| self.line_at(e.start))
    }
}

struct Scanner<'a> {
    b: &'a [u8],
    i: usize,
    entries: Vec<Entry>,
    /// Arrays and inline tables open around the current value.
    depth: usize,
}

/// Deepest nesting of arrays and inline tables the locator follows (a configuration nests two
/// or three; beyond this the locator stops and the TOML parser reports the file).
const MAX_NESTING: usize = 64;

fn join(prefix: &str, key: &str) -> String {
    if prefix.is_empty() {
        key.to_string()
    } else {
        format!("{prefix}.{key}")
    }
}

impl Scanner<'_> {
    fn peek(&self) -> Option<u8> {
        self.b.get(self.i).copied()
    }

    fn starts_with(&self, s: &[u8]) -> bool {
        self.b[self.i.min(self.b.len())..].starts_with(s)
    }

    /// Spaces and tabs.
    fn blank(&mut self) {
        while matches!(self.peek(), Some(b' ' | b'\t')) {
            self.i += 1;
        }
    }

    /// Spaces, tabs, newlines and comments.
    fn space(&mut self) {
        loop {
            match self.peek() {
                Some(b' ' | b'\t' | b'\r' | b'\n') => self.i += 1,
                Some(b'#') => {
                    while !matches!(self.peek(), None | Some(b'\n')) {
                        self.i += 1;
                    }
                }
                _ => return,
            }
        }
    }

    fn expect(&mut self, c: u8) -> Option<()> {
        (self.peek() == Some(c)).then(|| self.i += 1)
    }

    fn document(&mut self) -> Option<()> {
        let mut table = String::new();
        let mut arrays: HashMap<String, usize> = HashMap::new();
        loop {
            self.space();
            match self.peek() {
                None => return Some(()),
                Some(b'[') => {
                    let start = self.i;
                    let array = self.starts_with(b"[[");
                    self.i += if array { 2 } else { 1 };
                    let name = self.key()?.join(".");
                    self.blank();
                    self.expect(b']')?;
                    if array {
                        self.expect(b']')?;
                        let n = arrays.entry(name.clone()).or_insert(0);
                        table = format!("{name}[{n}]");
                        *n += 1;
                    } else {
                        table = name;
                    }
                    self.entries.push(Entry {
                        path: table.clone(),
                        start,
                        value_start: start,
                        end: self.i,
                        header: true,
                    });
                }
                Some(_) => self.key_value(&table)?,
            }
        }
    }

    fn key_value(&mut self, prefix: &str) -> Option<()> {
        let start = self.i;
        let path = join(prefix, &self.key()?.join("."));
        self.blank();
        self.expect(b'=')?;
        self.blank();
        let value_start = self.i;
        self.value(&path)?;
        self.entries.push(Entry {
            path,
            start,
            value_start,
            end: self.i,
            header: false,
        });
        Some(())
    }

    /// A possibly dotted key; quoted parts are taken verbatim (escapes are not decoded).
    fn key(&mut self) -> Option<Vec<String>> {
        let mut parts = Vec::new();
        loop {
            self.blank();
            let part = match self.peek()? {
                b'"' | b'\'' => {
                    let s = self.i + 1;
                    self.string()?;
                    // The closing quote is at `i - 1`.
                    String::from_utf8_lossy(&self.b[s..self.i - 1]).into_owned()
                }
                c if c.is_ascii_alphanumeric() || c == b'_' || c == b'-' => {
                    let s = self.i;
                    while matches!(self.peek(), Some(c) if c.is_ascii_alphanumeric() || c == b'_' || c == b'-')
                    {
                        self.i += 1;
                    }
                    String::from_utf8_lossy(&self.b[s..self.i]).into_owned()
                }
                _ => return None,
            };
            parts.push(part);
            self.blank();
            if self.peek() == Some(b'.') {
                self.i += 1;
            } else {
                return Some(parts);
            }
        }
    }

    /// Any string form; leaves `i` after the closing delimiter.
    fn string(&mut self) -> Option<()> {
        let (delim, escapes): (&[u8], bool) = if self.starts_with(b"\"\"\"") {
            (b"\"\"\"", true)
        } else if self.starts_with(b"'''") {
            (b"'''", false)
        } else if self.starts_with(b"\"") {
            (b"\"", true)
        } else {
            (b"'", false)
        };
        self.i += delim.len();
        loop {
            if self.i >= self.b.len() {
                return None;
            }
            if escapes && self.b[self.i] == b'\\' {
                self.i += 2;
                continue;
            }
            if self.starts_with(delim) {
                self.i += delim.len();
                // A multi-line string may end with up to two extra quotes.
                if delim.len() == 3 {
                    while self.peek() == Some(delim[0]) {
                        self.i += 1;
                    }
                }
                return Some(());
            }
            self.i += 1;
        }
    }

    fn value(&mut self, path: &str) -> Option<()> {
        if self.depth >= MAX_NESTING {
            return None;
        }
        self.depth += 1;
        let found = self.nested_value(path);
        self.depth -= 1;
        found
    }

    fn nested_value(&mut self, path: &str) -> Option<()> {
        match self.peek()? {
            b'"' | b'\'' => self.string(),
            b'[' => {
                self.i += 1;
                let mut n = 0;
                loop {
                    self.space();
                    if self.peek()? == b']' {
                        self.i += 1;
                        return Some(());
                    }
                    let start = self.i;
                    let element = format!("{path}[{n}]");
                    self.value(&element)?;
                    self.entries.push(Entry {
                        path: element,
                        start,
                        value_start: start,
                        end: self.i,
                        header: false,
                    });
                    n += 1;
                    self.space();
                    if self.peek() == Some(b',') {
                        self.i += 1;
                    }
                }
            }
            b'{' => {
                self.i += 1;
                loop {
                    self.blank();
                    if self.peek()? == b'}' {
                        self.i += 1;
                        return Some(());
                    }
                    self.key_value(path)?;
                    self.blank();
                    if self.peek() == Some(b',') {
                        self.i += 1;
                    }
                }
            }
            _ => {
                // Numbers, booleans, dates: up to a delimiter (a date may hold one space).
                let s = self.i;
                while !matches!(
                    self.peek(),
                    None | Some(b',' | b']' | b'}' | b'#' | b'\n' | b'\r')
                ) {
                    self.i += 1;
                }
                while self.i > s && matches!(self.b[self.i - 1], b' ' | b'\t') {
                    self.i -= 1;
                }
                (self.i > s).then_some(())
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TEXT: &str = r#"# comment [not.a.table]
top = 1
[robot]
host = "10.0.0.2" # a "quoted" comment
"quoted key" = 'x'
limits.speed = 2
[robot.ports]
rtde = 30004
[views]
joints = [
  [0, 1, 2, 3, 4, 5], # first
  [0, 1, 2, 3, "x", 5],
]
text = """a ] "" b"""
inline = { a = 1, b = { c = [1, 2] } }
[[views.obstacles]]
name = "a"
[[views.obstacles]]
name = "b"
size_m = [1, 2, 3]
"#;

    #[test]
    fn keys_map_to_lines_and_back() {
        let ix = KeyIndex::new(TEXT);
        let line = |p: &str| ix.line_of(p);
        assert_eq!(line("top"), Some(2));
        assert_eq!(line("robot"), Some(3));
        assert_eq!(line("robot.host"), Some(4));
        assert_eq!(line("robot.quoted key"), Some(5));
        assert_eq!(line("robot.limits.speed"), Some(6));
        assert_eq!(line("robot.ports.rtde"), Some(8));
        assert_eq!(line("views.joints"), Some(10));
        assert_eq!(line("views.joints[1]"), Some(12));
        assert_eq!(line("views.text"), Some(14));
        assert_eq!(line("views.inline.b.c[1]"), Some(15));
        assert_eq!(line("views.obstacles[0].name"), Some(17));
        assert_eq!(line("views.obstacles[1].size_m"), Some(20));
        assert_eq!(line("views.obstacles[1].size_m[2]"), Some(20));
        assert_eq!(line("not.a.table"), None);

        let x = TEXT.find("\"x\", 5").expect("x");
        assert_eq!(ix.path_at(x), Some("views.joints[1][4]"));
        assert_eq!(ix.line_at(x), 12);
        assert_eq!(ix.column_at(x), 16);
        let rtde = TEXT.find("rtde").expect("rtde");
        assert_eq!(ix.path_at(rtde), Some("robot.ports.rtde"));
        let header = TEXT.find("[robot.ports]").expect("header");
        assert_eq!(ix.table_starting_at(header), Some("robot.ports"));
        assert_eq!(ix.table_starting_at(0), None);
    }
}
