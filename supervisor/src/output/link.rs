//! What the report says about a run whose controller was on another host.

use deltaloop_config::RunConfig;

/// Whether the run's controller is across the link (`--controller-remote`, or a sweep's link
/// axis): its controller command is `deltaloop-bridge near`, which the supervisor put in the
/// controller's place. Its replies carry the far residence (docs/protocol.md §14), so the run
/// measures the link's round trip (`link_rtt`).
pub fn is_remote(cfg: &RunConfig) -> bool {
    let c = &cfg.controller.command;
    c.first().is_some_and(|p| p.ends_with("deltaloop-bridge"))
        && c.get(1).is_some_and(|a| a == "near")
}

/// For a run with `--controller-remote` (its controller command is `deltaloop-bridge near`): one
/// line naming the endpoint and the emulated link, and how to read the timing. None otherwise.
pub fn note(cfg: &RunConfig) -> Option<String> {
    if !is_remote(cfg) {
        return None;
    }
    let c = &cfg.controller.command;
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
        "controller on another host, across the link at {listen} (round trip = the link's round trip on the plant's clock; state → controller = the link both ways, compute = the far side's residence, link round trip = round trip − compute){}",
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
