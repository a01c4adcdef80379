/* Prints exp(A h) of the drive lag (drive_lag.c) for each "w zeta h" line of stdin, in the
 * balanced coordinates of tests/test_native_drive_lag.py: p00, p01 w, p10 / w, p11. */
#include <stdio.h>

#include "drive_lag.h"

int main(void) {
    double w, zeta, h, p[4];
    while (scanf("%lf %lf %lf", &w, &zeta, &h) == 3) {
        drive_lag_transition(w, zeta, h, p);
        printf("%.17g %.17g %.17g %.17g\n", p[0], p[1] * w, p[2] / w, p[3]);
    }
    return 0;
}
