//! Closed-loop behaviour of the in-process runner: every law tracks S1; the paper preset shows
//! the limit cycle; a diverging configuration is reported, not crashed; runs are deterministic.

use deltaloop_config::{Law, RunConfig};
use deltaloop_report::report::limit_cycle;
use deltaloop_runner::inproc;
use deltaloop_runner::lawrun::{Keep, LawRun};
use deltaloop_study::Study;
use deltaloop_study::record::metrics::LawMetrics;
use deltaloop_study::record::{Outcome, RunStatus};

fn study(extra: &str) -> Study {
    let text = format!("[scenario]\npath = \"s1\"\n[plant]\nfriction = true\n{extra}");
    Study::new(RunConfig::from_toml_str(&text, None).unwrap()).unwrap()
}

/// Keep every record (these runs are short).
fn keep() -> Keep {
    Keep {
        records: true,
        ..Keep::default()
    }
}

fn run_law(s: &Study, law: Law) -> LawRun {
    inproc::run_law(s, law, &keep()).unwrap()
}

fn run_laws(s: &Study, laws: &[Law]) -> Vec<LawRun> {
    inproc::run_laws(s, laws, |_| keep())
        .into_iter()
        .map(Result::unwrap)
        .collect()
}

fn metrics(s: &Study, law: Law) -> LawMetrics {
    run_law(s, law).metrics
}

#[test]
fn every_law_tracks_s1_with_bounded_error_matched_preset() {
    let s = study("");
    for (run, law) in run_laws(&s, Law::ALL).iter().zip(Law::ALL.iter().copied()) {
        assert_eq!(run.end.outcome, Outcome::Completed, "{law}");
        assert_eq!(run.records.len(), 2668);
        let m = &run.metrics;
        // The model-free TDC family tracks to well under a milliradian; PID to ~1 mrad.
        let bound = if law == Law::Pid { 2e-3 } else { 1e-4 };
        for i in 0..3 {
            assert!(
                m.max_abs_err_rad[i] < bound,
                "{law} joint {i}: {:e}",
                m.max_abs_err_rad[i]
            );
        }
        assert!(m.task_max_mm < 1.0, "{law}: {} mm", m.task_max_mm);
        assert_eq!(m.clamp_count, 0, "{law}");
        // s₀ = 0: the run starts on the sliding surface.
        assert_eq!(
            run.records[0].out.expect("answered").s,
            deltaloop_model::Vec3::zeros()
        );
    }
}

#[test]
fn tde_laws_beat_pid_on_the_matched_preset() {
    let s = study("");
    let pid = metrics(&s, Law::Pid).rms_rad[0];
    for law in [Law::Tdc, Law::TdeIs, Law::TdcIsSta] {
        assert!(metrics(&s, law).rms_rad[0] < pid / 10.0, "{law}");
    }
}

#[test]
fn paper_preset_limit_cycle_appears_for_sta_only() {
    let s = study("[controller]\npreset = \"paper\"\n");
    let sta = metrics(&s, Law::TdcIsSta);
    let peak = sta.torque_peak_hz[0];
    assert!(
        (25.0..40.0).contains(&peak),
        "limit cycle near 30 Hz, got {peak} Hz"
    );
    assert!(
        sta.clamp_count > 100,
        "the cycle rides the torque clamp: {}",
        sta.clamp_count
    );
    assert!(limit_cycle(&sta));
    // tde-is with φ = 100 rad/s (the paper preset's boundary layer) stays smooth.
    let is = metrics(&s, Law::TdeIs);
    assert!(!limit_cycle(&is) && is.clamp_count == 0, "{is:?}");
    // ... but a thin boundary layer makes it cycle too (docs/controllers.md).
    let thin = study("[controller]\npreset = \"paper\"\nphi = 0.5\n");
    assert!(limit_cycle(&metrics(&thin, Law::TdeIs)));
}

#[test]
fn diverging_configuration_is_reported_with_its_tick() {
    // M̄ far above the joint inertia makes TDC unstable: it must stop, not crash.
    let s = study("[controller]\nm_bar = 5.0\n");
    let run = run_law(&s, Law::Tdc);
    let Outcome::Diverged { tick, reason } = &run.end.outcome else {
        panic!("expected divergence, got {:?}", run.end.outcome)
    };
    assert!(*tick < 2667, "{tick}");
    assert_eq!(run.records.last().unwrap().sample.k, *tick);
    assert!(
        reason.contains("tracking error")
            || reason.contains("non-finite")
            || reason.contains("joint configuration"),
        "{reason}"
    );
    let m = &run.metrics;
    assert_eq!(
        (m.status, m.status_tick),
        (RunStatus::Diverged, Some(*tick))
    );
    assert_eq!(m.diverged_at_tick, Some(*tick));
}

#[test]
fn runs_are_deterministic_bit_for_bit() {
    let s = study("");
    let a = run_law(&s, Law::TdcIsSta);
    let b = run_laws(&s, &[Law::Pid, Law::TdcIsSta]).pop().unwrap();
    assert_eq!(a.records, b.records);
}

#[test]
fn truth_n_matches_closed_form_with_exact_tde() {
    // ℓ = 1, no noise: Ñ_k = N̂_k − N_k where N̂_k = a_{k−1} − τᵃ_k/M̄ and N_k = a_k − τᵃ_{k+1}/M̄,
    // so Ñ_k = (a_{k−1} − a_k) − (τᵃ_k − τᵃ_{k+1})/M̄, recomputed here from the records.
    let s = study("");
    let run = run_law(&s, Law::TdcIsSta);
    let ts = s.reference.ts;
    let m_bar = s.params.m_bar;
    let r = &run.records;
    let mut sq = 0.0;
    for k in 0..s.reference.n {
        let a = |j: usize| (r[j + 1].qd_true[0] - r[j].qd_true[0]) / ts;
        let a_prev = if k == 0 { 0.0 } else { a(k - 1) };
        let n_hat = a_prev - r[k].sample.tau_applied[0] / m_bar;
        assert!(
            (n_hat - r[k].out.expect("answered").n_hat[0]).abs() <= 1e-9 * n_hat.abs().max(1.0),
            "k={k}"
        );
        let truth = a(k) - r[k + 1].sample.tau_applied[0] / m_bar;
        sq += (n_hat - truth).powi(2);
    }
    let rms = (sq / s.reference.n as f64).sqrt();
    let m = &run.metrics;
    assert!(
        (m.tde_err_rms.unwrap()[0] - rms).abs() <= 1e-12 * rms,
        "{} vs {rms}",
        m.tde_err_rms.unwrap()[0]
    );
}
