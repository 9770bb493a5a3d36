"""The curved cut geometry (method.geometry = "curved", docs/curved-geometry.md) against
the P1 one: the geometric accuracy of the cut cells, the disk-on-slab convergence
against a curved P2 reference, and the cost of the NX = 80 run.

The solver and the error tool compute; this module runs, tabulates and times.
"""

import numpy as np
import pandas as pd

from driver.runner import REPO, TOOLS_DIR, freefem_binary, parse_json_file, run_command
from driver.studies.common import RESULTS_DIR, progress, run_point
from driver.studies.fd2d import DISK, QUIET, REFERENCE_NX, reference, run_with_errors

GEOMETRIES = ("p1", "curved")
LADDER = (40, 80, 160)
COST_NX, COST_REPEATS = 80, 3
PHASES = ("geometry", "assembly", "newton", "estimators", "all_steps")


def geometry_check():
    """Area, perimeter and a polynomial's integral over two disks at NX = 20, 40, 80, P1 and
    curved cells (freefem/tools/curved_geometry_check.edp): results/curved_geometry.csv;
    volume, area and a polynomial's integral over two balls at nx = 8, 16, 32
    (curved_geometry_check_3d.edp): results/curved_geometry_3d.csv."""
    for tool, csv in (("curved_geometry_check.edp", "curved_geometry.csv"),
                      ("curved_geometry_check_3d.edp", "curved_geometry_3d.csv")):
        out = RESULTS_DIR / csv
        run_command([freefem_binary(), "-nw", "-v", "0", str(TOOLS_DIR / tool), "-out", str(out)],
                    f"the curved-geometry check ({tool})", cwd=REPO)
        print(f"wrote {out}")


def convergence():
    """Disk-centre u_y and L2/H1 errors per body (fd_error_2d.edp) of both geometries on
    NX = 40, 80, 160 against the curved reference: results/curved_convergence.csv. Then
    the NX = 80 run as make case runs it (estimators on), repeated, minimum CPU per
    geometry and its ratio to P1: results/curved_cost.csv."""
    ref = reference(REFERENCE_NX, "curved")
    centre_ref = parse_json_file(ref / "results.json")["probes"]["centre"][1]
    rows = []
    for n, (geometry, nx) in enumerate([(g, nx) for g in GEOMETRIES for nx in LADDER], start=1):
        progress(n, len(GEOMETRIES) * len(LADDER), f"P2 NX = {nx}, geometry {geometry}")
        row = run_with_errors(ref, [f"mesh.nx={nx}", f"method.geometry={geometry}"],
                              {"geometry": geometry, "nx": nx})
        row["centre_rel_err"] = abs(row["centre_uy"] - centre_ref) / abs(centre_ref)
        rows.append(row)
    table = pd.DataFrame(rows)
    table["reference_uy"] = centre_ref
    table["rate"] = table.groupby("geometry")["centre_rel_err"].transform(
        lambda e: -np.log(e / e.shift()) / np.log(table.loc[e.index, "nx"] / table.loc[e.index, "nx"].shift()))
    table.to_csv(RESULTS_DIR / "curved_convergence.csv", index=False)
    cost = []
    for geometry in GEOMETRIES:
        cpu = []
        for i in range(COST_REPEATS):
            progress(i + 1, COST_REPEATS, f"cost, NX = {COST_NX}, geometry {geometry}")
            _, results, _ = run_point(DISK, [f"mesh.nx={COST_NX}", f"method.geometry={geometry}", *QUIET])
            cpu.append(results["timings_cpu_s"])
        best = min(cpu, key=lambda t: t["all_steps"])
        cost.append({"geometry": geometry, "nx": COST_NX, "repeats": COST_REPEATS,
                     **{f"cpu_{k}_s": best[k] for k in PHASES}})
    cost = pd.DataFrame(cost)
    cost["relative_to_p1"] = cost["cpu_all_steps_s"] / cost["cpu_all_steps_s"].iloc[0]
    cost.to_csv(RESULTS_DIR / "curved_cost.csv", index=False)
    print(f"wrote {RESULTS_DIR / 'curved_convergence.csv'}, {RESULTS_DIR / 'curved_cost.csv'}")
