/*
 * pgo's C API in one go: a robot drives a 1 m square twice; odometry
 * links consecutive poses, and place recognition proposes two loop
 * closures: pose 8 is where pose 0 was (many inliers: right), and pose 5
 * is 1.5 m to the left of where pose 1 was (a look-alike corridor: fewer
 * inliers, wrong). The optimisation decides them, and the χ² test judges
 * the map. Also shows how a failed call reads (an edge to a vertex that
 * was never added).
 *
 * Then reads the map's covariances: how well pose 8 is known, alone and
 * as seen from pose 4. A progress callback watches the solver's
 * iterations.
 *
 * Checks its own expectations — the right loop accepted, the wrong one
 * rejected, the test passed, the deliberate error reported, the fixed
 * pose certain and pose 8 relative to it as uncertain as pose 8 — and
 * exits 1 otherwise, so CI runs it as a test.
 *
 * Build (see capi/README.md):
 *   cargo build --release -p pgo-capi
 *   cc -Wall -Wextra -std=c11 -I capi/include capi/examples/simple.c \
 *      target/release/libpgo_c.a -lm -ldl -lpthread -o simple
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "pgo.h"

#define POSES 9
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

/* The poses and the odometry: 1 m forward and a quarter turn left, with
 * a little noise; the initial poses are the odometry composed (drifting). */
static void add_odometry(PgoGraph *graph) {
    static const double noise[POSES - 1][3] = {
        {0.012, -0.008, 0.010}, {-0.006, 0.011, -0.007}, {0.009, 0.004, 0.012},
        {-0.011, -0.005, 0.006}, {0.004, 0.010, -0.011}, {0.010, -0.012, 0.008},
        {-0.008, 0.006, 0.009}, {0.007, -0.004, -0.006},
    };
    const double info[9] = {100, 0, 0, 0, 100, 0, 0, 0, 400};
    double pose[3] = {0, 0, 0};
    check(pgo_graph_add_pose(graph, 0, pose, 3), "pgo_graph_add_pose");
    for (uint64_t k = 1; k < POSES; k++) {
        const double *n = noise[k - 1];
        double step[3] = {1.0 + n[0], n[1], HALF_PI + n[2]}, next[3];
        compose(pose, step, next);
        memcpy(pose, next, sizeof pose);
        check(pgo_graph_add_pose(graph, k, pose, 3), "pgo_graph_add_pose");
        check(pgo_graph_add_edge(graph, k - 1, k, step, 3, info, 9), "pgo_graph_add_edge");
    }
}

/* The two loop candidates; their indices are stored at right and wrong. */
static void add_loops(PgoGraph *graph, size_t *right, size_t *wrong) {
    const double info[9] = {50, 0, 0, 0, 50, 0, 0, 0, 200};
    const double same_place[3] = {0.01, -0.01, 0.005};
    const double look_alike[3] = {0.0, 1.5, 0.1};
    check(pgo_graph_add_loop_candidate(graph, 0, 8, same_place, 3, info, 9, 150, right),
          "pgo_graph_add_loop_candidate");
    check(pgo_graph_add_loop_candidate(graph, 1, 5, look_alike, 3, info, 9, 31, wrong),
          "pgo_graph_add_loop_candidate");
}

/* A call that fails on purpose, and what it says; 0 if it says it. */
static int show_an_error(PgoGraph *graph) {
    const double step[3] = {1, 0, 0}, info[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    PgoStatus status = pgo_graph_add_edge(graph, 8, 99, step, 3, info, 9);
    printf("adding an edge to vertex 99: status %d, \"%s\"\n", (int)status, pgo_last_error());
    return status == PGO_ERR_UNKNOWN_VERTEX && strstr(pgo_last_error(), "99") != NULL ? 0 : 1;
}

/* Prints the poses and the decisions; the number of failed expectations. */
static int report(const PgoResult *result, size_t right, size_t wrong) {
    int failures = 0;
    for (uint64_t id = 0; id < POSES; id++) {
        double p[3];
        check(pgo_result_pose(result, id, p, 3), "pgo_result_pose");
        printf("pose %llu: x %7.3f  y %7.3f  theta %7.3f\n", (unsigned long long)id, p[0], p[1], p[2]);
    }
    size_t loops;
    check(pgo_result_num_loops(result, &loops), "pgo_result_num_loops");
    for (size_t k = 0; k < loops; k++) {
        PgoLoopDecision d;
        check(pgo_result_loop(result, k, &d), "pgo_result_loop");
        const char *reason = pgo_result_loop_reason(result, k);
        printf("loop %zu (%llu -> %llu, %lld inliers): kept %d, weight %.3f, %s by %s\n", d.index,
               (unsigned long long)d.from, (unsigned long long)d.to, (long long)d.inliers, d.kept,
               d.weight, d.accepted ? "accepted" : "rejected", reason ? reason : "?");
        if ((d.index == right && !d.accepted) || (d.index == wrong && d.accepted)) {
            fprintf(stderr, "unexpected decision for loop %zu\n", d.index);
            failures++;
        }
    }
    double chi2;
    int verdict;
    check(pgo_result_chi2(result, &chi2), "pgo_result_chi2");
    check(pgo_result_verdict(result, &verdict), "pgo_result_verdict");
    printf("chi2 %.4f, chi2 test %s\n", chi2, verdict == 1 ? "passed" : verdict == 0 ? "failed" : "not run");
    /* What a caller checks before using the map: nothing questions it. */
    PgoMapStatus status;
    check(pgo_result_status(result, &status), "pgo_result_status");
    printf("map status %s\n", status == PGO_MAP_OK ? "ok" : "questioned or unfinished");
    return failures + (loops == 2 ? 0 : 1) + (verdict == 1 ? 0 : 1) + (status == PGO_MAP_OK ? 0 : 1);
}

/* Prints pose 8's standard deviations, alone and relative to pose 4; the
 * number of failed expectations. */
static int covariances(const PgoResult *result) {
    double c0[9], c8[9], rel[9], from0[9], joint[36];
    check(pgo_result_covariance(result, 0, c0, 9), "pgo_result_covariance");
    check(pgo_result_covariance(result, 8, c8, 9), "pgo_result_covariance");
    check(pgo_result_relative_covariance(result, 4, 8, rel, 9), "pgo_result_relative_covariance");
    check(pgo_result_relative_covariance(result, 0, 8, from0, 9), "pgo_result_relative_covariance");
    check(pgo_result_joint_covariance(result, 4, 8, joint, 36), "pgo_result_joint_covariance");
    printf("pose 8: sigma x %.4f y %.4f theta %.4f; from pose 4: %.4f %.4f %.4f\n", sqrt(c8[0]),
           sqrt(c8[4]), sqrt(c8[8]), sqrt(rel[0]), sqrt(rel[4]), sqrt(rel[8]));
    int failures = 0;
    for (int k = 0; k < 9; k++) {
        /* The fixed pose is certain; pose 8 from it is pose 8. */
        failures += c0[k] != 0.0;
        failures += fabs(from0[k] - c8[k]) > 1e-9 * sqrt(c8[4 * (k / 3)] * c8[4 * (k % 3)]);
        /* The joint's last block is pose 8's covariance. */
        failures += fabs(joint[6 * (3 + k / 3) + 3 + k % 3] - c8[k]) > 1e-9 * c8[0];
    }
    /* A buffer of the wrong length is refused. */
    failures += pgo_result_covariance(result, 8, c8, 6) != PGO_ERR_LENGTH;
    return failures + !(c8[0] > 0.0 && rel[0] > 0.0);
}

/* A progress callback: counts the solver's iterations and keeps the last
 * objective (a real front end would update a status line). Returning
 * nonzero would stop the job. */
struct progress {
    size_t iterations;
    double objective;
};

static int on_iteration(size_t iterations, double objective, void *user_data) {
    struct progress *p = user_data;
    p->iterations = iterations;
    p->objective = objective;
    return 0;
}

int main(void) {
    printf("pgo %s\n", pgo_version());
    PgoGraph *graph = NULL;
    PgoOptions *options = NULL;
    PgoResult *result = NULL;
    size_t right, wrong;
    check(pgo_graph_new(2, &graph), "pgo_graph_new");
    add_odometry(graph);
    add_loops(graph, &right, &wrong);
    int failures = show_an_error(graph);
    check(pgo_options_new(&options), "pgo_options_new");
    check(pgo_options_set(options, "alpha", "0.05"), "pgo_options_set");
    PgoCancel *watch = NULL;
    struct progress seen = {0, 0.0};
    check(pgo_cancel_new(&watch), "pgo_cancel_new");
    check(pgo_cancel_set_progress(watch, on_iteration, &seen), "pgo_cancel_set_progress");
    check(pgo_graph_optimize_with(graph, options, watch, &result), "pgo_graph_optimize_with");
    pgo_cancel_free(watch);
    printf("progress: %zu solver iterations, last objective %.6g\n", seen.iterations,
           seen.objective);
    failures += seen.iterations == 0;
    failures += report(result, right, wrong);
    failures += covariances(result);
    const char *json = pgo_result_report_json(result);
    printf("report: %zu bytes of JSON\n", json ? strlen(json) : 0);
    failures += json == NULL;
    pgo_result_free(result);
    pgo_options_free(options);
    pgo_graph_free(graph);
    if (failures > 0) {
        fprintf(stderr, "%d expectation(s) failed\n", failures);
        return 1;
    }
    return 0;
}
