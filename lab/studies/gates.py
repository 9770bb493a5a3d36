"""The gates of the two-body solvers against every shipped scene (make gates-study):
results/gates.csv, one row per scene of cases/, cases/hard/ and cases/verification/
run by fd_contact_2d or fd_contact_3d as a user runs it, with what the plausibility
and balance gates measure (freefem/lib/core/gates.idp). The tolerances there are
chosen against these figures (docs/reliability.md).

Each scene runs with both allow flags set, so that a scene the gates would refuse
still reports its figures; the columns implausible and unbalanced say whether the
gates flagged it. The hard cases that must fail (a floating body, theta = 1 beyond
coercivity) fail before the gates and are listed with their status."""

from pathlib import Path

import pandas as pd

from driver.runner import REPO
from driver.scene import load_scene
from driver.sweep import run_point
from .common import RESULTS_DIR, progress

KEEP = ["solver.allow_implausible=true", "solver.allow_unbalanced=true"]


def shipped_scenes():
    """The scene files of the two-body scripts, relative to the repository."""
    files = sorted((REPO / "cases").glob("*.toml")) + sorted((REPO / "cases" / "hard").glob("*.toml")) \
        + sorted((REPO / "cases" / "verification").glob("*.toml"))
    return [str(Path(f).relative_to(REPO)) for f in files
            if load_scene(str(f), [])[0]["scene"]["script"] in ("fd_contact_2d", "fd_contact_3d")]


def gates():
    rows = []
    cases = shipped_scenes()
    for i, case in enumerate(cases, start=1):
        progress(i, len(cases), case)
        row, results, _ = run_point(case, KEEP)
        if results is not None:
            plaus, balance = results["plausibility"], results["balance"]
            row.update(dim=results["dim"], floating_body1=results["supports"]["floating_body1"],
                       floating_body2=results["supports"]["floating_body2"],
                       size_body1=plaus["size_body1"], size_body2=plaus["size_body2"],
                       penetration_ratio=plaus["penetration_ratio"],
                       drift_ratio_body1=plaus["drift_ratio_body1"], drift_ratio_body2=plaus["drift_ratio_body2"],
                       implausible=plaus["implausible"],
                       pins_share=balance["pins_share"], mass_share=balance["mass_share"],
                       balance_error=balance["balance_error"], sideways_share=balance["sideways_share"],
                       roundoff_share=balance["roundoff_share"], unbalanced=balance["unbalanced"])
        rows.append(row)
    RESULTS_DIR.mkdir(exist_ok=True)
    pd.DataFrame(rows).to_csv(RESULTS_DIR / "gates.csv", index=False)
    print(f"wrote {RESULTS_DIR / 'gates.csv'}")
