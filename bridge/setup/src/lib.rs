//! What the supervisor and the bridges share of a link, and nothing of its traffic: where it
//! meets ([`parse_endpoint`]) and what the far host runs ([`far_command`]), the pre-shared link key ([`LinkKey`]: made, written and read as a private file, carried in
//! [`KEY_ENV`] to a bridge and scrubbed from every other process), what a near bridge reports of
//! a run's link ([`LinkReport`]: who joined, with which key's fingerprint, what each side
//! refused), and the one way both open such files ([`files`]: never through a symbolic link,
//! created new and private, refused past a size). The handshake and the sealing that use the key
//! are the bridge's and `deltaloop-link`'s.

mod endpoint;
mod far;
pub mod files;
mod key;
mod report;

pub use endpoint::parse_endpoint;
pub use far::{far_command, far_program};
pub use key::{KEY_ENV, KEY_LEN, LinkKey, SECRET_ENV, random_bytes, scrub_secrets};
pub use report::{LinkReport, RefusedCounts, SideRefusals};
