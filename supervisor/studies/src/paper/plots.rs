//! The paper run's figures: tracking error and torque panels per scenario and preset, and the\nexplicit-vs-implicit super-twisting torque.

use super::*;

/// The reference's task-space path and each run's FK(q), for the 3-D figure.
fn path_series(study: &Study, pair: &[&LawRun]) -> Vec<Series3> {
    let mut paths = vec![Series3 {
        name: "reference x_d".into(),
        color: plot::RGBColor(0, 0, 0),
        points: (0..study.reference.n + 1)
            .map(|k| study.reference.row(k).task.x)
            .map(|x| (x[0], x[1], x[2]))
            .collect(),
        width: 2,
    }];
    for r in pair {
        paths.push(Series3 {
            name: format!("{} FK(q)", r.law.paper_name()),
            color: plot::law_color(r.law),
            points: r
                .records
                .iter()
                .filter_map(|rec| study.robot.fk(&rec.q_true).ok())
                .map(|x| (x[0], x[1], x[2]))
                .collect(),
            width: 1,
        });
    }
    paths
}

/// Errors, torques, the torque zoom and the 3-D path for one case.
pub(super) fn figures(
    study: &Study,
    runs: &[LawRun],
    dir: &Path,
    stem: &str,
    title: &str,
) -> Result<Vec<String>> {
    let ts = study.reference.ts;
    let pair: Vec<&LawRun> = runs
        .iter()
        .filter(|r| matches!(r.law, Law::TdeIs | Law::TdcIsSta))
        .collect();
    let n = study.reference.n + 1;
    let err = |r: &LawRun, k: usize, j: usize| tracking_error(study, r, k, j);
    let mut out = Vec::new();
    let mut fig = |name: &str, t: &str, p: Vec<Panel>| -> Result<()> {
        let s = format!("{stem}-{name}");
        plot::figure(&dir.join(&s), &format!("{title}: {t}"), &p, 3)?;
        out.push(s);
        Ok(())
    };
    fig(
        "errors",
        "joint tracking error e = q_d − q",
        joint_panels(ts, &err, &pair, 0..n, "e (rad)"),
    )?;
    fig(
        "torques",
        "commanded joint torque",
        joint_panels(ts, &torque, &pair, 0..n.saturating_sub(1), "τ (N m)"),
    )?;
    // Chattering zoom: 15 ms around mid-motion (the speed peak), every law.
    let mid = (study.reference.duration / 2.0 / ts) as usize;
    let zoom = mid.saturating_sub(25)..(mid + 25).min(n.saturating_sub(1));
    let all: Vec<&LawRun> = runs.iter().filter(|r| LAWS.contains(&r.law)).collect();
    fig(
        "chatter",
        "torque around mid-motion (15 ms zoom: chattering)",
        joint_panels(ts, &torque, &all, zoom, "τ (N m)"),
    )?;
    // Task-space path vs reference (3-D).
    let paths = path_series(study, &pair);
    let s = format!("{stem}-path");
    plot::figure3(
        &dir.join(&s),
        &format!("{title}: task-space path (m, base frame, z up)"),
        &paths,
    )?;
    out.push(s);
    out.extend(sta_figure(study, runs, dir, stem, title)?);
    Ok(out)
}

/// Joint `j`'s tracking error e = q_d − q at record `k` of `r`, rad.
fn tracking_error(study: &Study, r: &LawRun, k: usize, j: usize) -> f64 {
    study.reference.row(r.records[k].sample.k as usize).joint.q[j] - r.records[k].q_true[j]
}

/// Joint `j`'s commanded torque at record `k` of `r`, N m.
fn torque(r: &LawRun, k: usize, j: usize) -> f64 {
    r.records[k].tau[j]
}

/// One panel per joint: `f` of each run over records `ks`, against run time k·Ts (s).
fn joint_panels(
    ts: f64,
    f: PerTick,
    runs: &[&LawRun],
    ks: std::ops::Range<usize>,
    y: &str,
) -> Vec<Panel> {
    (0..3)
        .map(|j| Panel {
            title: format!("joint {}", j + 1),
            x_label: "t (s)".into(),
            y_label: y.into(),
            log_x: false,
            log_y: false,
            series: runs
                .iter()
                .map(|r| Series {
                    dashed: false,
                    bars: Vec::new(),
                    name: format!("{} ({})", r.law.paper_name(), r.law.name()),
                    color: plot::law_color(r.law),
                    points: ks
                        .clone()
                        .filter(|&k| k < r.records.len())
                        .map(|k| (k as f64 * ts, f(r, k, j)))
                        .collect(),
                })
                .collect(),
        })
        .collect()
}

/// Explicit vs implicit super-twisting: joint 1's torque and error over the 50 ms window where
/// their torques differ most (`<stem>-sta-torque`), when both laws ran.
fn sta_figure(
    study: &Study,
    runs: &[LawRun],
    dir: &Path,
    stem: &str,
    title: &str,
) -> Result<Option<String>> {
    let ts = study.reference.ts;
    let sta: Vec<&LawRun> = runs
        .iter()
        .filter(|r| matches!(r.law, Law::TdcIsSta | Law::TdcIsIsta))
        .collect();
    let [a, b] = sta[..] else {
        return Ok(None);
    };
    let w = sta_window(a, b, (STA_WINDOW_S / ts).round() as usize);
    let (t0, t1) = (w.start as f64 * ts * 1e3, w.end as f64 * ts * 1e3);
    let err = |r: &LawRun, k: usize, j: usize| tracking_error(study, r, k, j);
    let one = |p: Vec<Panel>| p.into_iter().next().into_iter();
    let mut p: Vec<Panel> = one(joint_panels(ts, &torque, &sta, w.clone(), "τ₁ (N m)")).collect();
    p.extend(one(joint_panels(ts, &err, &sta, w, "e₁ (rad)")));
    p[0].title = "joint 1 torque".into();
    p[1].title = "joint 1 tracking error".into();
    let s = format!("{stem}-sta-torque");
    plot::figure(
        &dir.join(&s),
        &format!("{title}: explicit vs implicit super-twisting, t = {t0:.1}–{t1:.1} ms"),
        &p,
        2,
    )?;
    Ok(Some(s))
}

/// The window of `len` torque intervals in which joint 1's torque total variation differs most
/// between runs `a` and `b` (where a reader sees the difference), over the intervals both ran.
pub fn sta_window(a: &LawRun, b: &LawRun, len: usize) -> std::ops::Range<usize> {
    let n = a.records.len().min(b.records.len()).saturating_sub(1);
    let len = len.min(n);
    let dv = |r: &LawRun, k: usize| (r.records[k + 1].tau[0] - r.records[k].tau[0]).abs();
    let d: Vec<f64> = (0..n.saturating_sub(1))
        .map(|k| (dv(a, k) - dv(b, k)).abs())
        .collect();
    let mut sum: f64 = d.iter().take(len).sum();
    let (mut best, mut at) = (sum, 0);
    for k in len..d.len() {
        sum += d[k] - d[k - len];
        if sum > best {
            (best, at) = (sum, k + 1 - len);
        }
    }
    at..at + len
}

/// The stem suffix of the explicit-vs-implicit torque figure.
pub const STA_FIGURE: &str = "-sta-torque";
