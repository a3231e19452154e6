//! The one error type of the crate: every message is one line that names the key, the value and
//! what is allowed.

/// A config problem, naming the key, the value and what is allowed. Every message is one line:
/// echoed text has its control and format characters escaped and is cut to
/// [`MAX_ECHO_CHARS`](crate::text::MAX_ECHO_CHARS) characters.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum ConfigError {
    /// The file could not be read (missing, not a regular file, too large, not UTF-8).
    #[error("cannot read config file {path}: {reason}")]
    Read { path: String, reason: String },

    /// The text is not valid TOML for this schema (unknown key, wrong type, syntax), and where
    /// (1-based line and column, in characters), if the parser said.
    #[error(
        "invalid config{}: {message}{}",
        path.as_deref().map(|p| format!(" {p}")).unwrap_or_default(),
        position.map(|(l, c)| format!(" at line {l}, column {c}")).unwrap_or_default()
    )]
    Parse {
        path: Option<String>,
        message: String,
        position: Option<(usize, usize)>,
    },

    /// A key has a value outside its allowed range.
    #[error("config key `{key}` = {value} is out of range: {allowed}")]
    Range {
        key: String,
        value: String,
        allowed: String,
    },
}
