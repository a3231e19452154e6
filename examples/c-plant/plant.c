/* The Delta robot plant as a deltaloop plant process in C: the library (peer/include/deltaloop.h)
 * runs the plant process's loop (clock, arrival rule, misses, telemetry, final state, STOP, safe
 * stop, exit code) around five functions, and these forward to the project's own model
 * (dl_model_*), so a run with this plant gives the built-in plant's trace bit for bit. A rig's
 * driver fills the same five functions from its encoders and drives instead. Build: `make`
 * (README.md here), then
 *
 *   deltaloop run configs/s1-nominal.toml --mode lockstep --law tdc \
 *       --plant-cmd examples/c-plant/c-plant
 */
#include <stdio.h>

#include "deltaloop.h"

typedef struct {
    dl_model *model;
} plant;

static int start(void *user, const dl_run *run, const double *q0) {
    plant *p = user;
    return dl_model_open(run, q0, &p->model); /* dl_last_error() says why on failure */
}

static int truth(void *user, dl_joints *out) {
    return dl_model_truth(((plant *)user)->model, out);
}

static int measure(void *user, dl_joints *out) {
    return dl_model_measure(((plant *)user)->model, out);
}

static int advance(void *user, const double *tau, uint64_t latency_ns, uint32_t *drives) {
    return dl_model_advance(((plant *)user)->model, tau, latency_ns, drives);
}

static int brake(void *user, double damping) {
    return dl_model_brake(((plant *)user)->model, damping);
}

int main(int argc, char **argv) {
    plant p = {0};
    const dl_plant_fns fns = {
        .init = NULL, .start = start, .truth = truth, .measure = measure,
        .advance = advance, .brake = brake,
    };
    int code = dl_plant_main(argc, (const char *const *)argv, &fns, &p);
    dl_model_close(p.model);
    return code;
}
