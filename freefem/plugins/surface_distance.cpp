// surface_distance: the signed distance to a closed triangulated surface, for the 3D
// shape "surface" (driver/geometry.py, Surface): the scene module's phiNAt calls it at
// every point where the level set is wanted.
//
// Script interface:
//   int surfaceLoad(string file)
//       reads a surface table written by the driver (below), builds its search tree
//       and returns its number (0, 1, ...), or -1 when the file cannot be read or is
//       malformed (a message on stderr says why). Loading the same file again returns
//       the number it already has.
//   real surfaceDistance(int surface, real x, real y, real z)
//       the signed distance from (x, y, z) to the surface: the distance to the nearest
//       triangle, negative inside. An unknown surface number stops the script.
//
// The table (plain text, numbers only):
//   fdcontact-surface 1
//   NV NT
//   x y z            NV lines, the vertices
//   a b c            NT lines, each triangle's vertex numbers from 0, counter-clockwise
//                    seen from outside
// The driver checks the surface before it writes the table (closed, each edge shared by
// two triangles of opposite orientation, positive volume); this reader checks only what
// the arithmetic here needs (counts, finite coordinates, vertex numbers in range, no
// triangle of zero area).
//
// Sign: the angle-weighted pseudo-normal of the nearest feature (Baerentzen and Aanaes,
// 2005): the normal of the triangle when the nearest point lies inside it, the sum of
// the two triangles' normals on an edge, the sum of the normals of the triangles around
// a vertex weighted by their angles there. For a closed, consistently oriented surface
// (p - nearest point) . pseudo-normal > 0 exactly outside. The driver's checks use the
// same rule (libigl's signed_distance with pseudo-normals, driver/geometry.py).
//
// Search: a bounding-box tree over the triangles (median split along the longest side,
// at most four triangles a leaf), visited nearest box first and cut where a box lies
// farther than the best triangle found.
//
// Build: make setup (the Makefile's plugin rule, FreeFEM's ff-c++).

#include <algorithm>
#include <cmath>
#include <fstream>
#include <iostream>
#include <map>
#include <string>
#include <utility>
#include <vector>
#include "ff++.hpp"
#include "AFunction_ext.hpp"

namespace {

struct Vec {
    double x, y, z;
};
inline Vec operator-(const Vec &a, const Vec &b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
inline Vec operator+(const Vec &a, const Vec &b) { return {a.x + b.x, a.y + b.y, a.z + b.z}; }
inline Vec operator*(double s, const Vec &a) { return {s * a.x, s * a.y, s * a.z}; }
inline double dot(const Vec &a, const Vec &b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
inline Vec cross(const Vec &a, const Vec &b) {
    return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
inline double norm(const Vec &a) { return std::sqrt(dot(a, a)); }

// Where on a triangle its nearest point to a query lies.
enum Feature { VERTEX0, VERTEX1, VERTEX2, EDGE01, EDGE12, EDGE20, FACE };

// The point of triangle (a, b, c) nearest to p and the feature holding it (the regions of
// the triangle's plane by the signs of barycentric-type products).
Vec nearestOnTriangle(const Vec &p, const Vec &a, const Vec &b, const Vec &c, Feature &where) {
    const Vec ab = b - a, ac = c - a, ap = p - a;
    const double d1 = dot(ab, ap), d2 = dot(ac, ap);
    if (d1 <= 0. && d2 <= 0.) { where = VERTEX0; return a; }
    const Vec bp = p - b;
    const double d3 = dot(ab, bp), d4 = dot(ac, bp);
    if (d3 >= 0. && d4 <= d3) { where = VERTEX1; return b; }
    const double vc = d1 * d4 - d3 * d2;
    if (vc <= 0. && d1 >= 0. && d3 <= 0.) { where = EDGE01; return a + (d1 / (d1 - d3)) * ab; }
    const Vec cp = p - c;
    const double d5 = dot(ab, cp), d6 = dot(ac, cp);
    if (d6 >= 0. && d5 <= d6) { where = VERTEX2; return c; }
    const double vb = d5 * d2 - d1 * d6;
    if (vb <= 0. && d2 >= 0. && d6 <= 0.) { where = EDGE20; return a + (d2 / (d2 - d6)) * ac; }
    const double va = d3 * d6 - d5 * d4;
    if (va <= 0. && (d4 - d3) >= 0. && (d5 - d6) >= 0.) {
        where = EDGE12;
        return b + ((d4 - d3) / ((d4 - d3) + (d5 - d6))) * (c - b);
    }
    const double denom = 1. / (va + vb + vc);
    where = FACE;
    return a + (vb * denom) * ab + (vc * denom) * ac;
}

struct Node {
    Vec lo, hi;
    int left, right;      // children (-1 in a leaf)
    int first, count;     // the leaf's triangles: order[first .. first + count)
};

class Surface {
  public:
    std::vector<Vec> vertex;
    std::vector<int> tri;               // 3 per triangle
    std::vector<Vec> faceNormal, vertexNormal, edgeNormal;   // edgeNormal: 3 per triangle
    std::vector<int> order;
    std::vector<Node> nodes;

    bool read(const std::string &file, std::string &why);
    double signedDistance(const Vec &p) const;

  private:
    bool buildNormals(std::string &why);
    int build(int first, int count);
};

bool Surface::read(const std::string &file, std::string &why) {
    std::ifstream in(file.c_str());
    if (!in) { why = "cannot open it"; return false; }
    std::string magic;
    int version = 0;
    long nv = -1, nt = -1;
    if (!(in >> magic >> version) || magic != "fdcontact-surface" || version != 1) {
        why = "not a surface table (first line: fdcontact-surface 1)";
        return false;
    }
    if (!(in >> nv >> nt) || nv < 4 || nt < 4 || nv > 10000000 || nt > 10000000) {
        why = "bad vertex or triangle count";
        return false;
    }
    vertex.resize(nv);
    for (long i = 0; i < nv; ++i) {
        Vec &v = vertex[i];
        if (!(in >> v.x >> v.y >> v.z) || !std::isfinite(v.x) || !std::isfinite(v.y) || !std::isfinite(v.z)) {
            why = "vertex " + std::to_string(i) + " is missing or not finite";
            return false;
        }
    }
    tri.resize(3 * nt);
    for (long k = 0; k < 3 * nt; ++k) {
        long j = -1;
        if (!(in >> j) || j < 0 || j >= nv) {
            why = "triangle " + std::to_string(k / 3) + " is missing or names a vertex out of range";
            return false;
        }
        tri[k] = (int)j;
    }
    std::string extra;
    if (in >> extra) { why = "text after the last triangle"; return false; }
    if (!buildNormals(why)) return false;
    order.resize(nt);
    for (long k = 0; k < nt; ++k) order[k] = (int)k;
    nodes.reserve(2 * nt / 4 + 2);
    build(0, (int)nt);
    return true;
}

bool Surface::buildNormals(std::string &why) {
    const size_t nt = tri.size() / 3;
    faceNormal.resize(nt);
    vertexNormal.assign(vertex.size(), Vec{0., 0., 0.});
    edgeNormal.assign(3 * nt, Vec{0., 0., 0.});
    for (size_t k = 0; k < nt; ++k) {
        const int *t = &tri[3 * k];
        const Vec n = cross(vertex[t[1]] - vertex[t[0]], vertex[t[2]] - vertex[t[0]]);
        const double len = norm(n);
        if (!(len > 0.)) { why = "triangle " + std::to_string(k) + " has zero area"; return false; }
        faceNormal[k] = (1. / len) * n;
        for (int j = 0; j < 3; ++j) {
            // the angle of the triangle at its vertex j weights its normal there
            const Vec u = vertex[t[(j + 1) % 3]] - vertex[t[j]], w = vertex[t[(j + 2) % 3]] - vertex[t[j]];
            const double angle = std::atan2(norm(cross(u, w)), dot(u, w));
            vertexNormal[t[j]] = vertexNormal[t[j]] + angle * faceNormal[k];
        }
    }
    // an edge's pseudo-normal: the sum of the normals of the triangles that share it
    std::map<std::pair<int, int>, Vec> edgeSum;
    for (size_t k = 0; k < nt; ++k)
        for (int j = 0; j < 3; ++j) {
            const int a = tri[3 * k + j], b = tri[3 * k + (j + 1) % 3];
            Vec &s = edgeSum.emplace(std::make_pair(std::min(a, b), std::max(a, b)), Vec{0., 0., 0.}).first->second;
            s = s + faceNormal[k];
        }
    for (size_t k = 0; k < nt; ++k)
        for (int j = 0; j < 3; ++j) {
            const int a = tri[3 * k + j], b = tri[3 * k + (j + 1) % 3];
            edgeNormal[3 * k + j] = edgeSum[std::make_pair(std::min(a, b), std::max(a, b))];
        }
    return true;
}

// The tree over order[first .. first + count): returns the node's number.
int Surface::build(int first, int count) {
    Node node;
    node.lo = {HUGE_VAL, HUGE_VAL, HUGE_VAL};
    node.hi = {-HUGE_VAL, -HUGE_VAL, -HUGE_VAL};
    for (int i = first; i < first + count; ++i)
        for (int j = 0; j < 3; ++j) {
            const Vec &v = vertex[tri[3 * order[i] + j]];
            node.lo = {std::min(node.lo.x, v.x), std::min(node.lo.y, v.y), std::min(node.lo.z, v.z)};
            node.hi = {std::max(node.hi.x, v.x), std::max(node.hi.y, v.y), std::max(node.hi.z, v.z)};
        }
    node.left = node.right = -1;
    node.first = first;
    node.count = count;
    const int id = (int)nodes.size();
    nodes.push_back(node);
    if (count <= 4) return id;
    const Vec size = node.hi - node.lo;
    const int axis = (size.x >= size.y && size.x >= size.z) ? 0 : (size.y >= size.z ? 1 : 2);
    auto centre = [&](int k) {
        const Vec s = vertex[tri[3 * k]] + vertex[tri[3 * k + 1]] + vertex[tri[3 * k + 2]];
        return axis == 0 ? s.x : (axis == 1 ? s.y : s.z);
    };
    const int half = count / 2;
    std::nth_element(order.begin() + first, order.begin() + first + half, order.begin() + first + count,
                     [&](int a, int b) { return centre(a) < centre(b) || (centre(a) == centre(b) && a < b); });
    const int left = build(first, half);
    const int right = build(first + half, count - half);
    nodes[id].left = left;
    nodes[id].right = right;
    return id;
}

inline double boxDistance2(const Node &n, const Vec &p) {
    const double dx = std::max(std::max(n.lo.x - p.x, p.x - n.hi.x), 0.);
    const double dy = std::max(std::max(n.lo.y - p.y, p.y - n.hi.y), 0.);
    const double dz = std::max(std::max(n.lo.z - p.z, p.z - n.hi.z), 0.);
    return dx * dx + dy * dy + dz * dz;
}

double Surface::signedDistance(const Vec &p) const {
    double best2 = HUGE_VAL;
    Vec bestPoint = p, bestNormal = {0., 0., 1.};
    std::vector<int> stack;
    stack.reserve(64);
    stack.push_back(0);
    while (!stack.empty()) {
        const Node &n = nodes[stack.back()];
        stack.pop_back();
        if (boxDistance2(n, p) >= best2) continue;
        if (n.left < 0) {
            for (int i = n.first; i < n.first + n.count; ++i) {
                const int k = order[i];
                const int *t = &tri[3 * k];
                Feature where;
                const Vec q = nearestOnTriangle(p, vertex[t[0]], vertex[t[1]], vertex[t[2]], where);
                const Vec d = p - q;
                const double d2 = dot(d, d);
                if (d2 < best2) {
                    best2 = d2;
                    bestPoint = q;
                    switch (where) {
                        case VERTEX0: case VERTEX1: case VERTEX2: bestNormal = vertexNormal[t[where - VERTEX0]]; break;
                        case EDGE01: bestNormal = edgeNormal[3 * k]; break;
                        case EDGE12: bestNormal = edgeNormal[3 * k + 1]; break;
                        case EDGE20: bestNormal = edgeNormal[3 * k + 2]; break;
                        default: bestNormal = faceNormal[k];
                    }
                }
            }
            continue;
        }
        // the nearer child on top of the stack: visited first, it shrinks best2 sooner
        const double dl = boxDistance2(nodes[n.left], p), dr = boxDistance2(nodes[n.right], p);
        if (dl < dr) { stack.push_back(n.right); stack.push_back(n.left); }
        else { stack.push_back(n.left); stack.push_back(n.right); }
    }
    const double dist = std::sqrt(best2);
    return dot(p - bestPoint, bestNormal) < 0. ? -dist : dist;
}

std::vector<Surface *> surfaces;
std::map<std::string, long> loaded;

long surfaceLoad(string *const &file) {
    const std::string name = file ? *file : std::string();
    const auto known = loaded.find(name);
    if (known != loaded.end()) return known->second;
    Surface *s = new Surface;
    std::string why;
    if (!s->read(name, why)) {
        std::cerr << "surfaceLoad: " << name << ": " << why << std::endl;
        delete s;
        return -1;
    }
    surfaces.push_back(s);
    return loaded[name] = (long)surfaces.size() - 1;
}

double surfaceDistance(const long &surface, const double &x, const double &y, const double &z) {
    if (surface < 0 || surface >= (long)surfaces.size()) ExecError("surfaceDistance: no surface of that number");
    return surfaces[surface]->signedDistance(Vec{x, y, z});
}

}  // namespace

static void Load_Init() {
    Global.Add("surfaceLoad", "(", new OneOperator1_<long, string *>(surfaceLoad));
    Global.Add("surfaceDistance", "(", new OneOperator4_<double, long, double, double, double>(surfaceDistance));
}

LOADFUNC(Load_Init)
