"""The curved cut geometry (method.geometry = "curved", docs/curved-geometry.md) against
the P1 one: the geometric accuracy of the cut cells, the disk-on-slab convergence
against a curved P2 reference, the cost of the NX = 80 run, and two problems without
contact whose solutions are smooth (a patch test with an exact quadratic solution and
a held ring), where the elements' own orders show whether the geometry limits them.

The solver and the error tool compute; this module runs, tabulates and times.
"""

import tomllib

import numpy as np
import pandas as pd

from driver.runner import REPO, TOOLS_DIR, freefem_binary, parse_json_file, run_command, run_scene
from driver.scene import load_scene
from driver.studies.common import (RESULTS_DIR, cached_reference, loglog_slope, progress, run_point, save_figure,
                                   tool_errors)
from driver.studies.fd2d import DISK, QUIET, REFERENCE_NX, reference, run_with_errors

GEOMETRIES = ("p1", "curved")
LADDER = (40, 80, 160)
COST_NX, COST_REPEATS = 80, 3
PHASES = ("geometry", "assembly", "newton", "estimators", "all_steps")

VERIFICATION = REPO / "cases" / "verification"
CLAMPED_DISK = VERIFICATION / "clamped_disk.toml"
HELD_RING = VERIFICATION / "held_ring.toml"
PATCH_LADDER = (10, 20, 40, 80)
SMOOTH_LADDER = (10, 20, 40, 80, 160)
SMOOTH_REFERENCE_NX = 320
SMOOTH_THETAS = (1.0, 0.0, -1.0)
SMOOTH_RATE_MESHES = 3   # least squares on the finest three of the ladder


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


def clamped_disk_exact(scene_path):
    """The exact displacement of the clamped-disk scene at its probes, from the scene's
    own data: u = f (R^2 - r^2)/(2 lambda + 6 mu), r the distance to the centre."""
    scene = tomllib.loads(scene_path.read_text())
    body = scene["body2"]
    centre, radius = np.array(body["shape"]["centre"]), body["shape"]["radius"]
    force = np.array(body["body_force"])
    factor = 1.0 / (2 * body["lambda"] + 6 * body["mu"])
    return {probe["name"]: force * factor * (radius ** 2 - np.sum((np.array(probe["point"]) - centre) ** 2))
            for probe in scene["probe"]}


def smooth_reference(theta):
    """The held ring, P2 at NX = SMOOTH_REFERENCE_NX on the curved geometry, saved."""
    folder = REPO / "runs" / "reference" / f"held_ring_p2_nx{SMOOTH_REFERENCE_NX}_theta{theta:g}_curved"

    def compute():
        scene, module = load_scene(HELD_RING, [f"mesh.nx={SMOOTH_REFERENCE_NX}", f"method.theta={theta}",
                                               "method.geometry=curved", "output.save_solution=true",
                                               "output.estimators=false", *QUIET])
        run_scene(scene, module, out_dir=folder, replace=True)

    return cached_reference(folder, f"the held-ring reference (P2, NX = {SMOOTH_REFERENCE_NX}, theta = {theta:g})",
                            compute)


def smooth_problems():
    """The patch test (clamped disk: probes against the exact quadratic, NX = 10..80) and
    the held ring's ladder NX = 10..160 against its curved NX = 320 reference for every
    theta, both geometries: results/curved_patch.csv, results/curved_smooth.csv,
    results/curved_smooth_rates.csv, plots/curved_smooth.png."""
    exact = clamped_disk_exact(CLAMPED_DISK)
    scale = max(np.linalg.norm(u) for u in exact.values())
    patch = []
    grid = [(g, nx) for g in GEOMETRIES for nx in PATCH_LADDER]
    for n, (geometry, nx) in enumerate(grid, start=1):
        progress(n, len(grid), f"clamped disk, NX = {nx}, geometry {geometry}")
        row, results, _ = run_point(CLAMPED_DISK, [f"mesh.nx={nx}", f"method.geometry={geometry}", *QUIET])
        out = dict(geometry=geometry, nx=nx, status=row["status"])
        if results is not None:
            errors = {name: np.linalg.norm(np.array(results["probes"][name]) - u) / scale for name, u in exact.items()}
            out.update({f"probe_err_{name}": e for name, e in errors.items()},
                       max_probe_err=max(errors.values()),
                       area_rel_err=results["areas"]["body2"] / results["areas"]["body2_exact"] - 1,
                       newton_iterations=results["newton"]["iterations"])
        patch.append(out)
    pd.DataFrame(patch).to_csv(RESULTS_DIR / "curved_patch.csv", index=False)

    rows = []
    grid = [(theta, g, nx) for theta in SMOOTH_THETAS for g in GEOMETRIES for nx in SMOOTH_LADDER]
    for n, (theta, geometry, nx) in enumerate(grid, start=1):
        ref = smooth_reference(theta)
        progress(n, len(grid), f"held ring, theta = {theta:g}, NX = {nx}, geometry {geometry}")
        row, results, folder = run_point(HELD_RING, [f"mesh.nx={nx}", f"method.theta={theta}",
                                                     f"method.geometry={geometry}", "output.save_solution=true",
                                                     "output.estimators=false", *QUIET])
        out = dict(theta=theta, geometry=geometry, nx=nx, status=row["status"])
        if results is not None:
            err = tool_errors("fd_error_2d.edp", ref, folder)
            out.update(h=results["h"], dofs=results["dofs"], l2_body2=err["l2_body2"], h1_body2=err["h1_body2"],
                       area_rel_err=results["areas"]["body2"] / results["areas"]["body2_exact"] - 1,
                       stabilization=results["cut"]["stabilization"], dropped=results["cut"]["dropped_body2"],
                       points_in_reference_slivers=err["points_in_reference_slivers"]["body2"],
                       newton_iterations=results["newton"]["iterations"], wall_s=row["wall_s"])
        rows.append(out)
    table = pd.DataFrame(rows)
    table.to_csv(RESULTS_DIR / "curved_smooth.csv", index=False)
    rates = []
    for (theta, geometry), group in table[table.status == "converged"].groupby(["theta", "geometry"], sort=False):
        finest = group.sort_values("h").iloc[:SMOOTH_RATE_MESHES]
        rates.append(dict(theta=theta, geometry=geometry, nx_used=" ".join(str(int(v)) for v in sorted(finest.nx)),
                          l2_rate=loglog_slope(finest.h, finest.l2_body2),
                          h1_rate=loglog_slope(finest.h, finest.h1_body2)))
    pd.DataFrame(rates).to_csv(RESULTS_DIR / "curved_smooth_rates.csv", index=False)
    plot_smooth(table)
    print(f"wrote {RESULTS_DIR / 'curved_patch.csv'}, {RESULTS_DIR / 'curved_smooth.csv'}, "
          f"{RESULTS_DIR / 'curved_smooth_rates.csv'}")


def plot_smooth(table):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = table[table.status == "converged"]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5), sharex=True)
    for ax, norm, order in ((axes[0], "l2", 3), (axes[1], "h1", 2)):
        for (theta, geometry), group in ok.groupby(["theta", "geometry"]):
            group = group.sort_values("h")
            ax.loglog(group.h, group[f"{norm}_body2"], "o-" if geometry == "curved" else "s--",
                      label=f"{geometry}, theta = {theta:g}")
        h = np.array(sorted(ok.h.unique()))
        anchor = ok[(ok.geometry == "curved") & (ok.h == h[0])][f"{norm}_body2"].max()
        ax.loglog(h, anchor * (h / h[0]) ** order, "k:", label=f"h^{order}")
        ax.set_xlabel("h")
        ax.set_title(f"held ring, P2: relative {norm.upper()} error")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle("python -m driver study curved-smooth", fontsize=9)
    save_figure(fig, "curved_smooth.png")
