"""The Newton's MUMPS plugin (freefem/plugins/contact_mumps.cpp): answers, analysis
kept while the pattern stays, the low-rank correction of the factors, MUMPS's error
codes reaching the script, and the
solver options on whole runs of the disk on slab (P2, NX = 80, a few seconds each)."""

import json
import re

import numpy as np
import pandas as pd
import pytest

from conftest import relative_max_error, run_freefem

pytestmark = pytest.mark.freefem      # every test here starts FreeFEM (make test-fast leaves them out)


def relative(reference, value):
    """The largest difference from the reference, relative to its largest magnitude."""
    return relative_max_error(np.asarray(value, float), np.asarray(reference, float))


# A P2 convection-diffusion system on the unit square (non-symmetric), for the checks below.
TEST_SYSTEM = r"""
mesh Th = square(30, 30);
fespace Vh(Th, P2);
varf a(u, v) = int2d(Th)(dx(u)*dx(v) + dy(u)*dy(v) + 0.3*dx(u)*v) + on(1, 2, 3, 4, u = 0);
varf l(u, v) = int2d(Th)(v);
matrix A = a(Vh, Vh);
"""

PLUGIN_CHECK = r"""
load "freefem/plugins/contact_mumps"
include "freefem/lib/core/sparse_solver.idp"
""" + TEST_SYSTEM + r"""real[int] b = l(0, Vh), x(b.n), y(b.n), s(13);
int info = contactMumpsFactor(A, 1);
info = contactMumpsSolve(x, b);
set(A, solver = sparsesolver);
y = A^-1*b;
y -= x;
cout << "SOLVE " << info << " " << (y.linfty/x.linfty) << endl;
matrix B = 2.*A;
info = contactMumpsFactor(B, 1);
contactMumpsStats(s);
cout << "SAME_PATTERN " << info << " " << s[0] << " " << s[1] << endl;
info = contactMumpsFactor(B, 0);
contactMumpsStats(s);
cout << "NO_REUSE " << info << " " << s[0] << " " << s[1] << endl;
int[int] rows = [0, b.n - 1], cols = [b.n - 1, b.n - 1];
real[int] vals = [1e-3, 0.];
matrix E = [rows, cols, vals];
info = contactMumpsFactor(A, E, 1);
contactMumpsStats(s);
cout << "NEW_PATTERN " << info << " " << s[0] << " " << s[1] << endl;
info = contactMumpsSolve(x, b);
matrix C = A + E;
set(C, solver = sparsesolver);
y = C^-1*b;
y -= x;
cout << "SUM " << info << " " << (y.linfty/x.linfty) << endl;
real[int] zeroRow(b.n);
zeroRow = 1;
zeroRow[7] = 0;
matrix D = zeroRow;
matrix S = D*A;
S = S*D;
info = contactMumpsFactor(S, 1);
cout << "SINGULAR " << info << " " << sparseFailure("factorization", info) << endl;
info = contactMumpsSolve(y, b);
cout << "NO_FACTORS " << info << endl;
// low-rank correction: Kf = A + Pt' diag(d1) P factorized, then K2 = A + Pt' diag(d2) P
// solved through contactMumpsLowRank(PtT, P, d2 - d1) and checked against a direct solve
int nq = 40;
int[int] pr(2*nq), pc(2*nq), tr(2*nq), tc(2*nq);
real[int] pv(2*nq), tv(2*nq), d1(nq), d2(nq), dd(nq);
for (int q = 0; q < nq; q++) {
    pr[2*q] = q; pc[2*q] = 37*q + 11; pv[2*q] = 1.; pr[2*q + 1] = q; pc[2*q + 1] = 37*q + 12; pv[2*q + 1] = -0.5;
    tr[2*q] = q; tc[2*q] = 37*q + 11; tv[2*q] = 1.; tr[2*q + 1] = q; tc[2*q + 1] = 37*q + 13; tv[2*q + 1] = 0.25;
    d1[q] = (q < 20) ? 100. : 0.; d2[q] = (q >= 10 && q < 30) ? 100. : 0.;
}
matrix P = [pr, pc, pv], Pt = [tr, tc, tv];
P.resize(nq, b.n); Pt.resize(nq, b.n);
matrix PtT = Pt';
macro lowRankCheck(label, dk, expected)
{
    matrix Dk = dk;
    matrix T = Dk*P;
    matrix Kc = PtT*T;
    matrix K = A + Kc;
    set(K, solver = sparsesolver);
    real[int] xd = K^-1*b;
    info = contactMumpsSolve(x, b);
    xd -= x;
    cout << label << " " << info << " " << (xd.linfty/x.linfty) << " " << expected << endl;
}//
{
    matrix D1 = d1;
    matrix T1 = D1*P;
    matrix Kc1 = PtT*T1;
    info = contactMumpsFactor(A, Kc1, 1);
}
dd = d2 - d1;
int nCols = contactMumpsLowRank(PtT, P, dd, 100);
lowRankCheck("LOW_RANK", d2, nCols)
d2 = 0; d2[25] = 50.; d2[35] = 100.;
dd = d2 - d1;
nCols = contactMumpsLowRank(PtT, P, dd, 100);
lowRankCheck("LOW_RANK_KEPT", d2, nCols)
d2[36] = 100.; d2[37] = 100.;
dd = d2 - d1;
nCols = contactMumpsLowRank(PtT, P, dd, 1);
lowRankCheck("LOW_RANK_REFUSED", d1, nCols)
contactMumpsStats(s);
cout << "LOW_RANK_STATS " << s[11] << endl;
"""


def plugin_lines(tmp_path):
    script = tmp_path / "plugin_check.edp"
    script.write_text(PLUGIN_CHECK)
    proc = run_freefem(script)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    return {m.group(1): m.group(2).split() for m in re.finditer(r"^([A-Z_]+) (.*)$", proc.stdout, re.M)}


def test_plugin_answers_keeps_the_analysis_and_reports_failures(tmp_path):
    out = plugin_lines(tmp_path)
    # the same answer as FreeFEM's own MUMPS (measured 4e-15 relative)
    assert out["SOLVE"][0] == "0" and float(out["SOLVE"][1]) < 1e-12
    # same pattern: numeric factorization only; reuse = 0 analyses again; A + E, one
    # more coupling entry, is a new pattern: analysed again
    assert out["SAME_PATTERN"] == ["0", "1", "2"]
    assert out["NO_REUSE"] == ["0", "2", "3"]
    assert out["NEW_PATTERN"] == ["0", "3", "4"]
    # the plugin's own sum A + E answers as FreeFEM's sum does
    assert out["SUM"][0] == "0" and float(out["SUM"][1]) < 1e-12
    # a zero row: MUMPS's own code (-10, numerically singular) reaches the script,
    # and the factors are gone afterwards
    assert out["SINGULAR"][0] == "-10" and "numerically singular" in " ".join(out["SINGULAR"])
    assert out["NO_FACTORS"] == ["-1000"]
    # low-rank correction (Woodbury): the answer of a direct solve of the changed
    # matrix, one column per point whose term changed (0-9 removed, 20-29 added: 20);
    # a second change (0-19 removed, 25 and 35 added) re-uses the kept columns and
    # computes 10-19 and 35 only (11); a change needing more new columns than allowed
    # is refused (-1004) and the solve is the factorized matrix's again
    assert out["LOW_RANK"][0] == "0" and float(out["LOW_RANK"][1]) < 1e-12 and out["LOW_RANK"][2] == "20"
    assert out["LOW_RANK_KEPT"][0] == "0" and float(out["LOW_RANK_KEPT"][1]) < 1e-12
    assert out["LOW_RANK_KEPT"][2] == "11"
    assert out["LOW_RANK_REFUSED"][2] == "-1004" and float(out["LOW_RANK_REFUSED"][1]) < 1e-12
    assert out["LOW_RANK_STATS"] == ["31"]


def run_2d(tmp_path, name, *extra):
    out = tmp_path / name
    proc = run_freefem("fd_contact_2d.edp", "-Ddegree=2", "-nx", 80, "-estimators", 0, "-vtu", 0, "-csv", 0,
                       "-outdir", out, *extra)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads((out / "results.json").read_text())


def test_solver_options_change_the_work_not_the_answer(tmp_path):
    default = run_2d(tmp_path, "default")
    gmres = run_2d(tmp_path, "gmres", "-low_rank", 0)
    fresh = run_2d(tmp_path, "fresh", "-reuse_analysis", 0, "-refactor_auto", 0, "-low_rank", 0)
    n = default["newton"]
    # measured: one factorization and analysis, the later steps as low-rank
    # corrections (41 columns in all, one solve each), a budget of 19 solves
    assert n["analyses"] == 1 and n["factorizations"] == 1
    assert 30 <= n["low_rank_columns"] <= 60 and n["gmres_iterations"] == n["iterations"] - 1
    assert 15 <= n["refactor_budget"] <= 25
    # without the correction: 2 factorizations and 26 GMRES iterations on them
    assert gmres["newton"]["factorizations"] == 2 and gmres["newton"]["low_rank_columns"] == 0
    assert gmres["newton"]["gmres_iterations"] > 2*n["gmres_iterations"]
    assert fresh["newton"]["analyses"] == fresh["newton"]["factorizations"] == 2
    centre = default["probes"]["centre"][1]
    for other in (gmres, fresh):
        assert other["status"] == "converged"
        assert abs(other["probes"]["centre"][1] - centre) <= 1e-12*abs(centre)


def test_out_of_range_solver_options_are_refused(tmp_path):
    proc = run_freefem("fd_contact_2d.edp", "-Ddegree=1", "-nx", 10, "-refactor_auto", -1, "-outdir", tmp_path / "x")
    assert proc.returncode == 2 and "option -refactor_auto: -1 must be 0 or 1" in proc.stdout + proc.stderr
    proc = run_freefem("fd_contact_3d.edp", "-nx", 4, "-reuse_analysis", 2, "-outdir", tmp_path / "y")
    assert proc.returncode == 2 and "option -reuse_analysis: 2 must be 0 or 1" in proc.stdout + proc.stderr


def small_ball_results(out, flag, value):
    """results.json of the ball on slab, P2, nx = 6, run directly with one solver flag; the
    run's folder holds nothing else (MUMPS's factor files, prefix mumps_factors, are gone
    with the solve)."""
    proc = run_freefem("fd_contact_3d.edp", "-Ddegree=2", "-nx", 6, "-estimators", 0, "-vtu", 0, "-csv", 0,
                       flag, value, "-outdir", out)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert sorted(p.name for p in out.iterdir()) == ["results.json"]
    return json.loads((out / "results.json").read_text())


def test_out_of_core_factors_give_the_answer_and_leave_no_file(tmp_path):
    runs = {flag: small_ball_results(tmp_path / f"ooc{flag}", "-out_of_core", flag) for flag in (0, 1)}
    centre = runs[0]["probes"]["centre"][2]
    assert runs[1]["newton"]["factorizations"] == runs[0]["newton"]["factorizations"]
    assert abs(runs[1]["probes"]["centre"][2] - centre) <= 1e-12*abs(centre)


def test_automatic_ordering_keeps_amd_on_small_systems_and_takes_scotch_where_it_pays(tmp_path):
    def solve(script, *flags):
        out = tmp_path / f"run{len(list(tmp_path.iterdir()))}"
        proc = run_freefem(script, *flags, "-estimators", 0, "-vtu", 0, "-csv", 0, "-outdir", out)
        assert proc.returncode == 0, proc.stderr[-2000:]
        return json.loads((out / "results.json").read_text())

    # 2D default scene: AMD predicts about 1250 operations per matrix entry, below 6000
    auto, scotch = solve("fd_contact_2d.edp"), solve("fd_contact_2d.edp", "-ordering", "scotch")
    assert auto["newton"]["ordering"] == "amd" and scotch["newton"]["ordering"] == "scotch"
    assert 1000 <= auto["newton"]["amd_operations_per_entry"] <= 1500
    assert scotch["newton"]["amd_operations_per_entry"] == 0
    centre = scotch["probes"]["centre"][1]
    assert abs(auto["probes"]["centre"][1] - centre) <= 1e-12*abs(centre)
    # 3D P2 nx = 10: about 7700 per entry with AMD, and Scotch's factors need a third fewer operations
    auto, amd = solve("fd_contact_3d.edp", "-Ddegree=2", "-nx", 10), solve("fd_contact_3d.edp", "-Ddegree=2",
                                                                            "-nx", 10, "-ordering", "amd")
    assert auto["newton"]["ordering"] == "scotch" and amd["newton"]["ordering"] == "amd"
    assert 6000 < auto["newton"]["amd_operations_per_entry"] <= 9000
    assert auto["newton"]["factor_operations"] < 0.75*amd["newton"]["factor_operations"]
    centre = amd["probes"]["centre"][2]
    assert abs(auto["probes"]["centre"][2] - centre) <= 1e-12*abs(centre)


def test_an_unknown_ordering_is_refused(tmp_path):
    for script in ("fd_contact_2d.edp", "fd_contact_3d.edp"):
        out = tmp_path / script
        proc = run_freefem(script, "-nx", 4, "-ordering", "metis", "-outdir", out)
        assert proc.returncode == 2 and "option -ordering: 'metis' must be one of {auto, amd, scotch}" in proc.stdout + proc.stderr
        assert not out.exists()


def test_blas_threads_are_granted_and_give_the_same_numbers_from_run_to_run(tmp_path):
    def solve(threads, name):
        out = tmp_path / name
        proc = run_freefem("fd_contact_3d.edp", "-Ddegree=2", "-nx", 10, "-estimators", 0, "-vtu", 0, "-csv", 0,
                           "-threads", threads, "-outdir", out)
        assert proc.returncode == 0 and "WARNING" not in proc.stderr, proc.stderr[-2000:]
        return json.loads((out / "results.json").read_text())

    def numbers(results):
        return {key: value for key, value in results.items()
                if key not in ("timings_cpu_s", "memory", "steps", "adapt", "linear_solver")}

    one, two, again = solve(1, "one"), solve(2, "two"), solve(2, "again")
    # make setup installs the threaded OpenBLAS; the plugin sets the count asked
    assert one["linear_solver"]["blas_threads"] == 1 and two["linear_solver"]["blas_threads"] == 2
    # two threads sum the dense kernels' products in another order (the last digits
    # of the 3D P2 nx = 10 run change: the threads act), the same order every time
    assert numbers(two) != numbers(one)
    assert numbers(again) == numbers(two)
    centre = one["probes"]["centre"][2]
    assert abs(two["probes"]["centre"][2] - centre) <= 1e-12*abs(centre)


def test_a_thread_count_out_of_range_is_refused(tmp_path):
    for script in ("fd_contact_2d.edp", "fd_contact_3d.edp"):
        proc = run_freefem(script, "-nx", 4, "-threads", 0, "-outdir", tmp_path / script)
        assert proc.returncode == 2 and "option -threads: 0 must lie in [1, 256]" in proc.stdout + proc.stderr
        assert not (tmp_path / script / "results.json").exists()


PRECISION_CHECK = r"""
include "freefem/lib/core/args.idp"
include "freefem/lib/core/sparse_solver.idp"
""" + TEST_SYSTEM + r"""real[int] b = l(0, Vh), x(b.n), y(b.n), s(1);
set(A, solver = sparsesolver);
y = A^-1*b;
requireThat(contactMumpsPrecision(1) == 0, "precision");
int info = contactMumpsFactor(A, 1);
info = contactMumpsSolve(x, b);
contactMumpsStats(s);
x -= y;
cout << "SINGLE " << info << " " << (x.linfty/y.linfty) << " " << s[15] << " " << s[16] << " " << s[17] << " " << s[18] << endl;
// the same system scaled into single precision's subnormal range, where its
// factors hold no digit: factorized again in double precision
matrix T = 1e-44*A;
real[int] bt = 1e-44*b, xt(b.n);
info = contactMumpsFactor(T, 1);
info = contactMumpsSolve(xt, bt);
contactMumpsStats(s);
xt -= y;
cout << "FALLBACK " << info << " " << (xt.linfty/y.linfty) << " " << s[15] << " " << s[17] << endl;
contactMumpsRelease();
requireThat(contactMumpsPrecision(3) == -1009, "bad precision code");
cout << "COMPRESSION " << contactMumpsCompression(1e-4) << endl;
"""


def test_single_precision_factors_are_refined_to_double_precision(tmp_path):
    script = tmp_path / "precision_check.edp"
    script.write_text(PRECISION_CHECK)
    proc = run_freefem(script)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    out = {m.group(1): m.group(2).split() for m in re.finditer(r"^([A-Z_]+) (.*)$", proc.stdout, re.M)}
    info, diff, single, steps, fallbacks, error = out["SINGLE"]
    # single-precision factors, refined by a few GMRES steps to FreeFEM's double-precision
    # MUMPS answer (measured: 3 steps, 1.3e-14 apart; single-precision factors alone: 1e-7)
    assert info == "0" and single == "1" and fallbacks == "0"
    assert 2 <= int(steps) <= 6 and float(diff) < 5e-14 and float(error) <= 16*2.2e-16
    # the refinement cannot reach double precision from factors without a digit: the
    # matrix is factorized again in double (measured 1.3e-15 from the answer)
    info, diff, single, fallbacks = out["FALLBACK"]
    assert info == "0" and single == "0" and fallbacks == "1" and float(diff) < 1e-13
    # block low-rank factors need the MPI build (tests/test_mpi.py)
    assert out["COMPRESSION"] == ["-1010"]


def test_single_precision_run_gives_the_double_precision_answer(tmp_path):
    runs = {}
    for precision in ("double", "single"):
        out = tmp_path / precision
        proc = run_freefem("fd_contact_3d.edp", "-Ddegree=2", "-nx", 8, "-estimators", 0, "-vtu", 0,
                           "-precision", precision, "-outdir", out)
        assert proc.returncode == 0, proc.stderr[-2000:]
        runs[precision] = json.loads((out / "results.json").read_text()), pd.read_csv(out / "contact_pressure.csv")
    (double, pd_double), (single, pd_single) = runs["double"], runs["single"]
    assert double["newton"]["precision"] == "double" and single["newton"]["precision"] == "single"
    assert single["newton"]["refinement_steps"] > 0 and single["newton"]["precision_fallbacks"] == 0
    assert single["newton"]["iterations"] == double["newton"]["iterations"]
    # measured: centre 1.2e-14, force 2.0e-13, pressure 3.4e-13 of their largest value
    assert relative(double["probes"]["centre"], single["probes"]["centre"]) < 1e-13
    assert relative(double["contact"]["force_on_body1"], single["contact"]["force_on_body1"]) < 1e-12
    assert relative(pd_double.pressure, pd_single.pressure) < 2e-12


def test_factors_go_to_files_above_the_size_given(tmp_path):
    # 0: in memory; 1: the factors (about 10 MB) in files of the run's folder
    runs = {mb: small_ball_results(tmp_path / f"mb{mb}", "-out_of_core_mb", mb) for mb in (0, 1)}
    assert runs[0]["newton"]["factors_out_of_core"] == 0 and runs[1]["newton"]["factors_out_of_core"] == 1
    centre = runs[0]["probes"]["centre"][2]
    assert abs(runs[1]["probes"]["centre"][2] - centre) <= 1e-12*abs(centre)
