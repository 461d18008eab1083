/* A hand-written C loop for the `shaken` scene: the throughput ceiling.
 *
 * Written by hand (not by codegen/) and kept small on purpose. It does what one
 * step of jackbox/kernel.py does in free flight, and nothing else: one classical
 * RK4 step with the same tableau as `rk4_step`, then every one of the 16
 * contact gaps, naively, every step, keeping their minimum. No impacts are
 * resolved, so it is only a fair ceiling before the jack's first contact; the
 * minimum gap it prints says whether that held.
 *
 * The equations are those of generated/shaken.py (functions accel and phi),
 * written out the way one would by hand:
 *   qdd = (A s / m_box, 0, tau s / J_box, 0, -g, 0),  s = sin(2 pi t / T);
 *   the jack's 4 tips, rotated into the box frame, against the 4 walls at
 *   distance L: gap = L - n . (r + tip) for wall normal n.
 *
 *   shaken_step N_STEPS DT p0 .. p12 q0 .. q5 qd0 .. qd5
 * prints one JSON line: steps, seconds, ns_per_step, q, qd, min_gap.
 * Built by benchmarks/ceiling.py (-O3 -march=native -ffp-contract=off).
 */
#define _POSIX_C_SOURCE 199309L
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#define N_DOF 6
#define N_PARAM 13
/* parameter slots, in the order of PARAM_NAMES */
enum { M_BOX, J_BOX, L_IN, W_BOX, M_JACK, J_JACK, G, E, E_GROUND, A_JACK, A_PUSH, TAU, T_PERIOD };

static const double TWO_PI = 6.283185307179586;  /* float(2*pi), as Python's 2*math.pi */

/* qdd at time t; the shaken scene's accelerations do not depend on q or qd */
static void accel(double t, const double *p, double *qdd)
{
    double s = sin(TWO_PI * t / p[T_PERIOD]);
    qdd[0] = (1.0 / p[M_BOX]) * (p[A_PUSH] * s);
    qdd[1] = 0.0;
    qdd[2] = (1.0 / p[J_BOX]) * (s * p[TAU]);
    qdd[3] = 0.0;
    qdd[4] = -p[G];
    qdd[5] = 0.0;
}

/* the smallest of the 16 gaps: 4 jack tips against 4 walls */
static double min_gap(const double *q, const double *p)
{
    double cb = cos(q[2]), sb = sin(q[2]);
    double dx = q[3] - q[0], dy = q[4] - q[1];
    double u = cb * dx + sb * dy, v = cb * dy - sb * dx;   /* jack centre, box frame */
    double rel = q[5] - q[2];                              /* jack angle, box frame */
    double a = p[A_JACK], L = p[L_IN];
    double ac = a * cos(rel), as = a * sin(rel);
    double tx[4] = { ac, -as, -ac, as };                   /* tips at rel + k pi/2 */
    double ty[4] = { as, ac, -as, -ac };
    double m = INFINITY;
    for (int k = 0; k < 4; k++) {
        double px = u + tx[k], py = v + ty[k];
        double g[4] = { L - px, L - py, L + px, L + py }; /* right, top, left, bottom */
        for (int w = 0; w < 4; w++)
            m = g[w] < m ? g[w] : m;
    }
    return m;
}

/* one classical RK4 step of q' = qd, qd' = accel(t), in place (kernel.rk4_step's tableau) */
static void rk4_step(double t, double dt, const double *p, double *q, double *qd)
{
    double a1[N_DOF], a2[N_DOF], a3[N_DOF], a4[N_DOF], v2[N_DOF], v3[N_DOF], vs[N_DOF];
    double h2 = 0.5 * dt, h6 = dt / 6.0;
    /* the positions of the stages are not needed: accel ignores them */
    accel(t, p, a1);
    for (int i = 0; i < N_DOF; i++) v2[i] = qd[i] + h2 * a1[i];
    accel(t + h2, p, a2);
    for (int i = 0; i < N_DOF; i++) v3[i] = qd[i] + h2 * a2[i];
    accel(t + h2, p, a3);
    for (int i = 0; i < N_DOF; i++) vs[i] = qd[i] + dt * a3[i];
    accel(t + dt, p, a4);
    for (int i = 0; i < N_DOF; i++) {
        q[i] = q[i] + h6 * (qd[i] + 2.0 * v2[i] + 2.0 * v3[i] + vs[i]);
        qd[i] = qd[i] + h6 * (a1[i] + 2.0 * a2[i] + 2.0 * a3[i] + a4[i]);
    }
}

static void print_array(const char *name, const double *x)
{
    printf("\"%s\": [", name);
    for (int i = 0; i < N_DOF; i++) printf("%s%.17g", i ? ", " : "", x[i]);
    printf("]");
}

int main(int argc, char **argv)
{
    if (argc != 3 + N_PARAM + 2 * N_DOF) {
        fprintf(stderr, "usage: %s N_STEPS DT p0..p%d q0..q%d qd0..qd%d\n",
                argv[0], N_PARAM - 1, N_DOF - 1, N_DOF - 1);
        return 2;
    }
    long n = strtol(argv[1], NULL, 10);
    double dt = strtod(argv[2], NULL), p[N_PARAM], q[N_DOF], qd[N_DOF];
    for (int i = 0; i < N_PARAM; i++) p[i] = strtod(argv[3 + i], NULL);
    for (int i = 0; i < N_DOF; i++) q[i] = strtod(argv[3 + N_PARAM + i], NULL);
    for (int i = 0; i < N_DOF; i++) qd[i] = strtod(argv[3 + N_PARAM + N_DOF + i], NULL);
    if (n < 1 || !(dt > 0.0)) {
        fprintf(stderr, "N_STEPS must be >= 1 and DT > 0\n");
        return 2;
    }

    struct timespec t0, t1;
    double gap = INFINITY;
    clock_gettime(CLOCK_MONOTONIC, &t0);
    for (long i = 0; i < n; i++) {
        rk4_step(i * dt, dt, p, q, qd);   /* t = i dt, as the kernel computes it */
        double g = min_gap(q, p);
        gap = g < gap ? g : gap;
    }
    clock_gettime(CLOCK_MONOTONIC, &t1);

    double s = (double)(t1.tv_sec - t0.tv_sec) + 1e-9 * (double)(t1.tv_nsec - t0.tv_nsec);
    printf("{\"steps\": %ld, \"seconds\": %.9g, \"ns_per_step\": %.6g, ", n, s, 1e9 * s / (double)n);
    print_array("q", q);
    printf(", ");
    print_array("qd", qd);
    printf(", \"min_gap\": %.17g}\n", gap);
    return 0;
}
