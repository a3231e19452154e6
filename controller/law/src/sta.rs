//! The super-twisting term of the sliding-mode laws, per joint, in two discretisations of the same
//! continuous law u = k1·√|s|·sgn(s) + v, v̇ = k2·sgn(s) (docs/controllers.md, "Super-twisting:
//! explicit and implicit"). Both return (u_k, v_{k+1}) from (s_k, v_k); pure functions.
//!
//! Units: s in rad/s, u and v in rad/s², k1 in rad^½/s^(3/2), k2 in rad/s³, Ts in s.

use crate::sgn;

/// The paper's explicit (forward-Euler) step: u_k = k1·√|s_k|·sgn(s_k) + v_k,
/// v_{k+1} = v_k + Ts·k2·sgn(s_k). Not Lipschitz at s = 0: a round-off-sized change of s_k across
/// 0 flips both terms.
#[inline]
pub fn explicit(s: f64, v: f64, k1: f64, k2: f64, ts: f64) -> (f64, f64) {
    (k1 * s.abs().sqrt() * sgn(s) + v, v + ts * k2 * sgn(s))
}

/// The implicit (backward-Euler) step on the nominal sliding dynamics ṡ = −u that the TDC core
/// gives: u_k is the solution of
///
/// s_{k+1} = s_k − Ts·u_k,  u_k = k1·√|s_{k+1}|·Sgn(s_{k+1}) + v_{k+1},
/// v_{k+1} = v_k + Ts·k2·Sgn(s_{k+1}),
///
/// with Sgn set-valued at 0 (Sgn(0) = [−1, 1]). With w = s_k − Ts·v_k and the band b = Ts²·k2:
/// - |w| ≤ b: s_{k+1} = 0 and Sgn takes σ = w/b, so u_k = v_{k+1} = s_k/Ts;
/// - |w| > b: s_{k+1} = sgn(w)·x² with x > 0 the root of x² + Ts·k1·x − (|w| − b) = 0,
///   u_k = (s_k − s_{k+1})/Ts, v_{k+1} = v_k + Ts·k2·sgn(w).
///
/// u_k and v_{k+1} are continuous in s_k, with slope at most 1/Ts: a round-off change of s_k
/// moves them by round-off / Ts, never by a sign flip.
#[inline]
pub fn implicit(s: f64, v: f64, k1: f64, k2: f64, ts: f64) -> (f64, f64) {
    let w = s - ts * v;
    let band = ts * ts * k2;
    if w.abs() <= band {
        // Inside the band (band > 0 unless k2 = 0, and then w = 0 here): the set-valued sign.
        let sigma = if band > 0.0 { w / band } else { 0.0 };
        (s / ts, v + ts * k2 * sigma)
    } else {
        let a = ts * k1;
        let d = w.abs() - band;
        // x = (−a + √(a² + 4d))/2, written without the cancellation of −a + √(…) for small d.
        let x = 2.0 * d / (a + (a * a + 4.0 * d).sqrt());
        let s_next = w.signum() * x * x;
        ((s - s_next) / ts, v + ts * k2 * w.signum())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const TS: f64 = 3e-4;
    const K1: f64 = 700.0;
    const K2: f64 = 100.0;

    /// The hand-checked vectors of docs/controllers.md ("Super-twisting: explicit and implicit"),
    /// Ts = 0.3 ms, k1 = 700, k2 = 100: (s_k, v_k) → (u_k, v_{k+1}).
    #[test]
    fn implicit_step_matches_the_documented_vectors() {
        let cases = [
            // Outside the band: w = 0.00985, x = 0.03945068…, s_{k+1} = 0.00155636…; the
            // explicit step would give u = 70.5 and overshoot s past 0 (s − Ts·u = −0.0112).
            (0.01, 0.5, 28.145478538154583, 0.53),
            // Negative side, mirror image of the first.
            (-0.01, -0.5, -28.145478538154583, -0.53),
            // Far from the surface: w = 0.3006, s_{k+1} = 0.20541359….
            (0.3, -2.0, 315.28803254699704, -1.97),
            // Inside the band |w| ≤ Ts²·k2 = 9e-6: s_{k+1} = 0, u = v_{k+1} = s/Ts.
            (1e-6, 0.0, 1e-6 / TS, 1e-6 / TS),
            // On the band's edge from outside and inside agree (continuity).
            (9e-6, 0.0, 0.03, 0.03),
        ];
        for (s, v, u, v_next) in cases {
            let (gu, gv) = implicit(s, v, K1, K2, TS);
            assert!(
                (gu - u).abs() <= 1e-12 * u.abs().max(1.0) && (gv - v_next).abs() <= 1e-12,
                "s = {s}, v = {v}: got ({gu}, {gv}), want ({u}, {v_next})"
            );
        }
    }

    /// The implicit step solves its own equation: s_{k+1} = s_k − Ts·u_k and
    /// u_k = k1·√|s_{k+1}|·sgn(s_{k+1}) + v_{k+1} (outside the band).
    #[test]
    fn implicit_step_solves_the_backward_euler_equation() {
        for (s, v) in [(0.3, -2.0), (-0.02, 1.0), (1e-4, 0.1), (-5.0, 40.0)] {
            let (u, v1) = implicit(s, v, K1, K2, TS);
            let s1 = s - TS * u;
            let rhs = K1 * s1.abs().sqrt() * sgn(s1) + v1;
            assert!(
                (u - rhs).abs() <= 1e-9 * u.abs().max(1.0),
                "{s} {v}: {u} vs {rhs}"
            );
        }
    }

    /// As Ts → 0 the implicit step tends to the explicit one (consistency of the discretisation).
    #[test]
    fn implicit_tends_to_explicit_as_ts_goes_to_zero() {
        let (s, v) = (0.01, 0.5);
        let (ue, _) = explicit(s, v, K1, K2, 1e-9);
        let mut last = f64::INFINITY;
        for ts in [1e-3, 1e-4, 1e-5, 1e-6, 1e-7] {
            let (ui, _) = implicit(s, v, K1, K2, ts);
            let gap = (ui - ue).abs();
            assert!(
                gap < last,
                "ts = {ts}: gap {gap} did not shrink from {last}"
            );
            last = gap;
        }
        assert!(last < 1e-3 * ue.abs(), "{last}");
    }

    /// Across s = 0 a round-off change flips the explicit step's v update (by 2·Ts·k2) and its u;
    /// the implicit step moves by at most the change / Ts.
    #[test]
    fn a_round_off_change_across_zero_flips_the_explicit_law_not_the_implicit() {
        let (eps, v) = (1e-13, 0.0);
        let (ue_p, ve_p) = explicit(eps, v, K1, K2, TS);
        let (ue_m, ve_m) = explicit(-eps, v, K1, K2, TS);
        assert!(
            (ve_p - ve_m).abs() >= 2.0 * TS * K2 * 0.999,
            "explicit v does not flip"
        );
        assert!(
            (ue_p - ue_m).abs() > 1e-4,
            "explicit u does not flip: {ue_p} {ue_m}"
        );
        let (ui_p, vi_p) = implicit(eps, v, K1, K2, TS);
        let (ui_m, vi_m) = implicit(-eps, v, K1, K2, TS);
        assert!((ui_p - ui_m).abs() <= 2.0 * eps / TS * 1.0001);
        assert!((vi_p - vi_m).abs() <= 2.0 * eps / TS * 1.0001);
    }

    proptest! {
        /// u_k and v_{k+1} are Lipschitz in s_k with constant 1/Ts (continuous: no sign flip).
        #[test]
        fn implicit_step_is_lipschitz_in_s(
            s in -10.0f64..10.0,
            ds in -1e-3f64..1e-3,
            v in -100.0f64..100.0,
        ) {
            let (u0, v0) = implicit(s, v, K1, K2, TS);
            let (u1, v1) = implicit(s + ds, v, K1, K2, TS);
            let bound = ds.abs() / TS * (1.0 + 1e-9) + 1e-9;
            prop_assert!((u1 - u0).abs() <= bound, "{} > {}", (u1 - u0).abs(), bound);
            prop_assert!((v1 - v0).abs() <= bound, "{} > {}", (v1 - v0).abs(), bound);
        }

        /// Odd symmetry: (−s, −v) → (−u, −v_{k+1}), exactly.
        #[test]
        fn implicit_step_is_odd(s in -10.0f64..10.0, v in -100.0f64..100.0) {
            let (u, v1) = implicit(s, v, K1, K2, TS);
            let (um, v1m) = implicit(-s, -v, K1, K2, TS);
            prop_assert_eq!((u, v1), (-um, -v1m));
        }
    }
}
