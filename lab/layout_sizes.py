"""Sizes of the FreeFEM code's layout at revisions, to compare a reshaping of the code
with the tree before it: modules, macro names, names declared by token pasting, stage names read by
pasting a body index, and the top-level names each two-body script's stages share.

    python -m lab.layout_sizes [REV ...]      (default: the working tree)

A stage is a macro the step loop of fd_contact_2d.edp / fd_contact_3d.edp expands. Its
code is its body and the bodies of the macros it reaches (other stages excluded); a name
it declares outside any brace is a top-level name, and the name is shared when a later
stage's code reads it. The scan reads text, as tests/test_code_layout.py does: a macro
expanded inside braces counts as top level, so the count errs upwards."""

import re
import subprocess
import sys
import tarfile
import tempfile
from io import BytesIO
from pathlib import Path

from tests.test_code_layout import (BODY_PASTED, DECLARATION, code, declared_names, pasted_stage_reads,
                                    stage_sequence)

REPO = Path(__file__).resolve().parents[1]
MACRO = re.compile(r"^\s*macro\s+(\w+)\s*(\([^)]*\))?(.*?)(?=^\s*macro\s|\Z)", re.M | re.S)
WORD = re.compile(r"\b[A-Za-z_]\w*\b")


def macro_bodies(sources):
    """Macro name -> body (text up to the next macro of its file: the scan need not find
    the closing //, a name read after it is read by the file's top level)."""
    bodies = {}
    for path in sources:
        for match in MACRO.finditer(code(path)):
            bodies[match.group(1)] = bodies.get(match.group(1), "") + match.group(3)
    return bodies


def top_level_declarations(body):
    names, depth, start = [], 0, 0
    flat = []
    for i, ch in enumerate(body):
        if ch == "{":
            if depth == 0:
                flat.append(body[start:i])
            depth += 1
        elif ch == "}":
            depth = max(depth - 1, 0)
            if depth == 0:
                start = i + 1
    flat.append(body[start:] if depth == 0 else "")
    for part in flat:
        for match in DECLARATION.finditer(part):
            names += declared_names(match.group(1))
    return names


def shared_stage_names(script, bodies):
    stages = list(dict.fromkeys(stage_sequence(script)))
    reach = {}
    for stage in stages:
        seen, todo = set(), [stage]
        while todo:
            name = todo.pop()
            if name in seen or name not in bodies:
                continue
            seen.add(name)
            todo += [w for w in set(WORD.findall(bodies[name])) if w in bodies and w not in stages]
        reach[stage] = seen
    declared = {s: {n for m in reach[s] for n in top_level_declarations(bodies[m])} for s in stages}
    reads = {s: {w for m in reach[s] for w in WORD.findall(bodies[m])} for s in stages}
    shared = set()
    for i, stage in enumerate(stages):
        shared |= {n for n in declared[stage] if any(n in reads[t] for t in stages[i + 1:])}
    return len(shared)


def sizes(root):
    freefem = root / "freefem"
    sources = sorted(freefem.rglob("*.idp")) + sorted(freefem.rglob("*.edp"))
    bodies = macro_bodies(sources)
    dimension = {d: macro_bodies(sorted((freefem / "lib" / "core").glob("*.idp"))
                                 + sorted((freefem / "lib" / d).glob("*.idp"))) for d in ("fd2d", "fd3d")}
    pasted = [n for p in sources for m in DECLARATION.finditer(code(p)) for n in declared_names(m.group(1))
              if "#" in n]
    return {"modules (lib/)": len(list((freefem / "lib").rglob("*.idp"))),
            "macro names": len(bodies),
            "names declared by pasting": len(set(pasted)),
            "of them from a body index": len({n for n in pasted if BODY_PASTED.search(n)}),
            "stage names read by pasting a body index": sum(len(pasted_stage_reads(code(p))) for p in sources),
            "top-level names shared between 2D stages": shared_stage_names(freefem / "fd_contact_2d.edp",
                                                                                    dimension["fd2d"]),
            "top-level names shared between 3D stages": shared_stage_names(freefem / "fd_contact_3d.edp",
                                                                                    dimension["fd3d"])}


def tree_of(rev, folder):
    archive = subprocess.run(["git", "archive", rev, "freefem"], cwd=REPO, capture_output=True, check=True).stdout
    with tarfile.open(fileobj=BytesIO(archive)) as tar:
        tar.extractall(folder, filter="data")
    return folder


def main(revs):
    columns = {}
    with tempfile.TemporaryDirectory() as tmp:
        for rev in revs or ["working tree"]:
            root = REPO if rev == "working tree" else tree_of(rev, Path(tmp) / rev)
            columns[rev] = sizes(root)
    names = list(next(iter(columns.values())))
    print("| | " + " | ".join(columns) + " |\n|---|" + "---|" * len(columns))
    for name in names:
        print(f"| {name} | " + " | ".join(str(c[name]) for c in columns.values()) + " |")


if __name__ == "__main__":
    main(sys.argv[1:])
