//! Shard folders into the sweep's outputs: `sweep.csv` and `sweep.json` in plan order, the
//! plots, `report.md`, copies of `sweep.toml` and `base.toml`, and a `shard.json` listing every
//! point, so a merged folder is itself a shard (merges nest). Every point must be there exactly
//! once: a missing or duplicated point is an error that names it.

use super::plan::{Plan, ranges_text};
use super::shard::{MANIFEST, Manifest};
use super::{Row, SweepFile, plots, report};
use anyhow::{Context, Result, bail};
use deltaloop_config::RunConfig;
use deltaloop_config::files;
use std::path::{Path, PathBuf};

/// Largest shard `sweep.csv` read, bytes: a row is well under 4 KiB (its longest field is the
/// one-line reason), and a shard has at most [`super::MAX_POINTS`] of them.
pub const MAX_CSV_BYTES: u64 = super::MAX_POINTS * 4096;

/// How strict a merge is.
#[derive(Debug, Clone, Copy, Default)]
pub struct Options {
    /// Write what is there when points are missing (the report lists them) instead of failing.
    pub allow_missing: bool,
    /// The sweep was stopped by Ctrl-C / SIGTERM: the report says so.
    pub interrupted: bool,
}

/// What a merge wrote.
#[derive(Debug)]
pub struct Merged {
    pub plan: Plan,
    /// The rows written, in plan order (with `interrupted` ones, which are not results).
    pub rows: Vec<Row>,
    /// Points with no finished row, ascending indices.
    pub missing: Vec<usize>,
    pub sweep_file: String,
}

/// The plan a shard folder was run from, rebuilt from its `sweep.toml` and `base.toml`, and
/// checked against its manifest's hash.
fn plan_of(dir: &Path, m: &Manifest) -> Result<Plan> {
    let shown = dir.display();
    let text = deltaloop_config::read_text_file(&dir.join("sweep.toml"))
        .map_err(|e| anyhow::anyhow!("shard {shown}: cannot read sweep.toml: {e}"))?;
    let sweep: SweepFile = toml::from_str(&text)
        .map_err(|e| anyhow::anyhow!("shard {shown}: sweep.toml is not a sweep file: {e}"))?;
    let base = RunConfig::from_file(&dir.join("base.toml"))
        .map_err(|e| anyhow::anyhow!("shard {shown}: base.toml: {e}"))?;
    let plan = Plan::new(sweep, base).with_context(|| format!("shard {shown}"))?;
    if plan.hash != m.plan_hash {
        bail!(
            "shard {shown}: its sweep.toml and base.toml give plan {}, but its {MANIFEST} says {} (edited, or written by another deltaloop version)",
            plan.short_hash(),
            short(&m.plan_hash)
        );
    }
    Ok(plan)
}

fn short(h: &str) -> &str {
    h.get(..12).unwrap_or(h)
}

/// `id (label)` of up to 10 points, and how many more.
fn name_points(plan: &Plan, idx: &[usize]) -> String {
    let mut s: Vec<String> = idx
        .iter()
        .take(10)
        .map(|&i| format!("{} ({})", plan.points[i].id, plan.points[i].label()))
        .collect();
    if idx.len() > 10 {
        s.push(format!("and {} more", idx.len() - 10));
    }
    s.join(", ")
}

/// Merges the shard folders `dirs` into `out` (which the caller holds; it may be one of the
/// shards, as in the one-machine sweep).
pub fn merge(dirs: &[PathBuf], out: &Path, opts: Options) -> Result<Merged> {
    let m = gather(dirs, opts)?;
    write(&m.plan, &m.rows, &m.missing, &m.sweep_file, out, opts)?;
    for d in dirs {
        copy_points(d, out)?;
    }
    Ok(m)
}

/// Reads and checks the shard folders `dirs` (nothing is written): every point of one plan
/// exactly once, or, with `allow_missing`, at most once.
pub fn gather(dirs: &[PathBuf], opts: Options) -> Result<Merged> {
    let Some(first) = dirs.first() else {
        bail!("sweep merge: no shard folder given");
    };
    let manifests: Vec<Manifest> = dirs
        .iter()
        .map(|d| Manifest::read(d))
        .collect::<Result<_>>()?;
    let plan = plan_of(first, &manifests[0])?;
    for (d, m) in dirs.iter().zip(&manifests).skip(1) {
        if m.plan_hash != plan.hash {
            bail!(
                "shard {} is from another plan ({}) than {} ({}): a different sweep file or base config; merge only shards of one plan",
                d.display(),
                short(&m.plan_hash),
                first.display(),
                plan.short_hash()
            );
        }
    }
    let n = plan.points.len();
    let mut slots = Slots {
        slot: vec![None; n],
        listed: vec![None; n],
        dups: Vec::new(),
    };
    for (k, (d, m)) in dirs.iter().zip(&manifests).enumerate() {
        slots.read_shard(&plan, k, d, m)?;
    }
    let Slots {
        slot,
        listed,
        mut dups,
    } = slots;
    if !dups.is_empty() {
        dups.sort_unstable();
        bail!(duplicates_error(&plan, dirs, &dups));
    }
    let missing: Vec<usize> = (0..n)
        .filter(|&i| !slot[i].as_ref().is_some_and(|(r, _)| r.is_result()))
        .collect();
    if !missing.is_empty() && !opts.allow_missing {
        bail!(missing_error(
            &plan,
            &missing,
            &listed,
            &manifests[0].sweep_file
        ));
    }
    // Only folders and regular files are copied from the shards' points/: checked before
    // anything is written.
    for d in dirs {
        points_tree(d, None)?;
    }
    let rows: Vec<Row> = slot.into_iter().flatten().map(|(r, _)| r).collect();
    let sweep_file = manifests[0].sweep_file.clone();
    Ok(Merged {
        plan,
        rows,
        missing,
        sweep_file,
    })
}

/// Every row of the shards, in its point's slot.
struct Slots {
    /// Per point: its row and the shard it came from.
    slot: Vec<Option<(Row, usize)>>,
    /// Per point: the first shard whose manifest lists it.
    listed: Vec<Option<usize>>,
    /// (point, shard, shard) of each second finished row for a point.
    dups: Vec<(usize, usize, usize)>,
}

impl Slots {
    /// Files the rows of shard `k` (folder `d`, manifest `m`); a second finished row for a point
    /// is noted as a duplicate.
    fn read_shard(&mut self, plan: &Plan, k: usize, d: &Path, m: &Manifest) -> Result<()> {
        let shown = d.display();
        for id in &m.points {
            let i = plan.find(id).ok_or_else(|| {
                anyhow::anyhow!(
                    "shard {shown}: {MANIFEST} lists point {id:?}, which is not in the plan"
                )
            })?;
            self.listed[i].get_or_insert(k);
        }
        let csv_path = d.join("sweep.csv");
        let file = files::open_regular(&csv_path, MAX_CSV_BYTES, "a shard's sweep.csv")
            .map_err(|e| anyhow::anyhow!("shard {shown}: cannot read sweep.csv: {e}"))?;
        let mut rdr = csv::Reader::from_reader(std::io::BufReader::new(file));
        for (line, r) in rdr.deserialize::<Row>().enumerate() {
            let r =
                r.map_err(|e| anyhow::anyhow!("shard {shown}: sweep.csv row {}: {e}", line + 1))?;
            let i = check_row(plan, d, m, line, &r)?;
            match &self.slot[i] {
                // An interrupted row is no result: a finished one replaces it.
                Some((old, k0)) if old.is_result() && r.is_result() => self.dups.push((i, *k0, k)),
                Some((old, _)) if old.is_result() => {}
                _ => self.slot[i] = Some((r, k)),
            }
        }
        Ok(())
    }
}

/// The plan index of row `line` of shard `d`'s `sweep.csv`, checked: a point of the plan, listed
/// in the shard's manifest, with that point's parameters.
fn check_row(plan: &Plan, d: &Path, m: &Manifest, line: usize, r: &Row) -> Result<usize> {
    let shown = d.display();
    let Some(i) = plan.find(&r.point) else {
        bail!(
            "shard {shown}: sweep.csv has point {:?}, which is not in plan {}",
            r.point,
            plan.short_hash()
        );
    };
    if !m.points.contains(&r.point) {
        bail!(
            "shard {shown}: sweep.csv has point {}, which its {MANIFEST} does not list",
            r.point
        );
    }
    let p = &plan.points[i];
    if (
        r.law,
        r.mode,
        r.tde_delay_samples,
        r.transport_delay_samples,
    ) != (p.job.variant(), p.mode, p.job.ell, p.job.d)
        || r.scenario != p.job.scenario
        || r.preset != p.job.preset
        || r.compute_delay_us != p.job.kind.compute_us()
        || r.transport_delay_us != p.job.kind.transport_us()
        || r.link_delay_us != p.job.kind.link().map(|l| l.delay_us)
    {
        bail!(
            "shard {shown}: sweep.csv row {} says point {} but holds another point's parameters (expected {})",
            line + 1,
            r.point,
            p.label()
        );
    }
    Ok(i)
}

/// The error for points merged more than once (`dups` sorted), naming up to 10.
fn duplicates_error(plan: &Plan, dirs: &[PathBuf], dups: &[(usize, usize, usize)]) -> String {
    let mut named: Vec<String> = dups
        .iter()
        .take(10)
        .map(|&(i, k0, k)| {
            let p = &plan.points[i];
            let whr = if k0 == k {
                format!("twice in {}", dirs[k].display())
            } else {
                format!("in {} and {}", dirs[k0].display(), dirs[k].display())
            };
            format!("{} ({}) {whr}", p.id, p.label())
        })
        .collect();
    if dups.len() > 10 {
        named.push(format!("and {} more", dups.len() - 10));
    }
    format!(
        "sweep merge: {} point(s) merged more than once: {}; merge each point once (drop one of the folders, or re-run one without the point)",
        dups.len(),
        named.join(", ")
    )
}

/// The error for missing points: those in no shard and those a shard lists but did not finish.
fn missing_error(
    plan: &Plan,
    missing: &[usize],
    listed: &[Option<usize>],
    sweep_file: &str,
) -> String {
    let (unlisted, unfinished): (Vec<usize>, Vec<usize>) =
        missing.iter().partition(|&&i| listed[i].is_none());
    let mut why = Vec::new();
    if !unlisted.is_empty() {
        why.push(format!("in no shard: {}", name_points(plan, &unlisted)));
    }
    if !unfinished.is_empty() {
        why.push(format!(
            "not finished in the shard that lists them (interrupted or failed): {}",
            name_points(plan, &unfinished)
        ));
    }
    format!(
        "sweep merge: {} of {} points missing, {}; run them with `deltaloop sweep run {sweep_file} --points {}`",
        missing.len(),
        plan.points.len(),
        why.join("; "),
        ranges_text(missing)
    )
}

/// Writes the merged outputs (the shards' `points/` are copied apart, by [`copy_points`]).
pub fn write(
    plan: &Plan,
    rows: &[Row],
    missing: &[usize],
    sweep_file: &str,
    out: &Path,
    opts: Options,
) -> Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    std::fs::write(out.join("sweep.toml"), toml::to_string_pretty(&plan.sweep)?)?;
    std::fs::write(out.join("base.toml"), plan.base.to_toml_string())?;
    let done: Vec<usize> = rows.iter().filter_map(|r| plan.find(&r.point)).collect();
    Manifest::new(plan, sweep_file, &done).write(out)?;
    let mut w = csv::Writer::from_path(out.join("sweep.csv")).context("cannot write sweep.csv")?;
    for r in rows {
        w.serialize(r)?;
    }
    w.flush()?;
    std::fs::write(out.join("sweep.json"), serde_json::to_string_pretty(rows)?)?;
    let figures = plots(&plan.sweep, rows, out)?;
    let mut md = report(&plan.sweep, rows, &figures, Path::new(sweep_file));
    // An encoder hides the twins' one-ulp perturbation: say so, as a run's report does.
    if plan.sweep.sensitivity
        && let Some(note) = deltaloop_study::record::sensitivity::masked_note(&plan.base)
    {
        md.push_str(&format!("\n**Round-off and the encoder**: {note}.\n"));
    }
    let total = plan.points.len();
    if opts.interrupted {
        let finished = rows.iter().filter(|r| r.is_result()).count();
        let cut = rows.len() - finished;
        let cut = if cut > 0 {
            format!(
                " The {cut} point(s) running at the stop are marked `interrupted` in sweep.csv and are not results."
            )
        } else {
            String::new()
        };
        md.insert_str(0, &format!("> **Interrupted** (Ctrl-C / SIGTERM) after {finished} of {total} runs: the tables hold the finished ones.{cut}\n\n"));
    } else if !missing.is_empty() {
        md.insert_str(
            0,
            &format!(
                "> **Incomplete**: {} of {total} points are missing (not run, or failed): {}. Re-run them with `--points {}`.\n\n",
                missing.len(),
                name_points(plan, missing),
                ranges_text(missing)
            ),
        );
    }
    deltaloop_report::write_text(&out.join("report.md"), &md)?;
    Ok(())
}

/// Copies a shard's `points/` (the run folders of process-mode points) into `out`.
pub fn copy_points(shard: &Path, out: &Path) -> Result<()> {
    if deltaloop_report::RunFolder::same(shard, out) {
        return Ok(());
    }
    points_tree(shard, Some(&out.join("points")))
}

/// Walks a shard's `points/` (none is fine), copying it to `to` when given. Anything but a
/// folder or a regular file is refused with a line naming it, and a link is never followed
/// (regression: a `points` link made a merge copy any folder it pointed to into the output).
fn points_tree(shard: &Path, to: Option<&Path>) -> Result<()> {
    let from = shard.join("points");
    match std::fs::symlink_metadata(&from) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => bail!(
            "shard {}: cannot read {}: {e}",
            shard.display(),
            from.display()
        ),
        Ok(m) => {
            refuse_special(shard, &from, m.file_type(), true)?;
            walk(shard, &from, to)
        }
    }
}

/// Fails unless `t` is a folder (`dir_ok`) or a regular file.
fn refuse_special(shard: &Path, p: &Path, t: std::fs::FileType, dir_ok: bool) -> Result<()> {
    if t.is_file() || (dir_ok && t.is_dir()) {
        return Ok(());
    }
    let to = std::fs::read_link(p)
        .map(|l| format!(" (to {})", l.display()))
        .unwrap_or_default();
    bail!(
        "shard {}: {} is {}{to}: a merge copies only folders and regular files from a shard's points/, and never follows a link",
        shard.display(),
        p.display(),
        files::kind_of(t)
    )
}

fn walk(shard: &Path, from: &Path, to: Option<&Path>) -> Result<()> {
    if let Some(to) = to {
        std::fs::create_dir_all(to).with_context(|| format!("cannot create {}", to.display()))?;
    }
    for e in std::fs::read_dir(from).with_context(|| format!("cannot read {}", from.display()))? {
        let e = e.with_context(|| format!("cannot read {}", from.display()))?;
        let (p, t) = (e.path(), e.file_type()?);
        refuse_special(shard, &p, t, true)?;
        let dst = to.map(|to| to.join(e.file_name()));
        if t.is_dir() {
            walk(shard, &p, dst.as_deref())?;
        } else if let Some(dst) = dst {
            // Opened as a regular file again: the entry may have changed since it was checked.
            let mut src = files::open_regular(&p, u64::MAX, "a run folder's file")
                .map_err(|e| anyhow::anyhow!("shard {}: {}: {e}", shard.display(), p.display()))?;
            let mut w = std::fs::File::create(&dst)
                .with_context(|| format!("cannot create {}", dst.display()))?;
            std::io::copy(&mut src, &mut w)
                .with_context(|| format!("cannot copy {}", p.display()))?;
        }
    }
    Ok(())
}
