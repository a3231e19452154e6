//! The declaration against everything made or checked from it: the serde schema, its defaults,
//! the range checks and the key table of docs/guide/scenario-files.md.

use super::*;
use crate::RunConfig;
use crate::key::Bounds;
use crate::text::show_num;
use std::collections::{BTreeMap, BTreeSet};

/// The smallest valid file, with a `[link]` and a `[ros2]` so that their keys are there too.
const FULL: &str = "[scenario]\npath = \"s1\"\n[link]\nremote = \"controller\"\nlisten = \"127.0.0.1:7447\"\n[ros2]\n";

/// The fields of the schema's table `table` ("" for the top level), from serde's own list in its
/// unknown-field error; None if `table` is not a table (a key).
fn schema_fields(table: &str) -> Option<Vec<String>> {
    let text = if table.is_empty() {
        "zz_probe = 1\n".to_string()
    } else {
        format!("[{table}]\nzz_probe = 1\n")
    };
    let e = toml::from_str::<RunConfig>(&text).unwrap_err();
    let rest = e
        .message()
        .strip_prefix("unknown field `zz_probe`, expected ")?;
    Some(
        rest.split('`')
            .skip(1)
            .step_by(2)
            .map(String::from)
            .collect(),
    )
}

/// Every key of the serde schema, walking its tables from the top; the two layouts are one
/// `loop.<mode>` table.
fn schema_keys() -> BTreeSet<String> {
    let mut keys = BTreeSet::new();
    let mut tables = vec![String::new()];
    while let Some(table) = tables.pop() {
        for field in schema_fields(&table).expect("a table") {
            let path = if table.is_empty() {
                field
            } else {
                format!("{table}.{field}")
            };
            if schema_fields(&path).is_some() {
                tables.push(path);
            } else {
                keys.insert(
                    path.replace("loop.realtime.", "loop.<mode>.")
                        .replace("loop.lockstep.", "loop.<mode>."),
                );
            }
        }
    }
    keys
}

#[test]
fn every_key_of_the_schema_is_declared_and_every_declared_key_is_in_it() {
    let declared: BTreeSet<String> = all().iter().map(Key::name).collect();
    assert_eq!(declared.len(), all().len(), "a key is declared twice");
    let schema = schema_keys();
    let undeclared: Vec<_> = schema.difference(&declared).collect();
    let gone: Vec<_> = declared.difference(&schema).collect();
    assert!(
        undeclared.is_empty() && gone.is_empty(),
        "keys in the serde schema but not declared in protocol/config/src/keys.rs: {undeclared:?}; declared but not in the schema: {gone:?}"
    );
}

/// The value at a dotted path of a TOML table.
fn at<'a>(t: &'a toml::Value, path: &str) -> Option<&'a toml::Value> {
    path.split('.').try_fold(t, |t, k| t.get(k))
}

/// A file with every table of the declared keys, empty (`[link]` with its required keys): what
/// it leaves out takes serde's default of each field.
fn every_table() -> String {
    let mut text = String::from("[scenario]\npath = \"s1\"\n");
    let mut seen = BTreeSet::new();
    for key in all() {
        let table = key.table.replace("<mode>", "realtime");
        if matches!(table.as_str(), "" | "scenario") || !seen.insert(table.clone()) {
            continue;
        }
        text.push_str(&format!("[{table}]\n"));
        if table == "link" {
            text.push_str("remote = \"controller\"\nlisten = \"127.0.0.1:7447\"\n");
        }
        if table == "loop.realtime" {
            text.push_str("[loop.lockstep]\n");
        }
    }
    text
}

/// The serde default of each field (every table there, empty) and the `Default` of each
/// section (no table but `[scenario]`, `[link]` and `[ros2]`) are the declared defaults.
#[test]
fn the_schema_defaults_are_the_declared_ones() {
    for text in [every_table(), FULL.to_string()] {
        let cfg = RunConfig::from_toml_str(&text, None).unwrap();
        let file = toml::Value::try_from(&cfg).unwrap();
        for key in all() {
            let KeyDefault::Value(declared) = key.default else {
                continue;
            };
            let declared = declared();
            match at(&file, &key.name()) {
                Some(v) => assert_eq!(v, &declared, "the default of `{}` in\n{text}", key.name()),
                // Left out when it has its default (`skip_serializing_if`).
                None => assert!(
                    declared.as_array().is_some_and(Vec::is_empty)
                        || declared
                            .as_str()
                            .is_some_and(|s| s.is_empty() || s == "direct"),
                    "`{}` is not written though its default is {declared}",
                    key.name()
                ),
            }
        }
    }
}

/// A file setting `key` (a layout key in `[loop.realtime]`) to `value`.
fn file_with(key: &Key, value: &str) -> (String, String) {
    let table = key.table.replace("<mode>", "realtime");
    let name = format!("{table}.{}", key.field);
    let base = "[scenario]\npath = \"s1\"\n";
    let text = match table.as_str() {
        "link" => format!(
            "{base}[link]\nremote = \"controller\"\nlisten = \"127.0.0.1:7447\"\n{} = {value}\n",
            key.field
        ),
        "scenario" => format!("{base}{} = {value}\n", key.field),
        _ => format!("{base}[{table}]\n{} = {value}\n", key.field),
    };
    (name, text)
}

#[test]
fn validation_refuses_what_each_declared_range_does_not_allow_in_its_words() {
    let mut checked = 0;
    for key in all() {
        let Some(Bounds {
            lo, lo_open, hi, ..
        }) = key.allowed.bounds()
        else {
            continue;
        };
        let whole = key.toml_type() == "integer";
        let unsigned = key.ty.contains('u');
        let mut outside = vec![hi + 1.0];
        if lo_open {
            outside.push(lo);
        } else if !(whole && unsigned && lo < 1.0) {
            outside.push(lo - 1.0);
        }
        for v in outside {
            let (written, shown) = if whole {
                let v = format!("{}", v as i64);
                (v.clone(), v)
            } else {
                (format!("{v:?}"), show_num(v))
            };
            let (name, text) = file_with(&key, &written);
            let e = RunConfig::from_toml_str(&text, None)
                .map(|_| "accepted".to_string())
                .unwrap_or_else(|e| e.to_string());
            assert_eq!(
                e,
                format!(
                    "config key `{name}` = {shown} is out of range: {}",
                    key.allowed_text()
                ),
                "{text}"
            );
            checked += 1;
        }
        // The range does not refuse its bounds (a rule across keys may: `substeps` and the
        // period).
        for v in [hi, if lo_open { hi } else { lo }] {
            let v = if whole {
                format!("{}", v as i64)
            } else {
                format!("{v:?}")
            };
            let (_, text) = file_with(&key, &v);
            if let Err(e) = RunConfig::from_toml_str(&text, None) {
                assert!(!e.to_string().ends_with(&key.allowed_text()), "{text}: {e}");
            }
        }
    }
    assert!(checked > 40, "{checked}");
}

#[test]
fn span_words_name_their_bound_and_gain_units_read_as_their_docs() {
    for key in all() {
        if let Allowed::Span { bounds, words } = key.allowed {
            let hi = bounds.hi;
            let (a, b) = (format!("{}", hi as i64), show_num(hi));
            assert!(
                words.contains(&a) || words.contains(&b),
                "{}: {words}",
                key.name()
            );
        }
    }
    let units: Vec<String> = gain_keys()
        .iter()
        .map(|k| k.table_row().split(" | ").nth(2).unwrap().to_string())
        .collect();
    assert_eq!(
        units,
        [
            "kg m²",
            "1/s²",
            "1/s",
            "rad/s²",
            "rad/s",
            "rad^½/s^(3/2)",
            "rad/s³",
            "N m/rad",
            "N m/(rad s)",
            "N m s/rad"
        ]
    );
    assert_eq!(gain_unit(gain_keys()[0].doc), "kg m²");
}

const DOC: &str = "docs/guide/scenario-files.md";
const BEGIN: &str = "<!-- keys: begin";
const END: &str = "<!-- keys: end -->";

/// The key table of docs/guide/scenario-files.md is the declaration's: every key, and each
/// key's type, unit, default, allowed values and meaning. `DELTALOOP_UPDATE_DOCS=1` writes it.
#[test]
fn the_key_table_of_the_guide_is_the_declaration() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../..")
        .join(DOC);
    let doc = std::fs::read_to_string(&path).unwrap();
    let begin = doc
        .find(BEGIN)
        .expect("the guide has its key table's begin marker");
    let body = begin + doc[begin..].find("-->").unwrap() + 3;
    let end = doc
        .find(END)
        .expect("the guide has its key table's end marker");
    let want = format!("\n{}\n", doc_table());
    if std::env::var_os("DELTALOOP_UPDATE_DOCS").is_some() {
        let new = format!("{}{want}{}", &doc[..body], &doc[end..]);
        std::fs::write(&path, new).unwrap();
        return;
    }
    let rows = |t: &str| -> BTreeMap<String, String> {
        t.lines()
            .filter(|l| l.starts_with("| `"))
            .map(|l| (l.split('`').nth(1).unwrap().to_string(), l.to_string()))
            .collect()
    };
    let (have, want_rows) = (rows(&doc[body..end]), rows(&want));
    let missing: Vec<_> = want_rows
        .keys()
        .filter(|k| !have.contains_key(*k))
        .collect();
    let extra: Vec<_> = have
        .keys()
        .filter(|k| !want_rows.contains_key(*k))
        .collect();
    let differ: Vec<_> = want_rows
        .iter()
        .filter(|(k, row)| have.get(*k).is_some_and(|h| h != *row))
        .map(|(k, row)| format!("\n  doc:  {}\n  want: {row}", have[k]))
        .collect();
    assert!(
        missing.is_empty() && extra.is_empty() && differ.is_empty(),
        "{DOC}'s key table differs from protocol/config/src/keys.rs (DELTALOOP_UPDATE_DOCS=1 cargo test -p deltaloop-config keys writes it): declared keys missing from it: {missing:?}; keys it names that are not declared: {extra:?}; rows that differ:{}",
        differ.concat()
    );
    assert_eq!(&doc[body..end], want, "the table's order and header");
}
