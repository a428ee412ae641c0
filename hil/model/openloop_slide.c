/* The host simulator's common open-loop sub-step, compiled (issue 13): RK4 sub-steps of the
 * closed-form 2-DOF model of Reyes & Kelly (1997), Section 5, with both joints sliding under
 * the recording's held command, row after row, until a sticky joint's velocity changes sign.
 *
 * It is hil/model/openloop_core.py's `_rk4(_accelerations(...))` in the mode "both sliding"
 * (Coulomb friction levels frozen, no shaft torque) and the identity torque path, operation
 * for operation in the same order, so that it rounds exactly as the Python step does: built
 * without -ffast-math, without FMA contraction (-ffp-contract=off) and without builtins
 * (-fno-builtin: gcc would otherwise fuse sin and cos of one argument into sincos), calling the
 * C library's sin and cos as Python's math module does. hil/model/compiled_openloop.py builds
 * and loads it; tests/test_openloop_compiled.py compares it with the Python step bit for bit.
 */
#include <math.h>
#include <stddef.h>

/* p: t1 t2 t3 t4 t5 b1 b2 rot p2 p4 p5 level1 level2 (hil.model.openloop_core._rigid, then
 * the friction levels of the two sliding directions) */
static void acc(const double *p, int perp, double q1, double q2, double v1, double v2,
                double tau1, double tau2, double *a1, double *a2)
{
    const double t1 = p[0], t2 = p[1], t3 = p[2], t4 = p[3], t5 = p[4], b1 = p[5], b2 = p[6];
    const double m22 = t3 + p[7];
    double s2 = sin(q2), c2 = cos(q2);
    double g1 = t4 * sin(q1), g12 = t5 * sin(q1 + q2);
    double k = t2 * s2;
    double m11 = t1 + 2.0 * t2 * c2;
    double m12 = t3 + t2 * c2;
    if (perp) {
        const double p2 = p[8], p4 = p[9], p5 = p[10];
        double c12 = cos(q1 + q2);
        double g1n = g1 + p4 * cos(q1), g12n = g12 + p5 * c12, kn = k + p2 * c2;
        double m11n = m11 - 2.0 * p2 * s2, m12n = m12 - p2 * s2;
        g1 = g1n; g12 = g12n; k = kn; m11 = m11n; m12 = m12n;
    }
    /* e = tau - C(q, dq) dq - g(q) - f(dq) */
    double e1 = tau1 + k * (2.0 * v1 * v2 + v2 * v2) - g1 - g12 - b1 * v1;
    e1 -= p[11];
    double e2 = tau2 - k * v1 * v1 - g12 - b2 * v2;
    e2 -= p[12];
    double det = m11 * m22 - m12 * m12;
    *a1 = (m22 * e1 - m12 * e2) / det;
    *a2 = (m11 * e2 - m12 * e1) / det;
}

/* Classical RK4 on (q, dq) with tau held (openloop_core._rk4) */
static void rk4(const double *p, int perp, const double *x, double tau1, double tau2,
                double dt, double *y)
{
    const double q1 = x[0], q2 = x[1], v1 = x[2], v2 = x[3];
    double h2 = 0.5 * dt;
    double a1, a2, b1, b2, c1, c2, d1, d2;
    acc(p, perp, q1, q2, v1, v2, tau1, tau2, &a1, &a2);
    double u1 = v1 + h2 * a1, u2 = v2 + h2 * a2;
    acc(p, perp, q1 + h2 * v1, q2 + h2 * v2, u1, u2, tau1, tau2, &b1, &b2);
    double w1 = v1 + h2 * b1, w2 = v2 + h2 * b2;
    acc(p, perp, q1 + h2 * u1, q2 + h2 * u2, w1, w2, tau1, tau2, &c1, &c2);
    double z1 = v1 + dt * c1, z2 = v2 + dt * c2;
    acc(p, perp, q1 + dt * w1, q2 + dt * w2, z1, z2, tau1, tau2, &d1, &d2);
    double k = dt / 6.0;
    y[0] = q1 + k * (v1 + 2.0 * (u1 + w1) + z1);
    y[1] = q2 + k * (v2 + 2.0 * (u2 + w2) + z2);
    y[2] = v1 + k * (a1 + 2.0 * (b1 + c1) + d1);
    y[3] = v2 + k * (a2 + 2.0 * (b2 + c2) + d2);
}

/* From the state x (q1 q2 dq1 dq2) at the start of row 0, rows 0..n_rows-1 of tau (n_rows x 2,
 * row-major): each row's state written to q_out, dq_out (n_rows x 2), then its n_sub sub-steps
 * of dt_seg (times stretch[row] unless stretch is NULL). Stops before a row inside which a
 * sticky joint's velocity changes sign against its direction (x is then that row's start
 * state, the row's outputs written, for the caller to take the row again with its event
 * location). Returns the rows fully stepped; x is the state after them. */
long ddb_openloop_slide(const double *p, int perp, int sticky1, int sticky2, double dir1,
                        double dir2, const double *tau, const double *stretch, long n_rows,
                        int n_sub, double dt_seg, double *x, double *q_out, double *dq_out)
{
    double y[4];
    double s[4] = {x[0], x[1], x[2], x[3]};
    for (long k = 0; k < n_rows; ++k) {
        q_out[2 * k] = s[0];
        q_out[2 * k + 1] = s[1];
        dq_out[2 * k] = s[2];
        dq_out[2 * k + 1] = s[3];
        const double tau1 = tau[2 * k], tau2 = tau[2 * k + 1];
        const double dt = stretch == NULL ? dt_seg : dt_seg * stretch[k];
        double r[4] = {s[0], s[1], s[2], s[3]};
        for (int j = 0; j < n_sub; ++j) {
            rk4(p, perp, r, tau1, tau2, dt, y);
            if ((sticky1 && y[2] * dir1 < 0.0) || (sticky2 && y[3] * dir2 < 0.0)) {
                x[0] = s[0]; x[1] = s[1]; x[2] = s[2]; x[3] = s[3];
                return k;
            }
            r[0] = y[0]; r[1] = y[1]; r[2] = y[2]; r[3] = y[3];
        }
        s[0] = r[0]; s[1] = r[1]; s[2] = r[2]; s[3] = r[3];
    }
    x[0] = s[0]; x[1] = s[1]; x[2] = s[2]; x[3] = s[3];
    return n_rows;
}
