"""The shipped scenes of the 2D solver run as a user would (make scenes-study):
results/scenes.csv (one row per scene: DOFs, Newton iterations, contact force,
balance, wall time) and results/hertz.csv (the Hertz scene against Hertz's
half-width, total force and pressure profile)."""

import math

import numpy as np
import pandas as pd

from driver.errors import DriverError
from driver.sweep import run_point
from .common import RESULTS_DIR, hertz_radius_and_modulus, progress, weighted_relative_l2

# The shipped 3D scenes: the load is the body force times the discrete body's volume,
# so its error against the exact volume's load is the volume's (results/scenes_3d.csv).
SCENES_3D = ["cases/ball_on_slab.toml", "cases/rounded_cube_on_slab.toml", "cases/sphere_on_sphere.toml",
             "cases/hertz_spheres.toml", "cases/verification/clamped_ball.toml",
             "cases/verification/held_shell.toml", "cases/torus_on_slab.toml"]
SCENES = ["cases/disk_on_slab.toml", "cases/disk_on_tilted_slab.toml", "cases/hertz_cylinders.toml",
          "cases/punch.toml", "cases/ellipse_on_arch.toml", "cases/ring_on_slab.toml", "cases/cam_on_slab.toml"]

# cases/hertz_cylinders.toml: R1 = 0.25 on R2 = 0.75, E = 1, nu = 0.3, total load P
HERTZ_P, HERTZ_R1, HERTZ_R2, HERTZ_E, HERTZ_NU = 0.001, 0.25, 0.75, 1.0, 0.3


def hertz_solution():
    radius, e_star = hertz_radius_and_modulus(HERTZ_R1, HERTZ_R2, HERTZ_E, HERTZ_NU)
    a = math.sqrt(4 * HERTZ_P * radius / (math.pi * e_star))
    return a, 2 * HERTZ_P / (math.pi * a)


def hertz_row(results, folder):
    """Half-width (half the extent of the active points), total force, the relative L2
    difference of the raw and the recovered pressure from Hertz's over the zone |x| < a and
    the recovered peak against p0."""
    a, p0 = hertz_solution()
    x0, x1 = results["contact"]["active_extent"]["x"]
    s = pd.read_csv(folder / "contact_pressure.csv")
    zone = s[(s.x.abs() < a) & (s.y < 0.05)]
    exact = p0 * np.sqrt(1 - zone.x ** 2 / a ** 2)

    return dict(a_hertz=a, half_width=(x1 - x0) / 2, half_width_error=abs((x1 - x0) / 2 - a) / a,
                force=results["contact"]["force_on_body1"][1], force_error=abs(results["contact"]["force_on_body1"][1]
                                                                            - HERTZ_P),
                p0_hertz=p0, pressure_l2_error=weighted_relative_l2(zone.weight, zone.pressure, exact),
                recovered_l2_error=weighted_relative_l2(zone.weight, zone.pressure_recovered, exact),
                peak_recovered_error=results["contact"]["max_pressure_recovered"] / p0 - 1)


def scenes():
    rows, hertz = [], []
    for i, case in enumerate(SCENES, start=1):
        progress(i, len(SCENES), case)
        row, results, folder = run_point(case, [])
        if results is None:
            raise DriverError(f"{case} failed: {row['message']}")
        row.update(force_y=results["contact"]["force_on_body1"][1],
                   balance_error=results["balance"]["balance_error"],
                   area_body1=results["measures"]["body1"], area_body1_exact=results["measures"].get("body1_exact"))
        rows.append(row)
        if case.endswith("hertz_cylinders.toml"):
            hertz.append(dict(hertz_row(results, folder), dofs=results["dofs"], wall_s=row["wall_s"],
                              adapt_steps=len(results["steps"]["dofs"]) - 1))
    RESULTS_DIR.mkdir(exist_ok=True)
    pd.DataFrame(rows).to_csv(RESULTS_DIR / "scenes.csv", index=False)
    pd.DataFrame(hertz).to_csv(RESULTS_DIR / "hertz.csv", index=False)
    print(f"wrote {RESULTS_DIR / 'scenes.csv'} and {RESULTS_DIR / 'hertz.csv'}")


def relative_error(value, exact):
    return None if exact is None else value / exact - 1


def scenes_3d():
    """Each shipped 3D scene as it stands: its cut geometry, the bodies' volume errors
    against the exact volumes (null where the shape has no formula), the contact force
    balance and the cost: results/scenes_3d.csv."""
    rows = []
    for i, case in enumerate(SCENES_3D, start=1):
        progress(i, len(SCENES_3D), case)
        row, results, _ = run_point(case, ["output.vtu=false"])
        if results is None:
            raise DriverError(f"{case} failed: {row['message']}")
        m = results["measures"]
        row.update(geometry=results["cut"]["geometry"], degree=results["degree"],
                   volume_error_body1=relative_error(m["body1"], m.get("body1_exact")),
                   volume_error_body2=relative_error(m["body2"], m.get("body2_exact")),
                   applied_load_body1=results["contact"]["applied_force_body1"][2],
                   force_balance_error=results["contact"]["force_balance_error"])
        rows.append(row)
    RESULTS_DIR.mkdir(exist_ok=True)
    pd.DataFrame(rows).to_csv(RESULTS_DIR / "scenes_3d.csv", index=False)
    print(f"wrote {RESULTS_DIR / 'scenes_3d.csv'}")
