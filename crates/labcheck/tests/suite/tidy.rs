//! Tidy: checks on the repository's own text that no compiler makes.
//!
//! Walks every `.rs`, `.md`, `.ron` and `.toml` file of the repository (skipping build
//! output and hidden directories) and reports, as `file:line: message`:
//!
//! - comments and docs that cite an issue by its number (the word followed by a number
//!   or a list of numbers, or a hash followed by digits):
//!   an issue tracker is not part of the repository, so the text must say what it means;
//! - paths outside the repository: a parent-directory path into a sibling checkout
//!   (a sibling directory of the repository), an absolute path under the machine's work
//!   directory, or a relative
//!   link that climbs above the repository root;
//! - docs naming repository files that do not exist: a relative path to a `.rs`, `.md`,
//!   `.ron` or `.toml` file, in backticks, in a Markdown link, or written plainly under
//!   `crates/`, `docs/`, `scenes/` or `xtask/`;
//! - a Rust example of the README that is not, line for line, a doctest of some crate
//!   (its own test, `every_readme_example_is_a_doctest`).
//!
//! In Rust files only comments are read (code may build any string it likes); in RON and
//! TOML files only comments; Markdown is read whole, except fenced code blocks for the
//! issue rule (a shell command may contain `#`).

use std::fmt::Write as _;
use std::fs;
use std::path::{Component, Path, PathBuf};

/// The sibling checkout and the work directory a path must not point into. Spelled in
/// pieces so that this file does not contain what it looks for.
const SIBLING_CHECKOUT: &str = concat!("..", "/sha", "red");
const WORK_DIRECTORY: &str = concat!("/wo", "rk/");

/// A test fixture with the words this file looks for spelled in pieces: `{I}` is the
/// lower-case word, `{C}` the capitalised one, `{S}` the sibling checkout and `{W}` the
/// work directory, `{H}` a hash and `{L}` the shared workloads file's name.
#[cfg(test)]
fn fixture(text: &str) -> String {
    text.replace("{I}", concat!("iss", "ue"))
        .replace("{C}", concat!("Iss", "ue"))
        .replace("{S}", SIBLING_CHECKOUT)
        .replace("{W}", WORK_DIRECTORY)
        .replace("{H}", "#")
        .replace("{L}", concat!("WORK", "LOADS.md"))
}

/// Files not checked, each with the reason. Only genuine fixtures belong here.
const ALLOWED: &[(&str, &str)] = &[(
    "crates/labcheck/tests/suite/tidy.rs",
    "this file: its fixtures contain every pattern it looks for",
)];

/// One problem found, located.
#[derive(Debug, PartialEq)]
struct Finding {
    file: String,
    line: usize,
    message: String,
}

fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .ancestors()
        .nth(2)
        .expect("crates/labcheck sits two levels below the repository root")
        .to_path_buf()
}

/// Every checked file under `dir`, as paths relative to `root`, sorted.
fn walk(root: &Path, dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let path = entry.path();
        let name = entry.file_name();
        let name = name.to_string_lossy();
        if name.starts_with('.') || name == "target" || name == "node_modules" {
            continue;
        }
        if path.is_dir() {
            walk(root, &path, out);
        } else if matches!(
            path.extension().and_then(|e| e.to_str()),
            Some("rs" | "md" | "ron" | "toml")
        ) {
            out.push(path.strip_prefix(root).unwrap_or(&path).to_path_buf());
        }
    }
}

#[derive(Clone, Copy, PartialEq)]
enum Kind {
    Rust,
    Markdown,
    /// RON and TOML: only comments are prose. RON comments start with `//`, TOML with `#`.
    Ron,
    Toml,
}

fn kind_of(path: &Path) -> Kind {
    match path.extension().and_then(|e| e.to_str()) {
        Some("rs") => Kind::Rust,
        Some("md") => Kind::Markdown,
        Some("ron") => Kind::Ron,
        _ => Kind::Toml,
    }
}

/// The prose of one line (what the rules read), or `None` when the line has none.
fn prose(kind: Kind, line: &str, in_fence: bool) -> Option<&str> {
    match kind {
        Kind::Markdown => (!in_fence).then_some(line),
        Kind::Rust | Kind::Ron => line.find("//").map(|i| &line[i..]),
        Kind::Toml => {
            // A `#` inside a quoted string is not a comment; TOML strings here never hold one
            // together with a comment, so the first `#` outside quotes starts the comment.
            let mut quoted = false;
            for (i, c) in line.char_indices() {
                match c {
                    '"' => quoted = !quoted,
                    '#' if !quoted => return Some(&line[i + 1..]),
                    _ => {}
                }
            }
            None
        }
    }
}

/// The word "issue" (any case, singular or plural) followed by a number, a list of
/// numbers or a hash and a number, or a bare hash and digits that is not part of a
/// word, a colour or a Rust attribute.
fn cites_issue(text: &str) -> Option<String> {
    let lower = text.to_ascii_lowercase();
    let bytes = lower.as_bytes();
    for (i, _) in lower.match_indices("issue") {
        let before_ok = i == 0 || !bytes[i - 1].is_ascii_alphanumeric();
        let mut j = i + "issue".len();
        if bytes.get(j) == Some(&b's') {
            j += 1;
        }
        while bytes.get(j) == Some(&b' ') {
            j += 1;
        }
        if bytes.get(j) == Some(&b'#') {
            j += 1;
        }
        if before_ok && bytes.get(j).is_some_and(u8::is_ascii_digit) {
            let end = (j..bytes.len())
                .find(|&k| !bytes[k].is_ascii_digit())
                .unwrap_or(bytes.len());
            return Some(text[i..end].to_string());
        }
    }
    for (i, _) in text.match_indices('#') {
        let before_ok = i == 0 || matches!(bytes[i - 1], b' ' | b'(' | b'|' | b'[' | b',');
        let digits = bytes[i + 1..]
            .iter()
            .take_while(|b| b.is_ascii_digit())
            .count();
        let after = bytes.get(i + 1 + digits);
        let after_ok = after.is_none_or(|b| !b.is_ascii_alphanumeric() && *b != b'_');
        if before_ok && digits > 0 && after_ok {
            return Some(text[i..i + 1 + digits].to_string());
        }
    }
    None
}

/// Candidate file paths in a line of prose: backticked spans, Markdown link targets, and
/// plain words under the repository's top directories. Each comes with whether it is a
/// Markdown link (resolved against the file's directory first).
fn mentioned_paths(text: &str) -> Vec<(String, bool)> {
    let mut out = Vec::new();
    let mut rest = text;
    while let Some(open) = rest.find('`') {
        let after = &rest[open + 1..];
        let Some(close) = after.find('`') else { break };
        out.push((after[..close].to_string(), false));
        rest = &after[close + 1..];
    }
    let mut rest = text;
    while let Some(open) = rest.find("](") {
        let after = &rest[open + 2..];
        let Some(close) = after.find(')') else { break };
        let target = after[..close].split('#').next().unwrap_or("");
        out.push((target.to_string(), true));
        rest = &after[close + 1..];
    }
    for word in text.split(|c: char| c.is_whitespace() || "`()[]<>\"',;:".contains(c)) {
        let word = word.trim_end_matches(['.', ',']);
        if ["crates/", "docs/", "scenes/", "xtask/"]
            .iter()
            .any(|top| word.starts_with(top))
        {
            out.push((word.to_string(), false));
        }
    }
    out
}

/// Whether `candidate` looks like a relative path to a checked kind of file.
fn is_file_path(candidate: &str) -> bool {
    let plain = !candidate.is_empty()
        && !candidate.contains("://")
        && !candidate.starts_with('/')
        && !candidate.starts_with("target/")
        && !candidate.contains(|c: char| c.is_whitespace() || "*<>{}$|".contains(c));
    plain
        && candidate.contains('/')
        && [".rs", ".md", ".ron", ".toml"]
            .iter()
            .any(|e| candidate.ends_with(e))
}

/// `path` made lexical (`.` and `..` resolved); `None` if it climbs above its start.
fn normalize(path: &Path) -> Option<PathBuf> {
    let mut out = PathBuf::new();
    for part in path.components() {
        match part {
            Component::ParentDir => {
                if !out.pop() {
                    return None;
                }
            }
            Component::CurDir => {}
            other => out.push(other),
        }
    }
    Some(out)
}

/// Checks one file's text; `exists` answers for paths relative to the repository root.
/// `packages` are the directories of the repository's packages (`crates/x`, `xtask`): a
/// doc may name a file relative to the package it is about (`tests/terms.rs` in the
/// spring-sim docs) or to its sources (`potential/fused.rs`), so such a path is found if
/// it exists in any package or any package's `src`.
fn check_text(
    file: &Path,
    text: &str,
    exists: &dyn Fn(&Path) -> bool,
    packages: &[PathBuf],
) -> Vec<Finding> {
    let kind = kind_of(file);
    let name = file.to_string_lossy().replace('\\', "/");
    let dir = file.parent().unwrap_or(Path::new(""));
    // The crate a file belongs to, for paths written relative to it (`benches/x.rs`).
    let crate_dir: Option<PathBuf> = {
        let parts: Vec<_> = file.components().collect();
        (parts.len() > 2 && parts[0].as_os_str() == "crates")
            .then(|| Path::new("crates").join(parts[1].as_os_str()))
    };
    let mut findings = Vec::new();
    let mut in_fence = false;
    for (index, line) in text.lines().enumerate() {
        let mut report = |message: String| {
            findings.push(Finding {
                file: name.clone(),
                line: index + 1,
                message,
            });
        };
        if kind == Kind::Markdown && line.trim_start().starts_with("```") {
            in_fence = !in_fence;
            continue;
        }
        // Paths outside the repository are wrong anywhere, code blocks included.
        for outside in [SIBLING_CHECKOUT, WORK_DIRECTORY] {
            if line.contains(outside) {
                report(format!("names a path outside the repository ({outside})"));
            }
        }
        let Some(prose) = prose(kind, line, in_fence) else {
            continue;
        };
        if let Some(citation) = cites_issue(prose) {
            report(format!(
                "cites an issue number (\"{citation}\"): say what is meant instead"
            ));
        }
        let mut seen = Vec::new();
        for (candidate, is_link) in mentioned_paths(prose) {
            if !is_file_path(&candidate) || seen.contains(&candidate) {
                continue;
            }
            seen.push(candidate.clone());
            let relative = Path::new(&candidate);
            let mut bases: Vec<PathBuf> = Vec::new();
            if is_link || kind == Kind::Markdown {
                bases.push(dir.to_path_buf());
            }
            bases.push(PathBuf::new());
            bases.extend(crate_dir.clone());
            bases.push(dir.to_path_buf());
            bases.extend(packages.iter().cloned());
            bases.extend(packages.iter().map(|p| p.join("src")));
            let resolved: Vec<Option<PathBuf>> =
                bases.iter().map(|b| normalize(&b.join(relative))).collect();
            if is_link && resolved[0].is_none() {
                report(format!(
                    "links to {candidate}, which is outside the repository"
                ));
                continue;
            }
            if !resolved.iter().flatten().any(|p| exists(p)) {
                report(format!("names {candidate}, which does not exist"));
            }
        }
    }
    findings
}

#[test]
fn the_repository_is_tidy() {
    let root = repo_root();
    let mut files = Vec::new();
    walk(&root, &root, &mut files);
    files.sort();
    assert!(
        files.len() > 50 && files.iter().any(|f| f.ends_with("Cargo.toml")),
        "the walk found only {} files under {}: is the root right?",
        files.len(),
        root.display()
    );
    let exists = |p: &Path| root.join(p).exists();
    let mut packages: Vec<PathBuf> = files
        .iter()
        .filter(|f| f.ends_with("Cargo.toml"))
        .filter_map(|f| f.parent().map(Path::to_path_buf))
        .filter(|d| !d.as_os_str().is_empty())
        .collect();
    packages.dedup();
    let mut findings = Vec::new();
    for file in &files {
        let name = file.to_string_lossy().replace('\\', "/");
        if ALLOWED.iter().any(|(allowed, _)| *allowed == name) {
            continue;
        }
        let text = fs::read_to_string(root.join(file))
            .unwrap_or_else(|e| panic!("{name}: cannot read: {e}"));
        findings.extend(check_text(file, &text, &exists, &packages));
    }
    let mut message = String::new();
    for f in &findings {
        let _ = writeln!(message, "{}:{}: {}", f.file, f.line, f.message);
    }
    assert!(
        findings.is_empty(),
        "{} tidy findings:\n{message}",
        findings.len()
    );
}

#[test]
fn every_rule_finds_what_it_is_for() {
    let exists = |p: &Path| {
        [
            "docs/curves.md",
            "crates/spring-sim/src/lib.rs",
            "crates/ik-ccd/benches/common/mod.rs",
            "crates/labcheck/tests/math.rs",
        ]
        .iter()
        .any(|e| Path::new(e) == p)
    };
    let rust = Path::new("crates/ik-ccd/src/lib.rs");
    let packages = [PathBuf::from("crates/labcheck")];
    let lines = |file: &Path, text: &str| -> Vec<usize> {
        check_text(file, text, &exists, &packages)
            .iter()
            .map(|f| f.line)
            .collect()
    };
    // Issue numbers, in comments only.
    let text = fixture(
        "// fixed for {I} 9\n/// see {C}s 5 and 9\n//! as {H}12 asked\nlet s = \"{I} 3\";\n#[derive(Debug)]\n// colour #1f77b4, {:#?}, t{I} 4\n",
    );
    assert_eq!(lines(rust, &text), [1, 2, 3]);
    // Paths outside the repository, anywhere.
    let text = fixture("// {S}/{L}\nlet p = \"{W}main\";\n");
    assert_eq!(lines(rust, &text), [1, 2]);
    // Files that do not exist: backticked, plain, linked; relative to the crate too.
    let text = "// `docs/curves.md` and docs/curves.md exist\n// `docs/nope.md`\n// crates/spring-sim/src/gone.rs.\n// `benches/common/mod.rs`\n// `benches/other.rs`\n";
    assert_eq!(lines(rust, text), [2, 3, 5]);
    let md = Path::new("docs/bench/ik.md");
    let text = fixture(
        "[curves](../curves.md) and [gone](../gone.md)\n[out](../../../x.md)\n```\ncargo run # 1\n```\n{I} 4\n`tests/math.rs` and `tests/maths.rs`\n",
    );
    assert_eq!(lines(md, &text), [1, 2, 6, 7]);
    let toml = Path::new("crates/x/Cargo.toml");
    assert_eq!(lines(toml, &fixture("name = \"#1\" # see {I} 2\n")), [1]);
    // A finding says where and what.
    let found = check_text(rust, &fixture("\n// see {I} 7\n"), &exists, &packages);
    assert_eq!(
        found,
        [Finding {
            file: "crates/ik-ccd/src/lib.rs".into(),
            line: 2,
            message: fixture("cites an issue number (\"{I} 7\"): say what is meant instead"),
        }]
    );
}

/// The README's Rust examples (fenced as `rust`), each as its non-blank lines.
fn readme_examples(text: &str) -> Vec<Vec<String>> {
    let mut examples = Vec::new();
    let mut current: Option<Vec<String>> = None;
    for line in text.lines() {
        let fence = line.trim_start().strip_prefix("```");
        match (&mut current, fence) {
            (None, Some(info)) if info.trim() == "rust" => current = Some(Vec::new()),
            (Some(_), Some(_)) => examples.extend(current.take()),
            (Some(lines), None) if !line.trim().is_empty() => lines.push(line.trim_end().into()),
            _ => {}
        }
    }
    examples
}

/// The examples in a Rust file's documentation comments (`//!` and `///`) that rustdoc
/// compiles and runs (a fence with no language, `rust` or `should_panic`; not `ignore`,
/// `no_run`, `compile_fail` or another language), each as the lines a reader of the
/// rendered page sees: hidden lines (`#` alone or followed by a space) and blank lines
/// left out.
fn doc_examples(text: &str) -> Vec<Vec<String>> {
    let mut examples = Vec::new();
    let mut current: Option<(bool, Vec<String>)> = None;
    for line in text.lines() {
        let trimmed = line.trim_start();
        let Some(doc) = trimmed
            .strip_prefix("//!")
            .or_else(|| trimmed.strip_prefix("///"))
        else {
            current = None;
            continue;
        };
        let doc = doc.strip_prefix(' ').unwrap_or(doc);
        if let Some(info) = doc.trim_start().strip_prefix("```") {
            match current.take() {
                Some((true, lines)) => examples.push(lines),
                Some((false, _)) => {}
                None => {
                    let runs = info
                        .split(',')
                        .map(str::trim)
                        .all(|a| matches!(a, "" | "rust" | "should_panic"));
                    current = Some((runs, Vec::new()));
                }
            }
            continue;
        }
        if let Some((_, lines)) = &mut current {
            let visible = doc.trim();
            if !(visible.is_empty() || visible == "#" || visible.starts_with("# ")) {
                lines.push(doc.trim_end().into());
            }
        }
    }
    examples
}

/// The README says each of its examples is a doctest of its crate, so that `cargo test
/// --doc --workspace` checks that it compiles and holds: each must read, line for line,
/// as an example of some crate's documentation that rustdoc runs (blank lines and the
/// doctest's hidden lines aside).
#[test]
fn every_readme_example_is_a_doctest() {
    let root = repo_root();
    let readme = fs::read_to_string(root.join("README.md")).expect("README.md");
    let examples = readme_examples(&readme);
    assert!(
        examples.len() >= 4,
        "{} examples in README.md",
        examples.len()
    );
    let mut files = Vec::new();
    walk(&root, &root.join("crates"), &mut files);
    let mut doctests = Vec::new();
    for file in files.iter().filter(|f| kind_of(f) == Kind::Rust) {
        let text = fs::read_to_string(root.join(file)).expect("a source file");
        doctests.extend(doc_examples(&text));
    }
    let missing: Vec<String> = examples
        .iter()
        .filter(|e| !doctests.contains(e))
        .map(|e| e.first().cloned().unwrap_or_default())
        .collect();
    assert!(
        missing.is_empty(),
        "README examples that are no crate's doctest (first lines): {missing:#?}"
    );
}

#[test]
fn readme_and_doc_examples_are_read_as_they_render() {
    let readme = "text\n```rust\nuse a::b;\n\nlet x = 1;\n```\n```sh\ncargo test\n```\n";
    assert_eq!(readme_examples(readme), [["use a::b;", "let x = 1;"]]);
    let source = "//! ```\n//! use a::b;\n//!\n//! # let hidden = 0;\n//! #\n//! let x = 1;\n//! ```\n\
                  /// ```ignore\n/// not run\n/// ```\n    /// ```rust,should_panic\n    ///     indented();\n    /// ```\n";
    assert_eq!(
        doc_examples(source),
        [vec!["use a::b;", "let x = 1;"], vec!["    indented();"]]
    );
}
