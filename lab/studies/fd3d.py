"""Studies of the 3D fictitious-domain contact (ball on slab): convergence against a
P2 reference graded toward the contact point, cost (wall time, peak memory) against
DOFs, the centre-cut figure.

Errors come from freefem/tools/fd_error_3d.edp (reference cut integration; the uniform
ladder meshes are not nested in the graded reference, so the coarse fields are
evaluated at the reference quadrature points). This module only runs, tabulates
and plots.
"""

import os

import numpy as np
import pandas as pd

from driver.errors import DriverError, SceneError
from driver.runner import REPO, parse_json_file, run_scene
from driver.scene import load_scene
from .common import (cached_reference, loglog_slope, markdown_table, progress, RESULTS_DIR, save_figure,
                     tool_errors)
from .fd2d import rates_of

BALL = REPO / "cases" / "ball_on_slab.toml"
# The reference: P2, theta = -1, on cube(nx) refined by tetgen toward the contact
# point (edge about grade_h within grade_radius of it, growing by grade_slope per
# unit distance beyond; freefem/lib/fd3d/grading.idp). The solution is smooth except near the
# contact zone (radius about 0.1), which a uniform P2 mesh that fits in memory
# (h = 1/30, 248k DOFs, 9.8 GiB) resolves with only about 3 cells per radius.
REFERENCE_NX = int(os.environ.get("FD3D_REFERENCE_NX", "15"))
REFERENCE_GRADE_H = float(os.environ.get("FD3D_REFERENCE_GRADE_H", str(1 / 60)))
REFERENCE_GRADE_RADIUS = float(os.environ.get("FD3D_REFERENCE_GRADE_RADIUS", "0.16"))
REFERENCE_GRADE_SLOPE = float(os.environ.get("FD3D_REFERENCE_GRADE_SLOPE", "0.4"))


# The ladders keep one cut configuration: nx a multiple of 4 puts the slab top
# z = -0.25 on a grid plane and the first contact point (0, 0, -0.25) on a mesh
# vertex for every h. Meshes with other nx cut the contact zone differently, and
# their errors scatter about the ladder's trend by several per cent (P2 ball:
# 0.150 at nx = 15, 0.193 at nx = 20), which makes rates from mixed
# configurations meaningless over a factor 2 in h; those points (OFFSET_NX) are
# computed and tabulated but left out of the rates. P2 has ~7x the DOFs of P1 at
# the same nx; P1 goes to h = 1/48 (its contact zone, radius ~0.1, needs h well
# below 1/10 before the rates show).
def ladder(env, default):
    text = os.environ.get(env)
    return tuple(int(v) for v in text.split(",")) if text else default


P1_LADDER = ladder("FD3D_P1_LADDER", (8, 12, 16, 20, 24, 32, 40, 48))
P2_LADDER = ladder("FD3D_P2_LADDER", (8, 12, 16, 20))
# The curved-geometry study (method.geometry = "curved", fd3d/curved.idp): P2,
# theta = -1, the aligned nx only, against the same graded reference solved on the
# curved geometry; up to nx = 28 (about 200k DOFs): the rates take the three finest,
# past the coarse meshes whose cut of the contact zone tilts the ball
# (docs/curved-geometry.md).
CURVED_LADDER = ladder("FD3D_CURVED_LADDER", (8, 12, 16, 20, 24, 28))
OFFSET_NX = ladder("FD3D_OFFSET_NX", (6, 10, 15, 30))   # P1 and P2 (up to nx 15), other cuts


def aligned(nx):
    return nx % 4 == 0


THETAS = (1, 0, -1)
QUIET = ["output.vtu=false", "output.csv=false", "output.estimators=false"]
# Large P2 systems: GMRES on the last factorization for up to this many changed points.
REFERENCE_SETTINGS = ["method.degree=2", "method.theta=-1", "output.vtu=false", "output.save_solution=true",
                      "output.estimators=false", "solver.refactor_points=300"]


def reference_label(geometry="p1"):
    label = f"P2 nx = {REFERENCE_NX}"
    if REFERENCE_GRADE_H > 0:
        label += (f" graded to h = 1/{1 / REFERENCE_GRADE_H:.0f} within "
                  f"{REFERENCE_GRADE_RADIUS:g} of the contact point (slope {REFERENCE_GRADE_SLOPE:g})")
    return label + (", curved geometry" if geometry == "curved" else "")


def reference_settings(geometry="p1"):
    """The reference's scene settings (see REFERENCE_*), on the cut geometry `geometry`."""
    settings = [f"mesh.nx={REFERENCE_NX}", *REFERENCE_SETTINGS, f"method.geometry={geometry}"]
    if REFERENCE_GRADE_H > 0:
        settings += [f"mesh.grade_h={REFERENCE_GRADE_H!r}", f"mesh.grade_radius={REFERENCE_GRADE_RADIUS!r}",
                     f"mesh.grade_slope={REFERENCE_GRADE_SLOPE!r}"]
    return settings


def reference(geometry="p1"):
    """The P2 reference (see REFERENCE_*) on the cut geometry `geometry` (the P1 one
    keeps its folder name); the centre cut CSV is kept for the figure."""
    name = f"ball_on_slab_p2_nx{REFERENCE_NX}"
    settings = reference_settings(geometry)
    if REFERENCE_GRADE_H > 0:
        name += f"_grade{1 / REFERENCE_GRADE_H:.0f}_r{REFERENCE_GRADE_RADIUS:g}_s{REFERENCE_GRADE_SLOPE:g}"
    folder = REPO / "runs" / "reference" / (name + geometry_suffix(geometry))

    def compute():
        scene, module = load_scene(BALL, settings)
        run_scene(scene, module, out_dir=folder, replace=True)

    return cached_reference(folder, f"the ball-on-slab reference ({reference_label(geometry)})", compute)


def geometry_suffix(geometry):
    """Folder names: the P1 geometry keeps the names it had before the curved one existed."""
    return "" if geometry == "p1" else f"_{geometry}"


def errors_against(ref, run_folder):
    return tool_errors("fd_error_3d.edp", ref, run_folder)


def cost_columns(results):
    t = results.get("timings_cpu_s", {})
    return dict(wall_s=results.get("wall_s"), peak_rss_mb=results.get("peak_rss_mb"),
                cpu_geometry_s=t.get("geometry"), cpu_assembly_s=t.get("assembly"),
                cpu_newton_s=t.get("newton"), cpu_newton_factor_solve_s=t.get("newton_factor_solve"),
                cpu_newton_contact_s=t.get("newton_contact_assembly"), cpu_output_s=t.get("output"))


def study_folder(degree, theta, nx, geometry="p1"):
    return REPO / "runs" / "fd3d_study" / f"p{degree}_theta{theta:g}_nx{nx}{geometry_suffix(geometry)}"


def solve(degree, theta, nx, geometry="p1"):
    """One saved run of the ladder in runs/fd3d_study/ (kept: 3D runs are expensive;
    delete the folder to recompute it). None if it ran, else a failed-run row."""
    folder = study_folder(degree, theta, nx, geometry)
    if (folder / "results.json").is_file():
        return None
    overrides = [f"method.degree={degree}", f"method.theta={theta}", f"mesh.nx={nx}",
                 f"method.geometry={geometry}", "output.save_solution=true", *QUIET]
    scene, module = load_scene(BALL, overrides)
    try:
        run_scene(scene, module, out_dir=folder, replace=True)
    except SceneError:
        raise
    except DriverError as exc:
        return dict(degree=degree, theta=theta, nx=nx, status=type(exc).__name__,
                    message=str(exc).splitlines()[0])
    return None


def run_with_errors(ref, degree, theta, nx, geometry="p1"):
    """One saved run and its errors against the reference (errors.json kept with the
    run while it names this reference): a table row."""
    labels = dict(degree=degree, theta=theta)
    folder = study_folder(degree, theta, nx, geometry)
    failed = solve(degree, theta, nx, geometry)
    if failed:
        return failed
    err = None
    if (folder / "errors.json").is_file():
        err = parse_json_file(folder / "errors.json")
        if err.get("reference") != str(ref):
            err = None
    if err is None:
        err = errors_against(ref, folder)
    results = parse_json_file(folder / "results.json")
    out = dict(labels, status="converged", message="")
    out.update(nx=results["nx"], h=results["h"], dofs_body1=results["dofs_body1"],
               dofs_body2=results["dofs_body2"], dofs=results["dofs"],
               l2_body1=err["body1"]["l2_rel"], l2_body2=err["body2"]["l2_rel"],
               h1_body1=err["body1"]["h1_rel"], h1_body2=err["body2"]["h1_rel"],
               nodes_by_extension=err["body1"]["nodes_read_by_extension"] + err["body2"]["nodes_read_by_extension"],
               nested=err["nested"],
               elements_extended=err["body1"]["elements_extended"] + err["body2"]["elements_extended"],
               newton_iterations=results["newton"]["iterations"],
               factorizations=results["newton"]["factorizations"],
               force_balance_error=results["contact"]["force_balance_error"],
               centre_uz=results["probes"]["centre"][2],
               error_cpu_s=err["cpu_s"], **cost_columns(results))
    return out


def reference_row(ref):
    results = parse_json_file(ref / "results.json")
    return dict(degree=2, theta=-1, status="reference", message="", nx=results["nx"], h=results["h"],
                dofs_body1=results["dofs_body1"], dofs_body2=results["dofs_body2"], dofs=results["dofs"],
                newton_iterations=results["newton"]["iterations"],
                factorizations=results["newton"]["factorizations"],
                force_balance_error=results["contact"]["force_balance_error"],
                centre_uz=results["probes"]["centre"][2], **cost_columns(results))


def cost_exponents(table):
    """Least-squares exponents of wall time and peak memory in the DOFs, per degree
    (converged runs and the reference; peak RSS includes FreeFEM's ~70 MB start)."""
    rows = []
    for degree, group in table[table.status.isin(["converged", "reference"])].groupby("degree"):
        group = group.sort_values("dofs")
        big = group[group.dofs >= group.dofs.max() / 30]        # the larger runs: start-up costs fade
        for what in ("wall_s", "cpu_newton_factor_solve_s", "peak_rss_mb"):
            use = big if len(big) >= 3 else group
            rows.append(dict(degree=degree, quantity=what, exponent=loglog_slope(use.dofs, use[what]),
                             runs=len(use), dofs_used=f"{int(use.dofs.min())} .. {int(use.dofs.max())}"))
    return pd.DataFrame(rows)


def convergence():
    ref = reference()
    offset_p2 = tuple(n for n in OFFSET_NX if n <= max(P2_LADDER))
    grid = [(d, t, nx) for d, ladder_d in ((1, P1_LADDER + OFFSET_NX), (2, P2_LADDER + offset_p2))
            for t in THETAS for nx in ladder_d]
    rows = []
    for i, (degree, theta, nx) in enumerate(grid, 1):
        progress(i, len(grid), f"P{degree} theta={theta} nx={nx}")
        rows.append(dict(run_with_errors(ref, degree, theta, nx), ladder=aligned(nx)))
    rows.append(dict(reference_row(ref), ladder=False))
    table = pd.DataFrame(rows)
    RESULTS_DIR.mkdir(exist_ok=True)
    table.to_csv(RESULTS_DIR / "fd3d_convergence.csv", index=False)
    rates = rates_of(table[(table.status == "converged") & table.ladder], ["degree", "theta"])
    costs = cost_exponents(table)
    rates.to_csv(RESULTS_DIR / "fd3d_rates.csv", index=False)
    costs.to_csv(RESULTS_DIR / "fd3d_cost.csv", index=False)
    print(markdown_table(rates, digits=3))
    print(markdown_table(costs, digits=3))
    plot_convergence(table, costs)
    check_bars(table, rates)
    return table


def curved_convergence():
    """The P2 ladder (theta = -1, CURVED_LADDER) on the curved cut geometry against the
    graded reference solved on it (fd_error_3d.edp integrates on the reference's curved
    cut cells): results/fd3d_curved_convergence.csv (the columns of
    fd3d_convergence.csv plus geometry, the ball's volume error and its centre u_z
    error against the reference) and results/fd3d_curved_rates.csv (those of
    fd3d_rates.csv plus geometry)."""
    geometry = "curved"
    ref = reference(geometry)
    ref_results = parse_json_file(ref / "results.json")
    centre_ref = ref_results["probes"]["centre"][2]
    ladder_nx = [nx for nx in CURVED_LADDER if aligned(nx)]
    rows = []
    for i, nx in enumerate(ladder_nx, 1):
        progress(i, len(ladder_nx), f"P2 theta=-1 nx={nx}, geometry {geometry}")
        row = dict(run_with_errors(ref, 2, -1, nx, geometry), ladder=True)
        if row["status"] == "converged":
            row.update(ball_geometry(parse_json_file(study_folder(2, -1, nx, geometry) / "results.json")))
        rows.append(row)
    rows.append(dict(reference_row(ref), ladder=False, **ball_geometry(ref_results)))
    table = pd.DataFrame(rows)
    table.insert(0, "geometry", geometry)
    table["centre_uz_rel_err"] = (table.centre_uz - centre_ref).abs() / abs(centre_ref)
    RESULTS_DIR.mkdir(exist_ok=True)
    table.to_csv(RESULTS_DIR / "fd3d_curved_convergence.csv", index=False)
    rates = rates_of(table[(table.status == "converged") & table.ladder], ["geometry", "degree", "theta"])
    rates.to_csv(RESULTS_DIR / "fd3d_curved_rates.csv", index=False)
    print(markdown_table(rates, digits=3))
    failed = table[~table.status.isin(["converged", "reference"])]
    if len(failed):
        print(f"warning: {len(failed)} runs did not converge:\n" + failed[["nx", "message"]].to_string())
    return table


def ball_geometry(results):
    """The discrete ball's volume (the solver's, on its cut geometry) and its relative error."""
    v = results["measures"]
    return dict(volume_body1=v["body1"], volume_rel_err_body1=(v["body1"] - v["body1_exact"]) / v["body1_exact"])


def check_bars(table, rates):
    """Report (never hide) what misses the convergence bars: runs that did not converge
    (kept as rows of the table) and P1 H1 rates below 0.85."""
    failed = table[~table.status.isin(["converged", "reference"])]
    if len(failed):
        print(f"warning: {len(failed)} runs did not converge:\n"
              + failed[["degree", "theta", "nx", "message"]].to_string())
    p1 = rates[(rates.degree == 1) & (rates.norm == "H1")]
    low = p1[p1.rate < 0.85]
    if len(low):
        print("warning: P1 H1 rates below the bar 0.85:\n" + low.to_string())


def plot_convergence(table, costs):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    converged = table[table.status == "converged"]
    ok = converged[converged.ladder]
    offset = converged[~converged.ladder]
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.6))
    markers = {1: "o", 0: "s", -1: "^"}
    for body, ax in zip((1, 2), axes[:2]):
        for (degree, theta), group in ok.groupby(["degree", "theta"]):
            group = group.sort_values("h")
            for norm, style in (("l2", "--"), ("h1", "-")):
                ax.loglog(group.h, group[f"{norm}_body{body}"], style, marker=markers[theta],
                          color="C0" if degree == 1 else "C3", alpha=0.85,
                          label=f"P{degree} th={theta} {norm.upper()}")
        part = offset[offset.theta == -1]
        for degree, group in part.groupby("degree"):
            ax.loglog(group.h, group[f"h1_body{body}"], "x", color="C0" if degree == 1 else "C3",
                      label=f"P{degree} th=-1 H1, nx not a multiple of 4 (not in the rates)")
        hs = np.array([ok.h.min(), ok.h.max()])
        ax.loglog(hs, 0.5 * hs / hs.max() * ok[f"h1_body{body}"].max(), ":", color="gray", label="slope 1")
        ax.loglog(hs, 0.5 * (hs / hs.max()) ** 2 * ok[f"l2_body{body}"].max(), "-.", color="gray",
                  label="slope 2")
        ax.set_xlabel("h")
        ax.set_ylabel("relative error")
        ax.set_title(f"body {body} ({'ball' if body == 1 else 'slab'})")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=6, ncol=2)
    ax = axes[2]
    allruns = table[table.status.isin(["converged", "reference"])]
    for degree, group in allruns.groupby("degree"):
        group = group.drop_duplicates("nx").sort_values("dofs")
        ax.loglog(group.dofs, group.wall_s, "o-", color="C0" if degree == 1 else "C3", label=f"P{degree} wall s")
        ax.loglog(group.dofs, group.peak_rss_mb / 1024, "s--", color="C0" if degree == 1 else "C3",
                  label=f"P{degree} peak RSS GiB")
    for _, c in costs.iterrows():
        if c.quantity in ("wall_s", "peak_rss_mb"):
            ax.plot([], [], " ", label=f"P{int(c.degree)} {c.quantity}: DOFs^{c.exponent:.2f}")
    ax.set_xlabel("DOFs")
    ax.set_title("cost per run (theta = -1 and others)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    fig.suptitle(f"ball on slab 3D, gamma0 = 1/200: errors against {reference_label()} (make fd3d-study)", fontsize=9)
    save_figure(fig, "fd3d_convergence.png", dpi=120)


FIGURE_SETTINGS = ["method.degree=2", "method.theta=-1", "mesh.nx=10", f"mesh.grade_h={1 / 40!r}",
                   "mesh.grade_radius=0.1", "output.vtu=false", "output.estimators=false"]


def figure_run():
    """The run behind the figure: P2 on cube(10) graded to h = 1/40 within 0.1 of the
    contact point (77k DOFs, about 3 min; the centre cut is sampled at 1/120
    whatever the mesh)."""
    folder = REPO / "runs" / "fd3d_figure"

    def compute():
        scene, module = load_scene(BALL, FIGURE_SETTINGS)
        run_scene(scene, module, out_dir=folder, replace=True)

    return cached_reference(folder, "the ball-on-slab figure run (P2, cube(10) graded to h = 1/40)", compute)


def vonmises_figure(folder=None, scale=3.0):
    """plots/ball_on_slab_vonmises.png: the plane y = 0 through the ball's centre,
    deformed (displacement x scale), coloured by von Mises, from centre_cut.csv."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.tri as mtri

    folder = folder or figure_run()
    cut = pd.read_csv(folder / "centre_cut.csv")
    results = parse_json_file(folder / "results.json")
    fig, ax = plt.subplots(figsize=(6.4, 6.4))
    vmax = cut.von_mises.quantile(0.995)
    step = cut.x.diff().abs()[cut.x.diff().abs() > 0].min() if (cut.x.diff().abs() > 0).any() else 0.01
    image = None
    for body in (1, 2):
        part = cut[cut.body == body]
        tri = mtri.Triangulation(part.x, part.z)
        # drop triangles that bridge outside the body (longer than a grid diagonal)
        xs, zs = part.x.to_numpy()[tri.triangles], part.z.to_numpy()[tri.triangles]
        longest = np.max(np.hypot(xs - np.roll(xs, 1, axis=1), zs - np.roll(zs, 1, axis=1)), axis=1)
        tri.set_mask(longest > 3.0 * step)
        deformed = mtri.Triangulation(part.x + scale * part.ux, part.z + scale * part.uz, tri.triangles,
                                      mask=tri.mask)
        image = ax.tripcolor(deformed, part.von_mises, shading="gouraud", cmap="viridis", vmin=0, vmax=vmax)
    theta = np.linspace(0, 2 * np.pi, 200)
    ax.plot(0.25 * np.cos(theta), 0.25 * np.sin(theta), "k:", lw=0.8, zorder=5, label="undeformed")
    ax.axhline(-0.25, color="k", ls=":", lw=0.8, zorder=5)
    ax.set_aspect("equal")
    ax.set_xlim(-0.5, 0.5)
    ax.set_ylim(-0.5, 0.32)
    ax.set_xlabel("x")
    ax.set_ylabel("z")
    fig.colorbar(image, ax=ax, shrink=0.7, label="von Mises stress")
    graded = f", graded to 1/{1 / results['grade_h']:.0f}" if results.get("grade_h") else ""
    ax.set_title(f"ball on slab, plane y = 0, P{results['degree']} nx = {results['nx']}{graded}\n"
                 f"displacement x {scale:g}; centre u_z = {results['probes']['centre'][2]:.4f}")
    save_figure(fig, "ball_on_slab_vonmises.png", dpi=130, tight=False)

