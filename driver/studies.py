"""Studies: many runs of one scene, one table row per run, tables and plots.

A failed run (Newton, FreeFEM) is a row with its status and message, never
dropped: tables show what did not converge.
"""

import sys
from pathlib import Path

import pandas as pd

from driver.errors import DriverError, SceneError
from driver.runner import REPO, run_scene
from driver.scene import load_scene

RESULTS_DIR = REPO / "results"
PLOTS_DIR = REPO / "plots"


def run_point(case, overrides, runs_dir=None):
    """Run one scene with overrides; returns (row dict, results or None, run folder or None)."""
    scene, module = load_scene(case, overrides)
    row = {"case": str(case), "overrides": " ".join(overrides)}
    try:
        results, folder, wall = run_scene(scene, module, runs_dir=runs_dir)
    except SceneError:
        raise
    except DriverError as exc:
        row.update(status=type(exc).__name__, message=str(exc).splitlines()[0])
        return row, None, None
    row.update(status="converged", message="", wall_s=wall,
               newton_iterations=results["newton"]["iterations"], dofs=results["dofs"])
    return row, results, folder


def progress(i, n, text):
    print(f"[{i}/{n}] {text}", file=sys.stderr, flush=True)


def foundation_newton_table():
    """Newton iterations on the square scene at h = 1/32 for theta x degree (README table)."""
    case = REPO / "cases" / "square_slip_separation.toml"
    grid = [(theta, degree, gamma0) for gamma0 in (None, 2e-7)
            for theta in (1, 0, -1) for degree in (1, 2)]
    rows = []
    for i, (theta, degree, gamma0) in enumerate(grid, 1):
        overrides = [f"method.theta={theta}", f"method.degree={degree}", "mesh.nx=32",
                     "output.vtu=false"]
        if gamma0 is not None:
            overrides.append(f"method.gamma0={gamma0}")
        progress(i, len(grid), " ".join(overrides))
        row, results, _ = run_point(case, overrides)
        row.update(theta=theta, degree=degree, gamma0=gamma0 if gamma0 else 1e-6)
        if results is not None:
            box = results["contact"]["active_box"]
            row.update(active_length=results["contact"]["active_length"],
                       contact_xmin=box[0], contact_xmax=box[2])
        rows.append(row)
    table = pd.DataFrame(rows)
    RESULTS_DIR.mkdir(exist_ok=True)
    path = RESULTS_DIR / "foundation_newton.csv"
    table.drop(columns=["case"]).to_csv(path, index=False)
    print(f"wrote {path}")
    print(markdown_table(table[["theta", "degree", "gamma0", "status", "newton_iterations",
                                "active_length", "contact_xmin", "contact_xmax"]]))
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
    ax.plot(samples["x"], -samples["pressure"], "-", color="C3", label="contact pressure  -sigma_n")
    ax.set_xlabel("x on the contact boundary y = 0")
    ax.set_ylabel("pressure")
    ax2 = ax.twinx()
    ax2.plot(samples["x"], samples["open_gap"], "--", color="C0", label="open gap  g - [[u.n]]")
    ax2.set_ylabel("open gap")
    lines = ax.get_lines() + ax2.get_lines()
    ax.legend(lines, [line.get_label() for line in lines], loc="upper right")
    ax.set_title("square with slip and separation, P2, h = 1/32, theta = -1")
    fig.tight_layout()
    PLOTS_DIR.mkdir(exist_ok=True)
    path = PLOTS_DIR / "square_contact_pressure.png"
    fig.savefig(path, dpi=120)
    print(f"wrote {path}")


def markdown_table(frame, digits=4):
    """A pipe table for the README (numbers to `digits` significant figures)."""
    def cell(value):
        if isinstance(value, float):
            return "" if value != value else f"{value:.{digits}g}"
        return str(value)

    lines = ["| " + " | ".join(frame.columns) + " |", "|" + "---|" * len(frame.columns)]
    lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in frame.itertuples(index=False)]
    return "\n".join(lines)


STUDIES = {
    "foundation-newton": foundation_newton_table,
    "square-pressure": square_pressure_plot,
}
