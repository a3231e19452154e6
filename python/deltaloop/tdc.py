"""The `tdc` law (docs/controllers.md; controller/law/src/law.rs) in plain Python, for the
example controllers (examples/python-controller over iceoryx2, examples/ros2 over DDS):

    τ_k = τᵃ_{k−ℓ+1} − M̄ a_{k−ℓ} + M̄ (q̈_d,k + K_d ė_k + K_p e_k),   N̂_k = a_{k−ℓ} − τᵃ_{k−ℓ+1}/M̄

with the constants of the run's resolved config (`[controller]` m_bar, kp, kd,
tde_delay_samples; `[loop]` ts_s; `[sensor]` velocity). The arithmetic follows law.rs operation by
operation, so for the same states it gives the built-in controller's torques bit for bit. `step`
reads `st.q`, `st.qd`, `st.tau_applied` and `ref.q`, `ref.qd`, `ref.qdd` (three floats each) and
returns τ, s, N̂, u. Needs neither iceoryx2 nor cyclonedds.
"""


class Tdc:
    def __init__(self, config):
        c = config["controller"]
        self.m_bar, self.kp, self.kd = float(c["m_bar"]), float(c["kp"]), float(c["kd"])
        self.ell = max(1, int(c.get("tde_delay_samples", 1)))
        self.ts = float(config["loop"]["ts_s"])
        self.encoder = config.get("sensor", {}).get("velocity", "measured") == "encoder-difference"
        self.started = False
        self.e_int = [0.0, 0.0, 0.0]  # E_{k−1}, rad s

    def start(self, st):
        """Before tick 0 the robot rested at q_0 under τᵃ_0: a_j = 0, τᵃ_j = τᵃ_0 (j ≤ 0)."""
        tau0 = tuple(st.tau_applied)
        self.accel = [(0.0, 0.0, 0.0)] * self.ell  # the TDE ring: (a_{j−1}, τᵃ_j), oldest at head
        self.torque = [tau0] * self.ell
        self.head = 0
        self.qd_prev = tuple(st.qd)
        self.q_prev = (tuple(st.q), tuple(st.q))  # q_{k−1}, q_{k−2} (encoder source)
        self.tau_prev = tau0
        self.started = True

    def step(self, st, ref):
        if not self.started:
            self.start(st)
        ts, m_bar, kp, kd = self.ts, self.m_bar, self.kp, self.kd
        q, tau_a = st.q, st.tau_applied
        if self.encoder:
            q1, q2 = self.q_prev
            qd = tuple((q[i] - q1[i]) / ts for i in range(3))
            accel = tuple((q[i] - q1[i] * 2.0 + q2[i]) / (ts * ts) for i in range(3))
            pair = tuple((self.tau_prev[i] + tau_a[i]) / 2.0 for i in range(3))
            self.q_prev = (tuple(q), q1)
            self.tau_prev = tuple(tau_a)
        else:
            qd = tuple(st.qd)
            accel = tuple((qd[i] - self.qd_prev[i]) / ts for i in range(3))
            pair = tuple(tau_a)
        self.qd_prev = qd
        # TDE history: push (a_{k−1}, τᵃ_k), read the oldest (a_{k−ℓ}, τᵃ_{k−ℓ+1}).
        self.accel[self.head], self.torque[self.head] = accel, pair
        self.head = (self.head + 1) % self.ell
        a_lag, tau_lag = self.accel[self.head], self.torque[self.head]

        tau, s, n_hat = [0.0] * 3, [0.0] * 3, [0.0] * 3
        for i in range(3):
            e = ref.q[i] - q[i]
            ed = ref.qd[i] - qd[i]
            self.e_int[i] += e * ts
            s[i] = ed + e * kd + self.e_int[i] * kp
            n_hat[i] = a_lag[i] - tau_lag[i] / m_bar
            tau[i] = tau_lag[i] - a_lag[i] * m_bar + (ref.qdd[i] + ed * kd + e * kp + 0.0) * m_bar
        return tau, s, n_hat, (0.0, 0.0, 0.0)
