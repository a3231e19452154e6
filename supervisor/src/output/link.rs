//! What the report says about a run whose controller or plant was on another host.

pub use crate::timing::Across;
use deltaloop_config::RunConfig;

/// Which process of the run is on another host, from its config: the one whose command is
/// `deltaloop-bridge near`, which the supervisor put in its place (`--controller-remote`, a
/// sweep's link axis, `--plant-remote`). None for a one-host run.
pub fn across(cfg: &RunConfig) -> Option<Across> {
    let near = |c: &[String]| {
        c.first().is_some_and(|p| p.ends_with("deltaloop-bridge"))
            && c.get(1).is_some_and(|s| s == "near")
    };
    if near(&cfg.controller.command) {
        Some(Across::Controller)
    } else if near(&cfg.plant.command) {
        Some(Across::Plant)
    } else {
        None
    }
}

/// For a run split over two hosts: one line naming the endpoint and the emulated link, and how
/// to read the timing. None otherwise.
pub fn note(cfg: &RunConfig) -> Option<String> {
    let (c, how) = match across(cfg)? {
        Across::Controller => (
            &cfg.controller.command,
            "controller on another host, across the link at {} (round trip = the link's round trip on the plant's clock; state → controller = the link both ways, compute = the far side's residence, link round trip = round trip − compute)",
        ),
        Across::Plant => (
            &cfg.plant.command,
            "plant on another host, across the link at {} (round trip and wake-up = the plant's clock there; state → controller = from the state's arrival here, compute = the controller here, link round trip = round trip − (reply − the state's arrival here))",
        ),
    };
    let listen = c
        .iter()
        .position(|a| a == "--listen")
        .and_then(|i| c.get(i + 1))?;
    let flag = |name: &str| {
        c.iter()
            .find_map(|a| a.strip_prefix(&format!("--{name}=")))
            .unwrap_or("0")
            .to_string()
    };
    let emulated = ["link-delay-us", "link-jitter-us", "link-loss"]
        .iter()
        .any(|f| flag(f).parse::<f64>().is_ok_and(|v| v > 0.0));
    Some(format!(
        "{}{}",
        how.replace("{}", listen),
        if emulated {
            format!(
                "; emulated link: delay {} µs, jitter {} µs, loss {}, seed {} (each direction)",
                flag("link-delay-us"),
                flag("link-jitter-us"),
                flag("link-loss"),
                flag("link-seed")
            )
        } else {
            String::new()
        }
    ))
}
