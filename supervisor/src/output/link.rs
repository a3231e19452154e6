//! What the report says about a run whose controller was on another host.

use deltaloop_config::RunConfig;

/// For a run with `--controller-remote` (its controller command is `deltaloop-bridge near`): one
/// line naming the endpoint and the emulated link, and how to read the timing. None otherwise.
pub fn note(cfg: &RunConfig) -> Option<String> {
    let c = &cfg.controller.command;
    let bridge = c.first()?.ends_with("deltaloop-bridge") && c.get(1)? == "near";
    if !bridge {
        return None;
    }
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
        "controller on another host, across the link at {listen} (round trip = the link's round trip on the plant's clock; state → controller = the link both ways, compute = the far side's residence){}",
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
