//! The crate graph keeps its promises: the model and the laws are pure math (no transport, CLI,
//! error-reporting, signal or libc crate anywhere below them), the config schema carries no
//! transport, the transport's default build carries no command-line parser, and nothing on the
//! controller side depends on the plant (model-free by construction). Read from `cargo tree`, so a new dependency that breaks a rule fails here.

use std::process::Command;

/// Every package in the normal (non-dev, non-build) dependency graph of `pkg` with its default
/// features.
fn graph(pkg: &str) -> Vec<String> {
    graph_with(pkg, &[])
}

/// [`graph`] with more `cargo tree` arguments (`--features …`).
fn graph_with(pkg: &str, extra: &[&str]) -> Vec<String> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let out = Command::new(cargo)
        .args([
            "tree",
            "--offline",
            "--locked",
            "-p",
            pkg,
            "-e",
            "normal",
            "--prefix",
            "none",
            "--format",
            "{p}",
        ])
        .args(extra)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("run cargo tree");
    assert!(
        out.status.success(),
        "cargo tree -p {pkg}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    let mut names: Vec<String> = text
        .lines()
        .filter_map(|l| l.split_whitespace().next())
        .map(str::to_string)
        .collect();
    names.sort();
    names.dedup();
    assert!(
        names.contains(&pkg.to_string()),
        "{pkg} not in its own tree"
    );
    names
}

fn assert_none_of(pkg: &str, forbidden: &[&str]) {
    let g = graph(pkg);
    let found: Vec<&&str> = forbidden
        .iter()
        .filter(|f| g.iter().any(|n| n == *f))
        .collect();
    assert!(
        found.is_empty(),
        "{pkg} depends on {found:?}; its graph: {g:?}"
    );
}

const IMPURE: &[&str] = &[
    "iceoryx2",
    "clap",
    "anyhow",
    "signal-hook",
    "libc",
    "core_affinity",
    "deltaloop-transport",
    "deltaloop-config",
];

#[test]
fn model_crate_is_pure() {
    assert_none_of("deltaloop-model", IMPURE);
}

#[test]
fn law_crate_is_pure_and_model_free() {
    let mut forbidden = IMPURE.to_vec();
    forbidden.extend(["deltaloop-model", "deltaloop-plant"]);
    assert_none_of("deltaloop-law", &forbidden);
}

#[test]
fn config_schema_carries_no_transport() {
    assert_none_of(
        "deltaloop-config",
        &[
            "iceoryx2",
            "clap",
            "signal-hook",
            "libc",
            "deltaloop-transport",
        ],
    );
}

/// A peer that wants the wire types and the services gets no command-line parser: the loop
/// processes' arguments (`args::LoopArgs`) are behind the transport's feature `args`, which the
/// built-in plant and controller enable.
#[test]
fn transport_carries_no_command_line_parser_by_default() {
    assert_none_of("deltaloop-transport", &["clap", "anyhow"]);
    let with_args = graph_with("deltaloop-transport", &["--features", "args"]);
    assert!(
        with_args.iter().any(|n| n == "clap"),
        "the feature `args` brings clap: {with_args:?}"
    );
}

#[test]
fn controller_side_never_depends_on_the_plant() {
    assert_none_of(
        "deltaloop-controller",
        &["deltaloop-model", "deltaloop-plant"],
    );
}

/// The reader sees real edges: the plant process does use the transport and the model, so the
/// checks above are not passing on an empty graph.
#[test]
fn graph_reader_sees_transitive_dependencies() {
    let g = graph("deltaloop-plant");
    for dep in [
        "iceoryx2",
        "deltaloop-model",
        "deltaloop-transport",
        "nalgebra",
    ] {
        assert!(g.iter().any(|n| n == dep), "{dep} missing from {g:?}");
    }
}

/// The bridge carries messages and knows neither the robot nor a law; its default build (the one
/// `cargo build --release` and `cargo test` make) has no Zenoh, which costs ~700 crates.
#[test]
fn bridge_is_lean_and_zenoh_is_opt_in() {
    assert_none_of(
        "deltaloop-bridge",
        &[
            "deltaloop-model",
            "deltaloop-plant",
            "deltaloop-controller",
            "zenoh",
        ],
    );
    assert_none_of("deltaloop", &["zenoh"]);
}
