/* Native kernels of the static update (thesis §2.3) and of the ECM M-step, optional.
 *
 * kms2pin.virtual_work builds the virtual-work equilibrium on Pinocchio's joint
 * Jacobians; its per-iteration arithmetic (maximal coordinates -> springs ->
 * B = d q_max / d q -> B^T Q and the Newton matrix) is a few hundred flops on
 * 15 bodies, so from NumPy it is dominated by call overhead.  This module does
 * the same arithmetic in one C call.  It mirrors, line for line, the NumPy code
 * in virtual_work._Evaluator (which stays the fallback when no compiler was
 * available at install time); the tests check both against the SymPy reference.
 *
 * Layout: body coordinates X and targets T are (n, 7) [px, py, pz, x, y, z, w]
 * (Pinocchio's XYZQUAT order), J is Pinocchio's data.J (6 x nv, world frame:
 * rows 0-2 the velocity of the point at the origin, rows 3-5 omega).
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <string.h>

typedef struct {
    Py_buffer view;
    int held;
} Buf;

static int get_buf(PyObject *obj, Buf *b, int writable, const char *name)
{
    int flags = PyBUF_STRIDES | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(obj, &b->view, flags) < 0) {
        return -1;
    }
    b->held = 1;
    if (b->view.itemsize != 8 || b->view.format == NULL || strcmp(b->view.format, "d") != 0) {
        PyErr_Format(PyExc_TypeError, "%s must be a float64 array", name);
        return -1;
    }
    return 0;
}

static void release(Buf *bufs, int n)
{
    for (int i = 0; i < n; i++) {
        if (bufs[i].held) {
            PyBuffer_Release(&bufs[i].view);
            bufs[i].held = 0;
        }
    }
}

/* element (r, c) of a 2-D strided float64 buffer */
#define AT(b, r, c) (*(double *)((char *)(b).view.buf + (r) * (b).view.strides[0] + (c) * (b).view.strides[1]))

static int check_2d(const Buf *b, Py_ssize_t rows, Py_ssize_t cols, const char *name)
{
    if (b->view.ndim != 2 || (rows >= 0 && b->view.shape[0] != rows) || (cols >= 0 && b->view.shape[1] != cols)) {
        PyErr_Format(PyExc_ValueError, "%s has the wrong shape", name);
        return -1;
    }
    return 0;
}

static inline void cross(const double *a, const double *b, double *out)
{
    out[0] = a[1] * b[2] - a[2] * b[1];
    out[1] = a[2] * b[0] - a[0] * b[2];
    out[2] = a[0] * b[1] - a[1] * b[0];
}

static inline double dot3(const double *a, const double *b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

/* linearize(J, X, T, K, S, same_joint, grad_out, H_out, diff_out, hessian)
 *     -> (energy, ||grad||^2, max diag H)
 *
 * diff = X - T with each target's Euler parameters on the primary's side
 * (§2.2.1); rho = K * diff = -F (eq. 2.33); energy = 1/2 rho . diff;
 * grad = B^T rho = -B^T Q (eq. 2.28); H = B^T K B (+ the second-order term
 * sum_i rho_i . d^2 q_max,i / dq_a dq_b if hessian).  S (n, nv) is 1 where
 * velocity column a moves body i; same_joint (nv, nv) is 1 where two columns
 * belong to one joint (their second-order block is symmetrized).
 */
static PyObject *linearize(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 10) {
        PyErr_SetString(PyExc_TypeError, "linearize takes 10 arguments");
        return NULL;
    }
    Buf b[9];
    memset(b, 0, sizeof(b));
    static const char *names[9] = {"J", "X", "T", "K", "S", "same_joint", "grad", "H", "diff"};
    for (int i = 0; i < 9; i++) {
        if (get_buf(args[i], &b[i], i >= 6, names[i]) < 0) {
            release(b, 9);
            return NULL;
        }
    }
    int hessian = PyObject_IsTrue(args[9]);
    Buf J = b[0], X = b[1], T = b[2], K = b[3], S = b[4], SJ = b[5], G = b[6], H = b[7], D = b[8];
    Py_ssize_t n = X.view.ndim == 2 ? X.view.shape[0] : -1;
    Py_ssize_t nv = J.view.ndim == 2 ? J.view.shape[1] : -1;
    if (hessian < 0 || check_2d(&J, 6, -1, "J") || check_2d(&X, -1, 7, "X") || check_2d(&T, n, 7, "T") ||
        check_2d(&K, n, 7, "K") || check_2d(&S, n, nv, "S") || check_2d(&SJ, nv, nv, "same_joint") ||
        check_2d(&H, nv, nv, "H") || check_2d(&D, n, 7, "diff") || G.view.ndim != 1 || G.view.shape[0] != nv) {
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "grad has the wrong shape");
        release(b, 9);
        return NULL;
    }
    double *grad = (double *)G.view.buf;
    Py_ssize_t gs = G.view.strides[0] / 8;
    for (Py_ssize_t a = 0; a < nv; a++) {
        grad[a * gs] = 0.0;
        for (Py_ssize_t c = 0; c < nv; c++) AT(H, a, c) = 0.0;
    }
    /* per-body columns of B (7 x nv) and, for the second-order term, omega and Y */
    double *B = (double *)PyMem_Malloc(sizeof(double) * (size_t)(7 * nv + 3 * nv + 3 * nv + 1));
    if (B == NULL) {
        release(b, 9);
        return PyErr_NoMemory();
    }
    double *W = B + 7 * nv; /* omega columns, 3 x nv */
    double *Y = W + 3 * nv; /* Y columns, 3 x nv */
    double energy = 0.0;
    for (Py_ssize_t i = 0; i < n; i++) {
        double x[7], t[7], k[7], diff[7], rho[7];
        for (int c = 0; c < 7; c++) {
            x[c] = AT(X, i, c);
            t[c] = AT(T, i, c);
            k[c] = AT(K, i, c);
        }
        double align = t[3] * x[3] + t[4] * x[4] + t[5] * x[5] + t[6] * x[6];
        for (int c = 0; c < 7; c++) diff[c] = x[c] - t[c];
        if (align < 0) {
            for (int c = 3; c < 7; c++) diff[c] = x[c] + t[c];
        }
        int any_k = 0;
        for (int c = 0; c < 7; c++) {
            rho[c] = k[c] * diff[c];
            energy += 0.5 * rho[c] * diff[c];
            AT(D, i, c) = diff[c];
            any_k |= k[c] != 0.0;
        }
        if (!any_k) continue;
        const double *p = x, *v = x + 3;
        double w = x[6];
        /* g = E(theta)^T rho_theta with E = [w I - [v]x; -v^T] (d theta = 1/2 E omega) */
        double rv[3] = {rho[3], rho[4], rho[5]}, vxr[3], g[3];
        cross(v, rv, vxr);
        for (int c = 0; c < 3; c++) g[c] = w * rv[c] + vxr[c] - rho[6] * v[c];
        double cth = rv[0] * v[0] + rv[1] * v[1] + rv[2] * v[2] + rho[6] * w;
        double rmu[3] = {rho[0], rho[1], rho[2]};
        for (Py_ssize_t a = 0; a < nv; a++) {
            double *col = B + 7 * a;
            double *om = W + 3 * a;
            if (AT(S, i, a) == 0.0) {
                memset(col, 0, 7 * sizeof(double));
                om[0] = om[1] = om[2] = 0.0;
                continue;
            }
            double v0[3] = {AT(J, 0, a), AT(J, 1, a), AT(J, 2, a)};
            om[0] = AT(J, 3, a);
            om[1] = AT(J, 4, a);
            om[2] = AT(J, 5, a);
            double oxp[3], oxv[3];
            cross(om, p, oxp);
            cross(om, v, oxv);
            for (int c = 0; c < 3; c++) col[c] = v0[c] + oxp[c];              /* v(p) = v0 + omega x p */
            for (int c = 0; c < 3; c++) col[3 + c] = 0.5 * (w * om[c] + oxv[c]); /* 1/2 [0, omega] (x) theta */
            col[6] = -0.5 * dot3(om, v);
            double ga = 0.0;
            for (int c = 0; c < 7; c++) ga += rho[c] * col[c];
            grad[a * gs] += ga;
            if (hessian) {
                /* Y_b = J_lin,b x rho_mu + 1/4 (omega_b x g - c omega_b) */
                double t1[3], t2[3];
                cross(col, rmu, t1);
                cross(om, g, t2);
                for (int c = 0; c < 3; c++) Y[3 * a + c] = t1[c] + 0.25 * (t2[c] - cth * om[c]);
            }
        }
        for (Py_ssize_t a = 0; a < nv; a++) {
            if (AT(S, i, a) == 0.0) continue;
            const double *ca = B + 7 * a;
            for (Py_ssize_t c = a; c < nv; c++) {
                if (AT(S, i, c) == 0.0) continue;
                const double *cc = B + 7 * c;
                double s = 0.0;
                for (int r = 0; r < 7; r++) s += k[r] * ca[r] * cc[r];
                AT(H, a, c) += s;
            }
        }
        if (hessian) {
            /* A[a, b] = omega_a . Y_b; the upper triangle pairs an ancestor column a with a
             * descendant b; within one joint the block is symmetrized (stored in H's lower
             * triangle until the end). */
            for (Py_ssize_t a = 0; a < nv; a++) {
                if (AT(S, i, a) == 0.0) continue;
                const double *oa = W + 3 * a;
                for (Py_ssize_t c = 0; c < nv; c++) {
                    if (AT(S, i, c) == 0.0) continue;
                    if (c < a && AT(SJ, a, c) == 0.0) continue;
                    double s = dot3(oa, Y + 3 * c);
                    if (AT(SJ, a, c) != 0.0) {
                        if (c == a) {
                            AT(H, a, a) += s;
                        } else if (c > a) {
                            AT(H, a, c) += 0.5 * s;
                        } else {
                            AT(H, c, a) += 0.5 * s; /* A[a, c] with a > c: the transpose half */
                        }
                    } else {
                        AT(H, a, c) += s;
                    }
                }
            }
        }
    }
    double gsq = 0.0, hmax = 0.0;
    for (Py_ssize_t a = 0; a < nv; a++) {
        for (Py_ssize_t c = 0; c < a; c++) AT(H, a, c) = AT(H, c, a);
        gsq += grad[a * gs] * grad[a * gs];
        if (a == 0 || AT(H, a, a) > hmax) hmax = AT(H, a, a);
    }
    PyMem_Free(B);
    release(b, 9);
    return Py_BuildValue("(ddd)", energy, gsq, hmax);
}

/* frame_coordinates(rows, joints, offsets, out): body frames from joint placements.
 * rows[j] is joint j's world placement as [x, y, z, qx, qy, qz, qw] (Pinocchio's
 * SE3ToXYZQUAT of data.oMi[j]); body i sits at the fixed placement offsets[i] (same
 * layout) in joint joints[i]'s frame; out[i] = rows[joints[i]] * offsets[i]. */
static PyObject *frame_coordinates(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 4 || !PyList_Check(args[0])) {
        PyErr_SetString(PyExc_TypeError, "frame_coordinates(list, joints, offsets, out)");
        return NULL;
    }
    Buf b[3];
    memset(b, 0, sizeof(b));
    if (get_buf(args[1], &b[0], 0, "joints") < 0 || get_buf(args[2], &b[1], 0, "offsets") < 0 ||
        get_buf(args[3], &b[2], 1, "out") < 0) {
        release(b, 3);
        return NULL;
    }
    Py_ssize_t n = b[2].view.ndim == 2 ? b[2].view.shape[0] : -1;
    Py_ssize_t nrows = PyList_GET_SIZE(args[0]);
    if (check_2d(&b[2], n, 7, "out") || check_2d(&b[1], n, 7, "offsets") || b[0].view.ndim != 1 ||
        b[0].view.shape[0] != n) {
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "joints must have one entry per body");
        release(b, 3);
        return NULL;
    }
    for (Py_ssize_t i = 0; i < n; i++) {
        Py_ssize_t j = (Py_ssize_t)(*(double *)((char *)b[0].view.buf + i * b[0].view.strides[0]));
        if (j < 0 || j >= nrows) {
            PyErr_SetString(PyExc_IndexError, "joint index out of range");
            release(b, 3);
            return NULL;
        }
        Buf row;
        memset(&row, 0, sizeof(row));
        if (get_buf(PyList_GET_ITEM(args[0], j), &row, 0, "row") < 0 || row.view.ndim != 1 || row.view.shape[0] != 7) {
            if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "rows must be 7-vectors");
            release(&row, 1);
            release(b, 3);
            return NULL;
        }
        double a[7], o[7];
        for (int c = 0; c < 7; c++) {
            a[c] = *(double *)((char *)row.view.buf + c * row.view.strides[0]);
            o[c] = AT(b[1], i, c);
        }
        release(&row, 1);
        const double *av = a + 3, *ov = o + 3;
        double aw = a[6], ow = o[6];
        /* position: t_a + R(a) c = t_a + c + 2 w (v x c) + 2 v x (v x c) */
        double vxc[3], vxvxc[3];
        cross(av, o, vxc);
        cross(av, vxc, vxvxc);
        for (int c = 0; c < 3; c++) AT(b[2], i, c) = a[c] + o[c] + 2.0 * (aw * vxc[c] + vxvxc[c]);
        /* orientation: a (x) o */
        double axo[3];
        cross(av, ov, axo);
        for (int c = 0; c < 3; c++) AT(b[2], i, 3 + c) = aw * ov[c] + ow * av[c] + axo[c];
        AT(b[2], i, 6) = aw * ow - dot3(av, ov);
    }
    release(b, 3);
    Py_RETURN_NONE;
}

static PyMethodDef methods[] = {
    {"linearize", (PyCFunction)(void (*)(void))linearize, METH_FASTCALL,
     "linearize(J, X, T, K, S, same_joint, grad, H, diff, hessian) -> (energy, |grad|^2, max diag H)"},
    {"frame_coordinates", (PyCFunction)(void (*)(void))frame_coordinates, METH_FASTCALL,
     "frame_coordinates(rows, joints, offsets, out): out[i] = rows[joints[i]] * offsets[i] (XYZQUAT)"},
    {"ellipsoid_a2", (PyCFunction)(void (*)(void))ellipsoid_a2, METH_FASTCALL,
     "ellipsoid_a2(dirs, A, e, out): closest approach a^2 of every ray to the ellipsoid"},
    {"silhouette_fit", (PyCFunction)(void (*)(void))silhouette_fit, METH_FASTCALL,
     "silhouette_fit(dirs, A, e, inv, y, o, weight, jac, H, grad) -> (cost, evidence)"},
    {"estep_body", (PyCFunction)(void (*)(void))estep_body, METH_FASTCALL,
     "estep_body(dirs, A, e, inv, log_free, v0, u0, rows, cols, sp, log_free_o, widen)"},
    {"estep_view", (PyCFunction)(void (*)(void))estep_view, METH_FASTCALL,
     "estep_view(log_free, mask, v0, u0, rows, cols, sp, o, y)"},
    {"fit_body", (PyCFunction)(void (*)(void))fit_body, METH_FASTCALL,
     "fit_body(views, R, t, inner, iterations, damping, max_step, R_out, t_out, H_out) -> (evidence, cost)"},
    {"pose_springs", (PyCFunction)(void (*)(void))pose_springs, METH_FASTCALL,
     "pose_springs(J, X, T, K, S, A, g): the tracker's full-spring static update system"},
    {"solve_shifted", (PyCFunction)(void (*)(void))solve_shifted, METH_FASTCALL,
     "solve_shifted(H, grad, shift, step) -> bool: (H + shift I) step = -grad by Cholesky"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_kernels", "Native kernels of the static update and the ECM M-step.", -1, methods, NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__kernels(void) { return PyModule_Create(&module); }
