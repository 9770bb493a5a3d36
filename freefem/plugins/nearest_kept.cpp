// nearest_kept: the submesh element nearest to a point, for the 3D solver's points
// and elements that fall outside a body's submesh (freefem/lib/fd3d/spaces.idp,
// fdKeptPoints and fdKeptSubstitute).
//
// Script interface:
//   int nearestKeptElements(mesh3 Th, real[int] inBody, real[int] start, real[int] px,
//                           real[int] py, real[int] pz, int rings, real[int] kOut,
//                           real[int] score)
//       for each point i, among the background element start[i] and `rings` rings of
//       its face neighbours (each ring in the order it is reached, through faces 0 to
//       3), the element with inBody >= 0.5 in which (px[i], py[i], pz[i]) has the
//       largest smallest barycentric coordinate (0 on the element, about -d/h_K at a
//       distance d): kOut[i] its number (-1 if none), score[i] that coordinate
//       (-1e300 if none). Returns the number of points, or -1 when the arrays'
//       sizes differ or an element number is out of range.
//
// Why compiled: the script's search (a ring of neighbours built with a linear
// look-up of the elements already seen, then the barycentric coordinates in each)
// executes some ten thousand statements per point, and FreeFEM's interpreter pays a
// system call per statement (docs/benchmarks.md): at P2, h = 1/30 its 1,872 points
// took 19 s, 70 % of the cut geometry. The arithmetic is the script's
// (fd3d/spaces.idp fdTetPoints3 with shrink 1, fd3d/levelset.idp lsDet3), in the
// same order, so the elements chosen and the scores are those of the script to the
// bit.
//
// Build: make setup (the Makefile's plugin rule, FreeFEM's ff-c++).

#include <vector>
#include <algorithm>
#include "ff++.hpp"
#include "AFunction_ext.hpp"
#include "lgfem.hpp"

namespace {

typedef KN<double> *Reals;

// fd3d/levelset.idp lsDet3: the determinant of (b - a, c - a, d - a), same operations.
inline double det3(double ax, double ay, double az, double bx, double by, double bz, double cx, double cy, double cz,
                   double dx, double dy, double dz) {
    return (bx - ax) * ((cy - ay) * (dz - az) - (cz - az) * (dy - ay))
           - (by - ay) * ((cx - ax) * (dz - az) - (cz - az) * (dx - ax))
           + (bz - az) * ((cx - ax) * (dy - ay) - (cy - ay) * (dx - ax));
}

// The smallest barycentric coordinate of p in element k (fdTetPoints3 with shrink 1).
double smallestBarycentric(const Mesh3 &Th, int k, double px, double py, double pz) {
    const Mesh3::Element &K = Th[k];
    double cx = 0., cy = 0., cz = 0.;
    for (int j = 0; j < 4; ++j) { cx += K[j].x / 4.; cy += K[j].y / 4.; cz += K[j].z / 4.; }
    double x[4], y[4], z[4];
    for (int j = 0; j < 4; ++j) {
        x[j] = cx + 1. * (K[j].x - cx);
        y[j] = cy + 1. * (K[j].y - cy);
        z[j] = cz + 1. * (K[j].z - cz);
    }
    const double d = det3(x[0], y[0], z[0], x[1], y[1], z[1], x[2], y[2], z[2], x[3], y[3], z[3]);
    double mu[4];
    mu[0] = det3(px, py, pz, x[1], y[1], z[1], x[2], y[2], z[2], x[3], y[3], z[3]) / d;
    mu[1] = det3(x[0], y[0], z[0], px, py, pz, x[2], y[2], z[2], x[3], y[3], z[3]) / d;
    mu[2] = det3(x[0], y[0], z[0], x[1], y[1], z[1], px, py, pz, x[3], y[3], z[3]) / d;
    mu[3] = 1. - mu[0] - mu[1] - mu[2];
    double m = mu[0];
    for (int j = 1; j < 4; ++j) m = std::min(m, mu[j]);
    return m;
}

class NearestKeptElements : public E_F0mps {
  public:
    typedef long Result;
    Expression mesh, inBody, start, px, py, pz, rings, kOut, score;
    static const int n_name_param = 0;
    explicit NearestKeptElements(const basicAC_F0 &args) {
        args.SetNameParam(0, 0, 0);
        mesh = to<pmesh3>(args[0]);
        inBody = to<Reals>(args[1]);
        start = to<Reals>(args[2]);
        px = to<Reals>(args[3]);
        py = to<Reals>(args[4]);
        pz = to<Reals>(args[5]);
        rings = to<long>(args[6]);
        kOut = to<Reals>(args[7]);
        score = to<Reals>(args[8]);
    }
    static ArrayOfaType typeargs() {
        return ArrayOfaType(atype<pmesh3>(), atype<Reals>(), atype<Reals>(), atype<Reals>(), atype<Reals>(),
                            atype<Reals>(), atype<long>(), atype<Reals>(), atype<Reals>());
    }
    static E_F0 *f(const basicAC_F0 &args) { return new NearestKeptElements(args); }
    operator aType() const { return atype<long>(); }

    AnyType operator()(Stack stack) const {
        const Mesh3 *pTh = GetAny<pmesh3>((*mesh)(stack));
        const KN<double> &in = *GetAny<Reals>((*inBody)(stack));
        const KN<double> &k0 = *GetAny<Reals>((*start)(stack));
        const KN<double> &x = *GetAny<Reals>((*px)(stack));
        const KN<double> &y = *GetAny<Reals>((*py)(stack));
        const KN<double> &z = *GetAny<Reals>((*pz)(stack));
        const long nRings = GetAny<long>((*rings)(stack));
        KN<double> &best = *GetAny<Reals>((*kOut)(stack));
        KN<double> &bestScore = *GetAny<Reals>((*score)(stack));
        if (!pTh) return SetAny<long>(-1L);
        const Mesh3 &Th = *pTh;
        const long n = k0.N(), nt = Th.nt;
        if (x.N() != n || y.N() != n || z.N() != n || in.N() != nt) return SetAny<long>(-1L);
        for (long i = 0; i < n; ++i)
            if (!(k0[i] >= 0 && k0[i] < nt)) return SetAny<long>(-1L);
        best.resize(n);
        bestScore.resize(n);
        std::vector<int> ring;
        std::vector<char> seen(nt, 0);
        for (long i = 0; i < n; ++i) {
            // fd/core cut_cells.idp meshElementRings: k0, then each ring in the order reached
            ring.assign(1, (int)lround(k0[i]));
            seen[ring[0]] = 1;
            size_t first = 0;
            for (long r = 0; r < nRings; ++r) {
                const size_t end = ring.size();
                for (size_t a = first; a < end; ++a)
                    for (int face = 0; face < 4; ++face) {
                        int e = face;
                        const int kk = Th.ElementAdj(ring[a], e);
                        if (kk < 0 || kk == ring[a] || seen[kk]) continue;
                        seen[kk] = 1;
                        ring.push_back(kk);
                    }
                first = end;
            }
            int kBest = -1;
            double sBest = -1e300;
            for (int k : ring) {
                seen[k] = 0;
                if (in[k] < 0.5) continue;
                const double s = smallestBarycentric(Th, k, x[i], y[i], z[i]);
                if (s > sBest) { sBest = s; kBest = k; }
            }
            best[i] = kBest;
            bestScore[i] = sBest;
        }
        return SetAny<long>(n);
    }
};

}  // namespace

static void Load_Init() { Global.Add("nearestKeptElements", "(", new OneOperatorCode<NearestKeptElements>()); }

LOADFUNC(Load_Init)
