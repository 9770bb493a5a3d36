"""python -m driver plot RUN: figures of one run folder, written as PNG files into it.

2D fictitious-domain runs (fd_contact_2d; also the rigid-foundation script):
  plot_deformed.png   the deformed bodies coloured by von Mises, each clipped by its
                      level set, the active contact points marked (whole box and a zoom)
  plot_pressure.png   the contact pressure along the contact (arc length), raw and, when
                      the CSV has one, recovered
  plot_newton.png     the Newton history: residual, active and changed measure per iteration
3D runs (fd_contact_3d):
  plot_cut_<plane>.png  a plane cut of both bodies coloured by von Mises (--plane, default
                        y through the contact's pressure centre)
  plot_pressure.png     the contact pressure on the contact surface, projected on the plane
                        normal to the contact force, and against the distance to its centre
  plot_newton.png       as in 2D

Everything is read from the run's own files (results.json, scene.json, fields.vtu or
body1.vtu/body2.vtu, contact_pressure.csv); nothing is written outside the folder.
A folder that is not a converged run, or a file it should hold that is missing or
unreadable, gives one line naming the cause and exit code 2 (bad input, as a scene).
"""

import json
import math
import os
import re
import sys
import tempfile
from pathlib import Path

import numpy as np

from .errors import DriverError

FIGURE_DPI = 130
PRESSURE_LABEL = "contact pressure (positive in compression)"


class RunFolderError(DriverError):
    """The folder given to plot is not a readable converged run (bad input: exit 2)."""

    exit_code = 2


# ---------------------------------------------------------------------------
# Reading a run folder


class RunData:
    """What the figures need from one run folder, checked on reading."""

    def __init__(self, folder):
        self.folder = Path(folder)
        self.results = read_results(self.folder)
        self.scene = read_scene(self.folder)
        self.script = str(self.results.get("script", ""))
        self.name = str(self.results.get("scene") or self.scene.get("scene", {}).get("name") or self.folder.name)
        dim = self.results.get("dim", 3 if self.script == "fd_contact_3d" else 2)
        if dim not in (2, 3):
            raise RunFolderError(f"{self.folder / 'results.json'}: 'dim' is {dim!r}, expected 2 or 3")
        self.dim = int(dim)
        self.length, self.stress = unit_names(self.scene)
        self.outputs = self.results.get("outputs") or {}
        if not isinstance(self.outputs, dict):
            raise RunFolderError(f"{self.folder / 'results.json'}: 'outputs' is not a table")

    def has_output(self, filename):
        """True when results.json lists the file (the run was asked for it) or it exists anyway."""
        return filename in self.outputs.values() or self.file(filename).exists()

    def file(self, filename):
        """A file of the run folder: a name results.json gives must not lead outside it."""
        path = (self.folder / str(filename)).resolve()
        if not path.is_relative_to(self.folder.resolve()):
            raise RunFolderError(f"{self.folder / 'results.json'}: names {str(filename)[:80]!r}, a file outside "
                                 f"the run folder; only files inside it are read")
        return path

    def subtitle(self):
        r = self.results
        bits = [self.script]
        if "degree" in r:
            bits.append(f"P{r['degree']}")
        if isinstance(r.get("theta"), (int, float)):
            bits.append(f"theta = {r['theta']:.4g}")
        gamma0 = r.get("gamma0")       # the scene's value (gamma0_effective: what the terms use)
        if isinstance(gamma0, (int, float)):
            bits.append(f"gamma0 = {gamma0:.4g}")
        if isinstance(r.get("nx"), (int, float)):
            bits.append(f"nx = {r['nx']:g}")
        if isinstance(r.get("elements"), (int, float)):
            bits.append(f"{r['elements']:g} elements")
        steps = (r.get("steps") or {}).get("dofs") or []
        if len(steps) > 1:
            bits.append(f"adaptation step {len(steps) - 1}")
        return ", ".join(bits)

    def axis(self, name):
        return f"{name} [{self.length}]"


def read_results(folder):
    if not folder.exists():
        raise RunFolderError(f"{folder}: no such run folder")
    if not folder.is_dir():
        raise RunFolderError(f"{folder}: not a folder (give a run folder, e.g. runs/NAME-TIME-HASH)")
    path = folder / "results.json"
    if not path.is_file():
        failure = folder / "failure.json"
        if failure.is_file():
            try:
                info = json.loads(failure.read_text())
                why = f"{info.get('status', 'failed')}: {info.get('message', '')}".strip().rstrip(":")
            except (ValueError, UnicodeDecodeError, AttributeError):
                why = "see failure.json"
            raise RunFolderError(f"{folder}: a failed run ({one_line(why)}) has no results to plot")
        raise RunFolderError(f"{folder}: not a run folder (no results.json)")
    try:
        results = json.loads(path.read_text())
    except (ValueError, UnicodeDecodeError) as exc:
        raise RunFolderError(f"{path}: malformed JSON ({one_line(exc)})") from None
    if not isinstance(results, dict):
        raise RunFolderError(f"{path}: malformed (not a JSON object)")
    if results.get("status") not in (None, "converged", "ok"):
        raise RunFolderError(f"{path}: status {results.get('status')!r}, not a converged run")
    if results.get("script") not in ("fd_contact_2d", "fd_contact_3d", "contact_foundation_2d"):
        raise RunFolderError(f"{path}: unknown or missing 'script' ({str(results.get('script'))[:40]!r})")
    for key in TABLES:
        if key in results and not isinstance(results[key], dict):
            raise RunFolderError(f"{path}: '{key}' is a {type(results[key]).__name__}, not a table")
    return results


# The entries of results.json that are tables (JSON objects) when present.
TABLES = ("contact", "steps", "newton", "outputs", "balance", "estimator", "reference", "timings_cpu_s",
          "measures", "linear_solver", "reactions", "probes")


def read_scene(folder):
    """scene.json (the validated scene) when present; an empty table otherwise (direct FreeFEM runs)."""
    path = folder / "scene.json"
    if not path.is_file():
        return {}
    try:
        scene = json.loads(path.read_text())
    except (ValueError, UnicodeDecodeError) as exc:
        raise RunFolderError(f"{path}: malformed JSON ({one_line(exc)})") from None
    return scene if isinstance(scene, dict) else {}


def unit_names(scene):
    """Axis units: the scene's [scene] units (length, stress) when it states them; otherwise a
    scene is written in any consistent system (docs/scenes.md) and the labels name the
    dimensions, length and stress."""
    units = (scene.get("scene") or {}).get("units") or {}
    units = units if isinstance(units, dict) else {}
    return str(units.get("length", "length")), str(units.get("stress", "stress"))


def one_line(text):
    return " ".join(str(text).split())


def read_csv(run, filename, columns):
    import pandas as pd

    path = run.file(filename)
    if not path.is_file():
        raise RunFolderError(f"{path}: missing (results.json lists it)")
    try:
        frame = pd.read_csv(path)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError, ValueError) as exc:
        raise RunFolderError(f"{path}: malformed CSV ({one_line(exc)})") from None
    frame.columns = [str(c).strip() for c in frame.columns]
    missing = [c for c in columns if c not in frame.columns]
    if missing:
        raise RunFolderError(f"{path}: no column {', '.join(missing)} (has {', '.join(frame.columns)})")
    for column in frame.columns:
        values = pd.to_numeric(frame[column], errors="coerce")
        if values.isna().any() and column in columns:
            raise RunFolderError(f"{path}: column {column} has values that are not numbers")
        frame[column] = values
    if frame.empty:
        raise RunFolderError(f"{path}: no rows (no contact quadrature points)")
    return frame


def read_vtu(run, filename):
    import meshio

    path = run.file(filename)
    if not path.is_file():
        raise RunFolderError(f"{path}: missing (results.json lists it)")
    try:
        # the VTU reader itself: meshio.read prints and calls sys.exit on a file it cannot read
        mesh = meshio.vtu.read(path)
    except Exception as exc:  # ReadError, XML and value errors, KeyError on a file cut short
        detail = one_line(exc) or "not a complete VTU file"
        raise RunFolderError(f"{path}: unreadable VTU ({type(exc).__name__}: {detail})") from None
    if not len(mesh.points):
        raise RunFolderError(f"{path}: a VTU without points")
    return mesh


def point_field(mesh, path, *names, size=1):
    """The first of the named point fields, as (n,) or (n, size) floats."""
    for name in names:
        if name in mesh.point_data:
            data = np.asarray(mesh.point_data[name], dtype=float)
            if len(data) != len(mesh.points):
                break
            if size == 1:
                return data.reshape(len(data), -1)[:, 0]
            data = data.reshape(len(data), -1)
            if data.shape[1] < size:
                break
            return data[:, :size]
    raise RunFolderError(f"{path}: no point field {' or '.join(names)} "
                         f"(has {', '.join(mesh.point_data) or 'none'})")


def cells_of(mesh, path, kind, corners):
    """Corner connectivity of every cell whose type starts with kind (triangle6, Lagrange cells:
    corners first)."""
    blocks = [np.asarray(block.data)[:, :corners] for block in mesh.cells if block.type.startswith(kind)]
    if not blocks:
        raise RunFolderError(f"{path}: no {kind} cells")
    return np.concatenate(blocks).astype(np.int64)


# ---------------------------------------------------------------------------
# Geometry: clipping by a level set, plane cuts of tetrahedra


def clip_triangles(tris, data, phi_column):
    """Clip triangles to {phi < 0}, phi being linear on each triangle.

    data: (n, k) vertex values, interpolated linearly along the cut edges (coordinates among
    them); phi is data[:, phi_column]. Returns (new data, triangles into it, boundary segments
    (s, 2) into it: the zero line).
    """
    phi = data[:, phi_column][tris]
    neg = phi < 0
    count = neg.sum(axis=1)
    pieces = [data]
    out = [tris[count == 3]]
    segments = []
    base = len(data)
    for n_neg in (1, 2):
        sel = tris[count == n_neg]
        if not len(sel):
            continue
        # the odd vertex: the only negative one (1) or the only non-negative one (2)
        odd = np.argmax(neg[count == n_neg], axis=1) if n_neg == 1 else np.argmin(neg[count == n_neg], axis=1)
        rows = np.arange(len(sel))
        a, b, c = sel[rows, odd], sel[rows, (odd + 1) % 3], sel[rows, (odd + 2) % 3]
        ab = edge_points(data, a, b, phi_column)
        ac = edge_points(data, a, c, phi_column)
        m = len(sel)
        i_ab = base + np.arange(m)
        i_ac = base + m + np.arange(m)
        pieces += [ab, ac]
        base += 2 * m
        if n_neg == 1:          # the triangle (a, ab, ac)
            out.append(np.stack([a, i_ab, i_ac], axis=1))
        else:                   # the quadrilateral (b, c, ac, ab)
            out.append(np.stack([b, c, i_ac], axis=1))
            out.append(np.stack([b, i_ac, i_ab], axis=1))
        segments.append(np.stack([i_ab, i_ac], axis=1))
    new_tris = np.concatenate(out) if out else np.zeros((0, 3), dtype=np.int64)
    segs = np.concatenate(segments) if segments else np.zeros((0, 2), dtype=np.int64)
    return np.concatenate(pieces), new_tris, segs


def edge_points(data, a, b, column):
    """Points where the linear interpolant of data[:, column] between vertices a and b is zero."""
    fa, fb = data[a, column], data[b, column]
    t = fa / (fa - fb)
    return data[a] + t[:, None] * (data[b] - data[a])


def cut_tetrahedra(tets, data, axis_column, level):
    """Intersect tetrahedra with the plane data[:, axis_column] = level.

    Returns (data at the section's vertices, its triangles into them)."""
    dist = data[:, axis_column] - level
    work = np.concatenate([data, dist[:, None]], axis=1)
    col = work.shape[1] - 1
    side = dist[tets] >= 0
    count = side.sum(axis=1)
    pieces, tris, base = [], [], 0
    # one vertex alone on its side: a triangle on its three edges
    for k in (1, 3):
        sel, s = tets[count == k], side[count == k]
        if not len(sel):
            continue
        odd = np.argmax(s, axis=1) if k == 1 else np.argmin(s, axis=1)
        rows = np.arange(len(sel))
        others = [sel[rows, (odd + j) % 4] for j in (1, 2, 3)]
        a = sel[rows, odd]
        m = len(sel)
        pieces += [edge_points(work, a, o, col) for o in others]
        tris.append(base + np.stack([np.arange(m), m + np.arange(m), 2 * m + np.arange(m)], axis=1))
        base += 3 * m
    # two on each side: the quadrilateral on edges a-c, a-d, b-d, b-c
    sel, s = tets[count == 2], side[count == 2]
    if len(sel):
        order = np.argsort(~s, axis=1, kind="stable")        # the two on the + side first
        rows = np.arange(len(sel))[:, None]
        a, b, c, d = (sel[rows, order][:, j] for j in range(4))
        m = len(sel)
        pieces += [edge_points(work, a, c, col), edge_points(work, a, d, col),
                   edge_points(work, b, d, col), edge_points(work, b, c, col)]
        ac, ad, bd, bc = (base + j * m + np.arange(m) for j in range(4))
        tris += [np.stack([ac, ad, bd], axis=1), np.stack([ac, bd, bc], axis=1)]
    if not pieces:
        return np.zeros((0, data.shape[1])), np.zeros((0, 3), dtype=np.int64)
    return np.concatenate(pieces)[:, :data.shape[1]], np.concatenate(tris)


# ---------------------------------------------------------------------------
# Bodies as clipped, deformed triangulations


class Piece:
    """One body drawn in a plane: deformed vertices, triangles, von Mises, outline segments.
    Triangles of (nearly) no area, left by cuts through a vertex, are dropped: drawn, they
    leave hairlines."""

    def __init__(self, label, xy, tris, vm, segments):
        if len(tris):
            p = xy[tris]
            area = 0.5 * np.abs((p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1])
                                - (p[:, 2, 0] - p[:, 0, 0]) * (p[:, 1, 1] - p[:, 0, 1]))
            tris = tris[area > 1e-9 * area.max()]
        self.label, self.xy, self.tris, self.vm, self.segments = label, xy, tris, vm, segments


def bodies_2d(run, scale):
    """The bodies of a 2D run: fictitious domain from fields.vtu (or per-body body1/body2.vtu),
    the foundation from its body-fitted fields.vtu."""
    per_body = [f"body{i}.vtu" for i in (1, 2)]
    if all(run.has_output(f) for f in per_body):
        # each body on its own submesh (a P2 run's split once: the P2 nodal values)
        pieces, u1_field = [], None
        for i, filename in enumerate(per_body, start=1):
            mesh = read_vtu(run, filename)
            path = run.file(filename)
            tris = cells_of(mesh, path, "triangle", 3)
            xy = np.asarray(mesh.points[:, :2], dtype=float)
            u = point_field(mesh, path, "displacement", f"u{i}", "u", size=2)
            # FreeFEM's von_mises_inside: outside the body, the inside's values carried
            # outward (freefem/plugins/inside_extension.cpp), what the clipped cut cells show
            vm = point_field(mesh, path, "von_mises_inside", "von_mises")
            phi = point_field(mesh, path, "phi", f"phi{i}") if any(
                n in mesh.point_data for n in ("phi", f"phi{i}")) else None
            pieces.append(make_piece(f"body {i}", xy, tris, u, vm, phi, scale))
            if i == 1:
                u1_field = (xy, tris, u)
        return pieces, u1_field
    if not run.has_output("fields.vtu"):
        return None, None
    filename = "fields.vtu"
    mesh = read_vtu(run, filename)
    path = run.file(filename)
    tris = cells_of(mesh, path, "triangle", 3)
    xy = np.asarray(mesh.points[:, :2], dtype=float)
    if run.script == "contact_foundation_2d":
        u = point_field(mesh, path, "displacement", "u", size=2)
        vm = point_field(mesh, path, "von_mises")
        return [make_piece("body", xy, tris, u, vm, None, scale)], (xy, tris, u)
    pieces = []
    for i in (1, 2):
        u = point_field(mesh, path, f"u{i}", size=2)
        vm = point_field(mesh, path, f"von_mises{i}")      # each body's own stress, from FreeFEM
        pieces.append(make_piece(f"body {i}", xy, tris, u, vm, point_field(mesh, path, f"phi{i}"), scale))
    return pieces, (xy, tris, point_field(mesh, path, "u1", size=2))


def make_piece(label, xy, tris, u, vm, phi, scale):
    """Clip by phi < 0 (when given) and move the vertices by scale*u."""
    xy = np.asarray(xy, dtype=float)
    if phi is None:
        data = np.column_stack([xy, u, vm])
        segments = np.zeros((0, 2), dtype=np.int64)
    else:
        data, tris, segments = clip_triangles(tris, np.column_stack([xy, u, vm, phi]), 5)
    return Piece(label, data[:, 0:2] + scale * data[:, 2:4], tris, data[:, 4], segments)


def draw_pieces(ax, pieces, norm, cmap):
    from matplotlib.collections import LineCollection

    image = None
    for piece in pieces:
        if not len(piece.tris):
            continue
        image = ax.tripcolor(piece.xy[:, 0], piece.xy[:, 1], piece.tris, piece.vm, shading="gouraud",
                             norm=norm, cmap=cmap, rasterized=True)
        if len(piece.segments):
            ax.add_collection(LineCollection(piece.xy[piece.segments], colors="k", linewidths=0.6))
    ax.set_aspect("equal")
    return image


# The von Mises colour range ends at this percentile of the nodal values: a few points of
# badly cut elements carry stresses far above the rest (their polynomial extended over the
# whole element), which would otherwise set the scale; the colour bar marks the cut (extend).
VM_PERCENTILE = 99.0


def vm_norm(pieces):
    from matplotlib.colors import Normalize

    values = np.concatenate([p.vm[np.unique(p.tris)] for p in pieces if len(p.tris)] or [np.zeros(1)])
    values = values[np.isfinite(values)]
    top = float(np.percentile(values, VM_PERCENTILE)) if len(values) else 1.0
    return Normalize(vmin=0.0, vmax=top if top > 0 else 1.0)


def zoom_box(centre, extent, h):
    """A square window around the contact: its extent plus a margin of two mesh steps."""
    half = 0.75 * max(extent) + 2 * h
    return (centre[0] - half, centre[0] + half), (centre[1] - half, centre[1] + half)


# ---------------------------------------------------------------------------
# Contact samples


def contact_frame(run):
    """contact_pressure.csv with pressure positive in compression (every script writes it so;
    runs of earlier versions wrote it <= 0), or None when the run wrote none."""
    filename = next((f for k, f in run.outputs.items() if "pressure" in k and str(f).endswith(".csv")),
                    "contact_pressure.csv")
    if not run.has_output(filename):
        return None, None
    coords = ["x", "y"] + (["z"] if run.dim == 3 else [])
    frame = read_csv(run, filename, coords + ["pressure"])
    note = None
    if frame["pressure"].max() <= 0 < -frame["pressure"].min():
        frame["pressure"] = -frame["pressure"]
        for column in recovered_columns(frame):
            frame[column] = -frame[column]
        note = "sign reversed: the CSV writes it <= 0"
    if "active" not in frame.columns:
        frame["active"] = (frame["pressure"] > 0).astype(int)
    return frame, note


def recovered_columns(frame):
    return [c for c in frame.columns if "recover" in c.lower()]


def contact_centre(frame, coords):
    """The pressure-weighted centre of the active points (their mean when the pressure is zero)."""
    active = frame[frame["active"] > 0]
    if active.empty:
        active = frame[frame["pressure"] > 0]
    if active.empty:
        return None
    w = active["pressure"].to_numpy() * (active["weight"].to_numpy() if "weight" in active else 1.0)
    p = active[coords].to_numpy()
    if w.sum() > 0:
        return (p * w[:, None]).sum(axis=0) / w.sum()
    return p.mean(axis=0)


def chain_order(points):
    """Order points sampled along a curve: start at one end of its principal direction and walk
    to the nearest point not yet visited."""
    n = len(points)
    if n < 3:
        return np.arange(n), principal_direction(points)
    t = principal_direction(points)
    current = int(np.argmin(points @ t))
    visited = np.zeros(n, dtype=bool)
    order = np.empty(n, dtype=np.int64)
    for k in range(n):
        order[k] = current
        visited[current] = True
        if k == n - 1:
            break
        d = ((points - points[current]) ** 2).sum(axis=1)
        d[visited] = np.inf
        current = int(np.argmin(d))
    return order, t


def principal_direction(points):
    if len(points) < 2:
        return np.array([1.0, 0.0])
    centred = points - points.mean(axis=0)
    t = np.linalg.svd(centred, full_matrices=False)[2][0]
    # orient toward +x (or +y when the contact runs vertically)
    if t[0] < -1e-12 or (abs(t[0]) <= 1e-12 and t[1] < 0):
        t = -t
    return t


def contact_window(frame, coords, h, pad=0.5):
    """The samples in and around the active zone: within pad * its size of an active point
    (2 h for a zone of one point)."""
    active = frame[(frame["active"] > 0) | (frame["pressure"] > 0)]
    if active.empty:
        return frame
    pa = active[coords].to_numpy()
    size = float(np.ptp(pa, axis=0).max()) if len(pa) > 1 else 0.0
    reach = pad * size if size > 0 else 2 * h
    p = frame[coords].to_numpy()
    near = np.zeros(len(p), dtype=bool)
    for start in range(0, len(pa), 512):
        d = ((p[:, None, :] - pa[None, start:start + 512, :]) ** 2).sum(axis=2)
        near |= (d <= reach * reach).any(axis=1)
    return frame[near]


# ---------------------------------------------------------------------------
# Figures


def save(fig, run, filename):
    """Write into the run folder through a temporary file there (never a partial PNG)."""
    target = run.file(filename)
    handle, tmp = tempfile.mkstemp(prefix=".plot-", suffix=".png", dir=run.folder)
    os.close(handle)
    try:
        fig.savefig(tmp, dpi=FIGURE_DPI)
        os.replace(tmp, target)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    import matplotlib.pyplot as plt

    plt.close(fig)
    return target


def section_panels(run, pieces, norm, cmap, contact, zoom, contact_label, marker_sizes, labels, limits, h):
    """The deformed pieces coloured by von Mises over the whole box (limits: the box's two
    in-plane ranges, or None) and, when zoom, beside it a zoom on the active contact
    points (drawn in red, marker_sizes for the two panels), with one colour bar."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2 if zoom else 1, figsize=(12 if zoom else 7, 5.6),
                             squeeze=False, layout="constrained")
    axes = axes[0]
    for k, ax in enumerate(axes):
        image = draw_pieces(ax, pieces, norm, cmap)
        if contact is not None:
            ax.plot(contact[:, 0], contact[:, 1], ".", color="red", ms=marker_sizes[1] if k else marker_sizes[0],
                    label=contact_label)
        ax.set_xlabel(labels[0])
        ax.set_ylabel(labels[1])
    if limits is not None:
        (x0, x1), (y0, y1) = limits
        pad = 0.02 * (x1 - x0)
        axes[0].set_xlim(x0 - pad, x1 + pad)
        axes[0].set_ylim(y0 - pad, y1 + pad)
    axes[0].set_title("whole box", fontsize=9)
    if zoom:
        lo, hi = contact.min(axis=0), contact.max(axis=0)
        xlim, ylim = zoom_box((lo + hi) / 2, hi - lo, h)
        axes[1].set_xlim(*xlim)
        axes[1].set_ylim(*ylim)
        axes[1].set_title("the contact zone", fontsize=9)
    if contact is not None:
        axes[-1].legend(loc="upper right", fontsize=8)
    if image is not None:
        fig.colorbar(image, ax=list(axes), label=f"von Mises stress [{run.stress}] (scale to the "
                     f"{VM_PERCENTILE:g}th percentile)", shrink=0.9, extend="max")
    return fig


def mesh_step(run):
    """The background mesh step h (box width / nx), else results.json h_max."""
    for key in ("h", "h_max"):
        value = run.results.get(key)
        if isinstance(value, (int, float)) and value > 0:
            return float(value)
    return 0.02


def title(fig, run, what):
    fig.suptitle(f"{run.name}: {what}\n{run.subtitle()}", fontsize=10)


def figure_deformed_2d(run, pieces, u1_field, frame, scale):
    import matplotlib.pyplot as plt
    import matplotlib.tri as mtri

    cmap = plt.get_cmap("viridis")
    norm = vm_norm(pieces)
    h = mesh_step(run)
    contact = None
    if frame is not None:
        act = frame[frame["active"] > 0]
        if not act.empty:
            pts = act[["x", "y"]].to_numpy(dtype=float)
            if u1_field is not None:
                xy, tris, u1 = u1_field
                tri = mtri.Triangulation(xy[:, 0], xy[:, 1], tris)
                shift = np.column_stack([mtri.LinearTriInterpolator(tri, u1[:, k])(pts[:, 0], pts[:, 1])
                                         .filled(0.0) for k in (0, 1)])
                pts = pts + scale * shift
            contact = pts
    geometry = run.scene.get("geometry") or {}
    width = geometry.get("xmax", 1.0) - geometry.get("xmin", 0.0) if geometry else 1.0
    zoom = contact is not None and np.ptp(contact, axis=0).max() < 0.4 * width
    limits = [(geometry[f"{a}min"], geometry[f"{a}max"]) for a in "xy"] \
        if all(k in geometry for k in ("xmin", "xmax", "ymin", "ymax")) else None
    label = f"active contact ({len(contact) if contact is not None else 0} points)"
    fig = section_panels(run, pieces, norm, cmap, contact, zoom, label, (1.5, 2.5), (run.axis("x"), run.axis("y")),
                         limits, h)
    scale_text = "true scale" if scale == 1 else f"displacement x {scale:g}"
    what = "deformed body" if len(pieces) == 1 else "deformed bodies"
    title(fig, run, f"{what} ({scale_text}) coloured by von Mises stress, contact zone in red")
    return save(fig, run, "plot_deformed.png")


def figure_pressure_2d(run, frame, note):
    import matplotlib.pyplot as plt

    h = mesh_step(run)
    window = contact_window(frame, ["x", "y"], h)
    pts = window[["x", "y"]].to_numpy(dtype=float)
    order, t = chain_order(pts)
    window = window.iloc[order]
    pts = pts[order]
    steps = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    # the walk ends by jumping to samples off the contact's curve (another part of body 1's
    # boundary near body 2): keep the runs between jumps that hold active points
    if len(steps) and np.median(steps) > 0:
        run_id = np.concatenate([[0], np.cumsum(steps > 5 * np.median(steps))])
        keep = np.isin(run_id, np.unique(run_id[window["active"].to_numpy() > 0]))
        if keep.any():
            window, pts = window[keep], pts[keep]
            steps = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(steps)])
    boundary = "the contact boundary" if run.script == "contact_foundation_2d" else "body 1's boundary"
    if abs(t[0]) > 0.98 and arc[-1] <= 1.02 * np.ptp(pts[:, 0]):
        # a straight horizontal contact: x itself
        arc = pts[:, 0]
        xlabel = f"x on {boundary} [{run.length}]"
    else:
        centre = contact_centre(frame, ["x", "y"])
        origin = "its first sample"
        if centre is not None:
            k = int(np.argmin(((pts - centre) ** 2).sum(axis=1)))
            arc = arc - arc[k]
            origin = f"the pressure centre ({centre[0]:.4g}, {centre[1]:.4g})"
        xlabel = f"arc length along {boundary} [{run.length}], 0 at {origin}"
    fig, ax = plt.subplots(figsize=(8, 5), layout="constrained")
    active = window["active"].to_numpy() > 0
    p = window["pressure"].to_numpy()
    ax.plot(arc[active], p[active], ".", ms=3, color="C0", label="raw (Nitsche multiplier), active points")
    if (~active).any():
        ax.plot(arc[~active], p[~active], ".", ms=3, color="0.6", label="raw, inactive points")
    for k, column in enumerate(recovered_columns(window)):
        ax.plot(arc, window[column].to_numpy(), "-", lw=1.5, color=f"C{k + 1}", label=f"recovered ({column})")
    ax.axhline(0.0, color="k", lw=0.5)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(f"{PRESSURE_LABEL} [{run.stress}]")
    lines = [f"{int(active.sum())} active of {len(frame)} points"]
    if "weight" in frame.columns:
        force = float((frame["weight"] * frame["pressure"]).sum())
        lines.append(f"integral of p ds = {force:.4g} [force/{run.length}]")
    contact = run.results.get("contact") or {}
    if isinstance(contact.get("active_measure"), (int, float)):
        lines.append(f"active length {contact['active_measure']:.4g} [{run.length}]")
    if note:
        lines.append(note)
    side_panel(ax, lines)
    title(fig, run, f"{PRESSURE_LABEL} along the contact")
    return save(fig, run, "plot_pressure.png")


def side_panel(ax, lines):
    """The legend and the information lines to the right of the plot, one above the other,
    so that neither covers the curves or the other."""
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0)
    ax.text(1.02, 0.45, "\n".join(lines), transform=ax.transAxes, va="top", ha="left", fontsize=8)


def newton_history(run):
    """(residual, active measure, changed measure, tolerance) from results.json, checked."""
    newton = run.results.get("newton") or {}
    path = run.folder / "results.json"
    if not isinstance(newton, dict):
        raise RunFolderError(f"{path}: 'newton' is not a table")
    residual = numeric_list(newton.get("residual"), path, "newton.residual")
    if not residual:
        raise RunFolderError(f"{path}: no Newton history (newton.residual)")
    active = numeric_list(newton.get("active_measure"), path, "newton.active_measure")
    changed = numeric_list(newton.get("changed_measure"), path, "newton.changed_measure")
    tolerance = newton.get("tolerance")
    return residual, active, changed, tolerance if isinstance(tolerance, (int, float)) else None


def figure_newton(run, history):
    import matplotlib.pyplot as plt

    residual, active, changed, tolerance = history
    iters = np.arange(1, len(residual) + 1)
    measure = "area" if run.dim == 3 else "length"
    unit = f"{run.length}^2" if run.dim == 3 else run.length
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(7, 6.5), sharex=True, layout="constrained")
    ax1.semilogy(iters, positive(residual), "o-", label="nonlinear residual")
    if tolerance is not None and tolerance > 0:
        ax1.axhline(tolerance, color="C3", ls="--", lw=1, label=f"tolerance {tolerance:g}")
    ax1.set_ylabel("residual (relative) [1]")
    ax1.legend(fontsize=8)
    ax1.grid(True, which="both", alpha=0.3)
    positives = [v for v in (*active, *changed) if v > 0]
    for values, style, label in ((active, "s-", f"active {measure}"),
                                 (changed, "^-", f"{measure} that changed side")):
        if values:
            ax2.plot(iters[:len(values)], values, style, label=label)
    if positives:
        # logarithmic above the smallest positive measure, linear below it: a step where
        # nothing changed side sits at 0 on the axis, not at an invented small value
        ax2.set_yscale("symlog", linthresh=min(positives), linscale=0.5)
        ax2.set_ylim(bottom=0)
    ax2.set_ylabel(f"contact {measure} [{unit}]")
    ax2.set_xlabel("Newton iteration")
    ax2.xaxis.get_major_locator().set_params(integer=True)
    ax2.grid(True, which="both", alpha=0.3)
    if ax2.lines:
        ax2.legend(fontsize=8)
    steps = len((run.results.get("steps") or {}).get("dofs") or [])
    what = "Newton history" + (f" (last of {steps} adaptation solves)" if steps > 1 else "")
    title(fig, run, what)
    return save(fig, run, "plot_newton.png")


def numeric_list(values, path, key):
    if values is None:
        return []
    if not isinstance(values, list) or not all(isinstance(v, (int, float)) for v in values):
        raise RunFolderError(f"{path}: {key} is not a list of numbers")
    return [float(v) for v in values]


def positive(values):
    """Zeros cannot be drawn on a log scale: shown at the smallest positive value / 10."""
    v = np.asarray(values, dtype=float)
    pos = v[v > 0]
    return np.where(v > 0, v, (pos.min() / 10) if len(pos) else 1e-300)


# --- 3D


def parse_plane(text):
    """'y=0' -> (1, 0.0)."""
    m = re.fullmatch(r"\s*([xyzXYZ])\s*=\s*([^=\s]+)\s*", text or "")
    if not m:
        raise RunFolderError(f"--plane {text!r}: expected AXIS=VALUE with AXIS x, y or z, e.g. y=0")
    try:
        value = float(m.group(2))
    except ValueError:
        raise RunFolderError(f"--plane {text!r}: {m.group(2)!r} is not a number") from None
    if not math.isfinite(value):
        raise RunFolderError(f"--plane {text!r}: not a finite number")
    return "xyz".index(m.group(1).lower()), value


def bodies_3d(run):
    meshes = []
    for i in (1, 2):
        filename = run.outputs.get(f"vtu_body{i}", f"body{i}.vtu")
        if not run.has_output(filename):
            return None
        mesh = read_vtu(run, filename)
        path = run.file(filename)
        tets = cells_of(mesh, path, "tetra", 4)
        u = point_field(mesh, path, "displacement", f"u{i}", size=3)
        vm = point_field(mesh, path, "von_mises_inside", "von_mises")   # as in 2D: FreeFEM's extension
        phi = point_field(mesh, path, "phi", f"phi{i}")
        meshes.append((f"body {i}", np.asarray(mesh.points[:, :3], dtype=float), tets, u, vm, phi))
    return meshes


def figure_cut_3d(run, meshes, plane, frame, scale):
    import matplotlib.pyplot as plt

    axis, level = plane
    inplane = [k for k in range(3) if k != axis]
    names = "xyz"
    pieces, sections = [], []
    for label, pts, tets, u, vm, phi in meshes:
        data = np.column_stack([pts, u, vm, phi])          # columns 0-2, 3-5, 6, 7
        sec, tris = cut_tetrahedra(tets, data, axis, level)
        sections.append((label, sec))
        if not len(tris):
            continue
        local = np.column_stack([sec[:, inplane], sec[:, [3 + k for k in inplane]], sec[:, 6], sec[:, 7]])
        clipped, ctris, segs = clip_triangles(tris, local, 5)
        pieces.append(Piece(label, clipped[:, 0:2] + scale * clipped[:, 2:4], ctris, clipped[:, 4], segs))
    if not pieces:
        raise RunFolderError(f"--plane {names[axis]}={level:g} misses both bodies of {run.folder}")
    cmap = plt.get_cmap("viridis")
    norm = vm_norm(pieces)
    h = mesh_step(run)
    contact = None
    if frame is not None:
        coords = ["x", "y", "z"]
        act = frame[(frame["active"] > 0) & ((frame[coords[axis]] - level).abs() <= 0.5 * h)]
        if not act.empty:
            pts = act[coords].to_numpy(dtype=float)
            # displaced by body 1's displacement at the nearest section vertex
            sec = next(sec for label, sec in sections if label == "body 1")
            if len(sec):
                near = nearest(sec[:, :3], pts)
                pts = pts + scale * sec[near, 3:6]
            contact = pts[:, inplane]
    geometry = run.scene.get("geometry") or {}
    limits = [(geometry.get(f"{names[k]}min"), geometry.get(f"{names[k]}max")) for k in inplane]
    if not all(isinstance(v, (int, float)) for pair in limits for v in pair):
        limits = None
    label = f"active contact points within h/2 of the plane ({len(contact) if contact is not None else 0})"
    fig = section_panels(run, pieces, norm, cmap, contact, contact is not None, label, (2, 3),
                         (run.axis(names[inplane[0]]), run.axis(names[inplane[1]])), limits, h)
    scale_text = "true scale" if scale == 1 else f"displacement x {scale:g}"
    title(fig, run, f"cut {names[axis]} = {level:.4g} ({scale_text}) coloured by von Mises stress, contact in red")
    return save(fig, run, f"plot_cut_{names[axis]}{level:.4g}.png")


def nearest(points, queries):
    """Index of the nearest of points for each query (brute force in blocks)."""
    out = np.empty(len(queries), dtype=np.int64)
    for start in range(0, len(queries), 256):
        q = queries[start:start + 256]
        d = ((q[:, None, :] - points[None, :, :]) ** 2).sum(axis=2)
        out[start:start + 256] = np.argmin(d, axis=1)
    return out


def contact_basis(run, frame):
    """Unit normal of the contact (along the force on body 1) and two in-plane unit vectors with
    their axis labels."""
    force = (run.results.get("contact") or {}).get("force_on_body1")
    n = None
    if isinstance(force, list) and len(force) == 3 and all(isinstance(v, (int, float)) for v in force):
        n = np.asarray(force, dtype=float)
    if n is None or np.linalg.norm(n) == 0:
        n = np.array([0.0, 0.0, 1.0])
    n = n / np.linalg.norm(n)
    names = "xyz"
    main = int(np.argmax(np.abs(n)))
    basis, labels = [], []
    for k in (k for k in range(3) if k != main):
        e = np.eye(3)[k]
        for b in basis:
            e = e - (e @ b) * b
        e = e - (e @ n) * n
        e = e / np.linalg.norm(e)
        basis.append(e)
        if abs(e[k]) > 1 - 1e-9:
            labels.append(names[k])
        else:
            labels.append("(" + ", ".join(f"{c:.3g}" for c in e) + ") . position")
    return n, basis, labels


def figure_pressure_3d(run, frame, note):
    import matplotlib.pyplot as plt

    coords = ["x", "y", "z"]
    h = mesh_step(run)
    n, (e1, e2), labels = contact_basis(run, frame)
    window = contact_window(frame, coords, h)
    pts = window[coords].to_numpy(dtype=float)
    s = np.column_stack([pts @ e1, pts @ e2])
    p = window["pressure"].to_numpy()
    active = window["active"].to_numpy() > 0
    centre = contact_centre(frame, coords)
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 5.4), layout="constrained")
    if (~active).any():
        ax1.scatter(s[~active, 0], s[~active, 1], s=4, c="0.75", label="inactive points")
    recovered = recovered_columns(window)
    colour = window[recovered[0]].to_numpy() if recovered else p
    what = f"recovered ({recovered[0]})" if recovered else "raw"
    image = ax1.scatter(s[active, 0], s[active, 1], s=9, c=colour[active], cmap="viridis", vmin=0,
                        label=f"active points, coloured by the {what} pressure")
    ax1.set_aspect("equal")
    ax1.set_xlabel(run.axis(labels[0]))
    ax1.set_ylabel(run.axis(labels[1]))
    ax1.set_title("projected on the plane normal to the contact force n = (" +
                  ", ".join(f"{c:.3g}" for c in n) + ")", fontsize=9)
    ax1.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=1)
    fig.colorbar(image, ax=ax1, label=f"{PRESSURE_LABEL} [{run.stress}]", shrink=0.9)
    if centre is not None:
        c2 = np.array([centre @ e1, centre @ e2])
        ax1.plot(*c2, "+", color="red", ms=10)
        r = np.linalg.norm(s - c2, axis=1)
        ax2.plot(r[active], p[active], ".", ms=3, color="C0", label="raw (Nitsche multiplier), active points")
        if (~active).any():
            ax2.plot(r[~active], p[~active], ".", ms=3, color="0.6", label="raw, inactive points")
        for k, column in enumerate(recovered_columns(window)):
            ax2.plot(r, window[column].to_numpy(), ".", ms=3, color=f"C{k + 1}", label=f"recovered ({column})")
        ax2.set_xlabel(f"distance from the pressure centre (red +) in that plane [{run.length}]")
    ax2.set_ylabel(f"{PRESSURE_LABEL} [{run.stress}]")
    ax2.axhline(0.0, color="k", lw=0.5)
    lines = [f"{int((frame['active'] > 0).sum())} active of {len(frame)} points"]
    if recovered and np.nanmax(colour) > 0:
        # the axis follows the recovered pressure; raw values above it are counted, not drawn
        top = 1.5 * float(np.nanmax(colour))
        ax2.set_ylim(-0.05 * top, top)
        above = int((p > top).sum())
        if above:
            lines.append(f"{above} raw values above the axis (largest {p.max():.4g})")
    if "weight" in frame.columns:
        force = float((frame["weight"] * frame["pressure"]).sum())
        lines.append(f"integral of p dA = {force:.4g} [force]")
    if note:
        lines.append(note)
    side_panel(ax2, lines)
    title(fig, run, f"{PRESSURE_LABEL} on the contact surface")
    return save(fig, run, "plot_pressure.png")


# ---------------------------------------------------------------------------


def plot_run(folder, plane=None, scale=1.0, note=None):
    """Write the figures of one run folder into it; returns their paths. note(text) reports a
    figure left out because the run did not write its input."""
    import matplotlib

    matplotlib.use("Agg")
    if note is None:
        def note(text):
            print(f"note: {text}", file=sys.stderr)
    if not math.isfinite(scale):
        raise RunFolderError(f"--scale {scale}: not a finite number")
    try:
        return plot_checked(folder, plane, scale, note)
    except (AttributeError, TypeError, KeyError, IndexError, ValueError) as exc:
        raise RunFolderError(f"{folder}: a file of the run is malformed ({type(exc).__name__}: "
                             f"{one_line(exc)[:120]})") from None


def plot_checked(folder, plane, scale, note):
    run = RunData(folder)
    if not os.access(run.folder, os.W_OK):
        raise RunFolderError(f"{run.folder}: not writable, the figures are written into the run folder")
    written = []
    history = newton_history(run)
    frame, sign_note = contact_frame(run)
    if frame is None:
        note(f"{run.folder}: no contact_pressure.csv (output off): no pressure figure")
    if run.dim == 2:
        if plane is not None:
            raise RunFolderError(f"--plane is for 3D runs; {run.folder} is a 2D run")
        pieces, u1_field = bodies_2d(run, scale)
        if pieces is None:
            note(f"{run.folder}: no fields.vtu (output.vtu off): no deformed-body figure")
        else:
            written.append(figure_deformed_2d(run, pieces, u1_field, frame, scale))
        if frame is not None:
            written.append(figure_pressure_2d(run, frame, sign_note))
    else:
        meshes = bodies_3d(run)
        if plane is None:
            centre = contact_centre(frame, ["x", "y", "z"]) if frame is not None else None
            level = float(centre[1]) if centre is not None else 0.0
            step = mesh_step(run) / 4        # the centre is known to O(h): a quarter step
            plane = (1, float(f"{round(level / step) * step:.6g}") + 0.0)
        else:
            plane = parse_plane(plane)
        if meshes is None:
            note(f"{run.folder}: no body1.vtu/body2.vtu (output.vtu off): no cut figure")
        else:
            written.append(figure_cut_3d(run, meshes, plane, frame, scale))
        if frame is not None:
            written.append(figure_pressure_3d(run, frame, sign_note))
    written.append(figure_newton(run, history))
    return written

