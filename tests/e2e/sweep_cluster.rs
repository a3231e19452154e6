//! Sweeps beyond one machine: `deltaloop sweep plan | run | merge`, and `python -m deltaloop.dask`
//! on a real Dask cluster (a scheduler and two worker processes over TCP on 127.0.0.1, started
//! here and killed at the end, also when a test fails), and the Slurm job script of
//! dask-jobqueue. The Python side comes from the project's own venv (tests/e2e/common/python.rs).

use crate::common;

use common::python::{python, run_cmd, text};
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_deltaloop");

/// `deltaloop args…` run in `dir`.
fn dl(dir: &Path, args: &[&str]) -> Output {
    run_cmd(Command::new(BIN).args(args).current_dir(dir), "deltaloop")
}

fn ok(o: &Output) -> String {
    assert!(o.status.success(), "{}{}", text(&o.stdout), text(&o.stderr));
    text(&o.stdout)
}

fn err(o: &Output) -> String {
    assert!(!o.status.success(), "should fail: {}", text(&o.stdout));
    text(&o.stderr)
}

/// A sweep of `laws × ℓ × d` points on S1/S2 (matched), in `dir/sw.toml`, cheap points.
fn write_sweep(dir: &Path, name: &str, scenarios: &str, ells: &str, ds: &str) -> &'static str {
    std::fs::write(
        dir.join("base.toml"),
        "[scenario]\npath = \"s1\"\n[plant]\nfriction = true\n",
    )
    .unwrap();
    std::fs::write(
        dir.join("sw.toml"),
        format!(
            "name = \"{name}\"\nbase = \"base.toml\"\nscenarios = {scenarios}\npresets = [\"matched\"]\nlaws = [\"tdc\", \"tde-is\"]\ntde_delay_samples = {ells}\ntransport_delay_samples = {ds}\n"
        ),
    )
    .unwrap();
    "sw.toml"
}

/// The files a sweep writes (not the lock file): name -> bytes.
fn outputs(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut v: Vec<(String, Vec<u8>)> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.is_file() && !p.ends_with(".deltaloop-lock"))
        .map(|p| {
            (
                p.file_name().unwrap().to_string_lossy().into_owned(),
                std::fs::read(&p).unwrap(),
            )
        })
        .collect();
    v.sort();
    v
}

fn assert_same_outputs(a: &Path, b: &Path) {
    let (x, y) = (outputs(a), outputs(b));
    let names = |v: &[(String, Vec<u8>)]| v.iter().map(|f| f.0.clone()).collect::<Vec<_>>();
    assert_eq!(names(&x), names(&y), "{} vs {}", a.display(), b.display());
    for ((n, p), (_, q)) in x.iter().zip(&y) {
        assert!(
            p == q,
            "{n} differs between {} and {}",
            a.display(),
            b.display()
        );
    }
    for f in [
        "sweep.csv",
        "sweep.json",
        "report.md",
        "rms_vs_tde_delay.png",
    ] {
        assert!(x.iter().any(|(n, _)| n == f), "{f} written");
    }
}

/// Plan, shards, merge: byte for byte the one-machine sweep; missing, duplicated and foreign
/// points are named.
#[test]
fn shards_merge_into_the_one_machine_sweep_and_bad_merges_name_the_points() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let sw = write_sweep(d, "shards", "[\"s1\"]", "[1, 2, 3]", "[0, 1]");
    ok(&dl(d, &["sweep", sw, "--out", "one"]));
    let plan: serde_json::Value =
        serde_json::from_str(&ok(&dl(d, &["sweep", "plan", sw, "--json"]))).unwrap();
    let ids: Vec<&str> = plan["points"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p["id"].as_str().unwrap())
        .collect();
    assert_eq!(ids.len(), 12);
    ok(&dl(
        d,
        &["sweep", "run", sw, "--shard", "1/3", "--out", "a"],
    ));
    ok(&dl(
        d,
        &[
            "sweep", "run", sw, "--shard", "2/3", "--out", "b", "--jobs", "1",
        ],
    ));
    ok(&dl(
        d,
        &["sweep", "run", sw, "--points", "2,5,8,11", "--out", "c"],
    ));
    let m = ok(&dl(d, &["sweep", "merge", "a", "b", "c", "--out", "m"]));
    assert!(m.contains("12 of 12 points"), "{m}");
    assert_same_outputs(&d.join("one"), &d.join("m"));
    // The shard says what it holds.
    let man: serde_json::Value =
        serde_json::from_slice(&std::fs::read(d.join("c/shard.json")).unwrap()).unwrap();
    assert_eq!(man["plan_hash"], plan["plan_hash"]);
    assert_eq!(
        man["points"],
        serde_json::json!([ids[2], ids[5], ids[8], ids[11]])
    );

    // Missing: named, with the --points to run them; no output folder made.
    let e = err(&dl(d, &["sweep", "merge", "a", "c", "--out", "x"]));
    assert!(
        e.contains("4 of 12 points missing, in no shard: ")
            && e.contains(&format!("{} (s1/matched/tdc ℓ=1 d=1)", ids[1]))
            && e.trim_end()
                .ends_with("`deltaloop sweep run sw.toml --points 1,4,7,10`"),
        "{e}"
    );
    assert!(!d.join("x").exists());
    // Duplicated.
    ok(&dl(
        d,
        &["sweep", "run", sw, "--points", "4-5", "--out", "dup"],
    ));
    let e = err(&dl(
        d,
        &["sweep", "merge", "a", "b", "c", "dup", "--out", "x"],
    ));
    assert!(
        e.contains(&format!(
            "sweep merge: 2 point(s) merged more than once: {} (s1/matched/tdc ℓ=3 d=0) in b and dup, {} (s1/matched/tdc ℓ=3 d=1) in c and dup; ",
            ids[4], ids[5]
        )),
        "{e}"
    );
    // Another plan (one base constant changed).
    std::fs::create_dir(d.join("other")).unwrap();
    std::fs::write(d.join("other/base.toml"), "[scenario]\npath = \"s1\"\n").unwrap();
    std::fs::copy(d.join(sw), d.join("other/sw.toml")).unwrap();
    ok(&dl(
        d,
        &[
            "sweep",
            "run",
            "other/sw.toml",
            "--points",
            "1",
            "--out",
            "o",
        ],
    ));
    let e = err(&dl(d, &["sweep", "merge", "a", "b", "o", "--out", "x"]));
    assert!(
        e.contains("shard o is from another plan (")
            && e.contains("a different sweep file or base config"),
        "{e}"
    );
    // A shard whose files do not match its manifest.
    let t = std::fs::read_to_string(d.join("c/sweep.toml")).unwrap();
    std::fs::write(d.join("c/sweep.toml"), t.replace("[\n    1,", "[\n    4,")).unwrap();
    let e = err(&dl(d, &["sweep", "merge", "c", "a", "b", "--out", "x"]));
    assert!(
        e.contains("shard c: its sweep.toml and base.toml give plan "),
        "{e}"
    );
    let e = err(&dl(d, &["sweep", "merge", "a", "nope", "--out", "x"]));
    assert!(e.contains("nope is not a sweep shard folder"), "{e}");
    // --allow-missing writes what is there, says what is not, and fails.
    let e = err(&dl(
        d,
        &["sweep", "merge", "a", "--allow-missing", "--out", "part"],
    ));
    assert!(e.contains("8 of 12 points missing"), "{e}");
    let md = std::fs::read_to_string(d.join("part/report.md")).unwrap();
    assert!(
        md.starts_with("> **Incomplete**: 8 of 12 points are missing"),
        "{md}"
    );
    assert!(!d.join("x").exists());
}

/// The Dask processes of a test, each in its own process group; all killed on drop (a failed
/// assertion included), with whatever they started.
struct Procs(Vec<Child>);

impl Procs {
    fn spawn(&mut self, cmd: &mut Command, log: &Path) -> u32 {
        let f = std::fs::File::create(log).unwrap();
        let c = cmd
            .stdin(Stdio::null())
            .stdout(f.try_clone().unwrap())
            .stderr(f)
            .process_group(0)
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {cmd:?}: {e}"));
        let pid = c.id();
        self.0.push(c);
        pid
    }
}

impl Drop for Procs {
    fn drop(&mut self) {
        for c in &mut self.0 {
            // SAFETY: signalling the process group of a child we started.
            unsafe { libc::kill(-(c.id() as i32), libc::SIGKILL) };
            let _ = c.wait();
        }
    }
}

fn wait_for(what: &str, secs: u64, mut ready: impl FnMut() -> bool) {
    let t0 = Instant::now();
    while !ready() {
        assert!(
            t0.elapsed() < Duration::from_secs(secs),
            "{what}: not within {secs} s"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// Children of `pid` running `deltaloop sweep run`.
fn sweep_children(pid: u32) -> Vec<u32> {
    let mut found = Vec::new();
    for e in std::fs::read_dir("/proc").unwrap().flatten() {
        let Ok(p) = e.file_name().to_string_lossy().parse::<u32>() else {
            continue;
        };
        let stat = std::fs::read_to_string(e.path().join("stat")).unwrap_or_default();
        // The parent pid is the second field after the `(comm)`.
        let ppid = stat
            .rsplit_once(") ")
            .and_then(|(_, rest)| rest.split(' ').nth(1))
            .and_then(|s| s.parse::<u32>().ok());
        let cmd = std::fs::read(e.path().join("cmdline")).unwrap_or_default();
        if ppid == Some(pid) && String::from_utf8_lossy(&cmd).contains("sweep\0run") {
            found.push(p);
        }
    }
    found
}

fn driver(dir: &Path, args: &[&str]) -> Command {
    let mut c = Command::new(python());
    c.args(["-m", "deltaloop.dask"])
        .args(args)
        .args(["--deltaloop", BIN])
        .current_dir(dir);
    c
}

/// A real local Dask cluster runs a 40-point inproc sweep; one of its two workers is SIGKILLed
/// while it runs a point; the merged result is the one-machine sweep byte for byte. Then a point
/// that fails the same way twice is reported, and the others are merged.
#[test]
fn dask_cluster_sweep_equals_one_machine_and_survives_a_killed_worker() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let py = python();
    let mut procs = Procs(Vec::new());
    let sched_file = d.join("scheduler.json");
    procs.spawn(
        Command::new(py)
            .args([
                "-m",
                "distributed.cli.dask_scheduler",
                "--host",
                "127.0.0.1",
                "--port",
                "0",
            ])
            .args(["--no-dashboard", "--scheduler-file"])
            .arg(&sched_file),
        &d.join("scheduler.log"),
    );
    wait_for("the scheduler file", 60, || sched_file.is_file());
    let tmpdir = d.join("tmp");
    std::fs::create_dir(&tmpdir).unwrap();
    let workers: Vec<(u32, PathBuf)> = (0..2)
        .map(|i| {
            let log = d.join(format!("worker{i}.log"));
            let pid = procs.spawn(
                Command::new(py)
                    .args(["-m", "distributed.cli.dask_worker", "--scheduler-file"])
                    .arg(&sched_file)
                    .args(["--nthreads", "1", "--resources", "CPU=1", "--no-nanny"])
                    .args(["--no-dashboard", "--host", "127.0.0.1"])
                    // A killed worker leaves its task's temporary folder: keep it in ours.
                    .env("TMPDIR", &tmpdir),
                &log,
            );
            (pid, log)
        })
        .collect();
    for (_, log) in &workers {
        wait_for("a worker registered", 60, || {
            std::fs::read_to_string(log).is_ok_and(|s| s.contains("Registered to"))
        });
    }

    // 2 scenarios × 2 laws × 2 ℓ × 2 d = 16 points, run on this machine first.
    let sw = write_sweep(d, "dask16", "[\"s1\", \"s2\"]", "[1, 3]", "[0, 1]");
    ok(&dl(d, &["sweep", sw, "--out", "one"]));

    let sched = sched_file.to_str().unwrap();
    let mut drv = driver(d, &[sw, "--scheduler-file", sched, "--out", "dask"]);
    let log = d.join("driver.log");
    let t0 = Instant::now();
    procs.spawn(&mut drv, &log);
    let (victim, _) = workers[0];
    let mut in_flight = Vec::new();
    wait_for("worker 0 running a point", 60, || {
        in_flight = sweep_children(victim);
        !in_flight.is_empty()
    });
    // SAFETY: the worker's process group, ours: the worker and the point it runs die at once.
    assert_eq!(unsafe { libc::kill(-(victim as i32), libc::SIGKILL) }, 0);
    let drv = procs.0.last_mut().unwrap();
    let status = loop {
        if let Some(s) = drv.try_wait().unwrap() {
            break s;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(120),
            "driver: not within 120 s"
        );
        std::thread::sleep(Duration::from_millis(50));
    };
    let said = std::fs::read_to_string(&log).unwrap();
    assert!(status.success(), "{said}");
    assert!(said.contains("16 points, "), "{said}");
    assert_same_outputs(&d.join("one"), &d.join("dask"));
    let rows = std::fs::read_to_string(d.join("dask/sweep.csv")).unwrap();
    assert_eq!(rows.lines().count(), 17, "every point once");

    // A point whose run fails the same way every time (a worker binary that crashes on it):
    // reported after two attempts; the batch it was in is retried point by point; the rest is
    // merged, and the report names it.
    let fake = d.join("fake-deltaloop");
    std::fs::write(
        &fake,
        format!(
            "#!/bin/sh\ncase \" $* \" in *\" --points 3 \"*|*\" --points 0-3 \"*) echo 'deltaloop: error: simulated crash' >&2; exit 101;; esac\nexec {BIN} \"$@\"\n"
        ),
    )
    .unwrap();
    std::fs::set_permissions(&fake, std::os::unix::fs::PermissionsExt::from_mode(0o755)).unwrap();
    std::fs::create_dir(d.join("f")).unwrap();
    let sw8 = write_sweep(&d.join("f"), "fail8", "[\"s1\"]", "[1, 2]", "[0, 1]");
    let o = run_cmd(
        driver(
            &d.join("f"),
            &[
                sw8,
                "--scheduler-file",
                sched,
                "--out",
                "out",
                "--batch",
                "4",
            ],
        )
        .arg("--worker-deltaloop")
        .arg(&fake),
        "dask driver",
    );
    let e = text(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{e}");
    let plan: serde_json::Value =
        serde_json::from_str(&ok(&dl(&d.join("f"), &["sweep", "plan", sw8, "--json"]))).unwrap();
    let id3 = plan["points"][3]["id"].as_str().unwrap();
    assert!(e.contains("batch 0-3 failed"), "{e}");
    assert!(
        e.contains(&format!(
            "1 of 8 points failed twice ({id3}: SweepError: deltaloop exited with 101: deltaloop: error: simulated crash)"
        )),
        "{e}"
    );
    let md = std::fs::read_to_string(d.join("f/out/report.md")).unwrap();
    assert!(
        md.starts_with("> **Incomplete**: 1 of 8 points are missing"),
        "{md}"
    );
    assert!(md.contains(id3), "{md}");
    let rows = std::fs::read_to_string(d.join("f/out/sweep.csv")).unwrap();
    assert_eq!(rows.lines().count(), 8, "7 points and the header");
    assert!(!rows.contains(id3));
}

/// What a task holds: inproc points share batches and 1 CPU each; a realtime point runs alone
/// with 2 CPUs and the worker's one realtime slot.
#[test]
fn realtime_points_run_alone_on_two_cpus() {
    let out = common::python::py_snippet(
        r#"
from deltaloop.dask import batches, resources_for
pts = [{"index": i, "mode": m} for i, m in enumerate(
    ["inproc"] * 5 + ["realtime", "realtime"] + ["inproc"] * 3)]
b = batches(pts, 4)
print(b)
print([resources_for(pts, x) for x in b])
"#,
    );
    assert_eq!(
        out.trim(),
        "[[0, 1, 2, 3], [4], [5], [6], [7, 8, 9]]\n\
         [{'CPU': 1}, {'CPU': 1}, {'CPU': 2, 'RT': 1}, {'CPU': 2, 'RT': 1}, {'CPU': 1}]"
    );
}

/// The Slurm job script dask-jobqueue would submit, from a `[slurm]` section and flags.
#[test]
fn slurm_job_script_from_config_and_flags() {
    let tmp = tempfile::tempdir().unwrap();
    let cfg = tmp.path().join("slurm.toml");
    std::fs::write(
        &cfg,
        "[slurm]\nqueue = \"compute\"\naccount = \"ctrl-lab\"\nwalltime = \"02:00:00\"\ncores = 8\nmemory = \"16GB\"\njob_extra_directives = [\"--exclusive\"]\n",
    )
    .unwrap();
    let o = run_cmd(
        Command::new(python())
            .args([
                "-m",
                "deltaloop.dask",
                "configs/delay-sweep.toml",
                "--slurm",
            ])
            .arg(&cfg)
            .args([
                "--walltime",
                "04:00:00",
                "--out",
                "unused",
                "--print-job-script",
            ])
            .current_dir(common::python::root()),
        "job script",
    );
    let s = ok(&o);
    for line in [
        "#SBATCH -p compute",
        "#SBATCH -A ctrl-lab",
        "#SBATCH -t 04:00:00",
        "#SBATCH --cpus-per-task=8",
        "#SBATCH --mem=15G",
        "#SBATCH --exclusive",
        "--nthreads 8",
        "--resources CPU=8,RT=1",
    ] {
        assert!(s.contains(line), "{line:?} not in:\n{s}");
    }
    let o = run_cmd(
        Command::new(python())
            .args(["-m", "deltaloop.dask", "x.toml", "--slurm"])
            .arg(&cfg)
            .args(["--cores", "0", "--out", "unused", "--print-job-script"]),
        "bad cores",
    );
    assert_eq!(
        text(&o.stderr).trim(),
        "deltaloop.dask: error: slurm key `cores` = 0 is out of range: an integer >= 1"
    );
}
