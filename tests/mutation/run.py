"""Mutation check: does the suite fail when the method breaks? (make mutation)

Every mutant of tests/mutation/mutants.toml is one small change of the code (a sign,
a factor 1.01, a weight, a stopping rule: one or more exact text replacements). Each
is applied, alone, to a scratch copy of the checkout (the tracked and untracked files
git knows, plus the built plugins; the working tree is never touched); a mutant of a
plugin source (freefem/plugins/) rebuilds that plugin there, the others reuse the
built ones. Then the mutant's test files run (pytest -x). The first failing test is
recorded and what it failed on classified (failure_kind):

  results assertion  an assertion about what the code computed (numbers, outputs,
                     Newton's history);
  run failed         a run meant to converge exited non-zero;
  negative test      a run meant to fail did otherwise (its exit code or message);
  exception          not an assertion.

After anything but a results assertion the files run again without that test (up to
SIDE_EFFECT_RETRIES times) to find a results assertion that also fails. A mutant
marked `equivalent` (with the measurement that shows it changes nothing) is expected
to pass.

The clean copy's test files run first (all of them, without -x): a failing clean
suite would make every mutant look caught, so the check stops then.

Writes results/mutation.csv (one row per mutant; --only reruns some and keeps the
other rows). docs/mutation.md describes the check and how to add a mutant.
"""

import argparse
import csv
import os
import shutil
import subprocess
import sys
import tempfile
import time
import tomllib
import xml.etree.ElementTree as ET
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
MUTANTS = Path(__file__).with_name("mutants.toml")
TABLE = REPO / "results" / "mutation.csv"
PLUGINS = "freefem/plugins/"
SIDE_EFFECT_RETRIES = 3
TIMEOUT_S = 3600
COLUMNS = ["id", "file", "family", "description", "caught", "first_failing_test", "first_failure", "caught_by",
           "by_results_assertion", "results_test", "results_assertion", "seconds", "equivalent"]


def load_mutants(path=MUTANTS):
    """The mutants of the data file, each checked for its keys."""
    data = tomllib.loads(path.read_text())
    mutants, seen = [], set()
    for m in data["mutant"]:
        missing = {"id", "family", "description", "edits", "tests"} - set(m)
        if missing:
            raise SystemExit(f"{path.name}: mutant {m.get('id', '?')}: missing {', '.join(sorted(missing))}")
        if m["id"] in seen:
            raise SystemExit(f"{path.name}: mutant id {m['id']} given twice")
        seen.add(m["id"])
        for edit in m["edits"]:
            if set(edit) != {"file", "find", "replace"} or edit["find"] == edit["replace"]:
                raise SystemExit(f"{path.name}: mutant {m['id']}: each edit needs file, find and a different replace")
        mutants.append(m)
    return mutants


def checkout_files():
    """The files of the checkout that git knows (tracked or untracked, not ignored)."""
    out = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"], cwd=REPO,
                         capture_output=True, check=True).stdout
    return [name for name in out.decode().split("\0") if name and (REPO / name).is_file()]


def scratch_copy(target):
    """Copy the checkout and its built plugins into target (modification times kept,
    so that make rebuilds only a plugin whose source a mutant changes)."""
    for name in checkout_files() + [str(p.relative_to(REPO)) for p in (REPO / PLUGINS).glob("*.so")]:
        dest = target / name
        dest.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(REPO / name, dest)


def apply_edits(copy, mutant, originals):
    """Replace each edit's text (exactly once in its file); originals gets each changed
    file's text and modification time before the first edit, for restore()."""
    for edit in mutant["edits"]:
        path = (copy / edit["file"]).resolve()
        if copy.resolve() not in path.parents or not path.is_file():
            raise ValueError(f"{edit['file']}: not a file of the checkout")
        text = path.read_text()
        originals.setdefault(path, (text, path.stat().st_mtime_ns))
        count = text.count(edit["find"])
        if count != 1:
            raise ValueError(f"{edit['file']}: the text to replace occurs {count} times (must be once): "
                             f"{edit['find']!r}")
        path.write_text(text.replace(edit["find"], edit["replace"]))


def restore(originals, plugin_backup):
    """Put the mutated files back as they were (text and time) and the clean plugins."""
    for path, (text, mtime) in originals.items():
        path.write_text(text)
        os.utime(path, ns=(mtime, mtime))
    for path, saved in plugin_backup.items():
        shutil.copy2(saved, path)


def build_plugins(copy):
    """make every plugin of the copy (each source's .so): only those whose sources are
    newer are rebuilt."""
    plugins = [f"{PLUGINS}{source.stem}.so" for source in sorted((copy / PLUGINS).glob("*.cpp"))]
    proc = subprocess.run(["make", "-s", *plugins], cwd=copy, capture_output=True, text=True)
    return proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]


def node_id(copy, testcase):
    """pytest's node id of a junit testcase (tests/test_x.py::Class::name[param])."""
    parts = testcase.get("classname", "").split(".")
    for i in range(len(parts), 0, -1):
        path = "/".join(parts[:i]) + ".py"
        if (copy / path).is_file():
            return "::".join([path, *parts[i:], testcase.get("name", "")])
    return testcase.get("classname", "") + "::" + testcase.get("name", "")


def failures(copy, xml_path):
    """(node id, kind, failing line, message) of each failed or erroring test of a junit file."""
    found = []
    if not xml_path.is_file():
        return found
    for case in ET.parse(xml_path).getroot().iter("testcase"):
        for kind in ("failure", "error"):
            element = case.find(kind)
            if element is not None:
                text = element.text or ""
                found.append((node_id(copy, case), kind, failing_line(text), first_error_line(text, element)))
    return found


def failing_line(text):
    """The statement that failed: the last source line pytest marks with '>'."""
    lines = [line[1:].strip() for line in text.splitlines() if line.startswith(">")]
    return lines[-1] if lines else ""


def first_error_line(text, element):
    """The first line pytest prints with 'E' (the assertion or the exception)."""
    lines = [line[1:].strip() for line in text.splitlines() if line.startswith("E ")]
    return lines[0] if lines else (element.get("message") or "").split("\n")[0]


def failure_kind(kind, line, message):
    """What a failure says: 'results assertion' (about what the code computed), 'run
    failed' (a run meant to converge exited non-zero), 'negative test' (a run meant to
    fail did otherwise) or 'exception' (not an assertion)."""
    if kind != "failure" or not (line.startswith("assert") or message.startswith(("assert", "AssertionError"))):
        return "exception"
    if "driver failed" in message or "returncode == 0" in line:
        return "run failed"
    if "returncode" in line or "stderr" in line or "stdout" in line:
        return "negative test"
    return "results assertion"


def pytest_run(copy, tests, deselect, xml_path, exitfirst=True):
    env = dict(os.environ, FF_LOADPATH=os.environ.get("FF_LOADPATH", "/usr/lib/freefem++"))
    args = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", f"--junitxml={xml_path}", *tests]
    if exitfirst:
        args.insert(4, "-x")
    for node in deselect:
        args += ["--deselect", node]
    if xml_path.exists():
        xml_path.unlink()
    try:
        proc = subprocess.run(args, cwd=copy, env=env, capture_output=True, text=True, timeout=TIMEOUT_S)
    except subprocess.TimeoutExpired:
        return None, []
    return proc.returncode, failures(copy, xml_path)


def short(text, size=160):
    text = " ".join(str(text).split())
    return text if len(text) <= size else text[:size - 3] + "..."


def run_mutant(copy, mutant, scratch):
    """Apply, build if needed, run the tests, restore; returns the table row."""
    row = {"id": mutant["id"], "file": " ".join(dict.fromkeys(e["file"] for e in mutant["edits"])),
           "family": mutant["family"], "description": mutant["description"], "first_failing_test": "",
           "first_failure": "", "caught_by": "", "by_results_assertion": "no", "results_test": "",
           "results_assertion": "", "equivalent": mutant.get("equivalent", "")}
    start = time.monotonic()
    backup, originals = {}, {}
    try:
        plugin_files = [e["file"] for e in mutant["edits"] if e["file"].startswith(PLUGINS)]
        if plugin_files:
            for so in (copy / PLUGINS).glob("*.so"):
                saved = scratch / "plugins-clean" / so.name
                saved.parent.mkdir(exist_ok=True)
                if not saved.exists():
                    shutil.copy2(so, saved)
                backup[so] = saved
        apply_edits(copy, mutant, originals)
        if plugin_files:
            built, log = build_plugins(copy)
            if not built:
                row.update(caught="build fails", first_failure=short(log))
                return row
        xml_path = scratch / "junit.xml"
        deselect = []
        for attempt in range(SIDE_EFFECT_RETRIES + 1):
            code, failed = pytest_run(copy, mutant["tests"], deselect, xml_path)
            if code is None:
                if "caught" not in row:
                    row.update(caught="yes", first_failure=f"timeout after {TIMEOUT_S} s", caught_by="timeout")
                break
            if not failed:
                if code not in (0, 5) and attempt == 0:
                    row.update(caught="error", first_failure=f"pytest exit {code} without a failed test")
                break
            node, kind, line, message = failed[0]
            what = failure_kind(kind, line, message)
            if attempt == 0:
                row.update(caught="yes", first_failing_test=node, first_failure=short(f"{line} | {message}"),
                           caught_by=what)
            if what == "results assertion":
                row.update(by_results_assertion="yes", results_test=node, results_assertion=short(f"{line} | {message}"))
                break
            deselect.append(node)
        if "caught" not in row:
            row["caught"] = "no (equivalent)" if mutant.get("equivalent") else "no"
        elif mutant.get("equivalent"):
            print(f"  note: {mutant['id']} is marked equivalent but a test fails on it", flush=True)
    except ValueError as exc:
        row.update(caught="not applied", first_failure=short(str(exc)))
    finally:
        restore(originals, backup)
        row["seconds"] = round(time.monotonic() - start, 1)
    return row


def baseline(copy, mutants, scratch):
    tests = sorted({t for m in mutants for t in m["tests"]})
    print(f"clean copy: {len(tests)} test files", flush=True)
    start = time.monotonic()
    code, failed = pytest_run(copy, tests, [], scratch / "junit.xml", exitfirst=False)
    print(f"clean copy: {'passed' if code == 0 else 'failed'} in {time.monotonic() - start:.0f} s", flush=True)
    if code != 0:
        for node, kind, line, message in failed:
            print(f"  {kind}: {node}: {short(line)} | {short(message)}")
        raise SystemExit("the clean checkout fails its tests: every mutant would look caught; fix those first "
                         "(or --skip-baseline)")


def merged_rows(rows):
    """The new rows, plus the earlier table's rows of the mutants not run this time, in the data file's order."""
    by_id = {}
    if TABLE.is_file():
        with TABLE.open() as f:
            by_id = {r["id"]: r for r in csv.DictReader(f)}
    by_id.update({r["id"]: r for r in rows})
    order = [m["id"] for m in load_mutants()]
    return [by_id[i] for i in order if i in by_id]


def write_table(rows):
    TABLE.parent.mkdir(exist_ok=True)
    tmp = TABLE.with_suffix(".csv.tmp")
    with tmp.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    os.replace(tmp, TABLE)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", default="", help="comma-separated mutant ids (default: all)")
    parser.add_argument("--skip-baseline", action="store_true", help="do not run the clean copy's tests first")
    parser.add_argument("--list", action="store_true", help="list the mutants and exit")
    args = parser.parse_args(argv)
    mutants = load_mutants()
    if args.list:
        for m in mutants:
            print(f"{m['id']:32s} {m['family']:16s} {m['description']}")
        return 0
    if args.only:
        wanted = [i.strip() for i in args.only.split(",") if i.strip()]
        unknown = set(wanted) - {m["id"] for m in mutants}
        if unknown:
            raise SystemExit(f"unknown mutant ids: {', '.join(sorted(unknown))}")
        mutants = [m for m in mutants if m["id"] in wanted]
    with tempfile.TemporaryDirectory(prefix="fdcontact-mutation-") as tmp:
        scratch = Path(tmp)
        copy = scratch / "checkout"
        scratch_copy(copy)
        if not args.skip_baseline:
            baseline(copy, mutants, scratch)
        rows = []
        for n, mutant in enumerate(mutants, 1):
            print(f"[{n}/{len(mutants)}] {mutant['id']}: {mutant['description']}", flush=True)
            row = run_mutant(copy, mutant, scratch)
            print(f"  caught: {row['caught']}; results assertion: {row['by_results_assertion']} "
                  f"{row['results_test']} ({row['seconds']} s)", flush=True)
            rows.append(row)
            write_table(merged_rows(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
