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

from driver.errors import DriverError
from driver.runner import REPO, TOOLS_DIR, freefem_binary, parse_json_file, run_command
from driver.sweep import run_point, run_points, scene_point
from .common import RESULTS_DIR, loglog_slope, progress, save_figure, saved_reference, tool_errors
from .fd2d import DISK, QUIET, REFERENCE_NX, adaptive_rows, reference, run_with_errors
from .fd3d import QUIET as QUIET_3D

GEOMETRIES = ("p1", "curved")
LADDER = (40, 80, 160)
COST_NX, COST_REPEATS = 80, 3
PHASES = ("geometry", "assembly", "newton", "estimators", "all_steps")

VERIFICATION = REPO / "cases" / "verification"
CLAMPED_DISK = VERIFICATION / "clamped_disk.toml"
HELD_RING = VERIFICATION / "held_ring.toml"
CLAMPED_BALL = VERIFICATION / "clamped_ball.toml"
HELD_SHELL = VERIFICATION / "held_shell.toml"
PATCH_LADDER = (10, 20, 40, 80)
SMOOTH_LADDER = (10, 20, 40, 80, 160)
SMOOTH_REFERENCE_NX = 320
PATCH_LADDER_3D = (6, 8, 12)
SMOOTH_LADDER_3D = (8, 12, 16)
SMOOTH_REFERENCE_NX_3D = 32
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


ADAPT_START_NX, ADAPT_STEPS = 20, 5


def adaptive():
    """The disk on slab on estimator-adapted meshes (curved geometry, P2, theta = -1, the
    scene's stabilization, from NX = ADAPT_START_NX, ADAPT_STEPS adaptations): each step's
    estimators, L2/H1 errors per body against the curved reference and the relative error
    of the disk's area: results/curved_adaptive.csv (the uniform ladder it is read beside
    is results/curved_convergence.csv)."""
    ref = reference(REFERENCE_NX, "curved")
    progress(1, 1, f"adaptive P2 from NX = {ADAPT_START_NX}, {ADAPT_STEPS} steps")
    rows, results = adaptive_rows(ref, ADAPT_START_NX, ADAPT_STEPS, [])
    table = pd.DataFrame(rows)
    exact = results["measures"]["body1_exact"]
    table["area_rel_err"] = (table.area_body1 - exact) / exact
    out = RESULTS_DIR / "curved_adaptive.csv"
    table.to_csv(out, index=False)
    print(f"wrote {out}")


# Every NX = 8k from 48 to 400: where the contact zone's ends fall in their elements
# moves from mesh to mesh, and with it the disk's approach (docs/curved-geometry.md).
SCAN_NX = tuple(range(48, 401, 8))
SCAN_WINDOWS = ((48, 96), (104, 160), (168, 256), (264, 400))
SCAN_RUNS = REPO / "runs" / "curved-centre-scan"


def centre_scan():
    """The disk-centre u_y of the disk on slab (P2, theta = -1, curved geometry, the
    scene's stabilization) on every mesh of SCAN_NX, and its deviation from that of the
    reference's mesh (REFERENCE_NX, run with them): results/curved_centre_scan.csv (with the active zone's ends
    and the disk's area error).
    Per window of NX (SCAN_WINDOWS), the half range of u_y relative to the reference's
    u_y (how far the approach swings between neighbouring meshes) and the least-squares
    slope of the half ranges against h: results/curved_centre_scan_windows.csv;
    plots/curved_centre_scan.png."""
    # the reference's settings but for the saved solution: its NX is one of the scan's
    # runs, whose u_y is the reference's (no second solve of it)
    scan_nx = sorted({*SCAN_NX, REFERENCE_NX})
    points = [scene_point(DISK, [f"mesh.nx={nx}", "output.estimators=false", *QUIET], SCAN_RUNS, {"nx": nx}, index=i)
              for i, nx in enumerate(scan_nx)]
    rows = pd.DataFrame(run_points(points, "curved-centre-scan"))
    failed = rows[rows.status != "converged"]
    if len(failed):
        raise DriverError(f"curved-centre-scan: NX = {', '.join(map(str, failed.nx))} did not converge")
    centre_ref = rows.loc[rows.nx == REFERENCE_NX, "probes.centre.1"].iloc[0]
    table = pd.DataFrame({"nx": rows.nx, "dofs": rows.dofs, "centre_uy": rows["probes.centre.1"],
                          "active_xmin": rows["contact.active_extent.x.0"],
                          "active_xmax": rows["contact.active_extent.x.1"],
                          "newton_iterations": rows.newton_iterations, "wall_s": rows.wall_s,
                          "area_rel_err": (rows["measures.body1"] - rows["measures.body1_exact"]) / rows["measures.body1_exact"]})
    table["reference_uy"] = centre_ref
    table["rel_dev"] = (table.centre_uy - centre_ref) / abs(centre_ref)
    table.to_csv(RESULTS_DIR / "curved_centre_scan.csv", index=False)
    windows = []
    for lo, hi in SCAN_WINDOWS:
        part = table[(table.nx >= lo) & (table.nx <= hi)]
        windows.append({"nx_from": lo, "nx_to": hi, "meshes": len(part),
                        "h_mean": float(np.exp(np.mean(np.log(1.0 / part.nx)))),
                        "half_range_rel": (part.centre_uy.max() - part.centre_uy.min()) / 2 / abs(centre_ref),
                        "max_abs_dev_rel": part.rel_dev.abs().max(),
                        "max_abs_area_rel_err": part.area_rel_err.abs().max()})
    windows = pd.DataFrame(windows)
    windows["slope"] = loglog_slope(windows.h_mean, windows.half_range_rel)
    windows.to_csv(RESULTS_DIR / "curved_centre_scan_windows.csv", index=False)
    plot_centre_scan(table, windows)
    print(f"wrote {RESULTS_DIR / 'curved_centre_scan.csv'}, {RESULTS_DIR / 'curved_centre_scan_windows.csv'}")


def plot_centre_scan(table, windows):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
    axes[0].plot(table.nx, table.centre_uy, "o-", ms=3, lw=0.8, label="P2, curved geometry")
    axes[0].axhline(table.reference_uy.iloc[0], color="k", ls=":", label=f"NX = {REFERENCE_NX} reference")
    axes[0].set_xlabel("NX")
    axes[0].set_ylabel("disk-centre u_y")
    axes[0].legend(fontsize=8)
    axes[0].grid(True, alpha=0.3)
    axes[1].loglog(1.0 / table.nx, table.rel_dev.abs(), "o", ms=3, label="|u_y - reference| / |reference|")
    axes[1].loglog(windows.h_mean, windows.half_range_rel, "s-",
                   label=f"half range per window of NX (slope {windows.slope.iloc[0]:.2f})")
    axes[1].set_xlabel("h = 1/NX")
    axes[1].legend(fontsize=8)
    axes[1].grid(True, which="both", alpha=0.3)
    fig.suptitle("disk on slab, P2, theta = -1: the disk's approach from mesh to mesh "
                 "(python -m driver study curved-centre-scan)", fontsize=9)
    save_figure(fig, "curved_centre_scan.png")


def clamped_exact(scene_path):
    """The exact displacement of a clamped-ball scene (clamped_disk, clamped_ball) at its
    probes, from the scene's own data: u = f (R^2 - r^2)/(2 lambda + (2 d + 2) mu) in
    dimension d, r the distance to the centre."""
    scene = tomllib.loads(scene_path.read_text())
    body = scene["body2"]
    centre, radius = np.array(body["shape"]["centre"]), body["shape"]["radius"]
    force = np.array(body["body_force"])
    factor = 1.0 / (2 * body["lambda"] + (2 * len(centre) + 2) * body["mu"])
    return {probe["name"]: force * factor * (radius ** 2 - np.sum((np.array(probe["point"]) - centre) ** 2))
            for probe in scene["probe"]}


def patch_test(scene_path, ladder, csv, measure_name, quiet):
    """The clamped scene on both geometries (quiet: the overrides that turn its output
    files off): largest probe error relative to the largest exact displacement, and
    body 2's area (2D) or volume (3D) error (column MEASURE_NAME_rel_err): RESULTS_DIR/csv."""
    exact = clamped_exact(scene_path)
    scale = max(np.linalg.norm(u) for u in exact.values())
    rows = []
    grid = [(g, nx) for g in GEOMETRIES for nx in ladder]
    for n, (geometry, nx) in enumerate(grid, start=1):
        progress(n, len(grid), f"{scene_path.stem}, NX = {nx}, geometry {geometry}")
        row, results, _ = run_point(scene_path, [f"mesh.nx={nx}", f"method.geometry={geometry}", *quiet])
        out = dict(geometry=geometry, nx=nx, status=row["status"])
        if results is not None:
            errors = {name: np.linalg.norm(np.array(results["probes"][name]) - u) / scale for name, u in exact.items()}
            measure = results["measures"]
            out.update({f"probe_err_{name}": e for name, e in errors.items()},
                       max_probe_err=max(errors.values()),
                       **{f"{measure_name}_rel_err": measure["body2"] / measure["body2_exact"] - 1},
                       newton_iterations=results["newton"]["iterations"], wall_s=row["wall_s"])
        rows.append(out)
    pd.DataFrame(rows).to_csv(RESULTS_DIR / csv, index=False)


def smooth_reference(scene_path, theta, nx, quiet):
    """A held scene, P2 at NX = nx on the curved geometry, saved in runs/reference/."""
    return saved_reference(scene_path, [f"mesh.nx={nx}", f"method.theta={theta}", "method.geometry=curved", *quiet],
                           REPO / "runs" / "reference" / f"{scene_path.stem}_p2_nx{nx}_theta{theta:g}_curved",
                           f"the {scene_path.stem} reference (P2, NX = {nx}, theta = {theta:g})")


def smooth_ladder(scene_path, thetas, ladder, reference_nx, quiet, tool, body2_errors, measure_name, csv,
                  rates_csv):
    """A held scene's ladder for each theta and both geometries against its curved
    reference (quiet: the overrides that turn output files and estimators off; tool: the
    error script; body2_errors(errors.json) -> (L2, H1) of body 2, relative; measure_name:
    area or volume, the column MEASURE_NAME_rel_err), and its rates on the finest
    SMOOTH_RATE_MESHES meshes."""
    rows = []
    grid = [(theta, g, nx) for theta in thetas for g in GEOMETRIES for nx in ladder]
    for n, (theta, geometry, nx) in enumerate(grid, start=1):
        ref = smooth_reference(scene_path, theta, reference_nx, quiet)
        progress(n, len(grid), f"{scene_path.stem}, theta = {theta:g}, NX = {nx}, geometry {geometry}")
        row, results, folder = run_point(scene_path, [f"mesh.nx={nx}", f"method.theta={theta}",
                                                      f"method.geometry={geometry}", "output.save_solution=true",
                                                      *quiet])
        out = dict(theta=theta, geometry=geometry, nx=nx, status=row["status"])
        if results is not None:
            l2, h1 = body2_errors(tool_errors(tool, ref, folder))
            measure = results["measures"]
            out.update(h=results["h"], dofs=results["dofs"], l2_body2=l2, h1_body2=h1,
                       **{f"{measure_name}_rel_err": measure["body2"] / measure["body2_exact"] - 1},
                       stabilization=results["cut"]["stabilization"], dropped=results["cut"]["dropped_body2"],
                       newton_iterations=results["newton"]["iterations"], wall_s=row["wall_s"],
                       peak_rss_mb=results.get("peak_rss_mb"))
        rows.append(out)
    table = pd.DataFrame(rows)
    table.to_csv(RESULTS_DIR / csv, index=False)
    rates = []
    for (theta, geometry), group in table[table.status == "converged"].groupby(["theta", "geometry"], sort=False):
        finest = group.sort_values("h").iloc[:SMOOTH_RATE_MESHES]
        rates.append(dict(theta=theta, geometry=geometry, nx_used=" ".join(str(int(v)) for v in sorted(finest.nx)),
                          l2_rate=loglog_slope(finest.h, finest.l2_body2),
                          h1_rate=loglog_slope(finest.h, finest.h1_body2)))
    pd.DataFrame(rates).to_csv(RESULTS_DIR / rates_csv, index=False)
    return table


def smooth_problems():
    """2D: the patch test (clamped disk: probes against the exact quadratic, NX = 10..80)
    and the held ring's ladder NX = 10..160 against its curved NX = 320 reference for
    every theta, both geometries: results/curved_patch.csv, results/curved_smooth.csv,
    results/curved_smooth_rates.csv, plots/curved_smooth.png."""
    patch_test(CLAMPED_DISK, PATCH_LADDER, "curved_patch.csv", "area", QUIET)
    table = smooth_ladder(HELD_RING, SMOOTH_THETAS, SMOOTH_LADDER, SMOOTH_REFERENCE_NX,
                          [*QUIET, "output.estimators=false"], "fd_error_2d.edp",
                          lambda e: (e["l2_body2"], e["h1_body2"]), "area", "curved_smooth.csv",
                          "curved_smooth_rates.csv")
    plot_smooth(table, "held ring", "curved_smooth.png", "curved-smooth")
    print(f"wrote {RESULTS_DIR / 'curved_patch.csv'}, {RESULTS_DIR / 'curved_smooth.csv'}, "
          f"{RESULTS_DIR / 'curved_smooth_rates.csv'}")


def smooth_problems_3d():
    """3D, P2, theta = -1: the patch test (clamped ball, nx = 6, 8, 12) and the held
    shell's ladder nx = 8, 12, 16 against its curved nx = 32 reference, both geometries:
    results/curved_patch_3d.csv, results/curved_smooth_3d.csv,
    results/curved_smooth_3d_rates.csv, plots/curved_smooth_3d.png."""
    patch_test(CLAMPED_BALL, PATCH_LADDER_3D, "curved_patch_3d.csv", "volume", QUIET_3D)
    table = smooth_ladder(HELD_SHELL, (-1.0,), SMOOTH_LADDER_3D, SMOOTH_REFERENCE_NX_3D, QUIET_3D, "fd_error_3d.edp",
                          lambda e: (e["body2"]["l2_rel"], e["body2"]["h1_rel"]), "volume", "curved_smooth_3d.csv",
                          "curved_smooth_3d_rates.csv")
    plot_smooth(table, "held shell", "curved_smooth_3d.png", "fd3d-curved-smooth")
    print(f"wrote {RESULTS_DIR / 'curved_patch_3d.csv'}, {RESULTS_DIR / 'curved_smooth_3d.csv'}, "
          f"{RESULTS_DIR / 'curved_smooth_3d_rates.csv'}")


def plot_smooth(table, what, name, study):
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
        ax.set_title(f"{what}, P2: relative {norm.upper()} error")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(f"python -m driver study {study}", fontsize=9)
    save_figure(fig, name)
