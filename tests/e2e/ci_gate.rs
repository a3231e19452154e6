//! `.ci/run`'s lint gate: clippy over the test build (`.ci/clippy-rustc` as cargo's
//! RUSTC_WRAPPER), tried on a two-crate workspace of its own: a lint in either crate fails the
//! build as `cargo clippy -- -D warnings` would, a dependency is never linted, and a clean build
//! through the gate leaves nothing for the plain command after it to compile.

use std::path::Path;
use std::process::{Command, Output};

/// `cargo build` in `dir` (offline, its own target directory), through the gate if `gated`.
fn cargo_build(dir: &Path, gated: bool) -> Output {
    let mut c = Command::new(env!("CARGO"));
    c.arg("build")
        .arg("--offline")
        .current_dir(dir)
        .env("CARGO_TARGET_DIR", dir.join("target"))
        .env("CARGO_INCREMENTAL", "0")
        .env_remove("RUSTC_WRAPPER")
        .env_remove("RUSTC_WORKSPACE_WRAPPER")
        .env_remove("CLIPPY_DRIVER");
    if gated {
        let sysroot = Command::new("rustc")
            .args(["--print", "sysroot"])
            .output()
            .unwrap();
        let sysroot = String::from_utf8(sysroot.stdout).unwrap();
        c.env(
            "CLIPPY_DRIVER",
            Path::new(sysroot.trim()).join("bin/clippy-driver"),
        )
        .env(
            "RUSTC_WRAPPER",
            Path::new(env!("CARGO_MANIFEST_DIR")).join(".ci/clippy-rustc"),
        );
    }
    c.output().unwrap()
}

fn write(dir: &Path, file: &str, text: &str) {
    let p = dir.join(file);
    std::fs::create_dir_all(p.parent().unwrap()).unwrap();
    std::fs::write(p, text).unwrap();
}

/// A workspace of a library `low` and a binary `top` on it; `low_body` is `low`'s function body.
fn workspace(dir: &Path, low_body: &str, top_main: &str) {
    write(
        dir,
        "Cargo.toml",
        "[workspace]\nmembers = [\"low\", \"top\"]\nresolver = \"2\"\n",
    );
    write(
        dir,
        "low/Cargo.toml",
        "[package]\nname = \"low\"\nversion = \"0.1.0\"\nedition = \"2024\"\n",
    );
    write(
        dir,
        "low/src/lib.rs",
        &format!("pub fn count(v: &[u32]) -> usize {{\n    {low_body}\n}}\n"),
    );
    write(
        dir,
        "top/Cargo.toml",
        "[package]\nname = \"top\"\nversion = \"0.1.0\"\nedition = \"2024\"\n[dependencies]\nlow = { path = \"../low\" }\n",
    );
    write(dir, "top/src/main.rs", top_main);
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

#[test]
fn the_lint_gate_fails_on_a_lint_in_any_crate_and_leaves_the_build_to_the_tests() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let clean_main = "fn main() {\n    println!(\"{}\", low::count(&[1, 2]));\n}\n";

    // A clippy lint (len_zero) in the library: the gated build fails and names it.
    workspace(d, "if v.len() == 0 { 0 } else { v.len() }", clean_main);
    let o = cargo_build(d, true);
    assert!(!o.status.success(), "the lint passed: {}", stderr(&o));
    assert!(stderr(&o).contains("clippy::len_zero"), "{}", stderr(&o));

    // Fixed there, a rustc warning (an unused variable) in the binary: an error too.
    workspace(
        d,
        "v.len()",
        "fn main() {\n    let unused = 1;\n    println!(\"{}\", low::count(&[1, 2]));\n}\n",
    );
    let o = cargo_build(d, true);
    assert!(!o.status.success(), "the warning passed: {}", stderr(&o));
    assert!(stderr(&o).contains("unused_variables"), "{}", stderr(&o));

    // Clean: the gated build succeeds, and the plain build after it finds every crate fresh.
    workspace(d, "v.len()", clean_main);
    let o = cargo_build(d, true);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = cargo_build(d, false);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!stderr(&o).contains("Compiling"), "{}", stderr(&o));
    // And the program is the one rustc built (clippy's own run keeps no output).
    let run = Command::new(d.join("target/debug/top")).output().unwrap();
    assert_eq!(String::from_utf8_lossy(&run.stdout), "2\n");
}
