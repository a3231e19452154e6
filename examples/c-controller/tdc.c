/* The `tdc` law (docs/controllers.md; controller/law/src/law.rs) as a deltaloop controller in C:
 *
 *   τ_k = τᵃ_{k−ℓ+1} − M̄ a_{k−ℓ} + M̄ (q̈_d,k + K_d ė_k + K_p e_k),   N̂_k = a_{k−ℓ} − τᵃ_{k−ℓ+1}/M̄
 *
 * with the constants of the run's resolved config. The library (peer/include/deltaloop.h) does
 * the process: arguments, ports, handshake, waits, stamps, STOP/SIGTERM, exit code. The
 * arithmetic follows law.rs operation by operation, so a lockstep run gives the built-in
 * controller's trace bit for bit. Build: `make` (docs/guide/own-process.md), then
 *
 *   deltaloop run configs/s1-nominal.toml --mode lockstep --law tdc \
 *       --controller-cmd examples/c-controller/c-tdc
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "deltaloop.h"

typedef struct {
    double m_bar, kp, kd, ts;
    size_t ell;       /* TDE delay ℓ ≥ 1, ticks */
    int encoder;      /* velocity = "encoder-difference" */
    int started;
    double e_int[3];  /* E_{k−1}, rad s */
    double (*accel)[3], (*torque)[3]; /* the TDE ring: (a_{j−1}, τᵃ_j), oldest at head */
    size_t head;
    double qd_prev[3], q_prev1[3], q_prev2[3], tau_prev[3];
} tdc;

static int get(const dl_run *run, const char *key, double *out) {
    return dl_run_f64(run, key, out) != DL_OK; /* dl_last_error() names the key */
}

static int init(void *user, const dl_run *run) {
    tdc *c = user;
    const char *law = dl_run_law(run);
    if (strcmp(law, "") != 0 && strcmp(law, "tdc") != 0) {
        /* The run's files would carry the other law's name: refuse rather than mislabel. */
        char why[128];
        snprintf(why, sizeof why, "this controller implements only tdc, not %s (run with --law tdc)", law);
        dl_set_error(why);
        return 1;
    }
    int64_t ell = 1;
    char velocity[32] = "measured";
    if (get(run, "controller.m_bar", &c->m_bar) || get(run, "controller.kp", &c->kp) ||
        get(run, "controller.kd", &c->kd) || get(run, "loop.ts_s", &c->ts))
        return 1;
    dl_run_i64(run, "controller.tde_delay_samples", &ell);
    dl_run_str(run, "sensor.velocity", velocity, sizeof velocity);
    c->ell = ell < 1 ? 1 : (size_t)ell;
    c->encoder = strcmp(velocity, "encoder-difference") == 0;
    /* Allocated here, before READY: the loop allocates nothing. */
    c->accel = calloc(c->ell, sizeof *c->accel);
    c->torque = calloc(c->ell, sizeof *c->torque);
    return c->accel && c->torque ? 0 : 1;
}

/* Before tick 0 the robot rested at q_0 under τᵃ_0: a_j = 0, τᵃ_j = τᵃ_0 (j ≤ 0). */
static void start(tdc *c, const dl_state *st) {
    for (size_t j = 0; j < c->ell; j++)
        for (int i = 0; i < 3; i++) {
            c->accel[j][i] = 0.0;
            c->torque[j][i] = st->tau_applied[i];
        }
    for (int i = 0; i < 3; i++) {
        c->qd_prev[i] = st->qd[i];
        c->q_prev1[i] = c->q_prev2[i] = st->q[i];
        c->tau_prev[i] = st->tau_applied[i];
        c->e_int[i] = 0.0;
    }
    c->head = 0;
    c->started = 1;
}

static int step(void *user, const dl_state *st, const dl_ref_sample *ref, dl_torque *reply) {
    tdc *c = user;
    if (!c->started)
        start(c, st);
    const double ts = c->ts, m_bar = c->m_bar, kp = c->kp, kd = c->kd;
    double qd[3], accel[3], pair[3];
    for (int i = 0; i < 3; i++) {
        if (c->encoder) {
            qd[i] = (st->q[i] - c->q_prev1[i]) / ts;
            accel[i] = (st->q[i] - c->q_prev1[i] * 2.0 + c->q_prev2[i]) / (ts * ts);
            pair[i] = (c->tau_prev[i] + st->tau_applied[i]) / 2.0;
        } else {
            qd[i] = st->qd[i];
            accel[i] = (qd[i] - c->qd_prev[i]) / ts;
            pair[i] = st->tau_applied[i];
        }
    }
    for (int i = 0; i < 3; i++) {
        if (c->encoder) {
            c->q_prev2[i] = c->q_prev1[i];
            c->q_prev1[i] = st->q[i];
            c->tau_prev[i] = st->tau_applied[i];
        }
        c->qd_prev[i] = qd[i];
        c->accel[c->head][i] = accel[i]; /* push (a_{k−1}, τᵃ_k) … */
        c->torque[c->head][i] = pair[i];
    }
    c->head = (c->head + 1) % c->ell; /* … read the oldest (a_{k−ℓ}, τᵃ_{k−ℓ+1}) */
    const double *a_lag = c->accel[c->head], *tau_lag = c->torque[c->head];
    for (int i = 0; i < 3; i++) {
        double e = ref->q[i] - st->q[i];
        double ed = ref->qd[i] - qd[i];
        c->e_int[i] += e * ts;
        reply->s[i] = ed + e * kd + c->e_int[i] * kp;
        reply->n_hat[i] = a_lag[i] - tau_lag[i] / m_bar;
        reply->tau[i] = tau_lag[i] - a_lag[i] * m_bar + (ref->qdd[i] + ed * kd + e * kp + 0.0) * m_bar;
        reply->u[i] = 0.0;
    }
    return 0;
}

int main(int argc, char **argv) {
    static tdc law;
    int code = dl_controller_main(argc, (const char *const *)argv, init, step, &law);
    free(law.accel);
    free(law.torque);
    return code;
}
