//! The link key of this process's runs across a link (`--controller-remote`, `--plant-remote`, a
//! sweep's loopback): held here and handed to each bridge it starts, in its environment only.

use anyhow::Result;
use deltaloop_link_setup::{KEY_ENV, LinkKey};
use std::path::Path;
use std::process::Command;
use std::sync::OnceLock;

/// The link key of this process's runs across a link: handed to every near bridge it starts (in
/// its environment, never in a file of the run), and to the far bridges of a sweep's loopback.
static LINK_KEY: OnceLock<LinkKey> = OnceLock::new();

/// This process's link key, if a remote run set one.
pub fn link_key() -> Option<&'static LinkKey> {
    LINK_KEY.get()
}

/// This process's link key: `key` if none was set yet (the first one set stays).
pub fn install_link_key(key: LinkKey) -> &'static LinkKey {
    let _ = LINK_KEY.set(key);
    LINK_KEY.get().unwrap_or_else(|| unreachable!("just set"))
}

/// This process's link key, a one-time one made now if none was set (a sweep's loopback).
pub fn one_time_link_key() -> Result<&'static LinkKey> {
    match LINK_KEY.get() {
        Some(k) => Ok(k),
        None => Ok(install_link_key(
            LinkKey::generate().map_err(anyhow::Error::msg)?,
        )),
    }
}

/// Gives `cmd` this process's link key if it starts a bridge (`near`/`far`), and never any
/// other program: a key in this process's own environment is not passed on.
pub fn hand_key(cmd: &mut Command, program: &Path, first_arg: Option<&str>) {
    deltaloop_link_setup::scrub_secrets(cmd);
    let bridge = program.file_name().is_some_and(|n| n == "deltaloop-bridge");
    if bridge
        && matches!(first_arg, Some("near" | "far"))
        && let Some(k) = link_key()
    {
        cmd.env(KEY_ENV, k.to_hex());
    }
}
