//! Echoing user text in one-line errors: strings, paths, numbers and parser messages with their
//! control and format characters escaped and cut to a few dozen characters.

use std::path::Path;

/// Echoed user text (a value, a quoted part of a parser message) is cut to this many characters.
pub const MAX_ECHO_CHARS: usize = 60;

/// Longest parser message echoed, characters (the rest is cut with `…`).
const MAX_MESSAGE_CHARS: usize = 300;

/// Longest path echoed whole, characters (a longer one keeps its start and end).
const MAX_PATH_CHARS: usize = 160;

/// Pushes `c`, escaped as `{:?}` would when it is a control or format character (newline,
/// right-to-left mark, …), so that no echoed text breaks the line or reorders it. With `quoted`,
/// `"` and `\` are escaped too (the text is shown between our own quotes).
fn push_escaped(out: &mut String, c: char, quoted: bool) {
    let plain = matches!(c, '\'' | '"' | '\\') && !quoted;
    if plain || c == '\'' {
        out.push(c);
    } else {
        out.extend(c.escape_debug());
    }
}

/// `s` escaped (see [`push_escaped`]) and cut to `max` characters of the original with `…`.
pub(crate) fn escape_cut(s: &str, max: usize, quoted: bool) -> String {
    let mut out = String::new();
    for (i, c) in s.chars().enumerate() {
        if i == max {
            out.push('…');
            break;
        }
        push_escaped(&mut out, c, quoted);
    }
    out
}

/// A user string as echoed in errors: quoted, escaped like `{:?}` (control and format
/// characters visible), cut to [`MAX_ECHO_CHARS`] characters with `…`.
pub fn show_str(s: &str) -> String {
    format!("\"{}\"", escape_cut(s, MAX_ECHO_CHARS, true))
}

/// A path as echoed in errors: control and format characters escaped; a very long one keeps
/// its start and its end around `…`.
pub fn show_path(p: &Path) -> String {
    let s = p.to_string_lossy();
    let n = s.chars().count();
    if n <= MAX_PATH_CHARS {
        return escape_cut(&s, n, false);
    }
    let half = MAX_PATH_CHARS / 2;
    let tail: String = s.chars().skip(n - half).collect();
    format!(
        "{}{}",
        escape_cut(&s, half, false),
        escape_cut(&tail, half, false)
    )
}

/// A number as echoed in errors: plain between 1e-4 and 1e6, else in exponent form (`1e308`,
/// not 309 digits).
pub fn show_num(x: f64) -> String {
    if x != 0.0 && x.is_finite() && !(1e-4..1e6).contains(&x.abs()) {
        format!("{x:e}")
    } else {
        x.to_string()
    }
}

/// A parser message made safe to echo on one line: control and format characters escaped,
/// every quoted part (between backticks or double quotes, which is where the parser and serde
/// put the offending text) cut to [`MAX_ECHO_CHARS`], and the whole to a few hundred characters.
pub fn clean_message(msg: &str) -> String {
    let mut out = String::new();
    let mut chars = msg.trim_end().chars().peekable();
    while let Some(c) = chars.next() {
        if c == '`' || c == '"' {
            // A quoted part: up to the matching delimiter (a `"` part may escape it with `\`).
            let mut part = String::new();
            let mut closed = false;
            while let Some(d) = chars.next() {
                if d == c {
                    closed = true;
                    break;
                }
                part.push(d);
                if c == '"'
                    && d == '\\'
                    && let Some(e) = chars.next()
                {
                    part.push(e);
                }
            }
            out.push(c);
            out.push_str(&escape_cut(&part, MAX_ECHO_CHARS, false));
            if closed {
                out.push(c);
            }
        } else if c == '\n' {
            out.push_str("; ");
        } else {
            push_escaped(&mut out, c, false);
        }
    }
    if out.chars().count() > MAX_MESSAGE_CHARS {
        out = out.chars().take(MAX_MESSAGE_CHARS).collect();
        out.push('…');
    }
    out
}

/// Where a TOML error is: 1-based line and column (in characters) of the start of its span.
pub fn toml_error_position(text: &str, e: &toml::de::Error) -> Option<(usize, usize)> {
    let start = e.span()?.start.min(text.len());
    let before = text.as_bytes().get(..start)?;
    let line = before.iter().filter(|&&b| b == b'\n').count() + 1;
    let line_start = before
        .iter()
        .rposition(|&b| b == b'\n')
        .map_or(0, |i| i + 1);
    let column = String::from_utf8_lossy(&before[line_start..])
        .chars()
        .count()
        + 1;
    Some((line, column))
}

/// A TOML error on one line: the parser's message (cleaned, see [`clean_message`]) and where,
/// without the snippet of the offending line.
pub fn toml_error_line(text: &str, e: &toml::de::Error) -> String {
    let at = toml_error_position(text, e)
        .map(|(l, c)| format!(" at line {l}, column {c}"))
        .unwrap_or_default();
    format!("{}{at}", clean_message(e.message()))
}

#[cfg(test)]
mod tests {
    use crate::test_util::{MIN, err};

    #[test]
    fn regression_parse_error_is_one_line_with_line_and_column() {
        let e = err(&format!("{MIN}[plant]\nfrictoin = true\n"));
        assert!(
            e.starts_with(
                "invalid config configs/t.toml: unknown field `frictoin`, expected one of"
            ) && e.ends_with(" at line 4, column 1"),
            "{e}"
        );
        let e = err("[scenario]\npath = \"s1\"\nhold_s = = 2\n");
        assert!(e.ends_with("at line 3, column 10"), "{e}");
        assert!(!e.contains('|') && !e.contains('^'), "no snippet: {e}");
        // Columns count characters, not bytes.
        let e = err("description = \"ℓℓ\" x\n[scenario]\npath = \"s1\"\n");
        assert!(e.ends_with("at line 1, column 20"), "{e}");
        // A value echoed by the parser has its control characters escaped.
        let e = err("[scenario]\npath = \"s9\\nfoo\\u200f\"\n");
        assert!(e.contains(r"`s9\nfoo\u{200f}`"), "{e}");
    }

    #[test]
    fn regression_huge_values_are_echoed_compactly() {
        let e = err(&format!("{MIN}[controller]\nm_bar = 1e308\n"));
        assert_eq!(
            e,
            "config key `controller.m_bar` = 1e308 is out of range: 0 < m_bar <= 100 kg m^2"
        );
        let e = err(&format!("{MIN}[controller]\nkp = -1.5e-300\n"));
        assert!(e.contains("`controller.kp` = -1.5e-300 is"), "{e}");
        let e = err(&format!("{MIN}[controller]\nkp = 123456.5e10\n"));
        assert!(e.contains("= 1.234565e15 is"), "{e}");
        // Plain numbers stay plain.
        let e = err(&format!("{MIN}[controller]\nkp = -2.5\n"));
        assert!(e.contains("= -2.5 is"), "{e}");
        // A 200 KB string is cut, whatever echoes it.
        let long = "x".repeat(200_000);
        for text in [
            format!("[scenario]\npath = \"{long}\"\n"),
            format!("{MIN}[faults]\ninject = \"{long}\"\n"),
            format!("{MIN}[plant]\nsubsteps = \"{long}\"\n"),
            format!("{MIN}{long} = 1\n"),
            format!("name = \"{long}\"\n{MIN}"),
        ] {
            let e = err(&text);
            assert!(
                e.len() < 600 && e.contains('…'),
                "{} chars: {}",
                e.len(),
                &e[..200]
            );
        }
    }
}
