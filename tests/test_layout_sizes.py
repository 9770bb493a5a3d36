"""lab/layout_sizes.py, the layout's sizes at revisions: on this tree it agrees
with the layout tests (no stage name read by pasting a body index, no per-body name
declared by pasting) and finds the stages' shared names (a scan that found none would
report a layout it cannot see)."""
from lab.layout_sizes import REPO, sizes, top_level_declarations


def test_the_sizes_of_this_tree_agree_with_the_layout_tests():
    found = sizes(REPO)
    assert found["stage names read by pasting a body index"] == 0
    assert found["of them from a body index"] == 0
    assert found["modules (lib/)"] > 60 and found["macro names"] > 400
    assert 100 < found["top-level names shared between 2D stages"] < 400
    assert 100 < found["top-level names shared between 3D stages"] < 400


def test_a_declaration_inside_braces_is_not_top_level():
    body = "real[int] qx(1), qw(1);\n{ real t = 0; }\nint nq = qx.n;\nif (a) { matrix M; }\n"
    assert top_level_declarations(body) == ["qx", "qw", "nq"]
