//! The limits of a scenario file's values and the rules its words follow, in words the errors
//! and the key table both use. Constants only: the declaration (`keys`) and the checks
//! (`validate`, `sections`) read them.

/// Largest accepted TDE delay ℓ (`controller.tde_delay_samples`), ticks. The controller keeps ℓ
/// past (acceleration, torque) pairs.
pub const MAX_TDE_DELAY: u32 = 10_000;

/// Largest accepted transport delay d (`plant.transport_delay_samples`), ticks. The plant's drives
/// keep d commands in flight. Separate from [`MAX_TDE_DELAY`]: the two delays are different
/// things (one in the controller's estimate, one on the wire) and share a value by coincidence.
pub const MAX_TRANSPORT_DELAY: u32 = 10_000;

/// Largest accepted `plant.transport_delay_us`, µs (1 s).
pub const MAX_TRANSPORT_DELAY_US: f64 = 1e6;

/// Largest accepted `plant.substeps`; the period bounds it further (RK4 step ≥ 1 µs).
pub const MAX_SUBSTEPS: u32 = 1000;

/// The longest hold, s: a day (a run streams, so only the disk bounds its length).
pub const MAX_HOLD_S: f64 = 86_400.0;

/// The most ticks a run may have, N = round((motion + hold)/Ts): 300 000 000, a day's hold and an
/// hour of motion at Ts = 0.3 ms (25 h in all; 50 min at the shortest period). Every
/// command that reads a config checks it in a few operations per segment, so a small file cannot
/// ask for billions of ticks that take hours to walk before anything starts.
pub const MAX_TICKS: u64 = 300_000_000;

/// What a scenario or sweep `name` may be: it names a folder under `runs/`.
pub const NAME_RULE: &str = "1 to 64 characters from A-Z a-z 0-9 . _ -, not starting with . or -";

/// What a process command may be (`plant.command`, `controller.command`).
pub(crate) const COMMAND_RULE: &str =
    "a program and its arguments, each a non-empty string of at most 4096 bytes without NUL";

/// What a label may be (`controller.label`).
pub(crate) const LABEL_RULE: &str = "at most 64 printable characters on one line";

/// Largest accepted emulated link delay or jitter (`link.delay_us`, `link.jitter_us`, the flags
/// `--link-delay-us`/`--link-jitter-us` and the sweep's `link_delay_us`/`link_jitter_us`), µs:
/// the one bound all of them check.
pub const MAX_LINK_DELAY_US: f64 = 1e6;

/// What a ROS name's tokens may hold: letters, digits and `_`, split by `/`, no token starting
/// with a digit, no empty token.
pub const ROS_NAME_RULE: &str =
    "ROS name tokens of A-Z a-z 0-9 _ split by /, none empty or starting with a digit";
