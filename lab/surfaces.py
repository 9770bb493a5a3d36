"""Closed triangulated surfaces for the shape "surface": the shipped scene's torus
(cases/geo/torus.stl, `python -m lab.surfaces`) and the tests' closed forms (a notched cube, a prism with a sharp edge).

Each function returns (points, triangles) with the triangles counter-clockwise seen
from outside; write_stl writes them as an ascii STL, every coordinate in full precision
(the STL reader joins equal coordinates into one vertex).
"""

import math
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent


def torus(major, minor, n_major, n_minor, centre=(0.0, 0.0, 0.0)):
    """A torus about the z axis: n_major rings of n_minor vertices on the tube's circles."""
    u = 2 * math.pi * np.arange(n_major) / n_major
    v = 2 * math.pi * np.arange(n_minor) / n_minor
    uu, vv = np.meshgrid(u, v, indexing="ij")
    ring = major + minor * np.cos(vv)
    points = np.column_stack([(ring * np.cos(uu)).ravel(), (ring * np.sin(uu)).ravel(),
                              (minor * np.sin(vv)).ravel()]) + np.asarray(centre)
    triangles = []
    for i in range(n_major):
        for j in range(n_minor):
            a, b = i * n_minor + j, ((i + 1) % n_major) * n_minor + j
            c, d = ((i + 1) % n_major) * n_minor + (j + 1) % n_minor, i * n_minor + (j + 1) % n_minor
            triangles += [(a, b, c), (a, c, d)]
    return points, np.array(triangles)


def box(lo, hi, n):
    """The box [lo, hi] with each face cut into n x n squares of two triangles."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    points, triangles, index = [], [], {}

    def vertex(p):
        key = tuple(p)
        if key not in index:
            index[key] = len(points)
            points.append(key)
        return index[key]

    for axis in range(3):
        e1, e2 = (axis + 1) % 3, (axis + 2) % 3
        for side, value in ((0, lo[axis]), (1, hi[axis])):
            def at(i, j):
                # linspace ends exactly at lo and hi: a corner shared by three faces is one vertex
                p = np.empty(3)
                p[axis], p[e1], p[e2] = value, np.linspace(lo[e1], hi[e1], n + 1)[i], np.linspace(lo[e2], hi[e2], n + 1)[j]
                return vertex(p)
            for i in range(n):
                for j in range(n):
                    a, b, c, d = at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)
                    # (e1, e2, axis) is right-handed: counter-clockwise seen from +axis
                    quad = [(a, b, c), (a, c, d)] if side == 1 else [(a, c, b), (a, d, c)]
                    triangles += quad
    return np.array(points), np.array(triangles)


def notched_cube(lo, side, n):
    """The cube [lo, lo + side]^3 without its upper corner octant: its eight half-side cubes
    but the one at (1, 1, 1). Convex and concave edges and corners and saddle corners (where a
    concave edge meets convex ones); each square of the boundary in n x n squares of two
    triangles."""
    half = side / 2
    filled = {(i, j, k) for i in (0, 1) for j in (0, 1) for k in (0, 1)} - {(1, 1, 1)}
    points, triangles, index = [], [], {}

    def vertex(p):
        key = tuple(float(v) for v in p)
        if key not in index:
            index[key] = len(points)
            points.append(key)
        return index[key]

    for cell in sorted(filled):
        for axis in range(3):
            for step in (-1, 1):
                neighbour = list(cell)
                neighbour[axis] += step
                if tuple(neighbour) in filled:
                    continue
                e1, e2 = (axis + 1) % 3, (axis + 2) % 3
                corner = np.array(lo, float) + half * np.array(cell, float)
                corner[axis] += half if step == 1 else 0.0

                def at(i, j):
                    p = corner.copy()
                    p[e1] += half * i / n
                    p[e2] += half * j / n
                    return vertex(p)
                for i in range(n):
                    for j in range(n):
                        a, b, c, d = at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1)
                        # (e1, e2, axis) is right-handed: counter-clockwise seen from +axis
                        triangles += [(a, b, c), (a, c, d)] if step == 1 else [(a, c, b), (a, d, c)]
    return np.array(points), np.array(triangles)


def prism(corners, z0, z1):
    """The triangle `corners` ([[x, y], ...], counter-clockwise) extruded from z0 to z1: two
    end triangles, each side rectangle two triangles."""
    points = np.array([[x, y, z] for z in (z0, z1) for x, y in corners], float)
    triangles = [(0, 2, 1), (3, 4, 5)]
    for i in range(3):
        j = (i + 1) % 3
        triangles += [(i, j, j + 3), (i, j + 3, i + 3)]
    return points, np.array(triangles)


def write_stl(path, points, triangles, name="surface"):
    lines = [f"solid {name}"]
    for t in triangles:
        a, b, c = points[t]
        n = np.cross(b - a, c - a)
        n = n / np.linalg.norm(n)
        lines += [f"  facet normal {float(n[0])!r} {float(n[1])!r} {float(n[2])!r}", "    outer loop"]
        lines += [f"      vertex {float(p[0])!r} {float(p[1])!r} {float(p[2])!r}" for p in (a, b, c)]
        lines += ["    endloop", "  endfacet"]
    lines.append(f"endsolid {name}")
    Path(path).write_text("\n".join(lines) + "\n")


# The shipped scene's torus (cases/torus_on_slab.toml): radii 0.25 and 0.1, lying flat with
# its lowest circle on the slab top z = -0.25; 48 x 16 vertices, 1,536 triangles.
TORUS = dict(major=0.25, minor=0.1, n_major=48, n_minor=16, centre=(0.0, 0.0, -0.15))


if __name__ == "__main__":
    write_stl(REPO / "cases" / "geo" / "torus.stl", *torus(**TORUS), name="torus")
