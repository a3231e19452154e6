//! The run as the near side announces it in its HELLO frame (`Kind::Hello`).

use deltaloop_config::{Law, LoopMode};

/// The run as the near side announces it: run id, mode, law, the emulated link, and the resolved
/// config's text. Encoded as `key=value` lines, then an empty line, then the config.
#[derive(Clone, Debug, PartialEq)]
pub struct Hello {
    pub run_id: String,
    /// What runs on the far host.
    pub role: deltaloop_config::RemoteSide,
    /// Lockstep or realtime (never inproc: it has no processes).
    pub mode: LoopMode,
    /// The controller's law (None: the far side runs the plant, which takes none).
    pub law: Option<Law>,
    pub emulation: crate::emulation::Emulation,
    pub config: String,
}

impl Hello {
    pub fn encode(&self) -> Vec<u8> {
        let e = &self.emulation;
        format!(
            "run_id={}\nrole={}\nmode={}\nlaw={}\ndelay_ns={}\njitter_ns={}\nloss_ppm={}\nseed={}\n\n{}",
            self.run_id,
            self.role,
            self.mode.name(),
            self.law.map_or("none", Law::name),
            e.delay_ns,
            e.jitter_ns,
            e.loss_ppm,
            e.seed,
            self.config
        )
        .into_bytes()
    }

    /// Decodes a HELLO; one line naming what is wrong otherwise.
    pub fn decode(b: &[u8]) -> Result<Self, String> {
        let text = std::str::from_utf8(b).map_err(|_| "HELLO is not UTF-8".to_string())?;
        let (head, config) = text.split_once("\n\n").ok_or("HELLO has no config part")?;
        let mut h = Hello {
            run_id: String::new(),
            // A HELLO without a role is of a version that knew only the remote controller.
            role: deltaloop_config::RemoteSide::Controller,
            mode: LoopMode::Lockstep,
            law: None,
            emulation: Default::default(),
            config: config.to_string(),
        };
        for line in head.lines() {
            let (k, v) = line
                .split_once('=')
                .ok_or_else(|| format!("HELLO line without `=`: {}", escape(line)))?;
            let num = || {
                v.parse::<u64>()
                    .map_err(|_| format!("HELLO {k} = {}: not a whole number", escape(v)))
            };
            match k {
                "run_id" => h.run_id = v.to_string(),
                "role" => {
                    h.role = deltaloop_config::RemoteSide::parse(v)
                        .map_err(|e| format!("HELLO role: {}", escape(&e)))?
                }
                "mode" => {
                    h.mode = LoopMode::parse_process(v)
                        .map_err(|e| format!("HELLO mode: {}", escape(&e)))?
                }
                "law" if v == "none" => h.law = None,
                "law" => {
                    h.law = Some(Law::parse(v).map_err(|e| format!("HELLO law: {}", escape(&e)))?)
                }
                "delay_ns" => h.emulation.delay_ns = bounded(k, num()?, MAX_EMULATED_NS)?,
                "jitter_ns" => h.emulation.jitter_ns = bounded(k, num()?, MAX_EMULATED_NS)?,
                "loss_ppm" => h.emulation.loss_ppm = bounded(k, num()?, 1_000_000)? as u32,
                "seed" => h.emulation.seed = num()?,
                _ => {}
            }
        }
        let safe = |s: &str| {
            !s.is_empty()
                && s.len() <= 128
                && s.bytes()
                    .all(|c| c.is_ascii_alphanumeric() || c == b'-' || c == b'_')
        };
        if !safe(&h.run_id) {
            return Err(format!(
                "HELLO run_id = `{}`: expected 1-128 of A-Z a-z 0-9 - _",
                escape(&h.run_id)
            ));
        }
        if !head.lines().any(|l| l.starts_with("mode=")) {
            return Err("HELLO has no mode".into());
        }
        if (h.role == deltaloop_config::RemoteSide::Controller) != h.law.is_some() {
            return Err(format!(
                "HELLO law = {}: a remote controller needs a law, a remote plant takes none",
                h.law.map_or("none", Law::name)
            ));
        }
        Ok(h)
    }
}

/// The largest emulated delay or jitter a HELLO may ask for, ns: what `--link-delay-us` and
/// `--link-jitter-us` allow (10⁶ µs).
pub const MAX_EMULATED_NS: u64 = 1_000_000_000;

/// `v` if it is at most `max`, else one line naming the HELLO field.
fn bounded(k: &str, v: u64, max: u64) -> Result<u64, String> {
    if v <= max {
        Ok(v)
    } else {
        Err(format!("HELLO {k} = {v}: allowed 0..={max}"))
    }
}

fn escape(s: &str) -> String {
    let s: String = s.chars().take(80).collect();
    deltaloop_transport::wire::escape_peer_text(&s)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Regression: a HELLO with jitter_ns = 2⁶⁴ − 1 made the far bridge panic on its first
    /// datagram (a remainder by jitter + 1 = 0). The emulation is bounded like its flags.
    #[test]
    fn regression_a_hello_with_jitter_2_64_minus_1_is_refused_not_a_panic() {
        let text = format!(
            "run_id=r\nmode=lockstep\nlaw=tdc\njitter_ns={}\n\nx",
            u64::MAX
        );
        let e = Hello::decode(text.as_bytes()).unwrap_err();
        assert!(
            e.contains("jitter_ns") && e.contains("allowed 0..=1000000000"),
            "{e}"
        );
        let text = "run_id=r\nmode=lockstep\nlaw=tdc\nloss_ppm=1000001\n\nx";
        assert!(
            Hello::decode(text.as_bytes())
                .unwrap_err()
                .contains("loss_ppm")
        );
        let ok = format!("run_id=r\nmode=lockstep\nlaw=tdc\njitter_ns={MAX_EMULATED_NS}\n\nx");
        assert_eq!(
            Hello::decode(ok.as_bytes()).unwrap().emulation.jitter_ns,
            MAX_EMULATED_NS
        );
    }

    #[test]
    fn hello_round_trips_and_refuses_odd_names() {
        let h = Hello {
            run_id: "41cc-0-2cdf".into(),
            role: deltaloop_config::RemoteSide::Plant,
            mode: LoopMode::Lockstep,
            law: None,
            emulation: crate::emulation::Emulation {
                delay_ns: 5,
                jitter_ns: 6,
                loss_ppm: 7,
                seed: 8,
            },
            config: "name = \"x\"\n\n[loop]\n".into(),
        };
        assert_eq!(Hello::decode(&h.encode()), Ok(h.clone()));
        let bad = Hello {
            run_id: "../../etc".into(),
            ..h
        };
        let e = Hello::decode(&bad.encode()).unwrap_err();
        assert!(e.contains("run_id") && e.contains("../../etc"), "{e}");
        // A HELLO without a role (the remote controller's first version) puts the controller
        // on the far host.
        let old = "run_id=r\nmode=lockstep\nlaw=tdc\n\nname = \"x\"\n";
        assert_eq!(
            Hello::decode(old.as_bytes()).unwrap().role,
            deltaloop_config::RemoteSide::Controller
        );
    }
}
