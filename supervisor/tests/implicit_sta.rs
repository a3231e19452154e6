//! `tdc-is-ista`, the super-twisting term discretised implicitly, against the paper's explicit
//! `tdc-is-sta` and `tde-is` (docs/controllers.md, "Super-twisting: explicit and implicit"): the
//! properties that make it worth having, each measured in-process on S1–S3, preset `matched`.

use deltaloop_config::{Law, RunConfig};
use deltaloop_runner::inproc;
use deltaloop_runner::lawrun::Keep;
use deltaloop_study::Study;
use deltaloop_study::record::RunStatus;
use deltaloop_study::record::metrics::LawMetrics;

fn metrics(scenario: &str, extra: &str, law: Law) -> LawMetrics {
    let text = format!("[scenario]\npath = \"{scenario}\"\n[plant]\nfriction = true\n{extra}");
    let study = Study::new(RunConfig::from_toml_str(&text, None).unwrap()).unwrap();
    let m = inproc::run_law(&study, law, &Keep::default())
        .unwrap()
        .metrics;
    assert_eq!(m.status, RunStatus::Ok, "{scenario} {law}: {:?}", m.reason);
    m
}

fn max3(v: [f64; 3]) -> f64 {
    v.into_iter().fold(0.0, f64::max)
}

/// No delay: the implicit law keeps the torque smooth (high-frequency share at most a tenth of
/// the explicit law's) and tracks at least as well as `tde-is`, on every paper scenario.
#[test]
fn implicit_sta_is_smooth_and_tracks_as_well_as_tde_is() {
    for scn in ["s1", "s2", "s3"] {
        let [is, sta, ista] =
            [Law::TdeIs, Law::TdcIsSta, Law::TdcIsIsta].map(|l| metrics(scn, "", l));
        let (hf_sta, hf_ista) = (max3(sta.hf_torque_share), max3(ista.hf_torque_share));
        assert!(
            hf_ista <= hf_sta / 10.0,
            "{scn}: high-frequency torque share {hf_ista} vs explicit {hf_sta}"
        );
        assert!(
            max3(ista.rms_rad) <= max3(is.rms_rad),
            "{scn}: RMS {:?} vs tde-is {:?}",
            ista.rms_rad,
            is.rms_rad
        );
    }
}

/// 90 µs of transport delay (under a third of a tick): the explicit law's chattering feeds on
/// the delay and its RMS grows by two orders of magnitude; the implicit law's stays at least ten
/// times smaller.
#[test]
fn implicit_sta_keeps_its_accuracy_under_sub_tick_delay() {
    let delay = "transport_delay_us = 90\n";
    let sta = metrics("s1", delay, Law::TdcIsSta);
    let ista = metrics("s1", delay, Law::TdcIsIsta);
    let ratio = max3(sta.rms_rad) / max3(ista.rms_rad);
    assert!(ratio >= 10.0, "explicit / implicit RMS at 90 µs: {ratio}");
}
