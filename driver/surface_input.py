"""Closed triangulated surfaces (STL or gmsh .msh) a 3D scene names as a body's shape.

The file is read as data by meshio (its STL reader, ascii or binary, and its gmsh
reader; gmsh never runs on it) and refused with one SceneError naming the file and
the cause unless it holds triangles only (gmsh's point and line elements aside), at
most MAX_TRIANGLES of them, finite coordinates, no triangle of zero area, and is
closed and consistently oriented: every edge is shared by exactly two triangles that
run through it in opposite directions, and the enclosed volume is positive (the
triangles turn counter-clockwise seen from outside). Self-intersections are not
looked for. The checked surface becomes a plain numeric table (surface_table) that
the FreeFEM plugin freefem/plugins/surface_distance.cpp reads.
"""

import hashlib
from pathlib import Path

import numpy as np

from .errors import SceneError
from .gmsh_input import file_inside, read_msh

MAX_BYTES = 20_000_000          # an ascii STL of MAX_TRIANGLES triangles is about 14 MB
MAX_TRIANGLES = 50_000
IGNORED_CELLS = ("vertex", "line", "line3")    # gmsh's points and curves beside the surface


def read_surface(base_dir, name, scale, where):
    """(points, triangles) of a checked closed surface (triangles: vertex numbers, counter-
    clockwise seen from outside), its coordinates multiplied by scale."""
    path = file_inside(base_dir, name, where, (".stl", ".msh"))
    label = repr(path.name)
    size = path.stat().st_size
    if size == 0:
        raise SceneError(f"{where}: {label} is empty")
    if size > MAX_BYTES:
        raise SceneError(f"{where}: {label} is {size} bytes; a surface file may hold at most {MAX_BYTES}")
    mesh = read_stl(path, where) if path.suffix == ".stl" else read_msh(path, where)
    other = sorted({c.type for c in mesh.cells} - {"triangle"} - set(IGNORED_CELLS))
    if other:
        raise SceneError(f"{where}: {label} holds {', '.join(other)} elements; a surface is made of triangles only")
    blocks = [np.asarray(c.data) for c in mesh.cells if c.type == "triangle"]
    triangles = np.vstack(blocks).astype(np.int64) if blocks else np.zeros((0, 3), np.int64)
    if len(triangles) < 4:
        raise SceneError(f"{where}: {label} has {len(triangles)} triangles; a closed surface needs at least 4")
    if len(triangles) > MAX_TRIANGLES:
        raise SceneError(f"{where}: {label} has {len(triangles)} triangles; at most {MAX_TRIANGLES} (coarsen it)")
    points = np.asarray(mesh.points, dtype=float)
    if points.ndim != 2 or points.shape[1] != 3:
        raise SceneError(f"{where}: {label} does not hold 3D points")
    if triangles.min() < 0 or triangles.max() >= len(points):
        raise SceneError(f"{where}: {label} has triangles through points it does not define")
    used = np.unique(triangles)
    if not np.all(np.isfinite(points[used])):
        raise SceneError(f"{where}: {label} has coordinates that are not finite")
    renumber = np.full(len(points), -1, dtype=np.int64)
    renumber[used] = np.arange(len(used))
    points, triangles = points[used] * scale, renumber[triangles]
    check_closed(points, triangles, where, label)
    return points, triangles


def read_stl(path, where):
    """A meshio mesh from an STL file (ascii or binary), one SceneError if it is not one."""
    import warnings

    import meshio.stl

    try:
        # meshio first reads an ascii file's opening bytes as a binary triangle count: an
        # overflow there is expected, not a finding
        with warnings.catch_warnings(), np.errstate(over="ignore"):
            warnings.simplefilter("ignore")
            return meshio.stl.read(str(path))
    except Exception as exc:   # meshio raises many types on a malformed file
        detail = str(exc).strip().splitlines()[0][:120] if str(exc).strip() else type(exc).__name__
        raise SceneError(f"{where}: {path.name!r} is not a readable STL file ({detail})") from None


def check_closed(points, triangles, where, label):
    """Every triangle of positive area, every edge shared by two triangles of opposite
    orientation, a positive enclosed volume."""
    a, b, c = (points[triangles[:, j]] for j in range(3))
    area2 = np.linalg.norm(np.cross(b - a, c - a), axis=1)
    extent = float(np.ptp(points, axis=0).max())
    flat = np.flatnonzero(area2 <= 1e-14 * extent ** 2)
    if flat.size:
        raise SceneError(f"{where}: {label}: triangle {int(flat[0])} has zero area ({flat.size} such triangles)")
    n = len(points)
    heads = triangles.reshape(-1)
    tails = triangles[:, [1, 2, 0]].reshape(-1)
    undirected, counts = np.unique(np.minimum(heads, tails) * n + np.maximum(heads, tails), return_counts=True)
    if np.any(counts == 1):
        raise SceneError(f"{where}: {label} is not closed: {int(np.sum(counts == 1))} edges belong to one "
                         f"triangle only")
    if np.any(counts > 2):
        raise SceneError(f"{where}: {label} is not a closed surface: {int(np.sum(counts > 2))} edges are shared "
                         f"by more than two triangles")
    directed, counts = np.unique(heads * n + tails, return_counts=True)
    if np.any(counts > 1):
        raise SceneError(f"{where}: {label} is not consistently oriented: {int(np.sum(counts > 1))} edges are run "
                         f"through in the same direction by both of their triangles")
    volume = enclosed_volume(points, triangles)
    if abs(volume) <= 1e-12 * extent ** 3:
        raise SceneError(f"{where}: {label} encloses no volume")
    if volume < 0:
        raise SceneError(f"{where}: {label} is oriented inward (enclosed volume {volume:.6g} < 0): each triangle's "
                         f"vertices must turn counter-clockwise seen from outside")


def enclosed_volume(points, triangles):
    """The volume the closed surface encloses (the divergence theorem: a sum of tetrahedra
    from the origin), positive for outward triangles."""
    a, b, c = (points[triangles[:, j]] for j in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def surface_table(points, triangles):
    """The table freefem/plugins/surface_distance.cpp reads: a header line, the counts, one
    vertex per line (every digit of the double), one triangle per line."""
    lines = ["fdcontact-surface 1", f"{len(points)} {len(triangles)}"]
    lines += [" ".join(repr(float(v)) for v in p) for p in points]
    lines += [" ".join(str(int(v)) for v in t) for t in triangles]
    return "\n".join(lines) + "\n"


def table_name(text):
    """The table's file name beside the scene module: from its content, so a surface named
    twice is written once and a run folder's name says nothing of the scene's paths."""
    return f"surface-{hashlib.sha256(text.encode()).hexdigest()[:16]}.txt"


def is_table_name(name):
    return Path(name).name == name and name.startswith("surface-") and name.endswith(".txt") and len(name) == 28
