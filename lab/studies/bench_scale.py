"""Large 3D solves against d58614e, runs on several processes, and how they would scale
(make bench, study bench-scale). Timing lives here, never in tests.

- results/bench_scale_runs.csv, bench_scale.csv: the ball on slab (P2, h = 1/30), the
  graded sphere on sphere (P2, grade_h = 0.01) and the 2D default scene, by d58614e
  (checked out into a scratch worktree) and the current tree in turn; wall seconds,
  CPU seconds and peak memory of the whole process, and how far the answers differ;
- results/bench_scale_targets.csv: the targets of those runs as ratios to d58614e;
- results/bench_scale_mpi.csv: the ball on slab on one process (sequential build), and on
  one and two MPI processes (the plugin's MPI build), with MUMPS's statistics and the
  bytes the two processes exchanged;
- results/bench_scale_model.csv: flops, memory and communication per process for 4 to 64
  processes from those statistics;
- results/bench_scale_large.csv: the largest 3D P2 run (ball on slab, nx = 41 by default).
"""

import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

from driver.errors import DriverError
from driver.runner import REPO, freefem_binary, freefem_env, parse_json_file
from .bench import (load_average, machine, save_results, stamped, timed_run, user_environment,
                     versions_to_time)
from .common import markdown_table, progress, P1_GEOMETRY_FLAGS

SCALE_BASELINE = "d58614e"   # the version the large-run targets are set against
LARGE_REPEATS = int(os.environ.get("BENCH_SCALE_REPEATS", "3"))   # runs of minutes
SMALL_REPEATS = 5                                                  # runs of seconds
LARGE_NX = int(os.environ.get("BENCH_SCALE_LARGE_NX", "41"))
BALL_LABEL = "3D ball on slab, P2, nx = 30"
SPHERE_LABEL = "3D sphere on sphere, P2, grade_h = 0.01"
DISK_LABEL = "2D default scene (disk on slab), FreeFEM run"
MAKE_CASE_LABEL = "2D default scene, the driver's run (make case)"
# The sphere on sphere of the Hertz runs: F = 1e-4 on body 1 (f = F / volume),
# pinned on its axis, P2 graded to 0.01 within 0.04 of the contact point, on the P1
# cut geometry (P1_GEOMETRY_FLAGS): 122,562 DOFs.
SPHERE_SET = ("method.degree=2 mesh.grade_h=0.01 mesh.grade_radius=0.04 mesh.grade_point=[0,0,0] "
              "body1.body_force=[0,0,-0.0015278874536821952] rigid.fix_xy_points=[0,0,0.1,0,0,0.4] "
              "rigid.fix_y_point=[0.1,0,0.25] solver.allow_unbalanced=true method.geometry=p1")
# label -> (kind, arguments, repeats): "direct" runs FreeFem++ on freefem/..., "driver"
# runs python -m driver run
CASES = {
    BALL_LABEL: ("direct", ["freefem/fd_contact_3d.edp", "-Ddegree=2", "-nx", "30", "-estimators", "0", "-vtu", "0",
                            *P1_GEOMETRY_FLAGS],
                 LARGE_REPEATS),
    SPHERE_LABEL: ("driver", ["cases/sphere_on_sphere.toml", "--set", SPHERE_SET], LARGE_REPEATS),
    DISK_LABEL: ("direct", ["freefem/fd_contact_2d.edp"], SMALL_REPEATS),
    MAKE_CASE_LABEL: ("driver", ["cases/disk_on_slab.toml"], SMALL_REPEATS),
}
# the targets: at most these ratios to d58614e (wall time, peak memory)
TARGETS = {BALL_LABEL: (0.25, 0.5), SPHERE_LABEL: (0.35, 0.5), DISK_LABEL: (1.05, None), MAKE_CASE_LABEL: (1.05, None)}


def command(kind, args, out):
    """The command of one run, writing into folder `out`."""
    if kind == "direct":
        return [freefem_binary(), "-nw", "-v", "0", *args, "-outdir", str(out)]
    return [sys.executable, "-m", "driver", "run", *args, "--out", str(out)]


def answers(folder):
    """The answers compared between versions: the centre probe's displacement, the contact
    force on body 1 and the contact pressure at the points."""
    results = parse_json_file(folder / "results.json")
    pressure = pd.read_csv(folder / "contact_pressure.csv").pressure.to_numpy()
    return dict(centre=np.asarray(results["probes"]["centre"], float),
                force=np.asarray(results["contact"]["force_on_body1"], float), pressure=pressure), results


def relative(a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    if a.shape != b.shape:
        return float("inf")
    return float(np.abs(a - b).max() / np.abs(a).max())


def build_plugins(tree):
    """The FreeFEM plugins of a checked-out version, built by its own Makefile's rule."""
    plugins = [f"freefem/plugins/{source.stem}.so" for source in sorted((tree / "freefem" / "plugins").glob("*.cpp"))]
    proc = subprocess.run(["make", "-s", *plugins], cwd=tree, capture_output=True, text=True)
    if proc.returncode != 0:
        raise DriverError(f"bench-scale: cannot build the plugins of {SCALE_BASELINE}: "
                          f"{(proc.stdout + proc.stderr).strip()[-300:]}")


def version_runs():
    """Every case by both versions, in turn within each repeat."""
    rows = []
    total = sum(2 * repeats for _, _, repeats in CASES.values())
    with versions_to_time("bench-scale-", baseline=SCALE_BASELINE) as (tmp, trees):
        build_plugins(trees["baseline"])
        reference = {}
        for repeat in range(max(repeats for _, _, repeats in CASES.values())):
            for case, (kind, args, repeats) in CASES.items():
                if repeat >= repeats:
                    continue
                for version, tree in (("baseline", trees["baseline"]), ("current", trees["current"])):
                    progress(len(rows) + 1, total, f"{case}, {version}")
                    out = tmp / f"run{len(rows)}"
                    load = load_average()
                    env = freefem_env() if kind == "direct" else user_environment()
                    wall, cpu, rss = timed_run(command(kind, args, out), env, tree, f"bench-scale: {case}, {version}")
                    found, results = answers(out)
                    reference.setdefault(case, found)
                    rows.append(dict(case=case, version=version, repeat=repeat, dofs=results["dofs"],
                                     newton_iterations=results["newton"]["iterations"],
                                     factorizations=results["newton"]["factorizations"],
                                     wall_s=wall, cpu_s=cpu, peak_rss_mb=rss, load_1min_before=load,
                                     **{f"{what}_rel_diff": relative(reference[case][what], found[what])
                                        for what in ("centre", "force", "pressure")}))
                    shutil.rmtree(out)
    return pd.DataFrame(rows)


def version_summary(runs):
    """Medians per case and version, the ratios current / baseline of wall time and peak
    memory pair by pair (their median), and the largest answer differences."""
    rows = []
    for case, group in runs.groupby("case", sort=False):
        base, cur = group[group.version == "baseline"], group[group.version == "current"]
        pairs = cur.set_index("repeat").join(base.set_index("repeat"), rsuffix="_base")
        row = dict(case=case, runs=len(cur), dofs=int(cur.dofs.iloc[0]),
                   baseline_newton=int(base.newton_iterations.iloc[0]),
                   baseline_factorizations=int(base.factorizations.iloc[0]),
                   newton=int(cur.newton_iterations.iloc[0]), factorizations=int(cur.factorizations.iloc[0]),
                   baseline_wall_s=base.wall_s.median(), wall_s=cur.wall_s.median(),
                   wall_ratio=(pairs.wall_s / pairs.wall_s_base).median(),
                   baseline_peak_mb=base.peak_rss_mb.median(), peak_mb=cur.peak_rss_mb.median(),
                   peak_ratio=(pairs.peak_rss_mb / pairs.peak_rss_mb_base).median(),
                   **{f"{what}_rel_diff": group[f"{what}_rel_diff"].max() for what in ("centre", "force", "pressure")})
        rows.append(row)
    return stamped(rows, runs)


def targets_table(summary):
    """Issue 44's targets against the measured ratios."""
    rows = []
    for _, row in summary.iterrows():
        wall_bound, peak_bound = TARGETS[row.case]
        for what, bound, measured in (("wall time", wall_bound, row.wall_ratio), ("peak memory", peak_bound,
                                                                                  row.peak_ratio)):
            if bound is None:
                continue
            rows.append(dict(case=row.case, quantity=what, bound=bound, measured=measured, met=measured <= bound,
                             baseline=row[f"baseline_{'wall_s' if what == 'wall time' else 'peak_mb'}"],
                             current=row["wall_s" if what == "wall time" else "peak_mb"]))
    targets = pd.DataFrame(rows)
    targets["machine"], targets["load_1min"] = summary.machine.iloc[0], summary.load_1min.iloc[0]
    return targets


# ---- several processes: the ball on slab on 1 and 2 processes, MUMPS's statistics ----

MPI_RUNS = {   # label -> mpirun processes (0: FreeFem++, the sequential build)
    "1 process, FreeFem++ (sequential MUMPS)": 0,
    "1 process, FreeFem++-mpi (parallel MUMPS)": 1,
    "2 processes, FreeFem++-mpi (parallel MUMPS)": 2,
}


def loopback_bytes():
    """Bytes received on the loopback interface so far (the processes' TCP traffic)."""
    for line in Path("/proc/net/dev").read_text().splitlines():
        name, _, data = line.partition(":")
        if name.strip() == "lo":
            return int(data.split()[0])
    return 0


def mpi_command(processes, out):
    args = ["freefem/fd_contact_3d.edp", "-Ddegree=2", "-nx", "30", "-estimators", "0", "-vtu", "0", "-csv", "0",
            *P1_GEOMETRY_FLAGS, "-outdir", str(out)]
    if processes == 0:
        return [freefem_binary(), "-nw", "-v", "0", *args]
    # TCP between the processes (not shared memory), so that the loopback counts their bytes
    return [shutil.which("mpirun"), "-np", str(processes), "--oversubscribe", "--mca", "btl", "self,tcp",
            shutil.which("FreeFem++-mpi"), "-nw", "-v", "0", *args]


def mpi_runs():
    rows = []
    total = LARGE_REPEATS * len(MPI_RUNS)
    with tempfile.TemporaryDirectory(prefix="bench-scale-mpi-") as tmp:
        for repeat in range(LARGE_REPEATS):
            for label, processes in MPI_RUNS.items():
                progress(len(rows) + 1, total, label)
                out = Path(tmp) / f"run{len(rows)}"
                load, before = load_average(), loopback_bytes()
                wall, cpu, rss = timed_run(mpi_command(processes, out), freefem_env(mpi=processes > 0), REPO,
                                           f"bench-scale: {label}")
                sent = loopback_bytes() - before
                results = parse_json_file(out / "results.json")
                newton = results["newton"]
                # one process: the process's own peak (timed_run: the largest process mpirun waited for)
                peaks = newton.get("process_peak_mb", [rss])
                rows.append(dict(run=label, processes=max(processes, 1), repeat=repeat, dofs=results["dofs"],
                                 newton_iterations=newton["iterations"], factorizations=newton["factorizations"],
                                 ordering=newton["ordering"], precision=newton["precision"],
                                 factor_operations=newton["factor_operations"], factor_entries=newton["factor_entries"],
                                 factor_memory_mb=newton["factor_memory_mb"],
                                 factor_memory_mb_largest_process=newton["factor_memory_mb_largest_process"],
                                 largest_front=newton["largest_front"], wall_s=wall, cpu_s=cpu,
                                 cpu_newton_factor_solve=results["timings_cpu_s"]["newton_factor_solve"],
                                 cpu_mumps_factorization=results["timings_cpu_s"]["newton_mumps_factorization"],
                                 peak_mb_per_process=json.dumps([round(p, 1) for p in peaks]),
                                 peak_mb_sum=float(sum(peaks)), loopback_bytes=sent if processes > 1 else 0,
                                 centre_uz=results["probes"]["centre"][-1], load_1min_before=load))
                shutil.rmtree(out)
    return pd.DataFrame(rows)


def mpi_summary(runs):
    rows = []
    first = runs.run.iloc[0]
    for label, group in runs.groupby("run", sort=False):
        rows.append(dict(run=label, processes=int(group.processes.iloc[0]), runs=len(group),
                         dofs=int(group.dofs.iloc[0]), ordering=group.ordering.iloc[0],
                         factorizations=int(group.factorizations.iloc[0]),
                         factor_operations=group.factor_operations.iloc[0], factor_entries=group.factor_entries.iloc[0],
                         factor_memory_mb=group.factor_memory_mb.median(),
                         factor_memory_mb_largest_process=group.factor_memory_mb_largest_process.median(),
                         largest_front=int(group.largest_front.iloc[0]), wall_s=group.wall_s.median(),
                         cpu_mumps_factorization=group.cpu_mumps_factorization.median(),
                         peak_mb_per_process=group.peak_mb_per_process.iloc[0], peak_mb_sum=group.peak_mb_sum.median(),
                         loopback_mb_per_factorization=group.loopback_bytes.median() / 1e6
                         / max(int(group.factorizations.iloc[0]), 1),
                         centre_rel_diff=relative(runs[runs.run == first].centre_uz.iloc[:1], group.centre_uz.iloc[:1])))
    summary = stamped(rows, runs)
    summary["wall_ratio"] = summary.wall_s / summary.wall_s.iloc[0]
    return summary


# ---- the model for 4 to 64 processes ----

MODEL_PROCESSES = (1, 2, 4, 8, 16, 32, 64)


def scaling_model(mpi):
    """Per process, for P processes, from the measured runs on 1 and 2 (bench_scale_mpi):

    - operations: MUMPS's elimination operations (RINFOG(3)) over P, the load balance of
      the two-process run (its factorization's CPU on rank 0 against half the
      one-process one) carried over as the share of the operations that does not split;
    - memory: MUMPS's largest process (INFOG(21)) as m_1 (s + (1 - s)/P), s the share
      that does not split, from m_2 / m_1 = (1 + s)/2; rank 0 keeps the script's data
      (its peak minus its MUMPS memory, the one-process run);
    - communication of one factorization: the contribution blocks of the fronts the
      processes share. Nested dissection halves the mesh at each level of the tree; in
      3D a separator at depth l has about F 2^(-2l/3) unknowns (F: the largest front,
      INFOG(11)), and with P = 2^L processes the fronts of the top L levels are shared,
      each sending its contribution block (about its order squared) once: V(P) = c F^2
      sum_(l<L) 2^l 2^(-4l/3) bytes, c from the two-process run's measured traffic.
    """
    one = mpi[mpi.processes == 1].iloc[-1]      # the MPI build on one process
    two = mpi[mpi.processes == 2].iloc[0]
    ops, front = float(one.factor_operations), float(one.largest_front)
    m1, m2 = float(one.factor_memory_mb_largest_process), float(two.factor_memory_mb_largest_process)
    memory_share = min(max(2 * m2 / m1 - 1, 0.), 1.)
    speedup = float(one.cpu_mumps_factorization / two.cpu_mumps_factorization) if two.cpu_mumps_factorization > 0 \
        else float("nan")
    serial_share = min(max(2 / speedup - 1, 0.), 1.) if speedup == speedup else float("nan")
    script_mb = float(json.loads(one.peak_mb_per_process)[0]) - m1
    levels = lambda p: int(round(math.log2(p)))
    shape = lambda p: sum(2 ** l * 2 ** (-4 * l / 3) for l in range(levels(p)))
    measured = float(two.loopback_mb_per_factorization) * 1e6
    c = measured / (front ** 2 * shape(2)) if measured > 0 else float("nan")
    rows = []
    for p in MODEL_PROCESSES:
        rows.append(dict(processes=p, operations_per_process=ops * (serial_share + (1 - serial_share) / p),
                         factorization_speedup=1 / (serial_share + (1 - serial_share) / p),
                         mumps_memory_mb_per_process=m1 * (memory_share + (1 - memory_share) / p),
                         rank0_memory_mb=script_mb + m1 * (memory_share + (1 - memory_share) / p),
                         communication_mb_per_factorization=c * front ** 2 * shape(p) / 1e6,
                         serial_share=serial_share, memory_share=memory_share, bytes_per_entry=c))
    return pd.DataFrame(rows)


# ---- the largest run: the ball on slab, P2, nx = LARGE_NX ----

def large_run():
    with tempfile.TemporaryDirectory(prefix="bench-scale-large-") as tmp:
        out = Path(tmp) / "run"
        args = ["freefem/fd_contact_3d.edp", "-Ddegree=2", "-nx", str(LARGE_NX), "-estimators", "0", "-vtu", "0",
                "-csv", "0", *P1_GEOMETRY_FLAGS]
        progress(1, 1, f"3D ball on slab, P2, nx = {LARGE_NX}")
        load = load_average()
        wall, cpu, rss = timed_run(command("direct", args, out), freefem_env(), REPO, "bench-scale: the largest run")
        results = parse_json_file(out / "results.json")
    newton, timings = results["newton"], results["timings_cpu_s"]
    row = dict(nx=LARGE_NX, dofs=results["dofs"], newton_iterations=newton["iterations"],
               factorizations=newton["factorizations"], precision=newton["precision"],
               factors_out_of_core=newton["factors_out_of_core"], factor_operations=newton["factor_operations"],
               factor_entries=newton["factor_entries"], factor_memory_mb=newton["factor_memory_mb"], wall_s=wall,
               cpu_s=cpu, peak_rss_mb=rss, load_1min_before=load,
               **{f"cpu_{k}": timings[k] for k in ("geometry", "assembly", "newton", "newton_mumps_factorization",
                                                   "output")})
    return stamped([row], pd.DataFrame([row]))


def bench_scale():
    """make bench: the large 3D runs: against d58614e, on several processes, the largest,
    and the scaling model."""
    runs = save_results(bench_scale_runs=version_runs())
    summary = save_results(bench_scale=version_summary(runs))
    targets = save_results(bench_scale_targets=targets_table(summary))
    mpi = save_results(bench_scale_mpi=mpi_summary(save_results(bench_scale_mpi_runs=mpi_runs())))
    save_results(bench_scale_model=scaling_model(mpi))
    save_results(bench_scale_large=large_run())
    print(markdown_table(targets.drop(columns=["machine", "load_1min"]), digits=3))
    return targets


def scale_table(summary):
    columns = {"case": "case", "dofs": "DOFs", "baseline_newton": "Newton (d58614e)",
               "baseline_factorizations": "factorizations (d58614e)", "newton": "Newton", "factorizations":
               "factorizations", "baseline_wall_s": "wall s (d58614e)", "wall_s": "wall s", "wall_ratio": "wall ratio",
               "baseline_peak_mb": "peak MB (d58614e)", "peak_mb": "peak MB", "peak_ratio": "peak ratio",
               "centre_rel_diff": "centre diff", "force_rel_diff": "force diff", "pressure_rel_diff": "pressure diff"}
    return summary[list(columns)].rename(columns=columns)


def scale_targets_table(targets):
    columns = {"case": "case", "quantity": "quantity", "bound": "at most", "measured": "current / d58614e",
               "baseline": "d58614e", "current": "current", "met": "met"}
    return targets[list(columns)].rename(columns=columns)


def scale_mpi_table(mpi):
    columns = {"run": "run", "dofs": "DOFs", "ordering": "ordering", "factorizations": "factorizations",
               "factor_operations": "operations", "factor_entries": "factor entries", "largest_front": "largest front",
               "factor_memory_mb": "MUMPS MB (all)", "factor_memory_mb_largest_process": "MUMPS MB (largest process)",
               "peak_mb_per_process": "peak MB per process", "peak_mb_sum": "peak MB (sum)", "wall_s": "wall s",
               "wall_ratio": "wall / first", "cpu_mumps_factorization": "factorization CPU s (rank 0)",
               "loopback_mb_per_factorization": "MB exchanged per factorization", "centre_rel_diff": "centre diff"}
    return mpi[list(columns)].rename(columns=columns)


def scale_large_table(large):
    columns = {"nx": "nx", "dofs": "DOFs", "newton_iterations": "Newton", "factorizations": "factorizations",
               "precision": "precision", "factors_out_of_core": "factors in files", "factor_operations": "operations",
               "factor_entries": "factor entries", "wall_s": "wall s", "cpu_s": "CPU s", "peak_rss_mb": "peak MB",
               "cpu_geometry": "geometry s", "cpu_assembly": "assembly s", "cpu_newton": "Newton s",
               "cpu_newton_mumps_factorization": "factorization s"}
    return large[list(columns)].rename(columns=columns)
