// curved_cells: the quadrature of the 2D curved cut cells (docs/curved-geometry.md,
// freefem/lib/fd2d/curved.idp, which describes the construction), compiled.
//
// Why compiled: the construction is a loop over cut cells with root searches on the
// exact level set along lines; interpreted, it cost more than the rest of the cut
// geometry together on the default scene. Which cells are cut, the level set, the
// use of the rules are the script's; this plugin only builds the rules.
//
// Script interface:
//   int curvedCellRules(real[int] cells, real[int] rules, real[int] ratio,
//                       real[int] inBody, real[int] volume, real[int] interface,
//                       real phi)
//   cells: 10 numbers per cut cell: its element number, then x0 x1 x2 y0 y1 y2 of its
//       vertices and f0 f1 f2, the level set's vertex values (off zero);
//   rules: the script's quadrature rules (core/line_rules.idp lsGaussLegendre,
//       fd2d/levelset.idp lsTriangleRule7), concatenated: nS, nR, nG (the points in s
//       and r of the volume map and on the interface piece), the nodes and weights of
//       the three Gauss rules on [0, 1] (ts ws tr wr tg wg), then the barycentric
//       coordinates a, b and weights w of the 7-point triangle rule;
//   ratio, inBody: per element of the mesh; set for the cells' elements
//       (|K cap {phi < 0}|/|K|, at most 1, and 1 where that part is not empty);
//   volume, interface: resized to 4 n (n points): x of every point, then y, then
//       weights, then element numbers;
//   phi: the level set as an expression of x and y (the script's current point),
//       evaluated at the points the construction asks for.
//   Returns the number of (sub)cells done on the P1 cut (fallbacks), or -1 when the
//   rules or the cells are not laid out as above.
#include "ff++.hpp"
#include "script_powers.hpp"   // sq: x^2 as the script computes it, so the rules equal the
                                 // interpreted construction's to the bit

#include <cmath>
#include <vector>

namespace {

const int kDepthMax = 2;   // a failing cell is split into four, twice at most

struct Points {
    std::vector<double> x, y, w, k;
    void add(double px, double py, double pw, double pk) {
        x.push_back(px); y.push_back(py); w.push_back(pw); k.push_back(pk);
    }
    size_t size() const { return x.size(); }
    void truncate(size_t n) { x.resize(n); y.resize(n); w.resize(n); k.resize(n); }
    void copyTo(KN<double> &out) const {
        long n = size();
        out.resize(4 * n);
        for (long i = 0; i < n; i++) {
            out[i] = x[i]; out[n + i] = y[i]; out[2 * n + i] = w[i]; out[3 * n + i] = k[i];
        }
    }
};

// The level set as the script gave it: an expression of the current point.
class LevelSet {
  public:
    LevelSet(Stack stack, Expression phi) : stack_(stack), phi_(phi), mp_(MeshPointStack(stack)) {}
    double operator()(double x, double y) const {
        mp_->set(x, y);
        return GetAny<double>((*phi_)(stack_));
    }

  private:
    Stack stack_;
    Expression phi_;
    MeshPoint *mp_;
};

// Root lam in [lo, hi] of sgn phi(X0 + lam D), from lam0: the rule of core/line_rules.idp
// lineRootOf (secant steps, bisection whenever a step leaves the bracket); ok = 0 when
// |f| fell neither below 1e-8 of the largest |f| seen nor below fTol.
bool lineRoot(const LevelSet &phi, double x0, double y0, double dx, double dy, double sgn, double lo, double hi,
              double lam0, double fTol, double &lam) {
    auto along = [&](double l) { return sgn * phi(x0 + l * dx, y0 + l * dy); };
    double bLo = lo, bHi = hi;
    double x = lam0, f = along(x);
    double fMax = fabs(f);
    if (fabs(f) <= fTol) fMax = -1;   // the guess is a root (a straight interface)
    if (f < 0) bLo = x; else bHi = x;
    double xp = x + ((f < 0) ? 1e-4 : -1e-4) * (hi - lo);
    if (fMax < 0) xp = x;
    xp = std::min(std::max(xp, lo), hi);
    double fp = f;
    if (fMax >= 0) fp = along(xp);
    fMax = std::max(fMax, fabs(fp));
    if (fp < 0) bLo = std::max(bLo, xp); else bHi = std::min(bHi, xp);
    if (fabs(fp) < fabs(f)) { std::swap(x, xp); std::swap(f, fp); }
    for (int i = 0; i < 80 && f != 0 && fabs(f) > fTol * 1e-3; i++) {
        double n = 0.5 * (bLo + bHi);
        if (f != fp) n = x - f * (x - xp) / (f - fp);
        if (!(n > bLo && n < bHi)) n = 0.5 * (bLo + bHi);
        double fn = along(n);
        fMax = std::max(fMax, fabs(fn));
        if (fn < 0) bLo = n; else bHi = n;
        xp = x; fp = f; x = n; f = fn;
        if (fabs(x - xp) <= 1e-14 * (1. + fabs(x)) || bHi - bLo <= 1e-15 * (1. + fabs(x))) break;
    }
    lam = x;
    return fabs(f) <= std::max(1e-8 * fMax, fTol);
}

// Largest lam with X + lam D in the triangle (o, a, b) (X in it).
double exitParameter(double ox, double oy, double ax, double ay, double bx, double by, double X, double Y, double DX,
                     double DY) {
    double det = (ax - ox) * (by - oy) - (bx - ox) * (ay - oy);
    double la = ((X - ox) * (by - oy) - (bx - ox) * (Y - oy)) / det;
    double lb = ((ax - ox) * (Y - oy) - (X - ox) * (ay - oy)) / det;
    double da = (DX * (by - oy) - (bx - ox) * DY) / det;
    double db = ((ax - ox) * DY - DX * (ay - oy)) / det;
    double lo = 1. - la - lb, dO = -da - db;
    double lamMax = 1e30;
    if (da < 0) lamMax = std::min(lamMax, -std::max(la, 0.) / da);
    if (db < 0) lamMax = std::min(lamMax, -std::max(lb, 0.) / db);
    if (dO < 0) lamMax = std::min(lamMax, -std::max(lo, 0.) / dO);
    return lamMax;
}

// The script's rules: pointers into its concatenated array (see the interface above).
struct Rules {
    int nS, nR, nG;
    const double *ts, *ws, *tr, *wr, *tg, *wg, *a7, *b7, *w7;

    // false when `all` does not hold the layout of the interface above
    bool read(const KN<double> &all) {
        if (all.N() < 3) return false;
        nS = lround(all[0]); nR = lround(all[1]); nG = lround(all[2]);
        if (std::min(nS, std::min(nR, nG)) < 1 || all.N() != 3 + 2 * (nS + nR + nG) + 21) return false;
        const double *at = &all[0] + 3;
        ts = at; ws = (at += nS); tr = (at += nS); wr = (at += nR); tg = (at += nR); wg = (at += nG);
        a7 = (at += nG); b7 = at + 7; w7 = at + 14;
        return true;
    }
};

// The odd vertex o of a cut (sub)triangle and the P1 crossings ta, tb on o-a and o-b
// (fd2d/levelset.idp lsCrossing).
void crossing(const double *f, int nNeg, int &o, int &a, int &b, double &ta, double &tb) {
    if (nNeg == 1) o = (f[0] < 0) ? 0 : ((f[1] < 0) ? 1 : 2);
    else o = (f[0] >= 0) ? 0 : ((f[1] >= 0) ? 1 : 2);
    a = (o + 1) % 3;
    b = (o + 2) % 3;
    ta = f[o] / (f[o] - f[a]);
    tb = f[o] / (f[o] - f[b]);
}

void wholeTriangle(const Rules &q, const double *X, const double *Y, double area, double k, Points &vol) {
    for (int g = 0; g < 7; g++) {
        double l1 = q.a7[g], l2 = q.b7[g], l0 = 1. - l1 - l2;
        vol.add(l0 * X[0] + l1 * X[1] + l2 * X[2], l0 * Y[0] + l1 * Y[1] + l2 * Y[2], area * q.w7[g], k);
    }
}

// One pass of the ruled map on a cut (sub)triangle: exact = the interface of phi,
// else the P1 cut (rho = 1). Returns false (and writes nothing) where a root search
// fails or the Jacobian changes sign.
bool ruledMap(const LevelSet &phi, const Rules &q, const double *X, const double *Y, const double *F, int nNeg,
              double subArea, double step, bool exact, double k, Points &vol, Points &itf) {
    size_t nv0 = vol.size(), ni0 = itf.size();
    int o, a, b;
    double ta, tb;
    crossing(F, nNeg, o, a, b, ta, tb);
    double ox = X[o], oy = Y[o], ax = X[a], ay = Y[a], bx = X[b], by = Y[b];
    double fTol = 1e-12 * std::max(fabs(F[0]), std::max(fabs(F[1]), fabs(F[2])));
    double tA = ta, tB = tb;
    bool ok = true;
    if (exact) {
        double sgn = (nNeg == 1) ? 1. : -1.;   // negative at o
        bool okA = lineRoot(phi, ox, oy, ax - ox, ay - oy, sgn, 0., 1., ta, fTol, tA);
        bool okB = lineRoot(phi, ox, oy, bx - ox, by - oy, sgn, 0., 1., tb, fTol, tB);
        ok = okA && okB;
        // a vertex on the interface: crossings kept 1e-10 of the edge off the vertices
        tA = std::min(std::max(tA, 1e-10), 1. - 1e-10);
        tB = std::min(std::max(tB, 1e-10), 1. - 1e-10);
    }
    // base E0-E1 (the inside vertex o, or the inside edge a-b) and chord P0-P1
    double e0x = ox, e0y = oy, e1x = ox, e1y = oy;
    if (nNeg == 2) { e0x = ax; e0y = ay; e1x = bx; e1y = by; }
    double p0x = ox + tA * (ax - ox), p0y = oy + tA * (ay - oy);
    double p1x = ox + tB * (bx - ox), p1y = oy + tB * (by - oy);
    double dEx = e1x - e0x, dEy = e1y - e0y;
    double dQx = (p1x - p0x) - dEx, dQy = (p1y - p0y) - dEy;
    // orientation of the P1 map at its centre (rho = 1, s = r = 1/2)
    double qmx = p0x + 0.5 * (p1x - p0x) - e0x - 0.5 * dEx, qmy = p0y + 0.5 * (p1y - p0y) - e0y - 0.5 * dEy;
    double detRef = (dEx * qmy - dEy * qmx) + 0.5 * (dQx * qmy - dQy * qmx);
    for (int js = 0; js < q.nS && ok; js++) {
        double s = q.ts[js];
        double ex = e0x + s * dEx, ey = e0y + s * dEy;
        double qx = p0x + s * (p1x - p0x) - ex, qy = p0y + s * (p1y - p0y) - ey;
        double rho = 1.;
        if (exact) {
            double lamMax = exitParameter(ox, oy, ax, ay, bx, by, ex, ey, qx, qy);
            bool okR = lineRoot(phi, ex, ey, qx, qy, 1., 0., lamMax, 1., fTol, rho);
            if (!okR || rho <= 0) { ok = false; break; }
        }
        double cEq = dEx * qy - dEy * qx, cQq = dQx * qy - dQy * qx;
        for (int jr = 0; jr < q.nR; jr++) {
            double r = q.tr[jr], det = rho * cEq + r * sq(rho) * cQq;
            if (det * detRef <= 0) { ok = false; break; }
            vol.add(ex + r * rho * qx, ey + r * rho * qy, q.ws[js] * q.wr[jr] * fabs(det), k);
        }
    }
    // interface: the curve over the chord along its unit normal n (toward the outside)
    double lx = p1x - p0x, ly = p1y - p0y, len = sqrt(sq(lx) + sq(ly));
    double nx = -ly / len, ny = lx / len;
    if (nx * qmx + ny * qmy < 0) { nx = -nx; ny = -ny; }
    for (int jg = 0; jg < q.nG && ok; jg++) {
        double s = q.tg[jg];
        double px = p0x + s * lx, py = p0y + s * ly;
        double sig = 0., sp = 0.;
        // a chord below 1e-6 of the cell (a vertex on the interface) is the interface to 1e-12 h
        if (exact && len > 1e-6 * sqrt(2. * subArea)) {
            double fwd = exitParameter(ox, oy, ax, ay, bx, by, px, py, nx, ny);
            double back = exitParameter(ox, oy, ax, ay, bx, by, px, py, -nx, -ny);
            if (!lineRoot(phi, px, py, nx, ny, 1., -back, fwd, 0., fTol, sig)) { ok = false; break; }
            double cx = px + sig * nx, cy = py + sig * ny;
            double gx = (phi(cx + step, cy) - phi(cx - step, cy)) / (2. * step);
            double gy = (phi(cx, cy + step) - phi(cx, cy - step)) / (2. * step);
            double gn = gx * nx + gy * ny;
            if (gn <= 0.1 * sqrt(sq(gx) + sq(gy))) { ok = false; break; }   // not a graph over the chord
            sp = -(gx * lx + gy * ly) / gn;
        }
        itf.add(px + sig * nx, py + sig * ny, q.wg[jg] * sqrt(sq(len) + sq(sp)), k);
    }
    if (!ok) { vol.truncate(nv0); itf.truncate(ni0); }
    return ok;
}

struct SubCell {
    double X[3], Y[3], F[3];
    int depth;
};

// The inside part of one cut element and its interface: the cell and, where it fails,
// its four children (edge midpoints), down to kDepthMax; what still fails there is
// done on its P1 cut (counted in fallbacks). Returns the element's area.
double cutCell(const LevelSet &phi, const Rules &q, const double *cell, Points &vol, Points &itf, long &fallbacks) {
    double k = cell[0];
    const double *x = cell + 1, *y = cell + 4, *f = cell + 7;
    double areaK = 0.5 * fabs((x[1] - x[0]) * (y[2] - y[0]) - (x[2] - x[0]) * (y[1] - y[0]));
    double tiny = 1e-10 * sqrt(2. * areaK);   // as lsKeepOffZero: values within it count as outside
    double step = 1e-4 * sqrt(2. * areaK);    // central differences: truncation and round-off ~1e-10
    std::vector<SubCell> stack(1);
    for (int j = 0; j < 3; j++) { stack[0].X[j] = x[j]; stack[0].Y[j] = y[j]; stack[0].F[j] = f[j]; }
    stack[0].depth = 0;
    while (!stack.empty()) {
        SubCell c = stack.back();
        stack.pop_back();
        double X[6], Y[6], F[6];   // vertices 0..2, edge midpoints 3 (0-1), 4 (1-2), 5 (2-0)
        for (int j = 0; j < 3; j++) { X[j] = c.X[j]; Y[j] = c.Y[j]; F[j] = c.F[j]; }
        bool anomaly = false;
        for (int j = 0; j < 3; j++) {
            int j1 = (j + 1) % 3;
            X[3 + j] = 0.5 * (X[j] + X[j1]);
            Y[3 + j] = 0.5 * (Y[j] + Y[j1]);
            double m = phi(X[3 + j], Y[3 + j]);
            if (fabs(m) < tiny) m = tiny;
            F[3 + j] = m;
            if ((F[j] < 0) == (F[j1] < 0) && (m < 0) != (F[j] < 0)) anomaly = true;
        }
        int nNeg = (F[0] < 0) + (F[1] < 0) + (F[2] < 0);
        double subArea = 0.5 * fabs((X[1] - X[0]) * (Y[2] - Y[0]) - (X[2] - X[0]) * (Y[1] - Y[0]));
        bool done = false;
        if (!anomaly && nNeg == 0) done = true;
        if (!anomaly && nNeg == 3) { wholeTriangle(q, X, Y, subArea, k, vol); done = true; }
        if (!anomaly && (nNeg == 1 || nNeg == 2)) {
            done = ruledMap(phi, q, X, Y, F, nNeg, subArea, step, true, k, vol, itf);
            if (!done && c.depth >= kDepthMax) {
                fallbacks++;
                done = ruledMap(phi, q, X, Y, F, nNeg, subArea, step, false, k, vol, itf);
            }
        }
        if (done) continue;
        if (c.depth < kDepthMax) {   // split into four; the values at the midpoints are known
            static const int child[12] = {0, 3, 5, 3, 1, 4, 5, 4, 2, 3, 4, 5};
            for (int ch = 0; ch < 4; ch++) {
                SubCell s;
                for (int j = 0; j < 3; j++) {
                    int v = child[3 * ch + j];
                    s.X[j] = X[v]; s.Y[j] = Y[v]; s.F[j] = F[v];
                }
                s.depth = c.depth + 1;
                stack.push_back(s);
            }
        } else if (nNeg == 3) {   // deepest level, edge anomaly left: taken whole (P1)
            fallbacks++;
            wholeTriangle(q, X, Y, subArea, k, vol);
        } else if (nNeg == 0) fallbacks++;   // deepest level, edge anomaly left: taken empty (P1)
    }
    return areaK;
}

class CurvedCellRules : public E_F0mps {
  public:
    typedef long Result;
    Expression cells, rules, ratio, inBody, volume, interface, phi;

    explicit CurvedCellRules(const basicAC_F0 &args) {
        args.SetNameParam();
        cells = to<KN<double> *>(args[0]);
        rules = to<KN<double> *>(args[1]);
        ratio = to<KN<double> *>(args[2]);
        inBody = to<KN<double> *>(args[3]);
        volume = to<KN<double> *>(args[4]);
        interface = to<KN<double> *>(args[5]);
        phi = to<double>(args[6]);
    }
    static ArrayOfaType typeargs() {
        return ArrayOfaType(atype<KN<double> *>(), atype<KN<double> *>(), atype<KN<double> *>(),
                            atype<KN<double> *>(), atype<KN<double> *>(), atype<KN<double> *>(), atype<double>());
    }
    static E_F0 *f(const basicAC_F0 &args) { return new CurvedCellRules(args); }

    AnyType operator()(Stack stack) const {
        KN<double> &cellData = *GetAny<KN<double> *>((*cells)(stack));
        KN<double> &ruleData = *GetAny<KN<double> *>((*rules)(stack));
        KN<double> &ratioK = *GetAny<KN<double> *>((*ratio)(stack));
        KN<double> &inBodyK = *GetAny<KN<double> *>((*inBody)(stack));
        KN<double> &volumeOut = *GetAny<KN<double> *>((*volume)(stack));
        KN<double> &interfaceOut = *GetAny<KN<double> *>((*interface)(stack));
        Rules q;
        if (!q.read(ruleData) || cellData.N() % 10 != 0) return -1L;
        MeshPoint *mp = MeshPointStack(stack), saved = *mp;
        LevelSet levelSet(stack, phi);
        Points vol, itf;
        long fallbacks = 0;
        long nCells = cellData.N() / 10;
        for (long c = 0; c < nCells; c++) {
            const double *cell = &cellData[10 * c];
            size_t nv0 = vol.size();
            double areaK = cutCell(levelSet, q, cell, vol, itf, fallbacks);
            double area = 0;
            for (size_t v = nv0; v < vol.size(); v++) area += vol.w[v];
            long k = lround(cell[0]);
            ratioK[k] = std::min(area / areaK, 1.);
            inBodyK[k] = (area > 0);
        }
        *mp = saved;
        vol.copyTo(volumeOut);
        itf.copyTo(interfaceOut);
        return fallbacks;
    }
};

}  // namespace

static void Load_Init() { Global.Add("curvedCellRules", "(", new OneOperatorCode<CurvedCellRules>()); }

LOADFUNC(Load_Init)
