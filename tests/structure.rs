//! The house rules of the workspace's code, checked on the tree (issue 45): no function over
//! 80 lines and no file over 900 lines in any crate's `src/` (tests excluded: `#[cfg(test)]`
//! modules and `tests.rs` files), no import cycle between the top-level modules of a crate,
//! `anyhow` and `clap` in the CLI package only, and the Python bindings' signatures shown to
//! `help()` with their defaults.
//!
//! Lines are counted from a function's signature to its closing brace, by brace matching on the
//! text with comments, strings and character literals blanked (so a `{` in a string does not
//! count). A module's imports are the `crate::m` paths (and `super::m` at the top level) of its
//! files.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The longest function allowed (lines).
const MAX_FUNCTION_LINES: usize = 80;
/// The longest file allowed (lines, tests excluded).
const MAX_FILE_LINES: usize = 900;

/// Each crate's source folder, relative to the workspace root.
const CRATES: [&str; 7] = [
    "core/src",
    "solvers/src",
    "facade/src",
    "src",
    "ffi/ceres-sys/src",
    "ffi/python/src",
    "benchmarks/src",
];

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Every `.rs` file under `dir` that is not a test file.
fn sources(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        let Ok(entries) = std::fs::read_dir(&d) else {
            continue;
        };
        for e in entries.flatten() {
            let p = e.path();
            if p.is_dir() {
                if p.file_name().is_some_and(|n| n != "tests") {
                    stack.push(p);
                }
            } else if p.extension().is_some_and(|x| x == "rs")
                && p.file_name().is_some_and(|n| n != "tests.rs")
            {
                out.push(p);
            }
        }
    }
    out.sort();
    out
}

/// `text` with comments, string and character literals blanked (line breaks kept).
fn strip(text: &str) -> String {
    let c: Vec<char> = text.chars().collect();
    let mut out = String::with_capacity(text.len());
    let mut i = 0;
    let keep_newlines = |s: &[char], out: &mut String| {
        out.extend(s.iter().filter(|&&ch| ch == '\n'));
    };
    while i < c.len() {
        let rest = &c[i..];
        if rest.starts_with(&['/', '/']) {
            while i < c.len() && c[i] != '\n' {
                i += 1;
            }
        } else if rest.starts_with(&['/', '*']) {
            let end = find(&c, i + 2, &['*', '/']).map_or(c.len(), |e| e + 2);
            keep_newlines(&c[i..end], &mut out);
            i = end;
        } else if let Some(hashes) = raw_string_at(&c, i) {
            let mut close = vec!['"'];
            close.extend(std::iter::repeat_n('#', hashes));
            let start = i + 2 + hashes;
            let end = find(&c, start, &close).map_or(c.len(), |e| e + close.len());
            out.push_str("\"\"");
            keep_newlines(&c[i..end], &mut out);
            i = end;
        } else if c[i] == '"' {
            let mut j = i + 1;
            while j < c.len() && c[j] != '"' {
                j += if c[j] == '\\' { 2 } else { 1 };
            }
            out.push_str("\"\"");
            keep_newlines(&c[i..j.min(c.len())], &mut out);
            i = j + 1;
        } else if c[i] == '\'' && char_literal_len(&c, i).is_some() {
            out.push_str("' '");
            i += char_literal_len(&c, i).unwrap_or(1);
        } else {
            out.push(c[i]);
            i += 1;
        }
    }
    out
}

/// The index of the next `pat` in `c` from `from`.
fn find(c: &[char], from: usize, pat: &[char]) -> Option<usize> {
    (from..c.len()).find(|&k| c[k..].starts_with(pat))
}

/// The number of `#` of a raw string starting at `i` (`r"`, `r#"` …), if one does.
fn raw_string_at(c: &[char], i: usize) -> Option<usize> {
    if c[i] != 'r' || (i > 0 && (c[i - 1].is_alphanumeric() || c[i - 1] == '_')) {
        return None;
    }
    let hashes = c[i + 1..].iter().take_while(|&&ch| ch == '#').count();
    (c.get(i + 1 + hashes) == Some(&'"')).then_some(hashes)
}

/// The length of a character literal at `i` (`'a'`, `'\n'`, `'\u{2014}'`), not a lifetime.
fn char_literal_len(c: &[char], i: usize) -> Option<usize> {
    if c.get(i + 1) == Some(&'\\') {
        let end = (i + 2..c.len().min(i + 12)).find(|&k| c[k] == '\'')?;
        return Some(end - i + 1);
    }
    (c.get(i + 2) == Some(&'\'')).then_some(3)
}

/// The line after the block that starts at line `start` (its `{` on that line or later).
fn block_end(lines: &[&str], start: usize) -> usize {
    let mut depth = 0i64;
    let mut opened = false;
    for (k, l) in lines.iter().enumerate().skip(start) {
        depth += l.matches('{').count() as i64 - l.matches('}').count() as i64;
        opened |= l.contains('{');
        if opened && depth <= 0 {
            return k + 1;
        }
        if !opened && l.trim_end().ends_with(';') {
            return k + 1;
        }
    }
    lines.len()
}

/// The line ranges of `#[cfg(test)]` items.
fn test_ranges(lines: &[&str]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut k = 0;
    while k < lines.len() {
        if lines[k].trim_start().starts_with("#[cfg(test)]") {
            let end = block_end(lines, k + 1);
            out.push((k, end));
            k = end;
        } else {
            k += 1;
        }
    }
    out
}

/// Whether `line` starts a function (`fn`, `pub fn`, `pub(crate) const fn` …): its name.
fn fn_name(line: &str) -> Option<&str> {
    let mut words = line.split_whitespace().peekable();
    while let Some(w) = words.next() {
        match w {
            "fn" => {
                let name = words.next()?;
                let end = name
                    .find(|ch: char| !(ch.is_alphanumeric() || ch == '_'))
                    .unwrap_or(name.len());
                return Some(&name[..end]);
            }
            "pub" | "const" | "async" | "unsafe" | "extern" | "\"\"" => {}
            w if w.starts_with("pub(") => {}
            _ => return None,
        }
    }
    None
}

/// The functions of a stripped file over `max` lines: (name, first line, length).
fn long_functions(text: &str, max: usize) -> Vec<(String, usize, usize)> {
    let lines: Vec<&str> = text.lines().collect();
    let tests = test_ranges(&lines);
    let mut out = Vec::new();
    for (k, l) in lines.iter().enumerate() {
        if tests.iter().any(|&(a, b)| (a..b).contains(&k)) {
            continue;
        }
        if let Some(name) = fn_name(l) {
            let end = block_end(&lines, k);
            // A declaration without a body (a trait's) ends on its own line.
            if end - k > max && lines[k..end].iter().any(|x| x.contains('{')) {
                out.push((name.to_string(), k + 1, end - k));
            }
        }
    }
    out
}

/// The lines of a stripped file outside its tests.
fn non_test_lines(text: &str) -> usize {
    let lines: Vec<&str> = text.lines().collect();
    let tests: usize = test_ranges(&lines).iter().map(|(a, b)| b - a).sum();
    lines.len() - tests
}

/// The names the crate root re-exports (`pub use error::{Error, Result};` → `Error` → `error`),
/// so that `crate::Error` counts as an import of `error`.
fn reexports(src: &Path) -> BTreeMap<String, String> {
    let mut out = BTreeMap::new();
    for root in ["lib.rs", "main.rs"] {
        let text = strip(&std::fs::read_to_string(src.join(root)).unwrap_or_default());
        for statement in text.split(';') {
            let s = statement.trim();
            let Some(path) = s
                .strip_prefix("pub use ")
                .or_else(|| s.strip_prefix("pub(crate) use "))
                .or_else(|| s.strip_prefix("use "))
            else {
                continue;
            };
            let Some((module, rest)) = path.split_once("::") else {
                continue;
            };
            let names = rest.trim_start_matches('{').trim_end_matches('}');
            for name in names.split(',') {
                let name = name.split(" as ").last().unwrap_or(name).trim();
                let name = name.rsplit("::").next().unwrap_or(name);
                if !name.is_empty() {
                    out.insert(name.to_string(), module.trim().to_string());
                }
            }
        }
    }
    out
}

/// The module path of a file of `src` (`a/b.rs` → `[a, b]`, `a/mod.rs` and `a.rs` → `[a]`, the
/// crate root → `[]`).
fn module_path(src: &Path, file: &Path) -> Vec<String> {
    let rel = file.strip_prefix(src).unwrap_or(file);
    let mut path: Vec<String> = rel
        .components()
        .filter_map(|c| c.as_os_str().to_str())
        .map(|c| c.trim_end_matches(".rs").to_string())
        .collect();
    if matches!(
        path.last().map(String::as_str),
        Some("mod") | Some("lib") | Some("main")
    ) {
        path.pop();
    }
    path
}

/// The paths `text` names after `crate::`, `super::` and `self::` (resolved against `me`, the
/// file's module path), as module paths (identifiers only; a `{…}` group expands one level).
fn referenced(text: &str, me: &[String]) -> Vec<Vec<String>> {
    let mut out = Vec::new();
    let here = me.to_vec();
    let parent = me[..me.len().saturating_sub(1)].to_vec();
    for (prefix, base) in [
        ("crate::", Vec::new()),
        ("super::", parent),
        ("self::", here),
    ] {
        for (i, _) in text.match_indices(prefix) {
            if text[..i]
                .chars()
                .next_back()
                .is_some_and(|ch| ch.is_alphanumeric() || ch == '_' || ch == ':')
            {
                continue;
            }
            let rest = &text[i + prefix.len()..];
            let mut path = base.clone();
            let mut tail = rest;
            loop {
                let end = tail
                    .find(|ch: char| !(ch.is_alphanumeric() || ch == '_'))
                    .unwrap_or(tail.len());
                if end == 0 {
                    break;
                }
                path.push(tail[..end].to_string());
                tail = &tail[end..];
                match tail.strip_prefix("::") {
                    Some(t) => tail = t,
                    None => break,
                }
            }
            if let Some(group) = tail.strip_prefix('{') {
                let group = &group[..group.find('}').unwrap_or(group.len())];
                for item in group.split(',') {
                    let item = item.trim();
                    let end = item
                        .find(|ch: char| !(ch.is_alphanumeric() || ch == '_'))
                        .unwrap_or(item.len());
                    let mut p = path.clone();
                    p.push(item[..end].to_string());
                    out.push(p);
                }
            } else {
                out.push(path);
            }
        }
    }
    out
}

/// The import graphs between the sibling modules of a crate (files and folders with the same
/// parent module), keyed by the parent's path (tests excluded). A module's own children and its
/// parent are not edges: Rust declares children in their parent.
fn module_graphs(src: &Path) -> BTreeMap<Vec<String>, BTreeMap<String, BTreeSet<String>>> {
    let files = sources(src);
    let paths: BTreeSet<Vec<String>> = files.iter().map(|f| module_path(src, f)).collect();
    let reexported = reexports(src);
    let mut graphs: BTreeMap<Vec<String>, BTreeMap<String, BTreeSet<String>>> = BTreeMap::new();
    for f in &files {
        let me = module_path(src, f);
        let text = strip(&std::fs::read_to_string(f).unwrap_or_default());
        let lines: Vec<&str> = text.lines().collect();
        let tests = test_ranges(&lines);
        let kept: String = lines
            .iter()
            .enumerate()
            .filter(|(k, _)| !tests.iter().any(|&(a, b)| (a..b).contains(k)))
            .map(|(_, l)| format!("{l}\n"))
            .collect();
        for mut target in referenced(&kept, &me) {
            // `crate::Name` re-exported by the root names the module it comes from.
            if let Some(m) = target.first().and_then(|n| reexported.get(n))
                && !paths.contains(&target[..1])
            {
                target = vec![m.clone()];
            }
            // The longest module path the reference names.
            while !target.is_empty() && !paths.contains(&target) {
                target.pop();
            }
            let common = me.iter().zip(&target).take_while(|(a, b)| a == b).count();
            if common < me.len() && common < target.len() {
                graphs
                    .entry(me[..common].to_vec())
                    .or_default()
                    .entry(me[common].clone())
                    .or_default()
                    .insert(target[common].clone());
            }
        }
    }
    graphs
}

/// The cycles of `graph` (its strongly connected components of more than one module).
fn cycles(graph: &BTreeMap<String, BTreeSet<String>>) -> Vec<Vec<String>> {
    // Two modules are in one cycle when each reaches the other.
    let reach = |from: &String| {
        let mut seen = BTreeSet::new();
        let mut stack = vec![from.clone()];
        while let Some(m) = stack.pop() {
            for n in graph.get(&m).into_iter().flatten() {
                if seen.insert(n.clone()) {
                    stack.push(n.clone());
                }
            }
        }
        seen
    };
    let reached: BTreeMap<&String, BTreeSet<String>> =
        graph.keys().map(|m| (m, reach(m))).collect();
    let mut out: Vec<Vec<String>> = Vec::new();
    for m in graph.keys() {
        let mut cycle: Vec<String> = graph
            .keys()
            .filter(|n| reached[m].contains(*n) && reached[*n].contains(m))
            .cloned()
            .collect();
        if cycle.len() > 1 && !out.contains(&cycle) {
            cycle.sort();
            out.push(cycle);
        }
    }
    out
}

#[test]
fn no_function_over_80_lines_and_no_file_over_900() {
    let mut found = Vec::new();
    for dir in CRATES {
        let src = root().join(dir);
        for f in sources(&src) {
            let text = strip(&std::fs::read_to_string(&f).unwrap());
            let rel = f.strip_prefix(root()).unwrap().display().to_string();
            for (name, line, n) in long_functions(&text, MAX_FUNCTION_LINES) {
                found.push(format!("{rel}:{line}: fn {name} has {n} lines"));
            }
            let n = non_test_lines(&text);
            if n > MAX_FILE_LINES {
                found.push(format!("{rel}: {n} lines (tests excluded)"));
            }
        }
    }
    assert!(
        found.is_empty(),
        "over {MAX_FUNCTION_LINES} lines a function or {MAX_FILE_LINES} a file:\n{}",
        found.join("\n")
    );
}

#[test]
fn no_import_cycle_between_the_modules_of_a_crate() {
    let mut found = Vec::new();
    for dir in CRATES {
        for (parent, graph) in module_graphs(&root().join(dir)) {
            for cycle in cycles(&graph) {
                let within = if parent.is_empty() {
                    String::new()
                } else {
                    format!(" (in {})", parent.join("::"))
                };
                found.push(format!("{dir}{within}: {}", cycle.join(" ↔ ")));
            }
        }
    }
    assert!(found.is_empty(), "import cycles:\n{}", found.join("\n"));
}

#[test]
fn anyhow_and_clap_only_in_the_cli() {
    for dir in CRATES.iter().filter(|d| **d != "src") {
        let manifest = root().join(dir).parent().unwrap().join("Cargo.toml");
        let text = std::fs::read_to_string(&manifest).unwrap();
        let deps: toml::Table = toml::from_str(&text).unwrap();
        for section in ["dependencies", "build-dependencies"] {
            let Some(t) = deps.get(section).and_then(|v| v.as_table()) else {
                continue;
            };
            for banned in ["anyhow", "clap", "ctrlc"] {
                assert!(
                    !t.contains_key(banned),
                    "{}: [{section}] has {banned}, which only the CLI package may use",
                    manifest.display()
                );
            }
        }
    }
}

/// The parameter names of a Python signature's text `(a, b=1, *, c='x')` or of PyO3's
/// `signature = (a, b=1, *, c="x".to_string())`: each top-level comma-separated item up to its
/// `=`, the `*` marker kept.
fn signature_names(sig: &str) -> Vec<String> {
    let sig = sig.trim();
    let inner = sig.strip_prefix('(').unwrap_or(sig);
    let inner = inner.strip_suffix(')').unwrap_or(inner);
    let (mut names, mut depth, mut item) = (Vec::new(), 0i32, String::new());
    for ch in inner.chars().chain(std::iter::once(',')) {
        match ch {
            '(' | '[' => depth += 1,
            ')' | ']' => depth -= 1,
            ',' if depth == 0 => {
                let name = item.split('=').next().unwrap_or("").trim().to_string();
                if !name.is_empty() {
                    names.push(name);
                }
                item.clear();
                continue;
            }
            _ => {}
        }
        item.push(ch);
    }
    names
}

/// Each `#[pyo3(signature = (…), text_signature = "(…)")]` of the Python bindings: (file:line,
/// the signature, the text signature or None).
fn python_signatures() -> Vec<(String, String, Option<String>)> {
    let mut out = Vec::new();
    for file in sources(&root().join("ffi/python/src")) {
        let text = std::fs::read_to_string(&file).unwrap();
        for (i, line) in text.lines().enumerate() {
            let Some(rest) = line.trim().strip_prefix("#[pyo3(signature = ") else {
                continue;
            };
            let (sig, text_sig) = match rest.split_once(", text_signature = \"") {
                Some((sig, t)) => (sig, Some(t.trim_end_matches("\")]").to_string())),
                None => (rest.trim_end_matches(")]"), None),
            };
            out.push((
                format!("{}:{}", file.display(), i + 1),
                sig.to_string(),
                text_sig,
            ));
        }
    }
    out
}

#[test]
fn every_python_function_shows_its_defaults_to_help() {
    // PyO3 renders a default it cannot print (`"lm".to_string()`, `Vec::new()`, a constant) as
    // `...` in help() and inspect.signature; a text signature gives the Python spelling. It must
    // name the same parameters in the same order as the signature it describes.
    let found = python_signatures();
    assert!(
        found.len() >= 10,
        "only {} PyO3 signatures found",
        found.len()
    );
    for (at, sig, text_sig) in found {
        let text_sig =
            text_sig.unwrap_or_else(|| panic!("{at}: a signature without text_signature"));
        assert_eq!(
            signature_names(&sig),
            signature_names(&text_sig),
            "{at}: the text signature names other parameters than the signature"
        );
        assert!(
            !text_sig.contains("::") && !text_sig.contains("to_string") && !text_sig.contains('"'),
            "{at}: the text signature is not Python: {text_sig}"
        );
    }
}

// The checker itself: each rule must be able to fail.

#[test]
fn the_checker_finds_a_long_function_and_skips_tests_comments_and_strings() {
    let body = "    x += 1;\n".repeat(81);
    let long = format!("pub(crate) fn long(x: &mut i32) {{\n{body}}}\n");
    assert_eq!(
        long_functions(&strip(&long), 80),
        vec![("long".into(), 1, 83)]
    );
    // Braces in strings, chars and comments do not end the function early.
    let tricky = format!(
        "fn tricky() {{\n    let s = \"}}\"; let c = '}}'; // }}\n    /* }} */\n{body}}}\n"
    );
    assert_eq!(long_functions(&strip(&tricky), 80).len(), 1);
    let in_tests = format!("#[cfg(test)]\nmod tests {{\n{long}}}\n");
    assert!(long_functions(&strip(&in_tests), 80).is_empty());
    assert_eq!(non_test_lines(&strip(&in_tests)), 0);
    let short = "fn short() {\n    let r = r#\"{ not a brace\"#;\n}\n";
    assert!(long_functions(&strip(short), 80).is_empty());
}

#[test]
fn the_checker_finds_a_cycle() {
    let g: BTreeMap<String, BTreeSet<String>> = [
        ("a", vec!["b"]),
        ("b", vec!["c"]),
        ("c", vec!["a"]),
        ("d", vec!["a"]),
    ]
    .into_iter()
    .map(|(k, v)| (k.to_string(), v.into_iter().map(String::from).collect()))
    .collect();
    assert_eq!(
        cycles(&g),
        vec![vec!["a".to_string(), "b".into(), "c".into()]]
    );
    // A file `a/c.rs` naming its sibling `super::b` and the top-level `crate::d::{e, f}`.
    let me = vec!["a".to_string(), "c".to_string()];
    let text = "use super::b::x;\nuse crate::d::{e, f};\nlet y = self::g::h;";
    let want: Vec<Vec<&str>> = vec![
        vec!["d", "e"],
        vec!["d", "f"],
        vec!["a", "b", "x"],
        vec!["a", "c", "g", "h"],
    ];
    assert_eq!(referenced(text, &me), want);
}

#[test]
fn the_checker_reads_both_spellings_of_a_signature() {
    let rust = r#"(data, machine=None, *, engine="lm".to_string(), add=Vec::new(), t=f(1, 2))"#;
    let python = "(data, machine=None, *, engine='lm', add=(), t=3)";
    assert_eq!(
        signature_names(rust),
        ["data", "machine", "*", "engine", "add", "t"]
    );
    assert_eq!(signature_names(rust), signature_names(python));
    assert_ne!(
        signature_names(rust),
        signature_names("(data, *, engine='lm', add=(), t=3)")
    );
}
