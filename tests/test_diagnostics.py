"""One test per class of bad input: the message, the exact line:column, and the
command line's compiler-style report (``file:line:col: error: ...``, the source
line and a caret).  Columns are derived from the spec text, never hard-coded.
"""

from __future__ import annotations

import contextlib
import io
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest
from conftest import SPECS

from kms2pin import SpecError, load, parse_text
from kms2pin.cli import main
from kms2pin.errors import Diagnostic

BASE = """\
double fac = 1.25;

ellipsoidBody Leg(double length, bool left) {
    innerLam(0.1, 0.1, length);
    outerLam(fac*0.1, fac*0.1, fac*length);
    bvec hip {
        pos(0, 0, 0.8*length);
        orient(-1, 0, 0);
    }
    bvec knee {
        pos(0, 0, -0.8*length);
        orient(-1, 0, 0);
    }
}

bvec origin {
    pos(0, 0, 1);
    orient(0, 1, 0);
}

rigidBodySystem walker {
    ellipsoidBody pelvis {
        innerLam(0.2, 0.1, 0.1);
        outerLam(0.25, 0.125, 0.125);
        bvec anchor {
            pos(0, 0, 0);
            orient(0, 1, 0);
        }
        bvec leftHip {
            pos(0.1, -0.1, 0);
            orient(-1, 0, 0);
        }
    }
    Leg leftThigh(0.4, true);
    Leg leftShin(0.4, true);
    constraint revolute(pelvis.leftHip, leftThigh.hip, 80);
    constraint revolute(leftShin.knee, leftThigh.knee, 20);
}

constraint revolute(walker.pelvis.anchor, origin);
"""


def edit(old: str, new: str, text: str = BASE) -> str:
    assert text.count(old) == 1, f"{old!r} must occur once"
    return text.replace(old, new)


def where(text: str, needle: str, nth: int = 0) -> tuple[int, int]:
    """1-based (line, column) of the nth occurrence of ``needle`` in ``text`` (-1: the last)."""
    if nth < 0:
        return where(text, needle, text.count(needle) + nth)
    at = -1
    for _ in range(nth + 1):
        at = text.index(needle, at + 1)
    line = text.count("\n", 0, at) + 1
    return line, at - (text.rfind("\n", 0, at) + 1) + 1


def diagnostics(text: str):
    with pytest.raises(SpecError) as err:
        parse_text(text, "walker.kms")
    return err.value.diagnostics


def only(text: str, message: str, needle: str, nth: int = 0, exact: bool = True, call: str = ""):
    """The spec has exactly one error, with ``message``, at ``needle``; for an error in
    a body function, followed by the note naming the ``call`` that ran it."""
    ds = diagnostics(text)
    assert len(ds) == (2 if call else 1), "\n".join(d.format() for d in ds)
    d = ds[0]
    if exact:
        assert d.message == message
    else:
        assert message in d.message, d.message
    assert (d.line, d.column) == where(text, needle, nth)
    assert d.path == "walker.kms"
    assert d.source_line == text.splitlines()[d.line - 1]
    report = [f"{{path}}:{d.line}:{d.column}: error: {d.message}", *shown(d.source_line, d.column)]
    if call:
        line, col = where(text, call + "(")
        source = text.splitlines()[line - 1]
        assert ds[1] == Diagnostic("walker.kms", line, col, f"in call '{call}(...)'", source, "note")
        report += [
            f"{{path}}:{line}:{col}: note: in call '{call}(...)'",
            "    " + source,
            "    " + " " * (col - 1) + "^",
        ]
    assert cli_report(text) == report
    return d


def shown(source: str, column: int) -> list[str]:
    """The two lines a report shows for ``source`` and ``column``: the whole line and a
    caret, or for a line over 100 characters, 100 of them around the caret, "..."
    marking each cut end."""
    if len(source) <= 100:
        return ["    " + source, "    " + " " * (column - 1) + "^"]
    start = min(max(column - 1 - 50, 0), len(source) - 100)
    text = ("..." if start else "") + source[start : start + 100] + ("..." if start + 100 < len(source) else "")
    return ["    " + text, "    " + " " * (column - 1 - start + (3 if start else 0)) + "^"]


def cli_report(text: str) -> list[str]:
    """What ``kms2pin check`` prints on stderr for a file holding ``text`` (exit status 1);
    the file's name is replaced by ``{path}``."""
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "walker.kms"
        path.write_text(text)
        err, out = io.StringIO(), io.StringIO()
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
            assert main(["check", str(path)]) == 1
        assert out.getvalue() == ""
        return err.getvalue().replace(str(path), "{path}").splitlines()


def test_the_base_spec_is_valid():
    spec = parse_text(BASE)
    assert [b.name for b in spec.systems[0].bodies] == ["pelvis", "leftThigh", "leftShin"]


# ----------------------------------------------------------------------------- syntax


def test_syntax_error_says_what_was_expected():
    text = edit("innerLam(0.2, 0.1, 0.1);", "innerLam(0.2, 0.1 0.1);")
    d = only(text, "syntax error: unexpected '0.1'; expected one of", "0.1);", exact=False)
    assert "','" in d.message and "')'" in d.message


def test_missing_semicolon_points_just_after_the_previous_token():
    text = edit("outerLam(0.25, 0.125, 0.125);", "outerLam(0.25, 0.125, 0.125)")
    line, col = where(text, "outerLam(0.25, 0.125, 0.125)")
    ds = diagnostics(text)
    assert len(ds) == 1
    assert ds[0].message == "syntax error: expected ';' after ')'"
    assert (ds[0].line, ds[0].column) == (line, col + len("outerLam(0.25, 0.125, 0.125)"))


def test_missing_semicolon_on_the_same_line():
    text = edit("double fac = 1.25;", "double fac = 1.25 double x = 1;")
    only(text, "syntax error: unexpected 'double'; expected one of", "double x", exact=False)
    assert "';'" in diagnostics(text)[0].message


def test_unexpected_end_of_file():
    text = BASE.rstrip().removesuffix(";")
    d = diagnostics(text)[0]
    assert d.message.startswith("syntax error: unexpected end of file; expected")
    assert d.line == len(text.splitlines())


def test_unexpected_character():
    text = edit("double fac = 1.25;", "double fac = 1.25 @;")
    only(text, "syntax error: unexpected character '@'", "@")


def test_unterminated_comment_points_at_its_start():
    only(BASE + "/* never closed\n", "unterminated comment", "/* never")
    text = edit("double fac = 1.25;", "double fac = 1.25 /* never closed;")
    only(text, "unterminated comment", "/* never")


def test_a_syntax_error_before_an_unterminated_comment_comes_first():
    text = edit("double fac = 1.25;", "double fac = 1.25 @;") + "/* never closed\n"
    only(text, "syntax error: unexpected character '@'", "@")


def test_a_stray_token_after_a_semicolon_is_not_a_missing_semicolon():
    only(BASE + "* 2;\n", "syntax error: unexpected '*'; expected one of", "* 2", exact=False)


# ----------------------------------------------------------------------------- names


def test_unknown_variable():
    text = edit("fac*length);", "fac*lenght);")
    only(text, "unknown variable 'lenght' (did you mean 'length'?)", "lenght", call="Leg leftThigh")


def test_unknown_body():
    text = edit("revolute(leftShin.knee", "revolute(leftShim.knee")
    only(text, "unknown body 'leftShim' (did you mean 'leftShin'?)", "leftShim")


def test_unknown_bvec_points_at_the_bvec():
    text = edit("leftThigh.knee, 20", "leftThigh.kne, 20")
    d = only(text, "body 'leftThigh' has no bound vector 'kne' (did you mean 'knee'?)", "kne,")
    assert d.column == text.splitlines()[d.line - 1].index("kne,") + 1


def test_unknown_system_and_unknown_body_in_a_system():
    text = edit("revolute(walker.pelvis", "revolute(walkr.pelvis")
    only(text, "unknown rigidBodySystem 'walkr' (did you mean 'walker'?)", "walkr")
    text = edit("revolute(walker.pelvis", "revolute(walker.pelvs")
    only(text, "system 'walker' has no body 'pelvs' (did you mean 'pelvis'?)", "pelvs")


def test_unknown_inertial_bvec():
    text = edit("anchor, origin);", "anchor, orgin);")
    only(text, "unknown inertial bound vector 'orgin' (did you mean 'origin'?)", "orgin")


def test_unknown_body_function():
    text = edit("Leg leftShin", "Lge leftShin")
    only(text, "unknown body function 'Lge' (did you mean 'Leg'?)", "Lge leftShin")


def test_wrong_argument_count():
    text = edit("Leg leftShin(0.4, true)", "Leg leftShin(0.4)")
    only(
        text,
        "body function 'Leg' takes 2 arguments (double length, bool left), but 1 was given",
        "Leg leftShin",
    )


def test_wrong_argument_type_points_at_the_argument():
    text = edit("Leg leftShin(0.4, true)", "Leg leftShin(0.4, 1)")
    only(text, "argument 2 of 'Leg' ('left') must be bool, not double", "1);", nth=-1)


def test_wrong_argument_count_of_statements_and_maths_functions():
    text = edit("innerLam(0.2, 0.1, 0.1);", "innerLam(0.2, 0.1);")
    only(text, "'innerLam' takes 3 arguments (x, y, z), not 2", "innerLam(0.2")
    text = edit("double fac = 1.25;", "double fac = atan2(1.25);")
    only(text, "'atan2' takes 2 arguments, not 1", "atan2")
    text = edit("leftThigh.knee, 20);", "leftThigh.knee, 20, 30);")
    only(
        text,
        "constraint revolute(a, b[, defaultAngle[, lower, upper]]) takes 2, 3 or 5 arguments, not 4",
        "constraint revolute(leftShin",
    )


def test_duplicate_variable_in_one_scope():
    text = edit("double fac = 1.25;", "double fac = 1.25;\ndouble fac = 2;")
    only(text, "'fac' is already declared in this scope, as a variable (line 1)", "fac", nth=1)


def test_duplicate_body_in_a_system():
    text = edit("    Leg leftShin(0.4, true);\n", "    Leg leftShin(0.4, true);\n    Leg leftShin(0.5, true);\n")
    only(text, "system 'walker' already has a body 'leftShin' (line 35)", "leftShin", nth=1)


def test_duplicate_literal_body_name():
    text = edit(
        "    Leg leftThigh", "    ellipsoidBody pelvis { innerLam(1,1,1); outerLam(1,1,1); }\n    Leg leftThigh"
    )
    only(text, "system 'walker' already has a body 'pelvis' (line 22)", "pelvis", nth=1)


def test_duplicate_bvec_in_a_body():
    text = edit(
        "        bvec leftHip {", "        bvec anchor { pos(1, 0, 0); orient(1, 0, 0); }\n        bvec leftHip {"
    )
    only(text, "body 'pelvis' already has a bound vector 'anchor' (line 25)", "anchor", nth=1)


def test_duplicate_bvec_in_a_body_function_is_reported_once_per_body():
    text = edit("    bvec knee {", "    bvec hip { pos(0, 0, 0); orient(1, 0, 0); }\n    bvec knee {")
    ds = diagnostics(text)
    assert [(d.severity, d.message) for d in ds] == [
        ("error", "body 'leftThigh' already has a bound vector 'hip' (line 6)"),
        ("note", "in call 'Leg leftThigh(...)'"),
        ("error", "body 'leftShin' already has a bound vector 'hip' (line 6)"),
        ("note", "in call 'Leg leftShin(...)'"),
    ]
    hip = where(text, "hip", 1)
    assert [(d.line, d.column) for d in ds] == [hip, where(text, "Leg leftThigh"), hip, where(text, "Leg leftShin")]


def test_an_error_inside_a_body_function_is_reported_once():
    """Both Leg instantiations run the bad line; one message, at the line in the function,
    with a note naming the first call."""
    text = edit("fac*length);", "fac*lenght);")
    ds = diagnostics(text)
    assert [(d.severity, d.line, d.column) for d in ds] == [
        ("error", *where(text, "lenght")),
        ("note", *where(text, "Leg leftThigh")),
    ]


def test_a_value_error_in_a_body_function_names_the_call_that_caused_it():
    text = edit("Leg leftShin(0.4, true)", "Leg leftShin(0.4, false)")
    text = edit("pos(0, 0, 0.8*length);", "pos(0, 0, 0.8*length / (left ? 1 : 0));", text)
    only(text, "division by zero", "/ (left", call="Leg leftShin")


def test_a_check_of_a_finished_body_names_the_call_that_built_it():
    text = edit("Leg leftShin(0.4, true)", "Leg leftShin(-0.4, true)")
    ds = diagnostics(text)
    assert [(d.severity, d.line, d.column, d.message) for d in ds] == [
        ("error", *where(text, "innerLam(0.1"), "innerLam semi-axes must be positive, got (0.1, 0.1, -0.4)"),
        ("note", *where(text, "Leg leftShin"), "in call 'Leg leftShin(...)'"),
        ("error", *where(text, "outerLam(fac"), "outerLam semi-axes must be positive, got (0.125, 0.125, -0.5)"),
        ("note", *where(text, "Leg leftShin"), "in call 'Leg leftShin(...)'"),
    ]


def test_the_fullbody_shin_with_a_negative_radius_is_reported_with_its_call(tmp_path, capsys):
    lines = (SPECS / "fullbody.kms").read_text().splitlines(keepends=True)
    assert lines[165] == "    Shin rightShin(0.55, 0.23);\n"
    lines[165] = "    Shin rightShin(0.55, -0.23);\n"
    spec = tmp_path / "fb_neg.kms"
    spec.write_text("".join(lines))
    assert main(["check", str(spec)]) == 1
    assert capsys.readouterr().err.splitlines()[:6] == [
        f"{spec}:71:5: error: innerLam semi-axes must be positive, got (-0.23, -0.23, 0.55)",
        "        innerLam(radius,radius,length);",
        "        ^",
        f"{spec}:166:5: note: in call 'Shin rightShin(...)'",
        "        Shin rightShin(0.55, -0.23);",
        "        ^",
    ]


# ----------------------------------------------------------------------------- joints and the tree


def test_two_joints_between_the_same_bodies():
    text = edit(
        "    constraint revolute(leftShin.knee, leftThigh.knee, 20);\n",
        "    constraint revolute(leftShin.knee, leftThigh.knee, 20);\n"
        "    constraint fixed(leftThigh.hip, leftShin.hip);\n",
    )
    only(
        text,
        "a second joint between 'leftThigh' and 'leftShin' (the first is on line 37)",
        "constraint fixed",
    )


def loop_error(text: str, needle: str) -> Diagnostic:
    """A spec the language accepts whose one loop cannot be closed at rest: loading it (and
    ``kms2pin check``) reports it once, at ``needle``, compiler-style."""
    spec = parse_text(text, "walker.kms")
    with pytest.raises(SpecError) as err:
        load(spec)
    (d,) = err.value.diagnostics
    assert (d.line, d.column) == where(text, needle)
    assert d.source_line == text.splitlines()[d.line - 1]
    assert cli_report(text) == [f"{{path}}:{d.line}:{d.column}: error: {d.message}", *shown(d.source_line, d.column)]
    return d


KNEE = "    constraint revolute(leftShin.knee, leftThigh.knee, 20);\n"


def test_a_loop_that_cannot_close_at_rest_names_its_bodies_its_gap_and_the_joints_to_change():
    # breadth first from the pelvis, the fixed joint reaches the shin before the knee does:
    # the knee closes the loop
    text = edit(KNEE, "    constraint revolute(leftShin.knee, leftThigh.knee);\n"
                      "    constraint fixed(pelvis.anchor, leftShin.hip);\n")
    d = loop_error(text, "constraint revolute(leftShin")
    assert "this revolute joint closes the loop leftShin -> pelvis -> leftThigh -> leftShin" in d.message
    assert "cannot be closed near the rest pose" in d.message
    assert "apart and their axes" in d.message
    assert "(leftShin_hip, leftThigh_hip)" in d.message


def test_a_loop_through_the_inertial_frame_that_cannot_close():
    text = edit(KNEE, "    constraint revolute(leftShin.knee, leftThigh.knee);\n") + \
        "constraint fixed(walker.leftShin.hip, origin);\n"
    d = loop_error(text, "constraint revolute(leftShin")
    assert "closes the loop leftShin -> inertial frame -> pelvis -> leftThigh -> leftShin" in d.message


def test_a_loop_closing_joint_with_a_rest_value_is_refused_at_the_value():
    text = edit(KNEE, KNEE + "    constraint fixed(pelvis.anchor, leftShin.hip);\n")
    only(text, "this revolute joint closes a kinematic loop, and a loop-closing joint takes no rest value or "
               "limits: its value follows from the joints of the tree (leave them out, or write the joints so "
               "that another one closes the loop)", "20);")


def test_a_joint_from_a_body_to_itself():
    text = BASE + "constraint fixed(walker.leftShin.knee, walker.leftShin.hip);\n"
    only(text, "this joint connects body 'leftShin' to itself", "constraint fixed")


def test_body_without_a_path_to_the_inertial_frame():
    text = edit("    constraint revolute(leftShin.knee, leftThigh.knee, 20);\n", "")
    only(
        text,
        "body 'leftShin' has no path to the inertial frame (no chain of joints connects it)",
        "leftShin",
    )


def test_system_without_a_joint_to_the_inertial_frame():
    text = edit("constraint revolute(walker.pelvis.anchor, origin);\n", "")
    only(text, "rigidBodySystem 'walker' has no joint to the inertial frame", "walker")


def test_spec_without_a_system():
    ds = diagnostics("double x = 1;\n")
    assert [(d.line, d.column, d.message) for d in ds] == [(1, 1, "the spec defines no rigidBodySystem")]


# ----------------------------------------------------------------------------- bodies and bvecs


def test_zero_orient_vector():
    text = edit("orient(0, 1, 0);\n}", "orient(0, 0, 0);\n}")
    only(text, "orient vector of 'origin' is zero; a bound vector needs a direction", "orient(0, 0, 0)")
    text = edit(
        "            pos(0.1, -0.1, 0);\n            orient(-1, 0, 0);",
        "            pos(0.1, -0.1, 0);\n            orient(0, 0, fac - 1.25);",
    )
    only(
        text,
        "orient vector of 'leftHip' of body 'pelvis' is zero; a bound vector needs a direction",
        "orient(0, 0, fac",
    )


def test_bvec_without_pos_or_orient():
    text = edit("            pos(0.1, -0.1, 0);\n", "")
    only(text, "bound vector 'leftHip' of body 'pelvis' has no pos(x, y, z)", "leftHip")
    # a bvec that no joint uses (this once crashed when the model was built)
    text = edit("        bvec leftHip {", "        bvec spare { pos(1, 2, 3); }\n        bvec leftHip {")
    only(text, "bound vector 'spare' of body 'pelvis' has no orient(x, y, z)", "spare")
    text = edit(
        "        bvec leftHip {", "        bvec spare { pos(1, 2, 3); orent(1, 0, 0); }\n        bvec leftHip {"
    )
    only(text, "unknown statement 'orent' (did you mean 'orient'?)", "orent")


def test_body_without_inner_lam():
    text = edit("        innerLam(0.2, 0.1, 0.1);\n", "")
    only(text, "body 'pelvis' has no innerLam(x, y, z)", "pelvis")


def test_body_without_outer_lam():
    text = edit("        outerLam(0.25, 0.125, 0.125);\n", "")
    only(text, "body 'pelvis' has no outerLam(x, y, z)", "pelvis")


def test_outer_ellipsoid_must_enclose_the_inner_one():
    text = edit("outerLam(0.25, 0.125, 0.125);", "outerLam(0.25, 0.05, 0.125);")
    only(
        text,
        "the outer ellipsoid (0.25, 0.05, 0.125) of body 'pelvis' does not enclose the inner one "
        "(0.2, 0.1, 0.1): each outerLam semi-axis must be >= the innerLam one",
        "outerLam(0.25, 0.05",
    )


def test_semi_axes_must_be_positive():
    text = edit("innerLam(0.2, 0.1, 0.1);", "innerLam(0.2, 0, 0.1);")
    only(text, "innerLam semi-axes must be positive, got (0.2, 0, 0.1)", "innerLam(0.2, 0,")


def test_value_errors_in_expressions():
    text = edit("double fac = 1.25;", "double fac = 1.25 / (2 - 2);")
    only(text, "division by zero", "/ (2")
    text = edit("double fac = 1.25;", "double fac = sqrt(1 - 2);")
    only(text, "'sqrt(-1)' is undefined", "sqrt")
    text = edit("double fac = 1.25;", "double fac = 1e999;")
    only(text, "this number is too large", "1e999")


def test_deep_nesting_is_reported_where_the_expression_starts():
    text = edit("double fac = 1.25;", "double fac = " + "1 + (" * 5000 + "1" + ")" * 5000 + ";")
    only(text, "this expression is nested too deeply", "+ (")


# ----------------------------------------------------------------------------- statements in the wrong place


@pytest.mark.parametrize(
    "old, new, message, needle",
    [
        (
            "    Leg leftThigh",
            "    innerLam(1, 1, 1);\n    Leg leftThigh",
            "'innerLam' is only allowed inside an ellipsoidBody",
            "innerLam(1, 1, 1)",
        ),
        (
            "        bvec anchor {",
            "        pos(1, 1, 1);\n        bvec anchor {",
            "'pos' is only allowed inside a bvec block",
            "pos(1, 1, 1)",
        ),
        (
            "            orient(0, 1, 0);\n        }\n        bvec leftHip",
            "            orient(0, 1, 0);\n            outerLam(1, 1, 1);\n        }\n        bvec leftHip",
            "'outerLam' is only allowed inside an ellipsoidBody",
            "outerLam(1, 1, 1)",
        ),
        (
            "        bvec anchor {",
            "        ellipsoidBody foo { innerLam(1, 1, 1); }\n        bvec anchor {",
            "an ellipsoidBody is not allowed in an ellipsoidBody; it belongs inside a rigidBodySystem",
            "ellipsoidBody foo",
        ),
        (
            "bvec origin {",
            "ellipsoidBody stray { innerLam(1, 1, 1); }\nbvec origin {",
            "an ellipsoidBody is not allowed at top level; it belongs inside a rigidBodySystem",
            "ellipsoidBody stray",
        ),
        (
            "    Leg leftThigh",
            "    rigidBodySystem inner { }\n    Leg leftThigh",
            "a rigidBodySystem is not allowed in a rigidBodySystem; it belongs at top level",
            "rigidBodySystem inner",
        ),
        (
            "bvec origin {",
            "Leg stray(1, true);\nbvec origin {",
            "a body instantiation is not allowed at top level; it belongs inside a rigidBodySystem",
            "Leg stray",
        ),
        (
            "        bvec anchor {",
            "        constraint fixed(leftThigh.hip, leftShin.hip);\n        bvec anchor {",
            "a constraint is not allowed in an ellipsoidBody; it belongs in a rigidBodySystem or at top level",
            "constraint fixed",
        ),
        (
            "            pos(0, 0, 0);",
            "            pos(0, 0, 0); bvec inner { pos(0, 0, 0); orient(1, 0, 0); }",
            "a bvec is not allowed in a bvec; it belongs in an ellipsoidBody or at top level",
            "bvec inner",
        ),
        (
            "        bvec anchor {",
            "        ellipsoidBody F(double x) { }\n        bvec anchor {",
            "a body function is not allowed in an ellipsoidBody; it belongs at top level or in a rigidBodySystem",
            "ellipsoidBody F",
        ),
    ],
    ids=[
        "innerLam-outside-body",
        "pos-in-body",
        "outerLam-in-bvec",
        "body-in-body",
        "body-at-top",
        "system-in-system",
        "instance-at-top",
        "constraint-in-body",
        "bvec-in-bvec",
        "function-in-body",
    ],
)
def test_statement_in_the_wrong_place(old, new, message, needle):
    only(edit(old, new), message, needle)


@pytest.mark.parametrize(
    "statement, message",
    [
        ("sin(30);", "the value of 'sin(...)' is not used; a statement here does nothing"),
        ("outerlam(1, 1, 1);", "unknown statement 'outerlam' (did you mean 'outerLam'?)"),
    ],
    ids=["unused-value", "unknown-statement"],
)
def test_a_bad_statement_in_a_body_function(statement, message):
    text = edit("    innerLam(0.1, 0.1, length);", f"    innerLam(0.1, 0.1, length);\n    {statement}")
    only(text, message, statement, call="Leg leftThigh")


def test_bad_joint_type():
    text = edit("revolute(leftShin.knee", "screw(leftShin.knee")
    only(text, "unknown joint type 'screw'; the language has fixed, revolute, spherical and prismatic joints",
         "screw")
    text = edit("revolute(leftShin.knee", "revolut(leftShin.knee")
    only(
        text,
        "unknown joint type 'revolut' (did you mean 'revolute'?); the language has fixed, revolute, spherical "
        "and prismatic joints",
        "revolut(",
    )


@pytest.mark.parametrize(
    "joint, message, needle, nth",
    [
        ("spherical(leftShin.knee, leftThigh.knee, 20)",
         "constraint spherical(a, b[, rx, ry, rz]) takes 2 or 5 arguments, not 3", "constraint spherical", 0),
        ("spherical(leftShin.knee, leftThigh.knee, 1, 2, 3, 4)",
         "constraint spherical(a, b[, rx, ry, rz]) takes 2 or 5 arguments, not 6", "constraint spherical", 0),
        ("spherical(leftShin.knee, leftThigh.knee, 1, true, 3)",
         "a rotation vector component must be a double (degrees), not bool", "true", -1),
        ("prismatic(leftShin.knee, leftThigh.knee, 0.1, 0)",
         "constraint prismatic(a, b[, offset[, lower, upper]]) takes 2, 3 or 5 arguments, not 4",
         "constraint prismatic", 0),
        ("prismatic(leftShin.knee, leftThigh.knee, false)",
         "a joint offset must be a double (spec length units), not bool", "false", -1),
        ("prismatic(leftShin.knee, leftThigh.knee, 0, 0, true)",
         "an upper joint limit must be a double (spec length units), not bool", "true", -1),
        ("prismatic(leftShin.knee, leftThigh.knee, 0, 0.5, 0.5)",
         "the lower joint limit (0.5) must be below the upper one (0.5); a joint that cannot move is "
         "constraint fixed(a, b)", "0.5, 0.5", 0),
        ("prismatic(leftShin.knee, leftThigh.knee, 0.7, -0.5, 0.5)",
         "the default offset 0.7 is outside the joint limits -0.5..0.5", "0.7", 0),
        ("prismatic(leftShin.knee, leftThigh.knee, 2e6)",
         "a prismatic offset or limit must be at most 1e+06 in size, not 2e+06", "2e6", 0),
    ],
    ids=["spherical-3-args", "spherical-6-args", "spherical-bool", "prismatic-4-args", "prismatic-bool-offset",
         "prismatic-bool-limit", "prismatic-lower-not-below-upper", "prismatic-offset-outside", "prismatic-huge"],
)
def test_bad_spherical_and_prismatic_joints(joint, message, needle, nth):
    """Each mistake in the new joints' arguments is located at its argument (or the
    constraint), as the revolute joint's are."""
    text = edit("revolute(leftShin.knee, leftThigh.knee, 20)", joint)
    only(text, message, needle, nth)


def test_a_zero_orient_on_a_prismatic_joint_is_located():
    text = edit("revolute(leftShin.knee, leftThigh.knee, 20)", "prismatic(leftShin.knee, leftThigh.knee, 0.1)")
    text = edit("            pos(0.1, -0.1, 0);\n            orient(-1, 0, 0);",
                "            pos(0.1, -0.1, 0);\n            orient(0, 0, 0);", text)
    only(text, "orient vector of 'leftHip' of body 'pelvis' is zero; a bound vector needs a direction",
         "orient(0, 0, 0)")


def test_bad_joint_arguments():
    text = edit("leftThigh.knee, 20);", "leftThigh.knee, true);")
    only(text, "a joint angle must be a double (degrees), not bool", "true", nth=-1)
    text = edit("revolute(leftShin.knee,", "revolute(leftShin,")
    only(text, "'leftShin' is a body; name one of its bound vectors: leftShin.hip, leftShin.knee", "leftShin,")
    text = edit("revolute(leftShin.knee,", "revolute(1 + 2,")
    # an operation is located at its operator
    only(text, "expected a bound vector: body.bvec, system.body.bvec or an inertial bvec name", "+ 2")


def test_reserved_body_name_world():
    text = edit("    Leg leftShin(0.4, true);", "    Leg world(0.4, true);").replace("leftShin.knee", "world.knee")
    only(text, "'world' cannot name a body: the URDF uses it for the inertial frame", "world(")


# ----------------------------------------------------------------------------- many errors at once


def test_every_error_is_reported_in_one_run_sorted_by_position():
    text = BASE
    text = edit("double fac = 1.25;", "double fac = 1.25;\nbool fac = true;", text)  # duplicate
    text = edit("fac*length);", "fac*lenght);", text)  # unknown variable (in a function)
    text = edit("outerLam(0.25, 0.125, 0.125);", "outerLam(0.25, 0.05, 0.125);", text)  # not enclosing
    text = edit("leftThigh.knee, 20", "leftThigh.kne, 20", text)  # unknown bvec
    text = edit("revolute(pelvis.leftHip", "screw(pelvis.leftHip", text)  # bad joint type
    ds = [d for d in diagnostics(text) if d.severity == "error"]
    got = [(d.line, d.column) for d in ds]
    assert got == sorted(got)
    assert [(d.line, d.column) for d in ds] == [
        where(text, "fac", 1),
        where(text, "lenght"),
        where(text, "outerLam(0.25, 0.05"),
        where(text, "screw"),
        where(text, "kne,"),
    ]
    assert "unknown variable 'lenght'" in ds[1].message
    assert "has no bound vector 'kne'" in ds[4].message


def test_one_mistake_gives_one_message():
    """A failed statement poisons what it was building, so nothing echoes it."""
    cases = [
        edit("innerLam(0.2, 0.1, 0.1);", "innerLam(0.2, 0.1, nope);"),  # no 'no innerLam' echo
        edit("            pos(0.1, -0.1, 0);", "            pos(0.1, -0.1, nope);"),  # no 'no pos' echo
        edit("Leg leftShin(0.4, true)", "Leg leftShin(0.4, 1)"),  # no 'unknown body leftShin'
        edit("Leg leftShin", "Lge leftShin"),
        edit("Leg leftShin(0.4, true)", "Leg leftShin(0.4)"),
        edit("revolute(pelvis.leftHip", "screw(pelvis.leftHip"),  # no 'no path' echo
        edit("Leg leftShin(0.4, true);", "Leg leftShin(0.4, true);\n    Leg leftShin(0.4, true);"),
    ]
    for text in cases:
        ds = diagnostics(text)
        assert len(ds) == 1, "\n".join(d.format() for d in ds)


# ----------------------------------------------------------------------------- the command line


def test_cli_prints_file_line_column_source_and_caret(tmp_path, capsys):
    text = edit("leftThigh.knee, 20", "leftThigh.kne, 20")
    spec = tmp_path / "walker.kms"
    spec.write_text(text)
    assert main(["check", str(spec)]) == 1
    out, err = capsys.readouterr()
    assert out == ""
    line, col = where(text, "kne,")
    source = text.splitlines()[line - 1]
    assert err.splitlines() == [
        f"{spec}:{line}:{col}: error: body 'leftThigh' has no bound vector 'kne' (did you mean 'knee'?)",
        f"    {source}",
        "    " + " " * (col - 1) + "^",
    ]


def test_cli_reports_all_errors_and_exits_1(tmp_path, capsys):
    text = edit("fac*length);", "fac*lenght);", edit("leftThigh.knee, 20", "leftThigh.kne, 20"))
    spec = tmp_path / "walker.kms"
    spec.write_text(text)
    for command in (["check"], ["export", "-o", str(tmp_path / "out")]):
        assert main([*command, str(spec)]) == 1
        err = capsys.readouterr().err
        heads = [line for line in err.splitlines() if ": error: " in line]
        assert len(heads) == 2
        assert heads[0].startswith(f"{spec}:{where(text, 'lenght')[0]}:")
    assert not (tmp_path / "out").exists()


def test_cli_usage_errors_exit_2(tmp_path, capsys):
    assert main(["check", str(tmp_path / "missing.kms")]) == 2
    assert "missing.kms: no such file" in capsys.readouterr().err
    assert main(["check", str(tmp_path)]) == 2
    assert "is a directory" in capsys.readouterr().err
    for argv in (["check", "--bogus", "x.kms"], ["export", "x.kms", "--root", "nowhere"], [], ["frobnicate"]):
        with pytest.raises(SystemExit) as exit_:
            main(argv)
        assert exit_.value.code == 2
    capsys.readouterr()


def test_cli_non_utf8_file_is_a_located_model_error(tmp_path, capsys):
    spec = tmp_path / "bad.kms"
    spec.write_bytes(b"double x = 1;\ndouble y = \xff;\n")
    assert main(["check", str(spec)]) == 1
    assert capsys.readouterr().err.startswith(f"{spec}:2:12: error: the file is not UTF-8 text")


BAD_EDITS = [
    ("innerLam(0.2, 0.1, 0.1);", "innerLam(0.2, 0.1 0.1);"),  # syntax
    ("leftThigh.knee, 20", "leftThigh.kne, 20"),  # names
    ("Leg leftShin(0.4, true)", "Leg world(0.4, true)"),  # reserved name
    ("double fac = 1.25;", "double fac = 1.25;" + "{" * 3000 + "}" * 3000),  # deep blocks
    ("double fac = 1.25;", "double fac = " + "-" * 3000 + "1;"),  # deep expression
    ("double fac = 1.25;", "double fac = 1e400;"),  # inf
    ("double fac = 1.25;", "double fac = 0/0;"),  # nan
]


@pytest.mark.parametrize(
    "old, new", BAD_EDITS, ids=["syntax", "name", "reserved", "deep-blocks", "deep-expr", "inf", "nan"]
)
def test_a_users_mistake_is_a_located_error_and_exit_1(tmp_path, capsys, old, new):
    spec = tmp_path / "walker.kms"
    spec.write_text(edit(old, new))
    for command in (["check", str(spec)], ["export", str(spec), "-o", str(tmp_path / "out")]):
        assert main(command) == 1  # (an exception escaping main would be a traceback)
        out, err = capsys.readouterr()
        assert out == "" and err.startswith(f"{spec}:") and ": error: " in err
    assert not (tmp_path / "out").exists()


def test_no_traceback_from_the_installed_command(tmp_path):
    spec = tmp_path / "walker.kms"
    spec.write_text(edit("leftThigh.knee, 20", "leftThigh.kne, 20", edit(*BAD_EDITS[4])))
    command = ["export", str(spec), "-o", str(tmp_path / "out")]
    out = subprocess.run([sys.executable, "-m", "kms2pin.cli", *command], capture_output=True, text=True, timeout=120)
    assert out.returncode == 1, out.stderr
    assert "Traceback" not in out.stderr and "Traceback" not in out.stdout
    heads = [line for line in out.stderr.splitlines() if ": error: " in line]
    assert len(heads) == 2 and all(h.startswith(f"{spec}:") for h in heads)
    assert not (tmp_path / "out").exists()


def test_a_body_given_by_other_than_its_name_is_a_clear_type_error():
    """robot.inner(body) with the spec's Body object, not its name: a TypeError that says
    so (it was a TypeError from inside difflib's suggestion)."""
    from kms2pin.errors import RobotError, did_you_mean

    robot = load(SPECS / "human.kms")
    with pytest.raises(TypeError, match="a body is given by its name \\(a str\\), not a Body"):
        robot.inner(robot.system.bodies[0])
    with pytest.raises(RobotError, match="has no body 'torsoo' \\(did you mean 'torso'\\?\\)"):
        robot.inner("torsoo")
    assert did_you_mean(3, ["torso"]) == ""


def test_a_source_line_with_control_characters_is_echoed_harmlessly(tmp_path, capsys):
    """ESC (an escape sequence), BEL, DEL and a text-direction override in a spec line do not
    reach the terminal as themselves: the echoed line shows each as one visible character,
    and the caret stays under the column the message names."""
    import unicodedata

    spec = tmp_path / "esc.kms"
    spec.write_bytes("rigidBodySystem x {\n  body a \x1b[31m\x07\x7f\u202e = 1;\n}\n".encode())
    assert main(["export", str(spec), "-o", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err
    head, shown, caret = err.splitlines()[:3]
    assert head == f"{spec}:2:10: error: syntax error: unexpected character '\\x1b'"
    assert not [c for c in err if unicodedata.category(c) in ("Cc", "Cf") and c != "\n"], repr(err)
    assert shown == "      body a \u241b[31m\u2407\u2421\ufffd = 1;"
    assert caret.index("^") == shown.index("\u241b")
    assert not (tmp_path / "out").exists()
