//! What the declaration of a config key holds ([`Key`]: name, type, unit, allowed values,
//! default, doc line), the range check and the one-line error it gives, and the key table of
//! docs/guide/scenario-files.md rendered from it. The keys themselves are in [`crate::keys`].

use crate::error::ConfigError;
use crate::text::{MAX_ECHO_CHARS, escape_cut, show_num};
use std::fmt;

/// One config key, declared once in [`crate::keys`].
#[derive(Clone, Copy, Debug)]
pub struct Key {
    /// The TOML table it is in (`plant`, `loop.<mode>`; empty at the top level).
    pub table: &'static str,
    /// Its name in that table (`tau_max_nm`).
    pub field: &'static str,
    /// Its Rust type in the schema (`f64`, `Option<u32>`, `Vec<Law>`).
    pub ty: &'static str,
    /// Its unit as errors write it (`s`, `us`, `N m`; empty: none).
    pub unit: &'static str,
    /// What values it may take.
    pub allowed: Allowed,
    /// What it is when the file leaves it out.
    pub default: KeyDefault,
    /// One line that says what it is.
    pub doc: &'static str,
}

/// What values a key may take.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Allowed {
    /// Within the bounds, said `lo <= field <= hi unit (note)`; checked by the key's `check`.
    Range { bounds: Bounds, note: &'static str },
    /// Within the bounds, said in these words; checked by the key's `check`.
    Span { bounds: Bounds, words: &'static str },
    /// One of these words (the serde enum refuses the others).
    Words(&'static str),
    /// A rule the section's validation checks in code, in words.
    Rule(&'static str),
    /// Any value of its type.
    Any,
}

/// `lo <= value <= hi`, or `lo < value` where the lower bound is open (no key's upper bound is).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bounds {
    pub lo: f64,
    pub lo_open: bool,
    pub hi: f64,
}

impl Bounds {
    /// Whether `v` is within.
    pub fn admits(self, v: f64) -> bool {
        let above = if self.lo_open {
            v > self.lo
        } else {
            v >= self.lo
        };
        above && v <= self.hi
    }

    /// As errors say it: `lo <= field <= hi`.
    fn said(self, field: &str) -> String {
        let op = if self.lo_open { "<" } else { "<=" };
        format!("{} {op} {field} <= {}", bound(self.lo), bound(self.hi))
    }
}

impl Allowed {
    /// `lo <= value <= hi`.
    pub const fn closed(lo: f64, hi: f64) -> Self {
        Allowed::Range {
            bounds: Bounds {
                lo,
                lo_open: false,
                hi,
            },
            note: "",
        }
    }

    /// `lo < value <= hi`.
    pub const fn left_open(lo: f64, hi: f64) -> Self {
        Allowed::Range {
            bounds: Bounds {
                lo,
                lo_open: true,
                hi,
            },
            note: "",
        }
    }

    /// `lo <= value <= hi`, said in `words`.
    pub const fn span(lo: f64, hi: f64, words: &'static str) -> Self {
        Allowed::Span {
            bounds: Bounds {
                lo,
                lo_open: false,
                hi,
            },
            words,
        }
    }

    /// A range with a note after its unit (`(24 h)`).
    pub const fn note(self, note: &'static str) -> Self {
        match self {
            Allowed::Range { bounds, .. } => Allowed::Range { bounds, note },
            other => other,
        }
    }

    /// Its numeric bounds, if it has any.
    pub fn bounds(self) -> Option<Bounds> {
        match self {
            Allowed::Range { bounds, .. } | Allowed::Span { bounds, .. } => Some(bounds),
            Allowed::Words(_) | Allowed::Rule(_) | Allowed::Any => None,
        }
    }
}

/// What a key is when the file leaves it out.
#[derive(Clone, Copy, Debug)]
pub enum KeyDefault {
    /// This value (the declared default as TOML; serde's default function returns it typed).
    Value(fn() -> toml::Value),
    /// Each loop mode's layout default ([`crate::Layout::realtime_default`],
    /// [`crate::Layout::lockstep_default`]).
    PerMode,
    /// Worked out when the file is read, in words (`the file's stem`, `required`).
    Said(&'static str),
}

/// A bound as errors write it: a whole number in full (`1000000`), anything else as
/// [`show_num`] does (`1e-5`, `0.1`).
fn bound(x: f64) -> String {
    if x.fract() == 0.0 && x.abs() < 1e15 {
        format!("{}", x as i64)
    } else {
        show_num(x)
    }
}

/// A [`ConfigError::Range`] for `key`; a long value is cut to [`MAX_ECHO_CHARS`] characters.
pub(crate) fn range(key: &str, value: impl fmt::Display, allowed: &str) -> ConfigError {
    let value = value.to_string();
    ConfigError::Range {
        key: key.into(),
        value: if value.chars().count() > MAX_ECHO_CHARS {
            escape_cut(&value, MAX_ECHO_CHARS, false)
        } else {
            value
        },
        allowed: allowed.into(),
    }
}

impl Key {
    /// Its TOML path: `plant.tau_max_nm`, `name`, `loop.<mode>.spin_us`.
    pub fn name(&self) -> String {
        if self.table.is_empty() {
            self.field.into()
        } else {
            format!("{}.{}", self.table, self.field)
        }
    }

    /// Whether `v` is within the declared bounds (always, for a key without numeric bounds).
    fn admits(&self, v: f64) -> bool {
        self.allowed.bounds().is_none_or(|b| b.admits(v))
    }

    /// What is allowed, as the error and the key table say it.
    pub fn allowed_text(&self) -> String {
        match self.allowed {
            Allowed::Range { bounds, note } => {
                let mut s = bounds.said(self.field);
                for part in [self.unit, note] {
                    if !part.is_empty() {
                        s.push(' ');
                        s.push_str(part);
                    }
                }
                s
            }
            Allowed::Span { words, .. } | Allowed::Words(words) | Allowed::Rule(words) => {
                words.into()
            }
            Allowed::Any => String::new(),
        }
    }

    /// A real number within the declared bounds, and finite; else the error naming the key, the
    /// value and what is allowed.
    pub(crate) fn check(&self, v: f64) -> Result<(), ConfigError> {
        if v.is_finite() && self.admits(v) {
            Ok(())
        } else {
            Err(range(&self.name(), show_num(v), &self.allowed_text()))
        }
    }

    /// A whole number within the declared bounds.
    pub(crate) fn check_int(&self, v: i64) -> Result<(), ConfigError> {
        self.check_int_as(&self.name(), v)
    }

    /// [`Key::check_int`] for the key in `table` (a `loop.<mode>` key in `loop.realtime`).
    pub(crate) fn check_int_in(&self, table: &str, v: i64) -> Result<(), ConfigError> {
        self.check_int_as(&format!("{table}.{}", self.field), v)
    }

    fn check_int_as(&self, name: &str, v: i64) -> Result<(), ConfigError> {
        // Every bounded integer key fits an f64 exactly (u32, i32, u16).
        if self.admits(v as f64) {
            Ok(())
        } else {
            Err(range(name, v, &self.allowed_text()))
        }
    }

    /// Its default as the key table writes it.
    pub fn default_text(&self) -> String {
        match self.default {
            KeyDefault::Value(v) => format!("`{}`", v()),
            KeyDefault::PerMode => {
                let of = |layout: crate::Layout| {
                    let t = toml::Value::try_from(layout).expect("a layout serialises");
                    t.get(self.field)
                        .map_or_else(|| "unset".into(), |v| format!("`{v}`"))
                };
                format!(
                    "realtime {}, lockstep {}",
                    of(crate::Layout::realtime_default()),
                    of(crate::Layout::lockstep_default())
                )
            }
            KeyDefault::Said(words) => words.into(),
        }
    }

    /// Its TOML type, as the key table writes it.
    pub fn toml_type(&self) -> &'static str {
        let inner = self
            .ty
            .strip_prefix("Option<")
            .and_then(|t| t.strip_suffix('>'))
            .unwrap_or(self.ty);
        match inner {
            "f64" => "number",
            "u16" | "u32" | "u64" | "i32" => "integer",
            "bool" => "boolean",
            "Vec<Segment>" => "array of tables",
            t if t.starts_with("Vec<") => "array of strings",
            _ => "string",
        }
    }

    /// Its row of the key table: key, type, unit, default, allowed, meaning.
    pub fn table_row(&self) -> String {
        let cell = |s: &str| s.replace('|', "\\|");
        let unit = match self.unit {
            "us" => "µs".to_string(),
            u => u.replace("^2", "²"),
        };
        let allowed = match self.allowed {
            Allowed::Any => "—".into(),
            _ => self.allowed_text(),
        };
        format!(
            "| `{}` | {} | {} | {} | {} | {} |",
            self.name(),
            self.toml_type(),
            cell(&unit),
            cell(&self.default_text()),
            cell(&allowed),
            cell(self.doc.trim()),
        )
    }
}

/// The header of the key table.
pub const TABLE_HEADER: &str =
    "| key | type | unit | default | allowed | meaning |\n|---|---|---|---|---|---|";

#[cfg(test)]
mod tests {
    use super::*;

    fn key(allowed: Allowed, unit: &'static str) -> Key {
        Key {
            table: "plant",
            field: "x",
            ty: "f64",
            unit,
            allowed,
            default: KeyDefault::Said("none"),
            doc: "A key.",
        }
    }

    #[test]
    fn a_range_is_said_as_errors_say_it() {
        let k = key(Allowed::closed(0.0, 86_400.0).note("(24 h)"), "s");
        assert_eq!(k.allowed_text(), "0 <= x <= 86400 s (24 h)");
        let k = key(Allowed::left_open(0.0, 1e4), "N m");
        assert_eq!(k.allowed_text(), "0 < x <= 10000 N m");
        let k = key(Allowed::closed(1e-5, 0.1), "");
        assert_eq!(k.allowed_text(), "1e-5 <= x <= 0.1");
        assert!(k.check(0.1).is_ok() && k.check(f64::NAN).is_err());
        assert_eq!(
            k.check(0.2).unwrap_err().to_string(),
            "config key `plant.x` = 0.2 is out of range: 1e-5 <= x <= 0.1"
        );
        assert_eq!(
            k.check_int_in("loop.realtime", 3).unwrap_err().to_string(),
            "config key `loop.realtime.x` = 3 is out of range: 1e-5 <= x <= 0.1"
        );
    }
}
