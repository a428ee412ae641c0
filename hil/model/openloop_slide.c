/* The host simulator's common open-loop sub-steps, compiled (issue 13): RK4 sub-steps of the
 * closed-form 2-DOF model of Reyes & Kelly (1997), Section 5, in one stick mode under the
 * recording's held commands, row after row, until the mode changes (a stuck joint breaks
 * away, a sliding one's velocity changes sign: the Python integrator locates those events).
 *
 * It is hil/model/openloop_core.py's `_rk4(_accelerations(...))` and the break-away test of its
 * `release` (`_holding_torques`), with plain Coulomb friction, no shaft torque and the
 * identity torque path, operation
 * for operation in the same order, so that it rounds exactly as the Python step does: built
 * without -ffast-math, without FMA contraction (-ffp-contract=off) and without builtins
 * (-fno-builtin: gcc would otherwise fuse sin and cos of one argument into sincos), calling the
 * C library's sin and cos as Python's math module does. hil/model/compiled_openloop.py builds
 * and loads it; tests/test_openloop_compiled.py compares it with the Python step bit for bit.
 */
#include <math.h>
#include <stddef.h>

/* p: t1 t2 t3 t4 t5 b1 b2 rot p2 p4 p5 (hil.model.openloop_core._rigid), level1 level2 (the
 * Coulomb terms of the joints' directions, Friction.level), the static bands pos1 pos2 neg1
 * neg2 (Friction.static_positive, static_negative) */
enum { LEVEL1 = 11, LEVEL2, POS1, POS2, NEG1, NEG2, N_P };

/* q'' in one stick mode (openloop_core._accelerations, its four branches) */
static void acc(const double *p, int perp, int stuck1, int stuck2, double q1, double q2,
                double v1, double v2, double tau1, double tau2, double *a1, double *a2)
{
    const double t1 = p[0], t2 = p[1], t3 = p[2], t4 = p[3], t5 = p[4], b1 = p[5], b2 = p[6];
    const double p2 = p[8], p4 = p[9], p5 = p[10];
    const double m22 = t3 + p[7];
    if (!stuck1 && !stuck2) {
        double s2 = sin(q2), c2 = cos(q2);
        double g1 = t4 * sin(q1), g12 = t5 * sin(q1 + q2);
        double k = t2 * s2;
        double m11 = t1 + 2.0 * t2 * c2;
        double m12 = t3 + t2 * c2;
        if (perp) {
            double c12 = cos(q1 + q2);
            double g1n = g1 + p4 * cos(q1), g12n = g12 + p5 * c12, kn = k + p2 * c2;
            double m11n = m11 - 2.0 * p2 * s2, m12n = m12 - p2 * s2;
            g1 = g1n; g12 = g12n; k = kn; m11 = m11n; m12 = m12n;
        }
        /* e = tau - C(q, dq) dq - g(q) - f(dq) */
        double e1 = tau1 + k * (2.0 * v1 * v2 + v2 * v2) - g1 - g12 - b1 * v1;
        e1 -= p[LEVEL1];
        double e2 = tau2 - k * v1 * v1 - g12 - b2 * v2;
        e2 -= p[LEVEL2];
        double det = m11 * m22 - m12 * m12;
        *a1 = (m22 * e1 - m12 * e2) / det;
        *a2 = (m11 * e2 - m12 * e1) / det;
    } else if (stuck1 && !stuck2) {
        /* dq1 = q1'' = 0: row 2 of M q'' = e alone */
        double k = t2 * sin(q2), g12 = t5 * sin(q1 + q2);
        if (perp) {
            double kn = k + p2 * cos(q2), g12n = g12 + p5 * cos(q1 + q2);
            k = kn; g12 = g12n;
        }
        double e2 = tau2 - k * v1 * v1 - g12 - b2 * v2;
        e2 -= p[LEVEL2];
        *a1 = 0.0;
        *a2 = e2 / m22;
    } else if (stuck2 && !stuck1) {
        /* dq2 = q2'' = 0: row 1 of M q'' = e alone */
        double s2 = sin(q2), c2 = cos(q2);
        double k = t2 * s2, g1 = t4 * sin(q1), g12 = t5 * sin(q1 + q2), m11 = t1 + 2.0 * t2 * c2;
        if (perp) {
            double kn = k + p2 * c2, g1n = g1 + p4 * cos(q1);
            double g12n = g12 + p5 * cos(q1 + q2), m11n = m11 - 2.0 * p2 * s2;
            k = kn; g1 = g1n; g12 = g12n; m11 = m11n;
        }
        double e1 = tau1 + k * (2.0 * v1 * v2 + v2 * v2) - g1 - g12 - b1 * v1;
        e1 -= p[LEVEL1];
        *a1 = e1 / m11;
        *a2 = 0.0;
    } else {
        *a1 = 0.0;
        *a2 = 0.0;
    }
}

/* Whether a stuck joint's holding torque leaves its static band, so that it breaks away
 * (openloop_core._holding_torques and the test of release() in integrate_chunks) */
static int breaks_away(const double *p, int perp, int stuck1, int stuck2, const double *x,
                       double tau1, double tau2)
{
    const double t1 = p[0], t2 = p[1], t3 = p[2], t4 = p[3], t5 = p[4], b1 = p[5], b2 = p[6];
    const double p2 = p[8], p4 = p[9], p5 = p[10];
    const double q1 = x[0], q2 = x[1], v1 = x[2], v2 = x[3];
    double s2 = sin(q2), c2 = cos(q2);
    double k = t2 * s2;
    double g1 = t4 * sin(q1), g12 = t5 * sin(q1 + q2);
    double m11 = t1 + 2.0 * t2 * c2, m12 = t3 + t2 * c2;
    if (perp) {
        double kn = k + p2 * c2, g1n = g1 + p4 * cos(q1), g12n = g12 + p5 * cos(q1 + q2);
        double m11n = m11 - 2.0 * p2 * s2, m12n = m12 - p2 * s2;
        k = kn; g1 = g1n; g12 = g12n; m11 = m11n; m12 = m12n;
    }
    double r1 = tau1 + k * (2.0 * v1 * v2 + v2 * v2) - g1 - g12;
    double r2 = tau2 - k * v1 * v1 - g12;
    double held[2];
    if (stuck1 && stuck2) {
        held[0] = r1;
        held[1] = r2;
    } else if (stuck1) {
        double f2 = b2 * v2 + p[LEVEL2];
        held[0] = r1 - m12 * (r2 - f2) / (t3 + p[7]);
        held[1] = 0.0;
    } else {
        double f1 = b1 * v1 + p[LEVEL1];
        held[0] = 0.0;
        held[1] = r2 - m12 * (r1 - f1) / m11;
    }
    const int stuck[2] = {stuck1, stuck2};
    for (int i = 0; i < 2; ++i) {
        if (!stuck[i])
            continue;
        double band = held[i] > 0 ? p[POS1 + i] : p[NEG1 + i];
        double ratio = band > 0 ? fabs(held[i]) / band : (held[i] != 0.0 ? INFINITY : 0.0);
        if (ratio > 1.0)
            return 1;
    }
    return 0;
}

/* Classical RK4 on (q, dq) with tau held (openloop_core._rk4) */
static void rk4(const double *p, int perp, int stuck1, int stuck2, const double *x,
                double tau1, double tau2, double dt, double *y)
{
    const double q1 = x[0], q2 = x[1], v1 = x[2], v2 = x[3];
    double h2 = 0.5 * dt;
    double a1, a2, b1, b2, c1, c2, d1, d2;
    acc(p, perp, stuck1, stuck2, q1, q2, v1, v2, tau1, tau2, &a1, &a2);
    double u1 = v1 + h2 * a1, u2 = v2 + h2 * a2;
    acc(p, perp, stuck1, stuck2, q1 + h2 * v1, q2 + h2 * v2, u1, u2, tau1, tau2, &b1, &b2);
    double w1 = v1 + h2 * b1, w2 = v2 + h2 * b2;
    acc(p, perp, stuck1, stuck2, q1 + h2 * u1, q2 + h2 * u2, w1, w2, tau1, tau2, &c1, &c2);
    double z1 = v1 + dt * c1, z2 = v2 + dt * c2;
    acc(p, perp, stuck1, stuck2, q1 + dt * w1, q2 + dt * w2, z1, z2, tau1, tau2, &d1, &d2);
    double k = dt / 6.0;
    y[0] = q1 + k * (v1 + 2.0 * (u1 + w1) + z1);
    y[1] = q2 + k * (v2 + 2.0 * (u2 + w2) + z2);
    y[2] = v1 + k * (a1 + 2.0 * (b1 + c1) + d1);
    y[3] = v2 + k * (a2 + 2.0 * (b2 + c2) + d2);
}

/* From the state x (q1 q2 dq1 dq2) at the start of row 0, in the stick mode (stuck1, stuck2)
 * with the sliding joints' directions dir1, dir2: rows 0..n_rows-1 of tau (n_rows x 2,
 * row-major), each row's state written to q_out, dq_out (n_rows x 2), then its n_sub sub-steps
 * of dt_seg (times stretch[row] unless stretch is NULL), each after the break-away test when
 * a joint is stuck. Stops before a row inside which the mode would change: a stuck joint
 * breaks away, or a sliding sticky joint's velocity changes sign against its direction (x is
 * then that row's start state, for the caller to take the row again with its events).
 * Returns the rows fully stepped; x is the state after them. */
long ddb_openloop_slide(const double *p, int perp, int sticky1, int sticky2, int stuck1,
                        int stuck2, double dir1, double dir2, const double *tau,
                        const double *stretch, long n_rows, int n_sub, double dt_seg,
                        double *x, double *q_out, double *dq_out)
{
    double y[4];
    double s[4] = {x[0], x[1], x[2], x[3]};
    const int watch1 = sticky1 && !stuck1, watch2 = sticky2 && !stuck2;
    const int any_stuck = stuck1 || stuck2;
    for (long k = 0; k < n_rows; ++k) {
        q_out[2 * k] = s[0];
        q_out[2 * k + 1] = s[1];
        dq_out[2 * k] = s[2];
        dq_out[2 * k + 1] = s[3];
        const double tau1 = tau[2 * k], tau2 = tau[2 * k + 1];
        const double dt = stretch == NULL ? dt_seg : dt_seg * stretch[k];
        double r[4] = {s[0], s[1], s[2], s[3]};
        for (int j = 0; j < n_sub; ++j) {
            if (any_stuck && breaks_away(p, perp, stuck1, stuck2, r, tau1, tau2))
                goto mode_changes;
            rk4(p, perp, stuck1, stuck2, r, tau1, tau2, dt, y);
            if ((watch1 && y[2] * dir1 < 0.0) || (watch2 && y[3] * dir2 < 0.0))
                goto mode_changes;
            r[0] = y[0]; r[1] = y[1]; r[2] = y[2]; r[3] = y[3];
        }
        s[0] = r[0]; s[1] = r[1]; s[2] = r[2]; s[3] = r[3];
        continue;
    mode_changes:
        x[0] = s[0]; x[1] = s[1]; x[2] = s[2]; x[3] = s[3];
        return k;
    }
    x[0] = s[0]; x[1] = s[1]; x[2] = s[2]; x[3] = s[3];
    return n_rows;
}
