/* Native kernels of the static update (thesis §2.3) and of the ECM M-step, optional.
 *
 * kms2pin.virtual_work builds the virtual-work equilibrium on Pinocchio's joint
 * Jacobians; its per-iteration arithmetic (maximal coordinates -> springs ->
 * B = d q_max / d q -> B^T Q and the Newton matrix) is a few hundred flops on
 * 15 bodies, so from NumPy it is dominated by call overhead.  This module does
 * the same arithmetic in one C call.  Each function has a NumPy twin of the same
 * name in kms2pin/_numpy_kernels.py (the fallback when no compiler was available
 * at install time; kms2pin.native chooses); the tests check the two against each
 * other and the static update against the SymPy reference.
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
    char *hb = (char *)H.view.buf;
    Py_ssize_t h0 = H.view.strides[0], h1 = H.view.strides[1];
#define HH(r, c) (*(double *)(hb + (r) * h0 + (c) * h1))
    for (Py_ssize_t a = 0; a < nv; a++) {
        grad[a * gs] = 0.0;
        for (Py_ssize_t c = 0; c < nv; c++) HH(a, c) = 0.0;
    }
    /* per-body columns of B (7 x nv), k-weighted B, omega and Y (the second-order term),
     * and the columns that move the body (S != 0) */
    double *B = (double *)PyMem_Malloc(sizeof(double) * (size_t)(7 * nv + 7 * nv + 3 * nv + 3 * nv + 1));
    Py_ssize_t *cols = (Py_ssize_t *)PyMem_Malloc(sizeof(Py_ssize_t) * (size_t)(nv + 1));
    if (B == NULL || cols == NULL) {
        PyMem_Free(B);
        PyMem_Free(cols);
        release(b, 9);
        return PyErr_NoMemory();
    }
    double *KB = B + 7 * nv; /* k * B columns */
    double *W = KB + 7 * nv; /* omega columns, 3 x nv */
    double *Y = W + 3 * nv;  /* Y columns, 3 x nv */
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
        Py_ssize_t m = 0;
        for (Py_ssize_t a = 0; a < nv; a++)
            if (AT(S, i, a) != 0.0) cols[m++] = a;
        const double *p = x, *v = x + 3;
        double w = x[6];
        /* g = E(theta)^T rho_theta with E = [w I - [v]x; -v^T] (d theta = 1/2 E omega) */
        double rv[3] = {rho[3], rho[4], rho[5]}, vxr[3], g[3];
        cross(v, rv, vxr);
        for (int c = 0; c < 3; c++) g[c] = w * rv[c] + vxr[c] - rho[6] * v[c];
        double cth = rv[0] * v[0] + rv[1] * v[1] + rv[2] * v[2] + rho[6] * w;
        double rmu[3] = {rho[0], rho[1], rho[2]};
        for (Py_ssize_t ia = 0; ia < m; ia++) {
            Py_ssize_t a = cols[ia];
            double *col = B + 7 * ia, *kcol = KB + 7 * ia;
            double *om = W + 3 * ia;
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
            for (int c = 0; c < 7; c++) {
                ga += rho[c] * col[c];
                kcol[c] = k[c] * col[c];
            }
            grad[a * gs] += ga;
            if (hessian) {
                /* Y_b = J_lin,b x rho_mu + 1/4 (omega_b x g - c omega_b) */
                double t1[3], t2[3];
                cross(col, rmu, t1);
                cross(om, g, t2);
                for (int c = 0; c < 3; c++) Y[3 * ia + c] = t1[c] + 0.25 * (t2[c] - cth * om[c]);
            }
        }
        for (Py_ssize_t ia = 0; ia < m; ia++) {
            const double *ka = KB + 7 * ia;
            Py_ssize_t a = cols[ia];
            for (Py_ssize_t ic = ia; ic < m; ic++) {
                const double *cc = B + 7 * ic;
                double s = 0.0;
                for (int r = 0; r < 7; r++) s += ka[r] * cc[r];
                HH(a, cols[ic]) += s;
            }
        }
        if (hessian) {
            /* A[a, b] = omega_a . Y_b; the upper triangle pairs an ancestor column a with a
             * descendant b; within one joint the block is symmetrized (stored in H's lower
             * triangle until the end). */
            for (Py_ssize_t ia = 0; ia < m; ia++) {
                Py_ssize_t a = cols[ia];
                const double *oa = W + 3 * ia;
                for (Py_ssize_t ic = 0; ic < m; ic++) {
                    Py_ssize_t c = cols[ic];
                    int same = AT(SJ, a, c) != 0.0;
                    if (c < a && !same) continue;
                    double s = dot3(oa, Y + 3 * ic);
                    if (same) {
                        if (c == a) {
                            HH(a, a) += s;
                        } else if (c > a) {
                            HH(a, c) += 0.5 * s;
                        } else {
                            HH(c, a) += 0.5 * s; /* A[a, c] with a > c: the transpose half */
                        }
                    } else {
                        HH(a, c) += s;
                    }
                }
            }
        }
    }
    double gsq = 0.0, hmax = 0.0;
    for (Py_ssize_t a = 0; a < nv; a++) {
        for (Py_ssize_t c = 0; c < a; c++) HH(a, c) = HH(c, a);
        gsq += grad[a * gs] * grad[a * gs];
        if (a == 0 || HH(a, a) > hmax) hmax = HH(a, a);
    }
#undef HH
    PyMem_Free(B);
    PyMem_Free(cols);
    release(b, 9);
    return Py_BuildValue("(ddd)", energy, gsq, hmax);
}

/* a 7-vector row, a tuple of 7 floats (Pinocchio's SE3ToXYZQUATtuple) or a float64 array */
static int read_row(PyObject *obj, double *a)
{
    if (PyTuple_Check(obj)) {
        if (PyTuple_GET_SIZE(obj) != 7) {
            PyErr_SetString(PyExc_ValueError, "rows must be 7-vectors");
            return -1;
        }
        for (int c = 0; c < 7; c++) {
            a[c] = PyFloat_AsDouble(PyTuple_GET_ITEM(obj, c));
            if (a[c] == -1.0 && PyErr_Occurred()) return -1;
        }
        return 0;
    }
    Buf row;
    memset(&row, 0, sizeof(row));
    if (get_buf(obj, &row, 0, "row") < 0 || row.view.ndim != 1 || row.view.shape[0] != 7) {
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "rows must be 7-vectors");
        release(&row, 1);
        return -1;
    }
    for (int c = 0; c < 7; c++) a[c] = *(double *)((char *)row.view.buf + c * row.view.strides[0]);
    release(&row, 1);
    return 0;
}

/* frame_coordinates(rows, joints, offsets, out): body frames from joint placements.
 * rows[j] is joint j's world placement as [x, y, z, qx, qy, qz, qw] (Pinocchio's
 * SE3ToXYZQUAT or SE3ToXYZQUATtuple of data.oMi[j]); body i sits at the fixed placement offsets[i] (same
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
        double a[7], o[7];
        if (read_row(PyList_GET_ITEM(args[0], j), a) < 0) {
            release(b, 3);
            return NULL;
        }
        for (int c = 0; c < 7; c++) o[c] = AT(b[1], i, c);
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

/* closure_terms(J, X, moving, kind, end, vec, row, coef, order, r, Jc, H, what)
 *
 * Loop closures (kms2pin/closures.py) written as dot-product terms: term t adds
 * coef[t] x_t . y_t to row row[t].  Side s of a term, kind[t, s]: 0 the constant
 * vec[t, 3s..3s+2], 1 that vector fixed in end e = end[t, s] (R_e v), 2 end e's
 * origin p_e.  X (E, 7) the ends' XYZQUAT placements, moving (E, nv) 1 where
 * column a moves end e.  Sets r; with what >= 1 the Jacobian Jc (rows, nv) in the
 * tangent space (a vector's column b: omega_b x x; a point's: v_b + omega_b x p);
 * with what >= 2 each row's curvature H[r] = d^2 r_r / dq^2 (rows, nv, nv; C
 * order), with d^2 x / dq_a dq_b =
 * omega_a x (dx/dq_b) weighted by order[a, b] (1: a before b on the chain, 1/2
 * within one joint) and symmetrized, plus the product terms dx . dy.
 */
static void closure_side(int kind, const double *R, const double *p, const double *v, const double *Wm,
                         const double *Pm, Py_ssize_t nv, int jac, double *x, double *Xj)
{
    if (kind == 0) {
        for (int c = 0; c < 3; c++) x[c] = v[c];
    } else if (kind == 1) {
        for (int c = 0; c < 3; c++) x[c] = R[3 * c] * v[0] + R[3 * c + 1] * v[1] + R[3 * c + 2] * v[2];
    } else {
        for (int c = 0; c < 3; c++) x[c] = p[c];
    }
    if (!jac) return;
    for (Py_ssize_t b = 0; b < nv; b++) {
        if (kind == 0) {
            Xj[b] = Xj[nv + b] = Xj[2 * nv + b] = 0.0;
        } else if (kind == 1) {
            const double w[3] = {Wm[b], Wm[nv + b], Wm[2 * nv + b]};
            double o[3];
            cross(w, x, o);
            Xj[b] = o[0], Xj[nv + b] = o[1], Xj[2 * nv + b] = o[2];
        } else {
            Xj[b] = Pm[b], Xj[nv + b] = Pm[nv + b], Xj[2 * nv + b] = Pm[2 * nv + b];
        }
    }
}

/* M[a, b] += order[a, b] omega_a . (X_b x f) over the columns a, b that move the end (cols) */
static void closure_curve(const double *Wm, const double *Xj, const double *f, const Buf *order, Py_ssize_t nv,
                          const Py_ssize_t *cols, Py_ssize_t ncols, double *M)
{
    for (Py_ssize_t j = 0; j < ncols; j++) {
        Py_ssize_t b = cols[j];
        const double xb[3] = {Xj[b], Xj[nv + b], Xj[2 * nv + b]};
        double c[3];
        cross(xb, f, c);
        for (Py_ssize_t i = 0; i < ncols; i++) {
            Py_ssize_t a = cols[i];
            double o = AT(*order, a, b);
            if (o != 0.0) M[a * nv + b] += o * (Wm[a] * c[0] + Wm[nv + a] * c[1] + Wm[2 * nv + a] * c[2]);
        }
    }
}

static PyObject *closure_terms(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 13) {
        PyErr_SetString(PyExc_TypeError, "closure_terms takes 13 arguments");
        return NULL;
    }
    Buf b[12];
    memset(b, 0, sizeof(b));
    static const char *names[12] = {"J", "X", "moving", "kind", "end", "vec", "row", "coef", "order", "r", "Jc", "H"};
    for (int i = 0; i < 12; i++) {
        if (get_buf(args[i], &b[i], i >= 9, names[i]) < 0) {
            release(b, 12);
            return NULL;
        }
    }
    long what = PyLong_AsLong(args[12]);
    Buf J = b[0], X = b[1], MV = b[2], KD = b[3], EN = b[4], VC = b[5], RW = b[6], CF = b[7], OR = b[8],
        R_ = b[9], JC = b[10], H = b[11];
    Py_ssize_t E = X.view.ndim == 2 ? X.view.shape[0] : -1;
    Py_ssize_t nv = J.view.ndim == 2 ? J.view.shape[1] : -1;
    Py_ssize_t T = RW.view.ndim == 1 ? RW.view.shape[0] : -1;
    Py_ssize_t rows = R_.view.ndim == 1 ? R_.view.shape[0] : -1;
    if ((what == -1 && PyErr_Occurred()) || check_2d(&J, 6, -1, "J") || check_2d(&X, -1, 7, "X") ||
        check_2d(&MV, E, nv, "moving") || check_2d(&KD, T, 2, "kind") || check_2d(&EN, T, 2, "end") ||
        check_2d(&VC, T, 6, "vec") || T < 0 || CF.view.ndim != 1 || CF.view.shape[0] != T || rows < 0 ||
        (what >= 1 && check_2d(&JC, rows, nv, "Jc")) || (what >= 2 && check_2d(&OR, nv, nv, "order")) ||
        (what >= 2 && (H.view.ndim != 3 || H.view.shape[0] != rows || H.view.shape[1] != nv ||
                       H.view.shape[2] != nv || !PyBuffer_IsContiguous(&H.view, 'C')))) {
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "closure_terms: wrong shapes (H: C-contiguous)");
        release(b, 12);
        return NULL;
    }
#define V1(bb, i) (*(double *)((char *)(bb).view.buf + (i) * (bb).view.strides[0]))
    for (Py_ssize_t t = 0; t < T; t++) {
        Py_ssize_t row = (Py_ssize_t)V1(RW, t), e0 = (Py_ssize_t)AT(EN, t, 0), e1 = (Py_ssize_t)AT(EN, t, 1);
        if (row < 0 || row >= rows || e0 < 0 || e0 >= E || e1 < 0 || e1 >= E) {
            PyErr_SetString(PyExc_IndexError, "closure_terms: row or end out of range");
            release(b, 12);
            return NULL;
        }
    }
    /* per end: R (row-major), p, and the masked omega and point-velocity columns */
    size_t need = (size_t)E * (12 + 6 * (size_t)nv) + 6 * (size_t)nv;
    double *buf = (double *)PyMem_Calloc(need ? need : 1, sizeof(double));
    Py_ssize_t *cols = (Py_ssize_t *)PyMem_Calloc((size_t)(E * nv + E) + 1, sizeof(Py_ssize_t));
    if (buf == NULL || cols == NULL) {
        PyMem_Free(buf);
        PyMem_Free(cols);
        release(b, 12);
        return PyErr_NoMemory();
    }
    Py_ssize_t *ncols = cols + E * nv; /* end e's moving columns: cols[e * nv .. e * nv + ncols[e]) */
    double *Rp = buf, *Wm = buf + 12 * E, *Pm = Wm + 3 * nv * E, *X0 = Pm + 3 * nv * E, *Y1 = X0 + 3 * nv;
    double *Hall = what >= 2 ? (double *)H.view.buf : NULL; /* each row's M, then H = M + M^T */
    if (Hall != NULL) memset(Hall, 0, sizeof(double) * (size_t)(rows * nv * nv));
    for (Py_ssize_t e = 0; e < E; e++) {
        double x = AT(X, e, 3), y = AT(X, e, 4), z = AT(X, e, 5), w = AT(X, e, 6);
        double *R = Rp + 12 * e, *p = R + 9;
        R[0] = 1 - 2 * (y * y + z * z), R[1] = 2 * (x * y - z * w), R[2] = 2 * (x * z + y * w);
        R[3] = 2 * (x * y + z * w), R[4] = 1 - 2 * (x * x + z * z), R[5] = 2 * (y * z - x * w);
        R[6] = 2 * (x * z - y * w), R[7] = 2 * (y * z + x * w), R[8] = 1 - 2 * (x * x + y * y);
        for (int c = 0; c < 3; c++) p[c] = AT(X, e, c);
        if (what < 1) continue;
        double *W = Wm + 3 * nv * e, *P = Pm + 3 * nv * e;
        for (Py_ssize_t a = 0; a < nv; a++) {
            double m = AT(MV, e, a);
            if (m == 0.0) continue;
            cols[e * nv + ncols[e]++] = a;
            const double om[3] = {AT(J, 3, a), AT(J, 4, a), AT(J, 5, a)};
            double oxp[3];
            cross(om, p, oxp);
            for (int c = 0; c < 3; c++) {
                W[c * nv + a] = m * om[c];
                P[c * nv + a] = m * (AT(J, c, a) + oxp[c]);
            }
        }
    }
    for (Py_ssize_t i = 0; i < rows; i++) {
        V1(R_, i) = 0.0;
        for (Py_ssize_t a = 0; what >= 1 && a < nv; a++) AT(JC, i, a) = 0.0;
    }
    for (Py_ssize_t t = 0; t < T; t++) {
        Py_ssize_t row = (Py_ssize_t)V1(RW, t), e0 = (Py_ssize_t)AT(EN, t, 0), e1 = (Py_ssize_t)AT(EN, t, 1);
        int k0 = (int)AT(KD, t, 0), k1 = (int)AT(KD, t, 1);
        double v0[3] = {AT(VC, t, 0), AT(VC, t, 1), AT(VC, t, 2)}, v1[3] = {AT(VC, t, 3), AT(VC, t, 4), AT(VC, t, 5)};
        double x[3], y[3], coef = V1(CF, t);
        closure_side(k0, Rp + 12 * e0, Rp + 12 * e0 + 9, v0, Wm + 3 * nv * e0, Pm + 3 * nv * e0, nv, what >= 1, x, X0);
        closure_side(k1, Rp + 12 * e1, Rp + 12 * e1 + 9, v1, Wm + 3 * nv * e1, Pm + 3 * nv * e1, nv, what >= 1, y, Y1);
        V1(R_, row) += coef * dot3(x, y);
        if (what < 1) continue;
        for (Py_ssize_t a = 0; a < nv; a++)
            AT(JC, row, a) += coef * (y[0] * X0[a] + y[1] * X0[nv + a] + y[2] * X0[2 * nv + a] + x[0] * Y1[a] +
                                      x[1] * Y1[nv + a] + x[2] * Y1[2 * nv + a]);
        double wt = what >= 2 ? coef : 0.0;
        if (wt == 0.0) continue;
        double *M = Hall + row * nv * nv;
        const double fy[3] = {wt * y[0], wt * y[1], wt * y[2]}, fx[3] = {wt * x[0], wt * x[1], wt * x[2]};
        const Py_ssize_t *c0 = cols + e0 * nv, *c1 = cols + e1 * nv;
        if (k0 > 0) closure_curve(Wm + 3 * nv * e0, X0, fy, &OR, nv, c0, ncols[e0], M);
        if (k1 > 0) closure_curve(Wm + 3 * nv * e1, Y1, fx, &OR, nv, c1, ncols[e1], M);
        if (k0 == 0 || k1 == 0) continue;
        for (Py_ssize_t i = 0; i < ncols[e0]; i++)
            for (Py_ssize_t j = 0; j < ncols[e1]; j++) {
                Py_ssize_t a = c0[i], c = c1[j];
                double prod = X0[a] * Y1[c] + X0[nv + a] * Y1[nv + c] + X0[2 * nv + a] * Y1[2 * nv + c];
                M[a * nv + c] += 0.5 * wt * prod;
                M[c * nv + a] += 0.5 * wt * prod;
            }
    }
    for (Py_ssize_t i = 0; Hall != NULL && i < rows; i++) {
        double *M = Hall + i * nv * nv;
        for (Py_ssize_t a = 0; a < nv; a++)
            for (Py_ssize_t c = 0; c < a; c++) M[a * nv + c] = M[c * nv + a] = M[a * nv + c] + M[c * nv + a];
        for (Py_ssize_t a = 0; a < nv; a++) M[a * nv + a] *= 2.0;
    }
#undef V1
    PyMem_Free(buf);
    PyMem_Free(cols);
    release(b, 12);
    Py_RETURN_NONE;
}

/* nullspace_system(A, g, H, C, N, Hr, gr, lam) -> rank
 *
 * The Newton system of the static update reduced to the null space of the
 * constraints A dq = 0 (A (m, nv): loop closures' Jacobian rows, then unit rows of
 * held columns): a Householder QR of A^T with column pivoting, rank where |R_kk|
 * drops below 1e-10 |R_00|; N (nv, nv) gets an orthonormal basis of the null space
 * in its first k = nv - rank columns; lam (m) the basic least-squares multipliers
 * of A^T lam = -g; Hr (nv, nv) gets N^T (H + sum_r lam_r C[r]) N in its top-left
 * k x k block (C (mc, nv, nv), C order: the first mc rows' curvature) and gr the
 * first k entries of N^T g.
 */
static PyObject *nullspace_system(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 8) {
        PyErr_SetString(PyExc_TypeError, "nullspace_system takes 8 arguments");
        return NULL;
    }
    Buf b[8];
    memset(b, 0, sizeof(b));
    static const char *names[8] = {"A", "g", "H", "C", "N", "Hr", "gr", "lam"};
    for (int i = 0; i < 8; i++) {
        if (get_buf(args[i], &b[i], i >= 4, names[i]) < 0) {
            release(b, 8);
            return NULL;
        }
    }
    Buf A = b[0], G = b[1], H = b[2], C = b[3], N = b[4], HR = b[5], GR = b[6], LM = b[7];
    Py_ssize_t m = A.view.ndim == 2 ? A.view.shape[0] : -1, nv = A.view.ndim == 2 ? A.view.shape[1] : -1;
    Py_ssize_t mc = C.view.ndim == 3 ? C.view.shape[0] : -1;
    if (m < 0 || G.view.ndim != 1 || G.view.shape[0] != nv || check_2d(&H, nv, nv, "H") || mc < 0 || mc > m ||
        (mc > 0 && (C.view.shape[1] != nv || C.view.shape[2] != nv || !PyBuffer_IsContiguous(&C.view, 'C'))) ||
        check_2d(&N, nv, nv, "N") || check_2d(&HR, nv, nv, "Hr") || GR.view.ndim != 1 || GR.view.shape[0] != nv ||
        LM.view.ndim != 1 || LM.view.shape[0] != m) {
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "nullspace_system: wrong shapes");
        release(b, 8);
        return NULL;
    }
#define V1(bb, i) (*(double *)((char *)(bb).view.buf + (i) * (bb).view.strides[0]))
    /* T = A^T, column j (row j of A) at T + j * nv; Q (nv x nv) row-major; Hf; scratch */
    double *T = (double *)PyMem_Calloc((size_t)(m * nv + 3 * nv * nv + 2 * nv + m + 1), sizeof(double));
    Py_ssize_t *perm = (Py_ssize_t *)PyMem_Calloc((size_t)m + 1, sizeof(Py_ssize_t));
    if (T == NULL || perm == NULL) {
        PyMem_Free(T);
        PyMem_Free(perm);
        release(b, 8);
        return PyErr_NoMemory();
    }
    double *Q = T + m * nv, *Hf = Q + nv * nv, *W = Hf + nv * nv, *beta = W + nv * nv, *y = beta + nv, *gv = y + m;
    for (Py_ssize_t j = 0; j < m; j++) {
        perm[j] = j;
        for (Py_ssize_t i = 0; i < nv; i++) T[j * nv + i] = AT(A, j, i);
    }
    for (Py_ssize_t i = 0; i < nv; i++) gv[i] = V1(G, i);
    Py_ssize_t rank = 0, steps = m < nv ? m : nv;
    double first = 0.0;
    for (Py_ssize_t k = 0; k < steps; k++) {
        Py_ssize_t best = k;
        double bestn = -1.0;
        for (Py_ssize_t j = k; j < m; j++) { /* the column with the largest remaining norm */
            double s = 0.0;
            for (Py_ssize_t i = k; i < nv; i++) s += T[j * nv + i] * T[j * nv + i];
            if (s > bestn) bestn = s, best = j;
        }
        double norm = sqrt(bestn);
        if (k == 0) first = norm;
        if (!(norm > 1e-10 * first) || norm == 0.0) break;
        if (best != k) {
            for (Py_ssize_t i = 0; i < nv; i++) {
                double t = T[k * nv + i];
                T[k * nv + i] = T[best * nv + i], T[best * nv + i] = t;
            }
            Py_ssize_t t = perm[k];
            perm[k] = perm[best], perm[best] = t;
        }
        double *v = T + k * nv, alpha = v[k] > 0 ? -norm : norm;
        /* reflector I - beta u u^T with u = v[k:] - alpha e_k, stored in v[k:] */
        v[k] -= alpha;
        double un = 0.0;
        for (Py_ssize_t i = k; i < nv; i++) un += v[i] * v[i];
        beta[k] = un > 0 ? 2.0 / un : 0.0;
        for (Py_ssize_t j = k + 1; j < m; j++) {
            double *c = T + j * nv, s = 0.0;
            for (Py_ssize_t i = k; i < nv; i++) s += v[i] * c[i];
            s *= beta[k];
            for (Py_ssize_t i = k; i < nv; i++) c[i] -= s * v[i];
        }
        y[k] = alpha; /* R_kk */
        rank = k + 1;
    }
    /* Q = H_0 ... H_{rank-1}: applied to I from the last reflector */
    for (Py_ssize_t i = 0; i < nv; i++) Q[i * nv + i] = 1.0;
    for (Py_ssize_t k = rank - 1; k >= 0; k--) {
        const double *v = T + k * nv;
        for (Py_ssize_t c = 0; c < nv; c++) {
            double s = 0.0;
            for (Py_ssize_t i = k; i < nv; i++) s += v[i] * Q[i * nv + c];
            s *= beta[k];
            for (Py_ssize_t i = k; i < nv; i++) Q[i * nv + c] -= s * v[i];
        }
    }
    /* multipliers: R11 z = -Q1^T g; lam[perm[i]] = z[i] (R's strict upper part is in T above the diagonal) */
    double *z = W; /* scratch */
    for (Py_ssize_t i = 0; i < rank; i++) {
        double s = 0.0;
        for (Py_ssize_t r = 0; r < nv; r++) s += Q[r * nv + i] * gv[r];
        z[i] = -s;
    }
    for (Py_ssize_t i = rank - 1; i >= 0; i--) {
        double s = z[i];
        for (Py_ssize_t j = i + 1; j < rank; j++) s -= T[j * nv + i] * z[j];
        z[i] = s / y[i];
    }
    for (Py_ssize_t j = 0; j < m; j++) V1(LM, j) = 0.0;
    for (Py_ssize_t i = 0; i < rank; i++) V1(LM, perm[i]) = z[i];
    /* Hf = H + sum_r lam_r C[r] */
    const double *Cb = (const double *)C.view.buf;
    for (Py_ssize_t a = 0; a < nv; a++)
        for (Py_ssize_t c = 0; c < nv; c++) Hf[a * nv + c] = AT(H, a, c);
    for (Py_ssize_t r = 0; r < mc; r++) {
        double l = V1(LM, r);
        if (l == 0.0) continue;
        const double *Cr = Cb + r * nv * nv;
        for (Py_ssize_t e = 0; e < nv * nv; e++) Hf[e] += l * Cr[e];
    }
    /* N = Q[:, rank:]; W = Hf N (nv x k); Hr = N^T W (symmetrized); gr = N^T g */
    Py_ssize_t k = nv - rank;
    for (Py_ssize_t i = 0; i < nv; i++)
        for (Py_ssize_t c = 0; c < nv; c++) AT(N, i, c) = c < k ? Q[i * nv + rank + c] : 0.0;
    for (Py_ssize_t a = 0; a < nv; a++)
        for (Py_ssize_t c = 0; c < k; c++) {
            double s = 0.0;
            for (Py_ssize_t e = 0; e < nv; e++) s += Hf[a * nv + e] * Q[e * nv + rank + c];
            W[a * k + c] = s;
        }
    for (Py_ssize_t i = 0; i < nv; i++) {
        for (Py_ssize_t c = 0; c < nv; c++) AT(HR, i, c) = 0.0;
        V1(GR, i) = 0.0;
    }
    for (Py_ssize_t i = 0; i < k; i++) {
        double s = 0.0;
        for (Py_ssize_t e = 0; e < nv; e++) s += Q[e * nv + rank + i] * gv[e];
        V1(GR, i) = s;
        for (Py_ssize_t c = 0; c <= i; c++) {
            double u = 0.0, w = 0.0;
            for (Py_ssize_t e = 0; e < nv; e++) {
                u += Q[e * nv + rank + i] * W[e * k + c];
                w += Q[e * nv + rank + c] * W[e * k + i];
            }
            AT(HR, i, c) = AT(HR, c, i) = 0.5 * (u + w);
        }
    }
#undef V1
    PyMem_Free(T);
    PyMem_Free(perm);
    release(b, 8);
    return PyLong_FromSsize_t(rank);
}

/* index k of a float64 buffer holding integer indices */
#define IDX(b, k) ((Py_ssize_t)(*(double *)((char *)(b).view.buf + (k) * (b).view.strides[0])))
#define EL(b, k) (*(double *)((char *)(b).view.buf + (k) * (b).view.strides[0]))

/* all_unit(v, starts, lo2, hi2) -> bool: whether every entry of the vector v is finite and
 * each 4-block v[starts[k]:starts[k]+4] (a quaternion; float64 indices) has a squared norm
 * in [lo2, hi2].  The callers' usual case, checked in one pass; they explain a False. */
static PyObject *all_unit(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 4) {
        PyErr_SetString(PyExc_TypeError, "all_unit takes 4 arguments");
        return NULL;
    }
    Buf b[2];
    memset(b, 0, sizeof(b));
    if (get_buf(args[0], &b[0], 0, "v") < 0 || get_buf(args[1], &b[1], 0, "starts") < 0) {
        release(b, 2);
        return NULL;
    }
    double lo2 = PyFloat_AsDouble(args[2]), hi2 = PyFloat_AsDouble(args[3]);
    if (PyErr_Occurred() || b[0].view.ndim != 1 || b[1].view.ndim != 1) {
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "v and starts must be vectors");
        release(b, 2);
        return NULL;
    }
    Py_ssize_t n = b[0].view.shape[0], m = b[1].view.shape[0];
    int ok = 1;
    for (Py_ssize_t i = 0; i < n && ok; i++) ok = isfinite(EL(b[0], i));
    for (Py_ssize_t k = 0; k < m && ok; k++) {
        Py_ssize_t a = IDX(b[1], k);
        if (a < 0 || a + 4 > n) {
            PyErr_SetString(PyExc_IndexError, "starts out of range");
            release(b, 2);
            return NULL;
        }
        double s = 0.0;
        for (int c = 0; c < 4; c++) s += EL(b[0], a + c) * EL(b[0], a + c);
        ok = s >= lo2 && s <= hi2;
    }
    release(b, 2);
    return PyBool_FromLong(ok);
}

/* clip_limits(q, iq, lo, hi): q[iq[k]] clipped into [lo[k], hi[k]] in place (the joint
 * limits of the spec; iq float64 indices). */
static PyObject *clip_limits(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 4) {
        PyErr_SetString(PyExc_TypeError, "clip_limits takes 4 arguments");
        return NULL;
    }
    Buf b[4];
    memset(b, 0, sizeof(b));
    static const char *names[4] = {"q", "iq", "lo", "hi"};
    for (int i = 0; i < 4; i++) {
        if (get_buf(args[i], &b[i], i == 0, names[i]) < 0) {
            release(b, 4);
            return NULL;
        }
    }
    Py_ssize_t m = b[1].view.ndim == 1 ? b[1].view.shape[0] : -1;
    if (b[0].view.ndim != 1 || m < 0 || b[2].view.ndim != 1 || b[2].view.shape[0] != m || b[3].view.ndim != 1 ||
        b[3].view.shape[0] != m) {
        PyErr_SetString(PyExc_ValueError, "q, iq, lo and hi must be vectors, iq, lo and hi of one length");
        release(b, 4);
        return NULL;
    }
    Py_ssize_t nq = b[0].view.shape[0];
    for (Py_ssize_t k = 0; k < m; k++) {
        Py_ssize_t i = IDX(b[1], k);
        if (i < 0 || i >= nq) {
            PyErr_SetString(PyExc_IndexError, "iq out of range");
            release(b, 4);
            return NULL;
        }
        double x = EL(b[0], i), lo = EL(b[2], k), hi = EL(b[3], k);
        /* as np.clip: the upper bound wins when lo > hi */
        EL(b[0], i) = x < lo ? lo : x;
        if (EL(b[0], i) > hi) EL(b[0], i) = hi;
    }
    release(b, 4);
    Py_RETURN_NONE;
}

/* hold_limits(q, iq, iv, lo_at, hi_at, grad, H) -> ||grad||^2
 * The joints that sit at a limit (q[iq[k]] <= lo_at[k] or >= hi_at[k]) and are pushed
 * outwards (descent -grad leaves the range) taken out of the Newton system, in place:
 * zero gradient, zero row and column of H with its largest diagonal entry (before the
 * change, at least 1e-12) on the diagonal (projected Levenberg-Marquardt). */
static PyObject *hold_limits(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 7) {
        PyErr_SetString(PyExc_TypeError, "hold_limits takes 7 arguments");
        return NULL;
    }
    Buf b[7];
    memset(b, 0, sizeof(b));
    static const char *names[7] = {"q", "iq", "iv", "lo_at", "hi_at", "grad", "H"};
    for (int i = 0; i < 7; i++) {
        if (get_buf(args[i], &b[i], i >= 5, names[i]) < 0) {
            release(b, 7);
            return NULL;
        }
    }
    Py_ssize_t m = b[1].view.ndim == 1 ? b[1].view.shape[0] : -1;
    Py_ssize_t nv = b[5].view.ndim == 1 ? b[5].view.shape[0] : -1;
    int bad = b[0].view.ndim != 1 || m < 0 || nv < 0 || check_2d(&b[6], nv, nv, "H");
    for (int i = 2; i < 5 && !bad; i++) bad = b[i].view.ndim != 1 || b[i].view.shape[0] != m;
    if (bad) {
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "iq, iv, lo_at and hi_at must be vectors of one length");
        release(b, 7);
        return NULL;
    }
    Py_ssize_t nq = b[0].view.shape[0];
    char *active = (char *)PyMem_Malloc((size_t)m + 1);
    if (active == NULL) {
        release(b, 7);
        return PyErr_NoMemory();
    }
    int any = 0;
    for (Py_ssize_t k = 0; k < m; k++) {
        Py_ssize_t i = IDX(b[1], k), a = IDX(b[2], k);
        if (i < 0 || i >= nq || a < 0 || a >= nv) {
            PyErr_SetString(PyExc_IndexError, "iq or iv out of range");
            PyMem_Free(active);
            release(b, 7);
            return NULL;
        }
        double x = EL(b[0], i), g = EL(b[5], a);
        active[k] = (x <= EL(b[3], k) && g > 0) || (x >= EL(b[4], k) && g < 0);
        any |= active[k];
    }
    if (any) {
        double d = AT(b[6], 0, 0);
        for (Py_ssize_t c = 1; c < nv; c++)
            if (AT(b[6], c, c) > d) d = AT(b[6], c, c);
        if (!(d > 1e-12)) d = 1e-12;
        for (Py_ssize_t k = 0; k < m; k++) {
            if (!active[k]) continue;
            Py_ssize_t a = IDX(b[2], k);
            EL(b[5], a) = 0.0;
            for (Py_ssize_t c = 0; c < nv; c++) AT(b[6], a, c) = AT(b[6], c, a) = 0.0;
        }
        for (Py_ssize_t k = 0; k < m; k++)
            if (active[k]) AT(b[6], IDX(b[2], k), IDX(b[2], k)) = d;
    }
    PyMem_Free(active);
    double gsq = 0.0;
    for (Py_ssize_t a = 0; a < nv; a++) gsq += EL(b[5], a) * EL(b[5], a);
    release(b, 7);
    return PyFloat_FromDouble(gsq);
}

/* solve_shifted(H, grad, shift, step_out) -> bool
 * Cholesky solve of (H + shift I) step = -grad; False if the matrix is not
 * positive definite (the Levenberg-Marquardt loop then raises the shift). */
static PyObject *solve_shifted(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 4) {
        PyErr_SetString(PyExc_TypeError, "solve_shifted takes 4 arguments");
        return NULL;
    }
    Buf b[3];
    memset(b, 0, sizeof(b));
    if (get_buf(args[0], &b[0], 0, "H") < 0 || get_buf(args[1], &b[1], 0, "grad") < 0 ||
        get_buf(args[3], &b[2], 1, "step")) {
        release(b, 3);
        return NULL;
    }
    double shift = PyFloat_AsDouble(args[2]);
    if (shift == -1.0 && PyErr_Occurred()) {
        release(b, 3);
        return NULL;
    }
    Py_ssize_t nv = b[0].view.ndim == 2 ? b[0].view.shape[0] : -1;
    if (check_2d(&b[0], nv, nv, "H") || b[1].view.ndim != 1 || b[1].view.shape[0] != nv || b[2].view.ndim != 1 ||
        b[2].view.shape[0] != nv) {
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "grad and step must have H's size");
        release(b, 3);
        return NULL;
    }
    double *L = (double *)PyMem_Malloc(sizeof(double) * (size_t)(nv * nv + nv + 1));
    if (L == NULL) {
        release(b, 3);
        return PyErr_NoMemory();
    }
    double *y = L + nv * nv;
    int ok = 1;
    for (Py_ssize_t j = 0; j < nv && ok; j++) {
        const double *Lj = L + j * nv;
        double s = AT(b[0], j, j) + shift;
        for (Py_ssize_t m = 0; m < j; m++) s -= Lj[m] * Lj[m];
        if (!(s > 0.0) || !isfinite(s)) {
            ok = 0;
            break;
        }
        double d = sqrt(s);
        L[j * nv + j] = d;
        /* the rows below, four at a time: four independent sums, each in the order of
         * one row's (the same numbers as row by row, without waiting on one chain) */
        Py_ssize_t i = j + 1;
        for (; i + 3 < nv; i += 4) {
            const double *L0 = L + i * nv, *L1 = L0 + nv, *L2 = L1 + nv, *L3 = L2 + nv;
            double s0 = AT(b[0], i, j) + 0.0, s1 = AT(b[0], i + 1, j) + 0.0, s2 = AT(b[0], i + 2, j) + 0.0,
                   s3 = AT(b[0], i + 3, j) + 0.0; /* + 0.0: a -0 entry as the row-by-row sum took it */
            for (Py_ssize_t m = 0; m < j; m++) {
                double l = Lj[m];
                s0 -= L0[m] * l;
                s1 -= L1[m] * l;
                s2 -= L2[m] * l;
                s3 -= L3[m] * l;
            }
            L[i * nv + j] = s0 / d;
            L[(i + 1) * nv + j] = s1 / d;
            L[(i + 2) * nv + j] = s2 / d;
            L[(i + 3) * nv + j] = s3 / d;
        }
        for (; i < nv; i++) {
            double si = AT(b[0], i, j) + 0.0;
            for (Py_ssize_t m = 0; m < j; m++) si -= L[i * nv + m] * Lj[m];
            L[i * nv + j] = si / d;
        }
    }
    if (ok) {
        const char *gb = (const char *)b[1].view.buf;
        Py_ssize_t gs = b[1].view.strides[0];
        for (Py_ssize_t i = 0; i < nv; i++) {
            double s = -*(const double *)(gb + i * gs);
            for (Py_ssize_t m = 0; m < i; m++) s -= L[i * nv + m] * y[m];
            y[i] = s / L[i * nv + i];
        }
        char *sb = (char *)b[2].view.buf;
        Py_ssize_t ss = b[2].view.strides[0];
        for (Py_ssize_t i = nv - 1; i >= 0; i--) {
            double s = y[i];
            for (Py_ssize_t m = i + 1; m < nv; m++) s -= L[m * nv + i] * *(double *)(sb + m * ss);
            *(double *)(sb + i * ss) = s / L[i * nv + i];
        }
    }
    PyMem_Free(L);
    release(b, 3);
    return PyBool_FromLong(ok);
}

/* ------------------------------------------------------------------ ECM M-step
 * Per-pixel arithmetic of kms2pin.ecm.mstep (its module docstring has the model):
 * for pixel rays d (unit camera depth, world axes), the closest approach of the
 * ray to the inner ellipsoid in the ellipsoid metric, a^2, and its derivative
 * with respect to a world translation and rotation of the body.  A = R diag(L^-2) R^T,
 * e = camera centre - body centre. */

/* |h| beyond which the logistic edge counts as saturated: kms2pin.ecm.mstep.H_CUT */
#define H_CUT 7.0

/* One body's ellipsoid seen from a camera: A, e and A e, held in locals before a pixel
 * loop so that the compiler keeps them in registers and vectorizes the loop. */
typedef struct {
    double a00, a01, a02, a10, a11, a12, a20, a21, a22, e0, e1, e2, b0, b1, b2;
} Quadric;

typedef struct {
    double a2, q0, q1, q2, g0, g1, g2; /* a^2, q*, g = A q* */
} Closest;

static inline Quadric quadric(const double *A, const double *e, const double *Ae)
{
    Quadric k = {A[0], A[1], A[2], A[3], A[4], A[5], A[6], A[7], A[8], e[0], e[1], e[2], Ae[0], Ae[1], Ae[2]};
    return k;
}

/* The closest approach of the ray d to the ellipsoid (branch-free: vectorizable). */
static inline __attribute__((always_inline)) Closest ray_closest(Quadric k, double d0, double d1, double d2)
{
    double ad0 = k.a00 * d0 + k.a01 * d1 + k.a02 * d2, ad1 = k.a10 * d0 + k.a11 * d1 + k.a12 * d2,
           ad2 = k.a20 * d0 + k.a21 * d1 + k.a22 * d2;
    double dot = d0 * k.b0 + d1 * k.b1 + d2 * k.b2, nn = ad0 * d0 + ad1 * d1 + ad2 * d2;
    double s = nn > 0.0 ? -dot / nn : 0.0;
    s = s < 0.0 ? 0.0 : s;
    Closest c;
    c.q0 = k.e0 + s * d0;
    c.q1 = k.e1 + s * d1;
    c.q2 = k.e2 + s * d2;
    c.g0 = k.b0 + s * ad0;
    c.g1 = k.b1 + s * ad1;
    c.g2 = k.b2 + s * ad2;
    c.a2 = c.q0 * c.g0 + c.q1 * c.g1 + c.q2 * c.g2;
    return c;
}

static inline double closest_a2(const double *A, const double *e, const double *Ae, const double *d, double *qs,
                                double *g)
{
    Closest c = ray_closest(quadric(A, e, Ae), d[0], d[1], d[2]);
    qs[0] = c.q0;
    qs[1] = c.q1;
    qs[2] = c.q2;
    g[0] = c.g0;
    g[1] = c.g1;
    g[2] = c.g2;
    return c.a2;
}

static int vec_arg(PyObject *obj, Buf *b, Py_ssize_t n, int writable, const char *name)
{
    if (get_buf(obj, b, writable, name) < 0) return -1;
    if (b->view.ndim != 1 || (n >= 0 && b->view.shape[0] != n)) {
        PyErr_Format(PyExc_ValueError, "%s has the wrong shape", name);
        return -1;
    }
    return 0;
}

#define V(b, i) (*(double *)((char *)(b).view.buf + (i) * (b).view.strides[0]))

static int small_args(PyObject *Aobj, PyObject *eobj, double *A, double *e)
{
    Buf a, v;
    memset(&a, 0, sizeof(a));
    memset(&v, 0, sizeof(v));
    if (get_buf(Aobj, &a, 0, "A") < 0 || check_2d(&a, 3, 3, "A") || vec_arg(eobj, &v, 3, 0, "e") < 0) {
        release(&a, 1);
        release(&v, 1);
        return -1;
    }
    for (int r = 0; r < 3; r++) {
        e[r] = V(v, r);
        for (int c = 0; c < 3; c++) A[3 * r + c] = AT(a, r, c);
    }
    release(&a, 1);
    release(&v, 1);
    return 0;
}

/* ellipsoid_a2(dirs, A, e, out): a^2 of every ray (out (N,)). */
static PyObject *ellipsoid_a2(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 4) {
        PyErr_SetString(PyExc_TypeError, "ellipsoid_a2(dirs, A, e, out)");
        return NULL;
    }
    double A[9], e[3], Ae[3];
    if (small_args(args[1], args[2], A, e) < 0) return NULL;
    Buf b[2];
    memset(b, 0, sizeof(b));
    if (get_buf(args[0], &b[0], 0, "dirs") < 0 || check_2d(&b[0], -1, 3, "dirs") ||
        vec_arg(args[3], &b[1], b[0].view.shape[0], 1, "out") < 0) {
        release(b, 2);
        return NULL;
    }
    for (int r = 0; r < 3; r++) Ae[r] = A[3 * r] * e[0] + A[3 * r + 1] * e[1] + A[3 * r + 2] * e[2];
    Py_ssize_t N = b[0].view.shape[0];
    for (Py_ssize_t i = 0; i < N; i++) {
        double d[3] = {AT(b[0], i, 0), AT(b[0], i, 1), AT(b[0], i, 2)}, qs[3], g[3];
        V(b[1], i) = closest_a2(A, e, Ae, d, qs, g);
    }
    release(b, 2);
    Py_RETURN_NONE;
}

/* silhouette_union(rays (H,W,3), A (n,9), e (n,3), box (n,4), out (H,W))
 * The union of inner silhouettes (kms2pin.ecm.silhouette): sets out (bool/uint8)
 * wherever the pixel's ray meets body i's ellipsoid (a^2 <= 1, the arithmetic of
 * ellipsoid_a2) within body i's box (u0, v0, u1, v1; an empty box: none). */
static int image_arg(PyObject *obj, Buf *b, int writable, const char *name, int bytes);

static int union_image(PyObject *obj, Buf *b, int writable, const char *name, Py_ssize_t h, Py_ssize_t w)
{
    if (image_arg(obj, b, writable, name, 1) < 0) return -1;
    if (b->view.shape[0] != h || b->view.shape[1] != w || b->view.strides[1] != 1) {
        PyErr_Format(PyExc_ValueError, "%s must be a row-contiguous image of the ray grid's size", name);
        return -1;
    }
    return 0;
}

/* Body i of A, e, box (b[1], b[2], b[3]): its box (u0, v0, u1, v1) into box and its
 * quadric into kq; 0 (kq unset) if the box is empty. */
static int body_quadric(const Buf *b, Py_ssize_t i, Py_ssize_t *box, Quadric *kq)
{
    for (int k = 0; k < 4; k++) box[k] = (Py_ssize_t)AT(b[3], i, k);
    if (box[2] <= box[0] || box[3] <= box[1]) return 0;
    double A[9], e[3], Ae[3];
    for (int j = 0; j < 9; j++) A[j] = AT(b[1], i, j);
    for (int j = 0; j < 3; j++) e[j] = AT(b[2], i, j);
    for (int r = 0; r < 3; r++) Ae[r] = A[3 * r] * e[0] + A[3 * r + 1] * e[1] + A[3 * r + 2] * e[2];
    *kq = quadric(A, e, Ae);
    return 1;
}

/* Body i of A, e, box ORed into img (rows `stride` bytes apart; its pixel (0, 0) is the
 * image's (v0, u0)), the box checked to lie in it. */
static void paint_body(const Buf *b, Py_ssize_t i, const double *rays, Py_ssize_t W, unsigned char *img,
                       Py_ssize_t stride, Py_ssize_t v0, Py_ssize_t u0)
{
    Py_ssize_t box[4];
    Quadric kq;
    if (!body_quadric(b, i, box, &kq)) return;
    const Py_ssize_t bu0 = box[0], bv0 = box[1], bu1 = box[2], bv1 = box[3];
    for (Py_ssize_t v = bv0; v < bv1; v++) {
        const double *D = rays + 3 * (v * W + bu0);
        unsigned char *o = img + (v - v0) * stride + (bu0 - u0);
        for (Py_ssize_t c = 0; c < bu1 - bu0; c++) o[c] |= ray_closest(kq, D[3 * c], D[3 * c + 1], D[3 * c + 2]).a2 <= 1.0;
    }
}

/* Body i of A, e, box counted into img as paint_body paints it (each of its pixels + 1);
 * returns -1 if a count would pass 255 (img then partly counted). */
static int count_body(const Buf *b, Py_ssize_t i, const double *rays, Py_ssize_t W, unsigned char *img,
                      Py_ssize_t stride, Py_ssize_t v0, Py_ssize_t u0)
{
    Py_ssize_t box[4];
    Quadric kq;
    if (!body_quadric(b, i, box, &kq)) return 0;
    const Py_ssize_t bu0 = box[0], bv0 = box[1], bu1 = box[2], bv1 = box[3];
    int full = 0;
    for (Py_ssize_t v = bv0; v < bv1; v++) {
        const double *D = rays + 3 * (v * W + bu0);
        unsigned char *o = img + (v - v0) * stride + (bu0 - u0);
        for (Py_ssize_t c = 0; c < bu1 - bu0; c++) {
            unsigned char in = ray_closest(kq, D[3 * c], D[3 * c + 1], D[3 * c + 2]).a2 <= 1.0;
            full |= in & (o[c] == 255);
            o[c] += in;
        }
    }
    return full ? -1 : 0;
}

/* Grows the box (v0, u0)-(v1, u1) to hold boxes i0..i1 of box (n, 4: u0, v0, u1, v1),
 * the empty ones left out. */
static void grow_box(const Buf *box, Py_ssize_t i0, Py_ssize_t i1, Py_ssize_t *v0, Py_ssize_t *u0, Py_ssize_t *v1,
                     Py_ssize_t *u1)
{
    for (Py_ssize_t i = i0; i < i1; i++) {
        Py_ssize_t bu0 = (Py_ssize_t)AT(*box, i, 0), bv0 = (Py_ssize_t)AT(*box, i, 1);
        Py_ssize_t bu1 = (Py_ssize_t)AT(*box, i, 2), bv1 = (Py_ssize_t)AT(*box, i, 3);
        if (bu1 <= bu0 || bv1 <= bv0) continue;
        *v0 = bv0 < *v0 ? bv0 : *v0;
        *u0 = bu0 < *u0 ? bu0 : *u0;
        *v1 = bv1 > *v1 ? bv1 : *v1;
        *u1 = bu1 > *u1 ? bu1 : *u1;
    }
}

/* The rays, A, e and box arguments (b[0..3]); 0 or -1 with an exception set. */
static int union_args(PyObject *const *args, Buf *b)
{
    int ok = get_buf(args[0], &b[0], 0, "rays") == 0 && b[0].view.ndim == 3 && b[0].view.shape[2] == 3 &&
             PyBuffer_IsContiguous(&b[0].view, 'C');
    if (ok) ok = get_buf(args[1], &b[1], 0, "A") == 0 && check_2d(&b[1], -1, 9, "A") == 0;
    Py_ssize_t n = ok ? b[1].view.shape[0] : 0, H = ok ? b[0].view.shape[0] : 0, W = ok ? b[0].view.shape[1] : 0;
    ok = ok && get_buf(args[2], &b[2], 0, "e") == 0 && check_2d(&b[2], n, 3, "e") == 0 &&
         get_buf(args[3], &b[3], 0, "box") == 0 && check_2d(&b[3], n, 4, "box") == 0;
    for (Py_ssize_t i = 0; ok && i < n; i++) {
        double bu0 = AT(b[3], i, 0), bv0 = AT(b[3], i, 1), bu1 = AT(b[3], i, 2), bv1 = AT(b[3], i, 3);
        if (bu1 > bu0 && bv1 > bv0 && (bu0 < 0 || bv0 < 0 || bu1 > W || bv1 > H)) {
            PyErr_SetString(PyExc_ValueError, "a box is not within the image");
            ok = 0;
        }
    }
    if (!ok && !PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "rays must be a C-contiguous (H, W, 3) grid");
    return ok ? 0 : -1;
}

static PyObject *silhouette_union(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 5) {
        PyErr_SetString(PyExc_TypeError, "silhouette_union(rays, A, e, box, out)");
        return NULL;
    }
    Buf b[5];
    memset(b, 0, sizeof(b));
    if (union_args(args, b) < 0 || union_image(args[4], &b[4], 1, "out", b[0].view.shape[0], b[0].view.shape[1]) < 0) {
        release(b, 5);
        return NULL;
    }
    Py_ssize_t W = b[0].view.shape[1];
    for (Py_ssize_t i = 0; i < b[1].view.shape[0]; i++)
        paint_body(b, i, (const double *)b[0].view.buf, W, (unsigned char *)b[4].view.buf, b[4].view.strides[0], 0, 0);
    release(b, 5);
    Py_RETURN_NONE;
}

/* silhouette_counts(rays (H,W,3), A (n,9), e (n,3), box (n,4), offset (K+1,), on (H,W), off (H,W),
 *                   counts_out (K,2))
 * For K groups of bodies (group k: bodies offset[k]..offset[k+1]), each's union as
 * silhouette_union's, painted into a scratch image over its boxes' bounding box:
 * counts_out[k] = how many pixels of it the images on and off (bool/uint8) hold. */
static PyObject *silhouette_counts(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 8) {
        PyErr_SetString(PyExc_TypeError, "silhouette_counts(rays, A, e, box, offset, on, off, counts)");
        return NULL;
    }
    Buf b[8];
    memset(b, 0, sizeof(b));
    int ok = union_args(args, b) == 0;
    Py_ssize_t n = ok ? b[1].view.shape[0] : 0, H = ok ? b[0].view.shape[0] : 0, W = ok ? b[0].view.shape[1] : 0;
    ok = ok && get_buf(args[4], &b[4], 0, "offset") == 0 && b[4].view.ndim == 1 && b[4].view.shape[0] >= 1 &&
         union_image(args[5], &b[5], 0, "on", H, W) == 0 && union_image(args[6], &b[6], 0, "off", H, W) == 0;
    Py_ssize_t K = ok ? b[4].view.shape[0] - 1 : 0;
    ok = ok && get_buf(args[7], &b[7], 1, "counts") == 0 && check_2d(&b[7], K, 2, "counts") == 0;
    for (Py_ssize_t k = 0; ok && k <= K; k++) {
        double o = V(b[4], k);
        if (!(o >= (k > 0 ? V(b[4], k - 1) : 0.0) && o <= (double)n)) {
            PyErr_SetString(PyExc_ValueError, "offset must rise from 0 to at most the bodies' count");
            ok = 0;
        }
    }
    unsigned char *scratch = ok ? (unsigned char *)PyMem_Malloc((size_t)(H * W > 0 ? H * W : 1)) : NULL;
    if (ok && scratch == NULL) {
        PyErr_NoMemory();
        ok = 0;
    }
    if (!ok) {
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "silhouette_counts: bad arguments");
        release(b, 8);
        return NULL;
    }
    const double *rays = (const double *)b[0].view.buf;
    for (Py_ssize_t k = 0; k < K; k++) {
        Py_ssize_t i0 = (Py_ssize_t)V(b[4], k), i1 = (Py_ssize_t)V(b[4], k + 1), v0 = H, u0 = W, v1 = 0, u1 = 0;
        grow_box(&b[3], i0, i1, &v0, &u0, &v1, &u1); /* the bounding box of the group's boxes */
        Py_ssize_t w = u1 - u0, n_on = 0, n_off = 0;
        if (v1 > v0 && w > 0) {
            memset(scratch, 0, (size_t)((v1 - v0) * w));
            for (Py_ssize_t i = i0; i < i1; i++) paint_body(b, i, rays, W, scratch, w, v0, u0);
            for (Py_ssize_t v = v0; v < v1; v++) {
                const unsigned char *o = scratch + (v - v0) * w;
                const unsigned char *a = (const unsigned char *)b[5].view.buf + v * b[5].view.strides[0] + u0;
                const unsigned char *z = (const unsigned char *)b[6].view.buf + v * b[6].view.strides[0] + u0;
                for (Py_ssize_t c = 0; c < w; c++) {
                    n_on += (o[c] != 0) & (a[c] != 0);
                    n_off += (o[c] != 0) & (z[c] != 0);
                }
            }
        }
        AT(b[7], k, 0) = (double)n_on;
        AT(b[7], k, 1) = (double)n_off;
    }
    PyMem_Free(scratch);
    release(b, 8);
    Py_RETURN_NONE;
}

/* A count image must be uint8 (a bool image holds no counts): 0, or -1 with TypeError. */
static int counts_arg(const Buf *b)
{
    if (b->view.format == NULL || strcmp(b->view.format, "B") != 0) {
        PyErr_SetString(PyExc_TypeError, "counts must be a 2-D uint8 image");
        return -1;
    }
    return 0;
}

/* silhouette_add(rays (H,W,3), A (n,9), e (n,3), box (n,4), counts (H,W) uint8)
 * counts + 1 on each pixel of each body's silhouette (as silhouette_union paints it);
 * ValueError if a count would pass 255. */
static PyObject *silhouette_add(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 5) {
        PyErr_SetString(PyExc_TypeError, "silhouette_add(rays, A, e, box, counts)");
        return NULL;
    }
    Buf b[5];
    memset(b, 0, sizeof(b));
    if (union_args(args, b) < 0 || union_image(args[4], &b[4], 1, "counts", b[0].view.shape[0], b[0].view.shape[1]) < 0 ||
        counts_arg(&b[4]) < 0) {
        release(b, 5);
        return NULL;
    }
    Py_ssize_t W = b[0].view.shape[1];
    int full = 0;
    for (Py_ssize_t i = 0; i < b[1].view.shape[0]; i++)
        full |= count_body(b, i, (const double *)b[0].view.buf, W, (unsigned char *)b[4].view.buf,
                           b[4].view.strides[0], 0, 0);
    release(b, 5);
    if (full) {
        PyErr_SetString(PyExc_ValueError, "silhouette_add: more than 255 bodies on a pixel");
        return NULL;
    }
    Py_RETURN_NONE;
}

/* silhouette_swap(rays, A_old, e_old, box_old, A_new, e_new, box_new, counts (H,W), mask (H,W))
 *   -> (d_inter, d_union)
 * counts (uint8) holds how many bodies' silhouettes cover each pixel (silhouette_add), the
 * "old" bodies among them: the change in the union's intersection with mask and in its
 * union with mask when the old bodies are taken out and the new ones painted in
 * (silhouette_union's pixels), over the bounding box of both's boxes. */
static PyObject *silhouette_swap(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 9) {
        PyErr_SetString(PyExc_TypeError, "silhouette_swap(rays, A_old, e_old, box_old, A_new, e_new, box_new, counts, mask)");
        return NULL;
    }
    Buf b[6], nb[4];
    memset(b, 0, sizeof(b));
    memset(nb, 0, sizeof(nb));
    PyObject *const na[4] = {args[0], args[4], args[5], args[6]};
    int ok = union_args(args, b) == 0 && union_args(na, nb) == 0;
    Py_ssize_t H = ok ? b[0].view.shape[0] : 0, W = ok ? b[0].view.shape[1] : 0;
    ok = ok && union_image(args[7], &b[4], 0, "counts", H, W) == 0 && counts_arg(&b[4]) == 0 &&
         union_image(args[8], &b[5], 0, "mask", H, W) == 0;
    if (!ok) {
        release(b, 6);
        release(nb, 4);
        return NULL;
    }
    Py_ssize_t v0 = H, u0 = W, v1 = 0, u1 = 0;
    grow_box(&b[3], 0, b[3].view.shape[0], &v0, &u0, &v1, &u1); /* the bounding box of both groups' boxes */
    grow_box(&nb[3], 0, nb[3].view.shape[0], &v0, &u0, &v1, &u1);
    Py_ssize_t d_inter = 0, d_union = 0, w = u1 - u0, h = v1 - v0;
    if (h > 0 && w > 0) {
        unsigned char *old = (unsigned char *)PyMem_Calloc((size_t)(2 * h * w), 1);
        if (old == NULL) {
            release(b, 6);
            release(nb, 4);
            return PyErr_NoMemory();
        }
        unsigned char *neu = old + h * w;
        const double *rays = (const double *)b[0].view.buf;
        int full = 0;
        for (Py_ssize_t i = 0; i < b[1].view.shape[0]; i++) full |= count_body(b, i, rays, W, old, w, v0, u0);
        for (Py_ssize_t i = 0; i < nb[1].view.shape[0]; i++) paint_body(nb, i, rays, W, neu, w, v0, u0);
        for (Py_ssize_t v = v0; v < v1 && !full; v++) {
            const unsigned char *c = (const unsigned char *)b[4].view.buf + v * b[4].view.strides[0] + u0;
            const unsigned char *m = (const unsigned char *)b[5].view.buf + v * b[5].view.strides[0] + u0;
            const unsigned char *o = old + (v - v0) * w, *n = neu + (v - v0) * w;
            for (Py_ssize_t k = 0; k < w; k++) {
                full |= o[k] > c[k];
                int base = c[k] != 0, trial = (c[k] > o[k]) | (n[k] != 0), in = m[k] != 0;
                d_inter += (trial & in) - (base & in);
                d_union += (trial | in) - (base | in);
            }
        }
        PyMem_Free(old);
        if (full) {
            release(b, 6);
            release(nb, 4);
            PyErr_SetString(PyExc_ValueError, "silhouette_swap: the old bodies are not all in counts");
            return NULL;
        }
    }
    release(b, 6);
    release(nb, 4);
    return Py_BuildValue("(nn)", d_inter, d_union);
}

typedef struct {
    Buf dirs, y, o, w;
    double centre[3];
    double inv;
    int has_w;
    /* fit_bodies' views: contiguous arrays it does not hold (pd NULL: the Bufs above) */
    const double *pd, *py, *po;
    Py_ssize_t n;
} View;

static void release_views(View *v, Py_ssize_t n)
{
    for (Py_ssize_t i = 0; i < n; i++) {
        release(&v[i].dirs, 1);
        release(&v[i].y, 1);
        release(&v[i].o, 1);
        release(&v[i].w, 1);
    }
}

/* e^x for x <= 0 in branch-free arithmetic the compiler can vectorize (a libm call in
 * a loop stops it): x = n ln2 + r, |r| <= ln2/2; sets *scale = 2^n (built in the
 * exponent bits) and returns e^r - 1 = r (1 + r/2 + ... + r^12/13!) (truncation
 * < 1e-17 relative), so that e^x = scale (1 + e^r - 1) within a few ulp.  x below
 * -40 counts as -40: e^-40 < 2^-57, so 1 + e^x is already 1, and the products of
 * such values never go subnormal (which would slow every lane down).  Needs strict
 * IEEE rounding of tt - shift: no -ffast-math / -fassociative-math for this file. */
static inline double expm1_reduced(double x, double *scale)
{
    x = x < -40.0 ? -40.0 : x;
    const double shift = 6755399441055744.0; /* 1.5 * 2^52: adding it rounds to an integer */
    double tt = x * 1.4426950408889634 + shift;
    double n = tt - shift;
    double r = (x - n * 0.6931471803691238) - n * 1.9082149292705877e-10; /* ln 2, hi + lo */
    double p = 1.0 / 6227020800.0;
    p = p * r + 1.0 / 479001600.0;
    p = p * r + 1.0 / 39916800.0;
    p = p * r + 1.0 / 3628800.0;
    p = p * r + 1.0 / 362880.0;
    p = p * r + 1.0 / 40320.0;
    p = p * r + 1.0 / 5040.0;
    p = p * r + 1.0 / 720.0;
    p = p * r + 1.0 / 120.0;
    p = p * r + 1.0 / 24.0;
    p = p * r + 1.0 / 6.0;
    p = p * r + 0.5;
    p = p * r + 1.0;
    union { double d; long long i; } u, sc;
    u.d = tt;
    sc.i = (u.i - 0x4338000000000000LL + 1023LL) << 52;
    *scale = sc.d;
    return r * p;
}

/* e^x for x <= 0, vectorizable (expm1_reduced). */
static inline double exp_nonpositive(double x)
{
    double scale, em1 = expm1_reduced(x, &scale);
    return scale + scale * em1;
}

/* 1 - e^x for x <= 0, vectorizable and without cancellation near 0:
 * (1 - 2^n) - 2^n (e^r - 1) (expm1_reduced). */
static inline double one_minus_exp(double x)
{
    double scale, em1 = expm1_reduced(x, &scale);
    return (1.0 - scale) - scale * em1;
}

/* log(1 + z) for 0 <= z <= 1, vectorizable: 2 atanh(u), u = z / (2 + z) <= 1/3, by
 * its series to u^31 (truncation < 2e-17 relative). */
static inline double log1p_unit(double z)
{
    double u = z / (2.0 + z), u2 = u * u, p = 1.0 / 31.0;
    p = p * u2 + 1.0 / 29.0;
    p = p * u2 + 1.0 / 27.0;
    p = p * u2 + 1.0 / 25.0;
    p = p * u2 + 1.0 / 23.0;
    p = p * u2 + 1.0 / 21.0;
    p = p * u2 + 1.0 / 19.0;
    p = p * u2 + 1.0 / 17.0;
    p = p * u2 + 1.0 / 15.0;
    p = p * u2 + 1.0 / 13.0;
    p = p * u2 + 1.0 / 11.0;
    p = p * u2 + 1.0 / 9.0;
    p = p * u2 + 1.0 / 7.0;
    p = p * u2 + 1.0 / 5.0;
    p = p * u2 + 1.0 / 3.0;
    p = p * u2 + 1.0;
    return 2.0 * u * p;
}

/* softplus(h) = log(1 + e^h) = max(h, 0) + log1p(e^-|h|), vectorizable (exp clamped
 * as in exp_nonpositive: softplus(h) for h < -40 is e^-40, not e^h). */
static inline double softplus_v(double h)
{
    return (h > 0.0 ? h : 0.0) + log1p_unit(exp_nonpositive(-fabs(h)));
}

/* The vectorized loops are compiled three times, for AVX-512, AVX2 and baseline
 * x86-64; the loader picks the one the CPU runs (GCC function multi-versioning:
 * the x86-64-v3/v4 names need GCC 11, the dispatch glibc's ifunc; elsewhere the
 * baseline build only, so that the extension still compiles). */
#if defined(__GNUC__) && __GNUC__ >= 11 && defined(__x86_64__) && !defined(__clang__) && defined(__GLIBC__)
#define SIMD_CLONES __attribute__((target_clones("arch=x86-64-v4", "arch=x86-64-v3", "default")))
#else
#define SIMD_CLONES
#endif

#define BLOCK 256

/* view_accumulate's sums with the Jacobian over C-contiguous arrays, by blocks of
 * pixels: the per-pixel terms first (J = dr/dp and r, both times sqrt(weight)), then
 * the sums J^T J and J^T r; each loop branch-free, so that the compiler vectorizes
 * it.  The same terms as view_accumulate's loop; out = cost, evidence, g[6], hu[21]. */
static inline __attribute__((always_inline)) void edge_sums(Py_ssize_t N, const double *restrict dirs,
                                                            const double *restrict Y, const double *restrict O,
                                                            const double *restrict W, const double *A,
                                                            const double *e, const double *Ae, double inv,
                                                            double *out)
{
    const Quadric kq = quadric(A, e, Ae);
    double cost = 0.0, evid = 0.0, acc[27] = {0};
    double Jb[7][BLOCK] __attribute__((aligned(64)));
    for (Py_ssize_t i0 = 0; i0 < N; i0 += BLOCK) {
        int n = (int)(N - i0 < BLOCK ? N - i0 : BLOCK);
        const double *D = dirs + 3 * i0, *Yb = Y + i0, *Ob = O + i0, *Wb = W ? W + i0 : NULL;
#pragma omp simd reduction(+ : cost, evid)
        for (int i = 0; i < n; i++) {
            Closest cl = ray_closest(kq, D[3 * i], D[3 * i + 1], D[3 * i + 2]);
            double q0 = cl.q0, q1 = cl.q1, q2 = cl.q2, c0 = cl.g0, c1 = cl.g1, c2 = cl.g2;
            double h = (1.0 - cl.a2) * inv, ah = fabs(h);
            double z = exp_nonpositive(-ah), s1 = 1.0 / (1.0 + z), s0 = z * s1;
            double sg = h >= 0 ? s1 : s0;
            double y = Yb[i], o = Ob[i], wt = Wb ? Wb[i] : 1.0, sw = Wb ? sqrt(wt) : 1.0;
            double fr = 1.0 - o, r = y - o - fr * sg;
            cost += wt * r * r;
            evid += wt * fr * sg * y;
            double w = fr * s0 * s1 * inv;
            w = (ah < H_CUT && w > 0.0) ? -2.0 * w * sw : 0.0; /* saturated edge: no gradient */
            Jb[0][i] = c0 * w;
            Jb[1][i] = c1 * w;
            Jb[2][i] = c2 * w;
            Jb[3][i] = (q1 * c2 - q2 * c1) * w;
            Jb[4][i] = (q2 * c0 - q0 * c2) * w;
            Jb[5][i] = (q0 * c1 - q1 * c0) * w;
            Jb[6][i] = r * sw;
        }
        int m = 0;
        for (int a = 0; a < 6; a++)
            for (int c = a; c < 7; c++, m++) {
                const double *x = Jb[a], *z = Jb[c];
                double sum = 0.0;
#pragma omp simd reduction(+ : sum)
                for (int i = 0; i < n; i++) sum += x[i] * z[i];
                acc[m] += sum;
            }
    }
    /* acc: for each a, J_a.J_c (c = a..5) then J_a.r */
    out[0] = cost;
    out[1] = evid;
    int m = 0, k = 0;
    for (int a = 0; a < 6; a++) {
        for (int c = a; c < 6; c++) out[8 + k++] = acc[m++];
        out[2 + a] = acc[m++];
    }
}

/* edge_sums specialized on whether there are weights (a per-pixel test on W in the
 * loop stops it from vectorizing well: 2x slower). */
SIMD_CLONES
static void view_accumulate_jac(Py_ssize_t N, const double *restrict dirs, const double *restrict Y,
                                const double *restrict O, const double *restrict W, const double *A, const double *e,
                                const double *Ae, double inv, double *out)
{
    if (W)
        edge_sums(N, dirs, Y, O, W, A, e, Ae, inv, out);
    else
        edge_sums(N, dirs, Y, O, NULL, A, e, Ae, inv, out);
}

static int contiguous_1d(const Buf *b) { return b->view.ndim == 1 && b->view.strides[0] == 8; }
static int contiguous_n3(const Buf *b)
{
    return b->view.ndim == 2 && b->view.strides[1] == 8 && b->view.strides[0] == 24;
}

/* One pixel of a sharp silhouette s = sigma(h) against the mask y, o of it explained by
 * the other bodies (kms2pin._numpy_kernels._edge_sums): returns the residual
 * r = y - o - (1 - o) s, sets *s and *w = (1 - o) s (1 - s) inv, the weight of dh in dr,
 * which is 0 on a saturated edge (|h| >= H_CUT: no gradient).  s and 1 - s come from
 * one exp, without overflow. */
static inline double edge_term(double h, double inv, double y, double o, double *s, double *w)
{
    double z = exp(-fabs(h)), s1 = 1.0 / (1.0 + z), s0 = z * s1;
    *s = h >= 0 ? s1 : s0;
    *w = fabs(h) < H_CUT ? (1.0 - o) * s0 * s1 * inv : 0.0;
    return y - o - (1.0 - o) * *s;
}

/* The per-pixel sums of one view (kms2pin.ecm.mstep.body_cost), added to cost,
 * evidence, g6 (6) and Hu (the 21 entries of the upper triangle of H, row by row). */
static void view_accumulate(const View *v, const double *A, const double *t, int jac, double *cost_io,
                            double *evid_io, double *g6, double *Hu)
{
    double e[3] = {v->centre[0] - t[0], v->centre[1] - t[1], v->centre[2] - t[2]}, Ae[3];
    for (int r = 0; r < 3; r++) Ae[r] = A[3 * r] * e[0] + A[3 * r + 1] * e[1] + A[3 * r + 2] * e[2];
    if (v->pd != NULL) { /* fit_bodies' views: contiguous, no weights, always with jac */
        double out[29];
        view_accumulate_jac(v->n, v->pd, v->py, v->po, NULL, A, e, Ae, v->inv, out);
        *cost_io += out[0];
        *evid_io += out[1];
        for (int a = 0; a < 6; a++) g6[a] += out[2 + a];
        for (int m = 0; m < 21; m++) Hu[m] += out[8 + m];
        return;
    }
    Py_ssize_t N = v->dirs.view.shape[0];
    if (jac && contiguous_n3(&v->dirs) && contiguous_1d(&v->y) && contiguous_1d(&v->o) &&
        (!v->has_w || contiguous_1d(&v->w))) {
        double out[29];
        view_accumulate_jac(N, (const double *)v->dirs.view.buf, (const double *)v->y.view.buf,
                            (const double *)v->o.view.buf, v->has_w ? (const double *)v->w.view.buf : NULL, A, e, Ae,
                            v->inv, out);
        *cost_io += out[0];
        *evid_io += out[1];
        for (int a = 0; a < 6; a++) g6[a] += out[2 + a];
        for (int m = 0; m < 21; m++) Hu[m] += out[8 + m];
        return;
    }
    double inv = v->inv, cost = 0.0, evidence = 0.0, hu[21] = {0}, gl[6] = {0}; /* local: no aliasing */
    for (Py_ssize_t i = 0; i < N; i++) {
        double d[3] = {AT(v->dirs, i, 0), AT(v->dirs, i, 1), AT(v->dirs, i, 2)}, qs[3], g[3];
        double a2 = closest_a2(A, e, Ae, d, qs, g);
        double y = V(v->y, i), o = V(v->o, i), wt = v->has_w ? V(v->w, i) : 1.0;
        double s, w, r = edge_term((1.0 - a2) * inv, inv, y, o, &s, &w);
        cost += wt * r * r;
        if (!jac) continue;
        evidence += wt * (1.0 - o) * s * y;
        if (!(w > 0.0)) continue; /* off the edge, or saturated: no gradient */
        double J[6], qxg[3];
        cross(qs, g, qxg);
        for (int c = 0; c < 3; c++) {
            J[c] = -2.0 * g[c] * w;
            J[3 + c] = -2.0 * qxg[c] * w;
        }
        int m = 0;
        for (int a = 0; a < 6; a++) {
            double ja = wt * J[a];
            gl[a] += ja * r;
            for (int c = a; c < 6; c++) hu[m++] += ja * J[c];
        }
    }
    *cost_io += cost;
    *evid_io += evidence;
    for (int a = 0; a < 6; a++) g6[a] += gl[a];
    for (int m = 0; m < 21; m++) Hu[m] += hu[m];
}

/* H (n x n) += the symmetric matrix whose upper triangle, row by row, is hu; g (n) += gl */
static void add_packed(Buf *H, Buf *g, int n, const double *hu, const double *gl)
{
    int m = 0;
    for (int a = 0; a < n; a++) {
        V(*g, a) += gl[a];
        for (int c = a; c < n; c++, m++) {
            AT(*H, a, c) += hu[m];
            if (c != a) AT(*H, c, a) += hu[m];
        }
    }
}

/* silhouette_fit(dirs, A, e, inv, y, o, weight|None, jac, H, grad) -> (cost, evidence)
 * For the sharp silhouette s = sigma((1 - a^2) inv) of one body in one view:
 * r = y - o - (1 - o) s, cost = sum wt r^2, evidence = sum wt (1 - o) s y; with jac,
 * adds J^T wt J to H (6x6) and J^T wt r to grad (6), J = dr/d(delta t, omega) over
 * the pixels on the edge, |h| < H_CUT, h = (1 - a^2) inv. */
static PyObject *silhouette_fit(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 10) {
        PyErr_SetString(PyExc_TypeError, "silhouette_fit takes 10 arguments");
        return NULL;
    }
    double A[9], e[3];
    if (small_args(args[1], args[2], A, e) < 0) return NULL;
    View v;
    memset(&v, 0, sizeof(v));
    v.inv = PyFloat_AsDouble(args[3]);
    if (v.inv == -1.0 && PyErr_Occurred()) return NULL;
    int jac = PyObject_IsTrue(args[7]);
    if (jac < 0) return NULL;
    v.has_w = args[6] != Py_None;
    for (int c = 0; c < 3; c++) v.centre[c] = e[c]; /* with t = 0 below: centre - t = e */
    Buf b[2];
    memset(b, 0, sizeof(b));
    int ok = get_buf(args[0], &v.dirs, 0, "dirs") == 0 && check_2d(&v.dirs, -1, 3, "dirs") == 0;
    Py_ssize_t N = ok ? v.dirs.view.shape[0] : 0;
    ok = ok && vec_arg(args[4], &v.y, N, 0, "y") == 0 && vec_arg(args[5], &v.o, N, 0, "o") == 0 &&
         (!v.has_w || vec_arg(args[6], &v.w, N, 0, "weight") == 0) && get_buf(args[8], &b[0], 1, "H") == 0 &&
         check_2d(&b[0], 6, 6, "H") == 0 && vec_arg(args[9], &b[1], 6, 1, "grad") == 0;
    if (!ok) {
        release_views(&v, 1);
        release(b, 2);
        return NULL;
    }
    double cost = 0.0, evidence = 0.0, Hu[21] = {0}, g6[6] = {0}, zero[3] = {0.0, 0.0, 0.0};
    view_accumulate(&v, A, zero, jac, &cost, &evidence, g6, Hu);
    if (jac) add_packed(&b[0], &b[1], 6, Hu, g6);
    release_views(&v, 1);
    release(b, 2);
    return Py_BuildValue("(dd)", cost, evidence);
}

/* scale_fit(dirs, A, e, R, inner, inv, y, o, weight|None, H, grad) -> cost
 * kms2pin.ecm.mstep.body_scale_cost for one view: the silhouette cost of silhouette_fit
 * in the log semi-axes of the body's inner ellipsoid, its pose held.  With x* the
 * closest approach in the body frame in semi-axes, x_k = (R^T q*)_k / L_k, a^2 = |x|^2
 * and d(a^2)/d log L_k = -2 x_k^2; adds J^T wt J to H (3x3) and J^T wt r to grad (3),
 * J = dr/d log L over the pixels on the edge. */
static PyObject *scale_fit(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 11) {
        PyErr_SetString(PyExc_TypeError, "scale_fit takes 11 arguments");
        return NULL;
    }
    double A[9], e[3], R[9], L[3];
    if (small_args(args[1], args[2], A, e) < 0 || small_args(args[3], args[4], R, L) < 0) return NULL;
    double inv = PyFloat_AsDouble(args[5]);
    if (inv == -1.0 && PyErr_Occurred()) return NULL;
    int has_w = args[8] != Py_None;
    Buf b[6];
    memset(b, 0, sizeof(b));
    int ok = get_buf(args[0], &b[0], 0, "dirs") == 0 && check_2d(&b[0], -1, 3, "dirs") == 0;
    Py_ssize_t N = ok ? b[0].view.shape[0] : 0;
    ok = ok && vec_arg(args[6], &b[1], N, 0, "y") == 0 && vec_arg(args[7], &b[2], N, 0, "o") == 0 &&
         (!has_w || vec_arg(args[8], &b[3], N, 0, "weight") == 0) && get_buf(args[9], &b[4], 1, "H") == 0 &&
         check_2d(&b[4], 3, 3, "H") == 0 && vec_arg(args[10], &b[5], 3, 1, "grad") == 0;
    if (!ok) {
        release(b, 6);
        return NULL;
    }
    double Ae[3];
    for (int r = 0; r < 3; r++) Ae[r] = A[3 * r] * e[0] + A[3 * r + 1] * e[1] + A[3 * r + 2] * e[2];
    const Quadric kq = quadric(A, e, Ae);
    double cost = 0.0, hu[6] = {0}, gl[3] = {0}; /* hu: the upper triangle of H, row by row */
    for (Py_ssize_t i = 0; i < N; i++) {
        Closest cl = ray_closest(kq, AT(b[0], i, 0), AT(b[0], i, 1), AT(b[0], i, 2));
        double x[3];
        for (int k = 0; k < 3; k++) x[k] = (cl.q0 * R[k] + cl.q1 * R[3 + k] + cl.q2 * R[6 + k]) / L[k];
        double a2 = x[0] * x[0] + x[1] * x[1] + x[2] * x[2];
        double y = V(b[1], i), o = V(b[2], i), wt = has_w ? V(b[3], i) : 1.0;
        double s, w, r = edge_term((1.0 - a2) * inv, inv, y, o, &s, &w);
        cost += wt * r * r;
        if (!(w > 0.0)) continue; /* off the edge, or saturated: no gradient */
        double J[3] = {-2.0 * x[0] * x[0] * w, -2.0 * x[1] * x[1] * w, -2.0 * x[2] * x[2] * w};
        int m = 0;
        for (int a = 0; a < 3; a++) {
            double ja = wt * J[a];
            gl[a] += ja * r;
            for (int c = a; c < 3; c++) hu[m++] += ja * J[c];
        }
    }
    add_packed(&b[4], &b[5], 3, hu, gl);
    release(b, 6);
    return PyFloat_FromDouble(cost);
}

/* ------------------------------------------------------------------ ECM E-step
 * kms2pin.ecm.estep.UnionEStep's E-step per pixel: each body's sharp
 * silhouette s = sigma(h) on its box, the union's log(1 - M) = sum_j log(1 - s_j)
 * = -sum_j softplus(h_j) per camera, then for every body the share of each pixel
 * the others explain, o = 1 - exp(log(1 - M) + softplus(h_i)). */

static inline double softplus(double h) { return (h > 0 ? h : 0.0) + log1p(exp(-fabs(h))); }

static int image_arg(PyObject *obj, Buf *b, int writable, const char *name, int bytes)
{
    int flags = PyBUF_STRIDES | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(obj, &b->view, flags) < 0) return -1;
    b->held = 1;
    int is_bytes = b->view.itemsize == 1 && b->view.format && (!strcmp(b->view.format, "?") || !strcmp(b->view.format, "B"));
    int is_double = b->view.itemsize == 8 && b->view.format && !strcmp(b->view.format, "d");
    int fmt_ok = bytes == 2 ? (is_bytes || is_double) : bytes ? is_bytes : is_double;
    if (!fmt_ok || b->view.ndim != 2) {
        PyErr_Format(PyExc_TypeError, "%s must be a 2-D %s image", name,
                     bytes == 2 ? "bool/uint8/float64" : bytes ? "bool/uint8" : "float64");
        return -1;
    }
    return 0;
}

static int box_arg(PyObject *const *args, const Buf *img, Py_ssize_t N, Py_ssize_t *box)
{
    for (int k = 0; k < 4; k++) {
        box[k] = PyLong_AsSsize_t(args[k]);
        if (box[k] == -1 && PyErr_Occurred()) return -1;
    }
    /* v0, u0, rows, cols */
    if (box[0] < 0 || box[1] < 0 || box[2] < 0 || box[3] < 0 || box[0] + box[2] > img->view.shape[0] ||
        box[1] + box[3] > img->view.shape[1] || box[2] * box[3] != N) {
        PyErr_SetString(PyExc_ValueError, "box does not fit the image or the pixel count");
        return -1;
    }
    return 0;
}

/* estep_body's loop over a box, row by row, vectorized: lf and lfo point at the box's
 * first pixel in log_free / log_free_o (rows `stride` doubles apart; lfo may be NULL). */
static inline __attribute__((always_inline)) void estep_rows_body(Py_ssize_t rows, Py_ssize_t cols,
                                                                  const double *restrict dirs, const double *A,
                                                                  const double *e, const double *Ae, double inv,
                                                                  double *restrict lf, Py_ssize_t stride,
                                                                  double *restrict sp, double *restrict lfo,
                                                                  Py_ssize_t stride_o, double widen)
{
    const Quadric kq = quadric(A, e, Ae);
    for (Py_ssize_t r = 0; r < rows; r++) {
        const double *D = dirs + 3 * r * cols;
        double *S = sp + r * cols, *L = lf + r * stride, *LO = lfo ? lfo + r * stride_o : NULL;
#pragma omp simd
        for (Py_ssize_t c = 0; c < cols; c++) {
            double h = (1.0 - ray_closest(kq, D[3 * c], D[3 * c + 1], D[3 * c + 2]).a2) * inv, v = softplus_v(h);
            S[c] = v;
            L[c] -= v;
            if (LO) LO[c] -= softplus_v(widen * h);
        }
    }
}

SIMD_CLONES
static void estep_rows(Py_ssize_t rows, Py_ssize_t cols, const double *restrict dirs, const double *A, const double *e,
                       const double *Ae, double inv, double *restrict lf, Py_ssize_t stride, double *restrict sp,
                       double *restrict lfo, Py_ssize_t stride_o, double widen)
{
    if (lfo)
        estep_rows_body(rows, cols, dirs, A, e, Ae, inv, lf, stride, sp, lfo, stride_o, widen);
    else
        estep_rows_body(rows, cols, dirs, A, e, Ae, inv, lf, stride, sp, NULL, 0, widen);
}

/* estep_view's loop, vectorized: lf and mask point at the box's first pixel. */
SIMD_CLONES
static void estep_view_rows(Py_ssize_t rows, Py_ssize_t cols, const double *restrict lf, Py_ssize_t stride,
                            const unsigned char *restrict mask, Py_ssize_t mstride, const double *restrict sp,
                            double *restrict o, double *restrict y)
{
    for (Py_ssize_t r = 0; r < rows; r++) {
        const double *L = lf + r * stride, *S = sp + r * cols;
        const unsigned char *M = mask + r * mstride;
        double *Or = o + r * cols, *Yr = y + r * cols;
#pragma omp simd
        for (Py_ssize_t c = 0; c < cols; c++) {
            double others = L[c] + S[c];
            Or[c] = one_minus_exp(others < 0.0 ? others : 0.0);
            Yr[c] = M[c] ? 1.0 : 0.0;
        }
    }
}

/* estep_view_rows with a float64 mask (area fractions of a binned mask): y = mask. */
SIMD_CLONES
static void estep_view_rows_f(Py_ssize_t rows, Py_ssize_t cols, const double *restrict lf, Py_ssize_t stride,
                              const double *restrict mask, Py_ssize_t mstride, const double *restrict sp,
                              double *restrict o, double *restrict y)
{
    for (Py_ssize_t r = 0; r < rows; r++) {
        const double *L = lf + r * stride, *S = sp + r * cols, *M = mask + r * mstride;
        double *Or = o + r * cols, *Yr = y + r * cols;
#pragma omp simd
        for (Py_ssize_t c = 0; c < cols; c++) {
            double others = L[c] + S[c];
            Or[c] = one_minus_exp(others < 0.0 ? others : 0.0);
            Yr[c] = M[c];
        }
    }
}

/* estep_body(dirs, A, e, inv, log_free, v0, u0, rows, cols, sp_out, log_free_o|None, widen)
 * h = (1 - a^2) inv on the box; sp = softplus(h) = -log(1 - s); log_free[box] -= sp;
 * with log_free_o also log_free_o[box] -= softplus(widen h). */
static PyObject *estep_body(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 12) {
        PyErr_SetString(PyExc_TypeError, "estep_body takes 12 arguments");
        return NULL;
    }
    double A[9], e[3], Ae[3];
    if (small_args(args[1], args[2], A, e) < 0) return NULL;
    double inv = PyFloat_AsDouble(args[3]), widen = PyFloat_AsDouble(args[11]);
    if (PyErr_Occurred()) return NULL;
    int has_o = args[10] != Py_None;
    Buf b[4];
    memset(b, 0, sizeof(b));
    Py_ssize_t box[4];
    if (get_buf(args[0], &b[0], 0, "dirs") < 0 || check_2d(&b[0], -1, 3, "dirs") ||
        image_arg(args[4], &b[1], 1, "log_free", 0) < 0 || box_arg(args + 5, &b[1], b[0].view.shape[0], box) < 0 ||
        vec_arg(args[9], &b[2], b[0].view.shape[0], 1, "sp") < 0 ||
        (has_o && (image_arg(args[10], &b[3], 1, "log_free_o", 0) < 0 ||
                   box_arg(args + 5, &b[3], b[0].view.shape[0], box) < 0))) {
        release(b, 4);
        return NULL;
    }
    for (int r = 0; r < 3; r++) Ae[r] = A[3 * r] * e[0] + A[3 * r + 1] * e[1] + A[3 * r + 2] * e[2];
    if (contiguous_n3(&b[0]) && contiguous_1d(&b[2]) && b[1].view.strides[1] == 8 && b[1].view.strides[0] % 8 == 0 &&
        (!has_o || (b[3].view.strides[1] == 8 && b[3].view.strides[0] % 8 == 0))) {
        double *lf = &AT(b[1], box[0], box[1]), *lfo = has_o ? &AT(b[3], box[0], box[1]) : NULL;
        estep_rows(box[2], box[3], (const double *)b[0].view.buf, A, e, Ae, inv, lf, b[1].view.strides[0] / 8,
                   (double *)b[2].view.buf, lfo, has_o ? b[3].view.strides[0] / 8 : 0, widen);
        release(b, 4);
        Py_RETURN_NONE;
    }
    Py_ssize_t i = 0;
    for (Py_ssize_t r = 0; r < box[2]; r++)
        for (Py_ssize_t c = 0; c < box[3]; c++, i++) {
            double d[3] = {AT(b[0], i, 0), AT(b[0], i, 1), AT(b[0], i, 2)}, qs[3], g[3];
            double h = (1.0 - closest_a2(A, e, Ae, d, qs, g)) * inv, sp = softplus(h);
            V(b[2], i) = sp;
            AT(b[1], box[0] + r, box[1] + c) -= sp;
            if (has_o) AT(b[3], box[0] + r, box[1] + c) -= softplus(widen * h);
        }
    release(b, 4);
    Py_RETURN_NONE;
}

/* estep_view(log_free, mask, v0, u0, rows, cols, sp, o_out, y_out):
 * o = 1 - exp(min(log_free[box] + sp, 0)), y = mask[box] (bool/uint8: 0/1; float64:
 * the value, e.g. a binned mask's area fraction); sp from estep_body. */
static PyObject *estep_view(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 9) {
        PyErr_SetString(PyExc_TypeError, "estep_view takes 9 arguments");
        return NULL;
    }
    Buf b[5];
    memset(b, 0, sizeof(b));
    Py_ssize_t box[4];
    if (vec_arg(args[6], &b[2], -1, 0, "sp") < 0 || image_arg(args[0], &b[0], 0, "log_free", 0) < 0 ||
        image_arg(args[1], &b[1], 0, "mask", 2) < 0 || box_arg(args + 2, &b[0], b[2].view.shape[0], box) < 0 ||
        box_arg(args + 2, &b[1], b[2].view.shape[0], box) < 0 ||
        vec_arg(args[7], &b[3], b[2].view.shape[0], 1, "o") < 0 ||
        vec_arg(args[8], &b[4], b[2].view.shape[0], 1, "y") < 0) {
        release(b, 5);
        return NULL;
    }
    int fmask = b[1].view.itemsize == 8;
    if (fmask && contiguous_1d(&b[2]) && contiguous_1d(&b[3]) && contiguous_1d(&b[4]) && b[0].view.strides[1] == 8 &&
        b[0].view.strides[0] % 8 == 0 && b[1].view.strides[1] == 8 && b[1].view.strides[0] % 8 == 0) {
        estep_view_rows_f(box[2], box[3], &AT(b[0], box[0], box[1]), b[0].view.strides[0] / 8, &AT(b[1], box[0], box[1]),
                          b[1].view.strides[0] / 8, (const double *)b[2].view.buf, (double *)b[3].view.buf,
                          (double *)b[4].view.buf);
        release(b, 5);
        Py_RETURN_NONE;
    }
    if (!fmask && contiguous_1d(&b[2]) && contiguous_1d(&b[3]) && contiguous_1d(&b[4]) && b[0].view.strides[1] == 8 &&
        b[0].view.strides[0] % 8 == 0 && b[1].view.strides[1] == 1) {
        const unsigned char *m = (const unsigned char *)b[1].view.buf + box[0] * b[1].view.strides[0] + box[1];
        estep_view_rows(box[2], box[3], &AT(b[0], box[0], box[1]), b[0].view.strides[0] / 8, m, b[1].view.strides[0],
                        (const double *)b[2].view.buf, (double *)b[3].view.buf, (double *)b[4].view.buf);
        release(b, 5);
        Py_RETURN_NONE;
    }
    Py_ssize_t i = 0;
    for (Py_ssize_t r = 0; r < box[2]; r++)
        for (Py_ssize_t c = 0; c < box[3]; c++, i++) {
            double others = AT(b[0], box[0] + r, box[1] + c) + V(b[2], i);
            V(b[3], i) = -expm1(others < 0 ? others : 0.0);
            const char *m = (const char *)b[1].view.buf + (box[0] + r) * b[1].view.strides[0] + (box[1] + c) * b[1].view.strides[1];
            V(b[4], i) = fmask ? *(const double *)m : (*(const unsigned char *)m ? 1.0 : 0.0);
        }
    release(b, 5);
    Py_RETURN_NONE;
}

/* estep_camera(rays (H,W,3), A (n,9), e (n,3), inv (n,), box (n,4), offset (n+1,), mask,
 *              log_free (H,W), dirs_out (N,3), sp_out (N,), o_out (N,), y_out (N,))
 * The E-step of one camera (kms2pin.ecm.estep.UnionEStep) in one call, for bodies
 * that all have boxes (u0, v0, u1, v1; an empty box for a body out of view): body i's
 * pixels are rows offset[i]..offset[i+1] of the outputs, its box row by row.  Per body,
 * its rays are copied out of the ray grid and estep_body's loop runs; then per body
 * estep_view's; then log_free, which must be zero on entry, is zeroed again over the
 * boxes.  The same arithmetic in the same order as those two functions. */
static PyObject *estep_camera(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 12) {
        PyErr_SetString(PyExc_TypeError, "estep_camera takes 12 arguments");
        return NULL;
    }
    Buf b[12];
    memset(b, 0, sizeof(b));
    int ok = get_buf(args[0], &b[0], 0, "rays") == 0 && b[0].view.ndim == 3 && b[0].view.shape[2] == 3 &&
             PyBuffer_IsContiguous(&b[0].view, 'C');
    if (ok) ok = get_buf(args[1], &b[1], 0, "A") == 0 && check_2d(&b[1], -1, 9, "A") == 0;
    Py_ssize_t n = ok ? b[1].view.shape[0] : 0, H = ok ? b[0].view.shape[0] : 0, W = ok ? b[0].view.shape[1] : 0;
    ok = ok && get_buf(args[2], &b[2], 0, "e") == 0 && check_2d(&b[2], n, 3, "e") == 0 &&
         vec_arg(args[3], &b[3], n, 0, "inv") == 0 && get_buf(args[4], &b[4], 0, "box") == 0 &&
         check_2d(&b[4], n, 4, "box") == 0 && vec_arg(args[5], &b[5], n + 1, 0, "offset") == 0 &&
         image_arg(args[6], &b[6], 0, "mask", 2) == 0 && image_arg(args[7], &b[7], 1, "log_free", 0) == 0;
    Py_ssize_t N = ok ? (Py_ssize_t)V(b[5], n) : 0;
    ok = ok && get_buf(args[8], &b[8], 1, "dirs") == 0 && check_2d(&b[8], N, 3, "dirs") == 0 &&
         contiguous_n3(&b[8]) && vec_arg(args[9], &b[9], N, 1, "sp") == 0 && contiguous_1d(&b[9]) &&
         vec_arg(args[10], &b[10], N, 1, "o") == 0 && contiguous_1d(&b[10]) &&
         vec_arg(args[11], &b[11], N, 1, "y") == 0 && contiguous_1d(&b[11]);
    if (ok && (b[6].view.shape[0] != H || b[6].view.shape[1] != W || b[7].view.shape[0] != H ||
               b[7].view.shape[1] != W || b[7].view.strides[1] != 8 || b[7].view.strides[0] % 8 != 0 ||
               b[6].view.strides[1] != b[6].view.itemsize || b[6].view.strides[0] % b[6].view.itemsize != 0)) {
        PyErr_SetString(PyExc_ValueError, "mask and log_free must be row-contiguous images of the ray grid's size");
        ok = 0;
    }
    Py_ssize_t *bx = ok ? (Py_ssize_t *)PyMem_Malloc(sizeof(Py_ssize_t) * 5 * (size_t)(n > 0 ? n : 1)) : NULL;
    if (ok && bx == NULL) {
        PyErr_NoMemory();
        ok = 0;
    }
    for (Py_ssize_t i = 0; ok && i < n; i++) { /* u0, v0, rows, cols, offset: checked */
        double u0 = AT(b[4], i, 0), v0 = AT(b[4], i, 1), u1 = AT(b[4], i, 2), v1 = AT(b[4], i, 3);
        Py_ssize_t off = (Py_ssize_t)V(b[5], i), end = (Py_ssize_t)V(b[5], i + 1);
        bx[5 * i] = (Py_ssize_t)u0;
        bx[5 * i + 1] = (Py_ssize_t)v0;
        bx[5 * i + 2] = (Py_ssize_t)(v1 - v0);
        bx[5 * i + 3] = (Py_ssize_t)(u1 - u0);
        bx[5 * i + 4] = off;
        if (u0 < 0 || v0 < 0 || u1 > W || v1 > H || bx[5 * i + 2] < 0 || bx[5 * i + 3] < 0 || off < 0 ||
            end - off != bx[5 * i + 2] * bx[5 * i + 3] || end > N) {
            PyErr_SetString(PyExc_ValueError, "a box does not fit the image or its offsets");
            ok = 0;
        }
    }
    if (!ok) {
        PyMem_Free(bx);
        release(b, 12);
        return NULL;
    }
    const double *rays = (const double *)b[0].view.buf;
    double *lf = (double *)b[7].view.buf, *dirs = (double *)b[8].view.buf, *sp = (double *)b[9].view.buf;
    double *o = (double *)b[10].view.buf, *y = (double *)b[11].view.buf;
    Py_ssize_t ls = b[7].view.strides[0] / 8, ms = b[6].view.strides[0] / b[6].view.itemsize;
    int fmask = b[6].view.itemsize == 8;
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t i = 0; i < n; i++) {
        Py_ssize_t u0 = bx[5 * i], v0 = bx[5 * i + 1], rows = bx[5 * i + 2], cols = bx[5 * i + 3], off = bx[5 * i + 4];
        if (rows == 0 || cols == 0) continue;
        double *D = dirs + 3 * off;
        for (Py_ssize_t r = 0; r < rows; r++)
            memcpy(D + 3 * r * cols, rays + 3 * ((v0 + r) * W + u0), sizeof(double) * 3 * (size_t)cols);
        double A[9], e[3], Ae[3];
        for (int k = 0; k < 9; k++) A[k] = AT(b[1], i, k);
        for (int k = 0; k < 3; k++) e[k] = AT(b[2], i, k);
        for (int r = 0; r < 3; r++) Ae[r] = A[3 * r] * e[0] + A[3 * r + 1] * e[1] + A[3 * r + 2] * e[2];
        estep_rows(rows, cols, D, A, e, Ae, V(b[3], i), lf + v0 * ls + u0, ls, sp + off, NULL, 0, 1.0);
    }
    for (Py_ssize_t i = 0; i < n; i++) {
        Py_ssize_t u0 = bx[5 * i], v0 = bx[5 * i + 1], rows = bx[5 * i + 2], cols = bx[5 * i + 3], off = bx[5 * i + 4];
        if (rows == 0 || cols == 0) continue;
        if (fmask)
            estep_view_rows_f(rows, cols, lf + v0 * ls + u0, ls, (const double *)b[6].view.buf + v0 * ms + u0, ms,
                              sp + off, o + off, y + off);
        else
            estep_view_rows(rows, cols, lf + v0 * ls + u0, ls, (const unsigned char *)b[6].view.buf + v0 * ms + u0, ms,
                            sp + off, o + off, y + off);
    }
    for (Py_ssize_t i = 0; i < n; i++) {
        Py_ssize_t u0 = bx[5 * i], v0 = bx[5 * i + 1], rows = bx[5 * i + 2], cols = bx[5 * i + 3];
        for (Py_ssize_t r = 0; r < rows; r++) memset(lf + (v0 + r) * ls + u0, 0, sizeof(double) * (size_t)cols);
    }
    Py_END_ALLOW_THREADS
    PyMem_Free(bx);
    release(b, 12);
    Py_RETURN_NONE;
}

/* pose_springs(J, X, T, K, S, A_out, g_out)
 * The tracker's static update with a full 6x6 spring per body
 * (kms2pin.virtual_work.pose_spring_update): body i's pose error
 * e_i = (t_i - t'_i, log(R_i R'_i^T)) from X and T (n, 7) [t, x, y, z, w], its
 * LOCAL_WORLD_ALIGNED Jacobian J_i (6 x nv) at the body centre from Pinocchio's data.J
 * (world frame) and the support mask S (n, nv); K (n, 36) row-major 6x6 stiffness.
 * A = sum J_i^T K_i J_i, g = sum J_i^T K_i e_i; returns the energy sum 1/2 e_i^T K_i e_i. */
/* Body i's pose error e (6: translation, rotation vector of X_i's rotation relative to
 * T_i's, world axes) between rows i of X and T (n, 7, XYZQUAT); returns ``energy`` plus its
 * spring energy 1/2 e_r K_rc e_c (K 6x6 row-major), added term by term in (r, c) order
 * onto the running sum (the bodies' terms in one chain, as pose_springs always summed). */
static double pose_error(const Buf *X, const Buf *T, Py_ssize_t i, const double *K, double *e, double energy)
{
    double p[3] = {AT(*X, i, 0), AT(*X, i, 1), AT(*X, i, 2)};
    double qa[4] = {AT(*X, i, 3), AT(*X, i, 4), AT(*X, i, 5), AT(*X, i, 6)};
    double qb[4] = {AT(*T, i, 3), AT(*T, i, 4), AT(*T, i, 5), AT(*T, i, 6)};
    for (int c = 0; c < 3; c++) e[c] = p[c] - AT(*T, i, c);
    /* relative rotation qa (x) conj(qb), then its rotation vector (angle in [0, pi]) */
    double bxv[3], v[3];
    cross(qa, qb, bxv);
    double w = qa[3] * qb[3] + dot3(qa, qb);
    for (int c = 0; c < 3; c++) v[c] = qb[3] * qa[c] - qa[3] * qb[c] - bxv[c];
    if (w < 0) {
        w = -w;
        for (int c = 0; c < 3; c++) v[c] = -v[c];
    }
    double nrm = sqrt(dot3(v, v));
    double sc = nrm < 1e-12 ? 2.0 / fmax(w, 1e-300) : 2.0 * atan2(nrm, w) / nrm;
    for (int c = 0; c < 3; c++) e[3 + c] = v[c] * sc;
    for (int r = 0; r < 6; r++)
        for (int c = 0; c < 6; c++) energy += 0.5 * e[r] * K[6 * r + c] * e[c];
    return energy;
}

/* pose_energy(X, T, K) -> energy: pose_springs' energy alone (no Jacobian, no A, no g),
 * the same number to the last bit: the static update's last trial step needs only it. */
static PyObject *pose_energy(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 3) {
        PyErr_SetString(PyExc_TypeError, "pose_energy(X, T, K)");
        return NULL;
    }
    Buf b[3];
    memset(b, 0, sizeof(b));
    static const char *names[3] = {"X", "T", "K"};
    for (int i = 0; i < 3; i++) {
        if (get_buf(args[i], &b[i], 0, names[i]) < 0) {
            release(b, 3);
            return NULL;
        }
    }
    Py_ssize_t n = b[0].view.ndim == 2 ? b[0].view.shape[0] : -1;
    if (check_2d(&b[0], -1, 7, "X") || check_2d(&b[1], n, 7, "T") || check_2d(&b[2], n, 36, "K")) {
        release(b, 3);
        return NULL;
    }
    double energy = 0.0;
    for (Py_ssize_t i = 0; i < n; i++) {
        double e[6], Ki[36];
        for (int c = 0; c < 36; c++) Ki[c] = AT(b[2], i, c);
        energy = pose_error(&b[0], &b[1], i, Ki, e, energy);
    }
    release(b, 3);
    return PyFloat_FromDouble(energy);
}

static PyObject *pose_springs(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 7) {
        PyErr_SetString(PyExc_TypeError, "pose_springs(J, X, T, K, S, A, g)");
        return NULL;
    }
    Buf b[7];
    memset(b, 0, sizeof(b));
    static const char *names[7] = {"J", "X", "T", "K", "S", "A", "g"};
    for (int i = 0; i < 7; i++) {
        if (get_buf(args[i], &b[i], i >= 5, names[i]) < 0) {
            release(b, 7);
            return NULL;
        }
    }
    Py_ssize_t nv = b[0].view.ndim == 2 ? b[0].view.shape[1] : -1;
    Py_ssize_t n = b[1].view.ndim == 2 ? b[1].view.shape[0] : -1;
    if (check_2d(&b[0], 6, -1, "J") || check_2d(&b[1], -1, 7, "X") || check_2d(&b[2], n, 7, "T") ||
        check_2d(&b[3], n, 36, "K") || check_2d(&b[4], n, nv, "S") || check_2d(&b[5], nv, nv, "A") ||
        b[6].view.ndim != 1 || b[6].view.shape[0] != nv) {
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "g has the wrong shape");
        release(b, 7);
        return NULL;
    }
    /* per body, only its supported columns (idx: m of them) are gathered, in order: the
     * same sums as over every column with the others skipped */
    double *Jb = (double *)PyMem_Malloc(sizeof(double) * (size_t)(12 * nv + 1));
    Py_ssize_t *idx = (Py_ssize_t *)PyMem_Malloc(sizeof(Py_ssize_t) * (size_t)(nv + 1));
    if (Jb == NULL || idx == NULL) {
        PyMem_Free(Jb);
        PyMem_Free(idx);
        release(b, 7);
        return PyErr_NoMemory();
    }
    double *KJ = Jb + 6 * nv, energy = 0.0;
    for (Py_ssize_t a = 0; a < nv; a++) {
        V(b[6], a) = 0.0;
        for (Py_ssize_t c = 0; c < nv; c++) AT(b[5], a, c) = 0.0;
    }
    for (Py_ssize_t i = 0; i < n; i++) {
        double p[3] = {AT(b[1], i, 0), AT(b[1], i, 1), AT(b[1], i, 2)};
        double e[6], Ki[36];
        for (int c = 0; c < 36; c++) Ki[c] = AT(b[3], i, c);
        energy = pose_error(&b[1], &b[2], i, Ki, e, energy);
        /* J_i: rows (linear at p; angular), supported columns only (k-th: column idx[k]) */
        Py_ssize_t m = 0;
        for (Py_ssize_t a = 0; a < nv; a++) {
            double sa = AT(b[4], i, a);
            if (sa == 0.0) continue;
            double om[3] = {AT(b[0], 3, a), AT(b[0], 4, a), AT(b[0], 5, a)}, oxp[3];
            cross(om, p, oxp);
            for (int c = 0; c < 3; c++) {
                Jb[c * nv + m] = sa * (AT(b[0], c, a) + oxp[c]);
                Jb[(3 + c) * nv + m] = sa * om[c];
            }
            idx[m++] = a;
        }
        for (int r = 0; r < 6; r++)
            for (Py_ssize_t k = 0; k < m; k++) {
                double s = 0.0;
                for (int c = 0; c < 6; c++) s += Ki[6 * r + c] * Jb[c * nv + k];
                KJ[r * nv + k] = s;
            }
        for (Py_ssize_t k = 0; k < m; k++) {
            double ga = 0.0;
            for (int r = 0; r < 6; r++) ga += KJ[r * nv + k] * e[r];
            V(b[6], idx[k]) += ga;
            double Jk[6];
            for (int r = 0; r < 6; r++) Jk[r] = Jb[r * nv + k];
            for (Py_ssize_t l = 0; l < m; l++) {
                double s = 0.0;
                for (int r = 0; r < 6; r++) s += Jk[r] * KJ[r * nv + l];
                AT(b[5], idx[k], idx[l]) += s;
            }
        }
    }
    PyMem_Free(idx);
    PyMem_Free(Jb);
    release(b, 7);
    return PyFloat_FromDouble(energy);
}

/* ------------------------------------------------------------------ one body's M-step
 * kms2pin.ecm.mstep.fit_body in C: damped Gauss-Newton on the body's world pose
 * (translation, rotation vector), every camera's view at once.  Its NumPy twin
 * (kms2pin._numpy_kernels.fit_body) is the same loop with the per-pixel sums of
 * silhouette_fit. */

/* cost, evidence, and (jac) grad (6) and H (6x6, row-major) of one pose over all views */
static void views_eval(const View *views, Py_ssize_t nv, const double *R, const double *t, const double *inner,
                       int jac, double *cost_out, double *evid_out, double *grad, double *H)
{
    double A[9];
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++) {
            double s = 0.0;
            for (int k = 0; k < 3; k++) s += R[3 * r + k] * R[3 * c + k] / (inner[k] * inner[k]);
            A[3 * r + c] = s;
        }
    double Hu[21] = {0};
    *cost_out = *evid_out = 0.0;
    for (int a = 0; a < 6; a++) grad[a] = 0.0;
    for (Py_ssize_t k = 0; k < nv; k++) view_accumulate(&views[k], A, t, jac, cost_out, evid_out, grad, Hu);
    if (jac) {
        int m = 0;
        for (int a = 0; a < 6; a++)
            for (int c = a; c < 6; c++, m++) H[6 * a + c] = H[6 * c + a] = Hu[m];
    }
}

/* R <- exp([w]x) R (Rodrigues) */
static void rotate_by(const double *w, double *R)
{
    double th = sqrt(dot3(w, w)), E[9];
    double a, b;
    if (th < 1e-8) {
        a = 1.0 - th * th / 6.0;
        b = 0.5 - th * th / 24.0;
    } else {
        a = sin(th) / th;
        b = (1.0 - cos(th)) / (th * th);
    }
    double K[9] = {0, -w[2], w[1], w[2], 0, -w[0], -w[1], w[0], 0};
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++) {
            double kk = 0.0;
            for (int m = 0; m < 3; m++) kk += K[3 * r + m] * K[3 * m + c];
            E[3 * r + c] = (r == c ? 1.0 : 0.0) + a * K[3 * r + c] + b * kk;
        }
    double out[9];
    for (int r = 0; r < 3; r++)
        for (int c = 0; c < 3; c++) out[3 * r + c] = E[3 * r] * R[c] + E[3 * r + 1] * R[3 + c] + E[3 * r + 2] * R[6 + c];
    memcpy(R, out, sizeof(out));
}

/* solve (M + shift I) x = -g for a 6x6 symmetric M by Cholesky; 0 if not positive definite */
static int chol6(const double *M, double shift, const double *g, double *x)
{
    double L[36] = {0}, y[6];
    for (int j = 0; j < 6; j++) {
        for (int i = j; i < 6; i++) {
            double s = M[6 * i + j] + (i == j ? shift : 0.0);
            for (int k = 0; k < j; k++) s -= L[6 * i + k] * L[6 * j + k];
            if (i == j) {
                if (!(s > 0.0) || !isfinite(s)) return 0;
                L[6 * j + j] = sqrt(s);
            } else {
                L[6 * i + j] = s / L[6 * j + j];
            }
        }
    }
    for (int i = 0; i < 6; i++) {
        double s = -g[i];
        for (int k = 0; k < i; k++) s -= L[6 * i + k] * y[k];
        y[i] = s / L[6 * i + i];
    }
    for (int i = 5; i >= 0; i--) {
        double s = y[i];
        for (int k = i + 1; k < 6; k++) s -= L[6 * k + i] * x[k];
        x[i] = s / L[6 * i + i];
    }
    return 1;
}

/* the damped Gauss-Newton of fit_body from (R, t) (updated in place) over nv views:
 * sets H (6x6, row-major) at the result, *evidence_out and *cost_out */
static void fit_core(const View *views, Py_ssize_t nv, double *R, double *t, const double *inner, long iterations,
                     double damping, double max_step, double *H, double *evidence_out, double *cost_out)
{
    double cost = 0.0, evidence = 0.0, grad[6] = {0};
    for (int m = 0; m < 36; m++) H[m] = 0.0;
    if (nv > 0) views_eval(views, nv, R, t, inner, 1, &cost, &evidence, grad, H);
    int any = 0;
    for (int m = 0; m < 36; m++) any |= H[m] != 0.0;
    if (any) {
        double size = (inner[0] + inner[1] + inner[2]) / 3.0;
        double S[6] = {size, size, size, 1.0, 1.0, 1.0}, Hn[36], offset[6] = {0};
        double dmax = 0.0;
        for (int a = 0; a < 6; a++) dmax = fmax(dmax, S[a] * H[7 * a] * S[a]);
        double prior = damping * fmax(dmax, 1e-12);
        double lam = 1e-3;
        for (long it = 0; it < iterations; it++) {
            double gn[6], hmax = -INFINITY;
            for (int a = 0; a < 6; a++) {
                for (int c = 0; c < 6; c++) Hn[6 * a + c] = S[a] * H[6 * a + c] * S[c];
                gn[a] = S[a] * grad[a] + prior * offset[a] / S[a];
                hmax = fmax(hmax, Hn[7 * a]);
            }
            int improved = 0;
            for (int tries = 0; tries < 6; tries++) {
                double stepn[6], step[6];
                if (!chol6(Hn, prior + lam * hmax, gn, stepn)) break;
                if (max_step > 0.0) {
                    double big = fmax(sqrt(dot3(stepn, stepn)), sqrt(dot3(stepn + 3, stepn + 3)));
                    double f = fmin(1.0, max_step / fmax(big, 1e-300));
                    for (int a = 0; a < 6; a++) stepn[a] *= f;
                }
                double R2[9], t2[3], c2, e2, g2[6], H2[36], p_old = 0.0, p_new = 0.0, off2[6];
                for (int a = 0; a < 6; a++) {
                    step[a] = stepn[a] * S[a];
                    off2[a] = offset[a] + step[a];
                    p_old += (offset[a] / S[a]) * (offset[a] / S[a]);
                    p_new += (off2[a] / S[a]) * (off2[a] / S[a]);
                }
                memcpy(R2, R, sizeof(R2));
                rotate_by(step + 3, R2);
                for (int r = 0; r < 3; r++) t2[r] = t[r] + step[r];
                views_eval(views, nv, R2, t2, inner, 1, &c2, &e2, g2, H2);
                if (0.5 * c2 + 0.5 * prior * p_new <= 0.5 * cost + 0.5 * prior * p_old) {
                    memcpy(R, R2, sizeof(R2));
                    memcpy(t, t2, sizeof(t2));
                    memcpy(offset, off2, sizeof(off2));
                    memcpy(grad, g2, sizeof(g2));
                    memcpy(H, H2, sizeof(H2));
                    cost = c2;
                    evidence = e2;
                    lam = fmax(lam * 0.3, 1e-6);
                    improved = 1;
                    break;
                }
                lam *= 10.0;
            }
            if (!improved) break;
        }
    }
    *evidence_out = evidence;
    *cost_out = cost;
}

/* fit_body(views, R, t, inner, iterations, damping, max_step, R_out, t_out, H_out)
 *     -> (evidence, cost)
 * views: list of (dirs (N,3), camera centre (3,), inv = 1/(2 delta), y, o, weight|None).
 * max_step <= 0: no cap. */
static PyObject *fit_body(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 10 || !PyList_Check(args[0])) {
        PyErr_SetString(PyExc_TypeError, "fit_body(views, R, t, inner, iterations, damping, max_step, R, t, H)");
        return NULL;
    }
    Py_ssize_t nv = PyList_GET_SIZE(args[0]);
    View *views = (View *)PyMem_Calloc((size_t)(nv > 0 ? nv : 1), sizeof(View));
    if (views == NULL) return PyErr_NoMemory();
    Buf b[6];
    memset(b, 0, sizeof(b));
    double R[9], t[3], inner[3];
    int ok = 1;
    for (Py_ssize_t k = 0; k < nv && ok; k++) {
        PyObject *tup = PyList_GET_ITEM(args[0], k);
        if (!PyTuple_Check(tup) || PyTuple_GET_SIZE(tup) != 6) {
            PyErr_SetString(PyExc_TypeError, "a view is (dirs, centre, inv, y, o, weight)");
            ok = 0;
            break;
        }
        View *v = &views[k];
        Buf c;
        memset(&c, 0, sizeof(c));
        if (get_buf(PyTuple_GET_ITEM(tup, 0), &v->dirs, 0, "dirs") < 0 || check_2d(&v->dirs, -1, 3, "dirs") ||
            vec_arg(PyTuple_GET_ITEM(tup, 1), &c, 3, 0, "centre") < 0) {
            release(&c, 1);
            ok = 0;
            break;
        }
        for (int r = 0; r < 3; r++) v->centre[r] = V(c, r);
        release(&c, 1);
        v->inv = PyFloat_AsDouble(PyTuple_GET_ITEM(tup, 2));
        if (v->inv == -1.0 && PyErr_Occurred()) {
            ok = 0;
            break;
        }
        Py_ssize_t N = v->dirs.view.shape[0];
        PyObject *wobj = PyTuple_GET_ITEM(tup, 5);
        v->has_w = wobj != Py_None;
        if (vec_arg(PyTuple_GET_ITEM(tup, 3), &v->y, N, 0, "y") < 0 ||
            vec_arg(PyTuple_GET_ITEM(tup, 4), &v->o, N, 0, "o") < 0 ||
            (v->has_w && vec_arg(wobj, &v->w, N, 0, "weight") < 0)) {
            ok = 0;
            break;
        }
    }
    if (ok) {
        if (get_buf(args[1], &b[0], 0, "R") < 0 || check_2d(&b[0], 3, 3, "R") || vec_arg(args[2], &b[1], 3, 0, "t") < 0 ||
            vec_arg(args[3], &b[2], 3, 0, "inner") < 0 || get_buf(args[7], &b[3], 1, "R_out") < 0 ||
            check_2d(&b[3], 3, 3, "R_out") || vec_arg(args[8], &b[4], 3, 1, "t_out") < 0 ||
            get_buf(args[9], &b[5], 1, "H_out") < 0 || check_2d(&b[5], 6, 6, "H_out"))
            ok = 0;
    }
    long iterations = ok ? PyLong_AsLong(args[4]) : 0;
    double damping = ok ? PyFloat_AsDouble(args[5]) : 0.0;
    double max_step = ok ? PyFloat_AsDouble(args[6]) : 0.0;
    if (ok && PyErr_Occurred()) ok = 0;
    if (!ok) {
        release_views(views, nv);
        PyMem_Free(views);
        release(b, 6);
        return NULL;
    }
    for (int r = 0; r < 3; r++) {
        t[r] = V(b[1], r);
        inner[r] = V(b[2], r);
        for (int c = 0; c < 3; c++) R[3 * r + c] = AT(b[0], r, c);
    }
    double cost = 0.0, evidence = 0.0, H[36];
    Py_BEGIN_ALLOW_THREADS
    fit_core(views, nv, R, t, inner, iterations, damping, max_step, H, &evidence, &cost);
    Py_END_ALLOW_THREADS
    for (int r = 0; r < 3; r++) {
        V(b[4], r) = t[r];
        for (int c = 0; c < 3; c++) AT(b[3], r, c) = R[3 * r + c];
    }
    for (int a = 0; a < 6; a++)
        for (int c = 0; c < 6; c++) AT(b[5], a, c) = H[6 * a + c];
    release_views(views, nv);
    PyMem_Free(views);
    release(b, 6);
    return Py_BuildValue("(dd)", evidence, cost);
}

/* fit_bodies(cams, inv, seen, R, t, inner, iterations, damping, max_step, R_out, t_out, H_out, out)
 * fit_body of every body of one E-step (kms2pin.ecm.mstep.fit_packed), the views packed as
 * estep_camera makes them: cams, per camera, (dirs (N,3), y (N,), o (N,), offset (n+1,),
 * centre (3,)), body i's pixels at offset[i]..offset[i+1]; inv (ncam, n) = 1/(2 delta);
 * seen (ncam, n) nonzero where a camera sees the body (its views in camera order, no
 * weights); R (n,9), t (n,3), inner (n,3) the start poses; sets R_out (n,9), t_out (n,3),
 * H_out (n,36) and out (n,2) = (evidence, cost). */
static PyObject *fit_bodies(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 13 || !PyList_Check(args[0])) {
        PyErr_SetString(PyExc_TypeError,
                        "fit_bodies(cams, inv, seen, R, t, inner, iterations, damping, max_step, R, t, H, out)");
        return NULL;
    }
    Py_ssize_t nc = PyList_GET_SIZE(args[0]);
    Buf *cb = (Buf *)PyMem_Calloc((size_t)(5 * nc + 1), sizeof(Buf));
    Buf b[9];
    memset(b, 0, sizeof(b));
    View *views = (View *)PyMem_Calloc((size_t)(nc + 1), sizeof(View));
    int ok = cb != NULL && views != NULL;
    if (!ok) PyErr_NoMemory();
    ok = ok && get_buf(args[3], &b[0], 0, "R") == 0 && check_2d(&b[0], -1, 9, "R") == 0;
    Py_ssize_t n = ok ? b[0].view.shape[0] : 0;
    ok = ok && get_buf(args[1], &b[1], 0, "inv") == 0 && check_2d(&b[1], nc, n, "inv") == 0 &&
         get_buf(args[2], &b[2], 0, "seen") == 0 && check_2d(&b[2], nc, n, "seen") == 0 &&
         get_buf(args[4], &b[3], 0, "t") == 0 && check_2d(&b[3], n, 3, "t") == 0 &&
         get_buf(args[5], &b[4], 0, "inner") == 0 && check_2d(&b[4], n, 3, "inner") == 0 &&
         get_buf(args[9], &b[5], 1, "R_out") == 0 && check_2d(&b[5], n, 9, "R_out") == 0 &&
         get_buf(args[10], &b[6], 1, "t_out") == 0 && check_2d(&b[6], n, 3, "t_out") == 0 &&
         get_buf(args[11], &b[7], 1, "H_out") == 0 && check_2d(&b[7], n, 36, "H_out") == 0 &&
         get_buf(args[12], &b[8], 1, "out") == 0 && check_2d(&b[8], n, 2, "out") == 0;
    for (Py_ssize_t c = 0; ok && c < nc; c++) {
        PyObject *tup = PyList_GET_ITEM(args[0], c);
        if (!PyTuple_Check(tup) || PyTuple_GET_SIZE(tup) != 5) {
            PyErr_SetString(PyExc_TypeError, "a camera is (dirs, y, o, offset, centre)");
            ok = 0;
            break;
        }
        Buf *k = cb + 5 * c;
        ok = get_buf(PyTuple_GET_ITEM(tup, 0), &k[0], 0, "dirs") == 0 && check_2d(&k[0], -1, 3, "dirs") == 0 &&
             contiguous_n3(&k[0]);
        Py_ssize_t N = ok ? k[0].view.shape[0] : 0;
        ok = ok && vec_arg(PyTuple_GET_ITEM(tup, 1), &k[1], N, 0, "y") == 0 && contiguous_1d(&k[1]) &&
             vec_arg(PyTuple_GET_ITEM(tup, 2), &k[2], N, 0, "o") == 0 && contiguous_1d(&k[2]) &&
             vec_arg(PyTuple_GET_ITEM(tup, 3), &k[3], n + 1, 0, "offset") == 0 &&
             vec_arg(PyTuple_GET_ITEM(tup, 4), &k[4], 3, 0, "centre") == 0;
        for (Py_ssize_t i = 0; ok && i < n; i++) {
            double lo = V(k[3], i), hi = V(k[3], i + 1);
            if (!(lo >= 0 && hi >= lo && hi <= (double)N)) {
                PyErr_SetString(PyExc_ValueError, "a body's offsets do not fit its camera's pixels");
                ok = 0;
            }
        }
        if (!ok && !PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "dirs, y and o must be contiguous");
    }
    long iterations = ok ? PyLong_AsLong(args[6]) : 0;
    double damping = ok ? PyFloat_AsDouble(args[7]) : 0.0;
    double max_step = ok ? PyFloat_AsDouble(args[8]) : 0.0;
    if (ok && PyErr_Occurred()) ok = 0;
    if (!ok) {
        if (cb != NULL) release(cb, (int)(5 * nc));
        PyMem_Free(cb);
        PyMem_Free(views);
        release(b, 9);
        return NULL;
    }
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t i = 0; i < n; i++) {
        Py_ssize_t nv = 0;
        for (Py_ssize_t c = 0; c < nc; c++) {
            if (AT(b[2], c, i) == 0.0) continue;
            const Buf *k = cb + 5 * c;
            Py_ssize_t off = (Py_ssize_t)V(k[3], i), end = (Py_ssize_t)V(k[3], i + 1);
            View *v = &views[nv++];
            memset(v, 0, sizeof(*v));
            v->pd = (const double *)k[0].view.buf + 3 * off;
            v->py = (const double *)k[1].view.buf + off;
            v->po = (const double *)k[2].view.buf + off;
            v->n = end - off;
            for (int r = 0; r < 3; r++) v->centre[r] = V(k[4], r);
            v->inv = AT(b[1], c, i);
        }
        double R[9], t[3], inner[3], H[36], evidence, cost;
        for (int r = 0; r < 9; r++) R[r] = AT(b[0], i, r);
        for (int r = 0; r < 3; r++) {
            t[r] = AT(b[3], i, r);
            inner[r] = AT(b[4], i, r);
        }
        fit_core(views, nv, R, t, inner, iterations, damping, max_step, H, &evidence, &cost);
        for (int r = 0; r < 9; r++) AT(b[5], i, r) = R[r];
        for (int r = 0; r < 3; r++) AT(b[6], i, r) = t[r];
        for (int m = 0; m < 36; m++) AT(b[7], i, m) = H[m];
        AT(b[8], i, 0) = evidence;
        AT(b[8], i, 1) = cost;
    }
    Py_END_ALLOW_THREADS
    release(cb, (int)(5 * nc));
    PyMem_Free(cb);
    PyMem_Free(views);
    release(b, 9);
    Py_RETURN_NONE;
}

/* body_boxes(R (n,9), t (n,3), inner (n,3), Rwc (3,3), centre (3,), K (3,3), delta_px,
 *            slack_px, width, height, box_out (n,4), delta_out (n,), status_out (n,))
 * kms2pin.ecm.mstep.body_images' box arithmetic for an undistorted camera, per body:
 * status 2: the box u0, v0, u1, v1 of its inner ellipsoid grown to h = -H_CUT plus
 * slack_px (the image of the grown quadric, C* = P Q* P^T), and its edge width delta;
 * 0: not in view; 1: straddling the camera plane, containing the camera or degenerate
 * (the per-body path decides). */
static PyObject *body_boxes(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 13) {
        PyErr_SetString(PyExc_TypeError, "body_boxes takes 13 arguments");
        return NULL;
    }
    double delta_px = PyFloat_AsDouble(args[6]), slack_px = PyFloat_AsDouble(args[7]);
    Py_ssize_t W = PyLong_AsSsize_t(args[8]), H = PyLong_AsSsize_t(args[9]);
    if (PyErr_Occurred()) return NULL;
    Buf b[9];
    memset(b, 0, sizeof(b));
    int ok = get_buf(args[0], &b[0], 0, "R") == 0 && check_2d(&b[0], -1, 9, "R") == 0;
    Py_ssize_t n = ok ? b[0].view.shape[0] : 0;
    ok = ok && get_buf(args[1], &b[1], 0, "t") == 0 && check_2d(&b[1], n, 3, "t") == 0 &&
         get_buf(args[2], &b[2], 0, "inner") == 0 && check_2d(&b[2], n, 3, "inner") == 0 &&
         get_buf(args[3], &b[3], 0, "Rwc") == 0 && check_2d(&b[3], 3, 3, "Rwc") == 0 &&
         vec_arg(args[4], &b[4], 3, 0, "centre") == 0 && get_buf(args[5], &b[5], 0, "K") == 0 &&
         check_2d(&b[5], 3, 3, "K") == 0 && get_buf(args[10], &b[6], 1, "box") == 0 &&
         check_2d(&b[6], n, 4, "box") == 0 && vec_arg(args[11], &b[7], n, 1, "delta") == 0 &&
         vec_arg(args[12], &b[8], n, 1, "status") == 0;
    if (!ok) {
        release(b, 9);
        return NULL;
    }
    double Rwc[3][3], K[3][3], c[3];
    for (int r = 0; r < 3; r++) {
        c[r] = V(b[4], r);
        for (int k = 0; k < 3; k++) {
            Rwc[r][k] = AT(b[3], r, k);
            K[r][k] = AT(b[5], r, k);
        }
    }
    double focal = sqrt(K[0][0] * K[1][1]);
    for (Py_ssize_t i = 0; i < n; i++) {
        double R[3][3], L0[3], mu[3] = {0.0, 0.0, 0.0};
        for (int r = 0; r < 3; r++) {
            L0[r] = AT(b[2], i, r);
            for (int k = 0; k < 3; k++) R[r][k] = AT(b[0], i, 3 * r + k);
        }
        for (int k = 0; k < 3; k++) /* mu = (t - centre) @ Rwc: the centre in camera axes */
            for (int j = 0; j < 3; j++) mu[k] += (AT(b[1], i, j) - c[j]) * Rwc[j][k];
        int imax = L0[1] > L0[0] ? 1 : 0;
        imax = L0[2] > L0[imax] ? 2 : imax;
        double lmax = L0[imax], small2 = L0[(imax + 1) % 3] * L0[(imax + 2) % 3]; /* the two smallest */
        V(b[7], i) = 0.0;
        V(b[8], i) = 0.0;
        if (!(mu[2] > 1e-9 * lmax)) continue; /* behind the camera */
        double r_px = fmax(focal * sqrt(small2) / mu[2], 1e-6); /* a rough outline radius */
        double delta = fmin(fmax(delta_px / r_px, 1e-6), 0.08);
        double grow = sqrt(1.0 + 2.0 * H_CUT * delta) + slack_px / r_px, L[3], Rcb[3][3], sig[3][3], cb[3];
        for (int k = 0; k < 3; k++) L[k] = L0[k] * grow;
        for (int a = 0; a < 3; a++) /* R_cb = Rwc^T R */
            for (int k = 0; k < 3; k++) Rcb[a][k] = Rwc[0][a] * R[0][k] + Rwc[1][a] * R[1][k] + Rwc[2][a] * R[2][k];
        double inside = 0.0;
        for (int k = 0; k < 3; k++) { /* the camera centre in the body frame, in semi-axes */
            cb[k] = -(mu[0] * Rcb[0][k] + mu[1] * Rcb[1][k] + mu[2] * Rcb[2][k]);
            inside += (cb[k] / L[k]) * (cb[k] / L[k]);
        }
        for (int a = 0; a < 3; a++)
            for (int d = 0; d < 3; d++)
                sig[a][d] = Rcb[a][0] * L[0] * L[0] * Rcb[d][0] + Rcb[a][1] * L[1] * L[1] * Rcb[d][1] +
                            Rcb[a][2] * L[2] * L[2] * Rcb[d][2];
        V(b[7], i) = delta;
        V(b[8], i) = 1.0;
        if (inside <= 1.0 || !(mu[2] - sqrt(sig[2][2]) > 0.0)) continue; /* straddling: per body */
        double M[3][3], KM[3][3], D[3][3];
        for (int a = 0; a < 3; a++)
            for (int d = 0; d < 3; d++) M[a][d] = sig[a][d] - mu[a] * mu[d];
        for (int a = 0; a < 3; a++)
            for (int d = 0; d < 3; d++) KM[a][d] = K[a][0] * M[0][d] + K[a][1] * M[1][d] + K[a][2] * M[2][d];
        for (int a = 0; a < 3; a++) /* the dual conic K M K^T */
            for (int d = 0; d < 3; d++) D[a][d] = KM[a][0] * K[d][0] + KM[a][1] * K[d][1] + KM[a][2] * K[d][2];
        double lo[2], hi[2];
        int finite = 1;
        for (int a = 0; a < 2; a++) {
            double bb = D[a][2], cc = D[a][a], rt = sqrt(fmax(bb * bb - D[2][2] * cc, 0.0));
            double k1 = (bb - rt) / D[2][2], k2 = (bb + rt) / D[2][2];
            finite = finite && isfinite(k1) && isfinite(k2);
            lo[a] = k1 < k2 ? k1 : k2;
            hi[a] = k1 < k2 ? k2 : k1;
        }
        if (!finite) continue; /* degenerate: per body */
        double u0 = fmax(ceil(lo[0]) - 1.0, 0.0), v0 = fmax(ceil(lo[1]) - 1.0, 0.0);
        double u1 = fmin(floor(hi[0]) + 2.0, (double)W), v1 = fmin(floor(hi[1]) + 2.0, (double)H);
        if (u1 <= u0 || v1 <= v0) {
            V(b[8], i) = 0.0; /* out of the image */
            continue;
        }
        AT(b[6], i, 0) = u0;
        AT(b[6], i, 1) = v0;
        AT(b[6], i, 2) = u1;
        AT(b[6], i, 3) = v1;
        V(b[8], i) = 2.0;
    }
    release(b, 9);
    Py_RETURN_NONE;
}

/* twist_prior(q, iq, iv, axes, rest, free, k, A, g) -> energy
 * The tracker's twist prior (kms2pin.ecm.priors.TwistPrior) added to the Newton system in
 * place.  Per spherical joint (iq, iv its first q and v indices, float64): the rotation
 * relative to rest D = conj(rest) x (v, w) (sign chosen so w >= 0, normalized), its twist
 * theta = 2 atan2(v.a, w) about the unit axis a, past +-free when free > 0; with
 * J = dtheta/domega = (w^2 a + w a x v + (v.a) v) / (w^2 + (v.a)^2):
 * A += k J J^T, g += k J theta; returns 1/2 k sum theta^2.  The NumPy twin's operations in
 * its order; its einsum and arctan2 round differently in the last bit. */
static PyObject *twist_prior(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 9) {
        PyErr_SetString(PyExc_TypeError, "twist_prior(q, iq, iv, axes, rest, free, k, A, g)");
        return NULL;
    }
    double free_ = PyFloat_AsDouble(args[5]), k = PyFloat_AsDouble(args[6]);
    if (PyErr_Occurred()) return NULL;
    Buf b[9];
    memset(b, 0, sizeof(b));
    static const char *names[9] = {"q", "iq", "iv", "axes", "rest", "", "", "A", "g"};
    for (int i = 0; i < 9; i++) {
        if (i == 5 || i == 6) continue;
        if (get_buf(args[i], &b[i], i >= 7, names[i]) < 0) {
            release(b, 9);
            return NULL;
        }
    }
    Py_ssize_t n = b[1].view.ndim == 1 ? b[1].view.shape[0] : -1;
    Py_ssize_t nv = b[8].view.ndim == 1 ? b[8].view.shape[0] : -1;
    if (b[0].view.ndim != 1 || n < 0 || nv < 0 || b[2].view.ndim != 1 || b[2].view.shape[0] != n ||
        check_2d(&b[3], n, 3, "axes") || check_2d(&b[4], n, 4, "rest") || check_2d(&b[7], nv, nv, "A")) {
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "q, iq, iv and g must be vectors, iq and iv of one length");
        release(b, 9);
        return NULL;
    }
    Py_ssize_t nq = b[0].view.shape[0];
    for (Py_ssize_t j = 0; j < n; j++) {
        Py_ssize_t i = IDX(b[1], j), c = IDX(b[2], j);
        if (i < 0 || i + 4 > nq || c < 0 || c + 3 > nv) {
            PyErr_SetString(PyExc_IndexError, "iq or iv out of range");
            release(b, 9);
            return NULL;
        }
    }
    double sum = 0.0;
    for (Py_ssize_t j = 0; j < n; j++) {
        Py_ssize_t i = IDX(b[1], j), c = IDX(b[2], j);
        double xv[3] = {EL(b[0], i), EL(b[0], i + 1), EL(b[0], i + 2)}, xw = EL(b[0], i + 3);
        double rv[3] = {AT(b[4], j, 0), AT(b[4], j, 1), AT(b[4], j, 2)}, rw = AT(b[4], j, 3);
        double a[3] = {AT(b[3], j, 0), AT(b[3], j, 1), AT(b[3], j, 2)};
        double rxx[3], v[3], axv[3], J[3];
        cross(rv, xv, rxx);
        double w = rw * xw + dot3(rv, xv);
        for (int d = 0; d < 3; d++) v[d] = rw * xv[d] - xw * rv[d] - rxx[d];
        if (w < 0.0) {
            w = -w;
            for (int d = 0; d < 3; d++) v[d] = -v[d];
        }
        double norm = sqrt(w * w + dot3(v, v));
        w = w / norm;
        for (int d = 0; d < 3; d++) v[d] = v[d] / norm;
        double t = dot3(v, a);
        double theta = 2.0 * atan2(t, w);
        double den = fmax(w * w + t * t, 1e-300);
        cross(a, v, axv);
        for (int d = 0; d < 3; d++) J[d] = ((w * w) * a[d] + w * axv[d] + t * v[d]) / den;
        if (free_ > 0.0) {
            if (theta == theta) {
                double m = fmax(fabs(theta) - free_, 0.0);
                theta = theta > 0.0 ? m : (theta < 0.0 ? -m : 0.0);
            }
            if (theta == 0.0) continue;
        }
        for (int r = 0; r < 3; r++) {
            for (int d = 0; d < 3; d++) AT(b[7], c + r, c + d) += k * (J[r] * J[d]);
            EL(b[8], c + r) += k * J[r] * theta;
        }
        sum += theta * theta;
    }
    release(b, 9);
    return PyFloat_FromDouble(0.5 * k * sum);
}

/* spring_targets(R, t, H, inner, floor, T, K) -> hmax
 *
 * The full springs' targets and stiffnesses from the M-step fits (kms2pin.ecm.springs):
 * T[i] = [t_i, x, y, z, w] of rotation R_i (n, 9 row-major) by Eigen's (Pinocchio's
 * SE3ToXYZQUAT's) own formula, term for term, so the numbers are Pinocchio's to the last
 * bit; K = H (n, 36, 6x6 row-major) plus floor * hmax / S_d^2 on each diagonal entry d,
 * S_d each body's mean semi-axis for the translations and 1 for the rotations, hmax the
 * largest H_dd * S_d^2 (returned; NaN if any is, -inf for no body).  K is H where hmax <= 0.
 */
static PyObject *spring_targets(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 7) {
        PyErr_SetString(PyExc_TypeError, "spring_targets(R, t, H, inner, floor, T, K)");
        return NULL;
    }
    double floor_ = PyFloat_AsDouble(args[4]);
    if (PyErr_Occurred()) return NULL;
    Buf b[7];
    memset(b, 0, sizeof(b));
    static const char *names[7] = {"R", "t", "H", "inner", "", "T", "K"};
    for (int i = 0; i < 7; i++) {
        if (i == 4) continue;
        if (get_buf(args[i], &b[i], i >= 5, names[i]) < 0) {
            release(b, 7);
            return NULL;
        }
    }
    Py_ssize_t n = b[0].view.ndim == 2 ? b[0].view.shape[0] : -1;
    if (n < 0 || check_2d(&b[0], n, 9, "R") || check_2d(&b[1], n, 3, "t") || check_2d(&b[2], n, 36, "H") ||
        check_2d(&b[3], n, 3, "inner") || check_2d(&b[5], n, 7, "T") || check_2d(&b[6], n, 36, "K")) {
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "R must be (n, 9)");
        release(b, 7);
        return NULL;
    }
    double hmax = -INFINITY;
    int nan = 0;
    for (Py_ssize_t i = 0; i < n && !nan; i++) {
        double s = (AT(b[3], i, 0) + AT(b[3], i, 1) + AT(b[3], i, 2)) / 3.0;
        for (int d = 0; d < 6; d++) {
            double sd = d < 3 ? s : 1.0;
            double v = AT(b[2], i, 7 * d) * (sd * sd);
            if (v != v) {
                nan = 1;
                break;
            }
            if (v > hmax) hmax = v;
        }
    }
    if (nan) hmax = NAN;
    double c = floor_ * hmax;
    for (Py_ssize_t i = 0; i < n; i++) {
        double s = (AT(b[3], i, 0) + AT(b[3], i, 1) + AT(b[3], i, 2)) / 3.0;
        for (int e = 0; e < 36; e++) AT(b[6], i, e) = AT(b[2], i, e);
        if (!(hmax <= 0.0)) {
            for (int d = 0; d < 6; d++) {
                double sd = d < 3 ? s : 1.0;
                AT(b[6], i, 7 * d) += c / (sd * sd);
            }
        }
        double m[3][3], q[4]; /* q: x, y, z, w */
        for (int r = 0; r < 3; r++)
            for (int k = 0; k < 3; k++) m[r][k] = AT(b[0], i, 3 * r + k);
        double tr = m[0][0] + (m[1][1] + m[2][2]); /* Eigen's trace: the unrolled halves */
        if (tr > 0.0) {
            double u = sqrt(tr + 1.0);
            q[3] = 0.5 * u;
            u = 0.5 / u;
            q[0] = (m[2][1] - m[1][2]) * u;
            q[1] = (m[0][2] - m[2][0]) * u;
            q[2] = (m[1][0] - m[0][1]) * u;
        } else {
            int a = 0;
            if (m[1][1] > m[0][0]) a = 1;
            if (m[2][2] > m[a][a]) a = 2;
            int j = (a + 1) % 3, k = (j + 1) % 3;
            double u = sqrt(m[a][a] - m[j][j] - m[k][k] + 1.0);
            q[a] = 0.5 * u;
            u = 0.5 / u;
            q[3] = (m[k][j] - m[j][k]) * u;
            q[j] = (m[j][a] + m[a][j]) * u;
            q[k] = (m[k][a] + m[a][k]) * u;
        }
        for (int d = 0; d < 3; d++) AT(b[5], i, d) = AT(b[1], i, d);
        for (int d = 0; d < 4; d++) AT(b[5], i, 3 + d) = q[d];
    }
    release(b, 7);
    return PyFloat_FromDouble(hmax);
}

/* outline_pixels(R, t, inner, Rwc, centre, K, out)
 *
 * The outline points of ellipsoids (rotations R (n, 9) row-major, centres t (n, 3),
 * semi-axes inner (n, 3); world) projected into an undistorted pinhole camera (world_R_camera
 * Rwc, centre, intrinsics K): out (7n, 2) pixels of each centre, then the ends of its three
 * axes (+), then (-) (kms2pin.ecm.prediction.outline_points); NaN at or behind the camera
 * plane.  kms2pin.ecm.loop's convergence test in pixels (tol_px).
 */
static PyObject *outline_pixels(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 7) {
        PyErr_SetString(PyExc_TypeError, "outline_pixels(R, t, inner, Rwc, centre, K, out)");
        return NULL;
    }
    Buf b[7];
    memset(b, 0, sizeof(b));
    static const char *names[7] = {"R", "t", "inner", "Rwc", "centre", "K", "out"};
    for (int i = 0; i < 7; i++) {
        if (get_buf(args[i], &b[i], i == 6, names[i]) < 0) {
            release(b, 7);
            return NULL;
        }
    }
    Py_ssize_t n = b[0].view.ndim == 2 ? b[0].view.shape[0] : -1;
    if (n < 0 || check_2d(&b[0], n, 9, "R") || check_2d(&b[1], n, 3, "t") || check_2d(&b[2], n, 3, "inner") ||
        check_2d(&b[3], 3, 3, "Rwc") || b[4].view.ndim != 1 || b[4].view.shape[0] != 3 || check_2d(&b[5], 3, 3, "K") ||
        check_2d(&b[6], 7 * n, 2, "out")) {
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "centre must be a 3-vector");
        release(b, 7);
        return NULL;
    }
    double Rwc[3][3], K[3][3], c[3];
    for (int r = 0; r < 3; r++) {
        c[r] = *(double *)((char *)b[4].view.buf + r * b[4].view.strides[0]);
        for (int k = 0; k < 3; k++) {
            Rwc[r][k] = AT(b[3], r, k);
            K[r][k] = AT(b[5], r, k);
        }
    }
    for (Py_ssize_t i = 0; i < n; i++) {
        double t[3], e[3][3]; /* e[k]: axis k's half length, world */
        for (int r = 0; r < 3; r++) t[r] = AT(b[1], i, r);
        for (int k = 0; k < 3; k++)
            for (int r = 0; r < 3; r++) e[k][r] = AT(b[0], i, 3 * r + k) * AT(b[2], i, k);
        for (int m = 0; m < 7; m++) {
            double p[3], pc[3];
            for (int r = 0; r < 3; r++) p[r] = m == 0 ? t[r] : (m <= 3 ? t[r] + e[m - 1][r] : t[r] - e[m - 4][r]);
            for (int k = 0; k < 3; k++) pc[k] = (p[0] - c[0]) * Rwc[0][k] + (p[1] - c[1]) * Rwc[1][k] + (p[2] - c[2]) * Rwc[2][k];
            Py_ssize_t row = 7 * i + m;
            if (pc[2] > 0.0) {
                double x = pc[0] / pc[2], y = pc[1] / pc[2];
                AT(b[6], row, 0) = x * K[0][0] + y * K[0][1] + K[0][2];
                AT(b[6], row, 1) = x * K[1][0] + y * K[1][1] + K[1][2];
            } else {
                AT(b[6], row, 0) = NAN;
                AT(b[6], row, 1) = NAN;
            }
        }
    }
    release(b, 7);
    Py_RETURN_NONE;
}

static PyMethodDef methods[] = {
    {"linearize", (PyCFunction)(void (*)(void))linearize, METH_FASTCALL,
     "linearize(J, X, T, K, S, same_joint, grad, H, diff, hessian) -> (energy, |grad|^2, max diag H)"},
    {"frame_coordinates", (PyCFunction)(void (*)(void))frame_coordinates, METH_FASTCALL,
     "frame_coordinates(rows, joints, offsets, out): out[i] = rows[joints[i]] * offsets[i] (XYZQUAT)"},
    {"ellipsoid_a2", (PyCFunction)(void (*)(void))ellipsoid_a2, METH_FASTCALL,
     "ellipsoid_a2(dirs, A, e, out): closest approach a^2 of every ray to the ellipsoid"},
    {"silhouette_union", (PyCFunction)(void (*)(void))silhouette_union, METH_FASTCALL,
     "silhouette_union(rays, A, e, box, out): the bodies' inner silhouettes ORed into out"},
    {"silhouette_add", (PyCFunction)(void (*)(void))silhouette_add, METH_FASTCALL,
     "silhouette_add(rays, A, e, box, counts): each body's silhouette counted into counts"},
    {"silhouette_swap", (PyCFunction)(void (*)(void))silhouette_swap, METH_FASTCALL,
     "silhouette_swap(rays, A_old, e_old, box_old, A_new, e_new, box_new, counts, mask): the fit's counts' change"},
    {"silhouette_counts", (PyCFunction)(void (*)(void))silhouette_counts, METH_FASTCALL,
     "silhouette_counts(rays, A, e, box, offset, on, off, counts): groups' silhouettes counted on and off"},
    {"silhouette_fit", (PyCFunction)(void (*)(void))silhouette_fit, METH_FASTCALL,
     "silhouette_fit(dirs, A, e, inv, y, o, weight, jac, H, grad) -> (cost, evidence)"},
    {"scale_fit", (PyCFunction)(void (*)(void))scale_fit, METH_FASTCALL,
     "scale_fit(dirs, A, e, R, inner, inv, y, o, weight, H, grad) -> cost: one view's size fit"},
    {"estep_body", (PyCFunction)(void (*)(void))estep_body, METH_FASTCALL,
     "estep_body(dirs, A, e, inv, log_free, v0, u0, rows, cols, sp, log_free_o, widen)"},
    {"estep_view", (PyCFunction)(void (*)(void))estep_view, METH_FASTCALL,
     "estep_view(log_free, mask, v0, u0, rows, cols, sp, o, y)"},
    {"estep_camera", (PyCFunction)(void (*)(void))estep_camera, METH_FASTCALL,
     "estep_camera(rays, A, e, inv, box, offset, mask, log_free, dirs, sp, o, y): one camera's E-step"},
    {"fit_body", (PyCFunction)(void (*)(void))fit_body, METH_FASTCALL,
     "fit_body(views, R, t, inner, iterations, damping, max_step, R_out, t_out, H_out) -> (evidence, cost)"},
    {"fit_bodies", (PyCFunction)(void (*)(void))fit_bodies, METH_FASTCALL,
     "fit_bodies(cams, inv, seen, R, t, inner, iterations, damping, max_step, R, t, H, out): every body's M-step"},
    {"pose_energy", (PyCFunction)(void (*)(void))pose_energy, METH_FASTCALL,
     "pose_energy(X, T, K) -> energy: the full springs' energy alone"},
    {"pose_springs", (PyCFunction)(void (*)(void))pose_springs, METH_FASTCALL,
     "pose_springs(J, X, T, K, S, A, g) -> energy: the tracker's full-spring static update system"},
    {"body_boxes", (PyCFunction)(void (*)(void))body_boxes, METH_FASTCALL,
     "body_boxes(R, t, inner, Rwc, centre, K, delta_px, slack_px, width, height, box, delta, status)"},
    {"closure_terms", (PyCFunction)(void (*)(void))closure_terms, METH_FASTCALL,
     "closure_terms(J, X, moving, kind, end, vec, row, coef, order, r, Jc, H, what): loop closures"},
    {"nullspace_system", (PyCFunction)(void (*)(void))nullspace_system, METH_FASTCALL,
     "nullspace_system(A, g, H, C, N, Hr, gr, lam) -> rank: the Newton system on the constraints' null space"},
    {"all_unit", (PyCFunction)(void (*)(void))all_unit, METH_FASTCALL,
     "all_unit(v, starts, lo2, hi2) -> bool: v finite and its 4-blocks at starts of squared norm in [lo2, hi2]"},
    {"clip_limits", (PyCFunction)(void (*)(void))clip_limits, METH_FASTCALL,
     "clip_limits(q, iq, lo, hi): the limited coordinates of q clipped into their limits, in place"},
    {"hold_limits", (PyCFunction)(void (*)(void))hold_limits, METH_FASTCALL,
     "hold_limits(q, iq, iv, lo_at, hi_at, grad, H) -> |grad|^2: joints held at their limits"},
    {"solve_shifted", (PyCFunction)(void (*)(void))solve_shifted, METH_FASTCALL,
     "solve_shifted(H, grad, shift, step) -> bool: (H + shift I) step = -grad by Cholesky"},
    {"outline_pixels", (PyCFunction)(void (*)(void))outline_pixels, METH_FASTCALL,
     "outline_pixels(R, t, inner, Rwc, centre, K, out): ellipsoids' outline points in a pinhole camera"},
    {"spring_targets", (PyCFunction)(void (*)(void))spring_targets, METH_FASTCALL,
     "spring_targets(R, t, H, inner, floor, T, K) -> hmax: the full springs' targets and stiffnesses"},
    {"twist_prior", (PyCFunction)(void (*)(void))twist_prior, METH_FASTCALL,
     "twist_prior(q, iq, iv, axes, rest, free, k, A, g) -> energy: the twist prior added to A and g"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_kernels", "Native kernels of the static update and the ECM M-step.", -1, methods, NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__kernels(void) { return PyModule_Create(&module); }
