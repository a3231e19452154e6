//! The controller's side of one tick, written once and called by every loop mode (inproc,
//! lockstep, realtime, the loop benchmark): state k and tick k's reference row in, the reply out.
//! Transport code only moves these messages and stamps times.

use deltaloop_config::{Compensation, DelaySource, Law, RunConfig};
use deltaloop_law::predict::reference_ahead;
use deltaloop_law::{
    Controller, Delay, DelayEstimate, InertiaEstimate, Measurement, Output, Predictor, Reference,
    Vec3,
};
use deltaloop_wire::{RefSample, StateMsg, TorqueMsg};

/// The controller side of the loop: one law with its state.
#[derive(Clone, Debug)]
pub struct ControllerSide {
    ctrl: Controller,
    /// d, the whole ticks of D₀ a compensated law reads the reference ahead by.
    lookahead: Option<u64>,
    /// The delay measured from the drives' reports (`controller.compensate_delay = "measured"`).
    measured: Option<DelayEstimate>,
}

impl ControllerSide {
    /// A fresh controller for `law` with the config's constants, period, TDE delay and velocity
    /// source. Every mode builds its controller here.
    pub fn from_config(cfg: &RunConfig, law: Law) -> Self {
        let params = cfg.controller_params();
        let ts = cfg.loop_.ts_s;
        let ctrl = Controller::new(law, params, ts, cfg.controller.tde_delay_samples as usize)
            .with_velocity(cfg.sensor.velocity);
        let base = Delay::from_ns(cfg.compensation_delay_ns(), cfg.ts_ns());
        let tau_max = cfg.plant.tau_max_nm;
        let measured = (cfg.controller.compensate == Compensation::Predict
            && cfg.controller.compensate_delay == DelaySource::Measured)
            .then(|| DelayEstimate::new(base, ts, tau_max));
        let ctrl = match cfg.controller.compensate {
            Compensation::None => ctrl,
            // D₀ (the delay the run injects, or the one it is told to assume), with room for
            // what may be measured past it; the drives' limit; an inertia learned from M̄ up.
            Compensation::Predict => {
                let p = Predictor::new(base, ts, tau_max, InertiaEstimate::for_m_bar(params.m_bar));
                ctrl.with_predictor(match &measured {
                    Some(m) => p.with_room_for(m.max()),
                    None => p,
                })
            }
        };
        Self {
            lookahead: ctrl.predictor().map(|_| base.whole as u64),
            ctrl,
            measured,
        }
    }

    /// d, the whole ticks of the delay a compensated law looks ahead by; None without
    /// compensation.
    pub fn lookahead(&self) -> Option<u64> {
        self.lookahead
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
        self.measure(state);
        let ts = self.ctrl.ts();
        let r = match (self.ctrl.predictor(), self.lookahead) {
            // What the delay in use adds past row j (a measured one may pass row j + 1); its
            // sub-tick part exactly when it has d whole ticks.
            (Some(p), Some(d)) => {
                let delay = p.delay();
                let past = (delay.whole as f64 - d as f64) * ts + delay.frac;
                reference_ahead(row, next, past, ts)
            }
            _ => *row,
        };
        self.step(state, &r)
    }

    /// The law this side runs.
    pub fn law(&self) -> Law {
        self.ctrl.law()
    }

    /// A compensated law's learned inertia M̂ per joint (kg m²); None without compensation.
    pub fn m_hat(&self) -> Option<Vec3> {
        self.ctrl.predictor().map(|p| p.inertia().m_hat())
    }

    /// Tick k: the state the plant published and tick k's reference → the reply to tick k
    /// (commanded τ_k and the law's internals; skip count and times left zero for the transport).
    pub fn answer(&mut self, state: &StateMsg, r: &Reference) -> TorqueMsg {
        self.measure(state);
        self.step(state, r)
    }

    /// With a measured delay: learns from the state's τᵃ and predicts over the new estimate.
    fn measure(&mut self, state: &StateMsg) {
        if let Some(m) = &mut self.measured {
            m.observe(state.tick, Vec3::from(state.tau_applied));
            self.ctrl.set_delay(m.delay());
        }
    }

    fn step(&mut self, state: &StateMsg, r: &Reference) -> TorqueMsg {
        let out = self.ctrl.step(&measurement(state), r);
        if let Some(m) = &mut self.measured {
            m.sent(state.tick, out.tau);
        }
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
