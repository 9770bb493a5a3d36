"""The Newton's MUMPS plugin (freefem/plugins/contact_mumps.cpp): answers, analysis
kept while the pattern stays, MUMPS's error codes reaching the script, and the
solver options on whole runs of the disk on slab (P2, NX = 80, a few seconds each)."""

import json
import re
import subprocess

from conftest import REPO, run_freefem

PLUGIN_CHECK = r"""
load "freefem/plugins/contact_mumps"
include "freefem/lib/core/sparse_solver.idp"
mesh Th = square(30, 30);
fespace Vh(Th, P2);
varf a(u, v) = int2d(Th)(dx(u)*dx(v) + dy(u)*dy(v) + 0.3*dx(u)*v) + on(1, 2, 3, 4, u = 0);
varf l(u, v) = int2d(Th)(v);
matrix A = a(Vh, Vh);
real[int] b = l(0, Vh), x(b.n), y(b.n), s(11);
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
"""


def plugin_lines(tmp_path):
    script = tmp_path / "plugin_check.edp"
    script.write_text(PLUGIN_CHECK)
    proc = subprocess.run(["FreeFem++", "-nw", "-v", "0", str(script)], cwd=REPO, capture_output=True, text=True)
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


def run_2d(tmp_path, name, *extra):
    out = tmp_path / name
    proc = run_freefem("fd_contact_2d.edp", "-Ddegree=2", "-nx", 80, "-estimators", 0, "-vtu", 0, "-csv", 0,
                       "-outdir", out, *extra)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads((out / "results.json").read_text())


def test_solver_options_change_the_work_not_the_answer(tmp_path):
    default = run_2d(tmp_path, "default")
    fresh = run_2d(tmp_path, "fresh", "-reuse_analysis", 0, "-refactor_auto", 0)
    n = default["newton"]
    # measured: 2 factorizations, one analysis, a budget of 19 solves
    assert n["analyses"] == 1 and n["factorizations"] == 2
    assert fresh["newton"]["analyses"] == fresh["newton"]["factorizations"] == 2
    assert 15 <= n["refactor_budget"] <= 25
    centre = default["probes"]["centre"][1]
    assert fresh["status"] == "converged"
    assert abs(fresh["probes"]["centre"][1] - centre) <= 1e-12*abs(centre)


def test_out_of_range_solver_options_are_refused(tmp_path):
    proc = run_freefem("fd_contact_2d.edp", "-Ddegree=1", "-nx", 10, "-refactor_auto", -1, "-outdir", tmp_path / "x")
    assert proc.returncode == 2 and "reuse_analysis and refactor_auto must be 0 or 1" in proc.stdout + proc.stderr
    proc = run_freefem("fd_contact_3d.edp", "-nx", 4, "-reuse_analysis", 2, "-outdir", tmp_path / "y")
    assert proc.returncode == 2 and "reuse_analysis and refactor_auto must be 0 or 1" in proc.stdout + proc.stderr
