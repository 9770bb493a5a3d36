"""Direct runs check every flag with the driver's rules.

A script's flag rules come from two places (freefem/lib/core/args.idp): the
generated flag_rules.idp of its folder, written by `python3 -m driver readme` from
the scene schema, and its params.idp for the flags the driver derives or only
direct runs use. `-list_options 1` prints the rule of every key the script reads
("RULE: key: rule", "none" for a key without one). Here: the generated files are
current, every declared flag carries the schema's rule, no key goes without a
rule, and a direct run refuses a bad value (a number that is not wholly a number,
a value outside its range) with exit 2 and a line naming the flag, before it
creates its output folder.
"""

import re

import pytest

from lab import readme
from driver.scene import load_scene, script_modules
from driver.errors import SceneError
from driver.schema import flag_rule, flag_rules
from tests.conftest import REPO, run_freefem

SCRIPTS = list(readme.RULE_FOLDERS)


def printed(proc):
    return proc.stdout + proc.stderr   # FreeFEM's cerr may reach stdout


def script_rules(script, *args):
    """{key: rule} of every key the script reads, from -list_options 1 (after args)."""
    proc = run_freefem(f"{script}.edp", *args, "-list_options", 1)
    assert proc.returncode == 0, printed(proc)[-2000:]
    rules = {}
    for line in proc.stdout.splitlines():
        if line.startswith("RULE: "):
            key, _, rule = line[len("RULE: "):].partition(": ")
            rules[key] = rule
    return rules


def schema_field(script, dotted):
    return dict(readme.schema_rows(readme.script_schema(script_modules()[script])))[dotted]


@pytest.mark.parametrize("script", SCRIPTS)
def test_generated_rule_files_are_current(script):
    assert readme.flag_rules_path(script).read_text() == readme.flag_rules_module(script), \
        "the flag rules are out of date with the schema: run `python3 -m driver readme` and commit them"


@pytest.mark.freefem
@pytest.mark.parametrize("script", SCRIPTS)
def test_every_flag_read_has_a_rule_and_declared_flags_have_the_schemas(script):
    rules = script_rules(script)
    assert [key for key, rule in rules.items() if rule == "none"] == [], \
        "a flag without a rule: state it in the schema or in the script's params.idp"
    declared = flag_rules(readme.script_schema(script_modules()[script]))
    assert {flag: rules.get(flag) for flag in declared} == declared


@pytest.mark.freefem
@pytest.mark.parametrize("script, flag, key", [
    ("fd_contact_2d", "mu1", "body1.mu"), ("fd_contact_2d", "mu2", "body2.mu"),
    ("fd_contact_3d", "mu1", "body1.mu"), ("fd_contact_3d", "mu2", "body2.mu"),
    ("contact_foundation_2d", "E", "material.E"), ("contact_foundation_2d", "nu", "material.nu"),
])
def test_derived_flags_state_the_rule_of_their_scene_key(script, flag, key):
    """params.idp states these by hand: they must say what the schema says of the key they come from."""
    assert script_rules(script)[flag] == flag_rule(schema_field(script, key), key)


# Numbers that are not wholly numbers (read by prefix they would give theta 1, 0, 0, 5) and
# values outside their flag's range (newton_max 0, newton_tol 0, ghost_gamma -1 would end
# as an unconverged Newton, exit 3, the others run).
REFUSED = [("fd_contact_2d", flag, value, message) for flag, value, message in [
    ("theta", "1-2", "'1-2' is not a number"),
    ("theta", "--1", "'--1' is not a number"),
    ("theta", "-.e5", "'-.e5' is not a number"),
    ("theta", "5e", "'5e' is not a number"),
    ("active0", "-1", "-1 must be >= 0"),
    ("vtu", "7", "7 must be 0 or 1"),
    ("allow_unbalanced", "5", "5 must be 0 or 1"),
    ("adapt_warm_start", "9", "9 must be one of {0, 1, 2}"),
    ("predictor_steps", "-3", "-3 must be >= 0"),
    ("refactor_points", "-7", "-7 must be >= 0"),
    ("adapt_max_dofs", "-5", "-5 must be > 0"),
    ("save", "5", "5 must be 0 or 1"),
    ("csv", "2", "2 must be 0 or 1"),
    ("newton_max", "0", "0 must be >= 1"),
    ("newton_tol", "0", "0 must be > 0"),
    ("newton_tol", "-1", "-1 must be > 0"),
    ("ghost_gamma", "-1", "-1 must be > 0"),
]] + [("fd_contact_3d", flag, value, message) for flag, value, message in [
    ("theta", "1-2", "'1-2' is not a number"),
    ("active0", "-1", "-1 must be >= 0"),
    ("allow_unbalanced", "5", "5 must be 0 or 1"),
    ("predictor_steps", "-3", "-3 must be >= 0"),
    ("save", "5", "5 must be 0 or 1"),
    ("newton_max", "0", "0 must be >= 1"),
    ("newton_tol", "-1", "-1 must be > 0"),
    ("adapt_growth", "1", "1 must lie in (1, 16]"),
]] + [("contact_foundation_2d", flag, value, message) for flag, value, message in [
    ("theta", "5e", "'5e' is not a number"),
    ("csv", "2", "2 must be 0 or 1"),
    ("adapt_max_dofs", "-5", "-5 must be > 0"),
    ("newton_max", "0", "0 must be >= 1"),
    ("newton_tol", "0", "0 must be > 0"),
    ("dirichlet0_fix", "4", "4 must be one of {1, 2, 3}"),   # the rule of the pattern dirichlet{i}_fix
]] + [
    # both ends of each kind of range, and the integer limit
    ("fd_contact_2d", "rho", "0", "0 must lie in (0, 1]"),
    ("fd_contact_2d", "threads", "257", "257 must lie in [1, 256]"),
    ("fd_contact_2d", "nx", "4001", "4001 must lie in [2, 4000]"),
    ("fd_contact_2d", "nx", "2147483648", "2147483648 must lie in [-2147483647, 2147483647]"),
    ("fd_contact_2d", "nx", "1e3", "'1e3' is not an integer"),
    ("fd_contact_2d", "ordering", "Scotch", "'Scotch' must be one of {auto, amd, scotch}"),
    ("fd_contact_2d", "name", "-x", "'-x' is not a safe name"),
    ("fd_contact_3d", "nx", "151", "151 must lie in [2, 150]"),
    ("contact_foundation_2d", "nu", "0.5", "0.5 must lie in (-1, 0.5)"),
    ("contact_foundation_2d", "nu", "-1", "-1 must lie in (-1, 0.5)"),
]


@pytest.mark.freefem
@pytest.mark.parametrize("script, flag, value, message", REFUSED)
def test_direct_run_refuses_a_bad_value_naming_the_flag(script, flag, value, message, tmp_path):
    out = tmp_path / "out"
    proc = run_freefem(f"{script}.edp", "-nx", 4, f"-{flag}", value, "-outdir", out)
    assert proc.returncode == 2, printed(proc)[-2000:]
    assert f"INPUT ERROR: option -{flag}: {message}" in printed(proc)
    assert not out.exists()


@pytest.mark.freefem
@pytest.mark.parametrize("script, args", [
    ("fd_contact_2d", ["-theta", ".5", "-active0", "5.", "-mass_eps", "+1E-3", "-rho", "1", "-threads", "256",
                       "-nx", "4000", "-adapt_max_dofs", "2147483647", "-contact_qp", "4", "-ordering", "scotch",
                       "-name", "a.b-c", "-mu1", "1e-300", "-predictor_steps", "+0", "-vtu", "0"]),
    ("fd_contact_3d", ["-nx", "150", "-adapt_growth", "1.0000001", "-contact_qp", "0"]),
    ("contact_foundation_2d", ["-nu", "-0.999", "-ndirichlet", "1", "-dirichlet0_fix", "3", "-E", "1e-300"]),
])
def test_direct_run_accepts_values_at_the_edges_of_their_rules(script, args):
    script_rules(script, *args)   # parsed and checked, then the listing: exit 0


@pytest.mark.parametrize("case, override, words", [
    ("cases/disk_on_slab.toml", "mesh.nx=4001", "must lie in [2, 4000]"),
    ("cases/ball_on_slab.toml", "mesh.nx=151", "must lie in [2, 150]"),
    ("cases/ball_on_slab.toml", "adapt.growth=1.0", "must lie in (1, 16]"),
    ("cases/square_slip_separation.toml", "adapt.max_dofs=2147483648", "must lie in [-2147483647, 2147483647]"),
])
def test_driver_refuses_what_the_scripts_refuse(case, override, words):
    """The ranges added to the schema for the scripts' limits, and the integer limit of argInt."""
    with pytest.raises(SceneError, match=r"key '[a-z_.]+': " + re.escape(words)):
        load_scene(REPO / case, [override])


@pytest.mark.freefem
@pytest.mark.parametrize("lines, message", [
    ('argRule("x", "real >= abc");', "the rule of -x has the bound 'abc'"),
    ('argRule("x", "float");', "the rule of -x is 'float'"),
    ('argRule("x", "real (0, 1");', "the rule of -x is 'real (0, 1'"),
    ('argRule("x", "int >= 1"); real x = argReal("x", 0);', "option -x is read as real but its rule is 'int >= 1'"),
])
def test_a_malformed_rule_stops_the_script(lines, message, tmp_path):
    """A flaw of the script, not of its input: exit 4 (core/args.idp, requireSound)."""
    script = tmp_path / "rules.edp"
    script.write_text(f'include "freefem/lib/core/args.idp"\n{lines}\nargsRejectUnknown();\n')
    proc = run_freefem(script)
    assert proc.returncode == 4 and f"INTERNAL ERROR: {message}" in printed(proc), printed(proc)[-2000:]
