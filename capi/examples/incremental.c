/*
 * pgo's incremental solving from C, as an online mapping front end uses
 * it: a robot drives a 1 m square six times; every pose comes with its
 * odometry, and from the third lap on place recognition proposes a loop
 * closure to the same corner one lap before (many inliers: right), and
 * now and then one to the opposite corner claimed to be the same place
 * (few inliers: wrong). The front end asks for the map every two poses
 * with pgo_graph_update_with, which solves only what the additions need,
 * and prints how each update solved and which earlier decisions it
 * changed. Each update holds a PgoCancel token a watchdog thread could
 * request to stop a step that runs too long.
 *
 * Checks its own expectations — the first update a batch job, the first
 * laps' odometry composed without a solve, the whole job again only while
 * the map is too young for EM to resume from (or where its decisions
 * swung), an update with nothing added a no-op, and the last map the one pgo_graph_optimize makes of the whole
 * graph (the same decisions, the poses within 1e-6, χ² within 1e-6
 * relative), right, and passing the χ² test — and exits 1 otherwise, so
 * CI runs it as a test.
 *
 * Build (see capi/README.md):
 *   cargo build --release -p pgo-capi
 *   cc -Wall -Wextra -std=c11 -I capi/include capi/examples/incremental.c \
 *      target/release/libpgo_c.a -lm -ldl -lpthread -o incremental
 */
#include <math.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "pgo.h"

#define LAPS 6
#define SIDES 4
#define POSES (LAPS * SIDES + 1)
#define EVERY 2
#define HALF_PI 1.5707963267948966

/* Exits with pgo's message when a call failed. */
static void check(PgoStatus status, const char *what) {
    if (status != PGO_OK) {
        fprintf(stderr, "%s failed (status %d): %s\n", what, (int)status, pgo_last_error());
        exit(1);
    }
}

/* a ⊕ b for planar poses (x, y, θ). */
static void compose(const double a[3], const double b[3], double out[3]) {
    double c = cos(a[2]), s = sin(a[2]);
    out[0] = a[0] + c * b[0] - s * b[1];
    out[1] = a[1] + s * b[0] + c * b[1];
    out[2] = atan2(sin(a[2] + b[2]), cos(a[2] + b[2]));
}

/* A reproducible noise in [-scale, scale] (xorshift). */
static double noise(double scale) {
    static uint64_t state = 88172645463325252ull;
    state ^= state << 13;
    state ^= state >> 7;
    state ^= state << 17;
    return scale * ((double)(state >> 11) / 9007199254740992.0 * 2.0 - 1.0);
}

static const char *solve_name(PgoUpdateSolve solve) {
    switch (solve) {
    case PGO_NOT_AN_UPDATE: return "not an update";
    case PGO_UPDATE_BATCH: return "batch";
    case PGO_UPDATE_NONE: return "none";
    case PGO_UPDATE_EXTENDED: return "extended";
    case PGO_UPDATE_WARM: return "warm";
    case PGO_UPDATE_FULL: return "full";
    }
    return "?";
}

/* Adds pose k (k ≥ 1) with its odometry from pose k - 1 and, from the
 * third lap on, its loop candidates; `guess` is the odometry composed
 * so far (the pose's initial guess), advanced. Returns the number of
 * loop candidates added. */
static int add_step(PgoGraph *graph, uint64_t k, double guess[3]) {
    const double odometry_info[9] = {2500, 0, 0, 0, 2500, 0, 0, 0, 10000};
    const double loop_info[9] = {400, 0, 0, 0, 400, 0, 0, 0, 2500};
    double step[3] = {1.0 + noise(0.02), noise(0.02), HALF_PI + noise(0.01)}, next[3];
    compose(guess, step, next);
    for (int i = 0; i < 3; i++) guess[i] = next[i];
    check(pgo_graph_add_pose(graph, k, guess, 3), "pgo_graph_add_pose");
    check(pgo_graph_add_edge(graph, k - 1, k, step, 3, odometry_info, 9), "pgo_graph_add_edge");
    if (k < 2 * SIDES) return 0;
    /* The same corner one lap before: the same place, seen again. */
    const double same_place[3] = {noise(0.03), noise(0.03), noise(0.01)};
    check(pgo_graph_add_loop_candidate(graph, k - SIDES, k, same_place, 3, loop_info, 9,
                                       90 + (int64_t)(k % 7) * 9, NULL),
          "pgo_graph_add_loop_candidate");
    if (k % 5 != 3) return 1;
    /* The opposite corner (1.4 m away, facing the other way) taken for
     * this one: wrong. */
    const double look_alike[3] = {noise(0.03), noise(0.03), noise(0.01)};
    check(pgo_graph_add_loop_candidate(graph, k - 2, k, look_alike, 3, loop_info, 9,
                                       8 + (int64_t)(k % 4) * 3, NULL),
          "pgo_graph_add_loop_candidate");
    return 2;
}

/* Prints what an update did and the decisions it changed; the number of
 * failed expectations, `candidates` being the loop candidates added since
 * the last update, `first` whether it is the first and `resumed` whether an
 * earlier update resumed EM's decisions (set here). */
static int show_update(const PgoResult *result, size_t poses, int candidates, int first,
                       int *resumed) {
    PgoUpdate u;
    check(pgo_result_update(result, &u), "pgo_result_update");
    const char *reason = pgo_result_update_reason(result);
    printf("%2zu poses: %-8s (%s), +%zu poses +%zu edges +%zu candidates, %zu changed\n", poses,
           solve_name(u.solve), reason ? reason : "?", u.new_poses, u.new_edges,
           u.new_candidates, u.num_changed);
    for (size_t k = 0; k < u.num_changed; k++) {
        PgoDecisionChange c;
        check(pgo_result_change(result, k, &c), "pgo_result_change");
        const char *why = pgo_result_change_reason(result, k);
        printf("    loop %zu (%llu -> %llu) now %s by %s\n", c.index, (unsigned long long)c.from,
               (unsigned long long)c.to, c.accepted ? "accepted" : "rejected", why ? why : "?");
    }
    int failures = 0;
    if (first && u.solve != PGO_UPDATE_BATCH) failures++;
    /* The whole job again only while the map is young (too few candidates
     * for EM, no loop model yet: nothing to resume from) or where EM's
     * decisions from the last ones swung; once resumed, only the latter. */
    int swung = reason != NULL && strstr(reason, "swung") != NULL;
    if (!first && *resumed && u.solve == PGO_UPDATE_BATCH && !swung) failures++;
    if (!first && u.solve == PGO_UPDATE_WARM) *resumed = 1;
    /* Odometry alone is composed, not solved. */
    if (!first && candidates == 0 && u.solve != PGO_UPDATE_EXTENDED) failures++;
    if (failures > 0) fprintf(stderr, "unexpected update at %zu poses\n", poses);
    return failures;
}

/* The number of ways the last update differs from the batch job or is
 * wrong. (χ² counts every edge, the rejected candidates included.) */
static int compare_with_batch(const PgoResult *last, const PgoResult *batch) {
    int failures = 0;
    double worst = 0.0;
    for (uint64_t id = 0; id < POSES; id++) {
        double a[3], b[3];
        check(pgo_result_pose(last, id, a, 3), "pgo_result_pose");
        check(pgo_result_pose(batch, id, b, 3), "pgo_result_pose");
        double d[3] = {fabs(a[0] - b[0]), fabs(a[1] - b[1]),
                       fabs(atan2(sin(a[2] - b[2]), cos(a[2] - b[2])))};
        for (int i = 0; i < 3; i++) worst = d[i] > worst ? d[i] : worst;
    }
    size_t n, m, accepted = 0;
    check(pgo_result_num_loops(last, &n), "pgo_result_num_loops");
    check(pgo_result_num_loops(batch, &m), "pgo_result_num_loops");
    failures += n != m;
    for (size_t k = 0; k < n && k < m; k++) {
        PgoLoopDecision a, b;
        check(pgo_result_loop(last, k, &a), "pgo_result_loop");
        check(pgo_result_loop(batch, k, &b), "pgo_result_loop");
        failures += a.index != b.index || a.accepted != b.accepted;
        /* The map is right: the many-inlier candidates in, the others out. */
        failures += a.accepted != (a.inliers >= 90);
        accepted += a.accepted;
    }
    double chi2_last, chi2_batch;
    check(pgo_result_chi2(last, &chi2_last), "pgo_result_chi2");
    check(pgo_result_chi2(batch, &chi2_batch), "pgo_result_chi2");
    double relative = fabs(chi2_last / chi2_batch - 1.0);
    int verdict;
    check(pgo_result_verdict(last, &verdict), "pgo_result_verdict");
    printf("last update vs batch: poses within %.1e, chi2 %.6f vs %.6f, %zu of %zu loops "
           "accepted, chi2 test %s\n",
           worst, chi2_last, chi2_batch, accepted, n,
           verdict == 1 ? "passed" : verdict == 0 ? "failed" : "not run");
    return failures + (worst < 1e-6 ? 0 : 1) + (relative < 1e-6 ? 0 : 1) + (verdict == 1 ? 0 : 1);
}

int main(void) {
    PgoGraph *graph = NULL;
    PgoResult *last = NULL, *result = NULL;
    PgoCancel *cancel = NULL;
    check(pgo_graph_new(2, &graph), "pgo_graph_new");
    check(pgo_cancel_new(&cancel), "pgo_cancel_new");
    double guess[3] = {0, 0, 0};
    check(pgo_graph_add_pose(graph, 0, guess, 3), "pgo_graph_add_pose");
    int failures = 0, candidates = 0, first = 1, resumed = 0;
    for (uint64_t k = 1; k < POSES; k++) {
        candidates += add_step(graph, k, guess);
        if (k % EVERY != 0 && k + 1 != POSES) continue;
        /* pgo_cancel_request(cancel) from another thread would stop this
         * step with the best map so far, the graph's state kept. */
        check(pgo_graph_update_with(graph, NULL, cancel, &result), "pgo_graph_update_with");
        bool stopped = true;
        check(pgo_result_cancelled(result, &stopped), "pgo_result_cancelled");
        failures += stopped;
        failures += show_update(result, (size_t)k + 1, candidates, first, &resumed);
        pgo_result_free(last);
        last = result;
        candidates = 0;
        first = 0;
    }
    /* Nothing added since: the last map stands. */
    check(pgo_graph_update(graph, NULL, &result), "pgo_graph_update");
    PgoUpdate u;
    check(pgo_result_update(result, &u), "pgo_result_update");
    printf("again: %s\n", solve_name(u.solve));
    failures += u.solve != PGO_UPDATE_NONE;
    pgo_result_free(result);

    PgoResult *batch = NULL;
    check(pgo_graph_optimize(graph, NULL, &batch), "pgo_graph_optimize");
    check(pgo_result_update(batch, &u), "pgo_result_update");
    failures += u.solve != PGO_NOT_AN_UPDATE;
    failures += compare_with_batch(last, batch);
    pgo_result_free(batch);
    pgo_result_free(last);
    pgo_cancel_free(cancel);
    pgo_graph_free(graph);
    if (failures > 0) {
        fprintf(stderr, "%d expectation(s) failed\n", failures);
        return 1;
    }
    return 0;
}
