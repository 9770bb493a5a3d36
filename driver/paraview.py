"""ParaView's collection of a converged two-body run, written by the driver into the run
folder before it is published: bodies.pvd, a VTK collection of both bodies (part 0: body 1,
part 1: body 2) at each adaptation step (timestep: its index); open it in ParaView to load
them at once. The bodies' files are FreeFEM's, with the point array von_mises_inside to
colour by (freefem/lib/core/results.idp, fdVonMisesInside).
"""

from pathlib import Path

PVD = "bodies.pvd"


def write_collection(folder, datasets):
    """bodies.pvd: the datasets (timestep, name, file), each body a part of its timestep."""
    rows = "\n".join(f'    <DataSet timestep="{step}" part="{k}" file="{file}" name="{name}"/>'
                     for step, k, name, file in datasets)
    (Path(folder) / PVD).write_text('<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1">\n'
                                    f"  <Collection>\n{rows}\n  </Collection>\n</VTKFile>\n")


def paraview_files(folder, results):
    """For a two-body run that wrote its bodies' VTUs: bodies.pvd over the adaptation steps (the
    earlier steps' files steps/bodyI_K.vtu, the last step's bodyI.vtu); results.json's outputs
    gain "pvd". Nothing for other runs."""
    outputs = results.get("outputs") or {}
    last = [(name, outputs.get(f"vtu_{name}")) for name in ("body1", "body2")]
    if not all(file and (Path(folder) / file).is_file() for _, file in last):
        return
    steps = len((results.get("steps") or {}).get("dofs") or [1])
    datasets = [(step, k, name, f"steps/{name}_{step}.vtu")
                for step in range(steps - 1) for k, name in enumerate(("body1", "body2"))]
    datasets = [d for d in datasets if (Path(folder) / d[3]).is_file()]
    datasets += [(steps - 1, k, name, file) for k, (name, file) in enumerate(last)]
    write_collection(folder, datasets)
    outputs["pvd"] = PVD
