"""What every study shares: where tables and figures go, cached references, log-log
slopes and Markdown tables (one run as a table row: driver.sweep.run_point)."""

import sys
from pathlib import Path

import numpy as np

from driver.progress import run_started, write
from driver.runner import REPO, run_freefem_tool, run_scene
from driver.scene import load_scene

RESULTS_DIR = REPO / "results"
PLOTS_DIR = REPO / "plots"


def tool_errors(tool, ref, run_folder):
    """Errors of a run against a saved reference by a freefem/tools/ script (errors.json)."""
    return run_freefem_tool(tool, ["-ref", str(ref), "-run", str(run_folder), "-out", str(run_folder / "errors.json")],
                            run_folder / "errors.json", f"error computation for {Path(run_folder).name}")


def progress(i, n, text):
    """Run i of a loop of n starts: shown by the study's bar on a terminal, else one line."""
    if not run_started(f"[{i}/{n}] {text}"):
        print(f"[{i}/{n}] {text}", file=sys.stderr, flush=True)


def markdown_table(frame, digits=4):
    """A Markdown pipe table for the docs (numbers to `digits` significant figures)."""
    def cell(value):
        if isinstance(value, float):
            return "" if value != value else f"{value:.{digits}g}"
        return str(value)

    lines = ["| " + " | ".join(frame.columns) + " |", "|" + "---|" * len(frame.columns)]
    lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in frame.itertuples(index=False)]
    return "\n".join(lines)


def cached_reference(folder, what, compute):
    """A reference run kept in runs/reference/: computed once. Its results.json is
    written last and atomically, so its presence means the run is complete."""
    if not (folder / "results.json").is_file():
        write(f"computing {what} in {folder}")
        compute()
    return folder


def saved_reference(case, overrides, folder, what):
    """The run of `case` with `overrides` and its solution saved, in folder (a cached
    reference: computed once)."""
    def compute():
        scene, module = load_scene(case, [*overrides, "output.save_solution=true"])
        run_scene(scene, module, out_dir=folder, replace=True)

    return cached_reference(folder, what, compute)


def save_figure(fig, name, dpi=110, tight=True):
    """Write a study's figure to plots/NAME (the folder made if needed), close it, say so."""
    import matplotlib.pyplot as plt

    if tight:
        fig.tight_layout()
    PLOTS_DIR.mkdir(exist_ok=True)
    path = PLOTS_DIR / name
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    print(f"wrote {path}")
    return path


def loglog_slope(x, y):
    x, y = np.log(np.asarray(x, float)), np.log(np.asarray(y, float))
    return float(np.polyfit(x, y, 1)[0])


def hertz_radius_and_modulus(r1, r2, e, nu):
    """Hertz's relative radius 1/R = 1/R1 + 1/R2 and contact modulus E* = E / (2 (1 - nu^2))
    of two bodies of the same material."""
    return 1 / (1 / r1 + 1 / r2), e / (2 * (1 - nu ** 2))


def weighted_relative_l2(weight, value, exact):
    """sqrt(sum w (value - exact)^2 / sum w exact^2): a pressure against a closed form at
    quadrature points."""
    weight, value, exact = (np.asarray(v, float) for v in (weight, value, exact))
    return float(np.sqrt(np.sum(weight * (value - exact) ** 2) / np.sum(weight * exact ** 2)))


# The 3D timing studies run the P1 cut geometry: the versions they are timed against
# default to it, and their tables compare the solvers, not the cut geometries.
P1_GEOMETRY_FLAGS = ["-geometry", "p1"]
