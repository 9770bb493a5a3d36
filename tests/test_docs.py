"""The documentation that is generated or linked stays true to the code.

docs/scenes.md is written from the driver's schemas by `python -m driver readme`;
it must be the text the schemas give today and name every key a scene may hold.
Links between README.md and docs/ must resolve inside the repository. The studies'
declarations (lab/studies/__init__.py) agree with the docs' table markers and the
Makefile's targets.
"""

import re

import pytest

from conftest import run_cli
from lab import readme
from driver.runner import REPO
from driver.scene import script_modules
from lab.studies import OTHER_TABLES, groups as study_groups, tables


def test_scene_reference_is_current():
    committed = readme.SCENE_REFERENCE.read_text()
    assert committed == readme.scene_reference(), \
        "docs/scenes.md is out of date with the schemas: run `python3 -m driver readme` and commit it"


def test_scene_reference_lists_every_key():
    text = readme.SCENE_REFERENCE.read_text()
    modules = script_modules()
    for script, _ in readme.SCRIPT_TITLES:
        section = text.split(f"## `{script}`", 1)[1].split("\n## ", 1)[0]
        for key, field in readme.schema_rows(readme.script_schema(modules[script])):
            assert f"| `{key}` |" in section, f"{script}: key {key} missing from docs/scenes.md"
            assert field.doc, f"{script}: key {key} has no doc in its schema"
            check = field.check
            assert check is None or getattr(check, "description", ""), \
                f"{script}: key {key}: its check has no description (schema.described)"
    assert {s for s, _ in readme.SCRIPT_TITLES} == set(modules)


def test_doc_links_resolve():
    for page in [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]:
        for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", page.read_text()):
            if re.match(r"[a-z]+://", target):
                continue
            assert (page.parent / target).exists(), f"{page.relative_to(REPO)}: link to {target} does not resolve"


def test_every_table_has_one_marker():
    text = "\n".join(p.read_text() for p in readme.pages())
    for name in tables():
        assert text.count(f"<!-- table:{name} -->") == 1, f"table {name}: expected exactly one marker"
        assert text.count(f"<!-- end:{name} -->") == 1, f"table {name}: expected exactly one end marker"
        assert callable(readme.table_builder(name))


def test_every_table_block_is_declared_by_a_study():
    """A generated block no study declares would never be refilled."""
    text = "\n".join(p.read_text() for p in readme.pages())
    blocks = re.findall(r"<!-- table:([\w-]+) -->\n.*?<!-- end:\1 -->", text, re.S)
    assert blocks and set(blocks) == set(tables()), set(blocks) ^ set(tables())


def make_targets():
    """The targets of the Makefile: its rules' names, with $(STUDY_GROUPS) expanded."""
    text = (REPO / "Makefile").read_text().replace("\\\n", " ")
    variables = dict(re.findall(r"^([A-Z_]+) :?= *(.*)$", text, re.M))
    targets = set()
    for line in re.findall(r"^([^\t#=\n][^:=\n]*):(?!=)", text, re.M):
        for word in line.split():
            ref = re.fullmatch(r"\$\((\w+)\)", word)
            targets.update(variables[ref.group(1)].split() if ref else [word])
    return targets


def test_every_study_group_is_a_make_target_that_runs_it():
    targets = make_targets()
    declared = set(study_groups()) | set(OTHER_TABLES)
    assert declared <= targets, f"groups without a make target: {sorted(declared - targets)}"
    study_targets = set(re.search(r"^STUDY_GROUPS := (.*)$", (REPO / "Makefile").read_text().replace("\\\n", " "),
                                  re.M).group(1).split())
    assert study_targets == set(study_groups()), study_targets ^ set(study_groups())


OUTSIDE = re.compile(r"DESIGN\.md|\.\./shared|\bissues? #?\d+|/issues/\d+")


def test_nothing_points_outside_the_repository():
    """Documentation and code name only what is in the repository: no external design notes or issue numbers."""
    paths = [REPO / "README.md", REPO / "Makefile"]
    for folder, pattern in (("docs", "*.md"), ("driver", "*.py"), ("lab", "*.py"), ("tests", "*.py"), ("cases", "*"),
                            ("freefem", "*")):
        paths += [p for p in (REPO / folder).rglob(pattern) if p.is_file() and "__pycache__" not in p.parts]
    for path in paths:
        for number, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
            match = OUTSIDE.search(line)
            assert not match, f"{path.relative_to(REPO)}:{number}: {match.group(0)!r} points outside the repository"


def test_a_study_group_runs_its_studies_in_their_order(monkeypatch):
    """python -m driver study (the Makefile's command) hands the command line to the lab."""
    import lab.studies
    from driver import cli

    ran = []
    monkeypatch.setattr(lab.studies, "study", lambda name: lambda: ran.append(name))
    assert cli.main(["study", "--group", "hertz-3d-study", "gates"]) == 0
    assert ran == ["hertz-3d-settings", "hertz-3d-coarse", "hertz-3d-recovery", "hertz-3d", "gates"]


@pytest.mark.parametrize("args, message", [
    ((), "error: study: name a study or a --group"),
    (("nosuch",), "error: study: unknown study 'nosuch' (python -m driver study --help lists them)"),
])
def test_a_study_command_without_a_known_study_is_bad_input(args, message):
    proc = run_cli("study", *args)
    assert proc.returncode == 2 and proc.stderr.strip() == message
