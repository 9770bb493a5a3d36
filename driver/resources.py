"""Size of a run before it starts: estimated DOFs and peak memory against the machine.

The fits come from measured runs (results/bench.csv for 2D, results/fd3d_convergence.csv
for 3D: DOFs and peak resident memory per mesh size). They are deliberately on the
high side: their purpose is to refuse a run that cannot fit (a mesh far beyond the
memory would otherwise crash FreeFEM after minutes), not to predict its cost.
"""

import math
from pathlib import Path

from .errors import SceneError

# DOFs per cell of the initial background mesh (both bodies, measured).
DOFS_PER_CELL_2D = {1: 1.0, 2: 3.8}     # nx = 160: 23,776 (P1), 93,744 (P2) over nx^2 = 25,600
DOFS_PER_CELL_3D = {1: 1.15, 2: 9.5}    # nx = 48 P1: 121,764; nx = 20 P2: 73,890


def estimated_dofs(scene):
    """DOFs of the first solve, or of the largest adaptive step when that is bigger."""
    script, degree = scene["scene"]["script"], scene["method"]["degree"]
    nx = scene["mesh"]["nx"]
    if script == "fd_contact_3d":
        dofs = DOFS_PER_CELL_3D[degree] * nx ** 3
    elif script == "fd_contact_2d":
        dofs = DOFS_PER_CELL_2D[degree] * nx ** 2
    else:   # body-fitted foundation: nx cells across the box's width
        geo = scene.get("geometry", {})
        width = max(geo.get("xmax", 1.0) - geo.get("xmin", 0.0), 1e-300)
        aspect = (geo.get("ymax", 1.0) - geo.get("ymin", 0.0)) / width
        dofs = 2 * (degree * nx) ** 2 * max(aspect, 1e-12)
    adapt = scene.get("adapt", {})
    steps = adapt.get("steps", 0)
    if steps > 0:   # each step aims at growth x the DOFs, and stops before max_dofs
        growth = max(adapt.get("growth", 2.0), 1.0)
        grown = dofs * 1.5 * growth ** min(steps, 200)
        dofs = max(dofs, min(grown, adapt.get("max_dofs", grown)))
    return dofs


def estimated_memory_mb(scene, dofs):
    """Peak resident memory in MiB (sparse direct factorization: fill grows faster in 3D)."""
    if scene["scene"]["script"] == "fd_contact_3d":
        return 60.0 + 9e-4 * dofs ** (4.0 / 3.0)    # P2 nx = 20: 2,682 MiB measured
    return 50.0 + 7e-3 * dofs                         # P2 nx = 160: 603 MiB measured


def available_memory_mb():
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) / 1024.0
    except (OSError, ValueError, IndexError):
        pass
    return math.inf


def check_fits(scene, source):
    """Refuse (exit 2) a run whose estimated memory exceeds what the machine has available."""
    try:
        dofs = float(estimated_dofs(scene))
        need = float(estimated_memory_mb(scene, dofs))
    except OverflowError:
        dofs = need = math.inf
    have = available_memory_mb()
    if need > 0.9 * have:
        raise SceneError(f"{source}: the run is too large for this machine: about {dofs:.3g} DOFs and "
                         f"{need / 1024:.3g} GiB of memory estimated, {have / 1024:.3g} GiB available "
                         f"(reduce mesh.nx or adapt.max_dofs)")
    return dofs, need
