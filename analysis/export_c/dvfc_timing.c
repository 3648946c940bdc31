/* dvfc_timing.c: the time of each of `calls` steps, for the benchmark and
 * `dvfc export --check`. Not part of the controller: it is the only file here that reads a clock. */
#define _POSIX_C_SOURCE 199309L
#include <time.h>

#include "dvfc_controller.h"

/* Steps from dvfc_init at t = k DVFC_PERIOD with q, qd fixed and, when features is not NULL, an image
 * captured at the current sample every call; seconds[k] the time of call k: wall time (CLOCK_MONOTONIC,
 * preemption by other processes included) or, with cpu nonzero, the calling thread's CPU time
 * (CLOCK_THREAD_CPUTIME_ID: the step's own cost). Returns the last code. */
int dvfc_time_steps(long calls, const double* q, const double* qd, const double* features, int cpu,
                    double* seconds) {
    const clockid_t clock = cpu ? CLOCK_THREAD_CPUTIME_ID : CLOCK_MONOTONIC;
    static dvfc_state state;
    double tau[DVFC_N_JOINTS];
    struct timespec a, b;
    long k;
    int code = 0;
    dvfc_init(&state);
    for (k = 0; k < calls; ++k) {
        clock_gettime(clock, &a);
        code = dvfc_step(&state, k * DVFC_PERIOD, q, qd, features, (int)k, tau);
        clock_gettime(clock, &b);
        seconds[k] = (double)(b.tv_sec - a.tv_sec) + 1e-9 * (double)(b.tv_nsec - a.tv_nsec);
    }
    return code;
}
