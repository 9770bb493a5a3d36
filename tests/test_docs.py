"""The documentation that is generated or linked stays true to the code.

docs/scenes.md is written from the driver's schemas by `python -m driver readme`;
it must be the text the schemas give today and name every key a scene may hold.
Links between README.md and docs/ must resolve inside the repository.
"""

import re

from driver import readme
from driver.runner import REPO
from driver.scene import script_modules


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
    for name in readme.TABLES:
        assert text.count(f"<!-- table:{name} -->") == 1, f"table {name}: expected exactly one marker"
        assert text.count(f"<!-- end:{name} -->") == 1, f"table {name}: expected exactly one end marker"


OUTSIDE = re.compile(r"DESIGN\.md|\.\./shared|\bissues? #?\d+|/issues/\d+")


def test_nothing_points_outside_the_repository():
    """Documentation and code name only what is in the repository: no external design notes or issue numbers."""
    paths = [REPO / "README.md", REPO / "Makefile"]
    for folder, pattern in (("docs", "*.md"), ("driver", "*.py"), ("tests", "*.py"), ("cases", "*"), ("freefem", "*")):
        paths += [p for p in (REPO / folder).rglob(pattern) if p.is_file() and "__pycache__" not in p.parts]
    for path in paths:
        for number, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
            match = OUTSIDE.search(line)
            assert not match, f"{path.relative_to(REPO)}:{number}: {match.group(0)!r} points outside the repository"
