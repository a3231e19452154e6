//! Fuzzing the config parser: no input may panic it. Whatever it accepts is valid and round-trips.

use deltaloop_config::{KeyDefault, LoopMode, RunConfig, keys};
use proptest::prelude::*;

/// The tables of the declared keys (`loop.<mode>` as both layouts), the top level, and one the
/// schema does not know.
fn sections() -> Vec<String> {
    let mut t: Vec<String> = vec![String::new(), "bogus".into()];
    for key in keys::all() {
        for table in tables(key.table) {
            if !t.contains(&table) {
                t.push(table);
            }
        }
    }
    t
}

/// The tables a declared key is in: `loop.<mode>` is both layouts.
fn tables(table: &str) -> Vec<String> {
    if table.contains("<mode>") {
        ["realtime", "lockstep"]
            .map(|m| table.replace("<mode>", m))
            .to_vec()
    } else {
        vec![table.to_string()]
    }
}

/// Every declared key's name in its table, and one the schema does not know.
fn field_names() -> Vec<&'static str> {
    let mut k: Vec<&str> = keys::all().iter().map(|k| k.field).collect();
    k.sort_unstable();
    k.dedup();
    k.push("unknown_key");
    k
}

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
        prop_oneof![Just("catch-up"), Just("fault"), Just("tick"), Just("arrival"), Just("relay"), Just("direct"), Just("controller"), Just("plant"), Just("127.0.0.1:7447"), Just("[::1]:0"), Just("humble"), Just("subnet"), Just("yield"), Just("/robot_io"), Just("a/1b")]
            .prop_map(|s| format!("{s:?}")),
        Just(r#"["sh", "-c", "x"]"#.to_string()),
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
            prop::sample::select(sections()),
            prop::collection::vec((prop::sample::select(field_names()), value()), 0..6),
        ),
        0..6,
    )
    .prop_map(|sections| {
        let mut s = String::from("[scenario]\npath = \"s1\"\n");
        for (name, kvs) in sections {
            let name = name.as_str();
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

/// A document of declared keys, each in its own table (mostly), with values often wrong.
fn declared_document() -> impl Strategy<Value = String> {
    // Each key in its table, with its declared default where it has one (a valid value).
    let placed: Vec<(String, &'static str, Option<String>)> = keys::all()
        .iter()
        .flat_map(|k| {
            let default = match (k.default, k.name().as_str()) {
                (KeyDefault::Value(v), _) => Some(v().to_string()),
                // The required keys of `[link]`.
                (_, "link.remote") => Some("\"controller\"".into()),
                (_, "link.listen") => Some("\"127.0.0.1:7447\"".into()),
                _ => None,
            };
            tables(k.table)
                .into_iter()
                .map(move |t| (t, k.field, default.clone()))
        })
        .collect();
    let line = (prop::sample::select(placed), value(), any::<bool>());
    (prop::collection::vec(line, 0..12), any::<bool>()).prop_map(|(kvs, link)| {
        let mut top = String::new();
        let mut scenario = String::from("path = \"s1\"\n");
        let mut tables: Vec<(String, String)> = Vec::new();
        for ((table, field, default), v, plausible) in kvs {
            let v = default.filter(|_| plausible).unwrap_or(v);
            let line = format!("{field} = {v}\n");
            match table.as_str() {
                "" => top.push_str(&line),
                "scenario" => scenario.push_str(&line),
                _ => match tables.iter_mut().find(|(t, _)| *t == table) {
                    Some((_, lines)) => lines.push_str(&line),
                    None => tables.push((table, line)),
                },
            }
        }
        // Often a `[link]` with its required keys, so that its others are accepted too.
        if link {
            let required = "remote = \"controller\"\nlisten = \"127.0.0.1:7447\"\n";
            match tables.iter_mut().find(|(t, _)| t == "link") {
                Some((_, lines)) => lines.insert_str(0, required),
                None => tables.push(("link".into(), required.into())),
            }
        }
        let mut s = format!("{top}[scenario]\n{scenario}");
        for (table, lines) in tables {
            s.push_str(&format!("[{table}]\n{lines}"));
        }
        s
    })
}

/// The fuzzer's keys are the declared ones: every key it can write is declared, and it writes
/// every declared key in its table.
#[test]
fn the_fuzzer_writes_every_declared_key() {
    let fields = field_names();
    let tables = sections();
    for key in keys::all() {
        assert!(fields.contains(&key.field), "{}", key.name());
        for t in self::tables(key.table) {
            assert!(tables.contains(&t), "{}", key.name());
        }
    }
    for f in [
        "transport_delay_us",
        "overrun",
        "command",
        "trace",
        "listen",
        "namespace",
    ] {
        assert!(fields.contains(&f), "{f}");
    }
    for t in ["record", "link", "ros2"] {
        assert!(tables.contains(&t.to_string()), "{t}");
    }
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
    fn declared_keys_in_their_tables_never_panic(doc in declared_document()) {
        check(&doc);
    }

    #[test]
    fn arbitrary_text_never_panics(text in ".{0,400}") {
        check(&text);
    }
}
