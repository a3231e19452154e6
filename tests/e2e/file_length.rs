//! No source file over [`LIMIT`] lines before its first `#[cfg(test)]` (a file without one counts
//! whole), vendored code aside: a file that long holds more than one concept, and is split by
//! concept (docs/architecture.md).

use std::path::Path;
use std::process::Command;

/// Lines a file may hold before its tests.
const LIMIT: usize = 800;

/// Lines of `text` before its first line starting with `#[cfg(test)]`, or all of them.
fn lines_before_tests(text: &str) -> usize {
    text.lines()
        .position(|l| l.starts_with("#[cfg(test)]"))
        .unwrap_or_else(|| text.lines().count())
}

/// The files over the limit among `files` (paths relative to `root`): path and count, longest
/// first.
fn offenders(root: &Path, files: &[String]) -> Vec<(String, usize)> {
    let mut over: Vec<(String, usize)> = files
        .iter()
        .filter(|f| !f.starts_with("vendor/") && !f.starts_with("target/"))
        .filter_map(|f| {
            let text = std::fs::read_to_string(root.join(f)).ok()?;
            let n = lines_before_tests(&text);
            (n > LIMIT).then(|| (f.clone(), n))
        })
        .collect();
    over.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
    over
}

#[test]
fn no_source_file_is_over_800_lines_before_its_tests() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let out = Command::new("git")
        .args([
            "ls-files",
            "--cached",
            "--others",
            "--exclude-standard",
            "*.rs",
        ])
        .current_dir(root)
        .output()
        .expect("run git ls-files");
    assert!(out.status.success(), "git ls-files failed");
    let files: Vec<String> = String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(str::to_owned)
        .collect();
    assert!(
        files.iter().any(|f| f == "tests/e2e/file_length.rs"),
        "git ls-files listed none of the workspace's files"
    );
    let over = offenders(root, &files);
    assert!(
        over.is_empty(),
        "{} file(s) over {LIMIT} lines before their first #[cfg(test)] (split each by concept):\n{}",
        over.len(),
        over.iter()
            .map(|(f, n)| format!("  {f}: {n} lines"))
            .collect::<Vec<_>>()
            .join("\n")
    );
}

#[test]
fn lines_are_counted_up_to_the_first_test_module_or_whole() {
    assert_eq!(lines_before_tests("a\nb\n#[cfg(test)]\nmod tests {}\n"), 2);
    assert_eq!(lines_before_tests("a\n    #[cfg(test)]\nb\n"), 3);
    assert_eq!(lines_before_tests(""), 0);
}
