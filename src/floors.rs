//! The floors (see the top of `lib.rs`) kept true: a module may use the modules on its own
//! floor and below, never above. Reads every `src/**/*.rs` the library builds (not the
//! binary's `main.rs` and `cli/`, not test code) and every `calib/src/**/*.rs` of the
//! calibration core, and fails naming each `crate::…` path that climbs. (That the core uses
//! nothing of this crate, Cargo checks: it does not depend on it.) The drivers' modules (and the UR simulator's) may not use each other in a
//! circle either.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The floors, lowest first; every top-level module of the library is on exactly one.
const FLOORS: &[&[&str]] = &[
    &["frames", "skips"],
    &["model", "cloud"],
    // The pinhole model and the ray caster.
    &["geometry"],
    &["sim"],
    &["calib", "plan", "bench"],
    // Above the calibration core (the crate `handeye-calib`): the service.
    &["camera", "lockfile"],
    &["record", "calendar"],
    &["config"],
    &["report", "guard"],
    &["storage", "store"],
    &["run"],
    &["daemon"],
];

fn floor(module: &str) -> Option<usize> {
    FLOORS.iter().position(|f| f.contains(&module))
}

/// The library's source files outside test code: `tests.rs`, `testutil.rs` and the files of
/// modules declared `#[cfg(test)] mod name;` are left out.
fn library_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let mut test_only = BTreeSet::new();
    let mut entries: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.expect("entry").path())
        .collect();
    entries.sort();
    for path in &entries {
        if path.extension().is_some_and(|x| x == "rs") {
            let text = std::fs::read_to_string(path).expect("source");
            let lines: Vec<&str> = text.lines().map(str::trim).collect();
            for w in lines.windows(2) {
                if let ("#[cfg(test)]", Some(name)) = (w[0], w[1].strip_prefix("mod ")) {
                    if let Some(name) = name.strip_suffix(';') {
                        test_only.insert(name.to_string());
                    }
                }
            }
        }
    }
    for path in entries {
        let stem = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        if test_only.contains(&stem) || stem == "tests" || stem == "testutil" {
            continue;
        }
        if path.is_dir() {
            library_files(&path, out);
        } else if path.extension().is_some_and(|x| x == "rs") {
            out.push(path);
        }
    }
}

/// The modules `text` names as `prefix name` (`crate::name`, or in `crate::{a, b::c}`) in
/// code, outside comments and the trailing `#[cfg(test)] mod … { … }`.
fn used_modules(text: &str, prefix: &str) -> BTreeSet<String> {
    let mut used = BTreeSet::new();
    let mut lines = text.lines().map(str::trim).peekable();
    while let Some(line) = lines.next() {
        if line == "#[cfg(test)]" && lines.peek().is_some_and(|l| l.ends_with('{')) {
            break;
        }
        if line.starts_with("//") {
            continue;
        }
        let code = line.split("//").next().unwrap_or("");
        for (i, _) in code.match_indices(prefix) {
            let rest = &code[i + prefix.len()..];
            let names: Vec<&str> = match rest.strip_prefix('{') {
                Some(group) => group
                    .split(['}', ','])
                    .map(|n| n.trim().split("::").next().unwrap_or(""))
                    .collect(),
                None => vec![rest],
            };
            for n in names {
                let name: String = n
                    .chars()
                    .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                    .collect();
                if !name.is_empty() {
                    used.insert(name);
                }
            }
        }
    }
    used
}

#[test]
fn no_floor_uses_a_higher_one() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut climbs = Vec::new();
    let mut seen = BTreeSet::new();
    for crate_src in ["src", "calib/src"] {
        let src = root.join(crate_src);
        let mut files = Vec::new();
        library_files(&src, &mut files);
        for file in &files {
            let rel = file.strip_prefix(&src).expect("under src");
            let top = rel
                .components()
                .next()
                .map(|c| {
                    c.as_os_str()
                        .to_string_lossy()
                        .trim_end_matches(".rs")
                        .to_string()
                })
                .unwrap_or_default();
            if matches!(top.as_str(), "main" | "cli" | "lib" | "floors") {
                continue;
            }
            let Some(own) = floor(&top) else {
                panic!(
                    "{crate_src}/{}: module `{top}` is on no floor; add it to FLOORS",
                    rel.display()
                );
            };
            seen.insert(top.clone());
            let text = std::fs::read_to_string(file).expect("source");
            for used in used_modules(&text, "crate::") {
                match floor(&used) {
                    Some(f) if f > own => climbs.push(format!(
                        "{crate_src}/{} ({top}, floor {own}) uses crate::{used} (floor {f})",
                        rel.display()
                    )),
                    _ => {}
                }
            }
        }
    }
    let every: BTreeSet<String> = FLOORS
        .iter()
        .flat_map(|f| f.iter())
        .map(|m| m.to_string())
        .collect();
    assert_eq!(seen, every, "read a module on no floor, or missed one");
    assert!(
        climbs.is_empty(),
        "lower floors use higher ones:\n{}",
        climbs.join("\n")
    );
}

#[test]
fn the_reader_finds_uses_and_skips_comments_and_tests() {
    let text = "use crate::calib::Mount;\n// crate::daemon in a comment\nuse crate::{frames, record::RunMode};\nlet x = crate::calendar::unix_now(); // crate::run\n#[cfg(test)]\nmod tests {\n    use crate::daemon;\n}\n";
    let used: Vec<String> = used_modules(text, "crate::").into_iter().collect();
    assert_eq!(used, ["calendar", "calib", "frames", "record"]);
    let graph = [("a", ["b"]), ("b", ["c"]), ("c", ["a"])]
        .map(|(m, u)| (m.to_string(), u.map(String::from).into_iter().collect()));
    assert_eq!(
        circle(&graph.into_iter().collect()),
        Some(vec!["a".into(), "b".into(), "c".into(), "a".into()])
    );
}

/// The modules of `dir` (its `.rs` files but `lib.rs`/`mod.rs`, and its folders) and which
/// siblings each names with `prefix` (`crate::` at a crate's root, `super::` below it).
fn sibling_graph(dir: &Path, prefix: &str) -> BTreeMap<String, BTreeSet<String>> {
    let mut modules = BTreeMap::new();
    for entry in std::fs::read_dir(dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display())) {
        let path = entry.expect("entry").path();
        let name = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        if matches!(name.as_str(), "lib" | "mod" | "main" | "tests" | "testutil") {
            continue;
        }
        let mut files = Vec::new();
        if path.is_dir() {
            library_files(&path, &mut files);
        } else if path.extension().is_some_and(|x| x == "rs") {
            files.push(path);
        } else {
            continue;
        }
        let used: BTreeSet<String> = files
            .iter()
            .flat_map(|f| used_modules(&std::fs::read_to_string(f).expect("source"), prefix))
            .filter(|u| *u != name)
            .collect();
        modules.insert(name, used);
    }
    let names: BTreeSet<String> = modules.keys().cloned().collect();
    for used in modules.values_mut() {
        used.retain(|u| names.contains(u));
    }
    modules
}

/// A circle in `graph` (as the path that closes it), if there is one.
fn circle(graph: &BTreeMap<String, BTreeSet<String>>) -> Option<Vec<String>> {
    fn visit(
        graph: &BTreeMap<String, BTreeSet<String>>,
        node: &str,
        path: &mut Vec<String>,
        done: &mut BTreeSet<String>,
    ) -> Option<Vec<String>> {
        if let Some(i) = path.iter().position(|p| p == node) {
            let mut c = path[i..].to_vec();
            c.push(node.to_string());
            return Some(c);
        }
        if done.contains(node) {
            return None;
        }
        path.push(node.to_string());
        for next in graph.get(node).into_iter().flatten() {
            if let Some(c) = visit(graph, next, path, done) {
                return Some(c);
            }
        }
        path.pop();
        done.insert(node.to_string());
        None
    }
    let mut done = BTreeSet::new();
    graph
        .keys()
        .find_map(|n| visit(graph, n, &mut Vec::new(), &mut done))
}

#[test]
fn no_circle_among_the_drivers_modules() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("drivers");
    for (dir, prefix) in [
        ("hal/src", "crate::"),
        ("ur/src", "crate::"),
        ("ur/src/sim", "super::"),
        ("gige/src", "crate::"),
    ] {
        let graph = sibling_graph(&root.join(dir), prefix);
        assert!(graph.len() >= 4, "{dir}: read too little: {graph:?}");
        if let Some(c) = circle(&graph) {
            panic!("drivers/{dir}: modules in a circle: {}", c.join(" → "));
        }
    }
}
