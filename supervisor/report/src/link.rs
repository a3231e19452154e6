//! What the report says about a run whose controller or plant was on another host.

use deltaloop_config::{RemoteSide, RunConfig};

/// Which process of the run is on another host: the config's `[link] remote`, which
/// `--controller-remote`, `--plant-remote` and a sweep's link axis set. None for a one-host run.
pub fn across(cfg: &RunConfig) -> Option<RemoteSide> {
    cfg.link.as_ref().map(|l| l.remote)
}

/// For a run split over two hosts: one line naming the endpoint and the emulated link, and how
/// to read the timing. None otherwise.
pub fn note(cfg: &RunConfig) -> Option<String> {
    let link = cfg.link.as_ref()?;
    let how = match link.remote {
        RemoteSide::Controller => {
            "controller on another host, across the link at {} (round trip = the link's round trip on the plant's clock; state → controller = the link both ways, compute = the far side's residence, link round trip = round trip − compute)"
        }
        RemoteSide::Plant => {
            "plant on another host, across the link at {} (round trip and wake-up = the plant's clock there; state → controller = from the state's arrival here, compute = the controller here, link round trip = round trip − (reply − the state's arrival here))"
        }
    };
    let emulated = if link.emulated() {
        format!(
            "; emulated link: delay {} µs, jitter {} µs, loss {}, seed {} (each direction)",
            link.delay_us, link.jitter_us, link.loss, link.seed
        )
    } else {
        String::new()
    };
    Some(format!("{}{emulated}", how.replace("{}", &link.listen)))
}
