/*
 * pgo's C API on files: read a g2o file, list its pose ids, optimise it,
 * and write the optimised map (g2o: the file's own text with the new
 * poses), the trajectory in the TUM and KITTI formats that evo reads
 * (evo_ape tum truth.tum map.tum) and the pictures of `pgo optimize --plot`.
 *
 *   files IN.g2o OUTDIR     writes OUTDIR/map.g2o, map.tum, map.kitti and
 *                           OUTDIR/pictures/ (counts.svg, loops.svg,
 *                           trajectory.svg)
 *
 * Checks its own expectations — the map read back has the same ids in
 * the same order; the TUM file has one line per pose, its id as the
 * timestamp and its translation as pgo_result_pose gives it, to the bit;
 * the trajectory picture is an SVG — and exits 1 otherwise, so CI runs it
 * as a test.
 *
 * Build (see capi/README.md):
 *   cargo build --release -p pgo-capi
 *   cc -Wall -Wextra -std=c11 -I capi/include capi/examples/files.c \
 *      target/release/libpgo_c.a -lm -ldl -lpthread -o files
 *   ./files g2o_samples/grid2d.g2o /tmp
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "pgo.h"

/* Exits with pgo's message when a call failed. */
static void check(PgoStatus status, const char *what) {
    if (status != PGO_OK) {
        fprintf(stderr, "%s failed (status %d): %s\n", what, (int)status, pgo_last_error());
        exit(1);
    }
}

/* The ids of a graph's poses, in its order (malloc'd); their count at *n. */
static uint64_t *pose_ids(const PgoGraph *graph, size_t *n) {
    check(pgo_graph_len(graph, n), "pgo_graph_len");
    uint64_t *ids = malloc((*n > 0 ? *n : 1) * sizeof *ids);
    if (ids == NULL) {
        fprintf(stderr, "out of memory\n");
        exit(1);
    }
    check(pgo_graph_ids(graph, ids, *n), "pgo_graph_ids");
    return ids;
}

/* dir/name into out (of size len). */
static void join(char *out, size_t len, const char *dir, const char *name) {
    if ((size_t)snprintf(out, len, "%s/%s", dir, name) >= len) {
        fprintf(stderr, "path too long: %s/%s\n", dir, name);
        exit(1);
    }
}

/* The map read back: the same ids, in the same order; the number of
 * mismatches. */
static int compare_map(const char *path, const uint64_t *ids, size_t n) {
    PgoGraph *map = NULL;
    check(pgo_graph_read_g2o(path, &map), "pgo_graph_read_g2o (the map)");
    size_t m;
    uint64_t *back = pose_ids(map, &m);
    int failures = m != n;
    for (size_t k = 0; k < n && k < m; k++) {
        failures += back[k] != ids[k];
    }
    free(back);
    pgo_graph_free(map);
    return failures;
}

/* The TUM file: one line per pose, its id first, then its translation as
 * pgo_result_pose gives it, to the bit (z = 0 in 2D); the number of
 * mismatches. */
static int compare_tum(const char *path, const PgoResult *result, const uint64_t *ids, size_t n,
                       size_t width) {
    FILE *f = fopen(path, "r");
    if (f == NULL) {
        perror(path);
        return 1;
    }
    int failures = 0;
    size_t lines = 0;
    unsigned long long id;
    double v[7];
    while (fscanf(f, "%llu %lf %lf %lf %lf %lf %lf %lf", &id, &v[0], &v[1], &v[2], &v[3], &v[4],
                  &v[5], &v[6]) == 8) {
        if (lines >= n || id != ids[lines]) {
            failures++;
        } else {
            double pose[7];
            check(pgo_result_pose(result, ids[lines], pose, width), "pgo_result_pose");
            double z = width == 3 ? 0.0 : pose[2];
            failures += v[0] != pose[0] || v[1] != pose[1] || v[2] != z;
        }
        lines++;
    }
    fclose(f);
    return failures + (lines != n);
}

/* Whether the file at `path` begins as an SVG picture does. */
static int is_svg(const char *path) {
    FILE *f = fopen(path, "r");
    char head[5] = {0};
    int ok = f != NULL && fread(head, 1, 4, f) == 4 && strcmp(head, "<svg") == 0;
    if (f != NULL) {
        fclose(f);
    }
    if (!ok) {
        fprintf(stderr, "%s is no SVG picture\n", path);
    }
    return ok;
}

int main(int argc, char **argv) {
    if (argc != 3) {
        fprintf(stderr, "usage: %s IN.g2o OUTDIR\n", argv[0]);
        return 2;
    }
    char map_path[4096], tum_path[4096], kitti_path[4096], plots[4096], picture[4096];
    join(map_path, sizeof map_path, argv[2], "map.g2o");
    join(tum_path, sizeof tum_path, argv[2], "map.tum");
    join(kitti_path, sizeof kitti_path, argv[2], "map.kitti");
    join(plots, sizeof plots, argv[2], "pictures");
    join(picture, sizeof picture, plots, "trajectory.svg");

    PgoGraph *graph = NULL;
    PgoResult *result = NULL;
    check(pgo_graph_read_g2o(argv[1], &graph), "pgo_graph_read_g2o");
    int dim;
    check(pgo_graph_dim(graph, &dim), "pgo_graph_dim");
    size_t n, width = dim == 2 ? 3 : 7;
    uint64_t *ids = pose_ids(graph, &n);
    printf("%s: %zu poses in %dD, ids %llu ... %llu\n", argv[1], n, dim,
           n ? (unsigned long long)ids[0] : 0ULL, n ? (unsigned long long)ids[n - 1] : 0ULL);

    check(pgo_graph_optimize(graph, NULL, &result), "pgo_graph_optimize");
    check(pgo_result_write_g2o(result, map_path), "pgo_result_write_g2o");
    check(pgo_result_write_tum(result, tum_path), "pgo_result_write_tum");
    check(pgo_result_write_kitti(result, kitti_path), "pgo_result_write_kitti");
    check(pgo_result_write_plots(result, plots), "pgo_result_write_plots");
    printf("wrote %s, %s, %s and the pictures in %s\n", map_path, tum_path, kitti_path, plots);

    int failures = compare_map(map_path, ids, n) + compare_tum(tum_path, result, ids, n, width) +
                   !is_svg(picture);
    free(ids);
    pgo_result_free(result);
    pgo_graph_free(graph);
    if (failures > 0) {
        fprintf(stderr, "%d expectation(s) failed\n", failures);
        return 1;
    }
    return 0;
}
