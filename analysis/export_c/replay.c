/* replay.c: replay a recorded input file through the controller and print its torques.
 *
 *   ./replay inputs.csv > torques.csv
 *
 * Input: CSV, one control sample a line, in order from the first sample (k = 0); lines starting with
 * '#' are comments. Columns:
 *   t, capture_step, q_1..q_n, qd_1..qd_n, f_1..f_2m
 * with n = DVFC_N_JOINTS, 2m = DVFC_N_FEATURES, capture_step < 0 for a sample without an image (its
 * features are then ignored; write zeros). `dvfc export --check` writes such a file (sil_inputs.csv).
 * Output: CSV, one line per sample: k, status, tau_1..tau_n, each number with 17 significant digits
 * (the double exactly).
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "dvfc_controller.h"

#define COLUMNS (2 + 2 * DVFC_N_JOINTS + DVFC_N_FEATURES)

int main(int argc, char** argv) {
    static char line[1 << 16];
    double v[COLUMNS], tau[DVFC_N_JOINTS];
    dvfc_state state;
    FILE* in;
    long k = 0;
    if (argc != 2) {
        fprintf(stderr, "usage: %s inputs.csv\n", argv[0]);
        return 2;
    }
    in = fopen(argv[1], "r");
    if (!in) {
        fprintf(stderr, "replay: cannot open %s\n", argv[1]);
        return 2;
    }
    dvfc_init(&state);
    while (fgets(line, sizeof line, in)) {
        char* p = line;
        int c, code, capture;
        if (line[0] == '#' || line[0] == '\n') continue;
        for (c = 0; c < COLUMNS; ++c) {
            char* end;
            v[c] = strtod(p, &end);
            if (end == p) {
                fprintf(stderr, "replay: line %ld: expected %d numbers\n", k + 1, COLUMNS);
                fclose(in);
                return 2;
            }
            p = end + (*end == ',');
        }
        capture = (int)v[1];
        code = dvfc_step(&state, v[0], v + 2, v + 2 + DVFC_N_JOINTS,
                         capture >= 0 ? v + 2 + 2 * DVFC_N_JOINTS : NULL, capture, tau);
        printf("%ld,%d", k, code);
        for (c = 0; c < DVFC_N_JOINTS; ++c) printf(",%.17g", tau[c]);
        printf("\n");
        ++k;
    }
    fclose(in);
    return 0;
}
