/* A known competitor for `--explain` (tests/e2e/explain.rs, docs/guide/misses.md): pinned to
 * CPU `cpu` at SCHED_FIFO `prio`, it waits `start_ms`, then busy-loops `bursts` times for
 * `burst_ms`, `gap_ms` apart. Only its bursts run at SCHED_FIFO: it prints, sleeps and exits at
 * SCHED_OTHER, so it takes the CPU from the loop exactly while it burns. It prints each burst's
 * start and end (CLOCK_MONOTONIC, ns), one line each: `burst <start_ns> <end_ns>`.
 * Usage: burner CPU PRIO START_MS BURSTS BURST_MS GAP_MS */
#define _GNU_SOURCE
#include <sched.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

static long long now_ns(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (long long)t.tv_sec * 1000000000LL + t.tv_nsec;
}

static void sleep_ms(long ms) {
    struct timespec t = {ms / 1000, (ms % 1000) * 1000000L};
    nanosleep(&t, NULL);
}

int main(int argc, char **argv) {
    if (argc != 7) {
        fprintf(stderr, "usage: burner CPU PRIO START_MS BURSTS BURST_MS GAP_MS\n");
        return 2;
    }
    int cpu = atoi(argv[1]), prio = atoi(argv[2]), bursts = atoi(argv[4]);
    long start_ms = atol(argv[3]), burst_ms = atol(argv[5]), gap_ms = atol(argv[6]);
    cpu_set_t set;
    CPU_ZERO(&set);
    CPU_SET(cpu, &set);
    if (sched_setaffinity(0, sizeof set, &set) != 0) {
        perror("sched_setaffinity");
        return 1;
    }
    struct sched_param fifo = {.sched_priority = prio}, other = {.sched_priority = 0};
    sleep_ms(start_ms);
    for (int i = 0; i < bursts; i++) {
        if (sched_setscheduler(0, SCHED_FIFO, &fifo) != 0) {
            perror("sched_setscheduler");
            return 1;
        }
        long long a = now_ns(), end = a + burst_ms * 1000000LL, b;
        while ((b = now_ns()) < end) {
        }
        sched_setscheduler(0, SCHED_OTHER, &other);
        printf("burst %lld %lld\n", a, b);
        fflush(stdout);
        sleep_ms(gap_ms);
    }
    return 0;
}
