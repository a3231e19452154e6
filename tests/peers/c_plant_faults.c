/* A C plant that fails on purpose (tests/e2e/foreign_peers.rs): the project's model through
 * dl_model_* (as examples/c-plant), whose `truth` or `measure` returns an error from a given tick
 * on, with a message carrying an escape code and a newline. The first argument, before the
 * library's, says which: `truth@K` or `measure@K`. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "deltaloop.h"

typedef struct {
    dl_model *model;
    int fail_truth;     /* else measure */
    uint64_t fail_at;   /* the tick from which it fails */
    uint64_t tick;      /* advances so far */
} plant;

static int start(void *user, const dl_run *run, const double *q0) {
    plant *p = user;
    return dl_model_open(run, q0, &p->model);
}

static int failed(const plant *p) {
    dl_set_error("encoder 2: no answer on the CAN bus\x1b[0m\nretry 3 failed");
    (void)p;
    return 7;
}

static int truth(void *user, dl_joints *out) {
    plant *p = user;
    if (p->fail_truth && p->tick >= p->fail_at)
        return failed(p);
    return dl_model_truth(p->model, out);
}

static int measure(void *user, dl_joints *out) {
    plant *p = user;
    if (!p->fail_truth && p->tick >= p->fail_at)
        return failed(p);
    return dl_model_measure(p->model, out);
}

static int advance(void *user, const double *tau, uint64_t latency_ns, uint32_t *drives) {
    plant *p = user;
    p->tick++;
    return dl_model_advance(p->model, tau, latency_ns, drives);
}

static int brake(void *user, double damping) {
    return dl_model_brake(((plant *)user)->model, damping);
}

int main(int argc, char **argv) {
    plant p;
    dl_plant_fns fns;
    const char *at;
    int code;
    memset(&p, 0, sizeof p);
    memset(&fns, 0, sizeof fns);
    if (argc < 2 || (at = strchr(argv[1], '@')) == NULL) {
        fprintf(stderr, "usage: %s truth@K|measure@K --run-id … (the library's arguments)\n", argv[0]);
        return 2;
    }
    p.fail_truth = strncmp(argv[1], "truth@", 6) == 0;
    p.fail_at = strtoull(at + 1, NULL, 10);
    fns.start = start;
    fns.truth = truth;
    fns.measure = measure;
    fns.advance = advance;
    fns.brake = brake;
    argv[1] = argv[0]; /* the library's arguments follow: argv[0] stays the name */
    code = dl_plant_main(argc - 1, (const char *const *)(argv + 1), &fns, &p);
    dl_model_close(p.model);
    return code;
}
