//! `docs/protocol.md` is the contract a stranger implements a plant or controller from (Python,
//! C++, MuJoCo), so it must say exactly what the code does. This reads the document and checks
//! it against the code: for every wire type its iceoryx2 type name, size, alignment, and each
//! field's offset and type (the set and order of fields parsed from `wire.rs`, so an added field
//! fails here until it is documented); the services table against the QoS of the real iceoryx2
//! services; the constants and enum values the document lists; and the iceoryx2 version against
//! `Cargo.lock`.

use deltaloop_transport::exit;
use deltaloop_transport::ipc;
use deltaloop_transport::wire::{
    self, ControlKind, ControlMsg, RefSample, Sender, StateMsg, TelemetryMsg, TorqueMsg,
};
use iceoryx2::prelude::{PortFactory, ZeroCopySend};
use iceoryx2::service::static_config::message_type_details::{MessageTypeDetails, TypeVariant};
use std::collections::BTreeSet;
use std::mem::{align_of, offset_of, size_of};
use std::path::Path;

use crate::common;

fn read(rel: &str) -> String {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(rel);
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()))
}

fn doc() -> String {
    read("docs/protocol.md")
}

/// What the code says about one wire type.
struct Actual {
    /// The Rust type's name (`StateMsg`).
    rust: &'static str,
    /// Its iceoryx2 type name (`deltaloop::StateMsg/v1`).
    type_name: &'static str,
    size: usize,
    align: usize,
    /// Every field and its offset, in declaration order.
    fields: Vec<(&'static str, usize)>,
}

/// The layout of `$t` from the compiler: a field that no longer exists fails to compile, one that
/// is missing here is caught by the comparison with the struct parsed from `wire.rs`.
macro_rules! actual {
    ($t:ident { $($f:ident),* $(,)? }) => {
        Actual {
            rust: stringify!($t),
            // SAFETY: type_name only returns a string; the safety contract concerns the layout
            // that other processes assume, which is what this test checks.
            type_name: unsafe { <$t as ZeroCopySend>::type_name() },
            size: size_of::<$t>(),
            align: align_of::<$t>(),
            fields: vec![$((stringify!($f), offset_of!($t, $f))),*],
        }
    };
}

fn wire_types() -> Vec<Actual> {
    common::wire_types!(actual)
}

/// The fields of `pub struct <name>` in `wire.rs`, as (name, type) in declaration order.
fn source_fields(src: &str, name: &str) -> Vec<(String, String)> {
    let head = format!("pub struct {name} {{");
    let start = src
        .find(&head)
        .unwrap_or_else(|| panic!("wire.rs has no `{head}`"));
    let body = &src[start + head.len()..];
    let end = body
        .find("\n}")
        .unwrap_or_else(|| panic!("wire.rs: `{head}` has no closing brace"));
    body[..end]
        .lines()
        .map(str::trim)
        .filter(|l| !l.starts_with("//") && !l.starts_with("#[") && !l.is_empty())
        .map(|l| {
            let l = l.strip_prefix("pub ").unwrap_or(l).trim_end_matches(',');
            let (f, t) = l
                .split_once(':')
                .unwrap_or_else(|| panic!("wire.rs, struct {name}: cannot read field `{l}`"));
            (f.trim().to_string(), normalize(t))
        })
        .collect()
}

/// A type written without spaces (`[f64;3]`), so the document and the source compare as text.
fn normalize(t: &str) -> String {
    t.chars().filter(|c| !c.is_whitespace()).collect()
}

/// Bytes of a field type as the document and `wire.rs` write it: u8/u32/u64/f64 and arrays of
/// them.
fn type_size(t: &str) -> usize {
    match t {
        "u8" => 1,
        "u32" => 4,
        "u64" | "f64" => 8,
        _ => {
            let inner = t
                .strip_prefix('[')
                .and_then(|t| t.strip_suffix(']'))
                .unwrap_or_else(|| panic!("unknown wire field type `{t}`"));
            let (elem, n) = inner
                .rsplit_once(';')
                .unwrap_or_else(|| panic!("unknown wire field type `{t}`"));
            let n: usize = n
                .parse()
                .unwrap_or_else(|_| panic!("bad array length in `{t}`"));
            n * type_size(elem)
        }
    }
}

/// The text between backticks, in order.
fn backticked(s: &str) -> Vec<&str> {
    s.split('`').skip(1).step_by(2).collect()
}

/// The cells of a Markdown table row (None for any other line).
fn cells(line: &str) -> Option<Vec<&str>> {
    let l = line.trim();
    if !l.starts_with('|') || !l.ends_with('|') || l.len() < 2 {
        return None;
    }
    Some(l[1..l.len() - 1].split('|').map(str::trim).collect())
}

/// The lines of the section that starts at the line `heading` starts with, up to the next
/// heading of the same or a higher level.
fn section<'a>(doc: &'a str, heading: &str) -> Vec<&'a str> {
    let level = heading.chars().take_while(|&c| c == '#').count();
    let mut lines = doc.lines();
    let found = lines.by_ref().any(|l| l.starts_with(heading));
    assert!(
        found,
        "docs/protocol.md has no heading starting `{heading}`"
    );
    lines
        .take_while(|l| {
            let h = l.chars().take_while(|&c| c == '#').count();
            !(h > 0 && h <= level && l.chars().nth(h) == Some(' '))
        })
        .collect()
}

/// What the document says about one wire type.
struct Documented {
    type_name: String,
    size: usize,
    align: usize,
    /// (field, offset, type) in table order.
    fields: Vec<(String, usize, String)>,
}

/// Reads the section `### \`<rust>\` — \`<type name>\``: its size line and its field table.
fn documented(doc: &str, rust: &str) -> Documented {
    let heading = format!("### `{rust}`");
    let line = doc
        .lines()
        .find(|l| l.starts_with(&heading))
        .unwrap_or_else(|| panic!("docs/protocol.md has no heading `{heading} — `type name``"));
    let names = backticked(line);
    assert_eq!(
        names.len(),
        2,
        "the heading of {rust} must be `### \\`{rust}\\` — \\`<type name>\\``, found `{line}`"
    );
    let body = section(doc, &heading);
    let size_line = body
        .iter()
        .find(|l| l.starts_with("size "))
        .unwrap_or_else(|| panic!("{rust}: no line `size N B, alignment A`"));
    let (size, align) = size_line
        .strip_prefix("size ")
        .and_then(|s| s.split_once(" B, alignment "))
        .and_then(|(s, a)| Some((s.trim().parse().ok()?, a.trim().parse().ok()?)))
        .unwrap_or_else(|| panic!("{rust}: cannot read `{size_line}` as `size N B, alignment A`"));
    let fields = body
        .iter()
        .filter_map(|l| cells(l))
        .filter(|c| c.first().is_some_and(|f| f.starts_with('`')))
        .map(|c| {
            assert!(c.len() >= 3, "{rust}: short table row {c:?}");
            let offset = c[1].parse().unwrap_or_else(|_| {
                panic!("{rust}: offset `{}` of {} is not a number", c[1], c[0])
            });
            (
                c[0].trim_matches('`').to_string(),
                offset,
                normalize(c[2].trim_matches('`')),
            )
        })
        .collect();
    Documented {
        type_name: names[1].to_string(),
        size,
        align,
        fields,
    }
}

#[test]
fn every_wire_type_is_documented_exactly() {
    let (doc, src) = (doc(), read("protocol/wire/src/lib.rs"));
    for a in wire_types() {
        let t = a.rust;
        let d = documented(&doc, t);
        let source = source_fields(&src, t);

        // The struct itself: what the compiler lays out is what wire.rs declares.
        let source_names: Vec<&str> = source.iter().map(|(f, _)| f.as_str()).collect();
        let compiled: Vec<&str> = a.fields.iter().map(|(f, _)| *f).collect();
        assert_eq!(
            source_names, compiled,
            "{t}: wire.rs declares other fields than this test lists (update the test's actual!)"
        );

        // The type name, size and alignment iceoryx2 compares between peers.
        assert_eq!(
            d.type_name, a.type_name,
            "{t}: type name in docs/protocol.md"
        );
        assert_eq!(d.size, a.size, "{t}: size in docs/protocol.md");
        assert_eq!(d.align, a.align, "{t}: alignment in docs/protocol.md");

        // The same fields, none missing, none extra, in declaration order.
        let documented: BTreeSet<&str> = d.fields.iter().map(|(f, _, _)| f.as_str()).collect();
        let declared: BTreeSet<&str> = source_names.iter().copied().collect();
        let missing: Vec<_> = declared.difference(&documented).collect();
        let extra: Vec<_> = documented.difference(&declared).collect();
        assert!(
            missing.is_empty() && extra.is_empty(),
            "{t}: fields not documented {missing:?}, documented but not in the struct {extra:?}"
        );
        let doc_order: Vec<&str> = d.fields.iter().map(|(f, _, _)| f.as_str()).collect();
        assert_eq!(
            doc_order, source_names,
            "{t}: field order in docs/protocol.md"
        );

        // Each field's offset and type.
        for ((field, offset, ty), ((_, src_ty), (_, real))) in
            d.fields.iter().zip(source.iter().zip(&a.fields))
        {
            assert_eq!(offset, real, "{t}::{field}: offset in docs/protocol.md");
            assert_eq!(ty, src_ty, "{t}::{field}: type in docs/protocol.md");
        }

        // No implicit padding, as the document promises: each field starts where the previous
        // one ends, and the last one ends at the size.
        let mut end = 0;
        for (field, offset, ty) in &d.fields {
            assert_eq!(*offset, end, "{t}::{field}: implicit padding before it");
            end = offset + type_size(ty);
        }
        assert_eq!(end, a.size, "{t}: implicit padding at the end");
    }
}

/// The iceoryx2 version is part of the contract (it refuses services of another version).
#[test]
fn iceoryx2_version_is_the_locked_one() {
    let lock = read("Cargo.lock");
    let locked = lock
        .split("[[package]]")
        .find(|p| p.lines().any(|l| l.trim() == "name = \"iceoryx2\""))
        .and_then(|p| p.lines().find_map(|l| l.trim().strip_prefix("version = ")))
        .map(|v| v.trim_matches('"').to_string())
        .expect("Cargo.lock has no iceoryx2 package");
    let doc = doc();
    let marker = "iceoryx2 version: `";
    let at = doc
        .find(marker)
        .expect("docs/protocol.md states no `iceoryx2 version: \\`X.Y.Z\\``");
    let stated = doc[at + marker.len()..]
        .split('`')
        .next()
        .unwrap_or_default();
    assert_eq!(
        stated, locked,
        "iceoryx2 version in docs/protocol.md vs Cargo.lock"
    );
    let pin = format!("iceoryx2=={locked}");
    for f in ["python/requirements.txt", "python/pyproject.toml"] {
        assert!(
            read(f).contains(&pin),
            "{f} does not pin `{pin}` (the version of Cargo.lock)"
        );
    }
}

/// The value of the table row that has a cell exactly `` `key` ``: its first cell that is a
/// number. Every such row must agree; None if there is none.
fn table_value(doc: &str, key: &str) -> Option<u64> {
    let cell = format!("`{key}`");
    let values: Vec<u64> = doc
        .lines()
        .filter_map(cells)
        .filter(|c| c.contains(&cell.as_str()))
        .map(|c| {
            c.iter()
                .find_map(|v| v.replace([' ', '_'], "").parse().ok())
                .unwrap_or_else(|| panic!("the row of {cell} has no number: {c:?}"))
        })
        .collect();
    if let Some(v) = values.first() {
        assert!(
            values.iter().all(|x| x == v),
            "docs/protocol.md gives {cell} different values: {values:?}"
        );
    }
    values.first().copied()
}

#[test]
fn constants_and_enum_values_are_documented_exactly() {
    let doc = doc();
    let mut expected: Vec<(String, u64)> = [
        ("WIRE_VERSION", u64::from(wire::WIRE_VERSION)),
        ("STATE_FINAL", u64::from(wire::STATE_FINAL)),
        ("TEL_CLAMPED", u64::from(wire::TEL_CLAMPED)),
        ("TEL_HELD", u64::from(wire::TEL_HELD)),
        ("TEL_MISSED", u64::from(wire::TEL_MISSED)),
        ("TEL_REJECTED", u64::from(wire::TEL_REJECTED)),
        ("TEL_SAFE_STOP", u64::from(wire::TEL_SAFE_STOP)),
        ("TEL_STAMP_REPLACED", u64::from(wire::TEL_STAMP_REPLACED)),
        ("EXIT_USAGE", u64::from(exit::EXIT_USAGE)),
        ("EXIT_SETUP", u64::from(exit::EXIT_SETUP)),
        ("EXIT_FAULT", u64::from(exit::EXIT_FAULT)),
        ("EXIT_STOPPED", u64::from(exit::EXIT_STOPPED)),
        ("EXIT_PEER_SILENT", u64::from(exit::EXIT_PEER_SILENT)),
        ("LOOP_BUFFER", ipc::LOOP_BUFFER as u64),
        ("OBSERVER_BUFFER", ipc::OBSERVER_BUFFER as u64),
        ("REF_CHUNK", ipc::REF_CHUNK as u64),
        ("REF_RING", ipc::REF_RING as u64),
        ("HANDSHAKE_TIMEOUT_NS", ipc::HANDSHAKE_TIMEOUT_NS),
        ("START_TIMEOUT_NS", ipc::START_TIMEOUT_NS),
    ]
    .into_iter()
    .map(|(k, v)| (k.to_string(), v))
    .collect();
    // Every kind and sender this version knows, found by their wire values (so a new one must be
    // documented too).
    for v in 0..=u32::from(u8::MAX) {
        if let Some(k) = ControlKind::from_wire(v) {
            expected.push((format!("ControlKind::{k:?}"), u64::from(v)));
        }
        if let Some(s) = Sender::from_wire(v) {
            expected.push((format!("Sender::{s:?}"), u64::from(v)));
        }
    }
    for (key, value) in &expected {
        assert_eq!(
            table_value(&doc, key),
            Some(*value),
            "docs/protocol.md: the table row of `{key}`"
        );
    }
    // The Python helper's constants say the same (`ControllerError` is `CONTROLLER_ERROR`).
    let py = read("python/deltaloop/wire.py");
    for v in 0..=u32::from(u8::MAX) {
        let Some(k) = ControlKind::from_wire(v) else {
            continue;
        };
        let mut name = String::new();
        for (i, c) in format!("{k:?}").chars().enumerate() {
            if c.is_uppercase() && i > 0 {
                name.push('_');
            }
            name.push(c.to_ascii_uppercase());
        }
        let line = format!("{name} = {v}");
        assert!(
            py.lines()
                .any(|l| l == line || l.starts_with(&format!("{line} "))),
            "python/deltaloop/wire.py: no `{line}`"
        );
    }
    // And no kind or sender the code does not know.
    for c in doc.lines().filter_map(cells) {
        if let Some(k) = c.first().and_then(|f| backticked(f).first().copied())
            && (k.starts_with("ControlKind::") || k.starts_with("Sender::"))
        {
            assert!(
                expected.iter().any(|(e, _)| e == k),
                "docs/protocol.md documents `{k}`, which the code does not have"
            );
        }
    }
}

/// One row of the services table.
struct ServiceRow {
    name: String,
    payload: String,
    max_pub: usize,
    max_sub: usize,
    max_nodes: usize,
    /// Publish-subscribe only: subscriber max buffer, history, safe overflow.
    queue: Option<(usize, usize, bool)>,
}

fn service_rows(doc: &str) -> Vec<ServiceRow> {
    let num = |s: &str, what: &str, row: &[&str]| -> usize {
        s.parse()
            .unwrap_or_else(|_| panic!("services table: {what} `{s}` is not a number in {row:?}"))
    };
    section(doc, "## 3 Services")
        .into_iter()
        .filter_map(cells)
        .filter(|c| c.first().is_some_and(|f| f.starts_with('`')) && c.len() == 10)
        .map(|c| ServiceRow {
            name: c[0].trim_matches('`').to_string(),
            payload: c[2].trim_matches('`').to_string(),
            max_pub: num(c[4], "max publishers", &c),
            max_sub: num(c[5], "max subscribers", &c),
            max_nodes: num(c[6], "max nodes", &c),
            queue: c[1].starts_with("publish-subscribe").then(|| {
                let overflow = match c[9] {
                    "yes" => true,
                    "no" => false,
                    o => panic!("services table: safe overflow `{o}` is not yes/no in {c:?}"),
                };
                (num(c[7], "buffer", &c), num(c[8], "history", &c), overflow)
            }),
        })
        .collect()
}

/// Compares a publish-subscribe service's settings and types with its row.
fn check_pubsub(
    row: &ServiceRow,
    cfg: &iceoryx2::service::static_config::publish_subscribe::StaticConfig,
    type_name: &str,
    size: usize,
    variant: TypeVariant,
) {
    let n = &row.name;
    assert_eq!(cfg.max_publishers(), row.max_pub, "{n}: max publishers");
    assert_eq!(cfg.max_subscribers(), row.max_sub, "{n}: max subscribers");
    assert_eq!(cfg.max_nodes(), row.max_nodes, "{n}: max nodes");
    let (buffer, history, overflow) = row.queue.expect("a publish-subscribe row");
    assert_eq!(cfg.subscriber_max_buffer_size(), buffer, "{n}: buffer");
    assert_eq!(cfg.history_size(), history, "{n}: history");
    assert_eq!(cfg.has_safe_overflow(), overflow, "{n}: safe overflow");
    let MessageTypeDetails {
        payload,
        user_header,
        ..
    } = cfg.message_type_details();
    assert_eq!(
        payload.type_name().to_string(),
        type_name,
        "{n}: payload type"
    );
    assert_eq!(
        (payload.size(), payload.alignment()),
        (size, 8),
        "{n}: payload"
    );
    assert_eq!(payload.variant(), variant, "{n}: payload variant");
    // No user header: `()`, as the document says.
    assert_eq!(
        user_header.type_name().to_string(),
        "()",
        "{n}: user header"
    );
    assert_eq!((user_header.size(), user_header.alignment()), (0, 1));
}

/// The services table is what `ipc.rs` really creates: opened under a run id of this test's own.
#[test]
fn services_table_matches_the_iceoryx2_services() {
    let doc = doc();
    let rows = service_rows(&doc);
    let names: Vec<&str> = rows.iter().map(|r| r.name.as_str()).collect();
    assert_eq!(
        names,
        [
            "state",
            "torque",
            "telemetry",
            "control",
            "control-plant",
            "control-controller",
            "reference",
            "state-ready",
            "torque-ready"
        ],
        "the services table of docs/protocol.md"
    );
    let run_id = format!(
        "wire-contract-{}-{}",
        std::process::id(),
        deltaloop_transport::rt::now_ns()
    );
    let node = ipc::node("wire-contract", &run_id).expect("node");
    // SAFETY (each): only the type name string is read.
    let name_of = |rust: &str| -> &'static str {
        unsafe {
            match rust {
                "StateMsg" => <StateMsg as ZeroCopySend>::type_name(),
                "TorqueMsg" => <TorqueMsg as ZeroCopySend>::type_name(),
                "TelemetryMsg" => <TelemetryMsg as ZeroCopySend>::type_name(),
                "ControlMsg" => <ControlMsg as ZeroCopySend>::type_name(),
                "[RefSample]" => <RefSample as ZeroCopySend>::type_name(),
                other => panic!("services table: unknown payload `{other}`"),
            }
        }
    };
    for row in &rows {
        let fixed = TypeVariant::FixedSize;
        match row.name.as_str() {
            "state" => {
                let s = ipc::state(&node, &run_id).expect("state");
                check_pubsub(
                    row,
                    s.static_config(),
                    name_of(&row.payload),
                    size_of::<StateMsg>(),
                    fixed,
                );
            }
            "torque" => {
                let s = ipc::torque(&node, &run_id).expect("torque");
                check_pubsub(
                    row,
                    s.static_config(),
                    name_of(&row.payload),
                    size_of::<TorqueMsg>(),
                    fixed,
                );
            }
            "telemetry" => {
                let s = ipc::telemetry(&node, &run_id).expect("telemetry");
                check_pubsub(
                    row,
                    s.static_config(),
                    name_of(&row.payload),
                    size_of::<TelemetryMsg>(),
                    fixed,
                );
            }
            name @ ("control" | "control-plant" | "control-controller") => {
                let from = [Sender::Supervisor, Sender::Plant, Sender::Controller]
                    .into_iter()
                    .find(|s| ipc::control_service(*s) == name)
                    .expect("a sender of this control service");
                let s = ipc::control(&node, &run_id, from).expect("control");
                check_pubsub(
                    row,
                    s.static_config(),
                    name_of(&row.payload),
                    size_of::<ControlMsg>(),
                    fixed,
                );
            }
            "reference" => {
                let s = ipc::reference(&node, &run_id).expect("reference");
                let cfg = s.static_config();
                check_pubsub(
                    row,
                    cfg,
                    name_of(&row.payload),
                    size_of::<RefSample>(),
                    TypeVariant::Dynamic,
                );
                let stated = format!(
                    "`subscriber_max_borrowed_samples = {}`",
                    cfg.subscriber_max_borrowed_samples()
                );
                assert!(
                    doc.contains(&stated),
                    "docs/protocol.md must state {stated} for `reference`"
                );
            }
            event => {
                let s = ipc::wakeup(&node, &run_id, event).expect("event");
                let cfg = s.static_config();
                assert_eq!(row.payload, "—", "{event}: an event has no payload");
                assert_eq!(cfg.max_notifiers(), row.max_pub, "{event}: max notifiers");
                assert_eq!(cfg.max_listeners(), row.max_sub, "{event}: max listeners");
                assert_eq!(cfg.max_nodes(), row.max_nodes, "{event}: max nodes");
            }
        }
    }
    // The names the document gives are the names the code uses.
    let svc = ipc::service_name(&run_id, "state").expect("service name");
    assert_eq!(svc.to_string(), format!("deltaloop/{run_id}/state"));
    assert!(doc.contains("`deltaloop/<run id>/<service>`"));
    assert!(doc.contains("`deltaloop-<role>-<run id>`"));
    assert_eq!(
        node.name().to_string(),
        format!("deltaloop-wire-contract-{run_id}")
    );
    // Every service was this test's own: none outlives it.
    drop(node);
    let left = common::iceoryx_leftovers(&run_id);
    assert!(left.is_empty(), "iceoryx2 resources left behind: {left:?}");
}

/// The parser of `wire.rs` sees every field, doc comments and attributes aside, so a field added
/// to a wire type cannot slip past the comparison above.
#[test]
fn source_parser_sees_every_field() {
    let src = "/// A type.\n#[repr(C)]\npub struct T {\n    /// The tick.\n    pub tick: u64,\n    #[doc(hidden)]\n    pub q : [ f64 ; 3 ],\n    pub extra: u32,\n}\n\npub struct U {\n    pub other: u8,\n}\n";
    assert_eq!(
        source_fields(src, "T"),
        [
            ("tick".to_string(), "u64".to_string()),
            ("q".to_string(), "[f64;3]".to_string()),
            ("extra".to_string(), "u32".to_string()),
        ]
    );
    assert_eq!(type_size("[f64;3]") + type_size("[u8;160]"), 24 + 160);
}
