// inside_extension: a body's P1 field with its values at the vertices outside the body
// replaced by those of the inside, for the body files' von_mises_inside
// (freefem/lib/fd2d/results.idp and fd3d/results.idp, fdBodiesVtuAt).
//
// Script interface:
//   int insideExtension(mesh Th, real[int] values, real[int] phi)     (2D)
//   int insideExtension(mesh3 Th, real[int] values, real[int] phi)    (3D)
//       values and phi: P1 fields on Th (one value per vertex). The vertices with
//       phi < 0 are inside; each outside vertex that shares an edge with an inside
//       one takes the mean of those inside vertices' values, each counted once per
//       element holding the edge; then the vertices filled count as inside and the
//       next ring outward is filled the same way, until no vertex is left that
//       touches the filled ones. values is changed in place. Returns the number of
//       rings filled, or -1 when the arrays' sizes are not the number of vertices.
//
// Why: a stress at a vertex outside a body is the polynomial of a cut element extended
// beyond the body, largest on the tiniest cuts; with them replaced, the field's range
// is the inside's and, clipped at phi = 0, it is what the plots draw.
//
// Why compiled: the rings visit every pair of an element's vertices, a loop FreeFEM's
// interpreter runs a statement at a time (tens of thousands per ring). The sums are
// taken by element corner pair (i, j), then element, in that order.
//
// Build: make setup (the Makefile's plugin rule, FreeFEM's ff-c++).

#include <vector>
#include "ff++.hpp"

namespace {

typedef KN<double> *Reals;

template <int corners, class MeshT>
long fillOutside(const MeshT &Th, KN<double> &values, const KN<double> &phi) {
    const long nv = Th.nv, nt = Th.nt;
    if (values.N() != nv || phi.N() != nv) return -1L;
    std::vector<long> vertex(nt * corners);
    for (long k = 0; k < nt; ++k)
        for (int i = 0; i < corners; ++i) vertex[k * corners + i] = Th(Th[k][i]);
    std::vector<char> known(nv), fill(nv);
    for (long v = 0; v < nv; ++v) known[v] = phi[v] < 0;
    std::vector<double> total(nv), count(nv);
    long rings = 0;
    for (;;) {
        std::fill(total.begin(), total.end(), 0.);
        std::fill(count.begin(), count.end(), 0.);
        for (int i = 0; i < corners; ++i)
            for (int j = 0; j < corners; ++j) {
                if (i == j) continue;
                for (long k = 0; k < nt; ++k) {
                    const long p = vertex[k * corners + i], q = vertex[k * corners + j];
                    if (!known[p] && known[q]) {
                        total[p] += values[q];
                        count[p] += 1.;
                    }
                }
            }
        bool any = false;
        for (long v = 0; v < nv; ++v) {
            fill[v] = count[v] > 0;
            any = any || fill[v];
        }
        if (!any) return rings;
        ++rings;
        for (long v = 0; v < nv; ++v)
            if (fill[v]) {
                values[v] = total[v] / count[v];
                known[v] = 1;
            }
    }
}

// corners: the vertices of an element of the mesh (3 triangles, 4 tetrahedra)
template <class PMesh, int corners>
class InsideExtension : public E_F0mps {
  public:
    typedef long Result;
    Expression mesh, values, phi;
    explicit InsideExtension(const basicAC_F0 &args) {
        args.SetNameParam(0, 0, 0);
        mesh = to<PMesh>(args[0]);
        values = to<Reals>(args[1]);
        phi = to<Reals>(args[2]);
    }
    static ArrayOfaType typeargs() { return ArrayOfaType(atype<PMesh>(), atype<Reals>(), atype<Reals>()); }
    static E_F0 *f(const basicAC_F0 &args) { return new InsideExtension(args); }
    operator aType() const { return atype<long>(); }

    AnyType operator()(Stack stack) const {
        const auto *pTh = GetAny<PMesh>((*mesh)(stack));
        KN<double> &v = *GetAny<Reals>((*values)(stack));
        const KN<double> &p = *GetAny<Reals>((*phi)(stack));
        if (!pTh) return SetAny<long>(-1L);
        return SetAny<long>(fillOutside<corners>(*pTh, v, p));
    }
};

}  // namespace

static void Load_Init() {
    Global.Add("insideExtension", "(", new OneOperatorCode<InsideExtension<pmesh, 3>>());
    Global.Add("insideExtension", "(", new OneOperatorCode<InsideExtension<pmesh3, 4>>());
}

LOADFUNC(Load_Init)
