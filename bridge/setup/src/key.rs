//! The link's pre-shared key: made, written and read as a private file, carried to a bridge in
//! its environment and scrubbed from every other process's.

use std::path::Path;

/// Bytes of a link key (and of every session key the handshake derives from it).
pub const KEY_LEN: usize = 32;

/// Random bytes from the operating system.
pub fn random_bytes<const N: usize>() -> Result<[u8; N], String> {
    let mut b = [0u8; N];
    getrandom::fill(&mut b).map_err(|e| format!("no random bytes from the system: {e}"))?;
    Ok(b)
}

/// The pre-shared key of a link: 32 random bytes. A key file holds them as 64 hex digits and a
/// newline, readable by its owner only.
#[derive(Clone, PartialEq, Eq)]
pub struct LinkKey([u8; KEY_LEN]);

impl std::fmt::Debug for LinkKey {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "LinkKey({})", self.fingerprint())
    }
}

impl LinkKey {
    /// The key's bytes: the pre-shared key of the handshake.
    pub fn bytes(&self) -> &[u8; KEY_LEN] {
        &self.0
    }

    /// A fresh random key.
    pub fn generate() -> Result<Self, String> {
        random_bytes().map(Self)
    }

    /// The key of 64 hex digits (surrounding whitespace ignored); one line naming what is wrong.
    pub fn from_hex(text: &str) -> Result<Self, String> {
        let t = text.trim();
        if t.len() != 2 * KEY_LEN || !t.bytes().all(|c| c.is_ascii_hexdigit()) {
            return Err(format!(
                "a link key is {} hex digits (0-9, a-f); this is {} characters",
                2 * KEY_LEN,
                t.chars().count()
            ));
        }
        let mut k = [0u8; KEY_LEN];
        for (i, b) in k.iter_mut().enumerate() {
            *b = u8::from_str_radix(&t[2 * i..2 * i + 2], 16).map_err(|e| e.to_string())?;
        }
        Ok(Self(k))
    }

    /// The key as 64 lower-case hex digits (for a key file, or a `join --link-token`).
    pub fn to_hex(&self) -> String {
        self.0.iter().map(|b| format!("{b:02x}")).collect()
    }

    /// A name for the key that does not reveal it: `sha256:` and the first 16 hex digits of the
    /// SHA-256 of a label and the key. Both sides of a link print the same.
    pub fn fingerprint(&self) -> String {
        use sha2::{Digest, Sha256};
        let d = Sha256::new()
            .chain_update(b"deltaloop link key fingerprint\0")
            .chain_update(self.0)
            .finalize();
        let hex: String = d[..8].iter().map(|b| format!("{b:02x}")).collect();
        format!("sha256:{hex}")
    }

    /// Reads a key file: a regular file (not a link), owned by this user (or root), readable
    /// and writable by its owner only (as ssh wants a private key), holding the key's 64 hex
    /// digits. One line naming the file and what is wrong otherwise.
    pub fn read(path: &Path) -> Result<Self, String> {
        use std::os::unix::fs::{MetadataExt, PermissionsExt};
        let shown = path.display();
        let meta = std::fs::symlink_metadata(path)
            .map_err(|e| format!("cannot read link key {shown}: {e}"))?;
        if meta.file_type().is_symlink() {
            return Err(format!(
                "link key {shown} is a symbolic link: give the key file itself"
            ));
        }
        if !meta.is_file() {
            return Err(format!("link key {shown} is not a regular file"));
        }
        // SAFETY: geteuid has no preconditions.
        let me = unsafe { libc::geteuid() };
        if !owner_may_hold_key(meta.uid(), me) {
            return Err(format!(
                "link key {shown} is owned by uid {}: a key file must be owned by you (uid {me}) or root, mode 600",
                meta.uid()
            ));
        }
        let mode = meta.permissions().mode() & 0o777;
        if mode & 0o077 != 0 {
            return Err(format!(
                "link key {shown} is readable or writable by group or others (mode {mode:03o}): only its owner may read it, chmod 600 {shown}"
            ));
        }
        if meta.len() > 256 {
            return Err(format!(
                "link key {shown} has {} bytes: a key file is 64 hex digits",
                meta.len()
            ));
        }
        let text = crate::files::read_no_follow(path)
            .map_err(|e| format!("cannot read link key {shown}: {e}"))?;
        let text = String::from_utf8(text)
            .map_err(|_| format!("link key {shown} is not text: a key file is 64 hex digits"))?;
        Self::from_hex(&text).map_err(|e| format!("link key {shown}: {e}"))
    }

    /// Writes a fresh key to a new file at `path` (mode 600; an existing file or link is never
    /// overwritten). Returns it.
    pub fn write_new(path: &Path) -> Result<Self, String> {
        let key = Self::generate()?;
        crate::files::create_private(path, format!("{}\n", key.to_hex()).as_bytes())
            .map_err(|e| format!("cannot write link key {}: {e}", path.display()))?;
        Ok(key)
    }
}

/// Whether a key file owned by `owner` may be used by user `me`: their own file, or root's
/// (another user could have written the key it holds, or read it).
fn owner_may_hold_key(owner: u32, me: u32) -> bool {
    owner == me || owner == 0
}

/// The environment variable that carries the link key (64 hex digits) to a bridge: set by
/// `deltaloop run` for its near bridge and by `deltaloop join` for its far one, never written to
/// a run's files.
pub const KEY_ENV: &str = "DELTALOOP_LINK_KEY";

/// Every secret a bridge may hold in its environment: removed from the environment of every
/// process a bridge or the supervisor starts that is not a bridge ([`scrub_secrets`]).
pub const SECRET_ENV: &[&str] = &[KEY_ENV];

/// Removes [`SECRET_ENV`] from what `cmd` inherits: the link authenticates the two hosts, and
/// the processes they start (a controller or plant, maybe third-party code) get no key.
pub fn scrub_secrets(cmd: &mut std::process::Command) {
    for v in SECRET_ENV {
        cmd.env_remove(v);
    }
}

impl LinkKey {
    /// The key in [`KEY_ENV`]; one line if it is missing or malformed.
    pub fn from_env() -> Result<Self, String> {
        let v = std::env::var(KEY_ENV).map_err(|_| {
            format!(
                "no link key: {KEY_ENV} is not set (`deltaloop run … --controller-remote/--plant-remote` and `deltaloop join` set it from --link-key or --link-token)"
            )
        })?;
        Self::from_hex(&v).map_err(|e| format!("{KEY_ENV}: {e}"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_round_trip_as_hex_and_odd_text_is_refused() {
        let k = LinkKey::generate().unwrap();
        assert_eq!(
            LinkKey::from_hex(&format!("  {}\n", k.to_hex())),
            Ok(k.clone())
        );
        assert!(
            LinkKey::from_hex("abc")
                .unwrap_err()
                .contains("64 hex digits")
        );
        assert!(LinkKey::from_hex(&"zz".repeat(32)).is_err());
        assert_eq!(k.fingerprint().len(), "sha256:".len() + 16);
        assert_ne!(k.fingerprint(), LinkKey::generate().unwrap().fingerprint());
        assert!(
            !format!("{k:?}").contains(&k.to_hex()),
            "Debug never shows the key"
        );
    }

    #[test]
    fn key_files_must_be_private_regular_files_of_one_key() {
        use std::os::unix::fs::PermissionsExt;
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("link.key");
        let k = LinkKey::write_new(&p).unwrap();
        assert_eq!(
            std::fs::metadata(&p).unwrap().permissions().mode() & 0o777,
            0o600
        );
        assert_eq!(LinkKey::read(&p), Ok(k));
        assert!(
            LinkKey::write_new(&p).unwrap_err().contains("exists"),
            "never overwritten"
        );
        std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o644)).unwrap();
        assert!(LinkKey::read(&p).unwrap_err().contains("chmod 600"));
        std::fs::set_permissions(&p, std::fs::Permissions::from_mode(0o600)).unwrap();
        let l = d.path().join("link");
        std::os::unix::fs::symlink(&p, &l).unwrap();
        assert!(LinkKey::read(&l).unwrap_err().contains("symbolic link"));
        let short = d.path().join("short.key");
        crate::files::create_private(&short, b"abcd\n").unwrap();
        assert!(LinkKey::read(&short).unwrap_err().contains("64 hex digits"));
    }

    /// Regression: a key file owned by another user was accepted (ssh refuses such a private
    /// key: its owner could have chosen the key, or read it). Refused in one line naming the
    /// file and what is allowed; what `link-key` writes (mode 600, ours) stays accepted, and so
    /// does a key file of root's.
    #[test]
    fn regression_a_link_key_file_owned_by_another_user_is_refused() {
        use std::os::unix::fs::PermissionsExt;
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("link.key");
        let k = LinkKey::write_new(&p).unwrap();
        assert_eq!(
            std::fs::metadata(&p).unwrap().permissions().mode() & 0o777,
            0o600
        );
        assert_eq!(LinkKey::read(&p), Ok(k), "what link-key writes is accepted");
        assert!(owner_may_hold_key(1000, 1000) && owner_may_hold_key(0, 1000));
        assert!(!owner_may_hold_key(1001, 1000) && !owner_may_hold_key(1000, 0));
        // SAFETY: geteuid has no preconditions.
        let me = unsafe { libc::geteuid() };
        let other = if me == 0 { 4242 } else { 0 };
        if me != 0 {
            // Only root can give a file away; the rule itself is checked above.
            eprintln!("SKIPPED the chown half: needs root to make a file of another user");
            return;
        }
        std::os::unix::fs::chown(&p, Some(other), None).unwrap();
        let e = LinkKey::read(&p).unwrap_err();
        assert!(
            e.contains(&p.display().to_string())
                && e.contains(&format!("owned by uid {other}"))
                && e.contains("owned by you (uid 0) or root")
                && !e.contains('\n'),
            "{e}"
        );
        // Group- or other-readable and -writable stay refused.
        std::os::unix::fs::chown(&p, Some(me), None).unwrap();
        for mode in [0o640, 0o620, 0o604, 0o602] {
            std::fs::set_permissions(&p, std::fs::Permissions::from_mode(mode)).unwrap();
            assert!(
                LinkKey::read(&p).unwrap_err().contains("chmod 600"),
                "{mode:o}"
            );
        }
    }
}
