"""The studies behind the tables and figures of docs/: each declared once, in STUDIES.

A study's record names its function, the make target that runs it (its group: `make
GROUP` runs `python -m driver study --group GROUP`, the group's studies in the order
listed here, then refills the docs) and the generated tables of README.md and docs/*.md
it fills (`<!-- table:NAME -->`; lab/readme.py builds table NAME with its function
NAME from the study's results/*.csv). Modules are imported only when one of their
studies runs. tests/test_docs.py checks that every table has one marker and every
group is a make target.
"""

import importlib
from dataclasses import dataclass


@dataclass(frozen=True)
class Study:
    name: str           # python -m driver study NAME
    module: str         # in lab.studies
    function: str       # says what it writes
    group: str          # the make target
    tables: tuple = ()  # the docs tables made from what it writes


STUDIES = (
    Study("foundation-newton", "foundation", "foundation_newton_table", "foundation-study", ("foundation_newton",)),
    Study("square-pressure", "foundation", "square_pressure_plot", "foundation-study"),
    Study("aposteriori-uniform", "foundation", "aposteriori_uniform", "aposteriori-study",
          ("aposteriori_uniform", "aposteriori_slopes")),
    Study("aposteriori-adaptive", "foundation", "aposteriori_adaptive", "aposteriori-study",
          ("aposteriori_adaptive", "aposteriori_adaptive_summary")),
    Study("square-adapted", "foundation", "square_adapted_vonmises", "aposteriori-study"),
    Study("fd2d-convergence", "fd2d", "convergence", "fd2d-study", ("fd2d_rates",)),
    Study("fd2d-dense-ladder", "fd2d", "dense_ladder", "fd2d-study",
          ("fd2d_dense_ladder", "fd2d_dense_rates", "fd2d_dense_rigid")),
    Study("fd2d-gamma0", "fd2d", "gamma0_sweep", "fd2d-study", ("fd2d_gamma0",)),
    Study("fd2d-stabilization", "fd2d", "stabilization", "fd2d-study", ("fd2d_stabilization",)),
    Study("fd2d-theta1-stabilization", "fd2d", "theta1_stabilization", "fd2d-study", ("fd2d_theta1_stabilization",)),
    Study("fd2d-crosscheck", "fd2d", "crosscheck", "fd2d-study", ("fd2d_crosscheck",)),
    Study("disk-pressure", "fd2d", "pressure_profiles", "fd2d-study"),
    Study("fd-aposteriori", "fd2d", "aposteriori", "fd2d-study", ("fd_aposteriori",)),
    Study("pressure-recovery", "pressure", "recovery_vs_fitted", "pressure-study", ("pressure_recovery",)),
    Study("pressure-gamma0", "pressure", "gamma0_tradeoff", "pressure-study", ("pressure_gamma0",)),
    Study("hard-cases", "hard_cases", "hard_cases", "hard-study", ("hard_cases", "hard_gamma_scaling")),
    Study("hard-conditioning", "hard_cases", "hard_conditioning", "hard-study", ("hard_conditioning",)),
    Study("gates", "gates", "gates", "gates-study", ("gates",)),
    Study("bench-newton", "bench", "newton_grid", "bench", ("bench_newton",)),
    Study("bench", "bench", "bench", "bench", ("bench", "bench_scaling", "bench_targets")),
    Study("bench-overhead", "bench", "overhead", "bench",
          ("bench_overhead", "bench_overhead_targets", "bench_mumps", "bench_first_active_set")),
    Study("bench-ordering", "bench", "ordering", "bench", ("bench_ordering",)),
    Study("bench-solver", "bench", "solver", "bench", ("bench_solver", "bench_solver_budget")),
    Study("bench-3d", "bench", "bench3d", "bench", ("bench_3d", "bench_3d_scaling")),
    Study("bench-3d-large", "bench", "bench3d_large", "bench", ("bench_3d_large",)),
    Study("bench-3d-graded", "bench", "bench3d_graded", "bench", ("bench_3d_graded",)),
    Study("bench-error-tool", "bench", "error_tool_bench", "bench", ("bench_error_tool",)),
    Study("bench-scale", "bench_scale", "bench_scale", "bench",
          ("bench_scale", "bench_scale_targets", "bench_scale_mpi", "bench_scale_large", "bench_scale_model")),
    Study("scenes", "scenes", "scenes", "scenes-study", ("scenes", "hertz")),
    Study("scenes-3d", "scenes", "scenes_3d", "scenes-study", ("scenes_3d",)),
    Study("hertz-3d-settings", "hertz3d", "settings", "hertz-3d-study", ("hertz_spheres_settings",)),
    Study("hertz-3d-coarse", "hertz3d", "coarse", "hertz-3d-study", ("hertz_spheres_coarse",)),
    Study("hertz-3d-recovery", "hertz3d", "recovery", "hertz-3d-study", ("hertz_spheres_recovery",)),
    Study("hertz-3d", "hertz3d", "table", "hertz-3d-study", ("hertz_spheres",)),
    Study("curved-geometry", "curved", "geometry_check", "curved-study", ("curved_geometry", "curved_geometry_3d")),
    Study("curved-convergence", "curved", "convergence", "curved-study", ("curved_convergence", "curved_cost")),
    Study("curved-smooth", "curved", "smooth_problems", "curved-study",
          ("curved_patch", "curved_smooth", "curved_smooth_rates")),
    Study("curved-adaptive", "curved", "adaptive", "curved-study", ("curved_adaptive",)),
    Study("curved-centre-scan", "curved", "centre_scan", "curved-study", ("curved_centre_scan_windows",)),
    Study("fd3d-convergence", "fd3d", "convergence", "fd3d-study", ("fd3d_rates", "fd3d_convergence", "fd3d_cost")),
    Study("ball-on-slab-figure", "fd3d", "vonmises_figure", "fd3d-study"),
    Study("fd3d-adaptive", "fd3d_estimators", "adaptive_study", "fd3d-study", ("fd3d_adaptive",)),
    Study("fd3d-curved-convergence", "fd3d", "curved_convergence", "fd3d-curved-study",
          ("fd3d_curved_rates", "fd3d_curved_convergence")),
    Study("fd3d-curved-smooth", "curved", "smooth_problems_3d", "fd3d-curved-study",
          ("curved_patch_3d", "curved_smooth_3d", "curved_smooth_3d_rates")),
)

# Tables made by something else than a study, by make target: make mutation
# (tests/mutation/run.py) writes results/mutation.csv.
OTHER_TABLES = {"mutation": ("mutation", "mutation_totals")}

REGISTRY = {s.name: s for s in STUDIES}


def groups():
    """group -> its studies' names, in the order they run."""
    out = {}
    for s in STUDIES:
        out.setdefault(s.group, []).append(s.name)
    return out


def tables():
    """Every docs table: marker name -> the make target that writes its results."""
    out = {}
    for group, names in [(s.group, s.tables) for s in STUDIES] + list(OTHER_TABLES.items()):
        for name in names:
            if name in out:
                raise ValueError(f"table {name} is declared by two studies")
            out[name] = group
    return out


def study(name):
    """The function that runs study `name`."""
    s = REGISTRY[name]
    return getattr(importlib.import_module(f".{s.module}", __name__), s.function)
