"""Speed against error on the disk on slab (make bench): one row per solve with DOFs,
Newton iterations, wall time and CPU time by phase, peak memory, and the relative H1
error against the P2 NX = 320 reference. Timing lives here, never in tests.
"""

import platform

import numpy as np
import pandas as pd

from driver.errors import DriverError
from driver.fd2d_studies import DISK, QUIET, errors_against, reference
from driver.studies import PLOTS_DIR, RESULTS_DIR, loglog_slope, markdown_table, progress, run_point

PHASES = ("geometry", "assembly", "newton_contact_assembly", "newton_factor_solve", "estimators", "output")
LADDER = (10, 20, 40, 80, 160)


def machine():
    cpu = "unknown cpu"
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    import os

    return f"{cpu}, {os.cpu_count()} cores, {platform.system()} {platform.release()}"


def bench_row(method, results, err, wall, extra=None):
    timings = results.get("timings_cpu_s", {})
    row = dict(method=method, degree=results["degree"], theta=results["theta"], nx=results["nx"],
               dofs=results["dofs"], newton_iterations=results["newton"]["iterations"],
               factorizations=results["newton"].get("factorizations"), wall_s=wall,
               peak_rss_mb=results.get("peak_rss_mb"),
               h1_error=float(np.hypot(err["h1_body1"], err["h1_body2"])),
               **{f"cpu_{p}": timings.get(p, 0.0) for p in PHASES})
    row.update(extra or {})
    return row


def bench():
    ref = reference()
    rows = []
    grid = [(d, -1, nx) for d in (1, 2) for nx in LADDER] + [(2, t, 80) for t in (1, 0)]
    for i, (degree, theta, nx) in enumerate(grid, 1):
        progress(i, len(grid) + 1, f"uniform P{degree} theta={theta} NX={nx}")
        row, results, folder = run_point(DISK, [f"mesh.nx={nx}", f"method.degree={degree}",
                                                f"method.theta={theta}", "output.save_solution=true", *QUIET])
        if results is None:
            raise DriverError(f"bench run failed: {row['message']}")
        rows.append(bench_row(f"uniform P{degree}", results, errors_against(ref, folder), row["wall_s"]))
    progress(len(grid) + 1, len(grid) + 1, "adaptive P2 (ghost) from NX=20")
    row, results, folder = run_point(DISK, ["mesh.nx=20", "adapt.steps=6", "method.stabilization='ghost'",
                                            "output.save_solution=true", *QUIET])
    if results is None:
        raise DriverError(f"adaptive bench run failed: {row['message']}")
    steps = results["steps"]
    elapsed = np.cumsum(steps["cpu_s"])
    for k in range(len(steps["dofs"])):
        err = errors_against(ref, folder / f"step_{k}")
        rows.append(dict(method="adaptive P2 (ghost)", degree=2, theta=-1, nx=20, step=k,
                         dofs=int(steps["dofs"][k]), newton_iterations=int(steps["newton_iterations"][k]),
                         wall_s=float(elapsed[k]) * row["wall_s"] / max(elapsed[-1], 1e-300),
                         peak_rss_mb=results.get("peak_rss_mb"),
                         h1_error=float(np.hypot(err["h1_body1"], err["h1_body2"]))))
    table = pd.DataFrame(rows)
    RESULTS_DIR.mkdir(exist_ok=True)
    table.to_csv(RESULTS_DIR / "bench.csv", index=False)
    scaling = []
    for method, group in table[table.method.str.startswith("uniform") & (table.theta == -1)].groupby("method"):
        big = group[group.dofs >= 5000]
        for column in ["wall_s"] + [f"cpu_{p}" for p in PHASES]:
            values = big[column]
            if (values > 0).all() and len(big) >= 2:
                scaling.append(dict(method=method, quantity=column,
                                    exponent=loglog_slope(big.dofs, values), runs=len(big)))
    scaling = pd.DataFrame(scaling)
    scaling.to_csv(RESULTS_DIR / "bench_scaling.csv", index=False)
    print(markdown_table(table[["method", "theta", "nx", "dofs", "newton_iterations", "wall_s",
                                "peak_rss_mb", "h1_error"]]))
    print(markdown_table(scaling, digits=3))

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 5))
    for method, group in table[table.theta == -1].groupby("method"):
        group = group.sort_values("wall_s")
        ax.loglog(group.wall_s, group.h1_error, "o-", label=method)
    ax.set_xlabel("wall time of the FreeFEM run [s] (adaptive: cumulative over its steps)")
    ax.set_ylabel("relative H1 error (both bodies)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    ax.set_title(f"disk on slab, theta = -1: error against time\n{machine()}", fontsize=9)
    fig.tight_layout()
    PLOTS_DIR.mkdir(exist_ok=True)
    fig.savefig(PLOTS_DIR / "speed_vs_error.png", dpi=110)
    print(f"wrote {PLOTS_DIR / 'speed_vs_error.png'}")
    return table
