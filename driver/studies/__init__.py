"""The studies behind the tables and figures of docs/: one registry, name -> function.

`python -m driver study NAME` looks the name up here; each make target names its
studies (Makefile). Modules are imported only when one of their studies runs.
"""

import importlib

# name: (module in driver.studies, function); each function says what it writes
REGISTRY = {
    "foundation-newton": ("foundation", "foundation_newton_table"),
    "square-pressure": ("foundation", "square_pressure_plot"),
    "aposteriori-uniform": ("foundation", "aposteriori_uniform"),
    "aposteriori-adaptive": ("foundation", "aposteriori_adaptive"),
    "square-adapted": ("foundation", "square_adapted_vonmises"),
    "fd2d-convergence": ("fd2d", "convergence"),
    "fd2d-dense-ladder": ("fd2d", "dense_ladder"),
    "fd2d-gamma0": ("fd2d", "gamma0_sweep"),
    "fd2d-stabilization": ("fd2d", "stabilization"),
    "fd2d-theta1-stabilization": ("fd2d", "theta1_stabilization"),
    "fd2d-crosscheck": ("fd2d", "crosscheck"),
    "disk-pressure": ("fd2d", "pressure_profiles"),
    "pressure-recovery": ("pressure", "recovery_vs_fitted"),
    "pressure-gamma0": ("pressure", "gamma0_tradeoff"),
    "fd-aposteriori": ("fd2d", "aposteriori"),
    "fd3d-convergence": ("fd3d", "convergence"),
    "fd3d-curved-convergence": ("fd3d", "curved_convergence"),
    "ball-on-slab-figure": ("fd3d", "vonmises_figure"),
    "fd3d-adaptive": ("fd3d_estimators", "adaptive_study"),
    "hard-cases": ("hard_cases", "hard_cases"),
    "hard-conditioning": ("hard_cases", "hard_conditioning"),
    "gates": ("gates", "gates"),
    "scenes": ("scenes", "scenes"),
    "hertz-3d": ("hertz3d", "table"),
    "hertz-3d-settings": ("hertz3d", "settings"),
    "hertz-3d-recovery": ("hertz3d", "recovery"),
    "hertz-3d-coarse": ("hertz3d", "coarse"),
    "curved-geometry": ("curved", "geometry_check"),
    "curved-convergence": ("curved", "convergence"),
    "curved-smooth": ("curved", "smooth_problems"),
    "curved-adaptive": ("curved", "adaptive"),
    "curved-centre-scan": ("curved", "centre_scan"),
    "fd3d-curved-smooth": ("curved", "smooth_problems_3d"),
    "bench": ("bench", "bench"),
    "bench-newton": ("bench", "newton_grid"),
    "bench-overhead": ("bench", "overhead"),
    "bench-solver": ("bench", "solver"),
    "bench-3d": ("bench", "bench3d"),
    "bench-3d-large": ("bench", "bench3d_large"),
    "bench-3d-graded": ("bench", "bench3d_graded"),
    "bench-ordering": ("bench", "ordering"),
    "bench-error-tool": ("bench", "error_tool_bench"),
    "bench-scale": ("bench_scale", "bench_scale"),
}


def study(name):
    """The function that runs study `name`."""
    module, function = REGISTRY[name]
    return getattr(importlib.import_module(f".{module}", __name__), function)
