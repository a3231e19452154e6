//! Fuzzing the config parser: no input may panic it. Whatever it accepts is valid and round-trips.

use deltaloop_config::{LoopMode, RunConfig};
use proptest::prelude::*;

const SECTIONS: &[&str] = &[
    "",
    "scenario",
    "plant",
    "controller",
    "loop",
    "loop.realtime",
    "loop.lockstep",
    "sensor",
    "faults",
    "bogus",
];
const KEYS: &[&str] = &[
    "name",
    "path",
    "hold_s",
    "segments",
    "friction",
    "tau_max_nm",
    "substeps",
    "transport_delay_samples",
    "payload_step_kg",
    "payload_step_at_s",
    "preset",
    "laws",
    "tde_delay_samples",
    "compute_delay_us",
    "m_bar",
    "kp",
    "kd",
    "ks",
    "phi",
    "k1",
    "k2",
    "pid_p",
    "pid_i",
    "pid_d",
    "ts_s",
    "torque_budget_us",
    "silence_timeout_ms",
    "plant_cpu",
    "controller_cpu",
    "supervisor_cpu",
    "plant_priority",
    "controller_priority",
    "spin_us",
    "lock_memory",
    "wake_early_us",
    "controller_wake_early_us",
    "encoder_counts_per_rev",
    "q_noise_std_rad",
    "qd_noise_std_rad_s",
    "seed",
    "velocity",
    "controller_silence_ticks",
    "safe_stop_ms",
    "brake_damping_nm_s",
    "torque_limit",
    "inject",
    "unknown_key",
];

/// A TOML value that is often wrong: hostile numbers, wrong types, near-valid strings.
fn value() -> impl Strategy<Value = String> {
    prop_oneof![
        any::<i64>().prop_map(|v| v.to_string()),
        prop_oneof![Just(0.0f64), Just(-1.0), Just(1e308), Just(3e-4), Just(5e-5), Just(0.5), any::<f64>()].prop_map(|v| {
            if v.is_nan() { "nan".to_string() } else if v.is_infinite() { if v > 0.0 { "inf".into() } else { "-inf".into() } } else { format!("{v:e}") }
        }),
        Just("nan".to_string()),
        Just("-inf".to_string()),
        any::<bool>().prop_map(|b| b.to_string()),
        prop_oneof![Just("s1"), Just("s2"), Just("s3"), Just("custom"), Just("matched"), Just("paper"), Just("tdc"), Just("stall@3"), Just("nan-torque@x"), Just("reject"), Just("encoder-difference"), Just("")]
            .prop_map(|s| format!("{s:?}")),
        prop::collection::vec(prop_oneof![Just("\"tdc\""), Just("\"pid\""), Just("\"lqr\""), Just("1"), Just("0.25")], 0..4).prop_map(|v| format!("[{}]", v.join(", "))),
        Just("[{ from = [0.25, 0, -0.43], to = [-0.25, 0, -0.43], apex_m = 0.12, duration_s = 0.5 }]".to_string()),
        Just("[{ from = [9, 9, 9], to = [1], apex_m = nan, duration_s = -1 }]".to_string()),
        Just("[{ from = [0.25, 0, -0.43], to = [-0.25, 0, -0.43], apex_m = 0.12, duration_s = 1e-300 }]".to_string()),
        // Hostile strings: path escapes, control and format characters, very long text.
        prop_oneof![Just("../../../../tmp/victim"), Just("a/b"), Just("x\ny"), Just("\u{202e}gpj.exe"), Just(".x"), Just("-x"), Just("ok-name")]
            .prop_map(|s| toml::Value::from(s).to_string()),
        (1usize..5000).prop_map(|n| format!("\"{}\"", "\\n\\u200f".repeat(n))),
    ]
}

/// A config-shaped document: sections of key = value lines, mostly plausible, often wrong.
fn document() -> impl Strategy<Value = String> {
    prop::collection::vec(
        (
            prop::sample::select(SECTIONS),
            prop::collection::vec((prop::sample::select(KEYS), value()), 0..6),
        ),
        0..6,
    )
    .prop_map(|sections| {
        let mut s = String::from("[scenario]\npath = \"s1\"\n");
        for (name, kvs) in sections {
            if !name.is_empty() && name != "scenario" {
                s.push_str(&format!("[{name}]\n"));
            }
            for (k, v) in kvs {
                s.push_str(&format!("{k} = {v}\n"));
            }
        }
        s
    })
}

fn check(text: &str) {
    let parsed = RunConfig::from_toml_str(text, None);
    if let Err(e) = &parsed {
        // Errors are one line, and never echo a long value whole.
        let e = e.to_string();
        assert!(!e.contains(['\n', '\r']), "an error is one line: {e:?}");
        assert!(e.chars().count() < 1000, "an error is short: {e:?}");
    }
    if let Ok(cfg) = parsed {
        assert!(
            !cfg.name.is_empty() && !cfg.name.contains(['/', '\n']) && !cfg.name.starts_with('.'),
            "an accepted name is a plain folder name: {:?}",
            cfg.name
        );
        assert!(
            cfg.ticks(cfg.motion_duration_s()) >= 1,
            "an accepted run has at least one tick"
        );
        assert!(cfg.loop_.ts_s / f64::from(cfg.plant.substeps) >= 0.999e-6);
        cfg.validate().expect("an accepted config validates");
        let again = RunConfig::from_toml_str(&cfg.to_toml_string(), None)
            .expect("the resolved config parses");
        assert_eq!(cfg, again, "the resolved config round-trips");
        assert!(cfg.loop_.ts_s.is_finite() && cfg.controller_params().m_bar > 0.0);
        for (raw, layout) in [
            (&cfg.loop_.realtime, LoopMode::Realtime),
            (&cfg.loop_.lockstep, LoopMode::Lockstep),
        ] {
            let layout = layout.layout(&cfg).expect("a process mode has a layout");
            assert!(
                f64::from(layout.wake_early_us) <= cfg.loop_.ts_s * 1e6,
                "wake_early_us within one period"
            );
            let lead = layout.controller_lead_ns().unwrap_or(0) as f64 * 1e-9;
            assert!(
                lead <= cfg.loop_.ts_s,
                "controller_wake_early_us within one period"
            );
            // An accepted layout resolves without loss: each sentinel has its typed meaning.
            let key = |v: Option<usize>| v.map_or(-1, |c| c as i32);
            assert_eq!(raw.plant_cpu, Some(key(layout.plant_cpu)));
            assert_eq!(raw.controller_cpu, Some(key(layout.controller_cpu)));
            assert_eq!(raw.supervisor_cpu, Some(key(layout.supervisor_cpu)));
            assert_eq!(
                raw.plant_priority,
                Some(i32::from(layout.plant_priority.key_value()))
            );
            assert_eq!(
                raw.controller_priority,
                Some(i32::from(layout.controller_priority.key_value()))
            );
            assert_eq!(
                raw.controller_wake_early_us,
                Some(layout.controller_wake_early_us.map_or(-1, |us| us as i32))
            );
            assert_eq!(raw.spin_us, Some(layout.spin_us));
            assert_eq!(raw.wake_early_us, Some(layout.wake_early_us));
            assert_eq!(raw.lock_memory, Some(layout.lock_memory));
            assert_eq!(raw.poll, Some(layout.poll));
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    #[test]
    fn structured_toml_never_panics(doc in document()) {
        check(&doc);
    }

    #[test]
    fn arbitrary_text_never_panics(text in ".{0,400}") {
        check(&text);
    }
}
