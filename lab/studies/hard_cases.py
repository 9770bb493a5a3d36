"""Hard cases of the fictitious-domain contact: the scenes of cases/hard/,
the material scaling of gamma and the conditioning of the Newton matrix against
the smallest cut ratio.

hard-cases        -> results/hard_cases.csv, results/hard_gamma_scaling.csv
hard-conditioning -> results/hard_conditioning.csv, plots/conditioning.png
(make hard-study runs both and refills the tables of docs/hard-cases.md).
"""

import pandas as pd

from driver.errors import DriverError
from driver.runner import REPO
from driver.sweep import run_point
from .common import markdown_table, progress, RESULTS_DIR, save_figure

HARD = REPO / "cases" / "hard"
# Measured on the P1 cut geometry (results/hard_*.csv), which the study pins with a
# P1 reference until it is rerun on the curved one (lab/studies/fd2d.py).
QUIET = ["output.vtu=false", "output.pressure_csv=false", "method.geometry=p1"]
STABILIZATIONS = ("none", "neighbour", "ghost")
HARD_REFERENCE_NX = 160

# Every scene of cases/hard/ with what it probes and what must happen.
CASES = [
    ("sliver_shift", "disk moved by 1e-3 h: disk cut ratio 3e-7 (P1, NX = 20)", "converges"),
    ("grid_line", "slab top on a grid line (P1, NX = 40)", "converges"),
    ("gamma0_tiny", "gamma0 = 1e-4, theta = -1 (P2, NX = 30)", "converges"),
    ("gamma0_huge", "gamma0 = 100, theta = -1 (P2, NX = 30)", "converges"),
    ("theta1_large_gamma0", "gamma0 = 100, theta = 1 (P2, NX = 30)", "detected failure"),
    ("soft_disk", "E1/E2 = 1e-3 (P2, NX = 30)", "converges"),
    ("stiff_disk", "E1/E2 = 1e3 (P2, NX = 30)", "converges"),
    ("near_incompressible", "nu = 0.49 both bodies (P2, NX = 30)", "converges"),
    ("initial_gap", "gap 0.01 closed by the weight (P2, NX = 30)", "converges"),
    ("load_too_small", "gap 0.01, load 1e-10: never touches (P2, NX = 30)", "detected failure"),
]
# The sliver cases against their unperturbed position: (case, overrides of the perturbed
# run, overrides of the comparison run).
SLIVER_COMPARISONS = {
    "sliver_shift": ([], ["body1.centre=[0.0, 0.0]", "rigid.fix_x_points=[0.0, 0.0, 0.0, 0.1]"]),
    "grid_line": ([], ["mesh.nx=42"]),
}
GAMMA_SCALINGS = ("none", "body1", "mean_compliance")


def scene_path(name):
    return HARD / f"{name}.toml"


def summary(results):
    """The measured outcome of a converged run (one table row's numbers)."""
    c, cut = results["contact"], results["cut"]
    return dict(newton_iterations=results["newton"]["iterations"], dofs=results["dofs"],
                max_penetration=c["max_penetration"], force_balance_error=c["force_balance_error"],
                active_length=c["active_measure"], max_pressure=c["max_pressure"],
                centre_uy=results["probes"]["centre"][1],
                min_cut_ratio=min(cut["min_ratio_body1"], cut["min_ratio_body2"]),
                dropped=cut.get("dropped_body1", 0) + cut.get("dropped_body2", 0),
                gamma0_effective=results["gamma0_effective"])


def hard_reference():
    from .fd2d import reference

    return reference(HARD_REFERENCE_NX, "p1")


def run_with_errors(ref, case, overrides):
    """(row, results): a saved run of a hard scene and its relative errors against ref."""
    from .fd2d import errors_against

    row, results, folder = run_point(case, [*overrides, "output.save_solution=true", *QUIET])
    if results is None:
        return row, None
    err = errors_against(ref, folder)
    row.update(summary(results), h1_body1=err["h1_body1"], h1_body2=err["h1_body2"],
               h1_both=err["h1_both"])
    return row, results


def sliver_rows(ref, name):
    """The perturbed scene and its unperturbed comparison for each stabilization."""
    perturbed, plain = SLIVER_COMPARISONS[name]
    rows = []
    for stab in STABILIZATIONS:
        s = [f"method.stabilization='{stab}'"]
        row, _ = run_with_errors(ref, scene_path(name), [*perturbed, *s])
        base, _ = run_with_errors(ref, scene_path(name), [*plain, *s])
        row.update(stabilization=stab, unperturbed_h1_both=base.get("h1_both"),
                   unperturbed_status=base["status"])
        if "h1_both" in row and "h1_both" in base:
            row["h1_ratio"] = row["h1_both"] / base["h1_both"]
        rows.append(row)
    return rows


def hard_cases():
    ref = hard_reference()
    rows = []
    for i, (name, what, expected) in enumerate(CASES, 1):
        progress(i, len(CASES), name)
        if name in SLIVER_COMPARISONS:
            found = sliver_rows(ref, name)
        else:
            row, results, _ = run_point(scene_path(name), QUIET)
            if results is not None:
                row.update(summary(results))
            found = [row]
        for row in found:
            row.update(case=name, what=what, expected=expected)
            row.setdefault("stabilization", "")
            rows.append(row)
    table = pd.DataFrame(rows)
    RESULTS_DIR.mkdir(exist_ok=True)
    table.drop(columns=["overrides"]).to_csv(RESULTS_DIR / "hard_cases.csv", index=False)
    print(hard_cases_table(table))
    gamma_scaling()
    return table


def outcome(r):
    """One cell: the measured outcome or the error message."""
    if r.status != "converged":
        return f"{r.status}: {r.message}"
    text = (f"{int(r.newton_iterations)} Newton its, penetration {r.max_penetration:.2g}, "
            f"force balance {r.force_balance_error:.1g}")
    if "h1_ratio" in r and r.h1_ratio == r.h1_ratio:
        text += f", H1 error {r.h1_both:.3g} = {r.h1_ratio:.3f} x unperturbed"
    return text


def hard_cases_table(table):
    rows = []
    for _, r in table.iterrows():
        label = r.case + (f" ({r.stabilization})" if isinstance(r.stabilization, str) and r.stabilization else "")
        rows.append({"case": label, "what": r.what, "expected": r.expected, "outcome": outcome(r)})
    return markdown_table(pd.DataFrame(rows))


def gamma_scaling():
    """gamma = gamma0 h_K times 1, 1/E1 or (1/E1 + 1/E2)/2 on the two contrasts and the base scene."""
    cases = [("equal (E1 = E2 = 2.5)", REPO / "cases" / "disk_on_slab.toml", ["mesh.nx=30"]),
             ("soft disk E1/E2 = 1e-3", scene_path("soft_disk"), []),
             ("stiff disk E1/E2 = 1e3", scene_path("stiff_disk"), [])]
    rows = []
    for contrast, case, extra in cases:
        for theta in (-1, 1):
            for scaling in GAMMA_SCALINGS:
                progress(len(rows) + 1, 3 * 2 * len(GAMMA_SCALINGS), f"{contrast} theta={theta} {scaling}")
                row, results, _ = run_point(case, [*extra, *QUIET, f"method.gamma_scaling='{scaling}'",
                                                   f"method.theta={theta}"])
                if results is not None:
                    row.update(summary(results))
                row.update(contrast=contrast, theta=theta, gamma_scaling=scaling)
                rows.append(row)
    table = pd.DataFrame(rows)
    table.drop(columns=["overrides", "case"]).to_csv(RESULTS_DIR / "hard_gamma_scaling.csv", index=False)
    print(gamma_scaling_table(table))
    return table


def gamma_scaling_table(table):
    rows = []
    for _, r in table.iterrows():
        ok = r.status == "converged"
        rows.append({"contrast": r.contrast, "theta": f"{int(r.theta)}", "gamma_scaling": r.gamma_scaling,
                     "gamma0 h_K factor": f"{r.gamma0_effective / 0.005:.3g}" if ok else "",
                     "Newton": str(int(r.newton_iterations)) if ok else r.status,
                     "max penetration": f"{r.max_penetration:.2g}" if ok else "",
                     "force balance": f"{r.force_balance_error:.1g}" if ok else "",
                     "centre u_y": f"{r.centre_uy:.4g}" if ok else ""})
    return markdown_table(pd.DataFrame(rows))


# ---------------------------------------------------------------------------
# Conditioning of the Newton matrix against the smallest cut ratio.

CONDITIONING_NX = 20
# Horizontal disk shifts s = eps h: the grid vertex (0.25, 0), on the circle at
# s = 0, is eps h inside it; the elements around it are cut with ratio ~0.31 eps^2.
CONDITIONING_EPS = (0.5, 0.2, 0.1, 3e-2, 1e-2, 3e-3, 1e-3, 3e-4, 1e-4, 3e-5, 1e-5)


def condition_estimate(path):
    """cond_1(A) estimate: onenormest(A) * onenormest(A^-1), A^-1 through splu."""
    import scipy.io
    import scipy.sparse.linalg as sla

    A = scipy.io.mmread(str(path)).tocsc()
    lu = sla.splu(A)
    inverse = sla.LinearOperator(A.shape, matvec=lu.solve, rmatvec=lambda x: lu.solve(x, trans="T"),
                                 dtype=float)
    return float(sla.onenormest(A) * sla.onenormest(inverse)), A.shape[0]


def hard_conditioning():
    case = REPO / "cases" / "disk_on_slab.toml"
    grid = [(d, stab, eps) for d in (1, 2) for stab in STABILIZATIONS for eps in CONDITIONING_EPS]
    rows = []
    h = 1.0 / CONDITIONING_NX
    for i, (degree, stab, eps) in enumerate(grid, 1):
        shift = eps * h
        progress(i, len(grid), f"P{degree} {stab} shift {eps:g} h")
        overrides = [f"mesh.nx={CONDITIONING_NX}", f"method.degree={degree}", f"method.stabilization='{stab}'",
                     f"body1.centre=[{shift!r}, 0.0]", f"rigid.fix_x_points=[{shift!r}, 0.0, {shift!r}, 0.1]",
                     "output.export_matrix=true", *QUIET]
        row, results, folder = run_point(case, overrides)
        row.update(degree=degree, stabilization=stab, shift_over_h=eps)
        if results is not None:
            cond, n = condition_estimate(folder / "newton_matrix.mtx")
            row.update(min_cut_ratio_body1=results["cut"]["min_ratio_body1"],
                       min_kept_ratio_body1=results["cut"]["min_kept_ratio_body1"],
                       dropped_body1=results["cut"]["dropped_body1"], drop_ratio=results["cut"]["drop_ratio"],
                       matrix_size=n, cond1_estimate=cond, newton_iterations=results["newton"]["iterations"])
        rows.append(row)
    table = pd.DataFrame(rows).drop(columns=["overrides", "case"])
    RESULTS_DIR.mkdir(exist_ok=True)
    table.to_csv(RESULTS_DIR / "hard_conditioning.csv", index=False)
    print(markdown_table(table[[c for c in ("degree", "stabilization", "shift_over_h", "status",
                                             "min_cut_ratio_body1", "min_kept_ratio_body1", "dropped_body1",
                                             "cond1_estimate")
                                if c in table]], digits=3))
    plot_conditioning(table)
    return table


def conditioning_summary(table):
    """Per degree and stabilization: cond at the largest and smallest cut ratio, and the worst."""
    rows = []
    ok = table[table.status == "converged"]
    for (degree, stab), g in ok.groupby(["degree", "stabilization"], sort=False):
        g = g.sort_values("min_cut_ratio_body1")
        worst = g.loc[g.cond1_estimate.idxmax()]
        rows.append({"P": str(int(degree)), "stabilization": stab,
                     "largest ratio: cond": f"{g.min_cut_ratio_body1.iloc[-1]:.1e}: {g.cond1_estimate.iloc[-1]:.2g}",
                     "worst: ratio (kept): cond": f"{worst.min_cut_ratio_body1:.1e} ({worst.min_kept_ratio_body1:.1e}): "
                                                  f"{worst.cond1_estimate:.2g}",
                     "smallest ratio (kept): cond": f"{g.min_cut_ratio_body1.iloc[0]:.1e} "
                                                    f"({g.min_kept_ratio_body1.iloc[0]:.1e}): "
                                                    f"{g.cond1_estimate.iloc[0]:.2g}",
                     "runs": str(len(g)), "failed": str(int((table[(table.degree == degree) & (
                         table.stabilization == stab)].status != "converged").sum()))})
    return pd.DataFrame(rows)


def plot_conditioning(table):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = table[table.status == "converged"]
    if not len(ok):
        raise DriverError("no conditioning run converged; no plot made")
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.4), sharey=True)
    for ax, degree in zip(axes, (1, 2)):
        group = ok[ok.degree == degree]
        for stab, g in group.groupby("stabilization"):
            g = g.sort_values("min_cut_ratio_body1")
            ax.loglog(g.min_cut_ratio_body1, g.cond1_estimate, "o-", ms=4, label=stab)
        if len(group):
            ax.axvline(group.drop_ratio.iloc[0], color="k", ls=":", lw=1,
                       label=f"sliver rule: dropped below {group.drop_ratio.iloc[0]:g}")
        ax.set_xlabel("smallest cut ratio of the disk |K cap Omega_1|/|K|")
        ax.set_title(f"P{degree}, NX = {CONDITIONING_NX}")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    axes[0].set_ylabel("cond_1 estimate of the Newton matrix (free DOFs)")
    fig.suptitle("disk on slab, disk moved sideways: conditioning against the cut (make hard-study)")
    save_figure(fig, "conditioning.png")

