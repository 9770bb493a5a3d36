"""A small declarative schema for scene files: types, ranges, defaults.

Every problem is reported as one SceneError naming the file and the dotted key.
"""

import math

from .errors import SceneError

REQUIRED = object()
INT_LIMIT = 2**31 - 1   # the largest integer magnitude a flag takes (core/args.idp, argInt)


def finite_float(value):
    """value as a finite float, or None (not a number, a boolean, inf, nan, or an integer too
    large for a float)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    try:
        value = float(value)
    except OverflowError:
        return None
    return value if math.isfinite(value) else None


def finite_floats(values, length=None):
    """A list of finite floats (of the given length), or None."""
    if not isinstance(values, list) or (length is not None and len(values) != length):
        return None
    out = [finite_float(v) for v in values]
    return None if any(v is None for v in out) else out


class Field:
    """One scalar or vector entry of a scene table."""

    def __init__(self, kind, default=REQUIRED, check=None, choices=None, length=None, doc="", unit="",
                 flag=None, derived=None):
        self.kind = kind            # "float", "int", "str", "bool", "vector"; "tree": a table or list
                                    # checked by its own reader (shapes, supports: driver/scene_module.py)
        self.default = default
        self.check = check          # callable(value) -> error text or None; its .description reads as a range
        self.choices = choices
        self.length = length        # for vectors
        self.doc = doc              # one line for the scene reference (docs/scenes.md)
        self.unit = unit            # dimension in a consistent unit system ("1": dimensionless)
        self.flag = flag            # the script's flag carrying the value as is (a tuple: one per component)
        self.derived = derived      # or the flags the script module derives from it ("lambda1 mu1")

    def coerce(self, value, where):
        kind = self.kind
        if kind == "float":
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise SceneError(f"{where}: expected a number, got {type_name(value)} {value!r}")
            if finite_float(value) is None:
                raise SceneError(f"{where}: must be a finite number, got {str(value)[:40]}")
            value = float(value)
        elif kind == "int":
            if isinstance(value, bool) or not isinstance(value, int):
                raise SceneError(f"{where}: expected an integer, got {type_name(value)} {value!r}")
            if abs(value) > INT_LIMIT:
                raise SceneError(f"{where}: must lie in [-{INT_LIMIT}, {INT_LIMIT}], got {str(value)[:40]}")
        elif kind == "str":
            if not isinstance(value, str):
                raise SceneError(f"{where}: expected a string, got {type_name(value)} {value!r}")
        elif kind == "bool":
            if not isinstance(value, bool):
                raise SceneError(f"{where}: expected true or false, got {type_name(value)} {value!r}")
        elif kind == "tree":
            if not isinstance(value, (dict, list, str)):
                raise SceneError(f"{where}: expected a table, a list of tables or a name, got {type_name(value)}")
        elif kind == "vector":
            if not isinstance(value, list) or any(
                isinstance(v, bool) or not isinstance(v, (int, float)) for v in value
            ):
                raise SceneError(f"{where}: expected a list of numbers, got {value!r}")
            if self.length is not None and len(value) != self.length:
                raise SceneError(f"{where}: expected {self.length} numbers, got {len(value)}")
            if finite_floats(value) is None:
                raise SceneError(f"{where}: numbers must be finite, got {str(value)[:80]}")
            value = finite_floats(value)
        if self.choices is not None and value not in self.choices:
            options = ", ".join(repr(c) for c in self.choices)
            raise SceneError(f"{where}: must be one of {options}, got {value!r}")
        if self.check is not None:
            problem = self.check(value)
            if problem:
                raise SceneError(f"{where}: {problem}, got {value!r}")
        return value


class TableList:
    """An array of tables ([[name]] in TOML), each validated against a schema."""

    def __init__(self, schema, default=()):
        self.schema = schema
        self.default = list(default)


def type_name(value):
    return {bool: "boolean", int: "integer", float: "number", str: "string",
            list: "list", dict: "table"}.get(type(value), type(value).__name__)


def described(description):
    """Attach the readable range that the scene reference prints for a check that is not a Range."""
    def attach(check):
        check.description = description
        return check
    return attach


def bound_text(bound):
    """A bound as the scene reference and the FreeFEM rule files print it: 2, 0.5, 1e-12 (exact)."""
    bound = float(bound)
    return str(int(bound)) if bound.is_integer() and abs(bound) < 1e15 else repr(bound)


class Range:
    """The check lo < or <= value < or <= hi (lo or hi None: no bound on that side).

    Called with a value it returns the error text or None; its bounds and ends are
    readable, so the scene reference and the FreeFEM scripts' flag rules (both from
    description, see flag_rule) are written from the check the driver applies."""

    def __init__(self, lo=None, hi=None, lo_open=False, hi_open=False):
        self.lo, self.hi, self.lo_open, self.hi_open = lo, hi, lo_open, hi_open

    def __call__(self, value):
        above = self.lo is None or (value > self.lo if self.lo_open else value >= self.lo)
        below = self.hi is None or (value < self.hi if self.hi_open else value <= self.hi)
        return None if above and below else f"must {'be' if self.hi is None else 'lie in'} {self.written(bound_text)}"

    def written(self, show):
        """'>= 1', '(0, 1]': the range with its bounds written by show."""
        if self.hi is None:
            return f"{'>' if self.lo_open else '>='} {show(self.lo)}"
        return f"{'(' if self.lo_open else '['}{show(self.lo)}, {show(self.hi)}{')' if self.hi_open else ']'}"

    @property
    def description(self):
        """The range as the scene reference and the FreeFEM flag rules print it."""
        return self.written(bound_text)


positive = Range(0, lo_open=True)


def greater_than(bound):
    return Range(bound, lo_open=True)


def at_least(bound):
    return Range(bound)


def between(lo, hi):
    """lo <= value <= hi."""
    return Range(lo, hi)


def open_interval(lo, hi):
    """lo < value < hi."""
    return Range(lo, hi, lo_open=True, hi_open=True)


FLAG_KINDS = {"float": "real", "vector": "real", "int": "int", "bool": "bool", "str": "string"}


def flag_rule(field, where):
    """The rule a FreeFEM script applies to the field's flag (core/args.idp, argRule): its
    kind (real, int, bool: 0 or 1, string, name: a safe scene name), then a range
    ('>= 1', '(0, 1]') or the allowed values ('{auto, amd, scotch}')."""
    kind = FLAG_KINDS[field.kind]
    if field.check is not None:
        if field.choices is not None or field.kind == "vector":
            raise ValueError(f"{where}: a check with choices or on a vector has no flag rule")
        if isinstance(field.check, Range):
            return f"{kind} {field.check.description}"
        if not hasattr(field.check, "flag_rule"):
            raise ValueError(f"{where}: its check states no flag rule")
        return field.check.flag_rule
    if field.choices is not None:
        if any(not str(c) or set(str(c)) & set(' ,{}"\\') for c in field.choices):
            raise ValueError(f"{where}: a choice with a space, comma, brace, quote or backslash has no flag rule")
        return kind + " {" + ", ".join(str(c) for c in field.choices) + "}"
    return kind


def flag_rules(schema, prefix=""):
    """{flag: rule} for every flag the schema declares (one per component of a vector)."""
    rules = {}
    for key, spec in schema.items():
        if isinstance(spec, dict):
            rules.update(flag_rules(spec, f"{prefix}{key}."))
        elif isinstance(spec, Field) and spec.flag:
            names = spec.flag if isinstance(spec.flag, tuple) else (spec.flag,)
            for name in names:
                rules[name] = flag_rule(spec, f"{prefix}{key}")
    return rules


def validate(data, schema, source, prefix=""):
    """Return a new dict with defaults filled in; raise SceneError on any problem."""
    if not isinstance(data, dict):
        raise SceneError(f"{source}: key '{prefix.rstrip('.')}': expected a table, got {type_name(data)}")
    out = {}
    for key in data:
        if key not in schema:
            known = ", ".join(sorted(schema))
            raise SceneError(f"{source}: unknown key '{prefix}{key}' (known here: {known})")
    for key, spec in schema.items():
        where = f"{source}: key '{prefix}{key}'"
        if isinstance(spec, dict):
            out[key] = validate(data.get(key, {}), spec, source, f"{prefix}{key}.")
        elif isinstance(spec, TableList):
            items = data.get(key, spec.default)
            if not isinstance(items, list) or not all(isinstance(i, dict) for i in items):
                raise SceneError(f"{where}: expected an array of tables ([[{key}]])")
            out[key] = [validate(item, spec.schema, source, f"{prefix}{key}.{n}.")
                        for n, item in enumerate(items)]
        elif key in data:
            out[key] = spec.coerce(data[key], where)
        elif spec.default is REQUIRED:
            raise SceneError(f"{where}: required but missing")
        else:
            out[key] = spec.default
    return out


class FreeFemFlags(list):
    """FreeFEM command-line arguments: -key value pairs, floats in full precision."""

    def put(self, key, value):
        self.extend([f"-{key}", repr(value) if isinstance(value, float) else str(value)])

    def pairs(self):
        """The (-key, value) pairs put, after the leading macro definitions (-DNAME=value)."""
        start = 0
        while start < len(self) and self[start].startswith("-D") and "=" in self[start]:
            start += 1
        return list(zip(self[start::2], self[start + 1::2]))


def put_declared(flags, scene, schema):
    """Send every key of the schema that declares a flag, in schema order (booleans as 0/1)."""
    for key, spec in schema.items():
        if isinstance(spec, dict):
            put_declared(flags, scene[key], spec)
        elif isinstance(spec, Field) and spec.flag:
            names, values = ((spec.flag, scene[key]) if isinstance(spec.flag, tuple)
                             else ((spec.flag,), (scene[key],)))
            for name, value in zip(names, values):
                flags.put(name, int(value) if isinstance(value, bool) else value)


def schema_flags(schema):
    """Every flag a schema names, declared or derived (the set the driver may send)."""
    names = set()
    for key, spec in schema.items():
        if isinstance(spec, dict):
            names |= schema_flags(spec)
        elif isinstance(spec, TableList):
            names |= schema_flags(spec.schema)
        elif spec.flag:
            names |= set(spec.flag) if isinstance(spec.flag, tuple) else {spec.flag}
        if isinstance(spec, Field) and spec.derived:
            names |= set(spec.derived.split())
    return names


def two_body_method_schema(degree):
    """The [method] keys the two-body scripts (2D and 3D) share: degree, the Nitsche theta
    and gamma0, the neighbour stabilization's threshold."""
    return {
        "degree": Field("int", derived="Ddegree", default=degree, choices=(1, 2),
                        doc="finite element degree (P1 or P2)"),
        "theta": Field("float", flag="theta", default=-1.0, unit="1",
                       doc="Nitsche variant: 1 symmetric, 0 non-symmetric, -1 skew-symmetric (any real)"),
        "gamma0": Field("float", flag="gamma0", default=1.0 / 200.0, check=positive, unit="1",
                        doc="Nitsche parameter, gamma = gamma0 h_K / muStar (1/stress with gamma_scaling none)"),
        "rho": Field("float", flag="rho", default=0.25, check=Range(0.0, 1.0, lo_open=True), unit="1",
                     doc="neighbour stabilization: cut ratio |K cap Omega_i|/|K| below which an element "
                         "borrows its neighbour's stress"),
        "ghost_gamma": Field("float", flag="ghost_gamma", default=1e-2, check=positive, unit="1",
                             doc="ghost penalty weight, times lambda + 2 mu of each body"),
    }


def two_body_solver_schema(floating_body, contact_points):
    """The [solver] keys of the two-body scripts (2D and 3D): semi-smooth Newton and its start."""
    return {
        "newton_tol": Field("float", flag="newton_tol", default=1e-9, check=positive, unit="1",
                            doc="Newton stops when the relative nonlinear residual is below this and the "
                                "active set is stable"),
        "newton_max": Field("int", flag="newton_max", default=30, check=at_least(1),
                            doc="Newton iteration limit (then exit 3)"),
        "contact_points": contact_points,
        "active0": Field("float", flag="active0", default=0.1, check=at_least(0.0), unit="1",
                         doc="first active set: gap <= active0 * h (then a secant predictor)"),
        "predictor_steps": Field("int", flag="predictor_steps", default=4, check=at_least(0),
                                 doc="at most this many Newton steps of the secant predictor on the active measure (it stops once a trial set is too large)"),
        "refactor_points": Field("int", flag="refactor_points", default=12, check=at_least(0),
                                 doc="re-use the last factorization (low-rank correction or GMRES) when at most this "
                                     "many points changed, whatever the budget"),
        "refactor_auto": Field("bool", flag="refactor_auto", default=True,
                               doc="also re-use it when fewer points changed than the solves one "
                                   "factorization costs (from MUMPS's operation count)"),
        "reuse_analysis": Field("bool", flag="reuse_analysis", default=True,
                                doc="keep MUMPS's ordering and analysis while the matrix pattern stays"),
        "low_rank": Field("bool", flag="low_rank", default=True,
                          doc="solve a changed active set as a low-rank correction of the last "
                              "factorization (Woodbury) while its columns cost less than a factorization"),
        "out_of_core": Field("bool", flag="out_of_core", default=False,
                             doc="MUMPS keeps the factors in files of the run's folder instead of memory "
                                 "(deleted when the solve ends), whatever their size"),
        "out_of_core_mb": Field("float", flag="out_of_core_mb", default=500.0, check=at_least(0.0), unit="MB",
                                doc="factors MUMPS predicts larger than this go to files of the run's folder "
                                    "when it has twice their size free (less memory for large 3D runs, about "
                                    "the same time); 0: in memory unless out_of_core"),
        "threads": Field("int", flag="threads", default=1, check=between(1, 256),
                         doc="BLAS threads of MUMPS's dense kernels: more pay on large 3D runs; the last "
                             "digits of the results then differ from a one-thread run (the same from run to "
                             "run), and the CPU timings in results.json add up all threads"),
        "ordering": Field("str", flag="ordering", default="auto", choices=("auto", "amd", "scotch"),
                          doc="MUMPS's fill-reducing ordering: auto takes AMD unless its predicted "
                              "factorization does more than 6000 operations per matrix entry (then Scotch's "
                              "nested dissection, whose ordering costs more but pays on large 3D systems)"),
        "precision": Field("str", flag="precision", default="auto", choices=("auto", "double", "single"),
                           doc="precision of MUMPS's factors: single halves their memory and, on large 3D "
                               "systems, their time, and every solve is refined to double precision (GMRES "
                               "on the double-precision matrix); auto takes single when AMD's predicted "
                               "factorization exceeds 2e10 operations, double otherwise"),
        "compression": Field("float", flag="compression", default=0.0, check=Range(0.0, 1.0, hi_open=True),
                             unit="1",
                             doc="MUMPS's block low-rank factorization with this dropping parameter (CNTL(7), "
                                 "relative to the scaled matrix; 0: full rank): smaller, cheaper factors, every "
                                 "solve refined to double precision; needs the MPI build (the run goes through "
                                 "mpirun, also on one process)"),
        "ranks": Field("int", default=1, check=between(1, 1024),
                       doc="processes of the run: above 1, FreeFem++-mpi under mpirun on this machine, the "
                           "Newton's factorizations and solves distributed by parallel MUMPS (docs/design.md; "
                           "several machines: docs/mpi.md); the same numbers as one process to solver round-off"),
        "allow_unbalanced": Field("bool", flag="allow_unbalanced", default=False,
                                  doc=f"keep a run whose pins or mass term carry more than 1e-6 of the "
                                      f"{floating_body}'s load beyond the solve's round-off (flagged in "
                                      f"results.json 'balance'); refused (exit 3) otherwise"),
        "allow_implausible": Field("bool", flag="allow_implausible", default=False,
                                   doc="keep a run whose largest penetration exceeds 0.05 of the smaller body's "
                                       "size or whose floating body drifts by more than 0.5 of its size (flagged "
                                       "in results.json 'plausibility'); refused (exit 3) otherwise"),
    }


# Estimator-driven adaptation, the same keys for every script that adapts.
ADAPT_SCHEMA = {
    "steps": Field("int", flag="adapt_steps", default=0, check=between(0, 50),
                   doc="mesh adaptations after the first solve, each followed by a new solve (0: none)"),
    "growth": Field("float", flag="adapt_growth", default=2.0, check=Range(0.0, 16.0, lo_open=True),
                    unit="1", doc="wanted element-count growth per step"),
    "max_dofs": Field("int", flag="adapt_max_dofs", default=200000, check=positive,
                      doc="DOF budget: no adaptation step whose mesh would exceed it (growth x DOFs)"),
    "eta_target": Field("float", flag="adapt_eta_target", default=0.0, check=at_least(0.0), unit="as eta",
                        doc="stop once the estimator eta <= this (0: run every step)"),
    "max_refine": Field("float", flag="adapt_max_refine", default=4.0, check=at_least(1.0), unit="1",
                        doc="an element's size shrinks at most by this factor per step"),
    "max_coarsen": Field("float", flag="adapt_max_coarsen", default=2.0, check=at_least(1.0), unit="1",
                         doc="an element's size grows at most by this factor per step"),
}
