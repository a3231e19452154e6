//! The crate graph keeps its promises: the model and the laws are pure math (no transport, CLI,
//! error-reporting, signal or libc crate anywhere below them), the config schema carries no
//! transport and no law, both sides' ticks, the wire and the study are pure, the transport's
//! default build carries no command-line parser, nothing on the controller side depends on
//! the plant (model-free by construction), and the loop processes know the loop's transport only
//! through its traits. Read from `cargo tree`, so a new dependency that
//! breaks a rule fails here.

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

/// The config schema carries no transport, and stands beside the laws, not on them: both take
/// the laws' names and constants from `deltaloop-names`.
#[test]
fn config_schema_carries_no_transport_and_no_law() {
    assert_none_of(
        "deltaloop-config",
        &[
            "iceoryx2",
            "clap",
            "signal-hook",
            "libc",
            "deltaloop-transport",
            "deltaloop-law",
            "nalgebra",
        ],
    );
    assert_none_of("deltaloop-names", IMPURE);
}

/// What a run computes is pure, whichever loop carries it: both sides' ticks, the wire layout
/// they exchange (iceoryx2's `ZeroCopySend` only with its feature) and the study (reference,
/// recorder, metrics) have no transport, no command line and no process code below them.
#[test]
fn ticks_wire_and_study_are_pure() {
    let process = [
        "deltaloop-plant",
        "deltaloop-controller",
        "deltaloop-link",
        "deltaloop-bridge",
    ];
    for pkg in [
        "deltaloop-wire",
        "deltaloop-plant-tick",
        "deltaloop-controller-tick",
        "deltaloop-study",
    ] {
        let mut forbidden = IMPURE.to_vec();
        forbidden.retain(|c| *c != "deltaloop-config");
        forbidden.extend(process);
        assert_none_of(pkg, &forbidden);
    }
    assert_none_of("deltaloop-wire", &["deltaloop-config"]);
    assert_none_of(
        "deltaloop-controller-tick",
        &["deltaloop-model", "deltaloop-plant-tick"],
    );
    let shared = graph_with("deltaloop-wire", &["--features", "iceoryx2"]);
    assert!(
        shared.iter().any(|n| n == "iceoryx2"),
        "the feature `iceoryx2` brings iceoryx2: {shared:?}"
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

/// The supervisor's layers are crates, each standing only on those below it: timing, then the
/// report, then the runner, then the studies; the supervisor (the commands and the thin
/// operations) on top, and nothing but the executables on the supervisor. The study crate (the
/// pure bottom) stands on none of them.
#[test]
fn supervisor_layers_are_crates_each_on_those_below() {
    let layers = [
        "deltaloop-study",
        "deltaloop-timing",
        "deltaloop-report",
        "deltaloop-runner",
        "deltaloop-studies",
        "deltaloop-supervisor",
    ];
    for (i, layer) in layers.iter().enumerate() {
        assert_none_of(layer, &layers[i + 1..]);
    }
    // The edges are real: each layer does stand on the one below.
    for pair in layers.windows(2) {
        assert!(
            graph(pair[1]).iter().any(|n| n == pair[0]),
            "{} does not depend on {}",
            pair[1],
            pair[0]
        );
    }
    for pkg in [
        "deltaloop-baseline",
        "deltaloop-mcap",
        "deltaloop-plot",
        "deltaloop-bridge",
        "deltaloop-peer",
    ] {
        assert_none_of(pkg, &layers[1..]);
    }
}

/// The supervisor starts `deltaloop-bridge` as a program and shares only the link's set-up with
/// it (endpoint, key, report: `deltaloop-link-setup`); it does not link the bridge, its handshake
/// or its command line.
#[test]
fn supervisor_spawns_the_bridge_without_linking_it() {
    assert_none_of("deltaloop-supervisor", &["deltaloop-bridge", "snow"]);
    assert_none_of(
        "deltaloop-link-setup",
        &["clap", "iceoryx2", "deltaloop-transport", "deltaloop-link"],
    );
}

/// iceoryx2 is the transport's: every other crate reaches the run's services through
/// `deltaloop_transport::ipc` and its concrete ports, so iceoryx2's generic code is compiled once
/// (docs/performance.md, "Build and test time"). Only the transport and the wire (its
/// `ZeroCopySend`, behind a feature) name it among their normal dependencies.
#[test]
fn only_the_transport_and_the_wire_depend_on_iceoryx2() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let meta = workspace_metadata(root);
    let mut users: Vec<&str> = meta["packages"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|p| {
            p["dependencies"]
                .as_array()
                .unwrap()
                .iter()
                .any(|d| d["name"] == "iceoryx2" && d["kind"].is_null())
        })
        .map(|p| p["name"].as_str().unwrap())
        .collect();
    users.sort_unstable();
    assert_eq!(users, ["deltaloop-transport", "deltaloop-wire"]);
    // The edge is real: the loop processes do reach iceoryx2, through the transport.
    assert!(
        graph("deltaloop-controller")
            .iter()
            .any(|n| n == "iceoryx2")
    );
}

/// clap is the command line's, in one module each: `bridge/src/cli.rs` and
/// `supervisor/src/cmd/`. The rest of both crates takes its arguments as plain values.
#[test]
fn clap_only_in_the_command_line_modules() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut offenders = Vec::new();
    for (dir, allowed) in [
        ("bridge/src", "bridge/src/cli.rs"),
        ("supervisor/src", "supervisor/src/cmd/"),
    ] {
        for f in walk(&root.join(dir)) {
            if f.extension().is_none_or(|x| x != "rs") {
                continue;
            }
            let rel = f.strip_prefix(root).unwrap().to_string_lossy().into_owned();
            let text = std::fs::read_to_string(&f).unwrap();
            if !rel.starts_with(allowed) && text.contains("clap") {
                offenders.push(rel);
            }
        }
    }
    assert!(
        offenders.is_empty(),
        "clap outside the CLI modules: {offenders:?}"
    );
}

/// The loop processes speak to the loop's transport (`deltaloop_transport::exchange`), not to one
/// transport: the direct path across two hosts is a transport their binaries supply, so neither
/// process crate, nor anything below it, depends on the link (or the bridge).
#[test]
fn loop_processes_depend_on_no_link() {
    for pkg in ["deltaloop-plant", "deltaloop-controller"] {
        assert_none_of(pkg, &["deltaloop-link", "deltaloop-bridge"]);
    }
}

/// What a transport is made of stays in that transport: the plant's and the controller's process
/// code names neither the direct path's ends and socket nor iceoryx2's loop ports.
#[test]
fn loop_processes_name_no_transport_of_their_own() {
    const NAMES: &[&str] = &[
        "deltaloop_link",
        "direct::",
        "PlantEnd",
        "ControllerEnd",
        "UdpSocket",
        "StateOut",
        "StateIn",
        "TorqueOut",
        "TorqueIn",
    ];
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut found = Vec::new();
    for dir in ["plant/process/src", "controller/process/src"] {
        let files = walk(&root.join(dir));
        assert!(!files.is_empty(), "no sources under {dir}");
        for f in files
            .iter()
            .filter(|f| f.extension().is_some_and(|x| x == "rs"))
        {
            let text = std::fs::read_to_string(f).unwrap();
            let rel = f.strip_prefix(root).unwrap().display().to_string();
            for name in NAMES {
                // A whole name: `StateIn`, not `StateInfo`.
                let whole = text.match_indices(name).any(|(i, _)| {
                    let next = text[i + name.len()..].chars().next();
                    name.ends_with(':') || !next.is_some_and(|c| c.is_alphanumeric() || c == '_')
                });
                if whole {
                    found.push(format!("{rel}: {name}"));
                }
            }
        }
    }
    assert!(
        found.is_empty(),
        "the loop processes name a transport's own types (use the traits of \
         deltaloop_transport::exchange): {found:?}"
    );
}

/// The transport baselines of `bench loop` step the two ticks over bare transports: they need
/// neither the link nor the figures, which would put those crates on their build path.
#[test]
fn baselines_need_no_link_and_no_figures() {
    assert_none_of(
        "deltaloop-baseline",
        &["deltaloop-bridge", "deltaloop-plot", "deltaloop-supervisor"],
    );
}

/// What the recording supervisor encodes every tick (the MCAP file's scene, joint states and
/// writer) is a crate of its own, plain encoders over the model: it needs neither the
/// supervisor nor the loop's transport.
#[test]
fn mcap_messages_need_no_supervisor() {
    assert_none_of(
        "deltaloop-mcap",
        &[
            "deltaloop-supervisor",
            "deltaloop-transport",
            "deltaloop-plot",
        ],
    );
}

/// The build profiles, as a reader can hold them: fewer than 15 `[profile.*]` sections in
/// Cargo.toml and `.cargo/config.toml` together; nothing at opt-level 0 in release (regression:
/// the supervisor at opt-level 0 in release, 9bb8da4, took the MCAP scene with it, and writing a
/// tick's messages went from about 30 to 140 µs of the recording supervisor's CPU; a cold
/// dependency may sit at 1); and a per-package section names only a workspace crate or a
/// dependency a workspace crate names itself, so an update of a dependency cannot orphan it.
#[test]
fn profiles_are_few_optimised_in_release_and_name_direct_dependencies() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let manifest =
        std::fs::read_to_string(root.join("Cargo.toml")).expect("the workspace manifest");
    let config = std::fs::read_to_string(root.join(".cargo/config.toml")).unwrap_or_default();
    let mut sections = Vec::new();
    let mut release_zero = Vec::new();
    for text in [&manifest, &config] {
        let mut section = String::new();
        for line in text.lines().map(str::trim) {
            if line.starts_with("[profile.") {
                section = line.to_string();
                sections.push(section.clone());
            } else if line.starts_with('[') {
                section.clear();
            } else if section.starts_with("[profile.release")
                && line.replace(' ', "").starts_with("opt-level=0")
            {
                release_zero.push(section.clone());
            }
        }
    }
    assert!(
        sections.len() < 15,
        "{} profile sections: {sections:#?}",
        sections.len()
    );
    assert!(
        release_zero.is_empty(),
        "opt-level 0 in release: {release_zero:?}"
    );
    // What the workspace names: its members and their direct dependencies.
    let meta = workspace_metadata(root);
    let mut named: Vec<String> = Vec::new();
    for p in meta["packages"].as_array().unwrap() {
        named.push(p["name"].as_str().unwrap().to_string());
        for d in p["dependencies"].as_array().unwrap() {
            named.push(d["name"].as_str().unwrap().to_string());
        }
    }
    let orphans: Vec<&String> = sections
        .iter()
        .filter_map(|s| {
            let name = s.split(".package.").nth(1)?;
            let name = name.trim_end_matches(']').trim_matches('"');
            (name != "*" && !named.iter().any(|n| n == name)).then_some(s)
        })
        .collect();
    assert!(
        orphans.is_empty(),
        "sections naming crates the workspace does not depend on directly: {orphans:?}"
    );
}

/// `cargo metadata` of the workspace's own packages (no dependencies).
fn workspace_metadata(root: &std::path::Path) -> serde_json::Value {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let out = Command::new(cargo)
        .args([
            "metadata",
            "--offline",
            "--locked",
            "--no-deps",
            "--format-version",
            "1",
        ])
        .current_dir(root)
        .output()
        .expect("cargo metadata");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

/// The module a source file is (`a::b::c` from `src/a/b/c.rs` or `src/a/b/c/mod.rs`), and the
/// parent module its siblings share.
fn module_of(src: &std::path::Path, file: &std::path::Path) -> Vec<String> {
    let rel = file.strip_prefix(src).unwrap().with_extension("");
    let mut parts: Vec<String> = rel
        .iter()
        .map(|p| p.to_string_lossy().into_owned())
        .collect();
    if matches!(
        parts.last().map(String::as_str),
        Some("mod" | "lib" | "main")
    ) {
        parts.pop();
    }
    parts
}

/// The sibling modules `text` (module `me`) names: through `super::` or its full `crate::` path.
fn sibling_uses(text: &str, me: &[String], siblings: &[String]) -> Vec<String> {
    let parent = me[..me.len() - 1].join("::");
    let prefixes = if parent.is_empty() {
        vec!["super::".to_string(), "crate::".to_string()]
    } else {
        vec!["super::".to_string(), format!("crate::{parent}::")]
    };
    let mut named = Vec::new();
    for prefix in &prefixes {
        for (i, _) in text.match_indices(prefix.as_str()) {
            let rest = &text[i + prefix.len()..];
            // `super::{a, b::X}`: the first word of each item; else the word after the prefix.
            let items: Vec<&str> = match rest.strip_prefix('{') {
                Some(list) => list[..list.find('}').unwrap_or(list.len())]
                    .split(',')
                    .collect(),
                None => vec![rest],
            };
            for item in items {
                let word: String = item
                    .trim_start()
                    .chars()
                    .take_while(|c| c.is_alphanumeric() || *c == '_')
                    .collect();
                if siblings.contains(&word) && *me.last().unwrap() != word {
                    named.push(word);
                }
            }
        }
    }
    named.sort();
    named.dedup();
    named
}

/// No module imports a sibling that (directly or around a circle) imports it back: shared types
/// live in a leaf module both use. Parents and children may use each other; unit tests (after
/// `#[cfg(test)]`) are left out.
#[test]
fn no_import_circles_among_sibling_modules() {
    let root = crate::common::python::root();
    let mut srcs = Vec::new();
    for dir in [
        "bridge",
        "peer",
        "supervisor",
        "plant",
        "controller",
        "protocol",
    ] {
        for entry in walk(&root.join(dir)) {
            if entry.ends_with("src") && entry.is_dir() {
                srcs.push(entry);
            }
        }
    }
    assert!(srcs.len() >= 8, "found the crates' src folders: {srcs:?}");
    for src in srcs {
        let files: Vec<std::path::PathBuf> = walk(&src)
            .into_iter()
            .filter(|p| p.extension().is_some_and(|e| e == "rs"))
            .collect();
        let modules: Vec<Vec<String>> = files.iter().map(|f| module_of(&src, f)).collect();
        // Edges among siblings: files whose modules share a parent.
        let mut edges: std::collections::BTreeMap<Vec<String>, Vec<Vec<String>>> =
            Default::default();
        for (file, me) in files.iter().zip(&modules) {
            if me.is_empty() {
                continue;
            }
            let parent = &me[..me.len() - 1];
            let siblings: Vec<String> = modules
                .iter()
                .filter(|m| m.len() == me.len() && m[..m.len() - 1] == *parent)
                .map(|m| m.last().unwrap().clone())
                .collect();
            let text = std::fs::read_to_string(file).unwrap();
            let code: String = text[..text.find("#[cfg(test)]").unwrap_or(text.len())]
                .lines()
                .filter(|l| !l.trim_start().starts_with("//"))
                .collect::<Vec<_>>()
                .join("\n");
            for s in sibling_uses(&code, me, &siblings) {
                let mut to = parent.to_vec();
                to.push(s);
                edges.entry(me.clone()).or_default().push(to);
            }
        }
        // A depth-first search finds any circle.
        fn visit(
            m: &Vec<String>,
            edges: &std::collections::BTreeMap<Vec<String>, Vec<Vec<String>>>,
            path: &mut Vec<Vec<String>>,
            done: &mut std::collections::BTreeSet<Vec<String>>,
        ) -> Option<Vec<Vec<String>>> {
            if let Some(i) = path.iter().position(|p| p == m) {
                return Some(path[i..].to_vec());
            }
            if !done.insert(m.clone()) {
                return None;
            }
            path.push(m.clone());
            for n in edges.get(m).into_iter().flatten() {
                if let Some(c) = visit(n, edges, path, done) {
                    return Some(c);
                }
            }
            path.pop();
            None
        }
        let mut done = Default::default();
        for m in edges.keys() {
            let circle = visit(m, &edges, &mut Vec::new(), &mut done);
            assert!(
                circle.is_none(),
                "{}: modules import each other in a circle: {:?}",
                src.display(),
                circle.unwrap_or_default()
            );
        }
    }
}

/// Every path under `dir` (files and folders), `target` and hidden folders left out.
fn walk(dir: &std::path::Path) -> Vec<std::path::PathBuf> {
    let mut out = Vec::new();
    let Ok(rd) = std::fs::read_dir(dir) else {
        return out;
    };
    for e in rd.flatten() {
        let p = e.path();
        let name = e.file_name().to_string_lossy().into_owned();
        if name.starts_with('.') || name == "target" {
            continue;
        }
        if p.is_dir() {
            out.push(p.clone());
            out.extend(walk(&p));
        } else {
            out.push(p);
        }
    }
    out
}

/// ROS 2 has one crate per side: `deltaloop-ros2` (the messages, the participant, the live
/// topics, the DDS side of `bench ros2`) needs no baseline (the supervisor's bench composes
/// the two), and the robot of `--controller ros2` (`deltaloop-ros2-robot`) is a controller
/// process: it runs the controller's `serve` and never reaches the plant's process or the
/// supervisor.
#[test]
fn ros2_needs_no_baseline_and_its_robot_is_on_the_controller_side() {
    assert_none_of(
        "deltaloop-ros2",
        &[
            "deltaloop-baseline",
            "deltaloop-controller",
            "deltaloop-plant",
            "deltaloop-supervisor",
        ],
    );
    let robot = graph("deltaloop-ros2-robot");
    for side in ["deltaloop-controller", "deltaloop-ros2"] {
        assert!(
            robot.iter().any(|n| n == side),
            "deltaloop-ros2-robot does not depend on {side}; its graph: {robot:?}"
        );
    }
    assert_none_of(
        "deltaloop-ros2-robot",
        &[
            "deltaloop-plant",
            "deltaloop-baseline",
            "deltaloop-runner",
            "deltaloop-supervisor",
            "deltaloop-bridge",
        ],
    );
}
