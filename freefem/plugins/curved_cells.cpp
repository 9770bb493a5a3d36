// curved_cells: the quadrature of the 2D and 3D curved cut cells (docs/curved-geometry.md,
// freefem/lib/fd2d/curved.idp and fd3d/curved.idp, which describe the constructions), and the pieces of
// the cut elements' edges that the estimators integrate on, compiled.
//
// Why compiled: both are loops over cut cells and their edges with root searches on
// the exact level set along lines. Interpreted, the 2D construction cost more than the
// rest of the cut geometry together on the default scene, the edge pieces half of the
// estimators, and the 3D cells 11 of the 14 s of the Hertz spheres' geometry (FreeFEM's
// interpreter also reads the process clock twice per statement). Which cells are cut, the level set, the use of the rules and points
// are the script's; this plugin only builds them.
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
//
//   int curvedCellRules3(mesh3 Th, real[int] phiV, real[int] band, real[int] rules,
//                        real[int] ratio, real[int] inBody, real[int] cutK,
//                        real[int] volume, real[int] interface, real[int] counts, real phi)
//   the 3D cells of fd3d/curved.idp curvedCutCells3: phiV the P1 level set's vertex
//       values (off zero), band per element (1 where |phiV| is within about h_K of
//       the surface);
//   rules: nV, nR, nG (at most 64 points each), depthMax (at most 6), then the volume's
//       triangle rule (a, b, w: fd3d/levelset.idp lsTriangleRule), the Gauss rule in r
//       on [0, 1] (t, w), the interface's triangle rule (a, b, w);
//   cutK: in, the element of every P1 interface triangle; out, the cells (those
//       elements once each, then the band elements with an edge whose midpoint has
//       the other sign, then those the surface enters without a vertex or a midpoint
//       inside: the lowest value of the level set in the element is negative);
//   ratio, inBody: per element of Th; set for the cells;
//   volume resized to 5 n: x, y, z, weights, elements; interface to 6 n: x, y, z,
//       weights, elements (of the point), positions of the point's cell in cutK;
//   counts resized to 2: the (sub)cells done on the P1 cut (fallbacks), the volume
//       lines that left their cell inside the body;
//   phi: the level set as an expression of x, y and z.
//   Returns the number of cells, or -1 when the arrays are not sized or laid out as
//   above.
//
//   int cutEdgePieces(mesh Th, real[int] phiV, real[int] segK, real[int] chBg,
//                     real[int] faces, real[int] rule, int exact, real[int] points,
//                     int[int] entryPoint, real[int] entryElement, real phi)
//   the rule of fd2d/estimators.idp fdEstCutEdges: phiV the P1 level set's vertex
//   values, segK the cut elements, chBg the R_rho element of every element, faces =
//   [x0, x1, y0, y1] (the box), then by box-face label (7 each; 0 inside, 1..4 as
//   square() labels the sides) 1 where the face is held strongly, the traction data
//   x, the traction data y; rule = [nG, nodes, weights] (Gauss on [0, 1]); exact = 1
//   to end crossed edges at the root of phi;
//   points: resized to 10 nq (nq = nG per piece): x, y, weight, then per point the R_rho
//       elements of its two sides, 1 on interior edges, the edge's normal (x, y),
//       the face traction (x, y);
//   entryPoint, entryElement: nG per (piece, element it is added to): the point and
//       the element.
//   Returns the number of pieces, or -1 when the arrays are not sized as above or an
//   element of segK is not one of Th's.
//
//   int contactPointGeometry(real[int] px, real[int] py, real[int] pk, real[int] hK,
//                            real[int] params, real[int] out, real phi)
//   fd2d/contact.idp nitscheContactGeometry at the points (px, py) of elements pk
//   (the closest point of {phi = 0}, see project below, and grad phi there):
//   params = [gamma0, step, shiftIn], hK per element; out resized to 6 n: the gaps,
//   gamma = gamma0 h_K, the normals (x, y) of phi at the projections, the projections
//   moved by shiftIn h_K along -n (x, y). Returns n, or -1 when the arrays are not
//   sized as above.
//
//   int levelSetNormals(real[int] px, real[int] py, real step, real[int] out, real phi)
//   the unit normals grad phi/|grad phi| at the points (central differences of
//   half-width step); out resized to 2 n: x, then y. Returns n, or -1 when px and py
//   differ in size or step is not positive.
#include "ff++.hpp"
#include "script_powers.hpp"   // sq: x^2 as the script computes it, so the rules equal the
                                 // interpreted construction's to the bit

#include <algorithm>
#include <cmath>
#include <tuple>
#include <utility>
#include <vector>

namespace {

const int kDepthMax = 2;   // a failing cell is split into four, twice at most
// The 3D rules a script may ask for: points per rule and splitting depth (a cell splits
// into 8^depth sub-cells at most; the shipped scripts use 6 and 1).
const int kRulePointsMax = 64;
const int kDepthMax3 = 6;
const double kCrossingShiftMax = 0.25;   // of an edge: exact against P1 crossing, beyond it a cell fails
// The volume rule's area against the boundary's, relative to the (sub)cell: beyond
// it the s rule is applied on panels, halved until each agrees with its halves to
// this share of the cell times its length, at most kPanelDepthMax times.
const double kVolumeRuleTol = 1e-7;
const int kPanelDepthMax = 30;
// 3D: the volume rule on a piece's parameter triangle against the rule on its four
// children, relative to the (sub)cell's volume; at most kParamDepthMax levels.
const double kVolumeRuleTol3 = 1e-8;
const int kParamDepthMax = 6;
// 3D: an element without a vertex inside counts as entered by the body where phi
// falls below -kEntryDepth h_K in it (shallower entries hold less than 1e-12 h_K^2 R).
const double kEntryDepth = 1e-6;

// Quadrature points as N columns (x, y, [z,] weight, element, ...), copied to the
// script as N blocks of n numbers.
template <int N>
struct Points {
    std::vector<double> c[N];
    template <class... V>
    void add(V... v) {
        static_assert(sizeof...(V) == N, "one value per column");
        const double value[] = {double(v)...};
        for (int i = 0; i < N; i++) c[i].push_back(value[i]);
    }
    size_t size() const { return c[0].size(); }
    void truncate(size_t n) {
        for (int i = 0; i < N; i++) c[i].resize(n);
    }
    double sum(int column, size_t from) const {
        double total = 0;
        for (size_t v = from; v < size(); v++) total += c[column][v];
        return total;
    }
    void copyTo(KN<double> &out) const {
        long n = size();
        out.resize(N * n);
        for (int i = 0; i < N; i++)
            for (long j = 0; j < n; j++) out[i * n + j] = c[i][j];
    }
};
typedef Points<4> Points2;   // x, y, weight, element

// The level set as the script gave it: an expression of the current point.
class LevelSet {
  public:
    LevelSet(Stack stack, Expression phi) : stack_(stack), phi_(phi), mp_(MeshPointStack(stack)) {}
    double operator()(double x, double y) const {
        mp_->set(x, y);
        return GetAny<double>((*phi_)(stack_));
    }
    double operator()(double x, double y, double z) const {
        mp_->set(x, y, z);
        return GetAny<double>((*phi_)(stack_));
    }

  private:
    Stack stack_;
    Expression phi_;
    MeshPoint *mp_;
};

// FreeFEM's plugin idiom, written once for the functions below. The script passes
// arguments of the types Args... and, last, the level set (an expression of x and y).
// The types are listed once, so overload resolution (typeargs) and conversion (the
// constructor) cannot disagree. A call saves FreeFEM's current point, which the level
// set moves, runs Derived::evaluate(stack, levelSet) and restores the point on every
// return path.
typedef KN<double> *Reals;   // a script's real[int]

template <class Derived, class... Args>
class LevelSetFunction : public E_F0mps {
  public:
    typedef long Result;
    explicit LevelSetFunction(const basicAC_F0 &args) {
        args.SetNameParam();
        bind(args, std::index_sequence_for<Args...>());
    }
    static ArrayOfaType typeargs() { return ArrayOfaType(atype<Args>()..., atype<double>()); }
    static E_F0 *f(const basicAC_F0 &args) { return new Derived(args); }

    AnyType operator()(Stack stack) const {
        MeshPoint *mp = MeshPointStack(stack), saved = *mp;
        long result = static_cast<const Derived *>(this)->evaluate(stack, LevelSet(stack, phi_));
        *mp = saved;
        return result;
    }

  protected:
    // Argument I, evaluated (its type is the I-th of Args).
    template <size_t I>
    std::tuple_element_t<I, std::tuple<Args...>> arg(Stack stack) const {
        return GetAny<std::tuple_element_t<I, std::tuple<Args...>>>((*args_[I])(stack));
    }

  private:
    template <size_t... I>
    void bind(const basicAC_F0 &args, std::index_sequence<I...>) {
        Expression bound[] = {to<Args>(args[I])...};
        for (size_t i = 0; i < sizeof...(Args); i++) args_[i] = bound[i];
        phi_ = to<double>(args[sizeof...(Args)]);
    }
    Expression args_[sizeof...(Args)], phi_;
};

// Root lam in [lo, hi] of sgn f(lam), f(lam) = phi(X0 + lam D) (along(lam)), from lam0:
// the rule of core/line_rules.idp lineRootOf (secant steps, bisection whenever a step
// leaves the bracket); ok = 0 when |f| fell neither below 1e-8 of the largest |f| seen
// nor below fTol. The one root search of the 2D and 3D cells.
template <class Along>
bool rootAlong(const Along &phiAlong, double sgn, double lo, double hi, double lam0, double fTol, double &lam) {
    auto along = [&](double l) { return sgn * phiAlong(l); };
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

// rootAlong on the line of the plane from (x0, y0) along (dx, dy).
bool lineRoot(const LevelSet &phi, double x0, double y0, double dx, double dy, double sgn, double lo, double hi,
              double lam0, double fTol, double &lam) {
    return rootAlong([&](double l) { return phi(x0 + l * dx, y0 + l * dy); }, sgn, lo, hi, lam0, fTol, lam);
}

// rootAlong on the line of space from (x0, y0, z0) along (dx, dy, dz).
bool lineRoot3(const LevelSet &phi, double x0, double y0, double z0, double dx, double dy, double dz, double sgn,
               double lo, double hi, double lam0, double fTol, double &lam) {
    return rootAlong([&](double l) { return phi(x0 + l * dx, y0 + l * dy, z0 + l * dz); }, sgn, lo, hi, lam0, fTol,
                     lam);
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

void wholeTriangle(const Rules &q, const double *X, const double *Y, double area, double k, Points2 &vol) {
    for (int g = 0; g < 7; g++) {
        double l1 = q.a7[g], l2 = q.b7[g], l0 = 1. - l1 - l2;
        vol.add(l0 * X[0] + l1 * X[1] + l2 * X[2], l0 * Y[0] + l1 * Y[1] + l2 * Y[2], area * q.w7[g], k);
    }
}

// grad phi by central differences of half-width step: the one gradient of the exact
// level set (the interface's slopes, the projections, the normals).
void gradient(const LevelSet &phi, double px, double py, double step, double &gx, double &gy) {
    gx = (phi(px + step, py) - phi(px - step, py)) / (2. * step);
    gy = (phi(px, py + step) - phi(px, py - step)) / (2. * step);
}

// One pass of the ruled map on a cut (sub)triangle: exact = the interface of phi,
// else the P1 cut (rho = 1). Returns false (and writes nothing) where a root search
// fails or the Jacobian changes sign.
bool ruledMap(const LevelSet &phi, const Rules &q, const double *X, const double *Y, const double *F, int nNeg,
              double subArea, double step, bool exact, double k, Points2 &vol, Points2 &itf) {
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
        // An exact crossing far from the P1 one: the vertex values misread the cut (an
        // edge nearly tangent to the interface, a vertex next to it), and the rays from
        // this base all run along one edge. Left to the split into four.
        ok = okA && okB && fabs(tA - ta) <= kCrossingShiftMax && fabs(tB - tb) <= kCrossingShiftMax;
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
    // The volume points of the lines s in [s0, s1] (the s rule mapped there), and
    // their area.
    auto linesOn = [&](double s0, double s1, double &area) {
        area = 0;
        for (int js = 0; js < q.nS; js++) {
            double s = s0 + (s1 - s0) * q.ts[js], ws = (s1 - s0) * q.ws[js];
            double ex = e0x + s * dEx, ey = e0y + s * dEy;
            double qx = p0x + s * (p1x - p0x) - ex, qy = p0y + s * (p1y - p0y) - ey;
            double rho = 1.;
            if (exact) {
                double lamMax = exitParameter(ox, oy, ax, ay, bx, by, ex, ey, qx, qy);
                bool okR = lineRoot(phi, ex, ey, qx, qy, 1., 0., lamMax, 1., fTol, rho);
                if (!okR || rho <= 0) return false;
            }
            double cEq = dEx * qy - dEy * qx, cQq = dQx * qy - dQy * qx;
            for (int jr = 0; jr < q.nR; jr++) {
                double r = q.tr[jr], det = rho * cEq + r * sq(rho) * cQq;
                if (det * detRef <= 0) return false;
                double w = ws * q.wr[jr] * fabs(det);
                vol.add(ex + r * rho * qx, ey + r * rho * qy, w, k);
                area += w;
            }
        }
        return true;
    };
    double areaLines = 0;   // the s rule on [0, 1]
    ok = ok && linesOn(0., 1., areaLines);
    // interface: the curve over the chord along its unit normal n (toward the outside)
    double lx = p1x - p0x, ly = p1y - p0y, len = sqrt(sq(lx) + sq(ly));
    double nx = -ly / len, ny = lx / len;
    if (nx * qmx + ny * qmy < 0) { nx = -nx; ny = -ny; }
    // a chord below 1e-6 of the cell (a vertex on the interface) is the interface to 1e-12 h
    bool curvedChord = exact && len > 1e-6 * sqrt(2. * subArea);
    double sigmaIntegral = 0;   // of sigma over s in [0, 1], by the interface's rule
    for (int jg = 0; jg < q.nG && ok; jg++) {
        double s = q.tg[jg];
        double px = p0x + s * lx, py = p0y + s * ly;
        double sig = 0., sp = 0.;
        if (curvedChord) {
            double fwd = exitParameter(ox, oy, ax, ay, bx, by, px, py, nx, ny);
            double back = exitParameter(ox, oy, ax, ay, bx, by, px, py, -nx, -ny);
            if (!lineRoot(phi, px, py, nx, ny, 1., -back, fwd, 0., fTol, sig)) { ok = false; break; }
            double cx = px + sig * nx, cy = py + sig * ny;
            double gx, gy;
            gradient(phi, cx, cy, step, gx, gy);
            double gn = gx * nx + gy * ny;
            if (gn <= 0.1 * sqrt(sq(gx) + sq(gy))) { ok = false; break; }   // not a graph over the chord
            sp = -(gx * lx + gy * ly) / gn;
        }
        sigmaIntegral += q.wg[jg] * sig;
        itf.add(px + sig * nx, py + sig * ny, q.wg[jg] * sqrt(sq(len) + sq(sp)), k);
    }
    // The s rule's check. Lines that meet the interface at a shallow angle (an edge
    // crossing it nearly tangentially) make rho vary fast near one end of the chord,
    // and a fixed rule in s misjudges the cell: on an adapted mesh of the disk on slab
    // one element's inside part came out 1.4e-3 too large, the disk 1.1e-6. The boundary
    // gives the area independently, from the interface as a graph over the chord,
    // which stays smooth there: the polygon base-chord plus len times the integral of
    // sigma. Where the two disagree, the s rule is refined adaptively. With fewer than
    // 3 interface points (contact_qp < 3) the boundary's area is rougher and more cells
    // are refined (the disk at NX = 80: 6,624 volume points with contact_qp = 1, 3,912
    // with 3); the panels' own test then sets the accuracy.
    if (ok && curvedChord) {
        double polygon = 0.5 * fabs((p0x - e0x) * (p1y - e0y) - (p1x - e0x) * (p0y - e0y)
                                    + (p1x - e0x) * (e1y - e0y) - (e1x - e0x) * (p1y - e0y));
        if (fabs(areaLines - (polygon + len * sigmaIntegral)) > kVolumeRuleTol * subArea) {
            vol.truncate(nv0);
            struct Panel { double s0, s1, area; int depth; };
            std::vector<Panel> todo(1, Panel{0., 1., areaLines, 0});
            while (!todo.empty() && ok) {
                Panel p = todo.back();
                todo.pop_back();
                double m = 0.5 * (p.s0 + p.s1), aL = 0, aR = 0;
                size_t mark = vol.size();
                ok = linesOn(p.s0, m, aL) && linesOn(m, p.s1, aR);
                if (!ok || fabs(aL + aR - p.area) <= kVolumeRuleTol * subArea * (p.s1 - p.s0)
                    || p.depth >= kPanelDepthMax)
                    continue;
                vol.truncate(mark);
                todo.push_back(Panel{m, p.s1, aR, p.depth + 1});
                todo.push_back(Panel{p.s0, m, aL, p.depth + 1});
            }
        }
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
double cutCell(const LevelSet &phi, const Rules &q, const double *cell, Points2 &vol, Points2 &itf, long &fallbacks) {
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

class CurvedCellRules : public LevelSetFunction<CurvedCellRules, Reals, Reals, Reals, Reals, Reals, Reals> {
  public:
    using LevelSetFunction::LevelSetFunction;

    long evaluate(Stack stack, const LevelSet &levelSet) const {
        KN<double> &cellData = *arg<0>(stack);
        KN<double> &ruleData = *arg<1>(stack);
        KN<double> &ratioK = *arg<2>(stack);
        KN<double> &inBodyK = *arg<3>(stack);
        KN<double> &volumeOut = *arg<4>(stack);
        KN<double> &interfaceOut = *arg<5>(stack);
        Rules q;
        if (!q.read(ruleData) || cellData.N() % 10 != 0) return -1L;
        Points2 vol, itf;
        long fallbacks = 0;
        long nCells = cellData.N() / 10;
        for (long c = 0; c < nCells; c++) {
            const double *cell = &cellData[10 * c];
            size_t nv0 = vol.size();
            double areaK = cutCell(levelSet, q, cell, vol, itf, fallbacks);
            double area = vol.sum(2, nv0);
            long k = lround(cell[0]);
            ratioK[k] = std::min(area / areaK, 1.);
            inBodyK[k] = (area > 0);
        }
        vol.copyTo(volumeOut);
        itf.copyTo(interfaceOut);
        return fallbacks;
    }
};

// ---- The 3D curved cut cells (fd3d/curved.idp, which describes the construction).
// The arithmetic of the maps is the script's (fd3d/levelset.idp lsDet3, lsGradient3),
// written the same way; the volume-rule check and the cells found by the lowest value
// of the level set are the plugin's own (docs/curved-geometry.md).

// 6 x the signed volume of the tetrahedron (a, b, c, d) (fd3d/levelset.idp lsDet3).
inline double tetDet(double ax, double ay, double az, double bx, double by, double bz, double cx, double cy,
                     double cz, double dx, double dy, double dz) {
    return (bx - ax) * ((cy - ay) * (dz - az) - (cz - az) * (dy - ay))
           - (by - ay) * ((cx - ax) * (dz - az) - (cz - az) * (dx - ax))
           + (bz - az) * ((cx - ax) * (dy - ay) - (cy - ay) * (dx - ax));
}

// The determinant of the columns a, b, c.
inline double columnsDet(double ax, double ay, double az, double bx, double by, double bz, double cx, double cy,
                         double cz) {
    return ax * (by * cz - bz * cy) - ay * (bx * cz - bz * cx) + az * (bx * cy - by * cx);
}

void gradient3(const LevelSet &phi, double px, double py, double pz, double step, double &gx, double &gy,
               double &gz) {
    gx = (phi(px + step, py, pz) - phi(px - step, py, pz)) / (2. * step);
    gy = (phi(px, py + step, pz) - phi(px, py - step, pz)) / (2. * step);
    gz = (phi(px, py, pz + step) - phi(px, py, pz - step)) / (2. * step);
}

// The script's rules of the 3D cells: [nV, nR, nG, depthMax], then the volume's triangle rule
// (a, b, w: fd3d/levelset.idp lsTriangleRule), the Gauss rule in r on [0, 1], the
// interface's triangle rule.
struct Rules3 {
    int nV, nR, nG, depthMax;
    const double *va, *vb, *vw, *tr, *wr, *ga, *gb, *gw;

    bool read(const KN<double> &all) {
        if (all.N() < 4) return false;
        for (int j = 0; j < 4; j++)   // rule sizes and a splitting depth a script can mean
            if (!(all[j] >= 0 && all[j] <= (j == 3 ? kDepthMax3 : kRulePointsMax))) return false;
        nV = lround(all[0]); nR = lround(all[1]); nG = lround(all[2]); depthMax = lround(all[3]);
        if (std::min(nV, std::min(nR, nG)) < 1 || all.N() != 4L + 3L * nV + 2L * nR + 3L * nG)
            return false;
        const double *at = &all[0] + 4;
        va = at; vb = (at += nV); vw = (at += nV); tr = (at += nV); wr = (at += nR);
        ga = (at += nR); gb = (at += nG); gw = at + nG;
        return true;
    }
};

// A (sub)tetrahedron: vertices 0..3 and, once split, the edge midpoints 4..9.
struct Tet10 {
    double X[10], Y[10], Z[10], F[10];
};
const int kTetEdgeA[6] = {0, 0, 0, 1, 1, 2}, kTetEdgeB[6] = {1, 2, 3, 2, 3, 3};   // edge j: midpoint 4 + j

// Largest lam with X + lam D in the tetrahedron t (X in it): the line leaves through
// the face whose barycentric coordinate falls to 0 first.
double exitParameter3(const Tet10 &t, double X, double Y, double Z, double DX, double DY, double DZ) {
    const double *x = t.X, *y = t.Y, *z = t.Z;
    double v = tetDet(x[0], y[0], z[0], x[1], y[1], z[1], x[2], y[2], z[2], x[3], y[3], z[3]);
    double l[4], e[4];
    auto bary = [&](double px, double py, double pz, double *b) {
        b[0] = tetDet(px, py, pz, x[1], y[1], z[1], x[2], y[2], z[2], x[3], y[3], z[3]) / v;
        b[1] = tetDet(x[0], y[0], z[0], px, py, pz, x[2], y[2], z[2], x[3], y[3], z[3]) / v;
        b[2] = tetDet(x[0], y[0], z[0], x[1], y[1], z[1], px, py, pz, x[3], y[3], z[3]) / v;
        b[3] = 1. - b[0] - b[1] - b[2];
    };
    bary(X, Y, Z, l);
    bary(X + DX, Y + DY, Z + DZ, e);
    double lamMax = 1e30;
    for (int j = 0; j < 4; j++) {
        double d = e[j] - l[j];
        // a line in face j (l[j] = 0 and d zero but for round-off) does not leave through it
        if (d < -1e-12) lamMax = std::min(lamMax, -std::max(l[j], 0.) / d);
    }
    return lamMax;
}

// Where the line E + lam Q leaves the inside part of the cell: the root rho of phi on
// it (P1 guess 1), or the exit from the cell when phi < 0 there (exits: the inside
// part reaches a face of the cell beyond the chord's circular segment on that face,
// and the interface continues in the neighbour). false when neither.
bool lineEnd3(const LevelSet &phi, const Tet10 &t, double Ex, double Ey, double Ez, double Qx, double Qy, double Qz,
              double fTol, double &rho, bool &exits) {
    double lamMax = exitParameter3(t, Ex, Ey, Ez, Qx, Qy, Qz);
    exits = false;
    bool ok;
    if (lamMax < 1e29 && phi(Ex + lamMax * Qx, Ey + lamMax * Qy, Ez + lamMax * Qz) < 0) {
        exits = true; rho = lamMax; ok = true;
    } else
        ok = lineRoot3(phi, Ex, Ey, Ez, Qx, Qy, Qz, 1., 0., lamMax, std::min(1., lamMax), fTol, rho);
    return ok && rho > 0;
}

// The interface over a chord triangle P(s, t) = P0 + s P_s + t P_t (ps, pt), as the
// graph c = P + sigma nu(P) along the exact unit normal nu = grad phi/|grad phi| at
// the chord point: c depends on P alone, so two elements sharing a face (hence a
// chord edge) bound their pieces by the same curve and the pieces tile the surface;
// the graph of the chord's own normal would not (gaps of O(h^3) along every edge, an
// O(h^2) area error in total). sigma: root of phi along nu (from -phi/|grad phi|);
// area element |c_s x c_t| (returned as the area factor A of the reference triangle,
// weight = A x rule weight), c_s = P_s + sigma_s nu + sigma nu_s with nu_s = (I - nu
// nu') H P_s/|grad phi| (H P_s by central differences of the gradient) and sigma_s =
// -grad phi(c).(P_s + sigma nu_s)/grad phi(c).nu (implicit differentiation of
// phi(c) = 0). false when there is no root within hK or grad phi(c) is almost
// tangent to nu.
bool normalGraph3(const LevelSet &phi, double Px, double Py, double Pz, const double *ps, const double *pt, double hK,
                  double step, double fTol, double &cx, double &cy, double &cz, double &A) {
    double gx, gy, gz;
    gradient3(phi, Px, Py, Pz, step, gx, gy, gz);
    double g = sqrt(sq(gx) + sq(gy) + sq(gz));
    double nx = gx / g, ny = gy / g, nz = gz / g;
    double sig = 0;
    if (!lineRoot3(phi, Px, Py, Pz, nx, ny, nz, 1., -hK, hK, -phi(Px, Py, Pz) / g, fTol, sig)) return false;
    cx = Px + sig * nx; cy = Py + sig * ny; cz = Pz + sig * nz;
    double Cx, Cy, Cz;
    gradient3(phi, cx, cy, cz, step, Cx, Cy, Cz);
    double Cn = Cx * nx + Cy * ny + Cz * nz;
    if (Cn <= 0.1 * sqrt(sq(Cx) + sq(Cy) + sq(Cz))) return false;
    double D[2][3];   // c_s, c_t
    for (int j = 0; j < 2; j++) {
        const double *V = (j == 0) ? ps : pt;
        double L = sqrt(sq(V[0]) + sq(V[1]) + sq(V[2]));
        double e = 1e-2 * hK / std::max(L, 1e-300);   // a displacement of 1e-2 hK along the direction
        double ax, ay, az, bx, by, bz;
        gradient3(phi, Px + e * V[0], Py + e * V[1], Pz + e * V[2], step, ax, ay, az);
        gradient3(phi, Px - e * V[0], Py - e * V[1], Pz - e * V[2], step, bx, by, bz);
        double hx = (ax - bx) / (2. * e), hy = (ay - by) / (2. * e), hz = (az - bz) / (2. * e);
        double hn = hx * nx + hy * ny + hz * nz;
        double ux = (hx - hn * nx) / g, uy = (hy - hn * ny) / g, uz = (hz - hn * nz) / g;   // nu_s
        double ss = -(Cx * (V[0] + sig * ux) + Cy * (V[1] + sig * uy) + Cz * (V[2] + sig * uz)) / Cn;
        D[j][0] = V[0] + ss * nx + sig * ux; D[j][1] = V[1] + ss * ny + sig * uy; D[j][2] = V[2] + ss * nz + sig * uz;
    }
    A = 0.5 * sqrt(sq(D[0][1] * D[1][2] - D[0][2] * D[1][1]) + sq(D[0][2] * D[1][0] - D[0][0] * D[1][2])
                   + sq(D[0][0] * D[1][1] - D[0][1] * D[1][0]));
    return true;
}

// The lowest point of phi on the tetrahedron (X, Y, Z: its 4 vertices), by projected
// gradient descent on the barycentric coordinates (Euclidean projection onto the
// simplex, backtracking steps) from the best of the vertices, edge midpoints, face
// centroids and centroid: the global minimum for a convex phi (a ball, an ellipsoid),
// a local one otherwise. Returns phi there, the point in (mx, my, mz).
double lowestPoint(const LevelSet &phi, const double *X, const double *Y, const double *Z, double step, double &mx,
                   double &my, double &mz) {
    auto at = [&](const double *l, double &px, double &py, double &pz) {
        px = l[0] * X[0] + l[1] * X[1] + l[2] * X[2] + l[3] * X[3];
        py = l[0] * Y[0] + l[1] * Y[1] + l[2] * Y[2] + l[3] * Y[3];
        pz = l[0] * Z[0] + l[1] * Z[1] + l[2] * Z[2] + l[3] * Z[3];
        return phi(px, py, pz);
    };
    double best[4], fBest = 1e300, l[4];
    for (int m = 1; m < 16; m++) {   // the non-empty vertex subsets: their centroids
        int n = 0;
        for (int j = 0; j < 4; j++) n += (m >> j) & 1;
        for (int j = 0; j < 4; j++) l[j] = ((m >> j) & 1) ? 1. / n : 0.;
        double px, py, pz, f = at(l, px, py, pz);
        if (f < fBest) { fBest = f; for (int j = 0; j < 4; j++) best[j] = l[j]; }
    }
    // simplex projection of y (sum 1, entries >= 0)
    auto project = [](double *y) {
        double u[4] = {y[0], y[1], y[2], y[3]};
        std::sort(u, u + 4, [](double a, double b) { return a > b; });
        double sum = 0, tau = 0;
        for (int j = 0; j < 4; j++) {
            sum += u[j];
            double t = (sum - 1.) / (j + 1);
            if (u[j] - t > 0) tau = t;
        }
        for (int j = 0; j < 4; j++) y[j] = std::max(y[j] - tau, 0.);
    };
    double px, py, pz;
    at(best, px, py, pz);
    double alpha = 1.;
    for (int it = 0; it < 60; it++) {
        double gx, gy, gz;
        gradient3(phi, px, py, pz, step, gx, gy, gz);
        double G[4], spread = 0;
        for (int j = 0; j < 4; j++) G[j] = gx * (X[j] - px) + gy * (Y[j] - py) + gz * (Z[j] - pz);
        for (int j = 0; j < 4; j++) spread = std::max(spread, fabs(G[j]));
        if (spread <= 0) break;
        alpha = std::min(4. * alpha, 0.5 / spread);
        bool moved = false;
        for (int halving = 0; halving < 30 && !moved; halving++, alpha *= 0.5) {
            double y[4];
            for (int j = 0; j < 4; j++) y[j] = best[j] - alpha * G[j];
            project(y);
            double qx, qy, qz, f = at(y, qx, qy, qz);
            if (f < fBest) {
                moved = (fBest - f > 1e-14 * step);
                fBest = f; px = qx; py = qy; pz = qz;
                for (int j = 0; j < 4; j++) best[j] = y[j];
                if (!moved) break;
            }
        }
        if (!moved) break;
    }
    mx = px; my = py; mz = pz;
    return fBest;
}

typedef Points<5> Volume3;      // x, y, z, weight, element
typedef Points<6> Interface3;   // x, y, z, weight, element, position of the cell in the cell list

struct Counts3 {
    long fallbacks = 0, exits = 0;
};

// One pass of the ruled maps on a (sub)tetrahedron t with nNeg vertices inside:
// exact = on the interface of phi, else on the P1 cut (rho = 1); a tetrahedron wholly
// inside (nNeg = 4) is one piece on its P1 map. Writes nothing and returns false where
// a crossing or line end is not found, the Jacobian changes sign or the interface is
// not a graph over a chord.
bool ruledMaps3(const LevelSet &phi, const Mesh3 &Th, const Rules3 &q, const Tet10 &t, int nNeg, bool exact,
                bool withInterface, long k, long cell, double hK, double step, Volume3 &vol, Interface3 &itf,
                Counts3 &counts) {
    size_t nv0 = vol.size(), ni0 = itf.size();
    const double *X = t.X, *Y = t.Y, *Z = t.Z, *F = t.F;
    double fTol = 1e-12 * std::max(std::max(fabs(F[0]), fabs(F[1])), std::max(fabs(F[2]), fabs(F[3])));
    double subVolume = fabs(tetDet(X[0], Y[0], Z[0], X[1], Y[1], Z[1], X[2], Y[2], Z[2], X[3], Y[3], Z[3])) / 6.;
    // the pieces: base corners (b) and chord corners (c), 3 per piece
    double bx[6], by[6], bz[6], cx[6], cy[6], cz[6];
    int nPieces = 1;
    bool ok = true;
    int in[4], out[4], nIn = 0, nOut = 0;
    for (int j = 0; j < 4; j++) {
        if (F[j] < 0) in[nIn++] = j; else out[nOut++] = j;
    }
    if (nNeg == 4) {
        for (int j = 0; j < 3; j++) {
            bx[j] = X[0]; by[j] = Y[0]; bz[j] = Z[0];
            cx[j] = X[j + 1]; cy[j] = Y[j + 1]; cz[j] = Z[j + 1];
        }
    } else {
        // crossings on the edges (inside vertex, outside vertex) the pieces use
        int nEdges = (nNeg == 2) ? 4 : 3, ui[4], uo[4];
        if (nNeg == 1) for (int j = 0; j < 3; j++) { ui[j] = in[0]; uo[j] = out[j]; }
        else if (nNeg == 3) for (int j = 0; j < 3; j++) { ui[j] = in[j]; uo[j] = out[0]; }
        else {
            const int i2[4] = {in[0], in[0], in[1], in[1]}, o2[4] = {out[0], out[1], out[1], out[0]};
            for (int j = 0; j < 4; j++) { ui[j] = i2[j]; uo[j] = o2[j]; }
        }
        double px[4] = {0, 0, 0, 0}, py[4] = {0, 0, 0, 0}, pz[4] = {0, 0, 0, 0};
        for (int j = 0; j < nEdges && ok; j++) {
            int a = ui[j], b = uo[j];
            double ta = F[a] / (F[a] - F[b]);   // the P1 crossing, then the root from it
            if (exact) {
                double root;
                ok = lineRoot3(phi, X[a], Y[a], Z[a], X[b] - X[a], Y[b] - Y[a], Z[b] - Z[a], 1., 0., 1., ta, fTol,
                               root);
                if (ok) ta = root;
                // a vertex on the interface: crossings kept 1e-10 of the edge off the vertices
                ta = std::min(std::max(ta, 1e-10), 1. - 1e-10);
            }
            px[j] = X[a] + ta * (X[b] - X[a]);
            py[j] = Y[a] + ta * (Y[b] - Y[a]);
            pz[j] = Z[a] + ta * (Z[b] - Z[a]);
        }
        // pieces: (crossing of corner j, its inside vertex), j = 0..2
        const int corner[6] = {0, 1, 2, 0, 2, 3};
        if (nNeg == 2) nPieces = 2;
        for (int j = 0; j < 3 * nPieces; j++) {
            int u = corner[j];
            bx[j] = X[ui[u]]; by[j] = Y[ui[u]]; bz[j] = Z[ui[u]];
            cx[j] = px[u]; cy[j] = py[u]; cz[j] = pz[u];
        }
    }
    for (int p = 0; p < nPieces && ok; p++) {
        int c0 = 3 * p, c1 = 3 * p + 1, c2 = 3 * p + 2;
        double e1x = bx[c1] - bx[c0], e1y = by[c1] - by[c0], e1z = bz[c1] - bz[c0];
        double e2x = bx[c2] - bx[c0], e2y = by[c2] - by[c0], e2z = bz[c2] - bz[c0];
        double q1x = (cx[c1] - cx[c0]) - e1x, q1y = (cy[c1] - cy[c0]) - e1y, q1z = (cz[c1] - cz[c0]) - e1z;
        double q2x = (cx[c2] - cx[c0]) - e2x, q2y = (cy[c2] - cy[c0]) - e2y, q2z = (cz[c2] - cz[c0]) - e2z;
        // orientation of the P1 map at its centre (rho = 1, s = t = 1/3, r = 1/2)
        double qcx = (cx[c0] + cx[c1] + cx[c2] - bx[c0] - bx[c1] - bx[c2]) / 3.;
        double qcy = (cy[c0] + cy[c1] + cy[c2] - by[c0] - by[c1] - by[c2]) / 3.;
        double qcz = (cz[c0] + cz[c1] + cz[c2] - bz[c0] - bz[c1] - bz[c2]) / 3.;
        double detRef = columnsDet(e1x + 0.5 * q1x, e1y + 0.5 * q1y, e1z + 0.5 * q1z, e2x + 0.5 * q2x,
                                   e2y + 0.5 * q2y, e2z + 0.5 * q2z, qcx, qcy, qcz);
        // The line from the base point of (s, u) through its chord point: start E,
        // direction Q and end rho (1 on the P1 cut); seen gets 1 where the line ends at
        // the root of phi, 2 where it leaves the cell inside the body. false where the
        // end is not found.
        auto lineAt = [&](double s, double u, double &Ex, double &Ey, double &Ez, double &Qx, double &Qy, double &Qz,
                          double &rho, int &seen) {
            Ex = bx[c0] + s * e1x + u * e2x; Ey = by[c0] + s * e1y + u * e2y; Ez = bz[c0] + s * e1z + u * e2z;
            Qx = cx[c0] + s * (cx[c1] - cx[c0]) + u * (cx[c2] - cx[c0]) - Ex;
            Qy = cy[c0] + s * (cy[c1] - cy[c0]) + u * (cy[c2] - cy[c0]) - Ey;
            Qz = cz[c0] + s * (cz[c1] - cz[c0]) + u * (cz[c2] - cz[c0]) - Ez;
            rho = 1.;
            if (!exact) return true;
            bool exits;
            if (!lineEnd3(phi, t, Ex, Ey, Ez, Qx, Qy, Qz, fTol, rho, exits)) return false;
            seen |= exits ? 2 : 1;
            return true;
        };
        // volume: the rule's lines from the base through the chord to the interface, nR
        // points on each; on the parameter triangle (s, u) with corners S, U (the rule
        // mapped there). Returns the volume and, with emit, adds the points; seen as in
        // lineAt; false where a line end is not found or, with emit, the Jacobian
        // changes sign. Without emit (the check below) the Jacobian keeps its sign
        // against the map's orientation: where the lines of a piece cross (lines running
        // past their chord, rho ~ 1.5), the signed integral counts every point of the
        // piece once (the map's degree), where |det| counts the fold twice and failing
        // leaves the rule unchecked (the off-grid ball at nx = 8 had 1.2e-6 of its
        // volume too much in one such cell).
        auto linesOn = [&](const double *S, const double *U, bool emit, double &volume, int &seen) {
            double ds1 = S[1] - S[0], ds2 = S[2] - S[0], du1 = U[1] - U[0], du2 = U[2] - U[0];
            double jac = fabs(ds1 * du2 - ds2 * du1);
            volume = 0;
            for (int g = 0; g < q.nV; g++) {
                double s = S[0] + q.va[g] * ds1 + q.vb[g] * ds2, u = U[0] + q.va[g] * du1 + q.vb[g] * du2;
                double Ex, Ey, Ez, Qx, Qy, Qz, rho;
                int exits = 0;
                if (!lineAt(s, u, Ex, Ey, Ez, Qx, Qy, Qz, rho, exits)) return false;
                if (emit) counts.exits += (exits == 2);
                seen |= exits;
                for (int jr = 0; jr < q.nR; jr++) {
                    double r = q.tr[jr];
                    double det = rho * columnsDet(e1x + r * rho * q1x, e1y + r * rho * q1y, e1z + r * rho * q1z,
                                                  e2x + r * rho * q2x, e2y + r * rho * q2y, e2z + r * rho * q2z, Qx, Qy,
                                                  Qz);
                    if (emit && det * detRef <= 0) return false;
                    double w = 0.5 * q.vw[g] * q.wr[jr] * (detRef > 0 ? det : -det) * jac;
                    if (emit) vol.add(Ex + r * rho * Qx, Ey + r * rho * Qy, Ez + r * rho * Qz, w, k);
                    volume += w;
                }
            }
            return true;
        };
        const double S0[3] = {0., 1., 0.}, U0[3] = {0., 0., 1.};
        size_t mark = vol.size();
        double whole = 0;
        int seenWhole = 0;
        ok = linesOn(S0, U0, true, whole, seenWhole);
        // The rule's check. Where a line leaves the cell through a face (the surface
        // meets that face), rho has a kink along a curve of the parameter triangle, and
        // on coarse cells the rule's own error is large: the fixed rule misjudged the
        // off-grid ball at nx = 16 by 1.6e-5 of its volume. The rule on a parameter
        // triangle is compared with the sum over its four midpoint children; where they
        // differ by more than kVolumeRuleTol3 of the (sub)cell's volume times 2^-depth
        // (the share of a kink curve's length), the children are checked alike, at most
        // kParamDepthMax levels deep. The piece keeps the rule's points (refined points
        // would multiply them by up to 60 on coarse meshes, and the assembly with them)
        // with their weights scaled to the refined volume: the volume, hence the load
        // and the mass, is the refined one; higher moments keep the rule's accuracy. A
        // line whose end is not found in the check leaves the rule as it is.
        // Agreement alone can be a coincidence: a feature between the rule's points (the
        // curve where lines start to leave the cell running into a corner of the
        // triangle or along an edge: a cell vertex on or near the surface, an edge
        // tangent to it) is missed by the rule and by its children alike, at every
        // level (where all lines leave the cell the map is a polyhedron, integrated
        // exactly, so the two agree to round-off); such cells held the scene ball's
        // 4.2e-8 at nx = 8 and the off-grid ball's 5e-8 at nx = 16 and 32.
        // The lines at the triangle's corners and edge midpoints see it: where they
        // end otherwise (root or exit) than all the children's lines, the triangle is
        // refined whatever the agreement.
        if (ok && exact && whole > 0) {
            struct Param { double S[3], U[3], volume; int depth; };
            auto split = [](const Param &p, Param *kids) {   // the four midpoint children
                double ms[3] = {0.5 * (p.S[0] + p.S[1]), 0.5 * (p.S[1] + p.S[2]), 0.5 * (p.S[2] + p.S[0])};
                double mu[3] = {0.5 * (p.U[0] + p.U[1]), 0.5 * (p.U[1] + p.U[2]), 0.5 * (p.U[2] + p.U[0])};
                const double cs[4][3] = {{p.S[0], ms[0], ms[2]}, {ms[0], p.S[1], ms[1]}, {ms[2], ms[1], p.S[2]},
                                         {ms[1], ms[2], ms[0]}};
                const double cu[4][3] = {{p.U[0], mu[0], mu[2]}, {mu[0], p.U[1], mu[1]}, {mu[2], mu[1], p.U[2]},
                                         {mu[1], mu[2], mu[0]}};
                for (int c = 0; c < 4; c++) {
                    for (int j = 0; j < 3; j++) { kids[c].S[j] = cs[c][j]; kids[c].U[j] = cu[c][j]; }
                    kids[c].depth = p.depth + 1;
                }
            };
            double tol = kVolumeRuleTol3 * subVolume, refined = 0;
            bool checked = true;
            std::vector<Param> todo(1, Param{{0., 1., 0.}, {0., 0., 1.}, whole, 0});
            while (!todo.empty() && checked) {
                Param p = todo.back(), kids[4];
                todo.pop_back();
                split(p, kids);
                double sum = 0;
                int seenKids = 0, seenCorners = 0;
                for (int c = 0; c < 4 && checked; c++) {
                    checked = linesOn(kids[c].S, kids[c].U, false, kids[c].volume, seenKids);
                    sum += kids[c].volume;
                }
                if (!checked) break;
                for (int j = 0; j < 3; j++) {   // the corners and edge midpoints (the inner child's corners)
                    double Ex, Ey, Ez, Qx, Qy, Qz, rho;
                    lineAt(p.S[j], p.U[j], Ex, Ey, Ez, Qx, Qy, Qz, rho, seenCorners);
                    lineAt(kids[3].S[j], kids[3].U[j], Ex, Ey, Ez, Qx, Qy, Qz, rho, seenCorners);
                }
                bool hidden = (seenCorners & ~seenKids) != 0;
                if ((!hidden && fabs(sum - p.volume) <= tol * std::pow(0.5, p.depth)) || p.depth + 1 >= kParamDepthMax)
                    refined += sum;
                else
                    for (int c = 0; c < 4; c++) todo.push_back(kids[c]);
            }
            if (checked && refined != whole)
                for (size_t v = mark; v < vol.size(); v++) vol.c[3][v] *= refined / whole;
        }
        if (nNeg == 4 || !withInterface) continue;   // no interface in a cell wholly inside
        // interface: nG points of the chord moved along the exact normal of the chord
        // point (normalGraph3); a cell on the P1 cut keeps the chord
        const double ps[3] = {cx[c1] - cx[c0], cy[c1] - cy[c0], cz[c1] - cz[c0]};
        const double pt[3] = {cx[c2] - cx[c0], cy[c2] - cy[c0], cz[c2] - cz[c0]};
        for (int g = 0; g < q.nG && ok; g++) {
            double s = q.ga[g], u = q.gb[g];
            double Px = cx[c0] + s * ps[0] + u * pt[0], Py = cy[c0] + s * ps[1] + u * pt[1],
                   Pz = cz[c0] + s * ps[2] + u * pt[2];
            double ix = Px, iy = Py, iz = Pz;
            double A = 0.5 * sqrt(sq(ps[1] * pt[2] - ps[2] * pt[1]) + sq(ps[2] * pt[0] - ps[0] * pt[2])
                                  + sq(ps[0] * pt[1] - ps[1] * pt[0]));
            long kc = k;
            if (exact) {
                if (!normalGraph3(phi, Px, Py, Pz, ps, pt, hK, step, fTol, ix, iy, iz, A)) { ok = false; break; }
                // the element that holds the point (the script's Th(x, y, z).nuTriangle)
                R3 hat;
                bool outside;
                const Mesh3::Element *K = Th.Find(R3(ix, iy, iz), hat, outside);
                if (K) kc = Th(K);
            }
            itf.add(ix, iy, iz, q.gw[g] * A, kc, cell);
        }
    }
    if (!ok) { vol.truncate(nv0); itf.truncate(ni0); }
    return ok;
}

// The inside part of the element k of Th and its interface (curvedCutCells3 states
// the rule): the element and, where the map fails or an edge's midpoint has the other
// sign, its eight children (edge midpoints), down to depthMax; what still fails there
// is done on its P1 cut (counted in fallbacks). Returns the element's volume.
double cutCell3(const LevelSet &phi, const Mesh3 &Th, const Rules3 &q, const KN<double> &phiV, long k, long cell,
                int depthMax, Volume3 &vol, Interface3 &itf, Counts3 &counts) {
    const Mesh3::Element &K = Th[k];
    double volK = fabs(tetDet(K[0].x, K[0].y, K[0].z, K[1].x, K[1].y, K[1].z, K[2].x, K[2].y, K[2].z, K[3].x,
                              K[3].y, K[3].z)) / 6.;
    double hK = std::pow(6. * volK, 1. / 3.);
    double tiny = 1e-10 * hK;   // as lsKeepOffZero: values within it count as outside
    double step = 1e-4 * hK;    // central differences: truncation and round-off ~1e-10
    // volumeOnly: a part of an element split around its lowest point (below), whose
    // surface the neighbours' interface graphs already cover
    struct Sub { Tet10 t; int depth; bool volumeOnly; };
    std::vector<Sub> stack(1);
    for (int j = 0; j < 4; j++) {
        stack[0].t.X[j] = K[j].x; stack[0].t.Y[j] = K[j].y; stack[0].t.Z[j] = K[j].z;
        stack[0].t.F[j] = phiV[Th(k, j)];
    }
    stack[0].depth = 0;
    stack[0].volumeOnly = false;
    // the eight children of a split cell: vertices 0..3, edge midpoints 4..9
    static const int child[32] = {0, 4, 5, 6, 4, 1, 7, 8, 5, 7, 2, 9, 6, 8, 9, 3,
                                  5, 8, 4, 6, 5, 8, 6, 9, 5, 8, 9, 7, 5, 8, 7, 4};
    while (!stack.empty()) {
        Sub c = stack.back();
        stack.pop_back();
        Tet10 &t = c.t;
        bool anomaly = false;
        for (int e = 0; e < 6; e++) {
            int a = kTetEdgeA[e], b = kTetEdgeB[e];
            t.X[4 + e] = 0.5 * (t.X[a] + t.X[b]); t.Y[4 + e] = 0.5 * (t.Y[a] + t.Y[b]); t.Z[4 + e] = 0.5 * (t.Z[a] + t.Z[b]);
            double m = phi(t.X[4 + e], t.Y[4 + e], t.Z[4 + e]);
            if (fabs(m) < tiny) m = tiny;
            t.F[4 + e] = m;
            if ((t.F[a] < 0) == (t.F[b] < 0) && (m < 0) != (t.F[a] < 0)) anomaly = true;
        }
        int nNeg = (t.F[0] < 0) + (t.F[1] < 0) + (t.F[2] < 0) + (t.F[3] < 0);
        if (nNeg == 0 && (!anomaly || c.depth >= depthMax)) {
            // No vertex inside, yet the body may enter through a face or across an
            // edge without reaching a vertex or a midpoint (a dome through a face: the
            // off-grid ball at nx = 8 lost 1.3e-5 of its volume in two such elements).
            // Split around the lowest point of phi when it is inside: each of the four
            // tetrahedra (point, face) has one vertex inside and its own map.
            double mx, my, mz;
            double fm = lowestPoint(phi, t.X, t.Y, t.Z, step, mx, my, mz);
            if (fm < -kEntryDepth * hK) {
                double cx = 0.25 * (t.X[0] + t.X[1] + t.X[2] + t.X[3]), cy = 0.25 * (t.Y[0] + t.Y[1] + t.Y[2] + t.Y[3]),
                       cz = 0.25 * (t.Z[0] + t.Z[1] + t.Z[2] + t.Z[3]);
                // off the faces (the lowest point is often on one), where phi stays below 0
                double nx = mx + 1e-2 * (cx - mx), ny = my + 1e-2 * (cy - my), nz = mz + 1e-2 * (cz - mz);
                double fn = phi(nx, ny, nz);
                if (fn < -tiny) { mx = nx; my = ny; mz = nz; fm = fn; }
                double whole = fabs(tetDet(t.X[0], t.Y[0], t.Z[0], t.X[1], t.Y[1], t.Z[1], t.X[2], t.Y[2], t.Z[2],
                                           t.X[3], t.Y[3], t.Z[3]));
                for (int f = 0; f < 4; f++) {   // face f: the vertices other than f
                    Sub s;
                    int n = 0;
                    for (int j = 0; j < 4; j++)
                        if (j != f) { s.t.X[n] = t.X[j]; s.t.Y[n] = t.Y[j]; s.t.Z[n] = t.Z[j]; s.t.F[n] = t.F[j]; n++; }
                    s.t.X[3] = mx; s.t.Y[3] = my; s.t.Z[3] = mz; s.t.F[3] = fm;
                    double part = fabs(tetDet(s.t.X[0], s.t.Y[0], s.t.Z[0], s.t.X[1], s.t.Y[1], s.t.Z[1], s.t.X[2],
                                              s.t.Y[2], s.t.Z[2], s.t.X[3], s.t.Y[3], s.t.Z[3]));
                    if (part <= 1e-12 * whole) continue;   // the point on that face
                    s.depth = c.depth;
                    s.volumeOnly = true;
                    stack.push_back(s);
                }
                continue;
            }
        }
        bool done = false;
        if (anomaly && c.depth >= depthMax) counts.fallbacks++;   // the anomaly is ignored at the deepest level
        if (anomaly && c.depth < depthMax) done = false;
        else if (nNeg == 0) done = true;
        else {
            // pass 0 on the exact interface, pass 1 (deepest level only) on the P1 cut
            for (int pass = 0; pass < 2 && !done; pass++) {
                if (pass == 1 && c.depth < depthMax) break;
                if (pass == 1) counts.fallbacks++;
                done = ruledMaps3(phi, Th, q, t, nNeg, pass == 0 && nNeg < 4, !c.volumeOnly, k, cell, hK, step, vol,
                                  itf, counts);
            }
        }
        if (done) continue;
        if (c.depth >= depthMax) {   // deepest level and both passes failed: a flat sub-cell (no volume)
            counts.fallbacks++;
            continue;
        }
        for (int ch = 0; ch < 8; ch++) {   // split into eight; the values at the midpoints are known
            Sub s;
            for (int j = 0; j < 4; j++) {
                int v = child[4 * ch + j];
                s.t.X[j] = t.X[v]; s.t.Y[j] = t.Y[v]; s.t.Z[j] = t.Z[v]; s.t.F[j] = t.F[v];
            }
            s.depth = c.depth + 1;
            s.volumeOnly = c.volumeOnly;
            stack.push_back(s);
        }
    }
    return volK;
}

// The 3D cells' list and rules (fd3d/curved.idp curvedCutCells3, which states them).
class CurvedCellRules3
    : public LevelSetFunction<CurvedCellRules3, pmesh3, Reals, Reals, Reals, Reals, Reals, Reals, Reals, Reals, Reals> {
  public:
    using LevelSetFunction::LevelSetFunction;

    long evaluate(Stack stack, const LevelSet &levelSet) const {
        const Mesh3 &Th = *arg<0>(stack);
        const KN<double> &phiV = *arg<1>(stack);
        const KN<double> &band = *arg<2>(stack);
        const KN<double> &ruleData = *arg<3>(stack);
        KN<double> &ratio = *arg<4>(stack);
        KN<double> &inBody = *arg<5>(stack);
        KN<double> &cutK = *arg<6>(stack);
        KN<double> &volumeOut = *arg<7>(stack);
        KN<double> &interfaceOut = *arg<8>(stack);
        KN<double> &countsOut = *arg<9>(stack);
        Rules3 q;
        if (!q.read(ruleData) || phiV.N() != Th.nv || band.N() != Th.nt || ratio.N() != Th.nt
            || inBody.N() != Th.nt)
            return -1L;
        for (long s = 0; s < cutK.N(); s++)
            if (!(cutK[s] >= 0 && lround(cutK[s]) < Th.nt)) return -1L;
        // the cut elements once each, then the band elements with an edge whose midpoint
        // has the other sign
        std::vector<char> marked(Th.nt, 0);
        std::vector<long> cells;
        for (long s = 0; s < cutK.N(); s++) {
            long k = lround(cutK[s]);
            if (marked[k]) continue;
            marked[k] = 1;
            cells.push_back(k);
        }
        for (long k = 0; k < Th.nt; k++) {
            if (band[k] < 0.5 || marked[k]) continue;
            bool anomaly = false;
            for (int e = 0; e < 6 && !anomaly; e++) {
                int i0 = Th(k, kTetEdgeA[e]), i1 = Th(k, kTetEdgeB[e]);
                double m = levelSet(0.5 * (Th(i0).x + Th(i1).x), 0.5 * (Th(i0).y + Th(i1).y), 0.5 * (Th(i0).z + Th(i1).z));
                anomaly = ((m < 0) != (phiV[i0] < 0));
            }
            bool outside = true;
            for (int j = 0; j < 4; j++) outside = outside && phiV[Th(k, j)] >= 0;
            if (!anomaly && outside) {   // entered without a vertex or a midpoint inside (cutCell3 splits it)
                double X[4], Y[4], Z[4], mx, my, mz;
                for (int j = 0; j < 4; j++) { X[j] = Th[k][j].x; Y[j] = Th[k][j].y; Z[j] = Th[k][j].z; }
                double hK = std::pow(fabs(tetDet(X[0], Y[0], Z[0], X[1], Y[1], Z[1], X[2], Y[2], Z[2], X[3], Y[3], Z[3])), 1. / 3.);
                anomaly = lowestPoint(levelSet, X, Y, Z, 1e-4 * hK, mx, my, mz) < -kEntryDepth * hK;
            }
            if (!anomaly) continue;
            marked[k] = 1;
            cells.push_back(k);
        }
        Volume3 vol;
        Interface3 itf;
        Counts3 counts;
        cutK.resize(cells.size());
        for (size_t c = 0; c < cells.size(); c++) {
            long k = cells[c];
            cutK[(long)c] = k;
            size_t nv0 = vol.size();
            double volK = cutCell3(levelSet, Th, q, phiV, k, c, q.depthMax, vol, itf, counts);
            double inside = vol.sum(3, nv0);
            ratio[k] = (volK > 0) ? std::min(inside / volK, 1.) : 0.;
            inBody[k] = (inside > 0);
        }
        vol.copyTo(volumeOut);
        itf.copyTo(interfaceOut);
        countsOut.resize(2);
        countsOut[0] = counts.fallbacks;
        countsOut[1] = counts.exits;
        return (long)cells.size();
    }
};

// The estimators' cut-edge pieces (fd2d/estimators.idp fdEstCutEdges, which states
// the rule): every edge of the cut elements restricted to the body, as one piece
// shared by the elements it is added to, with its Gauss points and what each point
// reads (the R_rho elements of its two sides, whether it is interior, the edge's
// normal, the traction data of the box face it lies on).
class CutEdgePieces
    : public LevelSetFunction<CutEdgePieces, pmesh, Reals, Reals, Reals, Reals, Reals, long, Reals, KN<long> *, Reals> {
  public:
    using LevelSetFunction::LevelSetFunction;

    long evaluate(Stack stack, const LevelSet &levelSet) const {
        const Mesh &Th = *arg<0>(stack);
        const KN<double> &phiBg = *arg<1>(stack);
        const KN<double> &cut = *arg<2>(stack);
        const KN<double> &chosen = *arg<3>(stack);
        const KN<double> &faceData = *arg<4>(stack);
        const KN<double> &gauss = *arg<5>(stack);
        bool onExact = arg<6>(stack) != 0;
        KN<double> &pointsOut = *arg<7>(stack);
        KN<long> &entryPointOut = *arg<8>(stack);
        KN<double> &entryElementOut = *arg<9>(stack);
        if (gauss.N() < 1) return -1L;
        int nG = lround(gauss[0]);
        if (nG < 1 || gauss.N() != 1 + 2 * nG || phiBg.N() != Th.nv || chosen.N() != Th.nt || faceData.N() != 25)
            return -1L;
        const double *gt = &gauss[1], *gw = &gauss[1 + nG];
        double x0 = faceData[0], x1 = faceData[1], y0 = faceData[2], y1 = faceData[3];
        const double *heldFace = &faceData[4], *faceTx = &faceData[11], *faceTy = &faceData[18];
        // box face of an edge (square() labels: 1 bottom, 2 right, 3 top, 4 left; 0 none)
        auto boxFace = [&](double ax, double ay, double bx, double by) {
            if (fabs(ay - y0) + fabs(by - y0) < 1e-10) return 1;
            if (fabs(ax - x1) + fabs(bx - x1) < 1e-10) return 2;
            if (fabs(ay - y1) + fabs(by - y1) < 1e-10) return 3;
            if (fabs(ax - x0) + fabs(bx - x0) < 1e-10) return 4;
            return 0;
        };
        for (long s = 0; s < cut.N(); s++)
            if (!(cut[s] >= 0 && cut[s] < Th.nt)) return -1L;
        std::vector<char> isCut(Th.nt, 0);
        for (long s = 0; s < cut.N(); s++) isCut[lround(cut[s])] = 1;
        std::vector<long> pieceOf(3 * Th.nt, -1);
        // per piece: its inside and outside vertices, its ends, and what its points read
        struct Piece { int iN, iP; double ax, ay, bx, by, sa, sb, inner, nx, ny, tx, ty; };
        std::vector<Piece> pieces;
        std::vector<long> entryP, entryK;
        for (long s = 0; s < cut.N(); s++) {
            int k = lround(cut[s]);
            for (int e = 0; e < 3; e++) {
                int ia = Th(k, (e + 1) % 3), ib = Th(k, (e + 2) % 3);
                double fa = phiBg[ia], fb = phiBg[ib];
                if (fa >= 0 && fb >= 0) continue;
                int iN = (fa < 0) ? ia : ib, iP = (fa < 0) ? ib : ia;
                int ee = e, kk = Th.ElementAdj(k, ee);
                bool inner = (kk >= 0 && kk != k);
                long piece = -1;
                if (inner && isCut[kk])
                    for (int f = 0; f < 3; f++) {
                        long pf = pieceOf[3 * kk + f];
                        if (pf >= 0 && pieces[pf].iN == iN && pieces[pf].iP == iP) piece = pf;
                    }
                if (piece < 0) {
                    double fN = phiBg[iN], fP = phiBg[iP], t = 1.;
                    double nX = Th(iN).x, nY = Th(iN).y, pX = Th(iP).x, pY = Th(iP).y;
                    int face = inner ? 0 : boxFace(nX, nY, pX, pY);
                    if (!inner && heldFace[face] > 0.5) continue;   // held strongly: exact
                    if (fP >= 0) {
                        t = fN / (fN - fP);
                        double root;
                        if (onExact && lineRoot(levelSet, nX, nY, pX - nX, pY - nY, 1., 0., 1., t,
                                                1e-12 * std::max(-fN, fP), root))
                            t = root;
                    }
                    double ex = pX - nX, ey = pY - nY, len = sqrt(sq(ex) + sq(ey));
                    Piece p = {iN, iP, nX, nY, nX + t * ex, nY + t * ey, chosen[k], inner ? chosen[kk] : chosen[k],
                               inner ? 1. : 0., ey / len, -ex / len, faceTx[face], faceTy[face]};
                    piece = pieces.size();
                    pieces.push_back(p);
                }
                pieceOf[3 * k + e] = piece;
                entryP.push_back(piece); entryK.push_back(k);
                if (inner && !isCut[kk]) { entryP.push_back(piece); entryK.push_back(kk); }   // its side too
            }
        }
        // the pieces' Gauss points (fd2d/levelset.idp lsSegmentQuadrature), 10 blocks:
        // x, y, w, then per point sa, sb, inner, nx, ny, tx, ty
        long nq = pieces.size() * nG;
        pointsOut.resize(10 * nq);
        for (size_t p = 0; p < pieces.size(); p++) {
            const Piece &c = pieces[p];
            double len = sqrt(sq(c.bx - c.ax) + sq(c.by - c.ay));
            const double value[7] = {c.sa, c.sb, c.inner, c.nx, c.ny, c.tx, c.ty};
            for (int g = 0; g < nG; g++) {
                long q = p * nG + g;
                pointsOut[q] = c.ax + gt[g] * (c.bx - c.ax);
                pointsOut[nq + q] = c.ay + gt[g] * (c.by - c.ay);
                pointsOut[2 * nq + q] = len * gw[g];
                for (int v = 0; v < 7; v++) pointsOut[(3 + v) * nq + q] = value[v];
            }
        }
        long nE = entryP.size();
        entryPointOut.resize(nE * nG);
        entryElementOut.resize(nE * nG);
        for (long j = 0; j < nE; j++)
            for (int g = 0; g < nG; g++) {
                entryPointOut[j * nG + g] = entryP[j] * nG + g;
                entryElementOut[j * nG + g] = entryK[j];
            }
        return (long)pieces.size();
    }
};

void projectNormal(const LevelSet &phi, double &qx, double &qy, double step) {
    for (int it = 0; it < 3; it++) {
        double gx, gy;
        gradient(phi, qx, qy, step, gx, gy);
        double f = phi(qx, qy), g2 = std::max(sq(gx) + sq(gy), 1e-300);
        qx -= f * gx / g2;
        qy -= f * gy / g2;
        if (fabs(f) < 1e-14) break;
    }
}

// Closest point (qx, qy) of {phi = 0} to (px, py): first x - phi grad phi/|grad phi|^2,
// iterated onto the zero set (projectNormal: exact in one step for a signed distance
// to a line or a circle); then, because that foot point is the closest one only for
// such distances (ellipses, unions, expressions are not), the tangential part of
// x - q is added and the point projected again, until x - q is normal to the curve
// at q (at most 30 times; a kink of a union or intersection may stop it earlier, on
// the curve).
void project(const LevelSet &phi, double px, double py, double step, double &qx, double &qy) {
    qx = px; qy = py;
    projectNormal(phi, qx, qy, step);
    for (int it = 0; it < 30; it++) {
        double nx, ny;
        gradient(phi, qx, qy, step, nx, ny);
        double n = std::max(sqrt(sq(nx) + sq(ny)), 1e-300);
        nx /= n; ny /= n;
        double dx = px - qx, dy = py - qy, dn = dx * nx + dy * ny;
        double tx = dx - dn * nx, ty = dy - dn * ny;
        // the central-difference normal carries about 1e-9 of relative noise
        if (sqrt(sq(tx) + sq(ty)) <= 1e-8 * sqrt(sq(dx) + sq(dy)) + 1e-6 * step) break;
        qx += tx; qy += ty;
        projectNormal(phi, qx, qy, step);
    }
}

// The contact points' geometry (fd2d/contact.idp nitscheContactGeometry, which states
// it): projections onto body 2's level set, gaps, normals and gamma.
class ContactPointGeometry : public LevelSetFunction<ContactPointGeometry, Reals, Reals, Reals, Reals, Reals, Reals> {
  public:
    using LevelSetFunction::LevelSetFunction;

    long evaluate(Stack stack, const LevelSet &levelSet) const {
        const KN<double> &x = *arg<0>(stack);
        const KN<double> &y = *arg<1>(stack);
        const KN<double> &k = *arg<2>(stack);
        const KN<double> &h = *arg<3>(stack);
        const KN<double> &p = *arg<4>(stack);
        KN<double> &o = *arg<5>(stack);
        long n = x.N();
        if (y.N() != n || k.N() != n || p.N() != 3) return -1L;
        for (long q = 0; q < n; q++)
            if (!(k[q] >= 0 && k[q] < h.N())) return -1L;
        double gamma0 = p[0], step = p[1], shiftIn = p[2];
        o.resize(6 * n);
        for (long q = 0; q < n; q++) {
            double fx, fy, gx, gy;
            project(levelSet, x[q], y[q], step, fx, fy);
            gradient(levelSet, fx, fy, step, gx, gy);
            double gn = sqrt(sq(gx) + sq(gy)), nx = gx / gn, ny = gy / gn, hq = h[lround(k[q])];
            o[q] = (x[q] - fx) * nx + (y[q] - fy) * ny;
            o[n + q] = gamma0 * hq;
            o[2 * n + q] = nx;
            o[3 * n + q] = ny;
            o[4 * n + q] = fx - shiftIn * hq * nx;
            o[5 * n + q] = fy - shiftIn * hq * ny;
        }
        return n;
    }
};

// Unit normals grad phi/|grad phi| at points (fd2d/levelset.idp lsGradient's central
// differences): the cut boundaries' normals of the Nitsche holds and the estimators.
class LevelSetNormals : public LevelSetFunction<LevelSetNormals, Reals, Reals, double, Reals> {
  public:
    using LevelSetFunction::LevelSetFunction;

    long evaluate(Stack stack, const LevelSet &levelSet) const {
        const KN<double> &x = *arg<0>(stack);
        const KN<double> &y = *arg<1>(stack);
        double h = arg<2>(stack);
        KN<double> &o = *arg<3>(stack);
        long n = x.N();
        if (y.N() != n || !(h > 0)) return -1L;
        o.resize(2 * n);
        for (long q = 0; q < n; q++) {
            double gx, gy;
            gradient(levelSet, x[q], y[q], h, gx, gy);
            double gn = sqrt(sq(gx) + sq(gy));
            o[q] = gx / gn;
            o[n + q] = gy / gn;
        }
        return n;
    }
};

}  // namespace

static void Load_Init() {
    Global.Add("levelSetNormals", "(", new OneOperatorCode<LevelSetNormals>());
    Global.Add("contactPointGeometry", "(", new OneOperatorCode<ContactPointGeometry>());
    Global.Add("curvedCellRules", "(", new OneOperatorCode<CurvedCellRules>());
    Global.Add("curvedCellRules3", "(", new OneOperatorCode<CurvedCellRules3>());
    Global.Add("cutEdgePieces", "(", new OneOperatorCode<CutEdgePieces>());
}

LOADFUNC(Load_Init)
