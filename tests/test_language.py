"""The model language of thesis §3.1, checked through the ModelSpec it compiles to.

Most tests compile a one-body spec whose bound vector ``a`` has ``pos(EXPR, 0, 0)``
and read EXPR's value back from the model (``value``); others build small specs.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import SPECS

import kms2pin
from kms2pin import SpecError, parse_text


def one_body(expr: str = "0", top: str = "", body: str = "", bvec: str = "", system: str = "", after: str = "") -> str:
    return f"""{top}
rigidBodySystem s {{
    {system}
    ellipsoidBody b {{
        innerLam(1, 1, 1);
        outerLam(2, 2, 2);
        {body}
        bvec a {{
            {bvec}
            pos({expr}, 0, 0);
            orient(1, 0, 0);
        }}
    }}
    {after}
}}
bvec origin {{ pos(0, 0, 0); orient(1, 0, 0); }}
constraint revolute(s.b.a, origin);
"""


def value(expr: str, **parts) -> float:
    """The value of the double expression ``expr`` (in a bvec of a body of a system)."""
    return parse_text(one_body(expr, **parts)).systems[0].bodies[0].bvecs["a"].pos[0]


def truth(expr: str, **parts) -> bool:
    """The value of the bool expression ``expr``."""
    v = value(f"({expr}) ? 1 : 0", **parts)
    assert v in (0.0, 1.0)
    return v == 1.0


def messages(text: str) -> list[str]:
    with pytest.raises(SpecError) as err:
        parse_text(text)
    return [d.message for d in err.value.diagnostics]


# ----------------------------------------------------------------------------- comments


def test_display_3_1_commented_out_code_is_not_run():
    """Display 3.1 verbatim, plus a variable that records which branch ran."""
    display = """
// This is a single-line comment followed by variable declarations
double hypotenuse = 10;
double theta = 37;
double opposite = hypotenuse*sin(theta); // Sample mathematical ops
double adjacent = hypotenuse*cos(theta);

/* This is a multi-line comment
double swap = opposite;
opposite = adjacent;
adjacent = swap;
*/
double branch = 0;
if (adjacent < opposite) {
    // This block never reached because the swap code is commented
    branch = 1;
}
else {
    // This block of code will be evaluated instead
    branch = 2;
}
"""
    assert value("branch", top=display) == 2
    assert value("opposite", top=display) == pytest.approx(10 * math.sin(math.radians(37)))
    assert value("adjacent", top=display) == pytest.approx(10 * math.cos(math.radians(37)))


@pytest.mark.parametrize(
    "top, expected",
    [
        ("double x = 1; // x = 2;", 1),
        ("double x = 1; /* x = 2; */", 1),
        ("double x = 1; /* x = 2; \n x = 3; \n */ x += 10;", 11),
        ("double x = 1; /* a /* b */ x = 4;", 4),  # C: block comments do not nest
        ("double x = 1; // /* \n x = 5; // */", 5),  # a // comment hides a /*
        ("double x = 1; /* // */ x = 6;", 6),  # and a /* */ a //
        ("double x = /* inside */ 7 /**/;", 7),
        ("double x = 8; /**/ /***/ /* * / */", 8),
    ],
)
def test_comments(top, expected):
    assert value("x", top=top) == expected


def test_unterminated_block_comment_is_an_error():
    assert messages(one_body(top="double x = 1; /* never closed")) == ["unterminated comment"]


# ----------------------------------------------------------------------------- variables, types


def test_double_and_bool_variables():
    top = "double d = 2.5; bool t = true; bool f = false; double e = 1e3; double g = .5; double h = 3.;"
    assert value("d", top=top) == 2.5
    assert value("e + g + h", top=top) == 1003.5
    assert truth("t", top=top) and not truth("f", top=top)
    assert truth("t == !f", top=top)


def test_declaration_without_value_then_assignment():
    assert value("x", top="double x; x = 3;") == 3
    assert "used before it is given a value" in messages(one_body("x", top="double x;"))[0]


@pytest.mark.parametrize(
    "top, fragment",
    [
        ("double x = true;", "cannot initialize double 'x' with a bool value"),
        ("bool x = 1;", "cannot initialize bool 'x' with a double value"),
        ("double x = 1; x = false;", "cannot assign a bool value to double 'x'"),
        ("bool x = true; x += 1;", "cannot assign a double value to bool 'x'"),
        ("bool x = true; x += true;", "'+=' needs a double, but 'x' is bool"),
        ("if (1) { }", "an if condition must be bool, not double"),
        ("double x = 1 + true;", "'+' needs double operands, not double and bool"),
        ("bool x = 1 == true;", "cannot compare double with bool"),
        ("bool x = !1;", "'!' needs a bool, not double"),
        ("double x = -true;", "unary '-' needs a double, not bool"),
        ("bool x = 1 && true;", "'&&' needs bool operands; the left one is double"),
        ("double x = 1 ? 2 : 3;", "the condition of '?:' must be bool, not double"),
        ("double x = true ? 1 : false;", "the two branches of '?:' differ in type (double and bool)"),
        ("double x = sin(true);", "'sin' takes doubles; this argument is bool"),
        ("bool x = true < false;", "'<' needs double operands, not bool and bool"),
    ],
)
def test_types_are_strict(top, fragment):
    """No implicit bool/double conversion; conditions must be bool."""
    assert any(fragment in m for m in messages(one_body(top=top))), messages(one_body(top=top))


# ----------------------------------------------------------------------------- scoping


def test_inner_block_shadows_and_names_leave_scope_at_the_brace():
    top = """
    double x = 1;
    double seen = 0;
    {
        double x = 2;       // shadows the outer x
        seen = x;           // an outer variable assigned from the inner scope
        {
            x += 10;        // the inner x
        }
        seen = seen + x;    // 2 + 12
    }
    """
    assert value("x", top=top) == 1
    assert value("seen", top=top) == 14
    msgs = messages(one_body("y", top="{ double y = 3; }"))
    assert msgs == ["unknown variable 'y'"]


def test_if_branches_are_scopes():
    assert messages(one_body("y", top="if (true) { double y = 1; }")) == ["unknown variable 'y'"]
    assert messages(one_body("y", top="if (true) double y = 1;")) == ["unknown variable 'y'"]


def test_system_body_and_bvec_blocks_are_scopes():
    # body-local variables (like `height` in the thesis's trunk and head) do not clash
    text = one_body(
        "h + k",
        top="double h = 1;",
        system="double k = 100; ellipsoidBody other { double h = 5; innerLam(h, h, h); outerLam(h, h, h);"
        " bvec z { double q = 1; pos(0,0,0); orient(1,0,0); } }",
        after="constraint fixed(b.a, other.z);",
        body="double h = 7; double k = 3;",
    )
    spec = parse_text(text)
    assert spec.systems[0].body("b").bvecs["a"].pos[0] == 10  # the body's own h and k
    assert spec.systems[0].body("other").inner == (5, 5, 5)
    # a system's locals are not visible after it
    assert "unknown variable 'k'" in messages(one_body(system="double k = 1;") + "double z = k;")


def test_same_name_in_different_scopes_is_legal_but_not_in_one_scope():
    assert value("x", top="double x = 1; { double x = 2; { double x = 3; } }") == 1
    assert messages(one_body(top="double x = 1; bool x = true;")) == [
        "'x' is already declared in this scope, as a variable (line 1)"
    ]


# ----------------------------------------------------------------------------- assignment, arithmetic


@pytest.mark.parametrize(
    "stmts, expected",
    [
        ("x = 5;", 5),
        ("x += 5;", 7),
        ("x -= 5;", -3),
        ("x *= 5;", 10),
        ("x /= 4;", 0.5),
        ("x += 1; x *= 3; x -= 1; x /= 2;", 4),
        ("x = x * x + x;", 6),
    ],
)
def test_assignment_operators(stmts, expected):
    assert value("x", top="double x = 2; " + stmts) == expected


@pytest.mark.parametrize(
    "expr, expected",
    [
        ("2 + 3 * 4", 14),
        ("(2 + 3) * 4", 20),
        ("10 - 4 - 3", 3),  # left associative
        ("64 / 4 / 2", 8),
        ("2 * 3 % 4", 2),  # same level as * and /, left to right
        ("7 % 3 * 2", 2),
        ("-7 % 3", -1),  # C's fmod: the sign of the dividend
        ("7.5 % 2", 1.5),
        ("-2 * -3", 6),
        ("-2 * 3 + 1", -5),
        ("- - 4", 4),
        ("+3 - +1", 2),
        ("2 * (3 + (4 - 1) / 3)", 8),
        ("1e2 + 1.5e-1 + .25 + 4.", 104.4),
    ],
)
def test_arithmetic_and_precedence(expr, expected):
    assert value(expr) == pytest.approx(expected, abs=1e-12)


@pytest.mark.parametrize(
    "expr, expected",
    [
        ("1 < 2", True),
        ("2 < 1", False),
        ("2 <= 2", True),
        ("3 > 2", True),
        ("2 >= 3", False),
        ("2 == 2.0", True),
        ("2 != 2", False),
        ("true == true", True),
        ("true != false", True),
        ("1 + 2 < 4 == true", True),  # ((1 + 2) < 4) == true
        ("1 < 2 == 2 < 1", False),  # comparisons bind tighter than ==
        ("!false && false", False),  # ! binds tighter than &&
        ("true || false && false", True),  # && binds tighter than ||
        ("(true || false) && false", False),
        ("!(1 > 2)", True),
        ("!!true", True),
    ],
)
def test_comparisons_and_logic(expr, expected):
    assert truth(expr) is expected


def test_and_or_short_circuit():
    """The operand && / || skips is type-checked but not evaluated."""
    assert truth("false && 1 / 0 > 0") is False
    assert truth("true || sqrt(-1) > 0") is True
    assert truth("false && undefinedLater > 0", top="double undefinedLater;") is False
    # ... but it must still be well typed and name known variables
    assert messages(one_body(top="bool x = false && 1;")) == ["'&&' needs bool operands; the right one is double"]
    assert messages(one_body(top="bool x = true || nope > 0;")) == ["unknown variable 'nope'"]


@pytest.mark.parametrize(
    "expr, expected",
    [
        (" + ".join(["1"] * 10_000), 10_000),
        ("1" + " - 1" * 10_000, -9_999),  # left associative
        ("1" + " / 2 * 2" * 5_000, 1),
        (" && ".join(["1 < 2"] * 10_000) + " ? 1 : 0", 1),
        (" || ".join(["2 < 1"] * 9_999 + ["2 > 1"]) + " ? 1 : 0", 1),
        ("true" + " == true" * 10_000 + " ? 1 : 0", 1),
        ("(" * 5_000 + "1" + ")" * 5_000, 1),  # parentheses alone do not nest
    ],
    ids=["sum", "difference", "quotient", "and", "or", "equal", "parentheses"],
)
def test_long_operator_chains_are_not_too_deep(expr, expected):
    assert value(expr) == expected


def test_ternary():
    assert value("true ? 1 : 2") == 1
    assert value("false ? 1 : 2") == 2
    assert value("false ? 1 : true ? 2 : 3") == 2  # right associative
    assert value("1 < 2 ? 10 + 1 : 20") == 11
    assert value("true ? 5 : 1 / 0") == 5  # the branch not taken is not evaluated
    assert value("false ? sqrt(-1) : 6") == 6
    assert value("(true ? 2 : 3) * 2") == 4


def test_if_else_and_else_if_chains():
    top = """
    double x = {x};
    double r = 0;
    if (x < 1) {{
        r = 1;
    }} else if (x < 2) {{
        r = 2;
    }} else if (x < 3)
        r = 3;
    else {{
        r = 4;
    }}
    if (x == 0) r += 100;
    """
    assert [value("r", top=top.format(x=x)) for x in (0, 1.5, 2.5, 9)] == [101, 2, 3, 4]


def test_if_selects_statements_inside_bodies_and_bvecs():
    """The thesis's PlanarLinkage: innerLam and pos chosen by a bool parameter."""
    top = "bool horizontal = false;"
    body = "if (horizontal) { innerLam(3, 1, 1); } else { innerLam(1, 3, 1); } outerLam(4, 4, 4);"
    bvec = "if (!horizontal) { orient(0, 1, 0); } else orient(1, 0, 0);"
    spec = parse_text(one_body(top=top, body=body, bvec=bvec).replace("orient(1, 0, 0);\n        }", "}"))
    b = spec.systems[0].bodies[0]
    assert b.inner == (1, 3, 1)
    assert b.bvecs["a"].orient == (0, 1, 0)


# ----------------------------------------------------------------------------- maths functions


@pytest.mark.parametrize(
    "expr, expected",
    [
        ("sin(30)", 0.5),
        ("sin(90)", 1.0),
        ("sin(-30)", -0.5),
        ("sin(180)", 0.0),
        ("cos(60)", 0.5),
        ("cos(90)", 0.0),
        ("cos(180)", -1.0),
        ("cos(450)", 0.0),
        ("tan(45)", 1.0),
        ("tan(-45)", -1.0),
        ("atan2(1, 1)", 45.0),
        ("atan2(1, -1)", 135.0),
        ("atan2(-1, 0)", -90.0),
        ("atan(1)", 45.0),
        ("asin(1)", 90.0),
        ("acos(-1)", 180.0),
        ("acos(1)", 0.0),
    ],
)
def test_trigonometry_is_in_degrees_and_exact_at_special_angles(expr, expected):
    assert value(expr) == expected  # exact: sin(30) == 0.5 in the language too
    assert truth(f"{expr} == {expected}")


def test_trigonometry_in_degrees_elsewhere():
    assert value("sin(37)") == pytest.approx(math.sin(math.radians(37)), abs=1e-15)
    assert value("cos(10)") == pytest.approx(math.cos(math.radians(10)), abs=1e-15)
    assert value("tan(30)") == pytest.approx(math.tan(math.radians(30)), abs=1e-15)
    assert value("acos(0.5)") == pytest.approx(60, abs=1e-12)
    assert value("sin(370)") == pytest.approx(math.sin(math.radians(10)), abs=1e-15)
    assert value("sin(x) * sin(x) + cos(x) * cos(x)", top="double x = 123.4;") == pytest.approx(1)


@pytest.mark.parametrize(
    "expr, expected",
    [
        ("sqrt(16)", 4),
        ("abs(-3)", 3),
        ("fabs(-2.5)", 2.5),
        ("pow(2, 10)", 1024),
        ("exp(0)", 1),
        ("log(exp(2))", 2),
        ("log10(1000)", 3),
        ("floor(-2.5)", -3),
        ("ceil(2.1)", 3),
        ("min(3, -1)", -1),
        ("max(3, -1)", 3),
        ("fmod(7, 3)", 1),
    ],
)
def test_other_maths_functions(expr, expected):
    assert value(expr) == pytest.approx(expected, abs=1e-12)


# ----------------------------------------------------------------------------- bodies and functions

LEG = """
double fac = 1.25;
ellipsoidBody Leg(double length, bool left) {
    double r = 0.1;
    innerLam(r, r, length);
    outerLam(fac*r, fac*r, fac*length);
    bvec top {
        if (left) { pos(r, 0, 0.8*length); } else { pos(-r, 0, 0.8*length); }
        orient(-1, 0, 0);
    }
}
"""


def legs(system_body: str, top: str = LEG, after: str = "") -> str:
    return f"""{top}
bvec origin {{ pos(0, 0, 0); orient(0, 1, 0); }}
rigidBodySystem s {{
    ellipsoidBody pelvis {{
        innerLam(0.3, 0.2, 0.2); outerLam(0.4, 0.3, 0.3);
        bvec anchor {{ pos(0, 0, 0); orient(0, 1, 0); }}
        bvec l {{ pos(0.2, -0.1, 0); orient(-1, 0, 0); }}
        bvec r {{ pos(-0.2, -0.1, 0); orient(-1, 0, 0); }}
    }}
    {system_body}
}}
constraint revolute(s.pelvis.anchor, origin);
{after}
"""


def test_functional_bodies_compute_their_shape_from_arguments():
    spec = parse_text(
        legs("""
        Leg leftLeg(0.4, true);
        Leg rightLeg(0.5, false);
        constraint revolute(pelvis.l, leftLeg.top);
        constraint revolute(pelvis.r, rightLeg.top);
    """)
    )
    s = spec.systems[0]
    assert s.body("leftLeg").inner == (0.1, 0.1, 0.4)
    assert s.body("rightLeg").outer == pytest.approx((0.125, 0.125, 0.625))
    assert s.body("leftLeg").bvecs["top"].pos == pytest.approx((0.1, 0, 0.32))
    assert s.body("rightLeg").bvecs["top"].pos == pytest.approx((-0.1, 0, 0.4))
    assert [b.name for b in s.bodies] == ["pelvis", "leftLeg", "rightLeg"]


def test_literal_and_functional_bodies_mix():
    spec = parse_text(
        legs("""
        ellipsoidBody tail { innerLam(0.1, 0.1, 0.1); outerLam(0.1, 0.1, 0.1);
            bvec j { pos(0, 0, 0.1); orient(1, 0, 0); } }
        Leg leg(0.4, true);
        constraint fixed(pelvis.r, tail.j);
        constraint revolute(pelvis.l, leg.top);
    """)
    )
    assert {b.name for b in spec.systems[0].bodies} == {"pelvis", "tail", "leg"}


def test_a_function_sees_globals_declared_before_it_with_their_current_value():
    top = "double g = 1;" + LEG.replace("double r = 0.1;", "double r = g;") + "g = 0.2;"
    spec = parse_text(legs("Leg leg(0.4, true); constraint revolute(pelvis.l, leg.top);", top=top))
    assert spec.systems[0].body("leg").inner == (0.2, 0.2, 0.4)  # g's value when instantiated


def test_a_function_does_not_see_globals_declared_after_it():
    top = LEG.replace("double r = 0.1;", "double r = later;") + "double later = 0.1;"
    text = legs("Leg leg(0.4, true); constraint revolute(pelvis.l, leg.top);", top=top)
    assert messages(text) == ["unknown variable 'later'", "in call 'Leg leg(...)'"]


def test_a_function_does_not_see_the_instantiating_systems_locals():
    top = LEG.replace("double r = 0.1;", "double r = local;")
    text = legs("double local = 0.1; Leg leg(0.4, true); constraint revolute(pelvis.l, leg.top);", top=top)
    assert messages(text) == ["unknown variable 'local'", "in call 'Leg leg(...)'"]


def test_parameters_shadow_globals_and_function_locals_stay_inside():
    top = "double length = 99;" + LEG
    text = legs("Leg leg(0.4, true); constraint revolute(pelvis.l, leg.top); double z = r;", top=top)
    assert messages(text) == ["unknown variable 'r'"]
    spec = parse_text(legs("Leg leg(0.4, true); constraint revolute(pelvis.l, leg.top);", top=top))
    assert spec.systems[0].body("leg").inner[2] == 0.4


def test_each_instantiation_runs_the_function_afresh():
    top = LEG.replace("double r = 0.1;", "double r = 0.1; double n = 0; n += 1; r *= n;")
    spec = parse_text(
        legs(
            """
        Leg a(0.4, true); Leg b(0.4, false);
        constraint revolute(pelvis.l, a.top); constraint revolute(pelvis.r, b.top);
    """,
            top=top,
        )
    )
    assert spec.systems[0].body("a").inner == spec.systems[0].body("b").inner == (0.1, 0.1, 0.4)


def test_function_parameter_can_share_a_name_with_a_bvec_elsewhere():
    """As in the JPL hand: bool parameter `thumb` and the palm's bvec `thumb`."""
    top = LEG.replace("bool left", "bool r2").replace("if (left)", "if (r2)")
    spec = parse_text(
        legs(
            """
        Leg r2(0.4, true);
        constraint revolute(pelvis.r, r2.top);
    """,
            top=top,
        )
        .replace("bvec r {", "bvec r2 {")
        .replace("pelvis.r,", "pelvis.r2,")
    )
    assert spec.systems[0].body("r2").bvecs["top"].pos[0] == pytest.approx(0.1)


def test_function_defined_inside_a_system():
    spec = parse_text(
        legs("""
        ellipsoidBody Stub(double w) { innerLam(w, w, w); outerLam(w, w, w);
            bvec j { pos(0, 0, 0); orient(1, 0, 0); } }
        Stub stub(0.3);
        constraint fixed(pelvis.l, stub.j);
    """)
    )
    assert spec.systems[0].body("stub").inner == (0.3, 0.3, 0.3)


# ----------------------------------------------------------------------------- bvecs, references, systems


def test_orient_vectors_are_normalized_and_pos_is_kept():
    spec = parse_text(one_body("1", bvec="").replace("orient(1, 0, 0);", "orient(3, 0, -4);", 1))
    bv = spec.systems[0].bodies[0].bvecs["a"]
    assert bv.orient == pytest.approx((0.6, 0, -0.8), abs=1e-15)
    assert bv.pos == (1, 0, 0)
    assert bv.body == "b" and bv.qualified_name == "b.a"


def test_inertial_bvecs_top_level_and_in_a_system():
    text = one_body().replace(
        "bvec origin { pos(0, 0, 0); orient(1, 0, 0); }", "bvec origin { pos(1, 2, 3); orient(0, 0, 2); }"
    )
    spec = parse_text(text)
    origin = spec.inertial_bvecs["origin"]
    assert origin.body is None and origin.pos == (1, 2, 3) and origin.orient == (0, 0, 1)
    joint = spec.systems[0].joints[0]
    assert joint.parent is None and joint.parent_bvec.name == "origin" and joint.child_bvec.qualified_name == "b.a"
    # a bvec in a system but outside any body is bound to the inertial frame as well
    text = one_body(system="bvec ground { pos(0, 0, -1); orient(0, 1, 0); }", after="constraint fixed(ground, b.a);")
    text = text.replace("constraint revolute(s.b.a, origin);", "")
    spec = parse_text(text)
    j = spec.systems[0].joints[0]
    assert j.parent is None and j.parent_bvec.name == "ground" and j.kind == "fixed"


def test_qualified_references_and_multiple_systems():
    text = """
    bvec origin { pos(0, 0, 0); orient(1, 0, 0); }
    bvec other { pos(5, 0, 0); orient(1, 0, 0); }
    rigidBodySystem first {
        ellipsoidBody b { innerLam(1, 1, 1); outerLam(1, 1, 1); bvec a { pos(0,0,0); orient(1,0,0); } }
        constraint revolute(first.b.a, origin, 30);      // system.body.bvec inside its system
    }
    rigidBodySystem second {
        ellipsoidBody b { innerLam(2, 2, 2); outerLam(2, 2, 2); bvec a { pos(0,0,0); orient(1,0,0); } }
    }
    constraint fixed(second.b.a, other);                 // outside: system.body.bvec
    """
    spec = parse_text(text)
    assert [s.name for s in spec.systems] == ["first", "second"]
    assert spec.system("first").body("b").inner == (1, 1, 1)
    assert spec.system("second").body("b").inner == (2, 2, 2)  # same body name, other system
    assert spec.system("first").joints[0].default_angle == 30
    assert spec.system("second").joints[0].parent_bvec.name == "other"
    assert spec.system("second").dof == 0
    with pytest.raises(kms2pin.RobotError, match="2 rigidBodySystems"):
        spec.system()


def test_a_body_outside_its_system_needs_the_system_name():
    text = one_body().replace("constraint revolute(s.b.a, origin);", "constraint revolute(b.a, origin);")
    assert messages(text) == [
        "body 'b' belongs to rigidBodySystem 's'; outside it, write s.b.a",
    ]


def test_a_joint_cannot_join_two_systems():
    text = """
    rigidBodySystem p { ellipsoidBody b { innerLam(1,1,1); outerLam(1,1,1); bvec a { pos(0,0,0); orient(1,0,0); } } }
    rigidBodySystem q { ellipsoidBody c { innerLam(1,1,1); outerLam(1,1,1); bvec a { pos(0,0,0); orient(1,0,0); } } }
    bvec o { pos(0,0,0); orient(1,0,0); }
    constraint revolute(p.b.a, o);
    constraint revolute(q.c.a, p.b.a);
    """
    assert any("cannot connect two rigidBodySystems (p and q)" in m for m in messages(text))


def test_joint_default_angles_and_kinds():
    spec = parse_text(
        legs("""
        double bend = 10;
        Leg a(0.4, true); Leg b(0.4, false);
        constraint revolute(pelvis.l, a.top, 90 - bend);
        constraint fixed(pelvis.r, b.top);
    """)
    )
    s = spec.systems[0]
    ja, jb = s.joint_of("a"), s.joint_of("b")
    assert (ja.kind, ja.default_angle, ja.parent, ja.name) == ("revolute", 80, "pelvis", "a_top")
    assert (jb.kind, jb.default_angle, jb.parent) == ("fixed", 0, "pelvis")
    assert s.dof == 2  # root + a


def test_the_tree_not_the_argument_order_decides_parent_and_child():
    forward = legs("Leg a(0.4, true); constraint revolute(pelvis.l, a.top, 20);")
    backward = legs("Leg a(0.4, true); constraint revolute(a.top, pelvis.l, 20);")
    ja, jb = (parse_text(t).systems[0].joint_of("a") for t in (forward, backward))
    assert ja == jb
    assert ja.parent == "pelvis" and ja.parent_bvec.qualified_name == "pelvis.l"
    root = parse_text(backward.replace("(s.pelvis.anchor, origin)", "(origin, s.pelvis.anchor)")).systems[0]
    assert root.joints[0].parent is None and root.joints[0].child == "pelvis"


def test_empty_statements_and_blocks_are_allowed_everywhere():
    assert value("1", top=";;{};{ ; }", body=";{}", bvec=";{ ; }", system="; {}") == 1


def test_every_spec_compiles(spec_path):
    spec = kms2pin.parse(spec_path)
    expected = {"puma600": (5, 4), "lowerbody": (9, 7), "fullbody": (15, 12), "jplhand": (11, 11),
                "human": (15, 1 + 6 * 3 + 6), "gantry": (5, 3 + 1)}
    bodies, dof = expected[spec_path.stem]
    (system,) = spec.systems
    assert (len(system.bodies), system.dof) == (bodies, dof)
    for b in system.bodies:
        for bv in b.bvecs.values():
            assert np.linalg.norm(bv.orient) == pytest.approx(1, abs=1e-15)


def test_puma_planar_linkage_uses_its_bool_parameter():
    s = kms2pin.parse(SPECS / "puma600.kms").systems[0]
    # PlanarLinkage link2(1.0, 0.7, 0.2, false) and link3(1.2, 0.4, 0.2, true) (Display 3.10)
    assert s.body("link2").inner == pytest.approx((0.2, 1.0, 0.7))
    assert s.body("link2").outer == pytest.approx((0.25, 1.25, 0.875))
    assert s.body("link3").inner == pytest.approx((0.2, 0.4, 1.2))
    assert s.body("link2").bvecs["lowerLink"].pos == pytest.approx((0, -0.8, 0))
    assert s.body("link3").bvecs["lowerLink"].pos == pytest.approx((0, 0, 0.96))
