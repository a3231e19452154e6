//! The front door and the map name only what exists: every repository path that README.md and
//! docs/architecture.md name (in backticks, or as a relative link) resolves, so a moved or renamed
//! file fails here instead of sending a reader to nothing.

use std::path::{Path, PathBuf};

const ROOT: &str = env!("CARGO_MANIFEST_DIR");

/// The repository's top-level folders: a backticked path that starts with one of them is a
/// repository path.
const TOP: &[&str] = &[
    "supervisor/",
    "bridge/",
    "protocol/",
    "plant/",
    "controller/",
    "peer/",
    "tests/",
    "docs/",
    "configs/",
    "python/",
    "examples/",
    "benches/",
    "src/",
    ".ci/",
];

/// What a backticked token names: a repository path from the root (it starts with a top-level
/// folder), or a path within some folder (`ops/sweep/point.rs`, `procs/`, `tick_csv.rs`), which
/// must be the end of some path in the repository. Output folders (`runs/…`, `RUN_DIR/…`) and
/// anything with a space, a glob or a placeholder are not paths of the repository.
#[derive(Debug)]
enum Named {
    FromRoot(PathBuf),
    Within(String),
}

/// The repository paths `text` (a Markdown file in folder `dir`, relative to the root) names: its
/// backticked tokens that look like paths, and its relative link targets; anchors and line
/// numbers are cut.
fn named_paths(text: &str, dir: &Path) -> Vec<(String, Named)> {
    let mut out = Vec::new();
    for (i, part) in text.split('`').enumerate() {
        let odd = |c: char| " *<>=$".contains(c);
        if i % 2 == 0 || part.chars().any(odd) || part.starts_with("runs/") {
            continue;
        }
        let p = part.split(['#', ':']).next().unwrap_or("");
        if p.chars().next().is_some_and(|c| c.is_ascii_uppercase()) {
            continue;
        }
        if TOP.iter().any(|t| p.starts_with(t)) {
            out.push((part.to_string(), Named::FromRoot(PathBuf::from(p))));
        } else if p.ends_with(".rs") || (p.contains('/') && p.ends_with('/')) {
            out.push((part.to_string(), Named::Within(p.to_string())));
        }
    }
    for link in text.split("](").skip(1) {
        let target = link.split(')').next().unwrap_or("");
        let p = target.split('#').next().unwrap_or("");
        if p.is_empty() || p.contains("://") || p.starts_with("mailto:") {
            continue;
        }
        out.push((target.to_string(), Named::FromRoot(dir.join(p))));
    }
    out
}

/// Every file and folder of the repository (folders ending in `/`), relative to the root; build
/// output, git's and the Python venv's folders left out.
fn tree() -> Vec<String> {
    fn walk(dir: &Path, rel: &str, out: &mut Vec<String>) {
        let Ok(entries) = std::fs::read_dir(dir) else {
            return;
        };
        for e in entries.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            if ["target", ".git", ".venv", "node_modules", "__pycache__"].contains(&name.as_str()) {
                continue;
            }
            let path = format!("{rel}{name}");
            if e.file_type().is_ok_and(|t| t.is_dir()) {
                out.push(format!("{path}/"));
                walk(&e.path(), &format!("{path}/"), out);
            } else {
                out.push(path);
            }
        }
    }
    let mut out = Vec::new();
    walk(Path::new(ROOT), "", &mut out);
    out
}

/// Whether `named` is in the repository (`tree`: [`tree`]).
fn exists(named: &Named, tree: &[String]) -> bool {
    match named {
        Named::FromRoot(p) => Path::new(ROOT).join(p).exists(),
        Named::Within(p) => tree.iter().any(|t| t == p || t.ends_with(&format!("/{p}"))),
    }
}

#[test]
fn every_path_the_readme_and_the_architecture_name_exists() {
    let tree = tree();
    let mut missing = Vec::new();
    let mut checked = 0;
    for doc in ["README.md", "docs/architecture.md"] {
        let text = std::fs::read_to_string(Path::new(ROOT).join(doc)).unwrap();
        let dir = Path::new(doc).parent().unwrap_or(Path::new(""));
        for (written, named) in named_paths(&text, dir) {
            checked += 1;
            if !exists(&named, &tree) {
                missing.push(format!("{doc}: `{written}`"));
            }
        }
    }
    assert!(
        checked > 50,
        "only {checked} paths found: the reader is broken"
    );
    assert!(
        missing.is_empty(),
        "named but not in the repository:\n{}",
        missing.join("\n")
    );
}

#[test]
fn a_renamed_file_is_caught() {
    let found = named_paths(
        "see `supervisor/src/timing/csv.rs`, `csv.rs`, `tick_csv.rs`, `studies/src/sweep/mod.rs`, \
         `runs/x/` and [x](guide/nowhere.md)",
        Path::new("docs"),
    );
    let tree = tree();
    let seen: Vec<bool> = found.iter().map(|(_, n)| exists(n, &tree)).collect();
    // `timing/csv.rs` was renamed `tick_csv.rs`; `runs/x/` is an output folder, not named.
    assert_eq!(seen, [false, false, true, true, false], "{found:?}");
}
