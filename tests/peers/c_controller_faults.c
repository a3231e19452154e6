/* A C controller that fails on purpose (tests/e2e/foreign_peers.rs): it holds the applied torque
 * (τ = τᵃ_k: the robot stays near rest for the few ticks it runs) and its step returns an error
 * from a given tick on. The first argument, before the library's, says when: `fail@K`. It names
 * itself "qp-ctrl v1" (dl_run_set_label; tests/e2e/custom_process.rs). */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "deltaloop.h"

static int init(void *user, const dl_run *run) {
    (void)user;
    return dl_run_set_label(run, "qp-ctrl v1");
}

static int step(void *user, const dl_state *x, const dl_ref_sample *r, dl_torque *reply) {
    const uint64_t *fail_at = user;
    int i;
    (void)r;
    if (x->tick >= *fail_at) {
        dl_set_error("the solver did not converge (QP infeasible)");
        return 3;
    }
    for (i = 0; i < 3; i++)
        reply->tau[i] = x->tau_applied[i];
    return 0;
}

int main(int argc, char **argv) {
    uint64_t fail_at;
    if (argc < 2 || strncmp(argv[1], "fail@", 5) != 0) {
        fprintf(stderr, "usage: %s fail@K --run-id … (the library's arguments)\n", argv[0]);
        return 2;
    }
    fail_at = strtoull(argv[1] + 5, NULL, 10);
    argv[1] = argv[0];
    return dl_controller_main(argc - 1, (const char *const *)(argv + 1), init, step, &fail_at);
}
