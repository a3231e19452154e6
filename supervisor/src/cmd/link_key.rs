//! `deltaloop link-key FILE`: a fresh random key for a link between two hosts.

use super::Context;
use anyhow::Result;
use deltaloop_link_setup::LinkKey;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The new key file (mode 600; an existing file is never overwritten). Copy it to the other
    /// host by a channel you trust (scp, a config manager); `run … --link-key FILE` on the
    /// supervisor's host and `join … --link-key FILE` on the other use it.
    file: PathBuf,
}

pub fn exec(a: Args, _cx: &Context) -> Result<()> {
    let key = LinkKey::write_new(&a.file).map_err(anyhow::Error::msg)?;
    println!(
        "wrote a new link key to {} (mode 600), fingerprint {}",
        a.file.display(),
        key.fingerprint()
    );
    Ok(())
}
