"""The FreeFEM code's layout rules (docs/design.md "How the FreeFEM code is laid out"),
read from the sources: the contact law has one home, the 2D and 3D scripts run the
same stages in the same order, no name is declared by token pasting, and
every module has an include guard. No FreeFEM run: these are facts about the text."""
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FREEFEM = ROOT / "freefem"
MODULES = sorted(FREEFEM.rglob("*.idp"))
SOURCES = MODULES + sorted(FREEFEM.rglob("*.edp"))
SCRIPTS_TWO_BODY = [FREEFEM / "fd_contact_2d.edp", FREEFEM / "fd_contact_3d.edp"]

# The law's positive part [d]_+ divided by gamma, however it is spelled.
POSITIVE_PART = re.compile(r"max\(\s*[^(),]+,\s*0\.?\s*\)\s*/\s*\(?\s*gam")
# A declaration: at the start of a statement (or of a macro's body), a type, then its
# declarators up to the semicolon. The type is any name, since a macro declares with
# the space or type it is given (`Dh s(4)`, `fdDc#Vhi[int] GB(6)`); words that start
# other statements are not types.
NOT_A_TYPE = r"(?:macro|else|return|if|for|while|include|load|break|continue|func|IFMACRO|ENDIFMACRO|cout)\b"
DECLARATION = re.compile(
    r"(?:^|[;{}]|\bmacro\s+\w+\([^)]*\))[ \t]*(?!" + NOT_A_TYPE + r")[A-Za-z_][\w#]*(?:\[int\])*[ \t]+"
    r"(?=([A-Za-z_\[][^;]*))", re.M)
# A name made from a body-index macro parameter (cut#i#K, hold#b, ...).
BODY_PASTED = re.compile(r"[A-Za-z_]\w*#(?:i|b)\b|\b(?:i|b)#[A-Za-z_]")


def code(path):
    """The source without its // comments and /* */ comments."""
    text = path.read_text()
    text = re.sub(r"/\*.*?\*/", " ", text, flags=re.S)
    return re.sub(r"//[^\n]*", "", text)


def declared_names(declarators):
    """The names a declaration's comma-separated declarators introduce (top level only)."""
    names, depth, current = [], 0, ""
    for ch in declarators + ",":
        if ch in "([{":
            depth += 1
        elif ch in ")]}":
            depth -= 1
        if ch == "," and depth == 0:
            names.append(re.split(r"[=(\[\s]", current.strip(), maxsplit=1)[0])
            current = ""
        else:
            current += ch
    return [n for n in names if n]


def test_the_positive_part_of_the_contact_law_has_one_home():
    homes = sorted(str(p.relative_to(FREEFEM)) for p in SOURCES if POSITIVE_PART.search(code(p)))
    assert homes == ["lib/core/contact_law.idp"]


def stage_sequence(script):
    """Every fd... macro the step loop expands, in order, also those behind an if."""
    text = code(script)
    loop = text[text.index("for (int step = 0;"):]
    return re.findall(r"^\s*(?:if\s*\([^\n]*?\)\s*)?(fd[A-Z]\w*)\b", loop, re.M)


# The steps one dimension has and the other not, each for a reason.
ONLY_2D = {
    "fdExportNewtonMatrix": "-export_matrix writes the Newton matrix (a 2D study's conditioning)",
    "fdSaveSolution": "2D saves each adapted step for the error tool (3D saves the last, in fdResultsFiles)",
    "fdKeepPrevious": "the next adapted step's Newton starts from this step's solution (adaptmesh)",
}
ONLY_3D = {
    "fdEstimatorsVtu3": "estimators.vtu (2D writes its estimator fields into fields.vtu)",
}


def test_the_2d_and_3d_scripts_run_the_same_stages_in_the_same_order():
    two, three = (stage_sequence(s) for s in SCRIPTS_TWO_BODY)
    assert two[:3] == ["fdStageGeometry", "fdStageAssembly", "fdStageNewton"]
    assert set(ONLY_2D) <= set(two) and set(ONLY_3D) <= set(three)
    assert [n for n in two if n not in ONLY_2D] == [n for n in three if n not in ONLY_3D]


def pasted_declarations(source):
    """The names the declarations of a source make by token pasting (a `#` in the name)."""
    return [name for match in DECLARATION.finditer(source) for name in declared_names(match.group(1))
            if "#" in name]


def test_no_name_is_declared_by_token_pasting():
    """A record is an array with named components or fields written out at the call
    (docs/design.md), so grep finds every name where it is declared."""
    offenders = [f"{path.relative_to(FREEFEM)}: {name}" for path in SOURCES
                 for name in pasted_declarations(code(path))]
    assert len(SOURCES) > 70 and offenders == []


def test_the_declaration_scan_sees_a_pasted_name():
    """The scan above would catch a regression: pasted declarations in the forms the
    modules used, among declarations and pasted reads it must let pass."""
    sample = ("real[int] cut#i#K = seg#i#K, cv#i#x(0);\nint nCurvedFallback#i = 0;\n"
              "macro stressOf(Dh, s) Dh s#xx = sigXX(u), s#xy(2); //\n"
              "macro holdRows(p)\nmatrix p#Ux, p#Uy;\n//\n"
              "fdDc#Vhi GB#xx = sig3XX(lam);\nfespace W#fx(Thi, [P2, P2]);\n"
              "real[int] kept(3); matrix[int] G(4); Dh1[int] sig1(4);\n"
              "if (p#N > 0) kept#w.resize(3); else arr = p#y;\nt#c[q] -= s*n#c[q]; G[gradXY] = R;\n")
    found = [name for m in DECLARATION.finditer(sample) for name in declared_names(m.group(1))]
    assert {"kept", "G", "sig1", "arr"} & set(found) == {"kept", "G", "sig1"}
    assert pasted_declarations(sample) == ["cut#i#K", "cv#i#x", "nCurvedFallback#i", "s#xx", "s#xy",
                                           "p#Ux", "p#Uy", "GB#xx", "W#fx"]
    assert [n for n in pasted_declarations(sample) if BODY_PASTED.search(n)] == ["cut#i#K", "cv#i#x",
                                                                               "nCurvedFallback#i"]


# The scene module's per-body interface (docs/scene-modules.md), the one family of
# names a macro may still read by pasting a body index: a stage's names reach the
# macros as arguments or as a record prefix written at the call (ci1, hold1, sig1).
SCENE_PER_BODY = {"phi", "holdFace", "loadFace", "holdCut", "loadCut", "holdCutAny", "loadCutAny", "holdCutCount"}
BODY_PASTED_READ = re.compile(r"([A-Za-z_]\w*)#(?:i|b)\b")


def pasted_stage_reads(source):
    return [m.group(0) for m in BODY_PASTED_READ.finditer(source) if m.group(1) not in SCENE_PER_BODY]


def test_no_stage_name_is_read_by_pasting_a_body_index():
    offenders = [f"{path.relative_to(FREEFEM)}: {read}" for path in SOURCES for read in pasted_stage_reads(code(path))]
    assert offenders == []


def test_the_read_scan_sees_a_pasted_stage_name():
    sample = "fdTractionLoad(Vhi, load#i#qx, pts#qy, F) if (holdCutAny#i) phi#b#At(x, y);"
    assert pasted_stage_reads(sample) == ["load#i"]


def test_every_module_has_an_include_guard():
    """Generated flag-rule lists (flag_rules.idp) are data, included by their params.idp alone."""
    modules = [p for p in MODULES if p.name != "flag_rules.idp"]
    unguarded = [str(p.relative_to(FREEFEM)) for p in modules
                 if not re.match(r"\s*IFMACRO\(!\w+Included\)", code(p))]
    assert len(modules) > 60 and unguarded == []


def include_guard(path):
    """The macro a module's include guard defines (None for an unguarded file)."""
    match = re.match(r"\s*IFMACRO\(!(\w+Included)\)", code(path))
    return match.group(1) if match else None


def unguarded_includes(source, guards):
    """The include lines of a module's text that name a guarded module without its
    guard in front: FreeFEM opens and scans a file at every include, so a module
    included again re-reads it only to skip it, unless the include is written
    `IFMACRO(!guard) include "..." ENDIFMACRO`."""
    found = []
    for line in source.splitlines():
        match = re.search(r'include\s+"freefem/([^"]+)"', line)
        if not match or line.lstrip().startswith("//") or match.group(1) not in guards:
            continue
        guard = guards[match.group(1)]
        if not re.match(r"\s*IFMACRO\(!%s\)\s*include\s+\"[^\"]+\"\s*ENDIFMACRO" % guard, line):
            found.append(match.group(1))
    return found


def test_every_module_skips_a_module_already_included_without_opening_it():
    guards = {str(p.relative_to(FREEFEM)): include_guard(p) for p in MODULES if include_guard(p)}
    bad = {str(p.relative_to(FREEFEM)): unguarded_includes(p.read_text(), guards)
           for p in MODULES}
    assert len(guards) > 60 and {k: v for k, v in bad.items() if v} == {}


def test_the_include_site_check_sees_a_bare_or_misguarded_include():
    guards = {"lib/core/args.idp": "coreArgsIncluded"}
    assert unguarded_includes('include "freefem/lib/core/args.idp"', guards) == ["lib/core/args.idp"]
    assert unguarded_includes('IFMACRO(!coreResultsIncluded) include "freefem/lib/core/args.idp" ENDIFMACRO',
                              guards) == ["lib/core/args.idp"]
    assert unguarded_includes('IFMACRO(!coreArgsIncluded) include "freefem/lib/core/args.idp" ENDIFMACRO',
                              guards) == []


# Which modules a module may include: core/ is shared, except the dimension's
# elasticity and the 2D adaptation helper; the scene module and the flags are the
# script's, never a module's.
DIMENSIONAL_CORE = {"elasticity2d.idp": "core2d", "adapt2d.idp": "core2d", "elasticity3d.idp": "core3d"}
MAY_INCLUDE = {"core": {"core"}, "core2d": {"core", "core2d"}, "core3d": {"core", "core3d"},
               "fd2d": {"fd2d", "core", "core2d"}, "fd3d": {"fd3d", "core", "core3d"},
               "foundation": {"foundation", "core", "core2d"}}
SCRIPT_HOOKS = {"scene_default.idp", "params.idp", "params_two_body.idp", "flag_rules.idp"}
LIBRARY = [p for p in MODULES if p.parent.parent == FREEFEM / "lib"]


def family(path):
    folder = path.parent.name
    return DIMENSIONAL_CORE.get(path.name, folder) if folder == "core" else folder


def definitions():
    """Macro and function names -> the library modules defining them."""
    found = {}
    for path in LIBRARY:
        text = code(path)
        for name in re.findall(r"^\s*macro\s+(\w+)", text, re.M) + \
                re.findall(r"^\s*func\s+[\w\[\]]+\s+(\w+)\s*\(", text, re.M):
            found.setdefault(name, set()).add(path)
    return found


def missing_includes(path, defined, source=None):
    """The modules whose macros or functions the module at path (its text: source, or
    the file's) uses without including them. A name defined in the module's own
    folder and in core/ is the folder's (2D and 3D twins); a name only other
    dimensions define is a hook the script supplies."""
    source = path.read_text() if source is None else source
    text = re.sub(r"//[^\n]*", "", re.sub(r"/\*.*?\*/", " ", source, flags=re.S))
    text = re.sub(r'"[^"\n]*"', '""', text)   # words in strings name nothing
    own = set(re.findall(r"^\s*macro\s+(\w+)", text, re.M))
    # a macro's parameter is the macro's own name for its argument, not a module's macro
    own |= {p.strip() for params in re.findall(r"^\s*macro\s+\w+\(([^)]*)\)", text, re.M)
            for p in params.split(",")}
    included = {FREEFEM / m for m in re.findall(r'include\s+"freefem/([^"]+)"', source)}
    needed = set()
    for name in set(re.findall(r"\b[A-Za-z_]\w*\b", text)) - own:
        homes = [q for q in defined.get(name, ()) if q != path and q.name not in SCRIPT_HOOKS
                 and family(q) in MAY_INCLUDE[family(path)]]
        nearest = [q for q in homes if family(q) != "core"] or homes
        needed |= set(nearest)
    return sorted(str(q.relative_to(FREEFEM)) for q in needed - included)


def test_every_module_includes_what_it_uses():
    defined = definitions()
    gaps = {str(p.relative_to(FREEFEM)): missing_includes(p, defined)
            for p in LIBRARY if p.name not in SCRIPT_HOOKS}
    assert {k: v for k, v in gaps.items() if v} == {}


def test_the_include_check_sees_a_missing_include():
    """A 2D module calling the 2D spaces' fdBodyMesh without including them is reported,
    and is not once it includes them."""
    defined = definitions()
    probe = FREEFEM / "lib" / "fd2d" / "probe.idp"   # a path for its folder; never written
    text = "IFMACRO(!probeIncluded)\nmacro probeIncluded()1\n{}macro probe() fdBodyMesh(Th, inBody1, Th1) //\nENDIFMACRO\n"
    assert missing_includes(probe, defined, text.format("")) == ["lib/fd2d/spaces.idp"]
    assert missing_includes(probe, defined, text.format('include "freefem/lib/fd2d/spaces.idp"\n')) == []


def one_dimension_calls(path, defined, source=None):
    """The names a shared core module (source: its text, or the file's) uses that a
    dimension folder defines but not both fd2d/ and fd3d/ (nor core/): a call that
    would make the module written once work in one dimension only."""
    source = path.read_text() if source is None else source
    text = re.sub(r"//[^\n]*", "", re.sub(r"/\*.*?\*/", " ", source, flags=re.S))
    text = re.sub(r'"[^"\n]*"', '""', text)
    own = set(re.findall(r"^\s*macro\s+(\w+)", text, re.M))
    found = []
    for name in sorted(set(re.findall(r"\b[A-Za-z_]\w*\b", text)) - own):
        families = {family(q) for q in defined.get(name, ()) if q != path}
        if families and "core" not in families and not {"fd2d", "fd3d"} <= families:
            found.append(name)
    return found


def test_the_shared_core_calls_only_what_both_dimensions_define():
    """A core module written once reaches the dimension through hooks both define
    (fdEachAxis, fdDot, fdJsonCutOwn, ..), never through one dimension's macro."""
    defined = definitions()
    calls = {str(p.relative_to(FREEFEM)): one_dimension_calls(p, defined)
             for p in LIBRARY if family(p) == "core"}
    assert {k: v for k, v in calls.items() if v} == {}


def test_the_hook_check_sees_a_one_dimension_call():
    """A core module calling the 2D-only nitscheKeepPoints is reported; calling the hook
    fdEachAxis, which both dimension.idp define, is not."""
    defined = definitions()
    probe = FREEFEM / "lib" / "core" / "probe.idp"   # a path for its folder; never written
    text = "IFMACRO(!probeIncluded)\nmacro probeIncluded()1\nmacro probe(p) {} //\nENDIFMACRO\n"
    assert one_dimension_calls(probe, defined, text.format("nitscheKeepPoints(a, b, c, d, e, f, g, h, i)")) \
        == ["nitscheKeepPoints"]
    assert one_dimension_calls(probe, defined, text.format("fdEachAxis(M, p)")) == []
