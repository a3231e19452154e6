//! The Python side of the tests: a virtual environment under `target/python-venv` with every pin
//! of `python/requirements.txt` and the `python/` package, set up by the tests themselves.
//!
//! Needs Python ≥ 3.11 with its `venv` module, and PyPI the first time (pip). Without Python the
//! tests fail and say what to install; they never pass silently.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

pub fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

pub fn run_cmd(cmd: &mut Command, what: &str) -> Output {
    cmd.output()
        .unwrap_or_else(|e| panic!("{what}: cannot run {cmd:?}: {e}"))
}

pub fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// The virtual environment's python, set up once per test process (a file lock keeps two test
/// processes from building it at the same time).
pub fn python() -> &'static Path {
    static PYTHON: OnceLock<PathBuf> = OnceLock::new();
    PYTHON.get_or_init(set_up_venv)
}

/// What the venv lacks: "" when it has every `name==version` of requirements.txt and the current
/// python/ package; "requirements" or "deltaloop" (or both), "venv" when there is no venv.
fn venv_lacks(py: &Path) -> String {
    const CHECK: &str = r##"
import importlib.metadata as m, pathlib, re, sys
lacks = []
for line in pathlib.Path(sys.argv[2]).read_text().splitlines():
    line = line.split("#")[0].strip()
    if not line:
        continue
    name, want = line.split("==")
    try:
        ok = m.version(re.sub(r"\[.*\]", "", name)) == want
    except m.PackageNotFoundError:
        ok = False
    if not ok:
        lacks.append("requirements")
        break
try:
    import deltaloop
    inst = pathlib.Path(deltaloop.__file__).parent
    src = pathlib.Path(sys.argv[1])
    if any(not (inst / f.name).is_file() or (inst / f.name).read_bytes() != f.read_bytes()
           for f in src.glob("*.py")):
        lacks.append("deltaloop")
except ImportError:
    lacks.append("deltaloop")
print(" ".join(lacks))
"##;
    if !py.is_file() {
        return "venv".into();
    }
    let o = Command::new(py)
        .args(["-c", CHECK])
        .arg(root().join("python/deltaloop"))
        .arg(root().join("python/requirements.txt"))
        .output();
    match o {
        Ok(o) if o.status.success() => text(&o.stdout).trim().to_string(),
        _ => "venv".into(),
    }
}

fn set_up_venv() -> PathBuf {
    let target = root().join("target");
    std::fs::create_dir_all(&target).unwrap();
    let venv = target.join("python-venv");
    let py = venv.join("bin/python");
    let lock = std::fs::File::create(target.join("python-venv.lock")).unwrap();
    // SAFETY: flock on a descriptor we own; released when `lock` is dropped at the end.
    assert_eq!(
        unsafe { libc::flock(std::os::fd::AsRawFd::as_raw_fd(&lock), libc::LOCK_EX) },
        0
    );
    let mut lacks = venv_lacks(&py);
    if lacks.is_empty() {
        return py;
    }
    if lacks == "venv" {
        let install = "install Python >= 3.11 with its venv module (Debian/Ubuntu: `apt install python3 python3-venv`)";
        let v = Command::new("python3")
            .args(["-c", "import sys, venv; print(sys.version_info >= (3, 11))"])
            .output();
        match v {
            Err(e) => panic!("the Python interop tests need `python3` ({e}): {install}"),
            Ok(o) if !o.status.success() => panic!(
                "`python3` has no venv module ({}): {install}",
                text(&o.stderr).trim()
            ),
            Ok(o) if text(&o.stdout).trim() != "True" => {
                panic!(
                    "`python3` is older than 3.11 (the helper reads TOML with tomllib): {install}"
                )
            }
            Ok(_) => {}
        }
        let o = run_cmd(
            Command::new("python3")
                .args(["-m", "venv", "--clear"])
                .arg(&venv),
            "create the venv",
        );
        assert!(
            o.status.success() && py.is_file(),
            "`python3 -m venv {}` failed: {}\n{install}",
            venv.display(),
            text(&o.stderr)
        );
        lacks = venv_lacks(&py);
    }
    let pip = |args: &[&str]| {
        let o = run_cmd(
            Command::new(&py)
                .args(["-m", "pip", "install", "--disable-pip-version-check", "-q"])
                // No byte-compiling of every installed module (dask, numpy, mujoco, …): a
                // module is compiled when first imported. 36 -> 22 s for a fresh venv here.
                .arg("--no-compile")
                .args(args)
                .current_dir(root()),
            "pip",
        );
        assert!(
            o.status.success(),
            "`pip install {}` in {} failed (PyPI reachable?):\n{}{}",
            args.join(" "),
            venv.display(),
            text(&o.stdout),
            text(&o.stderr)
        );
    };
    if lacks.contains("requirements") {
        pip(&["-r", "python/requirements.txt"]);
    }
    if lacks.contains("deltaloop") || lacks.contains("requirements") {
        pip(&["--force-reinstall", "--no-deps", "./python"]);
    }
    let left = venv_lacks(&py);
    assert!(
        left.is_empty(),
        "{} still lacks {left} after pip install",
        venv.display()
    );
    py
}

/// Runs `code` with the venv's python from the repository root; its stdout, asserted to succeed.
pub fn py_snippet(code: &str) -> String {
    let o = run_cmd(
        Command::new(python())
            .args(["-c", code])
            .current_dir(root()),
        "python snippet",
    );
    assert!(o.status.success(), "python failed:\n{}", text(&o.stderr));
    text(&o.stdout)
}
