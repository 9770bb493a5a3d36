"""Hertz's sphere on sphere in 3D (cases/hertz_spheres.toml) against Hertz's solution.

FreeFEM computes the contact state at the contact points (contact_pressure.csv:
weight, raw multiplier, recovered pressure, active flag; results.json: the contact
force, the active area, the recovered pressure's integral); this module runs the scene
under the settings compared, reads those and compares with Hertz:
a = (3 F R/(4 E*))^(1/3), p0 = 3 F/(2 pi a^2), p(r) = p0 sqrt(1 - r^2/a^2), r the distance
from the axis through the first contact point (the origin).

Studies: hertz-3d (the scene as shipped, P2 and P1, against Hertz: results/hertz_spheres.csv,
the README table), hertz-3d-settings (gamma0, stabilization, contact points, cut geometry,
grading passes on the scene's mesh: results/hertz_spheres_settings.csv), hertz-3d-recovery
(the recovery's window, degree and zone on the shipped run's points, refitted by
freefem/tools/pressure_recovery_refit.edp: results/hertz_spheres_recovery.csv).
"""

import math
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

from driver.errors import DriverError
from driver.runner import REPO, run_freefem_tool
from driver.sweep import run_point
from .common import RESULTS_DIR, hertz_radius_and_modulus, markdown_table, progress, weighted_relative_l2

SPHERES = REPO / "cases" / "hertz_spheres.toml"
# the scene's data (cases/hertz_spheres.toml states them)
F, R1, R2, E, NU = 1e-4, 0.25, 0.75, 1.0, 0.3
# ball 1 touches the box top, so the driver gives no exact volume (measures.body1_exact: a
# shape is known unclipped only strictly inside the box)
BALL1_VOLUME = 4 / 3 * math.pi * R1 ** 3
LOWER_HALF = 0.05      # contact points below this height: the lower side of ball 1
SECTORS = 16           # angular sectors of the contact radius
# What P1 needs: its multiplier is a stress of piecewise constant gradients, so it
# takes a finer mesh than P2 for the same zone (the P1 rows of the table).
P1_MESH = ["method.degree=1", "mesh.grade_h=0.004"]
# The 3D defaults (gamma0 = 1/200, no stabilization for theta = -1, the curved cut
# geometry, one grading pass) on the scene's mesh: what a scene without the study's
# settings gets.
THREE_D_DEFAULTS = ["method.gamma0=0.005", "method.stabilization='none'", "method.geometry='curved'",
                    "mesh.grade_passes=1"]


def hertz_solution():
    """(a, p0) of Hertz's sphere on sphere."""
    radius, e_star = hertz_radius_and_modulus(R1, R2, E, NU)
    a = (3 * F * radius / (4 * e_star)) ** (1 / 3)
    return a, 3 * F / (2 * math.pi * a ** 2)


def hertz_pressure(r):
    a, p0 = hertz_solution()
    return p0 * np.sqrt(np.clip(1 - (np.asarray(r) / a) ** 2, 0, None))


def lower_points(folder):
    frame = pd.read_csv(Path(folder) / "contact_pressure.csv")
    return frame[frame.z < LOWER_HALF].reset_index(drop=True)


def contact_radius(points):
    """The radius of the active points: the mean over 16 angular sectors of the largest
    distance from the axis of an active point in the sector (the zone's edge, not pulled
    by one stray point)."""
    active = points[points.active > 0.5]
    if active.empty:
        return 0.0
    angle = np.arctan2(active.y, active.x)
    sector = np.floor((angle + math.pi) / (2 * math.pi) * SECTORS).astype(int).clip(0, SECTORS - 1)
    r = np.hypot(active.x, active.y)
    return float(r.groupby(sector).max().mean())


def profile_error(points, pressure):
    """Relative L2 difference of a pressure (one value per point) from Hertz's over the zone
    r < a (the contact points' quadrature weights)."""
    a, _ = hertz_solution()
    r = np.hypot(points.x, points.y).to_numpy()
    zone = r < a
    return weighted_relative_l2(points.weight.to_numpy()[zone], np.asarray(pressure)[zone], hertz_pressure(r[zone]))


def badly_cut_error(points, cut_below=0.05):
    """RMS of the raw multiplier's difference from Hertz, relative to p0, at the zone's points
    whose element is cut below cut_below (its part in ball 1 over its volume), and their share
    of the zone's weight: where the multiplier reads a poorly determined stress."""
    a, p0 = hertz_solution()
    r = np.hypot(points.x, points.y).to_numpy()
    zone = r < a
    bad = zone & (points.cut_ratio.to_numpy() < cut_below)
    w = points.weight.to_numpy()
    if not bad.any():
        return 0.0, 0.0
    dev = (points.pressure.to_numpy() - hertz_pressure(r)) / p0
    return float(np.sqrt(np.sum((w * dev ** 2)[bad]) / np.sum(w[bad]))), float(np.sum(w[bad]) / np.sum(w[zone]))


def outside_share(points, pressure):
    """The recovered pressure's integral beyond r = 1.1 a, relative to the raw one's over
    all points: what a recovery spreads past the zone's edge."""
    a, _ = hertz_solution()
    r = np.hypot(points.x, points.y).to_numpy()
    w = points.weight.to_numpy()
    return float(np.sum((w * np.asarray(pressure))[r > 1.1 * a]) / np.sum(w * points.pressure.to_numpy()))


def hertz_row(results, folder):
    """The Hertz figures of one run (relative errors, signed where the sign says something)."""
    a, p0 = hertz_solution()
    points = lower_points(folder)
    contact = results["contact"]
    force = contact["force_on_body1"][2]
    radius = contact_radius(points)
    bad_rms, bad_share = badly_cut_error(points)
    return dict(
        a_hertz=a, p0_hertz=p0, contact_radius=radius, radius_error=radius / a - 1,
        peak_recovered=contact["max_pressure_recovered"], peak_error=contact["max_pressure_recovered"] / p0 - 1,
        recovered_l2=profile_error(points, points.pressure_recovered), raw_l2=profile_error(points, points.pressure),
        raw_rms_badly_cut=bad_rms, badly_cut_share=bad_share,
        recovered_outside=outside_share(points, points.pressure_recovered),
        recovered_integral_ratio=results["pressure_recovery"]["integral_ratio"],
        force_error=force / F - 1, volume_error=results["measures"]["body1"] / BALL1_VOLUME - 1,
        active_area_ratio=contact["active_measure"] / (math.pi * a ** 2),
        zone_elements=contact["zone_elements"], sideways_pins_share=results["balance"]["pins_share"],
        dofs=results["dofs"], newton_iterations=results["newton"]["iterations"],
        wall_s=results["wall_s"], peak_rss_mb=results["peak_rss_mb"])


def run_row(label, overrides):
    row, results, folder = run_point(SPHERES, overrides)
    if results is None:
        raise DriverError(f"hertz spheres ({label}) failed: {row['message']}")
    return dict(run=label, overrides=" ".join(overrides), degree=results["degree"], gamma0=results["gamma0"],
                stabilization=results["cut"]["stabilization"], geometry=results["cut"]["geometry"],
                contact_points=results["contact_points"], grade_h=results["grade_h"],
                grade_passes=results["grade_passes"], **hertz_row(results, folder)), folder


def run_rows(runs, title):
    rows = []
    for i, (label, overrides) in enumerate(runs, start=1):
        progress(i, len(runs), f"{title}: {label}")
        rows.append(run_row(label, overrides)[0])
    return pd.DataFrame(rows)


# ---- hertz-3d: the table of the README ----
TABLE_RUNS = [
    ("P2, as shipped", []),
    ("P2, grade_h 0.015", ["mesh.grade_h=0.015"]),
    ("P2, grade_h 0.008", ["mesh.grade_h=0.008"]),
    ("P2, grade_h 0.02 and one estimator-driven step", ["mesh.grade_h=0.02", "adapt.steps=1"]),
    ("P1, grade_h 0.004", P1_MESH),
    ("P1, grade_h 0.003", ["method.degree=1", "mesh.grade_h=0.003"]),
    ("P2, the 3D defaults", THREE_D_DEFAULTS),
]


def table():
    """The scene as shipped (P2) and its neighbours in cost, P1 at the mesh it needs, and the
    3D defaults: results/hertz_spheres.csv."""
    frame = run_rows(TABLE_RUNS, "hertz spheres")
    RESULTS_DIR.mkdir(exist_ok=True)
    frame.to_csv(RESULTS_DIR / "hertz_spheres.csv", index=False)
    print(f"wrote {RESULTS_DIR / 'hertz_spheres.csv'}")


def percent(value, digits=1):
    return f"{100 * value:+.{digits}f} %"


def hertz_table(frame):
    """The README table: each run against Hertz's a and p0 and the targets."""
    rows = [{"run": t.run, "DOFs": int(t.dofs), "Newton": int(t.newton_iterations),
             "contact radius": percent(t.radius_error), "peak recovered": percent(t.peak_error),
             "recovered L2": f"{100 * t.recovered_l2:.1f} %", "raw L2": f"{100 * t.raw_l2:.1f} %",
             "force - F": f"{t.force_error:.1e}", "active area / pi a^2": f"{t.active_area_ratio:.3f}",
             "recovered integral / force": f"{t.recovered_integral_ratio:.4f}",
             "wall": f"{t.wall_s:.0f} s", "peak RSS": f"{t.peak_rss_mb / 1024:.1f} GiB"}
            for t in frame.itertuples()]
    return markdown_table(pd.DataFrame(rows))


# ---- hertz-3d-settings: what suits 3D ----
def method(gamma0, stabilization="neighbour", geometry="curved"):
    return [f"method.gamma0={gamma0}", f"method.stabilization='{stabilization}'", f"method.geometry='{geometry}'"]


SETTINGS_RUNS = [
    *[(f"P2, gamma0 {g}, neighbour", method(g)) for g in ("0.005", "0.05", "0.1", "0.2", "0.5", "1.0")],
    ("P2, gamma0 0.2, no stabilization", method("0.2", "none")),
    ("P2, gamma0 0.2, neighbour, 3 contact points", [*method("0.2"), "solver.contact_points=3"]),
    ("P2, gamma0 0.2, neighbour, p1 geometry", method("0.2", geometry="p1")),
    ("P2, gamma0 0.2, neighbour, one grading pass", [*method("0.2"), "mesh.grade_passes=1"]),
    *[(f"P1, gamma0 {g}, neighbour", [*P1_MESH, *method(g)]) for g in ("0.005", "0.2", "1.0")],
    ("P1, gamma0 0.2, no stabilization", [*P1_MESH, *method("0.2", "none")]),
]


def settings():
    """gamma0, stabilization, contact points, cut geometry and grading passes on the scene's mesh
    (P2) and on P1's: results/hertz_spheres_settings.csv."""
    frame = run_rows(SETTINGS_RUNS, "hertz spheres settings")
    RESULTS_DIR.mkdir(exist_ok=True)
    frame.to_csv(RESULTS_DIR / "hertz_spheres_settings.csv", index=False)
    print(f"wrote {RESULTS_DIR / 'hertz_spheres_settings.csv'}")


def settings_table(frame):
    rows = [{"run": t.run, "raw L2": f"{100 * t.raw_l2:.1f} %", "recovered L2": f"{100 * t.recovered_l2:.1f} %",
             "contact radius": percent(t.radius_error), "peak recovered": percent(t.peak_error),
             "active area / pi a^2": f"{t.active_area_ratio:.3f}", "force - F": f"{t.force_error:.1e}",
             "raw at cuts < 5 % (RMS / p0)": f"{100 * t.raw_rms_badly_cut:.0f} %",
             "zone elements": f"{t.zone_elements:.2f}", "DOFs": int(t.dofs), "Newton": int(t.newton_iterations),
             "wall": f"{t.wall_s:.0f} s"} for t in frame.itertuples()]
    return markdown_table(pd.DataFrame(rows))


# ---- hertz-3d-recovery: the recovery's window, degree and zone ----
WINDOWS = (0.35, 0.5, 0.7, 1.0)


def refit(points, window, degree, active_only, workdir):
    """The recovered pressure at the points under other options, by FreeFEM's recovery."""
    data = workdir / "points.txt"
    columns = points[["x", "y", "z", "normal_x", "normal_y", "normal_z", "weight", "pressure", "element_h"]]
    with open(data, "w") as out:
        out.write(f"{len(points)}\n")
        np.savetxt(out, columns.to_numpy(), fmt="%.17g")
    result = run_freefem_tool("pressure_recovery_refit.edp",
                              ["-points", str(data), "-out", str(workdir / "refit.json"), "-window", repr(window),
                               "-degree", str(degree), "-active_only", str(active_only)],
                              workdir / "refit.json", "the pressure recovery's refit")
    return np.array(result["pressure_recovered"])


def recovery():
    """The shipped P2 run's raw multiplier recovered with windows 0.35 .. 1 h_K, planes and
    quadratics, over all points or the active ones: results/hertz_spheres_recovery.csv."""
    _, p0 = hertz_solution()
    progress(1, 1, "hertz spheres as shipped: the recovery's options")
    shipped, folder = run_row("P2, as shipped", [])
    points = pd.read_csv(Path(folder) / "contact_pressure.csv")
    lower = (points.z < LOWER_HALF).to_numpy()
    rows = [dict(window_h="raw", degree="", active_only="", recovered_l2=shipped["raw_l2"],
                 peak_error=points.pressure.max() / p0 - 1, integral_ratio=1.0,
                 outside=0.0, zone_elements=shipped["zone_elements"])]
    with tempfile.TemporaryDirectory(prefix="fdcontact-refit-") as tmp:
        for window in WINDOWS:
            for degree in (1, 2):
                for active_only in (0, 1):
                    rec = refit(points, window, degree, active_only, Path(tmp))
                    low = points[lower].reset_index(drop=True)
                    rows.append(dict(window_h=window, degree=degree, active_only=active_only,
                                     recovered_l2=profile_error(low, rec[lower]), peak_error=rec.max() / p0 - 1,
                                     integral_ratio=float(np.sum(points.weight * rec) / np.sum(points.weight
                                                                                               * points.pressure)),
                                     outside=outside_share(low, rec[lower]), zone_elements=shipped["zone_elements"]))
    frame = pd.DataFrame(rows)
    RESULTS_DIR.mkdir(exist_ok=True)
    frame.to_csv(RESULTS_DIR / "hertz_spheres_recovery.csv", index=False)
    print(f"wrote {RESULTS_DIR / 'hertz_spheres_recovery.csv'}")


def recovery_table(frame):
    rows = [{"window (h_K)": t.window_h, "fit": {1: "plane", 2: "quadratic"}.get(t.degree, ""),
             "inactive points": {0: "fitted", 1: "0"}.get(t.active_only, ""),
             "recovered L2": f"{100 * t.recovered_l2:.1f} %", "peak": percent(t.peak_error),
             "integral / raw": f"{t.integral_ratio:.4f}", "beyond 1.1 a": f"{100 * t.outside:.2f} %"}
            for t in frame.itertuples()]
    return markdown_table(pd.DataFrame(rows))


# ---- hertz-3d-coarse: why gamma0 = 0.2 is the scene's setting, not the 3D default ----
BALL_ON_SLAB = REPO / "cases" / "ball_on_slab.toml"
COARSE_NX = (4, 8, 10, 16)
COARSE_GAMMA0 = ("0.005", "0.2")


def coarse():
    """The ball on slab (P1, theta = -1) at coarse meshes with gamma0 = 1/200 and 0.2, kept
    with solver.allow_implausible: the bodies' overlap against the gate's tolerance and the
    contact zone's resolution: results/hertz_spheres_coarse.csv."""
    runs = [(nx, g) for g in COARSE_GAMMA0 for nx in COARSE_NX]
    rows = []
    for i, (nx, gamma0) in enumerate(runs, start=1):
        progress(i, len(runs), f"ball on slab nx {nx}, gamma0 {gamma0}")
        overrides = [f"mesh.nx={nx}", f"method.gamma0={gamma0}", "solver.allow_implausible=true", "output.vtu=false"]
        row, results, _ = run_point(BALL_ON_SLAB, overrides)
        if results is None:
            raise DriverError(f"ball on slab ({' '.join(overrides)}) failed: {row['message']}")
        p, c = results["plausibility"], results["contact"]
        rows.append(dict(nx=nx, gamma0=float(gamma0), overlap_ratio=p["penetration_ratio"],
                         overlap_tolerance=p["penetration_tolerance"], refused_without_allow=p["implausible"],
                         zone_elements=c["zone_elements"], active_measure=c["active_measure"],
                         newton_iterations=results["newton"]["iterations"]))
    frame = pd.DataFrame(rows)
    RESULTS_DIR.mkdir(exist_ok=True)
    frame.to_csv(RESULTS_DIR / "hertz_spheres_coarse.csv", index=False)
    print(f"wrote {RESULTS_DIR / 'hertz_spheres_coarse.csv'}")


def coarse_table(frame):
    rows = [{"nx": int(t.nx), "gamma0": f"{t.gamma0:g}", "overlap / body size": f"{t.overlap_ratio:.4f}",
             "gate (tolerance 0.05)": "refused" if t.refused_without_allow else "passes",
             "zone elements": f"{t.zone_elements:.2f}", "Newton": int(t.newton_iterations)}
            for t in frame.itertuples()]
    return markdown_table(pd.DataFrame(rows))
