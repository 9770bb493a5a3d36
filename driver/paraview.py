"""ParaView-ready outputs of a converged two-body run, written by the driver into the run
folder before it is published: the bodies' files show what `plot` shows, and one
collection file groups them.

- body1.vtu, body2.vtu gain the point array `von_mises_inside`: von Mises with the value at
  each vertex outside the body (a vertex of a cut element, where the element's stress is
  its polynomial extended beyond the body, largest on tiny cuts) replaced by the mean of
  the inside vertices it shares an edge with (`inside_extension`, the plot's rule), ring
  after ring outward, so that its range is the inside's. Clipped at phi = 0 it is the
  field the plots draw; `von_mises` stays as FreeFEM wrote it.
- bodies.pvd: a VTK collection of both bodies (part 0: body 1, part 1: body 2) at the last
  adaptation step (timestep: its index); open it in ParaView to load both at once.
"""

import os
from pathlib import Path

import numpy as np

PVD = "bodies.pvd"


def inside_extension(cells, values, phi, rings=1):
    """values with those at the vertices outside {phi < 0} of cells the level set cuts replaced by
    the mean over their edges of the inside vertices' values. A stress at a vertex outside a
    body is its field extended from a cut element, possibly a tiny cut: not the body's.
    rings > 1 repeats it outward, the vertices filled counting as inside (None: until every
    vertex connected to the inside is filled)."""
    out = np.array(values, dtype=float)
    known = phi < 0
    corners = cells.shape[1]
    ring = 0
    while rings is None or ring < rings:
        ring += 1
        total = np.zeros(len(out))
        count = np.zeros(len(out))
        for i in range(corners):
            for j in range(corners):
                if i == j:
                    continue
                p, q = cells[:, i], cells[:, j]
                sel = ~known[p] & known[q]
                np.add.at(total, p[sel], out[q[sel]])
                np.add.at(count, p[sel], 1.0)
        fill = count > 0
        if not fill.any():
            break
        out[fill] = total[fill] / count[fill]
        known = known | fill
    return out


def add_inside_stress(path):
    """Add von_mises_inside to a body VTU (rewritten beside it, then moved over it)."""
    import meshio

    mesh = meshio.vtu.read(path)
    vm = np.asarray(mesh.point_data["von_mises"], dtype=float).reshape(-1)
    phi = np.asarray(mesh.point_data["phi"], dtype=float).reshape(-1)
    kind = "tetra" if any(block.type == "tetra" for block in mesh.cells) else "triangle"   # the body's cells
    cells = np.vstack([block.data for block in mesh.cells if block.type == kind])
    mesh.point_data["von_mises_inside"] = inside_extension(cells, vm, phi, rings=None)
    tmp = Path(path).with_name(f".{Path(path).name}.tmp.vtu")
    meshio.vtu.write(tmp, mesh, binary=True, compression=None)   # raw base64: 40 times faster than ASCII
    os.replace(tmp, path)


def write_collection(folder, datasets):
    """bodies.pvd: the datasets (timestep, name, file), each body a part of its timestep."""
    rows = "\n".join(f'    <DataSet timestep="{step}" part="{k}" file="{file}" name="{name}"/>'
                     for step, k, name, file in datasets)
    (Path(folder) / PVD).write_text('<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1">\n'
                                    f"  <Collection>\n{rows}\n  </Collection>\n</VTKFile>\n")


def paraview_files(folder, results):
    """For a two-body run that wrote its bodies' VTUs: von_mises_inside in each, and
    bodies.pvd over the adaptation steps (the earlier steps' files steps/bodyI_K.vtu,
    the last step's bodyI.vtu); results.json's outputs gain "pvd". Nothing for other runs."""
    outputs = results.get("outputs") or {}
    last = [(name, outputs.get(f"vtu_{name}")) for name in ("body1", "body2")]
    if not all(file and (Path(folder) / file).is_file() for _, file in last):
        return
    steps = len((results.get("steps") or {}).get("dofs") or [1])
    datasets = [(step, k, name, f"steps/{name}_{step}.vtu")
                for step in range(steps - 1) for k, name in enumerate(("body1", "body2"))]
    datasets = [d for d in datasets if (Path(folder) / d[3]).is_file()]
    datasets += [(steps - 1, k, name, file) for k, (name, file) in enumerate(last)]
    for *_, file in datasets:
        add_inside_stress(Path(folder) / file)
    write_collection(folder, datasets)
    outputs["pvd"] = PVD
