"""Generated parts of the documentation (make readme, python -m driver readme).

Study tables: in README.md and docs/*.md a generated block sits between
`<!-- table:NAME -->` and `<!-- end:NAME -->`; everything between the markers is
replaced from results/*.csv, nothing else is touched. A table whose CSV is
missing is left as it is (and reported). The study that writes the CSV declares the
table (lab/studies/__init__.py); this module's function NAME builds it.

Scene reference: docs/scenes.md is written whole from the schemas of the driver
(one table per FreeFEM script), so that it cannot disagree with what the driver
accepts; tests/test_docs.py checks that the committed file is current.

Flag rules: freefem/lib/{fd2d,fd3d,foundation}/flag_rules.idp are written from the
same schemas, the rule of every flag a schema declares (kind and range, or the
allowed values), which core/args.idp applies to a direct run's values;
tests/test_flags.py checks that the committed files are current.
"""

import inspect
import re

import numpy as np
import pandas as pd

from driver.runner import REPO
from driver.schema import REQUIRED, TableList, flag_rules
from .studies import tables
from .studies.common import markdown_table

RESULTS = REPO / "results"
DOCS = REPO / "docs"
SCENE_REFERENCE = DOCS / "scenes.md"


def foundation_newton():
    t = pd.read_csv(RESULTS / "foundation_newton.csv")
    t["newton_iterations"] = t["newton_iterations"].map(lambda v: "" if pd.isna(v) else str(int(v)))
    return markdown_table(t[["theta", "degree", "gamma0", "status", "newton_iterations", "active_length",
                             "contact_xmin", "contact_xmax"]])


def aposteriori_uniform():
    t = pd.read_csv(RESULTS / "aposteriori_uniform.csv")
    t = t[(t.theta == -1) & (t.status == "converged")].sort_values("nx")
    rows = {"h": [f"1/{int(n)}" for n in t.nx], "DOFs": [str(int(d)) for d in t.dofs]}
    for key, label, scale in (("l2_error", "L2 error (x1e-4)", 1e4), ("h1_error", "H1 error (x1e-3)", 1e3),
                              ("eta1", "eta1", 1), ("eta2", "eta2", 1), ("eta3", "eta3", 1),
                              ("eta4", "eta4", 1), ("eta", "eta", 1), ("efficiency", "Eff = eta/(E H1)", 1)):
        rows[label] = [f"{v * scale:.4g}" for v in t[key]]
    slopes = pd.read_csv(RESULTS / "aposteriori_uniform_slopes.csv")
    s = slopes[(slopes.theta == -1)].iloc[0]
    slope = {"L2 error (x1e-4)": s.l2_error, "H1 error (x1e-3)": s.h1_error, "eta1": s.eta1, "eta2": s.eta2,
             "eta3": s.eta3, "eta4": s.eta4, "eta": s.eta}
    lines = ["| size of mesh h | " + " | ".join(rows["h"]) + " | slope |",
             "|---|" + "---|" * (len(rows["h"]) + 1)]
    for label, values in rows.items():
        if label == "h":
            continue
        tail = f"{slope[label]:.3f}" if label in slope else ""
        lines.append(f"| {label} | " + " | ".join(values) + f" | {tail} |")
    return "\n".join(lines)


def aposteriori_slopes():
    t = pd.read_csv(RESULTS / "aposteriori_uniform_slopes.csv")
    return markdown_table(t[["theta", "gamma0", "runs", "l2_error", "h1_error", "eta", "efficiency_min",
                             "efficiency_max"]], digits=3)


def aposteriori_adaptive():
    t = pd.read_csv(RESULTS / "aposteriori_adaptive.csv")
    return markdown_table(t[["step", "dofs", "h1_error", "l2_error", "eta", "efficiency", "newton_iterations"]])


def aposteriori_adaptive_summary():
    t = pd.read_csv(RESULTS / "aposteriori_adaptive_summary.csv")
    return markdown_table(t, digits=3)


def fd2d_rates():
    from .studies.fd2d import rates_table

    return markdown_table(rates_table(pd.read_csv(RESULTS / "fd2d_rates.csv")))


def fd2d_dense_rates():
    from .studies.fd2d import dense_rates_table

    return markdown_table(dense_rates_table(pd.read_csv(RESULTS / "fd2d_dense_rates.csv")))


def dense_ladder_theta_minus1():
    """The theta = -1 rows of fd2d_dense_ladder.csv, by reference and mesh."""
    t = pd.read_csv(RESULTS / "fd2d_dense_ladder.csv")
    return t[t.theta == -1].sort_values(["reference_nx", "nx"])


def fd2d_dense_ladder():
    return markdown_table(dense_ladder_theta_minus1()[["reference_nx", "nx", "nested", "l2_body1", "l2_body2", "h1_body1",
                                                       "h1_body2", "centre_rel_err", "newton_iterations"]], digits=3)


def fd2d_dense_rigid():
    from .studies.fd2d import REFERENCE_NX

    t = dense_ladder_theta_minus1()
    return markdown_table(t[t.reference_nx == REFERENCE_NX][["nx", "l2_body1", "rigid_l2_body1", "l2_deformation_body1",
                                                            "rigid_ty_body1", "rigid_rotation_body1", "h1_body1",
                                                            "h1_deformation_body1"]], digits=3)


def fd2d_gamma0():
    t = pd.read_csv(RESULTS / "fd2d_gamma0.csv")
    rows = []
    for gamma0, group in t.groupby("gamma0", sort=False):
        row = {"gamma0": f"{gamma0:.4g}"}
        for theta in (1, 0, -1):
            g = group[group.theta == theta]
            if not len(g):
                continue
            r = g.iloc[0]
            row[f"theta={theta}: H1 disk / slab"] = (f"{r.h1_body1:.3g} / {r.h1_body2:.3g}"
                                                     if r.status == "converged" else "not converged")
            row[f"theta={theta}: Newton"] = (str(int(r.newton_iterations)) if r.status == "converged"
                                             else r.status)
        rows.append(row)
    return markdown_table(pd.DataFrame(rows))


def fd2d_stabilization():
    t = pd.read_csv(RESULTS / "fd2d_stabilization.csv")
    cols = ["theta", "stabilization", "nx", "status", "min_cut_ratio", "dropped", "case_b", "case_c",
            "newton_iterations", "h1_body1", "h1_body2"]
    return markdown_table(t[[c for c in cols if c in t]])


def fd2d_theta1_stabilization():
    t = pd.read_csv(RESULTS / "fd2d_theta1_stabilization.csv")
    rows = []
    for nx, group in t.groupby("nx"):
        row = {"NX": str(int(nx)), "min cut ratio": f"{group.min_cut_ratio.iloc[0]:.2e}"}
        for _, r in group.iterrows():
            row[f"{r.stabilization}: H1 disk / slab"] = (f"{r.h1_body1:.3g} / {r.h1_body2:.3g}"
                                                        if r.status == "converged" else r.status)
        rows.append(row)
    return markdown_table(pd.DataFrame(rows))


def fd2d_crosscheck():
    return markdown_table(pd.read_csv(RESULTS / "fd2d_crosscheck.csv"), digits=3)


def fd_aposteriori():
    t = pd.read_csv(RESULTS / "fd_aposteriori.csv")
    return markdown_table(t[["mode", "step", "dofs", "eta", "eta1", "eta2", "eta3", "eta4", "eta5",
                             "h1_body1", "h1_body2", "efficiency", "area_body1"]], digits=3)


def bench():
    t = pd.read_csv(RESULTS / "bench.csv")
    t = t[t.theta == -1]
    return markdown_table(t[["method", "nx", "dofs", "newton_iterations", "wall_s", "peak_rss_mb", "h1_error"]],
                          digits=3)


def bench_scaling():
    return markdown_table(pd.read_csv(RESULTS / "bench_scaling.csv"), digits=3)


def bench_targets():
    t = pd.read_csv(RESULTS / "bench_targets.csv")
    t["met"] = t.met.map({True: "yes", False: "**no**"})
    t.loc[t.bound.fillna("").isin(["", "(no target)"]), "met"] = ""   # information rows
    return (markdown_table(t[["target", "bound", "measured", "met"]])
            + f"\n\nMachine: {t.machine.iloc[0]}; load average (1 min) {t.load_average.iloc[0]} the timed runs.")


def machine_stamp(t):
    """The line under a make-bench table: the machine and the load over its runs."""
    return f"\n\nMachine: {t.machine.iloc[0]}; load average (1 min) {t.load_1min.iloc[0]} over the runs."


def stamped_bench_table(name, table_function, module="bench"):
    """A make-bench table made from results/NAME.csv by a table function of
    lab.studies.MODULE (bench or bench_scale), with its machine stamp."""
    import importlib

    study = importlib.import_module(f".studies.{module}", __package__)
    t = pd.read_csv(RESULTS / f"{name}.csv")
    return markdown_table(getattr(study, table_function)(t), digits=3) + machine_stamp(t)


def bench_overhead():
    return stamped_bench_table("bench_overhead", "overhead_table")


def bench_overhead_targets():
    return stamped_bench_table("bench_overhead_targets", "overhead_targets_table")


def bench_solver():
    return stamped_bench_table("bench_solver", "solver_table")


def bench_3d():
    return stamped_bench_table("bench_3d", "bench3d_table")


def bench_3d_large():
    return stamped_bench_table("bench_3d_large", "bench3d_large_table")


def bench_3d_graded():
    return stamped_bench_table("bench_3d_graded", "bench3d_large_table")


def bench_ordering():
    return stamped_bench_table("bench_ordering", "ordering_table")


def bench_scale():
    return stamped_bench_table("bench_scale", "scale_table", "bench_scale")


def bench_scale_targets():
    return stamped_bench_table("bench_scale_targets", "scale_targets_table", "bench_scale")


def bench_scale_mpi():
    return stamped_bench_table("bench_scale_mpi", "scale_mpi_table", "bench_scale")


def bench_scale_large():
    return stamped_bench_table("bench_scale_large", "scale_large_table", "bench_scale")


def bench_scale_model():
    return markdown_table(pd.read_csv(RESULTS / "bench_scale_model.csv"), digits=3)


def bench_solver_budget():
    t = pd.read_csv(RESULTS / "bench_solver_budget.csv")
    return markdown_table(t[["case", "factor_operations", "factor_entries", "sqrt_operations_per_entry",
                             "factorization_s", "solve_s", "time_ratio", "time_ratio_over_sqrt",
                             "refactor_budget", "low_rank_columns", "column_s", "solves_per_column"]], digits=3)


def bench_3d_scaling():
    return markdown_table(pd.read_csv(RESULTS / "bench_3d_scaling.csv"), digits=3)


def bench_error_tool():
    t = pd.read_csv(RESULTS / "bench_error_tool.csv")
    return (markdown_table(t[["version", "nx", "runs", "wall_s", "wall_s_ratio", "cpu_s", "peak_rss_mb", "errors_rel_diff",
                              "l2_rel_body1", "h1_rel_body1", "l2_rel_body2", "h1_rel_body2"]], digits=3)
            + machine_stamp(t))


def bench_mumps():
    from .studies.bench import mumps_summary

    return markdown_table(mumps_summary(pd.read_csv(RESULTS / "bench_mumps.csv")), digits=3)


def bench_first_active_set():
    t = pd.read_csv(RESULTS / "bench_first_active_set.csv")
    return markdown_table(t[["active0", "newton_iterations", "factorizations", "gmres_iterations", "cpu_newton",
                             "cpu_newton_factor_solve", "active_length", "centre_uy_rel_diff"]], digits=3)


def bench_newton():
    """Newton iterations per (degree, theta) and gamma0: the largest over the NX ladder."""
    t = pd.read_csv(RESULTS / "bench_newton.csv")
    rows = []
    for (degree, theta), group in t.groupby(["degree", "theta"], sort=False):
        row = {"P": degree, "theta": theta}
        for gamma0, cell in group.groupby("gamma0", sort=False):
            failed = cell[cell.status != "converged"]
            text = f"{int(cell.newton_iterations.max())}" if failed.empty else \
                f"fails at NX {' '.join(str(n) for n in failed.nx)}"
            row[f"gamma0 = 1/{1 / gamma0:.0f}"] = text
        rows.append(row)
    return markdown_table(pd.DataFrame(rows))


def hard_cases():
    from .studies.hard_cases import hard_cases_table

    return hard_cases_table(pd.read_csv(RESULTS / "hard_cases.csv"))


def hard_gamma_scaling():
    from .studies.hard_cases import gamma_scaling_table

    return gamma_scaling_table(pd.read_csv(RESULTS / "hard_gamma_scaling.csv"))


def gates():
    t = pd.read_csv(RESULTS / "gates.csv")
    t = t[t.status == "converged"].copy()
    t["scene"] = t.case.str.replace("cases/", "", regex=False).str.replace(".toml", "", regex=False)
    t["floats"] = t.floating_body1.astype(int).astype(str) + t.floating_body2.astype(int).astype(str)
    t["floats"] = t.floats.map({"10": "body 1", "01": "body 2", "11": "both", "00": ""})
    t["drift / size"] = [max(d1 if f1 else 0.0, d2 if f2 else 0.0) if f1 or f2 else float("nan") for d1, d2, f1, f2
                         in zip(t.drift_ratio_body1, t.drift_ratio_body2, t.floating_body1, t.floating_body2)]
    t = t.rename(columns={"penetration_ratio": "penetration / size", "pins_share": "pins", "mass_share": "mass term",
                          "balance_error": "balance error", "roundoff_share": "round-off"})
    return markdown_table(t[["scene", "floats", "penetration / size", "drift / size", "pins", "mass term",
                             "balance error", "round-off"]], digits=2)


def hard_conditioning():
    from .studies.hard_cases import conditioning_summary

    return markdown_table(conditioning_summary(pd.read_csv(RESULTS / "hard_conditioning.csv")))


def fd3d_rates():
    t = pd.read_csv(RESULTS / "fd3d_rates.csv")
    rows = []
    for norm, body, name in (("L2", 1, "ball"), ("L2", 2, "slab"), ("H1", 1, "ball"), ("H1", 2, "slab")):
        row = {"rate (h = 1/nx, nx used)": f"{norm} body {body} ({name})"}
        for degree in (1, 2):
            for theta in (1, 0, -1):
                pick = t[(t.degree == degree) & (t.theta == theta) & (t.body == body) & (t.norm == norm)]
                row[f"P{degree} th={theta}"] = (f"{pick.rate.iloc[0]:.2f} ({pick.nx_used.iloc[0]})"
                                               if len(pick) else "-")
        rows.append(row)
    return markdown_table(pd.DataFrame(rows))


def fd3d_convergence():
    t = pd.read_csv(RESULTS / "fd3d_convergence.csv")
    t = t[(t.theta == -1) | (t.status != "converged")].sort_values(["degree", "nx"])
    t["in rates"] = t["ladder"].map({True: "yes", False: "no"})
    columns = ["degree", "theta", "status", "nx", "in rates", "dofs", "l2_body1", "l2_body2", "h1_body1",
               "h1_body2", "newton_iterations", "wall_s", "peak_rss_mb"]
    return markdown_table(t[columns], digits=3)


def fd3d_cost():
    return markdown_table(pd.read_csv(RESULTS / "fd3d_cost.csv"), digits=3)


def fd3d_curved_rates():
    """P2, theta = -1: the curved geometry's rates (its ladder against the curved
    reference) beside the P1 geometry's (against the P1 reference, fd3d_rates.csv)."""
    curved = pd.read_csv(RESULTS / "fd3d_curved_rates.csv")
    p1 = pd.read_csv(RESULTS / "fd3d_rates.csv")
    rows = []
    for norm, body, name in (("L2", 1, "ball"), ("L2", 2, "slab"), ("H1", 1, "ball"), ("H1", 2, "slab")):
        row = {"P2, theta = -1: rate (nx used)": f"{norm} body {body} ({name})"}
        for label, t in (("curved geometry", curved), ("P1 geometry", p1)):
            pick = t[(t.degree == 2) & (t.theta == -1) & (t.body == body) & (t.norm == norm)]
            row[label] = f"{pick.rate.iloc[0]:.2f} ({pick.nx_used.iloc[0]})" if len(pick) else "-"
        rows.append(row)
    return markdown_table(pd.DataFrame(rows))


def fd3d_curved_convergence():
    """The curved ladder and reference, then the P1 geometry's P2 theta = -1 ladder and
    reference (fd3d_convergence.csv): errors and the centre u_z error against each one's
    own reference, the ball's volume error (curved only), costs."""
    curved = pd.read_csv(RESULTS / "fd3d_curved_convergence.csv")
    p1 = pd.read_csv(RESULTS / "fd3d_convergence.csv")
    p1 = p1[(p1.degree == 2) & (p1.theta == -1) & (p1.ladder | (p1.status == "reference"))].copy()
    p1.insert(0, "geometry", "p1")
    centre_ref = p1.loc[p1.status == "reference", "centre_uz"].iloc[0]
    p1["centre_uz_rel_err"] = (p1.centre_uz - centre_ref).abs() / abs(centre_ref)
    t = pd.concat([curved, p1], ignore_index=True)
    t["nx"] = [f"{int(n)} (reference)" if s == "reference" else str(int(n)) for n, s in zip(t.nx, t.status)]
    columns = ["geometry", "nx", "dofs", "l2_body1", "l2_body2", "h1_body1", "h1_body2", "centre_uz_rel_err",
               "volume_rel_err_body1", "newton_iterations", "force_balance_error", "wall_s", "peak_rss_mb"]
    return markdown_table(t[columns], digits=3)


def fd3d_adaptive():
    from .studies.common import loglog_slope

    t = pd.read_csv(RESULTS / "fd3d_adaptive.csv")
    rows = []
    for kind in ("uniform", "adaptive"):
        part = t[t.refinement == kind].sort_values("dofs")
        rows.append({"refinement": kind, "solves": len(part),
                     "DOFs": f"{int(part.dofs.iloc[0])} .. {int(part.dofs.iloc[-1])}",
                     "eta": f"{part.eta.iloc[0]:.3g} .. {part.eta.iloc[-1]:.3g}",
                     "eta_2 (stress jumps)": f"{part.eta2.iloc[0]:.3g} .. {part.eta2.iloc[-1]:.3g}",
                     "slope of eta in DOFs": f"{loglog_slope(part.dofs, part.eta):.3f}",
                     "ball volume (last)": f"{part.volume_ball.iloc[-1]:.5f}"})
    return markdown_table(pd.DataFrame(rows))


def hertz():
    t = pd.read_csv(RESULTS / "hertz.csv").iloc[0]
    return markdown_table(pd.DataFrame([{
        "half-width a (Hertz)": f"{t.a_hertz:.5f}", "measured": f"{t.half_width:.5f}",
        "error": f"{100 * t.half_width_error:.2f} %", "force - P": f"{t.force_error:.2g}",
        "peak recovered": f"{100 * t.peak_recovered_error:+.2f} %",
        "recovered vs Hertz (rel. L2)": f"{100 * t.recovered_l2_error:.1f} %",
        "raw vs Hertz (rel. L2)": f"{100 * t.pressure_l2_error:.1f} %", "DOFs": int(t.dofs),
        "wall": f"{t.wall_s:.0f} s"}]))


def hertz_spheres_table(name, formatter):
    from .studies import hertz3d

    return getattr(hertz3d, formatter)(pd.read_csv(RESULTS / name))


def hertz_spheres():
    return hertz_spheres_table("hertz_spheres.csv", "hertz_table")


def hertz_spheres_settings():
    return hertz_spheres_table("hertz_spheres_settings.csv", "settings_table")


def hertz_spheres_recovery():
    return hertz_spheres_table("hertz_spheres_recovery.csv", "recovery_table")


def hertz_spheres_coarse():
    return hertz_spheres_table("hertz_spheres_coarse.csv", "coarse_table")


def scenes():
    t = pd.read_csv(RESULTS / "scenes.csv")
    t["scene"] = t.case.str.replace("cases/", "", regex=False)
    return markdown_table(t[["scene", "dofs", "newton_iterations", "force_y", "balance_error", "wall_s"]], digits=3)


def scenes_3d():
    t = pd.read_csv(RESULTS / "scenes_3d.csv")
    t["scene"] = t.case.str.replace("cases/", "", regex=False)
    out = t[["scene", "geometry", "degree", "dofs", "newton_iterations"]].copy()
    for body in ("body1", "body2"):
        out[f"volume error {body}"] = t[f"volume_error_{body}"].map(lambda v: "no formula" if pd.isna(v) else f"{v:.1e}")
    out["force balance"] = t.force_balance_error.map(lambda v: f"{v:.1e}")
    out["wall s"] = t.wall_s.map(lambda v: f"{v:.1f}")
    return markdown_table(out, digits=3)



def pressure_recovery():
    from .studies.pressure import recovery_table

    return recovery_table(pd.read_csv(RESULTS / "pressure_recovery.csv"))


def pressure_gamma0():
    from .studies.pressure import gamma0_table

    return gamma0_table(pd.read_csv(RESULTS / "pressure_gamma0.csv"))


def curved_geometry_table(name, shape, counts):
    t = pd.read_csv(RESULTS / name)
    measures = [c for c in ("area_rel_err", "volume_rel_err", "perimeter_rel_err", "poly_rel_err", "section_rel_err")
                if c in t]
    wide = t.pivot_table(index=[shape, "nx"], columns="geometry", values=measures).reset_index()
    out = pd.DataFrame({shape: wide[shape], "NX": wide["nx"]})
    labels = {"area_rel_err": "area", "volume_rel_err": "volume", "perimeter_rel_err": "perimeter",
              "poly_rel_err": "polynomial", "section_rel_err": "section"}
    for value in measures:
        for geometry in ("p1", "curved"):
            out[f"{labels[value]} {geometry}"] = wide[(value, geometry)].map(lambda v: f"{v:.2g}")
    if counts:   # the curved cells: how many, how many fell back to the P1 cut, their volume points
        curved = t[t["geometry"] == "curved"].set_index([shape, "nx"])
        out["curved cut cells"] = [
            f"{int(curved.loc[(b, n), 'cut_elements'])}" for b, n in zip(out[shape], out["NX"])]
        out["fallbacks"] = [int(curved.loc[(b, n), "fallback"]) for b, n in zip(out[shape], out["NX"])]
        if "volume_points" in curved:
            out["volume points"] = [int(curved.loc[(b, n), "volume_points"]) for b, n in zip(out[shape], out["NX"])]
    return markdown_table(out)


def curved_geometry():
    return curved_geometry_table("curved_geometry.csv", "disk", counts=True)


def curved_geometry_3d():
    return curved_geometry_table("curved_geometry_3d.csv", "ball", counts=True)


def curved_convergence():
    t = pd.read_csv(RESULTS / "curved_convergence.csv")
    out = t[["nx", "geometry", "centre_rel_err", "rate", "l2_body1", "l2_body2", "h1_body1", "h1_body2", "wall_s"]]
    return markdown_table(out, digits=2)


def curved_cost():
    return markdown_table(pd.read_csv(RESULTS / "curved_cost.csv"), digits=3)


def curved_patch(csv="curved_patch.csv", measure="area_rel_err"):
    t = pd.read_csv(RESULTS / csv)
    return markdown_table(t[["geometry", "nx", "max_probe_err", measure, "newton_iterations"]], digits=2)


def curved_smooth_rates(csv="curved_smooth_rates.csv"):
    """A held scene's rates: one row per theta, L2 and H1 per geometry."""
    t = pd.read_csv(RESULTS / csv)
    rows = []
    for theta, group in t.groupby("theta", sort=False):
        by = group.set_index("geometry")
        rows.append({"theta": f"{theta:g}", "nx used": by.nx_used.iloc[0],
                     "L2 curved": f"{by.l2_rate['curved']:.2f}", "L2 p1": f"{by.l2_rate['p1']:.2f}",
                     "H1 curved": f"{by.h1_rate['curved']:.2f}", "H1 p1": f"{by.h1_rate['p1']:.2f}"})
    return markdown_table(pd.DataFrame(rows))


def curved_adaptive():
    """The disk on slab's errors per DOFs: the uniform curved ladder (curved_convergence.csv)
    and the adaptive loop (curved_adaptive.csv)."""
    uniform = pd.read_csv(RESULTS / "curved_convergence.csv")
    uniform = uniform[uniform.geometry == "curved"].assign(mode="uniform", step=0, area_rel_err=np.nan)
    t = pd.concat([uniform, pd.read_csv(RESULTS / "curved_adaptive.csv")], ignore_index=True)
    rows = [{"mode": r.mode, "nx": r.nx, "step": r.step, "dofs": r.dofs,
             "L2 disk": f"{r.l2_body1:.2e}", "L2 slab": f"{r.l2_body2:.2e}",
             "H1 disk": f"{r.h1_body1:.2e}", "H1 slab": f"{r.h1_body2:.2e}",
             "disk area": "" if np.isnan(r.area_rel_err) else f"{r.area_rel_err:.1e}"} for r in t.itertuples()]
    return markdown_table(pd.DataFrame(rows))


def curved_centre_scan_windows():
    t = pd.read_csv(RESULTS / "curved_centre_scan_windows.csv")
    return markdown_table(t[["nx_from", "nx_to", "meshes", "half_range_rel", "max_abs_dev_rel", "slope",
                             "max_abs_area_rel_err"]], digits=3)


def curved_smooth(csv="curved_smooth.csv", extra=()):
    t = pd.read_csv(RESULTS / csv)
    t = t[t.theta == -1].sort_values(["geometry", "nx"])
    return markdown_table(t[["geometry", "nx", "dofs", "l2_body2", "h1_body2", "dropped", "newton_iterations",
                             "wall_s", *extra]], digits=3)


def mutation_frame():
    return pd.read_csv(RESULTS / "mutation.csv", keep_default_na=False)


def mutation():
    """make mutation's table: each mutant, what caught it and which test; then the
    equivalent mutants with the measurement that shows it."""
    t = mutation_frame()
    rows = [{"mutant": r.id, "family": r.family, "file": f"`{r.file}`", "caught": r.caught,
             "first failure": r.caught_by, "by a results assertion": r.by_results_assertion,
             "test": f"`{r.results_test or r.first_failing_test}`" if r.first_failing_test else "",
             "s": r.seconds} for r in t.itertuples()]
    notes = [f"- `{r.id}` ({r.caught}): {r.equivalent}" for r in t.itertuples() if r.equivalent]
    return markdown_table(pd.DataFrame(rows)) + ("\n\nEquivalent mutants:\n\n" + "\n".join(notes) if notes else "")


def mutation_totals():
    """Per family: mutants caught by an assertion about the results; caught only by a
    run meant to converge failing; only otherwise (a run meant to fail, an exception);
    missed; equivalent; not run (not applied, build or pytest error)."""
    t = mutation_frame()
    results = t.by_results_assertion == "yes"
    caught_only = (t.caught == "yes") & ~results
    kinds = {"caught by a results assertion": results, "only by a run failing": caught_only & (t.caught_by == "run failed"),
             "only otherwise": caught_only & (t.caught_by != "run failed"), "missed": t.caught == "no",
             "equivalent": t.caught == "no (equivalent)", "not run": ~t.caught.isin(["yes", "no", "no (equivalent)"])}
    rows = []
    for family, part in list(t.groupby("family", sort=False)) + [("all", t)]:
        rows.append({"family": family, "mutants": len(part), **{k: int(v[part.index].sum()) for k, v in kinds.items()}})
    counted = len(t) - int(kinds["equivalent"].sum())
    return (markdown_table(pd.DataFrame(rows))
            + f"\n\nCaught by an assertion about the results: {int(results.sum())} of {counted} non-equivalent "
              f"mutants ({100 * results.sum() / max(counted, 1):.0f} %); {t.seconds.astype(float).sum() / 60:.0f} min "
              f"of test runs.")


def curved_patch_3d():
    return curved_patch("curved_patch_3d.csv", "volume_rel_err")


def curved_smooth_3d_rates():
    return curved_smooth_rates("curved_smooth_3d_rates.csv")


def curved_smooth_3d():
    return curved_smooth("curved_smooth_3d.csv", ("peak_rss_mb",))


def table_builder(name):
    """The function of this module that builds docs table `name` (a study declares the
    tables it fills: lab/studies/__init__.py); KeyError when there is none."""
    make = globals().get(name)
    if not (inspect.isfunction(make) and make.__module__ == __name__):
        raise KeyError(f"table {name}: no function {name} in {__name__}")
    return make


def pages():
    """The files whose table markers are refilled."""
    return [REPO / "README.md"] + sorted(p for p in DOCS.glob("*.md") if p != SCENE_REFERENCE)


def refill(text, built, found):
    """Replace every known table block in text; tables are computed once (built) and their names recorded."""
    for name in tables():
        pattern = re.compile(rf"(<!-- table:{name} -->\n)(.*?)(<!-- end:{name} -->)", re.S)
        if not pattern.search(text):
            continue
        found.add(name)
        if name not in built:
            try:
                built[name] = table_builder(name)()
            except FileNotFoundError as exc:
                print(f"readme: {name}: {exc.filename} missing, table left as it was")
                built[name] = None
        if built[name] is not None:
            text = pattern.sub(lambda m: m.group(1) + built[name] + "\n" + m.group(3), text)
    return text


# ---- scene reference (docs/scenes.md) ----

SCRIPT_TITLES = (
    ("fd_contact_2d", "two bodies in 2D, fictitious domain (disk on slab)"),
    ("fd_contact_3d", "two bodies in 3D, fictitious domain (ball on slab)"),
    ("contact_foundation_2d", "one body on a rigid foundation, body-fitted mesh (2D)"),
)

KIND_NAMES = {"float": "number", "int": "integer", "str": "string", "bool": "boolean", "vector": "numbers",
              "tree": "table"}

INTRO = """# Scene reference

Generated by `python3 -m driver readme` from the driver's schemas
(`driver/fd2d.py`, `driver/fd3d.py`, `driver/foundation.py`, `ADAPT_SCHEMA` in
`driver/schema.py`, `SCENE_HEADER` in `driver/header.py`): edit those, not this
file (`tests/test_docs.py` fails when it is out of date).

A scene is a TOML file; `[scene] script` chooses the FreeFEM script and so the
table below that applies. A key is written as `table.key` (`--set
method.theta=1` on the command line, `[method] theta = 1` in the file); a key
left out takes its default, a key marked *required* must be given, an unknown
key is refused. `[[boundary]]` and `[[point_constraint]]` are arrays of tables,
shown as `boundary[].label`.

Units: any consistent system. The unit column names the dimension: `length`,
`stress` (force/area), `force/volume`, `1` for a dimensionless number; empty for
counts, switches and names. The shipped scenes are written in units of the
material (Lame 1, 1) or in Pa and m. A default `none` means "not set": each body
needs either `lambda` and `mu` or `E` and `nu`.

The FreeFEM flag column is where a key goes on a direct run (`FreeFem++ -nw
freefem/SCRIPT.edp -flag value`): the driver sends every key that names a flag
under that name, and derives the flags of the others (Lame coefficients from E
and nu, the pins, per-boundary flags); `-Ddegree` is a macro define and comes
first. Keys without a flag reach the script through the run's scene module
(`docs/scene-modules.md`). `tests/test_defaults.py` checks that the flags sent
are exactly these and the keys the script reads.
"""


def markdown_cell(text):
    return str(text).replace("|", "\\|")


def format_value(value):
    if value is REQUIRED:
        return "*required*"
    if value is None:
        return "none"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, list):
        return "[" + ", ".join(format_value(v) for v in value) + "]"
    return str(value)


def field_type(field):
    if field.kind == "vector":
        return f"{field.length} numbers" if field.length is not None else "list of numbers"
    return KIND_NAMES[field.kind]


def field_range(field):
    parts = []
    if field.choices is not None:
        parts.append(", ".join(format_value(c) for c in field.choices))
    if field.check is not None:
        parts.append(field.check.description)
    if field.kind == "bool":
        parts.append("true, false")
    return "; ".join(parts) or "any"


def field_flags(field):
    """The flag column: the flag carrying the key as is, or (derived) the flags made from it."""
    if field.flag:
        names = field.flag if isinstance(field.flag, tuple) else (field.flag,)
        return ", ".join(f"`-{name}`" for name in names)
    if field.derived:
        return "from it: " + ", ".join(f"`-{name}`" for name in field.derived.split())
    return ""


def schema_rows(schema, prefix=""):
    """(dotted key, Field) for every key of a schema, in schema order."""
    for key, spec in schema.items():
        if isinstance(spec, dict):
            yield from schema_rows(spec, f"{prefix}{key}.")
        elif isinstance(spec, TableList):
            yield from schema_rows(spec.schema, f"{prefix}{key}[].")
        else:
            yield f"{prefix}{key}", spec


def script_schema(module):
    from driver.scene import full_schema

    return full_schema(module)


def scene_reference():
    """The text of docs/scenes.md."""
    from driver.scene import script_modules

    modules = script_modules()
    parts = [INTRO]
    for script, title in SCRIPT_TITLES:
        module = modules[script]
        lines = [f"## `{script}`: {title}", "", module.__doc__.strip(), "",
                 "| key | type | unit | default | range | FreeFEM flag | meaning |",
                 "|---|---|---|---|---|---|---|"]
        for key, field in schema_rows(script_schema(module)):
            cells = (f"`{key}`", field_type(field), field.unit, format_value(field.default), field_range(field),
                     field_flags(field), field.doc)
            lines.append("| " + " | ".join(markdown_cell(c) for c in cells) + " |")
        parts.append("\n".join(lines) + "\n")
    parts.append(shapes_reference())
    return "\n".join(parts)


SHAPES_INTRO = """## Shapes

`bodyN.shape` (two-body scripts) and every `region` of a hold or load is a shape
table `{ type = "...", ... }` (written by `driver/geometry.py`, checked there).
Any shape also takes `rotate` (degrees: one angle in 2D, `[about x, about y,
about z]` in 3D, applied in that order) and `translate` (a vector): the shape is
turned about the origin of its own coordinates, then moved by `translate`. To
turn a shape in place, give it `centre = [0, 0]` and place it with `translate`.
A body is the part of the box where its level set is negative.
"""

SUPPORTS_TEXT = """## Supports, loads, probes

- `[[bodyN.hold]]`: `face = "xmin" | "xmax" | "ymin" | "ymax" | "zmin" | "zmax"`
  holds the body's degrees of freedom on that box face strongly (`displacement`,
  default zero; `components = "xy"` or a part of it); or `region = { shape }`
  holds the part of the body's cut boundary inside the region by Nitsche (all
  components; needs `gamma_scaling` shear or none).
- `[[bodyN.load]]`: `face = ...` or `region = { shape }` with `traction = [...]`
  (force per area), on the part of the face or cut boundary inside the body.
- `[[probe]]`: `name` (letters, digits, `_`, `-`), `point`, `body` (1 or 2,
  default 1); results.json `probes` gives the displacement there.
- A body that no hold holds in every component is floating: `rigid.mass_eps`
  holds its rigid motions (and for body 1 in 2D the pins `rigid.fix_x_points`);
  the balance gate refuses a run whose load they carry.
"""


def shapes_reference():
    from driver.geometry import SHAPE_DOCS

    lines = [SHAPES_INTRO, "| type | dimension | keys | level set |", "|---|---|---|---|"]
    for name, (dims, keys, meaning) in SHAPE_DOCS.items():
        lines.append("| " + " | ".join(markdown_cell(c) for c in (f"`{name}`", dims, keys, meaning)) + " |")
    return "\n".join(lines) + "\n\n" + SUPPORTS_TEXT


# ---- flag rules of the FreeFEM scripts (freefem/lib/*/flag_rules.idp) ----

RULE_FOLDERS = {"fd_contact_2d": "fd2d", "fd_contact_3d": "fd3d", "contact_foundation_2d": "foundation"}


def flag_rules_path(script):
    return REPO / "freefem" / "lib" / RULE_FOLDERS[script] / "flag_rules.idp"


def flag_rules_module(script):
    """The text of the script's flag_rules.idp: one argRule call per flag its schema declares."""
    from driver.scene import script_modules

    module = script_modules()[script]
    source = module.__name__.replace(".", "/") + ".py"
    folder = RULE_FOLDERS[script]
    lines = [f"// Generated by `python3 -m driver readme` from the scene schema of {source}: edit",
             "// the schema, not this file (tests/test_flags.py fails when it is out of date).",
             "// The rule of every flag the schema declares, applied by core/args.idp to a",
             f"// direct run's values as the driver applies the schema to a scene's; {folder}/params.idp",
             "// states the rules of the flags the driver derives or only direct runs use."]
    lines += [f'argRule("{flag}", "{rule}");' for flag, rule in flag_rules(script_schema(module)).items()]
    return "\n".join(lines) + "\n"


def write_if_changed(path, text):
    if not path.is_file() or path.read_text() != text:
        path.write_text(text)
        print(f"readme: {path.relative_to(REPO)} written")


def update():
    DOCS.mkdir(exist_ok=True)
    write_if_changed(SCENE_REFERENCE, scene_reference())
    for script in RULE_FOLDERS:
        write_if_changed(flag_rules_path(script), flag_rules_module(script))
    built, found = {}, set()
    for path in pages():
        old = path.read_text()
        new = refill(old, built, found)
        if new != old:
            path.write_text(new)
        names = sorted(n for n in built if n in found and re.search(f"<!-- table:{n} -->", new))
        if names:
            print(f"readme: {path.relative_to(REPO)}: {', '.join(names)}")
    for name in tables():
        if name not in found:
            print(f"readme: {name}: no <!-- table:{name} --> marker in README.md or docs/")
