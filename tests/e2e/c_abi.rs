//! The C ABI as a C user meets it: the header under the compilers and standards C code is built
//! with, the `main` one-liners the guide documents, and linking with the documented flags.
//! Each test needs `cc` (and `c++`, `pkg-config`); without one it says so and passes.

use crate::common;

use common::python::{root, text};
use std::process::{Command, Output};

/// Whether `tool` runs here (else one line saying the test is skipped).
fn have(tool: &str) -> bool {
    let ok = Command::new(tool).arg("--version").output().is_ok();
    if !ok {
        eprintln!("SKIPPED: no `{tool}` on this machine");
    }
    ok
}

fn run(cmd: &mut Command) -> Output {
    cmd.output().unwrap_or_else(|e| panic!("{cmd:?}: {e}"))
}

fn assert_ok(o: &Output, what: &str) {
    assert!(
        o.status.success(),
        "{what}: {}{}",
        text(&o.stdout),
        text(&o.stderr)
    );
}

/// Regression: the header used `//` comments (cbindgen's c99 style, and its C++ guard's
/// `#endif // __cplusplus`), so C code built as C89/C90 (Embedded Coder targets set to it)
/// could not include it. It compiles with exactly `cc -std=c89 -pedantic -Werror
/// -fsyntax-only`, and with C99 and C++ as before.
#[test]
fn regression_the_header_compiles_as_c89_c99_and_cpp() {
    if !have("cc") {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let src = tmp.path().join("uses_header.c");
    std::fs::write(
        &src,
        "#include \"deltaloop.h\"\nint main(void) { return dl_wire_version() > 0 ? 0 : 1; }\n",
    )
    .unwrap();
    let include = root().join("peer/include");
    for std in ["-std=c89", "-std=c99"] {
        let o = run(Command::new("cc")
            .args([std, "-pedantic", "-Werror", "-fsyntax-only", "-I"])
            .arg(&include)
            .arg(&src));
        assert_ok(&o, &format!("cc {std}"));
    }
    if have("c++") {
        let o = run(Command::new("c++")
            .args([
                "-x",
                "c++",
                "-std=c++11",
                "-pedantic",
                "-Wall",
                "-Wextra",
                "-Werror",
            ])
            .args(["-fsyntax-only", "-I"])
            .arg(&include)
            .arg(&src));
        assert_ok(&o, "c++");
    }
}

/// The `return dl_…_main(…);` lines of `text` (backticked in the guide, or in the header's
/// comments), one each.
fn one_liners(text: &str) -> Vec<String> {
    text.split('`')
        .flat_map(|s| s.lines())
        .map(|l| l.trim().trim_start_matches('*').trim())
        .filter(|l| l.starts_with("return dl_") && l.contains("_main(") && l.ends_with(");"))
        .map(str::to_string)
        .collect()
}

/// Regression: the guide's `main` one-liner passed `char **argv` where the header declares
/// `const char *const *`: a warning in C (an error with `-Werror`, and in newer compilers by
/// default). Every `main` one-liner of the guide and of the header compiles with `-Wall -Wextra
/// -Werror`.
#[test]
fn regression_the_documented_main_one_liners_compile_without_warnings() {
    if !have("cc") {
        return;
    }
    let guide = std::fs::read_to_string(root().join("docs/guide/own-process.md")).unwrap();
    let header = std::fs::read_to_string(root().join("peer/include/deltaloop.h")).unwrap();
    let mut lines = one_liners(&guide);
    lines.extend(one_liners(&header));
    for f in ["dl_controller_main", "dl_plant_main"] {
        assert!(
            lines.iter().filter(|l| l.contains(f)).count() >= 2,
            "a `main` one-liner for {f} in the guide and the header: {lines:?}"
        );
    }
    let tmp = tempfile::tempdir().unwrap();
    for (i, line) in lines.iter().enumerate() {
        let src = tmp.path().join(format!("main{i}.c"));
        std::fs::write(
            &src,
            format!(
                "#include \"deltaloop.h\"\n\
                 static int init(void *u, const dl_run *r) {{ (void)u; (void)r; return 0; }}\n\
                 static int step(void *u, const dl_state *x, const dl_ref_sample *r, dl_torque *y) {{ (void)u; (void)x; (void)r; (void)y; return 0; }}\n\
                 static int law, rig;\n\
                 static dl_plant_fns fns;\n\
                 int main(int argc, char **argv) {{\n    (void)init; (void)step; (void)law; (void)rig; (void)fns;\n    {line}\n}}\n"
            ),
        )
        .unwrap();
        let o = run(Command::new("cc")
            .args([
                "-std=c99",
                "-Wall",
                "-Wextra",
                "-Werror",
                "-fsyntax-only",
                "-I",
            ])
            .arg(root().join("peer/include"))
            .arg(&src));
        assert_ok(&o, line);
    }
}

/// The guide's `cc … $(pkg-config … <package>)` line, as documented.
fn documented_link_line(guide: &str, package: &str) -> String {
    let end = format!("{package})");
    guide
        .lines()
        .find(|l| l.starts_with("cc ") && l.trim_end().ends_with(&end))
        .unwrap_or_else(|| panic!("no `cc … {end}` line in the guide"))
        .to_string()
}

/// Regression: the static library needs system libraries (`-lm` and more) that nothing said,
/// and neither linking was documented. Next to the built library are `deltaloop_peer.pc` and
/// `deltaloop_peer-static.pc`, and a C program built with exactly the guide's lines links and
/// runs: the static one without `libdeltaloop_peer.so`.
#[test]
fn regression_a_c_program_links_with_the_documented_flags() {
    if !have("cc") || !have("pkg-config") {
        return;
    }
    let lib = common::peer_lib_dir();
    let guide = std::fs::read_to_string(root().join("docs/guide/own-process.md")).unwrap();
    let tmp = tempfile::tempdir().unwrap();
    std::fs::write(
        tmp.path().join("my_controller.c"),
        "#include <stdio.h>\n#include \"deltaloop.h\"\nint main(void) { printf(\"%s %u\\n\", dl_version(), (unsigned)dl_wire_version()); return 0; }\n",
    )
    .unwrap();
    for package in ["deltaloop_peer", "deltaloop_peer-static"] {
        assert!(
            lib.join(format!("{package}.pc")).is_file(),
            "no {package}.pc in {}",
            lib.display()
        );
        let line = documented_link_line(&guide, package);
        let o = run(Command::new("sh")
            .args(["-c", &line])
            .current_dir(tmp.path())
            .env("PKG_CONFIG_PATH", &lib));
        assert_ok(&o, &line);
        let exe = tmp.path().join("my_controller");
        let mut ran = Command::new(&exe);
        if package.ends_with("-static") {
            // Nowhere to find the shared library: the program must not need it.
            ran.env_remove("LD_LIBRARY_PATH");
            let needed = run(Command::new("ldd").arg(&exe));
            assert!(
                !text(&needed.stdout).contains("libdeltaloop_peer"),
                "{line}: {}",
                text(&needed.stdout)
            );
        }
        let o = run(&mut ran);
        assert_ok(&o, &format!("{line}: run"));
        let want = format!(
            "{} {}",
            env!("CARGO_PKG_VERSION"),
            deltaloop_transport::wire::WIRE_VERSION
        );
        assert_eq!(text(&o.stdout).trim(), want, "{line}");
        std::fs::remove_file(&exe).unwrap();
    }
}
