//! Human-readable results: the terminal table and `report.md`, shaped like the paper's
//! Tables II–IV, plus the columns the paper does not have.

use deltaloop_config::{Compensation, LawVariant, PathKind, VelocitySource};
use deltaloop_config::{ControllerParams, Law, LoopMode, Overrun, Preset, RunConfig};
use deltaloop_study::analysis::Mismatch;
use deltaloop_study::record::metrics::LawMetrics;
use deltaloop_study::record::sensitivity;
use deltaloop_timing::TimingSummary;
use std::fmt::Write;

mod timing;

pub use timing::{timing_markdown, timing_table};

/// The paper's published RMS errors (rad) for TDC+IS and TDC+IS+STA (Tables II–IV).
pub fn paper_rms(path: PathKind, law: Law) -> Option<[f64; 3]> {
    let t = match (path, law) {
        (PathKind::S1, Law::TdeIs) => [3.463e-4, 3.587e-4, 3.587e-4],
        (PathKind::S1, Law::TdcIsSta) => [3.423e-4, 3.583e-4, 3.583e-4],
        (PathKind::S2, Law::TdeIs) => [0.0056, 0.0069, 0.0069],
        (PathKind::S2, Law::TdcIsSta) => [0.0044, 0.0047, 0.0047],
        (PathKind::S3, Law::TdeIs) => [7.265e-4, 1.622e-4, 1.608e-4],
        (PathKind::S3, Law::TdcIsSta) => [5.592e-4, 1.776e-4, 1.752e-4],
        _ => return None,
    };
    Some(t)
}

/// The paper's table number for a scenario.
pub fn paper_table(path: PathKind) -> Option<&'static str> {
    match path {
        PathKind::S1 => Some("II"),
        PathKind::S2 => Some("III"),
        PathKind::S3 => Some("IV"),
        PathKind::Custom => None,
    }
}

fn e(x: f64) -> String {
    format!("{x:.3e}")
}

/// A figure with the digits its law's round-off twin leaves it (`rel`: the relative spread; all
/// four without a twin).
fn fig(x: f64, rel: Option<f64>) -> String {
    rel.map_or_else(|| e(x), |r| sensitivity::sci(x, r))
}

/// One of `m`'s RMS figures (rad) with the digits its round-off twin leaves it.
pub fn rms_fig(m: &LawMetrics, x: f64) -> String {
    fig(x, m.sensitivity.map(|t| t.rms_rel))
}

/// The round-off column of a law: the spread of its RMS (the figures of its row), or `-`
/// without a twin.
fn spread_cell(m: &LawMetrics) -> String {
    m.sensitivity
        .map_or("-".into(), |s| sensitivity::show_spread(s.rms_rel))
}

/// A law's status for the tables (from its [`RunStatus`](deltaloop_study::record::RunStatus)).
fn status(m: &LawMetrics) -> String {
    use deltaloop_study::record::RunStatus;
    let k = m.status_tick.unwrap_or(0);
    match m.status {
        RunStatus::Ok => "ok".into(),
        RunStatus::Diverged => format!("diverged at tick {k}"),
        RunStatus::Interrupted => format!("interrupted at tick {k}"),
        RunStatus::Fault => format!("FAULT at tick {k}"),
        RunStatus::Stopped => format!("STOPPED at tick {k}"),
        RunStatus::LostData => {
            format!(
                "LOST DATA ({} ticks)",
                m.lost_ticks + m.telemetry_missing + m.replies_lost
            )
        }
        RunStatus::Error => "error".into(),
    }
}

/// What a run in `mode` calls its controller when it is not the built-in one: the label of the
/// config (`controller.label`, `--controller-label`), else the name the controller gave itself
/// in its READY (`said`), else its command's program (see [`RunConfig::controller_label`]). The
/// in-process modes run the built-in law: none.
pub fn controller_label(cfg: &RunConfig, mode: LoopMode, said: Option<&str>) -> Option<String> {
    if !mode.is_process() {
        return None;
    }
    match said {
        Some(s) if cfg.controller.label.is_empty() => Some(s.to_string()),
        _ => cfg.controller_label(),
    }
}

/// A law as the tables name it: with the controller's label when a foreign one answered as it
/// (`tdc (c-tdc)`), so it is never taken for the built-in law.
fn law_cell(law: LawVariant, label: Option<&str>) -> String {
    match label {
        Some(l) => format!("{law} ({l})"),
        None => law.to_string(),
    }
}

/// The terminal table: one line per law (with `label`, the controller that ran, beside it).
pub fn terminal_table(cfg: &RunConfig, label: Option<&str>, metrics: &[LawMetrics]) -> String {
    let mut s = String::new();
    let width = metrics
        .iter()
        .map(|m| {
            law_cell(LawVariant::as_run(m.law, cfg.controller.compensate), label)
                .chars()
                .count()
        })
        .max()
        .unwrap_or(0)
        .max(11);
    let _ = writeln!(
        s,
        "{} ({:?}, preset {}, {} ticks of {} ms)",
        cfg.name,
        cfg.scenario.path,
        cfg.controller.preset.name(),
        metrics.first().map_or(0, |m| m.ticks),
        cfg.loop_.ts_s * 1e3
    );
    let twins = metrics.iter().any(|m| m.sensitivity.is_some());
    let _ = writeln!(
        s,
        "{:<width$} {:>10} {:>10} {:>10} {:>9} {:>9} {:>8} {:>7} {:>10}{}  status",
        "law",
        "rms q1",
        "rms q2",
        "rms q3",
        "task mm",
        "max|tau|",
        "HF shr",
        "clamps",
        "TDE rms",
        if twins { "  round-off" } else { "" }
    );
    for m in metrics {
        let rel = m.sensitivity.map(|s| s.rms_rel);
        let tde_rel = m.sensitivity.and_then(|s| s.tde_rel);
        let tde = m.tde_err_rms.map_or("-".into(), |t| fig(max3(t), tde_rel));
        let task = match m.sensitivity {
            Some(x) if sensitivity::is_sensitive(x.task_rms_rel) => {
                sensitivity::sci(m.task_rms_mm, x.task_rms_rel)
            }
            _ => format!("{:.4}", m.task_rms_mm),
        };
        let _ = writeln!(
            s,
            "{:<width$} {:>10} {:>10} {:>10} {:>9} {:>9.3} {:>8.4} {:>7} {:>10}{}  {}",
            law_cell(LawVariant::as_run(m.law, cfg.controller.compensate), label),
            fig(m.rms_rad[0], rel),
            fig(m.rms_rad[1], rel),
            fig(m.rms_rad[2], rel),
            task,
            max3(m.max_abs_tau_nm),
            max3(m.hf_torque_share),
            m.clamp_count,
            tde,
            if twins {
                format!("  {:>9}", spread_cell(m))
            } else {
                String::new()
            },
            status(m)
        );
    }
    if twins {
        let _ = writeln!(
            s,
            "round-off: the largest relative change of a law's RMS over its 8 twins (q(0) one ulp up or down, per joint and in all); RMS, task and TDE figures keep the digits that survive their own largest change (summary.json: sensitivity)"
        );
    }
    s
}

/// Whether a run shows the limit cycle of a mismatched M̄: sustained torque oscillation with a
/// dominant line above 10 Hz, hitting the clamp or carrying a large share of the torque energy.
pub fn limit_cycle(m: &LawMetrics) -> bool {
    let peak = max3(m.torque_peak_hz);
    let share = max3(m.hf_torque_share);
    m.law != Law::Pid && peak > 10.0 && (m.clamp_count > 0 || share > 0.05)
}

/// Three per-joint values in the report's exponent form, `j1 / j2 / j3`.
fn e3(v: [f64; 3]) -> String {
    format!("{} / {} / {}", e(v[0]), e(v[1]), e(v[2]))
}

/// Three per-joint values with `d` decimals, `j1 / j2 / j3`.
fn f3(v: [f64; 3], d: usize) -> String {
    format!("{:.d$} / {:.d$} / {:.d$}", v[0], v[1], v[2])
}

/// The largest of three per-joint values (0 for none above 0).
fn max3(v: [f64; 3]) -> f64 {
    v.into_iter().fold(0.0, f64::max)
}

/// `report.md` for one scenario run.
pub fn markdown(
    cfg: &RunConfig,
    mode: LoopMode,
    label: Option<&str>,
    command: &str,
    metrics: &[LawMetrics],
    mismatch: &Mismatch,
) -> String {
    let p = cfg.controller_params();
    let mut s = String::new();
    header(&mut s, cfg, &p, mode, command);
    controller_line(&mut s, cfg, label);
    let comp = cfg.controller.compensate;
    rms_section(&mut s, cfg.scenario.path, comp, metrics);
    accuracy_section(&mut s, comp, metrics);
    tde_section(&mut s, &p, comp, metrics);
    rejected_notes(&mut s, metrics);
    peer_notes(&mut s, metrics);
    stopped_section(&mut s, metrics);
    diverged_section(&mut s, cfg, metrics);
    mismatch_section(&mut s, cfg, &p, metrics, mismatch);
    s
}

/// Title, the constants of the run, what was injected, and the command that produced it.
fn header(s: &mut String, cfg: &RunConfig, p: &ControllerParams, mode: LoopMode, command: &str) {
    let _ = writeln!(
        s,
        "# {} — {}\n",
        cfg.name,
        if cfg.description.is_empty() {
            "deltaloop run"
        } else {
            &cfg.description
        }
    );
    let _ = writeln!(
        s,
        "Scenario `{:?}`, preset `{}` ({}; SI units, docs/controllers.md), \
         friction {}, τ_max = {} N m, Ts = {} ms, TDE delay ℓ = {}, mode `{mode}`.\n",
        cfg.scenario.path,
        cfg.controller.preset.name(),
        gains_text(p),
        if cfg.plant.friction { "on" } else { "off" },
        cfg.plant.tau_max_nm,
        cfg.loop_.ts_s * 1e3,
        cfg.controller.tde_delay_samples,
    );
    if cfg.controller.compensate != Compensation::None {
        let _ = writeln!(
            s,
            "Delay compensation: `{}` over D = {} µs{} (docs/controllers.md, \"Delay compensation\").\n",
            cfg.controller.compensate,
            cfg.compensation_delay_ns() as f64 / 1e3,
            match cfg.controller.compensate_delay {
                deltaloop_config::DelaySource::Config => "",
                deltaloop_config::DelaySource::Measured =>
                    ", measured each tick from the drives' reports up to one tick more",
            }
        );
    }
    let extras = injected(cfg);
    if !extras.is_empty() {
        let _ = writeln!(s, "Injected: {}.\n", extras.join("; "));
    }
    let _ = writeln!(s, "Produced by: `{command}`\n");
}

/// Which controller ran, when it was not the built-in one (`label`).
fn controller_line(s: &mut String, cfg: &RunConfig, label: Option<&str>) {
    if let Some(l) = label {
        let _ = writeln!(
            s,
            "Controller: `{}`, its own process in place of the built-in one, answering as {}; \
             every law's figures below are its.\n",
            l.replace('`', "'"),
            cfg.controller
                .laws
                .iter()
                .map(|l| format!("`{l}`"))
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
}

/// What the config adds to the nominal loop: delays, a payload step, sensor realism.
fn injected(cfg: &RunConfig) -> Vec<String> {
    let mut extras: Vec<String> = super::link::note(cfg).into_iter().collect();
    if cfg.plant.transport_delay_samples > 0 {
        extras.push(format!(
            "transport delay d = {} ticks",
            cfg.plant.transport_delay_samples
        ));
    }
    if cfg.controller.compute_delay_us > 0 {
        extras.push(format!(
            "controller compute delay {} µs",
            cfg.controller.compute_delay_us
        ));
    }
    if let Some(k) = cfg.payload_step_tick() {
        extras.push(format!(
            "payload step to {} kg at tick {k} (t = {:.4} s)",
            cfg.plant.payload_step_kg,
            k as f64 * cfg.loop_.ts_s
        ));
    }
    let se = &cfg.sensor;
    if !se.is_ideal() || se.velocity != VelocitySource::Measured {
        extras.push(format!(
            "sensor: {} counts/rev, noise σ_q = {} rad, σ_q̇ = {} rad/s, seed {}, velocity {:?}",
            se.encoder_counts_per_rev,
            se.q_noise_std_rad,
            se.qd_noise_std_rad_s,
            se.seed,
            se.velocity
        ));
    }
    extras
}

/// What the round-off column means, and which laws' figures it cuts.
fn sensitivity_note(s: &mut String, metrics: &[LawMetrics]) {
    let _ = writeln!(
        s,
        "\nRound-off: each law ran its twins, {} (`--sensitivity`); the column is the largest relative change of its RMS over them, and each figure keeps only the digits that survive its own largest change (`summary.json` has the changes of the max, task and TDE errors too, the twins' count and the median RMS change). The largest of a few twins is a sample of how far round-off can move the law, not a bound.",
        sensitivity::PERTURBATION
    );
    let touchy: Vec<String> = metrics
        .iter()
        .filter(|m| {
            m.sensitivity
                .is_some_and(|x| sensitivity::is_sensitive(x.worst()))
        })
        .map(|m| {
            let w = m.sensitivity.map_or(0.0, |x| x.worst());
            format!("`{}` (up to {})", m.law, sensitivity::show_spread(w))
        })
        .collect();
    if !touchy.is_empty() {
        let _ = writeln!(
            s,
            "Round-off sensitive: {}. Their results move by that much under a change at the level of the arithmetic's rounding: the closed loop amplifies it here (a super-twisting term |s|^½ sign(s), not Lipschitz at s = 0; a torque riding the clamp; a limit cycle). A difference smaller than that between two implementations, or two laws, is not a result.",
            touchy.join(", ")
        );
    }
}

/// Our RMS error per joint and law, then the paper's published table for this scenario.
fn rms_section(s: &mut String, path: PathKind, comp: Compensation, metrics: &[LawMetrics]) {
    let table = paper_table(path);
    let _ = writeln!(
        s,
        "## RMS tracking error per joint (rad){}\n",
        table.map_or(String::new(), |t| format!(
            ", shaped like the paper's Table {t}"
        ))
    );
    let twins = metrics.iter().any(|m| m.sensitivity.is_some());
    let _ = writeln!(
        s,
        "| Controller | Joint 1 | Joint 2 | Joint 3 |{} status |\n|---|---|---|---|{}---|",
        if twins { " round-off |" } else { "" },
        if twins { "---|" } else { "" }
    );
    for m in metrics {
        let law = m.law;
        let rel = m.sensitivity.map(|s| s.rms_rel);
        let _ = writeln!(
            s,
            "| {} (`{}`) | {} | {} | {} |{} {} |",
            law.paper_name(),
            LawVariant::as_run(m.law, comp),
            fig(m.rms_rad[0], rel),
            fig(m.rms_rad[1], rel),
            fig(m.rms_rad[2], rel),
            if twins {
                format!(" {} |", spread_cell(m))
            } else {
                String::new()
            },
            status(m)
        );
    }
    if twins {
        sensitivity_note(s, metrics);
    }
    let Some(t) = table else { return };
    let _ = writeln!(
        s,
        "\nThe paper's Table {t} (its own, unpublished robot model and Simulink):\n"
    );
    let _ = writeln!(
        s,
        "| Controller | Joint 1 | Joint 2 | Joint 3 |\n|---|---|---|---|"
    );
    for law in [Law::TdeIs, Law::TdcIsSta] {
        if let Some(v) = paper_rms(path, law) {
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} |",
                law.paper_name(),
                e(v[0]),
                e(v[1]),
                e(v[2])
            );
        }
    }
}

/// Error and torque figures the paper does not report.
fn accuracy_section(s: &mut String, comp: Compensation, metrics: &[LawMetrics]) {
    let _ = writeln!(s, "\n## Accuracy and torque\n");
    let _ = writeln!(
        s,
        "| law | max \\|e\\| (rad) j1 / j2 / j3 | task RMS (mm) | task max (mm) | max \\|τ\\| (N m) | torque TV (N m) j1 / j2 / j3 | clamped intervals | HF share >100 Hz | HF RMS (N m) | torque peak (Hz) |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|---|");
    for m in metrics {
        let _ = writeln!(
            s,
            "| `{}` | {} | {:.4} | {:.4} | {:.3} | {} | {} | {} | {} | {} |",
            LawVariant::as_run(m.law, comp),
            e3(m.max_abs_err_rad),
            m.task_rms_mm,
            m.task_max_mm,
            max3(m.max_abs_tau_nm),
            f3(m.torque_tv_nm, 1),
            m.clamp_count,
            f3(m.hf_torque_share, 4),
            f3(m.hf_torque_rms_nm, 3),
            f3(m.torque_peak_hz, 1),
        );
    }
}

/// The TDE error and the super-twisting gain condition, per law with a TDE.
fn tde_section(s: &mut String, p: &ControllerParams, comp: Compensation, metrics: &[LawMetrics]) {
    let _ = writeln!(
        s,
        "\n## Time-delay estimation and the super-twisting gain condition (eq. 43)\n"
    );
    let _ = writeln!(
        s,
        "Ñ = N̂ − N from the plant's true velocities; δ_N = |ΔÑ|/Ts. Eq. 43 asks k2 > δ_N(δ_N + 3k1²)/(2k1²) with k1 = {}. \
        It is a sufficient condition for an exogenous Ñ; here Ñ contains u itself, so it can fail where the law works.\n",
        p.k1
    );
    let _ = writeln!(
        s,
        "| law | TDE error RMS (rad/s²) j1 / j2 / j3 | δ_N max (rad/s³) | δ_N p99.9 (rad/s³) | k2 demanded | k2 in use | eq. 43 holds |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|");
    for m in metrics {
        match (m.tde_err_rms, m.delta_n_max, m.delta_n_p999, m.k2_required) {
            (Some(r), Some(dm), Some(dp), Some(k2)) => {
                let _ = writeln!(
                    s,
                    "| `{}` | {} | {} | {} | {} | {} | {} |",
                    LawVariant::as_run(m.law, comp),
                    e3(r),
                    e(max3(dm)),
                    e(max3(dp)),
                    e(k2),
                    m.k2_in_use,
                    if m.eq43_holds == Some(true) {
                        "yes"
                    } else {
                        "no"
                    }
                );
            }
            _ => {
                let _ = writeln!(s, "| `{}` | n/a (no TDE) | | | | | |", m.law);
            }
        }
    }
}

/// One paragraph per law whose commands the plant rejected.
fn rejected_notes(s: &mut String, metrics: &[LawMetrics]) {
    for m in metrics.iter().filter(|m| m.rejected_count > 0) {
        let _ = writeln!(
            s,
            "\n**`{}`: the plant rejected {} torque command(s)** (non-finite, or beyond ±τ_max with `faults.torque_limit = \"reject\"`) and held the last applied torque instead; they never reached the integrator.",
            m.law, m.rejected_count
        );
    }
}

/// One paragraph per law whose peer broke the protocol in a way the run survived.
fn peer_notes(s: &mut String, metrics: &[LawMetrics]) {
    for m in metrics {
        if m.stamps_replaced > 0 {
            let _ = writeln!(
                s,
                "\n**`{}`: {} reply stamp(s) could not be true** (`t_publish_ns` before the state was published or after the plant received the reply): the plant judged and applied those replies by its own receive time (telemetry flag `TEL_STAMP_REPLACED`).",
                m.law, m.stamps_replaced
            );
        }
        if m.refused_replies > 0 {
            let _ = writeln!(
                s,
                "\n**`{}`: the controller's transport refused {} reply(ies)** before they reached the plant ({}).",
                m.law,
                m.refused_replies,
                m.refused_replies_why
                    .as_deref()
                    .unwrap_or("no causes given")
            );
        }
        if m.duplicate_replies > 0 {
            let _ = writeln!(
                s,
                "\n**`{}`: the controller sent {} extra reply(ies) for ticks it had already answered**: the plant applies the first reply of a tick, and the trace records that one.",
                m.law, m.duplicate_replies
            );
        }
    }
}

/// Runs a fault or an interrupt ended early.
fn stopped_section(s: &mut String, metrics: &[LawMetrics]) {
    let stopped: Vec<_> = metrics
        .iter()
        .filter(|m| m.interrupted_at_tick.is_some() || m.fault.is_some())
        .collect();
    if stopped.is_empty() {
        return;
    }
    let _ = writeln!(s, "\n## Stopped runs\n");
    for m in stopped {
        match (&m.fault, m.interrupted_at_tick) {
            (Some(cause), _) => {
                let _ = writeln!(
                    s,
                    "- `{}`: **fault** at tick {}: {cause}. Trace and metrics cover ticks 0..{}.",
                    m.law,
                    m.fault_at_tick.unwrap_or(0),
                    m.ticks
                );
            }
            (None, Some(k)) => {
                let _ = writeln!(
                    s,
                    "- `{}`: **interrupted** (Ctrl-C / SIGTERM) at tick {k}. Trace and metrics cover ticks 0..{}.",
                    m.law, m.ticks
                );
            }
            _ => {}
        }
    }
}

/// Runs that diverged, where and why.
fn diverged_section(s: &mut String, cfg: &RunConfig, metrics: &[LawMetrics]) {
    let diverged: Vec<_> = metrics
        .iter()
        .filter(|m| m.diverged_at_tick.is_some())
        .collect();
    if diverged.is_empty() {
        return;
    }
    let _ = writeln!(s, "\n## Diverged runs\n");
    for m in diverged {
        let _ = writeln!(
            s,
            "- `{}` stopped at tick {} (t = {:.4} s): {}. Its metrics cover ticks 0..{} only.",
            m.law,
            m.diverged_at_tick.unwrap_or(0),
            m.diverged_at_tick.unwrap_or(0) as f64 * cfg.loop_.ts_s,
            m.diverged_reason.as_deref().unwrap_or("?"),
            m.ticks
        );
    }
}

/// M̄ against this plant: the loop it makes, why the paper's M̄ cycles, and the cycles seen.
fn mismatch_section(
    s: &mut String,
    cfg: &RunConfig,
    p: &ControllerParams,
    metrics: &[LawMetrics],
    mm: &Mismatch,
) {
    let _ = writeln!(s, "\n## M̄ against this plant\n");
    let _ = writeln!(
        s,
        "Along this reference M(q) has eigenvalues in [{:.4}, {:.4}] kg m² (mean joint inertia {:.4}); M̄ = {} kg m², so the TDE \
         lags the plant by Ts·M/M̄ = {:.2}–{:.2} ms. Seen through the plant, the TDC core is a PID with P = M̄K_d/Ts = {:.0} N m/rad, \
         I = M̄K_p/Ts = {:.0} N m/(rad s), D = M̄/Ts = {:.2} N m s/rad: on the mean joint inertia it rings at {:.1} Hz with damping ratio ζ = {:.3}.\n",
        mm.lambda_min,
        mm.lambda_max,
        mm.joint_inertia_mean,
        mm.m_bar,
        mm.tde_lag_min_s * 1e3,
        mm.tde_lag_max_s * 1e3,
        mm.equiv_p,
        mm.equiv_i,
        mm.equiv_d,
        mm.equiv_freq_hz,
        mm.equiv_zeta
    );
    if cfg.controller.preset == Preset::Paper || mm.m_bar < 0.1 * mm.lambda_min {
        let _ = writeln!(
            s,
            "**Why the paper's M̄ misbehaves here.** M̄ = {} kg m² is {:.0}× smaller than the smallest joint inertia of this robot \
             (the paper's M̄ belongs to its own, unpublished robot). The TDE then carries a {:.0}–{:.0} ms lag and the core is the \
             lightly damped PID above (ζ ≈ {:.2}, ~{:.0} Hz). The switching terms add integral action to that loop, so `tdc-is-sta` \
             (k1 = {}) and `tde-is` with a thin boundary layer settle into a limit cycle near that frequency against the torque \
             clamp. That is a property of the gain/plant mismatch, not an implementation bug; the `matched` preset \
             (M̄ ≈ 0.9 λmin(M)) runs the method as intended.\n",
            mm.m_bar,
            mm.lambda_min / mm.m_bar,
            mm.tde_lag_min_s * 1e3,
            mm.tde_lag_max_s * 1e3,
            mm.equiv_zeta,
            mm.equiv_freq_hz,
            p.k1
        );
    }
    limit_cycles(s, metrics);
}

/// The laws that show a limit cycle in this run, or a line saying none does.
fn limit_cycles(s: &mut String, metrics: &[LawMetrics]) {
    let cycling: Vec<&LawMetrics> = metrics.iter().filter(|m| limit_cycle(m)).collect();
    if cycling.is_empty() {
        let _ = writeln!(
            s,
            "No law shows a sustained torque oscillation in this run (dominant torque line > 10 Hz together with clamping or HF share > 5 %)."
        );
        return;
    }
    let _ = writeln!(
        s,
        "Observed limit cycles (dominant torque line > 10 Hz with clamping or HF share > 5 %):\n"
    );
    for m in cycling {
        let _ = writeln!(
            s,
            "- `{}`: torque peaks at {} Hz, HF share {}, clamped in {} of {} intervals, max |τ| = {:.1} N m.",
            m.law,
            f3(m.torque_peak_hz, 1),
            f3(m.hf_torque_share, 3),
            m.clamp_count,
            m.ticks,
            max3(m.max_abs_tau_nm)
        );
    }
}

/// Every controller constant by its config key (`m_bar = 0.03, kp = 1800, …`), from the one list
/// of gains, so a new gain is in every report without a word written here.
fn gains_text(p: &ControllerParams) -> String {
    p.named()
        .iter()
        .map(|(k, v)| format!("{k} = {v}"))
        .collect::<Vec<_>>()
        .join(", ")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Regression: the header named seven of the ten constants and left the PID gains out. It
    /// lists every one, by its config key, with the value the run used.
    #[test]
    fn regression_the_header_names_every_controller_constant() {
        let cfg = RunConfig::from_file(std::path::Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../configs/s1-nominal.toml"
        )))
        .unwrap();
        let mut p = cfg.controller_params();
        p.pid_i = 12345.5;
        let mut s = String::new();
        header(&mut s, &cfg, &p, LoopMode::Inproc, "deltaloop run");
        for (k, v) in p.named() {
            assert!(s.contains(&format!("{k} = {v}")), "{k} missing: {s}");
        }
        assert!(s.contains("pid_i = 12345.5"), "{s}");
    }

    /// The plant's torque budget runs from the state's publication (`until = t_publish + budget`
    /// in the plant's run loop), not from the tick's deadline; the report must say so.
    #[test]
    fn timing_section_measures_a_miss_from_the_state_publication() {
        let cfg = RunConfig::from_toml_str("[scenario]\npath = \"s1\"\n", None).unwrap();
        let md = timing_markdown(&cfg, LoopMode::Realtime, &[], &[]);
        assert!(
            md.contains(&format!(
                "within {} µs (the torque budget) of the plant publishing its state",
                cfg.loop_.torque_budget_us
            )),
            "{md}"
        );
        assert!(!md.contains("µs of the deadline"), "{md}");
    }

    #[test]
    fn every_paper_scenario_has_a_table() {
        assert_eq!(paper_table(PathKind::S1), Some("II"));
        assert_eq!(paper_table(PathKind::S2), Some("III"));
        assert_eq!(paper_table(PathKind::S3), Some("IV"));
        assert_eq!(paper_table(PathKind::Custom), None);
    }
}
