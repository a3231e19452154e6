//! The controller's side of one tick, written once and called by every loop mode (inproc,
//! lockstep, realtime, the loop benchmark): state k and tick k's reference row in, the reply out.
//! Transport code only moves these messages and stamps times.

use deltaloop_config::{Compensation, Law, RunConfig};
use deltaloop_law::predict::reference_ahead;
use deltaloop_law::{
    Controller, Delay, InertiaEstimate, Measurement, Output, Predictor, Reference, Vec3,
};
use deltaloop_wire::{RefSample, StateMsg, TorqueMsg};

/// The controller side of the loop: one law with its state.
#[derive(Clone, Debug)]
pub struct ControllerSide {
    ctrl: Controller,
}

impl ControllerSide {
    /// A fresh controller for `law` with the config's constants, period, TDE delay and velocity
    /// source. Every mode builds its controller here.
    pub fn from_config(cfg: &RunConfig, law: Law) -> Self {
        let params = cfg.controller_params();
        let ts = cfg.loop_.ts_s;
        let ctrl = Controller::new(law, params, ts, cfg.controller.tde_delay_samples as usize)
            .with_velocity(cfg.sensor.velocity);
        Self {
            ctrl: match cfg.controller.compensate {
                Compensation::None => ctrl,
                // The delay the run injects; the drives' limit; an inertia learned from M̄ up.
                Compensation::Predict => ctrl.with_predictor(Predictor::new(
                    Delay::from_ns(cfg.transport_delay_ns(), cfg.ts_ns()),
                    ts,
                    cfg.plant.tau_max_nm,
                    InertiaEstimate::for_m_bar(params.m_bar),
                )),
            },
        }
    }

    /// d, the whole ticks of the delay a compensated law looks ahead by; None without
    /// compensation.
    pub fn lookahead(&self) -> Option<u64> {
        self.ctrl.predictor().map(|p| p.delay().whole as u64)
    }

    /// Tick k of a compensated law with the reference rows j = k + d (`row`) and j + 1 (`next`,
    /// read only for a sub-tick delay), d its [`lookahead`](Self::lookahead). Without
    /// compensation, [`answer`](Self::answer) with `row`.
    pub fn answer_ahead(
        &mut self,
        state: &StateMsg,
        row: &Reference,
        next: &Reference,
    ) -> TorqueMsg {
        let r = match self.ctrl.predictor() {
            Some(p) => reference_ahead(row, next, p.delay().frac, self.ctrl.ts()),
            None => *row,
        };
        self.answer(state, &r)
    }

    /// The law this side runs.
    pub fn law(&self) -> Law {
        self.ctrl.law()
    }

    /// Tick k: the state the plant published and tick k's reference → the reply to tick k
    /// (commanded τ_k and the law's internals; skip count and times left zero for the transport).
    pub fn answer(&mut self, state: &StateMsg, r: &Reference) -> TorqueMsg {
        let out = self.ctrl.step(&measurement(state), r);
        reply(state.tick, &out)
    }
}

/// What the controller measures, read off a state message: joint data and applied torque only.
pub fn measurement(s: &StateMsg) -> Measurement {
    Measurement {
        q: Vec3::from(s.q),
        qd: Vec3::from(s.qd),
        tau_applied: Vec3::from(s.tau_applied),
    }
}

/// A reference row as it arrives over the wire.
pub fn reference(r: &RefSample) -> Reference {
    Reference {
        q: Vec3::from(r.q),
        qd: Vec3::from(r.qd),
        qdd: Vec3::from(r.qdd),
    }
}

/// The reply to tick `tick`: the torque and the law's internals.
fn reply(tick: u64, out: &Output) -> TorqueMsg {
    TorqueMsg {
        tick,
        tau: out.tau.into(),
        s: out.s.into(),
        n_hat: out.n_hat.into(),
        u: out.u.into(),
        ..TorqueMsg::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The side answers exactly what the law computes from the same measurement.
    #[test]
    fn answer_is_the_law_step_on_the_state() {
        let cfg = RunConfig::from_toml_str("name = \"t\"\n[scenario]\npath = \"s1\"\n", None)
            .expect("config");
        let mut side = ControllerSide::from_config(&cfg, Law::TdcIsSta);
        let mut law = Controller::new(Law::TdcIsSta, cfg.controller_params(), 3e-4, 1);
        let state = StateMsg {
            tick: 5,
            q: [0.1, 0.2, 0.3],
            qd: [0.01, -0.02, 0.0],
            tau_applied: [1.0, 1.5, 2.0],
            ..StateMsg::default()
        };
        let r = Reference {
            q: Vec3::new(0.1001, 0.2, 0.3),
            ..Reference::default()
        };
        let msg = side.answer(&state, &r);
        let out = law.step(&measurement(&state), &r);
        assert_eq!(msg.tick, 5);
        assert_eq!(msg.tau, <[f64; 3]>::from(out.tau));
        assert_eq!(msg.s, <[f64; 3]>::from(out.s));
        assert_eq!(msg.n_hat, <[f64; 3]>::from(out.n_hat));
        assert_eq!(msg.u, <[f64; 3]>::from(out.u));
        assert_eq!((msg.skipped, msg.t_publish_ns), (0, 0));
    }
}
