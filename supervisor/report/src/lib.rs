//! What a run leaves for people and tools: the run folder (claimed, written whole or not at all:
//! `summary.json`, `trace.csv` and its columns in [`trace`], `report.md` and the terminal tables
//! in [`report`], the figures in [`plot`]), the note of a run across two hosts ([`link`]) and the
//! MCAP file and live bus for Foxglove, PlotJuggler and ros2 bag ([`mcap`]). It reads a run's
//! records and timing; it runs nothing. The resolved `config.toml` is written by the runner,
//! before the runs.

pub mod link;
pub mod mcap;
pub mod plot;
pub mod report;
pub mod trace;

pub use trace::{TraceWriter, join_trace, trace_part};

use anyhow::{Context, Result};
use deltaloop_config::{Compensation, LoopMode, Preset};
use deltaloop_law::{ControllerParams, Law};
use deltaloop_study::analysis::Mismatch;
use deltaloop_study::record::metrics::LawMetrics;
use deltaloop_timing::TimingSummary;
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// `summary.json`.
#[derive(Debug, Serialize)]
pub struct Summary<'a> {
    /// The scenario's name (`name` in its file).
    pub scenario: &'a str,
    pub mode: LoopMode,
    /// The controller that ran, when it is not the built-in one (`controller.label`, or its
    /// command's program): each law's figures are that process's, answering as the law.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub controller_label: Option<&'a str>,
    pub preset: Preset,
    pub command: &'a str,
    pub started_utc: String,
    /// Control period, s.
    pub ts_s: f64,
    /// N: ticks after tick 0 covered by the metrics.
    pub ticks: usize,
    /// Motion duration T, s.
    pub motion_duration_s: f64,
    pub friction: bool,
    pub tau_max_nm: f64,
    pub tde_delay_samples: u32,
    /// The laws' delay compensation (`controller.compensate`): `none` or `predict`.
    pub compensate: Compensation,
    pub controller: ControllerParams,
    pub mismatch: &'a Mismatch,
    /// Ctrl-C / SIGTERM stopped the run: the data is partial.
    pub interrupted: bool,
    /// Metrics per law, keyed by law name (in report order).
    pub laws: BTreeMap<Law, &'a LawMetrics>,
    /// The iceoryx2 run id of each law's process pair (process modes only).
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub run_ids: BTreeMap<Law, &'a str>,
    /// Loop timing per law (process modes only), keyed by law name.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub timing: BTreeMap<Law, &'a TimingSummary>,
}

/// A progress bar over `len` steps on stderr, or a hidden one (`show` false: tests, pipes).
pub fn progress_bar(len: usize, show: bool) -> indicatif::ProgressBar {
    let bar = if show {
        indicatif::ProgressBar::new(len as u64)
    } else {
        indicatif::ProgressBar::hidden()
    };
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{spinner} [{elapsed_precise}] {bar:30} {pos}/{len} {msg}",
        )
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    bar
}

/// The default run folder: `runs/<UTC time>-<scenario name>`.
pub fn default_run_dir(name: &str) -> PathBuf {
    let stamp = chrono::Utc::now().format("%Y%m%d-%H%M%S");
    PathBuf::from("runs").join(format!("{stamp}-{name}"))
}

/// A run folder this process holds: created (or emptied with `force`), and locked for as long as
/// this value lives, so no two runs ever write into one folder.
#[derive(Debug)]
pub struct RunFolder {
    dir: PathBuf,
    _lock: std::fs::File,
    /// The topmost folder [`RunFolder::release_unused`] may remove: the first the claim made, or
    /// `dir` if it was deltaloop's already (None: a folder of the user's, kept).
    removable: Option<PathBuf>,
}

/// The lock file in every folder a command claimed. Its content, [`MARK`], marks the folder as
/// deltaloop's: only a claim that succeeded writes it.
const LOCK_FILE: &str = ".deltaloop-lock";

/// What a successful claim writes into [`LOCK_FILE`]: the one mark `--force` trusts. An empty
/// lock file (left by a refused command of an older deltaloop, or made by anyone) or a
/// stranger's `config.toml` does not make a folder deltaloop's.
const MARK: &[u8] =
    b"deltaloop output folder: `--force` may empty it; locked while a command writes here\n";

/// A folder is, holds or lies inside something the command reads: refused, `--force` or not.
fn refuse_sources<P: AsRef<Path>>(dir: &Path, sources: &[(P, &str)]) -> Result<()> {
    let here = resolved(dir);
    for (src, what) in sources {
        let src = src.as_ref();
        let there = resolved(src);
        let how = if here == there {
            "is"
        } else if there.starts_with(&here) {
            "contains"
        } else if here.starts_with(&there) {
            "is inside"
        } else {
            continue;
        };
        anyhow::bail!(
            "--out {} {how} {what} {}: writing there would destroy what is read; choose another --out (--force does not change this)",
            dir.display(),
            src.display()
        );
    }
    Ok(())
}

/// Takes the lock of an open lock file without waiting; false if another run holds it.
fn try_lock(f: &std::fs::File) -> bool {
    // SAFETY: flock on a descriptor we own; non-blocking, released when the file closes.
    unsafe {
        libc::flock(
            std::os::fd::AsRawFd::as_raw_fd(f),
            libc::LOCK_EX | libc::LOCK_NB,
        ) == 0
    }
}

/// Whether `dir` is a deltaloop folder: its lock file carries [`MARK`].
fn is_marked(dir: &Path) -> bool {
    let mut head = [0u8; MARK.len()];
    std::fs::File::open(dir.join(LOCK_FILE))
        .and_then(|mut f| std::io::Read::read_exact(&mut f, &mut head))
        .is_ok_and(|()| head == MARK)
}

impl RunFolder {
    /// Claims `dir`: refuses a non-empty folder unless `force` (then empties it, but only if it
    /// is a deltaloop folder: one a command claimed, its lock file marked so), and refuses a
    /// folder another run holds, `force` or not. A refusal leaves nothing behind: no lock file,
    /// no folder that was not there.
    /// A symbolic link is refused, `force` or not: emptying it would empty whatever it points to.
    pub fn claim(dir: &Path, force: bool) -> Result<Self> {
        Self::claim_apart::<&Path>(dir, force, &[])
    }

    /// [`RunFolder::claim`], refusing also, `force` or not, a folder that is, contains or lies
    /// inside one of `sources` (every file or folder the command reads, with a few words naming
    /// it): emptying it would destroy the command's own input. Paths are compared resolved
    /// (links, `..`), so no spelling of the same folder slips through.
    pub fn claim_apart<P: AsRef<Path>>(
        dir: &Path,
        force: bool,
        sources: &[(P, &str)],
    ) -> Result<Self> {
        let shown = dir.display();
        if std::fs::symlink_metadata(dir).is_ok_and(|m| m.file_type().is_symlink()) {
            let to = std::fs::read_link(dir)
                .map(|t| format!(" (to {})", t.display()))
                .unwrap_or_default();
            anyhow::bail!(
                "run folder {shown} is a symbolic link{to}: deltaloop never writes through a link; give a real folder as --out"
            );
        }
        refuse_sources(dir, sources)?;
        // Everything is decided before anything is written: a refusal creates nothing.
        let doomed = Self::survey(dir, force)?;
        let removable = if is_marked(dir) {
            Some(dir.to_path_buf())
        } else {
            dir.ancestors()
                .take_while(|a| !a.as_os_str().is_empty() && !a.exists())
                .last()
                .map(Path::to_path_buf)
        };
        std::fs::create_dir_all(dir)
            .with_context(|| format!("cannot create run folder {shown}"))?;
        let lock = std::fs::OpenOptions::new()
            .create(true)
            .truncate(false)
            .write(true)
            .open(dir.join(LOCK_FILE))
            .with_context(|| format!("cannot create {}", dir.join(LOCK_FILE).display()))?;
        if !try_lock(&lock) {
            // Another run took it since the survey: the folder and its lock file are its own.
            anyhow::bail!(
                "run folder {shown} is in use by another deltaloop run: choose another --out"
            );
        }
        for p in doomed {
            let r = if p.is_dir() && !p.is_symlink() {
                std::fs::remove_dir_all(&p)
            } else {
                std::fs::remove_file(&p)
            };
            r.with_context(|| format!("--force: cannot remove {}", p.display()))?;
        }
        lock.set_len(0)
            .and_then(|()| std::io::Write::write_all(&mut &lock, MARK))
            .with_context(|| format!("cannot write {}", dir.join(LOCK_FILE).display()))?;
        Ok(Self {
            dir: dir.to_path_buf(),
            _lock: lock,
            removable,
        })
    }

    /// What claiming `dir` would remove (its entries but the lock file), or why it is refused:
    /// held by another run, or not empty without `force`, or not empty and not deltaloop's.
    /// Reads only.
    fn survey(dir: &Path, force: bool) -> Result<Vec<PathBuf>> {
        let shown = dir.display();
        let entries: Vec<PathBuf> = match std::fs::read_dir(dir) {
            Ok(rd) => rd.filter_map(|e| e.ok().map(|e| e.path())).collect(),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
            Err(e) => anyhow::bail!("cannot read run folder {shown}: {e}"),
        };
        if std::fs::File::open(dir.join(LOCK_FILE)).is_ok_and(|f| !try_lock(&f)) {
            anyhow::bail!(
                "run folder {shown} is in use by another deltaloop run: choose another --out"
            );
        }
        let theirs: Vec<PathBuf> = entries
            .into_iter()
            .filter(|p| !p.ends_with(LOCK_FILE))
            .collect();
        if theirs.is_empty() {
            return Ok(theirs);
        }
        if !force {
            anyhow::bail!(
                "run folder {shown} is not empty ({} entries): choose another --out, or pass --force to empty and reuse it",
                theirs.len()
            );
        }
        if !is_marked(dir) {
            anyhow::bail!(
                "run folder {shown} is not empty and does not look like a deltaloop run folder (no deltaloop command wrote it: its {LOCK_FILE} is missing or unmarked): refusing to empty it, even with --force"
            );
        }
        Ok(theirs)
    }

    /// Whether two paths name the same folder (resolved: links, `..`), existing or not.
    pub fn same(a: &Path, b: &Path) -> bool {
        resolved(a) == resolved(b)
    }

    /// The folder.
    pub fn path(&self) -> &Path {
        &self.dir
    }

    /// Gives the folder up; if nothing but its lock file was written (a command refused after
    /// the claim), removes the lock file, and the folder unless it was a folder of the user's
    /// (with the folders the claim made for it): no empty folder is left behind.
    pub fn release_unused(self) {
        let only_lock = std::fs::read_dir(&self.dir).is_ok_and(|entries| {
            entries
                .flatten()
                .all(|e| e.file_name() == std::ffi::OsStr::new(LOCK_FILE))
        });
        if only_lock {
            let _ = std::fs::remove_file(self.dir.join(LOCK_FILE));
            if let Some(top) = &self.removable {
                // Only empty folders go (remove_dir): from `dir` up to the first it made.
                for d in self.dir.ancestors() {
                    if std::fs::remove_dir(d).is_err() || d == top.as_path() {
                        break;
                    }
                }
            }
        }
    }
}

/// `p` absolute, with links and `..` resolved as far as it exists; the part that does not exist
/// yet is appended as written, `..` folded (nothing in it can be a link).
fn resolved(p: &Path) -> PathBuf {
    use std::path::Component;
    let abs = std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf());
    let mut base = abs.as_path();
    let mut rest = Vec::new();
    let mut out = loop {
        if let Ok(c) = base.canonicalize() {
            break c;
        }
        match (base.parent(), base.components().next_back()) {
            (Some(up), Some(last)) => {
                rest.push(last);
                base = up;
            }
            _ => break PathBuf::from("/"),
        }
    };
    for c in rest.into_iter().rev() {
        match c {
            Component::ParentDir => {
                out.pop();
            }
            Component::Normal(n) => out.push(n),
            _ => {}
        }
    }
    out
}

/// UTC now, RFC 3339.
pub fn now_utc() -> String {
    chrono::Utc::now().to_rfc3339_opts(chrono::SecondsFormat::Secs, true)
}

/// Writes a text file whole or not at all (see [`write_whole`]), naming it on failure.
pub fn write_text(path: &Path, text: &str) -> Result<()> {
    write_whole(path, text.as_bytes())
}

/// Writes `bytes` to `path` whole or not at all: into a temporary file beside it, synced, then
/// renamed over `path`. A full disk leaves no empty or cut file (the temporary one is removed),
/// and a link at `path` is replaced, never written through. Errors name `path`.
pub fn write_whole(path: &Path, bytes: &[u8]) -> Result<()> {
    use std::io::Write as _;
    let named = || format!("cannot write {}", path.display());
    let mut tmp = temp_beside(path).with_context(named)?;
    // The file's own errors: the temporary name is no concern of the message.
    tmp.as_file_mut()
        .write_all(bytes)
        .and_then(|()| tmp.as_file().sync_all())
        .with_context(named)?;
    tmp.persist(path).map_err(|e| e.error).with_context(named)?;
    sync_parent(path);
    Ok(())
}

/// A new temporary file in `path`'s folder, `.<name>.<random>.tmp`, removed when dropped unless
/// persisted. Its mode is what `File::create` gives (0666 less the umask).
pub fn temp_beside(path: &Path) -> std::io::Result<tempfile::NamedTempFile> {
    use std::os::unix::fs::PermissionsExt;
    // The temporary name is `.<name>.XXXXXX.tmp`: cut <name> so that it stays within the 255
    // bytes a file name may have, whatever the output's own name.
    let mut name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let mut end = name.len().min(200);
    while !name.is_char_boundary(end) {
        end -= 1;
    }
    name.truncate(end);
    tempfile::Builder::new()
        .prefix(&format!(".{name}."))
        .suffix(".tmp")
        .permissions(std::fs::Permissions::from_mode(0o666))
        .tempfile_in(parent_of(path))
        .map_err(without_temp_name)
}

/// The OS's reason alone (tempfile appends `at path "<temporary name>"`): the caller names the
/// file the user asked for.
fn without_temp_name(e: std::io::Error) -> std::io::Error {
    let said = e.to_string();
    match said.rfind(" at path \"") {
        Some(at) => std::io::Error::new(e.kind(), &said[..at]),
        None => e,
    }
}

/// The folder `path` is in ("." for a bare name).
fn parent_of(path: &Path) -> &Path {
    match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    }
}

/// Syncs the folder of `path`, so a rename into it outlives a power cut (best effort: the file
/// itself is already whole).
pub fn sync_parent(path: &Path) {
    if let Ok(d) = std::fs::File::open(parent_of(path)) {
        let _ = d.sync_all();
    }
}

/// Writes `summary.json` and `report.md` into `dir` and joins the trace parts of `laws` into
/// `trace.csv` (None: the run wrote no trace, `record.trace = false`). The folder's
/// `config.toml` is not written here: the runner writes it once, before the runs (the
/// child processes read it, and it documents a run that fails).
///
/// Each file is attempted whatever became of the others (on a full disk the trace, which needs
/// no free space for its first law, is kept though the summary cannot be written); each is whole
/// or absent. The error names every file that could not be written.
pub fn write_run_folder(
    dir: &Path,
    summary: &Summary<'_>,
    laws: Option<&[Law]>,
    report_md: &str,
) -> Result<()> {
    std::fs::create_dir_all(dir)
        .with_context(|| format!("cannot create run folder {}", dir.display()))?;
    let results = [
        laws.map_or(Ok(()), |laws| join_trace(dir, laws)),
        serde_json::to_string_pretty(summary)
            .map_err(anyhow::Error::from)
            .and_then(|json| write_text(&dir.join("summary.json"), &json)),
        write_text(&dir.join("report.md"), report_md),
    ];
    let failed: Vec<String> = results
        .into_iter()
        .filter_map(|r| r.err().map(|e| format!("{e:#}")))
        .collect();
    if failed.is_empty() {
        Ok(())
    } else {
        anyhow::bail!("{}", failed.join("; "))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tmp(tag: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("deltaloop-out-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(d.join("run")).unwrap();
        d
    }

    /// Regression: the temporary file beside an output of a 250-byte name (a valid name) had a
    /// name past the 255 bytes a file system allows, so the write failed.
    #[test]
    fn regression_an_output_with_a_long_name_is_written() {
        let d = tmp("long");
        let path = d.join(format!("{}.mcap", "é".repeat(122)));
        assert_eq!(path.file_name().unwrap().len(), 249);
        write_text(&path, "whole").unwrap();
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "whole");
        let _ = std::fs::remove_dir_all(&d);
    }

    /// A text file is written whole or not at all: a failed write (here the name is a folder)
    /// names the file and leaves no temporary file; a link at the name is replaced, its target
    /// untouched.
    #[test]
    fn a_file_is_written_whole_or_not_at_all() {
        let d = tmp("whole");
        let e = write_text(&d.join("run"), "x").unwrap_err();
        let said = format!("{e:#}");
        assert!(
            said.starts_with(&format!("cannot write {}: ", d.join("run").display())),
            "{said}"
        );
        let names = || -> Vec<String> {
            let mut n: Vec<String> = std::fs::read_dir(&d)
                .unwrap()
                .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
                .collect();
            n.sort();
            n
        };
        assert_eq!(names(), ["run"]);
        let missing = d.join("no/summary.json");
        let e = write_text(&missing, "{}").unwrap_err();
        assert_eq!(
            format!("{e:#}"),
            format!(
                "cannot write {}: No such file or directory (os error 2)",
                missing.display()
            ),
            "the file asked for, not a temporary name"
        );
        std::fs::write(d.join("target"), "keep").unwrap();
        std::os::unix::fs::symlink(d.join("target"), d.join("summary.json")).unwrap();
        write_text(&d.join("summary.json"), "{}").unwrap();
        assert_eq!(std::fs::read_to_string(d.join("target")).unwrap(), "keep");
        assert!(!d.join("summary.json").is_symlink());
        assert_eq!(names(), ["run", "summary.json", "target"]);
        let _ = std::fs::remove_dir_all(&d);
    }

    /// A path is compared resolved: links and `..` in the part that exists, `..` folded in the
    /// part that does not.
    #[test]
    fn paths_are_compared_resolved() {
        let d = tmp("resolve");
        std::os::unix::fs::symlink(d.join("run"), d.join("link")).unwrap();
        let run = d.join("run").canonicalize().unwrap();
        assert_eq!(resolved(&d.join("link")), run);
        assert_eq!(resolved(&d.join("run/new/../.")), run);
        assert_eq!(resolved(&d.join("run/a/b/../c")), run.join("a/c"));
        assert!(RunFolder::same(&d.join("link/x"), &d.join("run/./x")));
        let _ = std::fs::remove_dir_all(&d);
    }

    /// Regression: replay claimed its --out with force on, and the run it read could be that
    /// folder. A folder that is, holds or lies inside a source is refused before anything is
    /// created; a link is refused, its target untouched.
    #[test]
    fn regression_claim_refuses_sources_and_links() {
        let d = tmp("claim");
        let run = d.join("run");
        std::fs::write(run.join("config.toml"), "x").unwrap();
        let src = [(run.as_path(), "the run folder")];
        for (out, how) in [
            (run.clone(), "is the run folder"),
            (d.clone(), "contains the run folder"),
            (run.join("sub"), "is inside the run folder"),
        ] {
            let e = RunFolder::claim_apart(&out, true, &src)
                .unwrap_err()
                .to_string();
            assert!(e.contains(how), "{e}");
        }
        assert!(!run.join("sub").exists() && run.join("config.toml").exists());
        std::os::unix::fs::symlink(&run, d.join("link")).unwrap();
        let e = RunFolder::claim(&d.join("link"), true)
            .unwrap_err()
            .to_string();
        assert!(e.contains("is a symbolic link"), "{e}");
        assert!(run.join("config.toml").exists());
        let other = RunFolder::claim_apart(&d.join("other"), false, &src).unwrap();
        assert!(other.path().join(LOCK_FILE).exists());
        let _ = std::fs::remove_dir_all(&d);
    }

    /// Every entry of `dir` by name, sorted.
    fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .flatten()
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    /// Regression: a refused claim left `.deltaloop-lock` in the folder, and that file alone made
    /// it deltaloop's: the next claim with `force` emptied it. Refused without and with `force`,
    /// the folder keeps its one file and gains nothing; a folder that did not exist is not made.
    #[test]
    fn regression_a_refused_claim_leaves_no_lock_file() {
        let d = tmp("refused");
        let thesis = d.join("thesis");
        std::fs::create_dir_all(&thesis).unwrap();
        std::fs::write(thesis.join("thesis.tex"), "precious").unwrap();
        for force in [false, true, true] {
            let e = RunFolder::claim(&thesis, force).unwrap_err().to_string();
            let says = if force {
                "does not look like"
            } else {
                "is not empty"
            };
            assert!(e.contains(says), "{e}");
            assert_eq!(names(&thesis), ["thesis.tex"]);
        }
        let src = [(thesis.as_path(), "the source")];
        assert!(RunFolder::claim_apart(&thesis.join("new"), true, &src).is_err());
        assert_eq!(names(&thesis), ["thesis.tex"]);
        let _ = std::fs::remove_dir_all(&d);
    }

    /// Regression: `force` emptied any folder with a lock file, `config.toml`, `summary.json` or
    /// `sweep.toml`, files a refusal or a stranger leaves. Only a claim's mark counts; a folder
    /// with nothing but an unmarked lock file is empty, and claimed.
    #[test]
    fn regression_force_trusts_no_stray_lock_file_or_strangers_files() {
        let top = tmp("stray");
        let d = top.join("run");
        let all = [
            LOCK_FILE,
            "config.toml",
            "summary.json",
            "sweep.toml",
            "thesis.tex",
        ];
        for f in all {
            std::fs::write(d.join(f), "").unwrap();
        }
        let e = RunFolder::claim(&d, true).unwrap_err().to_string();
        assert!(
            e.contains("does not look like a deltaloop run folder"),
            "{e}"
        );
        let mut want = all.map(String::from).to_vec();
        want.sort();
        assert_eq!(names(&d), want);
        for f in &all[1..] {
            std::fs::remove_file(d.join(f)).unwrap();
        }
        let f = RunFolder::claim(&d, false).unwrap();
        assert!(is_marked(f.path()));
        let _ = std::fs::remove_dir_all(&top);
    }

    /// A claimed folder stays deltaloop's however its command ended (here: cut short after its
    /// config): `force` empties it. A command that fails before writing anything releases its
    /// folder: the lock file goes, and the folder too (with the folders the claim made for it)
    /// unless it was an empty folder of the user's.
    #[test]
    fn a_claimed_folder_is_reclaimed_with_force_and_released_whole() {
        let d = tmp("reclaim");
        let run = d.join("a/b/run");
        let f = RunFolder::claim(&run, false).unwrap();
        std::fs::write(run.join("config.toml"), "x").unwrap();
        assert!(
            RunFolder::claim(&run, true)
                .unwrap_err()
                .to_string()
                .contains("in use")
        );
        drop(f);
        assert!(RunFolder::claim(&run, false).is_err());
        let f = RunFolder::claim(&run, true).unwrap();
        assert_eq!(names(&run), [LOCK_FILE]);
        f.release_unused();
        assert_eq!(names(&d.join("a")), ["b"]);
        assert!(names(&d.join("a/b")).is_empty());
        let user = d.join("user");
        std::fs::create_dir(&user).unwrap();
        RunFolder::claim(&user, false).unwrap().release_unused();
        assert!(user.is_dir() && names(&user).is_empty());
        RunFolder::claim(&d.join("x/y/z"), false)
            .unwrap()
            .release_unused();
        assert!(!d.join("x").exists());
        let _ = std::fs::remove_dir_all(&d);
    }
}

/// The unit tests' allocator: the system's, counting each thread's allocations, so a test can
/// hold a per-tick path to its allocation budget (other tests run on other threads).
#[cfg(test)]
mod alloc_count {
    use std::alloc::{GlobalAlloc, Layout, System};
    use std::cell::Cell;

    thread_local! {
        static ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
    }

    struct Counting;

    // SAFETY: every call is forwarded to the system allocator unchanged.
    unsafe impl GlobalAlloc for Counting {
        unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
            ALLOCATIONS.with(|n| n.set(n.get() + 1));
            unsafe { System.alloc(layout) }
        }
        unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
            unsafe { System.dealloc(ptr, layout) }
        }
        unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
            ALLOCATIONS.with(|n| n.set(n.get() + 1));
            unsafe { System.realloc(ptr, layout, new_size) }
        }
    }

    #[global_allocator]
    static COUNTING: Counting = Counting;

    /// Allocations (and reallocations) this thread has made so far.
    pub fn allocations() -> u64 {
        ALLOCATIONS.with(Cell::get)
    }
}
