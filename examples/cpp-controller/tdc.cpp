// The `tdc` law as a C++ controller on deltaloop.hpp: the same arithmetic, operation by
// operation, as controller/law/src/law.rs (and examples/c-controller/tdc.c), so a lockstep run
// gives the built-in controller's trace bit for bit.
#include <array>
#include <stdexcept>
#include <vector>

#include "deltaloop.hpp"

using Vec3 = std::array<double, 3>;

class Tdc {
  public:
    void init(const deltaloop::Run &run) {
        const std::string law = run.law();
        if (!law.empty() && law != "tdc")
            throw std::runtime_error("this controller implements only tdc, not " + law +
                                     " (run with --law tdc)");
        m_bar_ = run.f64("controller.m_bar");
        kp_ = run.f64("controller.kp");
        kd_ = run.f64("controller.kd");
        ts_ = run.f64("loop.ts_s");
        const auto ell = run.i64("controller.tde_delay_samples", 1);
        encoder_ = run.str("sensor.velocity", "measured") == "encoder-difference";
        // Allocated here, before READY: the loop allocates nothing.
        accel_.assign(ell < 1 ? 1 : static_cast<std::size_t>(ell), Vec3{});
        torque_.assign(accel_.size(), Vec3{});
    }

    void step(const dl_state &st, const dl_ref_sample &ref, dl_torque &reply) {
        if (!started_) start(st);
        Vec3 qd{}, accel{}, pair{};
        for (int i = 0; i < 3; i++) {
            if (encoder_) {
                qd[i] = (st.q[i] - q_prev1_[i]) / ts_;
                accel[i] = (st.q[i] - q_prev1_[i] * 2.0 + q_prev2_[i]) / (ts_ * ts_);
                pair[i] = (tau_prev_[i] + st.tau_applied[i]) / 2.0;
            } else {
                qd[i] = st.qd[i];
                accel[i] = (qd[i] - qd_prev_[i]) / ts_;
                pair[i] = st.tau_applied[i];
            }
        }
        for (int i = 0; i < 3; i++) {
            if (encoder_) {
                q_prev2_[i] = q_prev1_[i];
                q_prev1_[i] = st.q[i];
                tau_prev_[i] = st.tau_applied[i];
            }
            qd_prev_[i] = qd[i];
        }
        accel_[head_] = accel;  // push (a_{k−1}, τᵃ_k), read the oldest (a_{k−ℓ}, τᵃ_{k−ℓ+1})
        torque_[head_] = pair;
        head_ = (head_ + 1) % accel_.size();
        const Vec3 &a_lag = accel_[head_], &tau_lag = torque_[head_];
        for (int i = 0; i < 3; i++) {
            const double e = ref.q[i] - st.q[i];
            const double ed = ref.qd[i] - qd[i];
            e_int_[i] += e * ts_;
            reply.s[i] = ed + e * kd_ + e_int_[i] * kp_;
            reply.n_hat[i] = a_lag[i] - tau_lag[i] / m_bar_;
            reply.tau[i] = tau_lag[i] - a_lag[i] * m_bar_ + (ref.qdd[i] + ed * kd_ + e * kp_ + 0.0) * m_bar_;
            reply.u[i] = 0.0;
        }
    }

  private:
    // Before tick 0 the robot rested at q_0 under τᵃ_0: a_j = 0, τᵃ_j = τᵃ_0 (j ≤ 0).
    void start(const dl_state &st) {
        for (std::size_t j = 0; j < accel_.size(); j++)
            for (int i = 0; i < 3; i++) {
                accel_[j][i] = 0.0;
                torque_[j][i] = st.tau_applied[i];
            }
        for (int i = 0; i < 3; i++) {
            qd_prev_[i] = st.qd[i];
            q_prev1_[i] = q_prev2_[i] = st.q[i];
            tau_prev_[i] = st.tau_applied[i];
        }
        started_ = true;
    }

    double m_bar_ = 0, kp_ = 0, kd_ = 0, ts_ = 0;
    bool encoder_ = false, started_ = false;
    std::vector<Vec3> accel_, torque_;
    std::size_t head_ = 0;
    Vec3 e_int_{}, qd_prev_{}, q_prev1_{}, q_prev2_{}, tau_prev_{};
};

int main(int argc, char **argv) {
    Tdc law;
    return deltaloop::serve(argc, argv, law);
}
