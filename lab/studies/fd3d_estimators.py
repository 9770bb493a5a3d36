"""Study of the 3D residual estimator under uniform and tetgen-adaptive refinement
(ball on slab, P1): eta against DOFs, uniform nx ladder vs an adaptive loop from
the coarsest nx (freefem/lib/fd3d/adapt.idp). This module only runs,
tabulates and plots.
"""

import os

import pandas as pd

from driver.runner import REPO
from driver.sweep import run_point
from .common import loglog_slope, markdown_table, progress, RESULTS_DIR, save_figure

BALL = REPO / "cases" / "ball_on_slab.toml"
# Measured on the P1 cut geometry (results/fd3d_adaptive.csv), which the study pins.
QUIET = ["output.vtu=false", "output.csv=false", "method.geometry=p1"]
UNIFORM_NX = tuple(int(v) for v in os.environ.get("FD3D_EST_UNIFORM_NX", "6,8,10,12,14,16").split(","))
ADAPT_STEPS = int(os.environ.get("FD3D_EST_ADAPT_STEPS", "5"))
COMPONENTS = ("eta", "eta1", "eta2", "eta3", "eta4", "eta5")


def adaptive_study():
    """results/fd3d_adaptive.csv and plots/fd3d_adaptive.png: eta vs DOFs, uniform P1
    nx ladder and the adaptive P1 loop from nx = UNIFORM_NX[0] (growth 2 per step)."""
    rows = []
    n = len(UNIFORM_NX) + 1
    for i, nx in enumerate(UNIFORM_NX, 1):
        progress(i, n, f"uniform P1 nx = {nx}")
        row, results, _ = run_point(BALL, [f"mesh.nx={nx}", *QUIET])
        if results is None:
            print(f"uniform nx = {nx}: {row['message']}")
            continue
        est = results["estimator"]
        rows.append(dict(refinement="uniform", nx=nx, step=0, dofs=results["dofs"], elements=results["elements"],
                         **{k: est[k] for k in COMPONENTS}, volume_ball=results["measures"]["body1"],
                         newton=results["newton"]["iterations"], cpu_s=results["steps"]["cpu_s"][0]))
    progress(n, n, f"adaptive P1 from nx = {UNIFORM_NX[0]}, {ADAPT_STEPS} steps")
    row, results, _ = run_point(BALL, [f"mesh.nx={UNIFORM_NX[0]}", f"adapt.steps={ADAPT_STEPS}", *QUIET])
    if results is None:
        raise RuntimeError(f"adaptive run failed: {row['message']}")
    steps = results["steps"]
    for s in range(len(steps["dofs"])):
        rows.append(dict(refinement="adaptive", nx=UNIFORM_NX[0], step=s, dofs=steps["dofs"][s],
                         elements=steps["elements"][s], **{k: steps[k][s] for k in COMPONENTS},
                         volume_ball=steps["measure_body1"][s], newton=steps["newton_iterations"][s],
                         cpu_s=steps["cpu_s"][s]))
    table = pd.DataFrame(rows)
    RESULTS_DIR.mkdir(exist_ok=True)
    table.to_csv(RESULTS_DIR / "fd3d_adaptive.csv", index=False)
    slopes = {}
    for kind, part in table.groupby("refinement"):
        slopes[kind] = loglog_slope(part["dofs"], part["eta"])
    plot(table, slopes)
    print(markdown_table(table[["refinement", "nx", "step", "dofs", "eta", "eta1", "eta2", "eta3", "eta4"]]))
    for kind, slope in slopes.items():
        print(f"{kind}: eta ~ DOFs^{slope:.3f}")
    met = slopes["adaptive"] < slopes["uniform"]
    print(f"bar 'adaptive lowers eta per DOF faster than uniform': {'met' if met else 'NOT met'}")
    return table


def plot(table, slopes):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4.5))
    for kind, marker in (("uniform", "o-"), ("adaptive", "s-")):
        part = table[table["refinement"] == kind]
        ax.loglog(part["dofs"], part["eta"], marker, label=f"{kind} (slope {slopes[kind]:.2f})")
    ax.set_xlabel("DOFs")
    ax.set_ylabel("eta")
    ax.set_title("Ball on slab, P1: eta, uniform vs tetgen-adaptive", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    save_figure(fig, "fd3d_adaptive.png", dpi=120)

