// pressure_recovery: the recovered contact pressure of freefem/lib/core/pressure_recovery.idp
// (which states the fit: a weighted least-squares plane of the raw multiplier over
// the points within a radius), compiled.
//
// Why compiled, and with cells of the smallest radius: every point near a pressure
// reads the points within its radius. The interpreted version found them through
// cells of the largest radius, which on a graded 3D mesh (fine where the contact is,
// coarse around it) put most of the contact points in every window: quadratic in
// the number of points, most of the graded reference's output stage. Here each
// point reads the cells its own radius reaches, and the window is sorted by
// distance, then by point number: a fit's sums do not depend on the cells.
//
// Script interface:
//   int pressureRecoveryFitWith(real[int] options, real[int] qx, real[int] qy,
//                               real[int] qz, real[int] nqx, real[int] nqy, real[int] nqz,
//                               real[int] qw, real[int] pRaw, real[int] radius,
//                               real[int] pRec)
//   pRec (resized to the number of points) = the recovered pressure at each point,
//   options = [dim, degree, activeOnly]: dim 2 reads qz and nqz but takes the tangent
//   (-ny, nx); degree 1 fits the plane, 2 adds the squares and the product of the
//   tangential coordinates; activeOnly = 1 fits only at the points whose raw pressure
//   is positive (the active points: the law's multiplier is positive exactly there),
//   the others recovering 0. Returns the number of points fitted, -1 when the arrays'
//   sizes differ, a radius is not positive or the options are not of that form.
#include "ff++.hpp"
#include "script_powers.hpp"   // sq, cube: x^2, x^3 as the script computes them

#include <algorithm>
#include <cmath>
#include <utility>
#include <vector>

namespace {

double sumOf(const std::vector<double> &a) {
    double s = 0;
    for (double v : a) s += v;
    return s;
}

double dot(const std::vector<double> &a, const std::vector<double> &b) {
    double s = 0;
    for (size_t i = 0; i < a.size(); i++) s += a[i] * b[i];
    return s;
}

// Solves the symmetric system m x = b of size n (row-major) by Gaussian elimination
// with partial pivoting; false when a pivot falls below tol times the largest
// diagonal entry (the window's points do not determine the fit).
bool solveSmall(int n, std::vector<double> m, std::vector<double> b, double tol, std::vector<double> &x) {
    double scale = 0;
    for (int i = 0; i < n; i++) scale = std::max(scale, fabs(m[i * n + i]));
    for (int c = 0; c < n; c++) {
        int piv = c;
        for (int r = c + 1; r < n; r++)
            if (fabs(m[r * n + c]) > fabs(m[piv * n + c])) piv = r;
        if (!(fabs(m[piv * n + c]) > tol * scale)) return false;
        if (piv != c) {
            for (int k = 0; k < n; k++) std::swap(m[c * n + k], m[piv * n + k]);
            std::swap(b[c], b[piv]);
        }
        for (int r = c + 1; r < n; r++) {
            double f = m[r * n + c] / m[c * n + c];
            for (int k = c; k < n; k++) m[r * n + k] -= f * m[c * n + k];
            b[r] -= f * b[c];
        }
    }
    x.assign(n, 0.);
    for (int r = n - 1; r >= 0; r--) {
        double v = b[r];
        for (int k = r + 1; k < n; k++) v -= m[r * n + k] * x[k];
        x[r] = v / m[r * n + r];
    }
    return true;
}

// The constant term of the quadratic fit a + b s + c t + d s^2 + e s t + f t^2 (2D:
// a + b s + d s^2) of p with weights w; false when the window does not determine it.
bool quadraticFit(int dim, const std::vector<double> &w, const std::vector<double> &s, const std::vector<double> &t,
                  const std::vector<double> &p, double &a) {
    int n = (dim == 3) ? 6 : 3;
    std::vector<double> m(n * n, 0.), b(n, 0.), phi(n), x;
    for (size_t c = 0; c < w.size(); c++) {
        if (dim == 3) {
            phi[0] = 1; phi[1] = s[c]; phi[2] = t[c]; phi[3] = s[c] * s[c]; phi[4] = s[c] * t[c]; phi[5] = t[c] * t[c];
        } else {
            phi[0] = 1; phi[1] = s[c]; phi[2] = s[c] * s[c];
        }
        for (int i = 0; i < n; i++) {
            b[i] += w[c] * phi[i] * p[c];
            for (int j = 0; j < n; j++) m[i * n + j] += w[c] * phi[i] * phi[j];
        }
    }
    if (!solveSmall(n, m, b, 1e-10, x)) return false;
    a = x[0];
    return true;
}

long recover(int dim, int degree, bool activeOnly, const KN_<double> &qx, const KN_<double> &qy, const KN_<double> &qz, const KN_<double> &nqx,
             const KN_<double> &nqy, const KN_<double> &nqz, const KN_<double> &qw, const KN_<double> &pRaw,
             const KN_<double> &radius, KN<double> &pRec) {
    long n = qx.N();
    pRec.resize(n);
    pRec = 0.;
    if (n == 0 || pRaw.max() <= 0) return 0;
    if (!(radius.min() > 0)) return -1;
    // cells of the smallest radius, coarser when there would be more than 4 per point;
    // a point's window reads the cells within its own radius around its cell
    double cell = radius.min();
    double x0 = qx.min(), y0 = qy.min(), z0 = qz.min();
    long nx = 1, ny = 1, nz = 1, cells = 0;
    for (int attempt = 0; attempt < 200; attempt++) {
        nx = 1 + lround(floor((qx.max() - x0) / cell));
        ny = 1 + lround(floor((qy.max() - y0) / cell));
        nz = 1 + lround(floor((qz.max() - z0) / cell));
        cells = nx * ny * nz;
        if (cells <= 4 * n + 1000) break;
        cell *= 1.5;
    }
    std::vector<long> cx(n), cy(n), cz(n), order(n), start(cells + 1, 0);
    for (long i = 0; i < n; i++) {
        cx[i] = std::min(nx - 1, lround(floor((qx[i] - x0) / cell)));
        cy[i] = std::min(ny - 1, lround(floor((qy[i] - y0) / cell)));
        cz[i] = std::min(nz - 1, lround(floor((qz[i] - z0) / cell)));
        start[cx[i] + nx * (cy[i] + ny * cz[i]) + 1]++;
    }
    // the points of cell c are order[start[c] .. start[c + 1] - 1], by index
    for (long c = 0; c < cells; c++) start[c + 1] += start[c];
    {
        std::vector<long> next(start.begin(), start.end() - 1);
        for (long i = 0; i < n; i++) order[next[cx[i] + nx * (cy[i] + ny * cz[i])]++] = i;
    }
    // only points within the largest radius of a point with a pressure can fit one
    double low[3] = {1e300, 1e300, 1e300}, high[3] = {-1e300, -1e300, -1e300};
    for (long i = 0; i < n; i++)
        if (pRaw[i] > 0) {
            low[0] = std::min(low[0], qx[i]); low[1] = std::min(low[1], qy[i]); low[2] = std::min(low[2], qz[i]);
            high[0] = std::max(high[0], qx[i]); high[1] = std::max(high[1], qy[i]); high[2] = std::max(high[2], qz[i]);
        }
    double reach = radius.max();
    for (int d = 0; d < 3; d++) { low[d] -= reach; high[d] += reach; }
    long fitted = 0;
    std::vector<std::pair<double, long>> near;
    std::vector<double> dx, dy, dz, w, p, s, t, ws, wt;
    for (long i = 0; i < n; i++) {
        if (activeOnly && !(pRaw[i] > 0)) continue;
        if (qx[i] < low[0] || qx[i] > high[0] || qy[i] < low[1] || qy[i] > high[1] || qz[i] < low[2]
            || qz[i] > high[2])
            continue;
        // the points within the radius (cells within ceil(r/cell) of x_i's: a cell index
        // differs from x_i's by at most that along each axis), by distance, then index
        double r = radius[i], limit = sq(r) * (1. + 1e-12);
        long k = std::max(1L, lround(ceil(r / cell)));
        long kz = (dim == 3) ? k : 0;
        near.clear();
        for (long jz = std::max(cz[i] - kz, 0L); jz <= std::min(cz[i] + kz, nz - 1); jz++)
            for (long jy = std::max(cy[i] - k, 0L); jy <= std::min(cy[i] + k, ny - 1); jy++) {
                long row = nx * (jy + ny * jz);
                long first = start[std::max(cx[i] - k, 0L) + row], end = start[std::min(cx[i] + k, nx - 1) + row + 1];
                for (long c = first; c < end; c++) {
                    long j = order[c];
                    double ex = qx[j] - qx[i], ey = qy[j] - qy[i], ez = qz[j] - qz[i];
                    double d2 = ex * ex + ey * ey + ez * ez;
                    if (d2 < limit) near.emplace_back(d2, j);
                }
            }
        std::sort(near.begin(), near.end());
        long inside = near.size();
        if (inside == 0) continue;
        dx.resize(inside); dy.resize(inside); dz.resize(inside); w.resize(inside); p.resize(inside);
        for (long c = 0; c < inside; c++) {
            long j = near[c].second;
            dx[c] = qx[j] - qx[i]; dy[c] = qy[j] - qy[i]; dz[c] = qz[j] - qz[i];
            w[c] = qw[j]; p[c] = pRaw[j];
        }
        // tangents: 2D (-ny, nx); 3D t1 = n x e (e the axis least aligned with n), t2 = n x t1
        double t1x = -nqy[i], t1y = nqx[i], t1z = 0, t2x = 0, t2y = 0, t2z = 0;
        if (dim == 3) {
            if (fabs(nqx[i]) <= fabs(nqy[i]) && fabs(nqx[i]) <= fabs(nqz[i])) {
                t1x = 0; t1y = nqz[i]; t1z = -nqy[i];
            } else if (fabs(nqy[i]) <= fabs(nqz[i])) {
                t1x = -nqz[i]; t1y = 0; t1z = nqx[i];
            } else {
                t1x = nqy[i]; t1y = -nqx[i]; t1z = 0;
            }
            double norm = sqrt(sq(t1x) + sq(t1y) + sq(t1z));
            t1x /= norm; t1y /= norm; t1z /= norm;
            t2x = nqy[i] * t1z - nqz[i] * t1y;
            t2y = nqz[i] * t1x - nqx[i] * t1z;
            t2z = nqx[i] * t1y - nqy[i] * t1x;
        }
        // the tangential coordinates s, t of the window's points, in units of the radius
        s.resize(inside); t.resize(inside); ws.resize(inside); wt.resize(inside);
        for (long c = 0; c < inside; c++) {
            s[c] = (t1x / r) * dx[c];
            t[c] = (t2x / r) * dx[c];
            s[c] += (t1y / r) * dy[c];
            s[c] += (t1z / r) * dz[c];
            t[c] += (t2y / r) * dy[c];
            t[c] += (t2z / r) * dz[c];
            ws[c] = w[c] * s[c];
            wt[c] = w[c] * t[c];
        }
        // normal equations of the fit
        double m00 = sumOf(w), m01 = sumOf(ws), m02 = sumOf(wt);
        double m11 = dot(ws, s), m12 = dot(ws, t), m22 = dot(wt, t);
        double b0 = dot(w, p), b1 = dot(ws, p), b2 = dot(wt, p);
        if (m00 <= 0) continue;
        // the constant term by Cramer's rule; a window whose points do not span the
        // tangent(s) keeps its weighted mean
        double a = b0 / m00;
        if (dim == 3) {
            double det = m00 * (m11 * m22 - sq(m12)) - m01 * (m01 * m22 - m12 * m02) + m02 * (m01 * m12 - m11 * m02);
            if (det > 1e-8 * cube(m00))
                a = (b0 * (m11 * m22 - sq(m12)) - m01 * (b1 * m22 - m12 * b2) + m02 * (b1 * m12 - m11 * b2)) / det;
        } else {
            double det = m00 * m11 - sq(m01);
            if (det > 1e-8 * sq(m00)) a = (b0 * m11 - m01 * b1) / det;
        }
        // degree 2: the quadratic's constant term where the window determines it (else
        // the plane's): the plane's value at x_i is the window's weighted mean minus a
        // term of the curvature times radius^2, which flattens a peak a few windows wide
        if (degree == 2) {
            double aq;
            if (quadraticFit(dim, w, s, t, p, aq)) a = aq;
        }
        pRec[i] = std::max(a, 0.);
        fitted++;
    }
    return fitted;
}

// pressureRecoveryFitWith(options, qx, qy, qz, nqx, nqy, nqz, qw, pRaw, radius, pRec),
// options = [dim, degree, activeOnly]
class PressureRecoveryFitWith : public E_F0mps {
  public:
    typedef long Result;
    Expression arrays[11];

    explicit PressureRecoveryFitWith(const basicAC_F0 &args) {
        args.SetNameParam();
        for (int a = 0; a < 11; a++) arrays[a] = to<KN<double> *>(args[a]);
    }
    static ArrayOfaType typeargs() {
        aType v = atype<KN<double> *>();
        return ArrayOfaType(v, v, v, v, v, v, v, v, v, v, v);
    }
    static E_F0 *f(const basicAC_F0 &args) { return new PressureRecoveryFitWith(args); }

    AnyType operator()(Stack stack) const {
        KN<double> *a[11];
        for (int k = 0; k < 11; k++) a[k] = GetAny<KN<double> *>((*arrays[k])(stack));
        const KN<double> &o = *a[0];
        if (o.N() != 3) return -1L;
        long d = lround(o[0]), g = lround(o[1]), act = lround(o[2]);
        if ((d != 2 && d != 3) || (g != 1 && g != 2) || (act != 0 && act != 1)) return -1L;
        long n = a[1]->N();
        for (int k = 1; k < 10; k++)
            if (a[k]->N() != n) return -1L;
        return recover(d, g, act == 1, *a[1], *a[2], *a[3], *a[4], *a[5], *a[6], *a[7], *a[8], *a[9], *a[10]);
    }
};

}  // namespace

static void Load_Init() {
    Global.Add("pressureRecoveryFitWith", "(", new OneOperatorCode<PressureRecoveryFitWith>());
}

LOADFUNC(Load_Init)
