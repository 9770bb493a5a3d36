"""The rigid-foundation studies: Newton on the square, its contact pressure, and the
residual estimators on uniform and adaptive meshes (docs/foundation.md, docs/estimators.md).

A failed run (Newton, FreeFEM) is a row with its status and message, never
dropped: tables show what did not converge.
"""

from pathlib import Path

import pandas as pd

from driver.errors import DriverError
from driver.runner import REPO, run_scene
from driver.scene import load_scene
from driver.sweep import run_point
from .common import cached_reference, loglog_slope, markdown_table, progress, RESULTS_DIR, save_figure


def foundation_newton_table():
    """Newton iterations on the square scene at h = 1/32 for theta x degree (docs/foundation.md)."""
    case = REPO / "cases" / "square_slip_separation.toml"
    grid = [(theta, degree, gamma0) for gamma0 in (None, 0.2)
            for theta in (1, 0, -1) for degree in (1, 2)]
    rows = []
    for i, (theta, degree, gamma0) in enumerate(grid, 1):
        overrides = [f"method.theta={theta}", f"method.degree={degree}", "mesh.nx=32",
                     "output.vtu=false"]
        if gamma0 is not None:
            overrides.append(f"method.gamma0={gamma0}")
        progress(i, len(grid), " ".join(overrides))
        row, results, _ = run_point(case, overrides)
        row.update(theta=theta, degree=degree, gamma0=gamma0 if gamma0 else 1.0)
        if results is not None:
            box = results["contact"]["active_box"]
            row.update(active_length=results["contact"]["active_measure"],
                       contact_xmin=box[0], contact_xmax=box[2])
        rows.append(row)
    table = pd.DataFrame(rows)
    RESULTS_DIR.mkdir(exist_ok=True)
    path = RESULTS_DIR / "foundation_newton.csv"
    table.drop(columns=["case"]).to_csv(path, index=False)
    print(f"wrote {path}")
    print(markdown_table(table[["theta", "degree", "gamma0", "status", "newton_iterations",
                                "active_measure", "contact_xmin", "contact_xmax"]]))
    return table


def square_pressure_plot():
    """Contact pressure and open gap along the bottom of the square scene (P2, h = 1/32)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    case = REPO / "cases" / "square_slip_separation.toml"
    _, results, folder = run_point(case, [])
    if results is None:
        raise DriverError("the square scene did not run; no plot made")
    samples = pd.read_csv(Path(folder) / "contact_pressure.csv").sort_values("x")
    fig, ax = plt.subplots(figsize=(7, 3.6))
    ax.plot(samples["x"], samples["pressure"], "-", color="C3", label="contact pressure  -sigma_n")
    ax.set_xlabel("x on the contact boundary y = 0")
    ax.set_ylabel("pressure")
    ax2 = ax.twinx()
    ax2.plot(samples["x"], samples["open_gap"], "--", color="C0", label="open gap  g - [[u.n]]")
    ax2.set_ylabel("open gap")
    lines = ax.get_lines() + ax2.get_lines()
    ax.legend(lines, [line.get_label() for line in lines], loc="upper right")
    ax.set_title("square with slip and separation, P2, h = 1/32, theta = -1")
    save_figure(fig, "square_contact_pressure.png", dpi=120)




# ---------------------------------------------------------------------------
# A posteriori estimators on the square (body-fitted), uniform and adaptive.

SQUARE = REPO / "cases" / "square_slip_separation.toml"
SQUARE_REFERENCE = REPO / "runs" / "reference" / "square_p2"
SQUARE_REFERENCE_SETTINGS = ["mesh.nx=16", "adapt.steps=30", "adapt.growth=2.5",
                             "adapt.max_dofs=1500000", "output.save_solution=true",
                             "output.vtu=false", "output.pressure_csv=false"]
UNIFORM_NX = (8, 16, 32, 64, 80)


def square_reference():
    """Adaptive P2, theta = -1, about 1e6 DOFs."""
    def compute():
        scene, module = load_scene(SQUARE, SQUARE_REFERENCE_SETTINGS)
        run_scene(scene, module, out_dir=SQUARE_REFERENCE, replace=True)

    return cached_reference(SQUARE_REFERENCE, "the square reference (adaptive P2, ~1e6 DOFs)", compute)


def estimator_rows(results, **labels):
    """One row per solve of a run (several with adaptation) with errors and estimators."""
    steps, ref, E = results["steps"], results["reference"], results["E"]
    rows = []
    for i in range(len(steps["dofs"])):
        h1 = steps["h1_error"][i]
        rows.append(dict(labels, step=i, dofs=int(steps["dofs"][i]), elements=int(steps["elements"][i]),
                         l2_error=steps["l2_error"][i], h1_error=h1,
                         l2_rel=steps["l2_error"][i] / ref["l2_norm"], h1_rel=h1 / ref["h1_norm"],
                         eta=steps["eta"][i], eta1=steps["eta1"][i], eta2=steps["eta2"][i],
                         eta3=steps["eta3"][i], eta4=steps["eta4"][i], zeta=steps["zeta"][i],
                         efficiency=steps["eta"][i] / (E * h1),
                         newton_iterations=int(steps["newton_iterations"][i]),
                         cpu_s=steps["cpu_s"][i]))
    return rows


def aposteriori_uniform():
    """The slides' table on the square: uniform h = 1/8 ... 1/80, P2, theta = -1, 0, 1."""
    reference = square_reference()
    variants = [(-1, None), (0, None), (1, None), (1, 1e-7)]   # gamma0 = 1/E unless given
    rows, n = [], len(variants) * len(UNIFORM_NX)
    for theta, gamma0 in variants:
        for nx in UNIFORM_NX:
            overrides = [f"method.theta={theta}", f"mesh.nx={nx}", f"reference.folder='{reference}'",
                         "output.vtu=false"]
            if gamma0:
                overrides.append(f"method.gamma0={gamma0}")
            progress(len(rows) + 1, n, " ".join(overrides[:2] + overrides[4:]))
            row, results, _ = run_point(SQUARE, overrides)
            labels = dict(theta=theta, gamma0=gamma0 or 1e-6, nx=nx, h=1.0 / nx)
            if results is None:
                rows.append(dict(labels, status=row["status"], message=row["message"]))
                continue
            rows += [dict(r, status="converged", wall_s=row["wall_s"])
                     for r in estimator_rows(results, **labels)]
    table = pd.DataFrame(rows)
    RESULTS_DIR.mkdir(exist_ok=True)
    table.to_csv(RESULTS_DIR / "aposteriori_uniform.csv", index=False)
    slopes = uniform_slopes(table)
    slopes.to_csv(RESULTS_DIR / "aposteriori_uniform_slopes.csv", index=False)
    print(markdown_table(table[["theta", "gamma0", "nx", "dofs", "l2_error", "h1_error", "eta1",
                                "eta2", "eta3", "eta4", "eta", "efficiency", "status"]]))
    print(markdown_table(slopes, digits=3))
    plot_aposteriori_uniform(table)
    return table


def uniform_slopes(table):
    """Least-squares slopes in h over each uniform ladder, and the efficiency range."""
    slopes = []
    for (theta, gamma0), group in table[table.status == "converged"].groupby(["theta", "gamma0"]):
        if len(group) < 2:
            continue
        slope = {k: loglog_slope(group.h, group[k])
                 for k in ("l2_error", "h1_error", "eta1", "eta2", "eta3", "eta4", "eta")}
        slopes.append(dict(theta=theta, gamma0=gamma0, runs=len(group), **slope,
                           efficiency_min=group.efficiency.min(), efficiency_max=group.efficiency.max(),
                           efficiency_mean=group.efficiency.mean()))
    return pd.DataFrame(slopes)


def plot_aposteriori_uniform(table):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = table[table.status == "converged"]
    fig, axes = plt.subplots(1, 3, figsize=(13, 4.2), sharex=True)
    for ax, (key, label) in zip(axes, [("eta", "estimator eta"), ("h1_error", "H1 error"),
                                       ("l2_error", "L2 error")]):
        for (theta, gamma0), group in ok.groupby(["theta", "gamma0"]):
            slope = -2 * loglog_slope(group.dofs, group[key])
            ax.loglog(group.dofs, group[key], "o-",
                      label=f"theta={theta:g}, gamma0={gamma0:g}: slope {slope:.2f} (h)")
        ax.set_title(label)
        ax.set_xlabel("DOFs")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle("square with slip and separation, uniform P2 meshes h = 1/8 ... 1/80 "
                 "(make aposteriori-study)")
    save_figure(fig, "aposteriori_convergence.png")


def aposteriori_adaptive():
    """Adaptive P2 loop on the square against the uniform ladder (theta = -1)."""
    import numpy as np

    reference = square_reference()
    uniform_path = RESULTS_DIR / "aposteriori_uniform.csv"
    if not uniform_path.is_file():
        raise DriverError(f"{uniform_path} is missing: run the uniform study first (make aposteriori-study)")
    uniform = pd.read_csv(uniform_path)
    uniform = uniform[(uniform.status == "converged") & (uniform.theta == -1)].sort_values("dofs")
    overrides = ["mesh.nx=8", "adapt.steps=14", "adapt.growth=2.0", "adapt.max_dofs=120000",
                 f"reference.folder='{reference}'"]
    progress(1, 1, " ".join(overrides))
    row, results, folder = run_point(SQUARE, overrides)
    if results is None:
        raise DriverError(f"adaptive run failed: {row['message']}")
    table = pd.DataFrame(estimator_rows(results, theta=-1, gamma0=1e-6))
    table.to_csv(RESULTS_DIR / "aposteriori_adaptive.csv", index=False)
    finest = uniform.iloc[-1]
    reached = table[table.h1_error <= finest.h1_error]
    half = table.iloc[len(table) // 2:]
    summary = dict(
        uniform_h_1_80_dofs=int(finest.dofs), uniform_h_1_80_h1_error=finest.h1_error,
        adaptive_dofs_reaching_it=int(reached.dofs.iloc[0]) if len(reached) else None,
        adaptive_h1_slope_vs_dofs=loglog_slope(half.dofs, half.h1_error),
        adaptive_eta_slope_vs_dofs=loglog_slope(half.dofs, half.eta),
        efficiency_mean=table.efficiency.mean(), efficiency_min=table.efficiency.min(),
        efficiency_max=table.efficiency.max())
    pd.DataFrame([summary]).to_csv(RESULTS_DIR / "aposteriori_adaptive_summary.csv", index=False)
    print(markdown_table(table[["step", "dofs", "h1_error", "l2_error", "eta", "efficiency",
                                "newton_iterations"]]))
    print(markdown_table(pd.DataFrame([summary]), digits=3))

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    E = results["E"]
    for data, name, style in ((uniform, "uniform", "s--"), (table, "adaptive", "o-")):
        ax.loglog(data.dofs, data.eta / E, style, label=f"eta / E, {name}")
        ax.loglog(data.dofs, data.h1_error, style, label=f"H1 error, {name}")
    ref_n = np.array([table.dofs.min(), table.dofs.max()], float)
    ax.loglog(ref_n, table.h1_error.iloc[0] * (ref_n / ref_n[0]) ** -1.0, "k:", label="DOFs^-1")
    ax.set_xlabel("DOFs")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("P2, theta = -1: estimator and true error")
    ax2.semilogx(table.dofs, table.efficiency, "o-", label="adaptive")
    ax2.semilogx(uniform.dofs, uniform.efficiency, "s--", label="uniform")
    ax2.axhline(table.efficiency.mean(), color="gray", lw=0.8)
    ax2.set_ylim(0, 2.2 * max(table.efficiency.max(), uniform.efficiency.max()))
    ax2.set_xlabel("DOFs")
    ax2.set_title("efficiency index eta / (E |u - u_h|_1)")
    ax2.legend()
    ax2.grid(True, which="both", alpha=0.3)
    fig.suptitle("square with slip and separation: adaptive vs uniform (make aposteriori-study)")
    save_figure(fig, "aposteriori_adaptive.png")
    return table


def square_adapted_vonmises():
    """The slides' figure: adapted mesh and von Mises stress side by side."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.tri as mtri
    import meshio

    overrides = ["mesh.nx=8", "adapt.steps=7", "adapt.growth=2.0"]
    progress(1, 1, " ".join(overrides))
    row, results, folder = run_point(SQUARE, overrides)
    if results is None:
        raise DriverError(f"adaptive run failed: {row['message']}")
    vtu = meshio.read(Path(folder) / "fields.vtu")
    tri = mtri.Triangulation(vtu.points[:, 0], vtu.points[:, 1], vtu.cells_dict["triangle"])
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(11, 5))
    ax.triplot(tri, lw=0.3, color="k")
    samples = pd.read_csv(Path(folder) / "contact_pressure.csv")
    active = samples[samples.active == 1]
    ax.plot(active.x, active.y, "r.", ms=3, label="active contact")
    ax.set_title(f"adapted mesh ({results['elements']} triangles, {results['dofs']} DOFs)")
    ax.set_aspect("equal")
    ax.legend(loc="upper right", fontsize=8)
    shade = ax2.tripcolor(tri, vtu.point_data["von_mises"].ravel(), shading="gouraud", cmap="viridis")
    fig.colorbar(shade, ax=ax2, label="von Mises stress")
    ax2.set_aspect("equal")
    ax2.set_title("von Mises stress (P2, theta = -1, gamma0 = 1/E)")
    fig.suptitle("square with slip and separation after 7 adaptation steps (make aposteriori-study)")
    save_figure(fig, "square_adapted_vonmises.png")


