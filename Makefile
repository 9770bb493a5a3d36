# Two commands on a fresh Debian 12 machine: `make case` and `make test`.
# Both install what is missing first (make setup).

PYTHON ?= python3
CASE ?= cases/disk_on_slab.toml
SET ?=
SUDO := $(shell [ "$$(id -u)" -eq 0 ] || echo sudo)
# libopenblas0-pthread: MUMPS links the system BLAS; the reference BLAS is slower.
# The threaded OpenBLAS runs on one thread unless a run asks for more (solver.threads,
# -threads: the plugin sets the count), where it gives the serial build's numbers to
# the bit; more threads pay on large 3D runs (docs/benchmarks.md).
# python3, python3-venv: Debian's interpreter and what `python3 -m venv` needs (ensurepip
# and the pip wheel it installs), for the driver's virtual environment (setup-python);
# ca-certificates: Debian's pip trusts only /etc/ssl/certs/ca-certificates.crt, which a
# minimal Debian does not have.
# libfreefem++-dev, libmumps-seq-dev, g++: to build the plugins (freefem/plugins:
# the Newton's MUMPS instance, contact_mumps.cpp; the 2D curved cut cells, the
# estimators' cut-edge pieces, the contact points' projections and the level-set
# normals, curved_cells.cpp; the recovered contact pressure, pressure_recovery.cpp; the
# nearest submesh element of 3D points outside a body's submesh, nearest_kept.cpp; the
# body files' von_mises_inside, inside_extension.cpp; the signed distance to a surface
# shape's triangles, surface_distance.cpp).
# libmumps-dev, libopenmpi-dev, openmpi-bin: runs on several processes (solver.ranks,
# docs/mpi.md): Debian's parallel MUMPS (with ScaLAPACK) for the MPI build of
# contact_mumps, mpicxx to build it, mpirun to start FreeFem++-mpi (in freefem++).
DEBIAN_PACKAGES := freefem++ libfreefem++ gmsh libopenblas0-pthread libfreefem++-dev libmumps-seq-dev g++ \
	libmumps-dev libopenmpi-dev openmpi-bin python3 python3-venv ca-certificates
OPENBLAS := /usr/lib/x86_64-linux-gnu/openblas-pthread/libblas.so.3
export FF_LOADPATH := /usr/lib/freefem++

.PHONY: setup setup-system setup-python case test clean

PLUGINS := $(patsubst %.cpp,%.so,$(wildcard freefem/plugins/*.cpp))
# what each plugin links besides FreeFEM: freefem/plugins/link_flags.txt (driver/plugins.py,
# which builds them for an installed package, reads the same file)
PLUGIN_FLAGS = $(shell sed -n 's|^$(1):\(.*\)|\1|p' freefem/plugins/link_flags.txt)
MPI_PLUGINS := freefem/plugins/mpi/contact_mumps.so   # for FreeFem++-mpi (below)

setup: setup-system setup-python $(PLUGINS) $(MPI_PLUGINS)

# A plugin is rebuilt when its source or the plugins' shared header changes (ff-c++ is
# FreeFEM's plugin compiler), in a scratch folder, then moved in place: a run that has
# the old one loaded keeps it.
PLUGIN_HEADERS := $(wildcard freefem/plugins/*.hpp) freefem/plugins/link_flags.txt
freefem/plugins/%.so: freefem/plugins/%.cpp $(PLUGIN_HEADERS) | setup-system
	@echo "building $@"
	@tmp=$$(mktemp -d) && cp $< $$tmp/ && (cd $$tmp && ff-c++ $*.cpp -I$(CURDIR)/freefem/plugins $(call PLUGIN_FLAGS,$*) > build.log 2>&1) \
	  && mv $$tmp/$*.so $@ && rm -rf $$tmp \
	  || { cat $$tmp/build.log; rm -rf $$tmp; echo "ERROR: could not build $@"; exit 1; }

# The Newton's MUMPS plugin for FreeFem++-mpi (several processes: solver.ranks): the same
# source against Debian's parallel MUMPS and Open MPI (ff-c++ -mpi compiles with
# mpicxx). FreeFem++-mpi looks for plugins in each load path's mpi/ folder, so the
# scripts' load "contact_mumps" finds this one there and the sequential one otherwise
# (freefem++.pref puts freefem/plugins on the load path). Its link flags: the line
# mpi/contact_mumps of freefem/plugins/link_flags.txt.
freefem/plugins/mpi/%.so: freefem/plugins/%.cpp $(PLUGIN_HEADERS) | setup-system
	@echo "building $@"
	@mkdir -p $(@D) && tmp=$$(mktemp -d) && cp $< $$tmp/ \
	  && (cd $$tmp && ff-c++ -mpi -DCONTACT_MUMPS_MPI $*.cpp -I$(CURDIR)/freefem/plugins $(call PLUGIN_FLAGS,mpi/$*) > build.log 2>&1) \
	  && mv $$tmp/$*.so $@ && rm -rf $$tmp \
	  || { cat $$tmp/build.log; rm -rf $$tmp; echo "ERROR: could not build $@"; exit 1; }

# FreeFEM's plugins (msh3, iovtk, gmsh, ...) live in libfreefem++, which the
# freefem++ package does not pull in: check for a plugin file, not the binary.
setup-system:
	@if ! command -v FreeFem++ >/dev/null || ! command -v gmsh >/dev/null \
	    || [ ! -f /usr/lib/freefem++/iovtk.so ] || [ ! -f $(OPENBLAS) ] \
	    || [ ! -f /usr/include/freefem++/ff++.hpp ] || [ ! -f /usr/include/dmumps_c.h ] || ! command -v g++ >/dev/null \
	    || [ ! -f /usr/lib/x86_64-linux-gnu/libdmumps.so ] || ! command -v mpicxx >/dev/null || ! command -v mpirun >/dev/null \
	    || [ ! -x /usr/bin/python3 ] || [ -z "$(wildcard /usr/lib/python3*/ensurepip/__init__.py)" ] \
	    || [ ! -f /etc/ssl/certs/ca-certificates.crt ]; then \
	  echo "installing Debian packages: $(DEBIAN_PACKAGES)"; \
	  $(SUDO) apt-get update -qq && \
	  DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq $(DEBIAN_PACKAGES) >/dev/null; \
	fi

# The driver and pytest run in a virtual environment in the checkout, $(VENV), made
# with $(PYTHON): Debian's own python3 refuses pip installs into the system
# interpreter (PEP 668, externally managed), and a venv works the same with any
# interpreter. $(VENV_MARK) records which PYTHON made it, so that make knows the
# venv as its own: a $(VENV) without it (a user's) is never removed or changed,
# make stops with one line instead. Another PYTHON makes the venv anew; the venv's
# own interpreter, or any path to the same binary, counts as the same PYTHON.
#
# The check costs nothing when everything is installed: $(PYTHON_STAMP) lists the
# venv's interpreter and the file each package was found at, and while the stamp is
# newer than requirements.txt, pyproject.toml and this Makefile (its PYTHON_PACKAGES),
# the venv was made by the same PYTHON and every file it lists exists, no Python starts. Otherwise one Python process looks the packages
# up (find_spec locates them without importing; importing them all costs about
# 1.3 s) and writes the stamp, or exits 1 when one is missing: then pip installs
# requirements.txt into the venv and the look-up runs again. A package removed, a
# new requirement or another PYTHON: the check runs again.
VENV := .venv
VENV_PYTHON := $(VENV)/bin/python
VENV_MARK := $(VENV)/.made-by-make-setup
PYTHON_PACKAGES := numpy pandas matplotlib meshio igl pytest scipy dask distributed tqdm fdcontact
PYTHON_STAMP := $(VENV)/.setup-python
PYTHON_STAMP_WRITE = $(VENV_PYTHON) -c "import importlib.util as u, os, sys; \
	specs = [u.find_spec(m) for m in sys.argv[3:]]; None in specs and sys.exit(1); \
	f = sys.argv[2]; open(f + '.tmp', 'w').write('\\n'.join([sys.argv[1]] + [s.origin for s in specs]) + '\\n'); \
	os.replace(f + '.tmp', f)" $(VENV_PYTHON) $(PYTHON_STAMP) $(PYTHON_PACKAGES)
SAME_PYTHON = { [ "$$(cat $(VENV_MARK) 2>/dev/null)" = "$$base" ] || [ "$$base" -ef $(VENV_PYTHON) ]; }
setup-python: setup-system
	@base="$$(command -v $(PYTHON))" || { echo "ERROR: no interpreter $(PYTHON) (set PYTHON=/path/to/python3)"; exit 1; }; \
	if ! { [ $(PYTHON_STAMP) -nt requirements.txt ] && [ $(PYTHON_STAMP) -nt pyproject.toml ] \
	        && [ $(PYTHON_STAMP) -nt Makefile ] && $(SAME_PYTHON) \
	        && ( while read -r f; do [ -e "$$f" ] || exit 1; done < $(PYTHON_STAMP) ); }; then \
	  if ! { [ -f $(VENV_MARK) ] && $(SAME_PYTHON) && [ -x $(VENV_PYTHON) ]; }; then \
	    if [ -e $(VENV) ] || [ -L $(VENV) ]; then \
	      [ -f $(VENV_MARK) ] || { echo "ERROR: $(VENV) exists but make setup did not make it: move it aside"; exit 1; }; \
	      rm -rf $(VENV); \
	    fi; \
	    echo "making the virtual environment $(VENV) with $$base"; \
	    mkdir $(VENV) && printf '%s\n' "$$base" > $(VENV_MARK) && $(PYTHON) -m venv $(VENV) \
	      || { echo "ERROR: $(PYTHON) -m venv $(VENV) failed (Debian: apt-get install python3-venv)"; exit 1; }; \
	  fi; \
	  if ! $(PYTHON_STAMP_WRITE) 2>/dev/null; then \
	    echo "installing Python packages from requirements.txt and this package (editable) into $(VENV)"; \
	    $(VENV_PYTHON) -m pip install -q -r requirements.txt && $(VENV_PYTHON) -m pip install -q --no-deps -e . \
	      && $(PYTHON_STAMP_WRITE) \
	      || { echo "ERROR: not every one of $(PYTHON_PACKAGES) can be found in $(VENV) after installing requirements.txt"; exit 1; }; \
	  fi; \
	fi

# make case [CASE=cases/NAME.toml] [SET="mesh.nx=80 method.theta=1"] [RANKS=N]
# RANKS=N: solver.ranks = N, the run on N MPI processes of this machine (docs/mpi.md).
RANKS ?=
CASE_SET = $(strip $(SET) $(if $(strip $(RANKS)),solver.ranks=$(strip $(RANKS))))
case: setup
	$(VENV)/bin/fdcontact run $(CASE) $(if $(CASE_SET),--set "$(CASE_SET)")

test: setup
	$(VENV_PYTHON) -m pytest -q tests

# The fast tier: the tests that start no FreeFEM (pytest -m "not freefem"), with a
# stand-in FreeFem++ first on PATH that fails (tests/fast_tier): a test that starts
# FreeFEM without its mark fails here.
.PHONY: test-fast
test-fast: setup
	PATH="$(CURDIR)/tests/fast_tier:$$PATH" $(VENV_PYTHON) -m pytest -q -m "not freefem" tests

# clean keeps $(VENV): making it again downloads every package (rm -rf $(VENV) drops it).
clean:
	rm -rf runs .pytest_cache $(PLUGINS) $(MPI_PLUGINS)

# The mutation check (docs/mutation.md; not part of make test): each mutant of
# tests/mutation/mutants.toml applied alone to a scratch copy of the checkout, the
# test files it names run against it; results/mutation.csv and docs/mutation.md.
# make mutation [MUTANTS=id1,id2] (some of them; the table keeps the other rows)
MUTANTS ?=
.PHONY: mutation
mutation: setup
	$(VENV_PYTHON) tests/mutation/run.py $(if $(strip $(MUTANTS)),--only "$(MUTANTS)")
	$(VENV_PYTHON) -m driver readme

# Tables and figures of the study pages in docs/: one target per group of studies, each
# running `python -m driver study --group TARGET` (the group's studies in their order; the
# lab's command, which the driver hands to lab/ in a checkout) and then refilling the
# generated tables of README.md and docs/*.md (make readme). Which study belongs to which
# target, and which tables it fills, is declared once per study in lab/studies/__init__.py
# (STUDIES); tests/test_docs.py checks that every group declared there is listed here.
#
# foundation-study: Newton on the foundation square, its contact pressure.
# aposteriori-study: residual estimators on the square: uniform ladder (slides' table),
#   adaptive loop, adapted mesh figure. The reference (adaptive P2, ~1e6 DOFs) is computed
#   once into runs/reference/square_p2.
# fd2d-study: fictitious-domain disk on slab: convergence (P1/P2, theta = 1, 0, -1)
#   against a P2 reference (NX = 320, computed once into runs/reference/), gamma0 sweep at
#   NX = 90, stabilization on sliver cuts, cross-check against body-fitted meshes.
# pressure-study: the contact pressure of the disk on slab (P2, theta = -1,
#   docs/outputs.md): the recovered pressure at NX = 40, 80, 160 against body-fitted P2
#   solutions at h = 1/320 (gamma0 = 1/200 and 1, computed once into runs/reference/), and
#   the gamma0 trade-off at NX = 160 (errors against the NX = 320 reference of fd2d-study):
#   results/pressure_*.csv, plots/pressure_*.png.
# hard-study: the scenes of cases/hard/ (results/hard_cases.csv), the material scaling of
#   gamma (results/hard_gamma_scaling.csv), the conditioning of the Newton matrix against
#   the cut (results/hard_conditioning.csv, plots/conditioning.png). The sliver errors use a
#   P2 NX = 160 reference (computed once into runs/reference/).
# gates-study: the gates of the two-body solvers (freefem/lib/core/gates.idp) on every
#   shipped scene of cases/, cases/hard/, cases/verification/: penetration, drift and load
#   shares against the tolerances (results/gates.csv, table in docs/reliability.md).
# bench: speed against error on the disk on slab (timings: ratios and medians belong
#   here, never in tests): results/bench*.csv (Newton grid first: not timed),
#   plots/speed_vs_error.png. bench-overhead: make case's whole process against the
#   FreeFEM run alone (medians), MUMPS's phases and the first active set
#   (results/bench_overhead*.csv, bench_mumps.csv, bench_first_active_set.csv).
#   bench-solver and bench-3d time the previous version (a scratch git worktree) beside
#   the current tree: the Newton's linear solver, and the 3D runs' cost by phase with its
#   growth against DOFs (results/bench_3d*.csv), and the 3D error tool against the graded
#   reference (results/bench_error_tool*.csv). bench-scale: the large 3D runs against
#   d58614e, the runs on several processes, the largest 3D run and the scaling model
#   (results/bench_scale*.csv; BENCH_SCALE_REPEATS, BENCH_SCALE_LARGE_NX).
# scenes-study: the shipped 2D scenes as a user runs them: results/scenes.csv,
#   results/hertz.csv (the Hertz scene against Hertz's half-width, force and pressure;
#   README table); the shipped 3D scenes' volume (load) errors, balance and cost:
#   results/scenes_3d.csv.
# hertz-3d-study: Hertz's sphere on sphere (cases/hertz_spheres.toml) against Hertz
#   (docs/hertz-3d.md): the settings that suit 3D (gamma0, stabilization, contact points,
#   cut geometry, grading passes; results/hertz_spheres_settings.csv), the recovery's
#   options on the shipped run's points (results/hertz_spheres_recovery.csv), then the
#   scene as shipped, coarser, in P1 and with the 3D defaults (results/hertz_spheres.csv,
#   README table).
# curved-study: the curved cut geometry against the P1 one (docs/curved-geometry.md):
#   cut-cell accuracy, disk-on-slab convergence against a curved P2 NX = 320 reference
#   (computed once into runs/reference/), cost of the NX = 80 run, and the smooth problems
#   of cases/verification/ (a patch test with an exact quadratic, the held ring's ladder
#   against its own NX = 320 references), and the disk on slab on estimator-adapted meshes
#   against the same reference (results/curved_adaptive.csv), and the disk's approach on
#   every NX = 48, 56, ..., 400 (results/curved_centre_scan*.csv).
# fd3d-study: fictitious-domain ball on slab (3D): P1 (theta = 1, 0, -1) and P2 ladders
#   against a P2 reference graded toward the contact point (cube(15) refined by tetgen to
#   h = 1/60 within 0.16 of it; FD3D_REFERENCE_* in lab/studies/fd3d.py; computed once
#   into runs/reference/: 294k DOFs, 26 min, 16.6 GiB peak), cost against DOFs, the
#   centre-cut von Mises figure; then the estimator-driven tetgen refinement against
#   uniform refinement (fd3d-adaptive).
# fd3d-curved-study: the 3D P2 ladder (theta = -1, nx = 8 to 28) on the curved cut
#   geometry (docs/curved-geometry.md) against fd3d-study's graded reference solved on the
#   curved geometry (computed once into runs/reference/): results/fd3d_curved_*.csv; then
#   the 3D smooth problems of cases/verification/ (clamped ball, held shell against its own
#   nx = 32 reference): results/curved_*_3d*.csv.
STUDY_GROUPS := foundation-study aposteriori-study fd2d-study pressure-study hard-study gates-study bench \
	scenes-study hertz-3d-study curved-study fd3d-study fd3d-curved-study
.PHONY: $(STUDY_GROUPS) readme
$(STUDY_GROUPS): setup
	$(VENV_PYTHON) -m driver study --group $@
	$(VENV_PYTHON) -m driver readme

readme:
	$(VENV_PYTHON) -m driver readme

# Parameter sweeps on Dask (docs/sweeps.md): one FreeFEM run per point,
# one row per point in results/sweep_NAME.csv, resumable (runs/sweeps/NAME/rows/).
# make sweep [SWEEP=cases/sweeps/NAME.toml] [WORKERS=2] [SCHEDULER=tcp://HOST:8786]
SWEEP ?= cases/sweeps/smoke.toml
WORKERS ?=
SCHEDULER ?=
.PHONY: sweep sweep-bench
sweep: setup
	$(VENV_PYTHON) -m driver sweep $(SWEEP) $(if $(strip $(WORKERS)),--workers $(WORKERS)) \
	    $(if $(strip $(SCHEDULER)),--scheduler $(SCHEDULER))

# The smoke sweep with --workers 1 and --workers 2, 3 times each in fresh folders:
# medians and their ratio in results/sweep_bench.csv (run on an idle machine).
sweep-bench: setup
	$(VENV_PYTHON) -m driver sweep-bench $(SWEEP) --repeats 3

# Figures of one run folder, written into it (docs/outputs.md):
# make plot RUN=runs/NAME-TIME-HASH [PLANE=y=0] (PLANE: 3D cut, default through the contact)
RUN ?=
PLANE ?=
.PHONY: plot
plot: setup-python
	@if [ -z "$(RUN)" ]; then echo "error: make plot needs RUN=<run folder>, e.g. RUN=runs/NAME-TIME-HASH" >&2; exit 2; fi
	$(VENV_PYTHON) -m driver plot "$(RUN)" $(if $(strip $(PLANE)),--plane "$(PLANE)")
