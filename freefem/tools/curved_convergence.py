"""Disk on slab, P2, theta = -1, gamma0 = 1/200 (the solver's defaults): the disk-centre
displacement with the P1 and the curved cut geometry (-geometry p1|curved) against a
reference P2 NX = 320 run with the curved geometry, and the cost of the NX = 80 run.

Runs FreeFEM directly, one job at a time, from the repository root:
    python3 freefem/tools/curved_convergence.py [--nxs 40 80 160] [--ref-nx 320]
        [--repeats 3] [--out results/curved_convergence.csv]
Writes one row per (geometry, nx): centre u_y, its relative error against the
reference, the rate between successive meshes, the area error of the disk, the
relative L2 and H1 errors of both bodies (freefem/tools/fd_error_2d.edp, which
integrates on the reference's P1 cut geometry), DOFs, Newton iterations and CPU time; and results/curved_cost.csv: the NX = 80 run (with
estimators, as `make case`) repeated, minimum CPU of all steps per geometry.
Run folders go to runs/curved_convergence/ (not committed).
"""
import argparse
import csv
import json
import math
import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def run(nx, geometry, folder, *extra, reuse=False):
    """One run; reuse=True keeps an existing result (the reference)."""
    out = REPO / "runs" / "curved_convergence" / folder
    if not (reuse and (out / "results.json").exists()):
        cmd = ["FreeFem++", "-nw", "-v", "0", "freefem/fd_contact_2d.edp", "-nx", str(nx),
               "-geometry", geometry, "-outdir", str(out), *map(str, extra)]
        proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True)
        if proc.returncode != 0 or not (out / "results.json").exists():
            raise SystemExit(f"failed: {' '.join(cmd)}\n{proc.stdout[-2000:]}\n{proc.stderr[-2000:]}")
    return json.loads((out / "results.json").read_text())


def errors(ref_folder, run_folder):
    """fd_error_2d.edp of a saved run against the saved reference: relative L2/H1 per body."""
    base = REPO / "runs" / "curved_convergence"
    out = base / f"errors_{run_folder}.json"
    cmd = ["FreeFem++", "-nw", "-v", "0", "freefem/tools/fd_error_2d.edp", "-ref", str(base / ref_folder),
           "-run", str(base / run_folder), "-out", str(out)]
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True)
    if proc.returncode != 0 or not out.exists():
        raise SystemExit(f"failed: {' '.join(cmd)}\n{proc.stdout[-2000:]}\n{proc.stderr[-2000:]}")
    return json.loads(out.read_text())


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--nxs", type=int, nargs="+", default=[40, 80, 160])
    ap.add_argument("--ref-nx", type=int, default=320)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default="results/curved_convergence.csv")
    ap.add_argument("--cost-out", default="results/curved_cost.csv")
    args = ap.parse_args()

    ref_folder = f"ref_curved_{args.ref_nx}"
    ref = run(args.ref_nx, "curved", ref_folder, "-estimators", 0, "-vtu", 0, "-csv", 0, "-save", 1, reuse=True)
    uref = ref["probes"]["centre"][1]
    rows = []
    for geometry in ["p1", "curved"]:
        prev = None
        for nx in args.nxs:
            folder = f"{geometry}_{nx}"
            r = run(nx, geometry, folder, "-estimators", 0, "-vtu", 0, "-csv", 0, "-save", 1)
            e = errors(ref_folder, folder)
            u = r["probes"]["centre"][1]
            err = abs(u - uref) / abs(uref)
            rate = math.log(prev[1] / err) / math.log(nx / prev[0]) if prev else float("nan")
            area = r["areas"]
            rows.append({"geometry": geometry, "nx": nx, "centre_uy": f"{u:.12e}",
                         "reference_uy": f"{uref:.12e}", "centre_rel_err": f"{err:.4e}",
                         "rate": "" if prev is None else f"{rate:.2f}",
                         "disk_area_rel_err": f"{(area['body1'] - area['body1_exact']) / area['body1_exact']:.3e}",
                         **{k: f"{e[k]:.3e}" for k in ["l2_body1", "l2_body2", "h1_body1", "h1_body2"]},
                         "dofs": r["dofs"], "newton_iterations": r["newton"]["iterations"],
                         "cpu_all_steps_s": f"{r['timings_cpu_s']['all_steps']:.3f}"})
            prev = (nx, err)
            print(rows[-1])
    with open(REPO / args.out, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)

    cost = []
    for geometry in ["p1", "curved"]:
        best = None
        for i in range(args.repeats):
            t = run(80, geometry, f"cost_{geometry}_80_{i}", "-estimators", 1)["timings_cpu_s"]
            best = t if best is None or t["all_steps"] < best["all_steps"] else best
        cost.append({"geometry": geometry, "nx": 80, "repeats": args.repeats,
                     **{f"cpu_{k}_s": f"{best[k]:.3f}" for k in ["geometry", "assembly", "newton", "estimators", "all_steps"]}})
    base = float(cost[0]["cpu_all_steps_s"])
    for c in cost:
        c["relative_to_p1"] = f"{float(c['cpu_all_steps_s']) / base:.3f}"
    print(cost)
    with open(REPO / args.cost_out, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(cost[0]))
        w.writeheader()
        w.writerows(cost)


if __name__ == "__main__":
    main()
