"""Fuzzing the compiler: whatever the text, it raises SpecError or succeeds.

Random text, random soups of the language's tokens and random mutations of the
four thesis specs go through ``kms2pin.parse_text`` and ``kms2pin.load`` (which
also writes the URDF and builds the Pinocchio model).  The only exception allowed
is :class:`kms2pin.SpecError`; when a mutated spec compiles, loading it and
evaluating its rest pose must work too.

KMS2PIN_FUZZ_SCALE=10 multiplies the number of examples (for a longer bug hunt).
"""

from __future__ import annotations

import os
import re
import warnings

import numpy as np
import pytest
from conftest import SPEC_NAMES, SPECS
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import kms2pin
from kms2pin.lang import looks_like_path

SCALE = float(os.environ.get("KMS2PIN_FUZZ_SCALE", "1"))


def _n(n: int) -> int:
    return max(1, int(n * SCALE))


SETTINGS = dict(deadline=None, suppress_health_check=[HealthCheck.too_slow], derandomize=SCALE == 1)

SPEC_TEXT = {name: (SPECS / f"{name}.kms").read_text() for name in SPEC_NAMES}

KEYWORDS = [
    "double", "bool", "if", "else", "true", "false", "bvec", "ellipsoidBody", "rigidBodySystem",
    "constraint", "fixed", "revolute", "prismatic", "innerLam", "outerLam", "pos", "orient",
    "sin", "cos", "tan", "atan2", "sqrt", "pow", "log", "acos", "fmod", "min",
]  # fmt: skip
PUNCT = [
    "{", "}", "(", ")", ";", ",", ".", "=", "+=", "-=", "*=", "/=", "+", "-", "*", "/", "%",
    "<", ">", "<=", ">=", "==", "!=", "&&", "||", "!", "?", ":", "//", "/*", "*/", "\n",
]  # fmt: skip
NAMES = ["a", "b", "x", "fac", "s", "body", "origin", "knee", "hip", "world", "root", "joint", "a_b", "_"]
NUMBERS = ["0", "1", "0.5", ".5", "2.", "1e308", "1e400", "1e-320", "180", "90", "-1", "1e18", "0e0"]
BIG_NUMBERS = ["0", "0.0", "1e308", "1e400", "1e-320", "-0", "1e18", "360", "-180", "3.5e5", "1e-12", "7"]

_TOKEN = re.compile(
    r"//[^\n]*|/\*.*?\*/"  # comments
    r"|[A-Za-z_][A-Za-z0-9_]*"  # names
    r"|(?:\d+\.\d*|\.\d+|\d+)(?:[eE][+-]?\d+)?"  # numbers
    r"|\+=|-=|\*=|/=|<=|>=|==|!=|&&|\|\||[-+*/%<>=!?:;,.(){}]"  # operators, punctuation
    r"|\s+|.",
    re.S,
)
_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")
_NUMBER = re.compile(r"(?:\d+\.\d*|\.\d+|\d+)(?:[eE][+-]?\d+)?\Z")


def tokens(text: str) -> list[str]:
    return _TOKEN.findall(text)


assert all("".join(tokens(t)) == t for t in SPEC_TEXT.values())


def compile_and_load(text: str) -> None:
    """The property: SpecError or success, and a compiled spec loads and moves."""
    as_text = not looks_like_path(text)  # load() takes a one-line "x.kms" for a file name
    try:
        spec = kms2pin.parse_text(text)
    except kms2pin.SpecError as err:
        assert err.diagnostics, "a SpecError must carry at least one diagnostic"
        for d in err.diagnostics:
            assert d.line >= 1 and d.column >= 1 and d.message
        if as_text:
            with pytest.raises(kms2pin.SpecError):
                kms2pin.load(text)  # compiles the same text: must fail the same way
        return
    for system in spec.systems:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # absurd sizes may overflow: allowed
            robot = kms2pin.load(text if as_text else spec, system=system.name)
            robot.body_poses(robot.q_rest)
            robot.maximal_coordinates(robot.q_rest)


# ----------------------------------------------------------------------------- random text


@settings(max_examples=_n(150), **SETTINGS)
@given(st.text(max_size=200))
def test_random_text_raises_only_spec_error(text):
    compile_and_load(text)


@settings(max_examples=_n(100), **SETTINGS)
@given(st.text(alphabet="{}();,.=+-*/%<>!&|?: \n\tabx01e", max_size=200))
def test_random_punctuation_raises_only_spec_error(text):
    compile_and_load(text)


TOKEN_SOUP = st.lists(st.sampled_from(KEYWORDS + PUNCT + NAMES + NUMBERS), max_size=80).map(" ".join)


@settings(max_examples=_n(300), **SETTINGS)
@given(TOKEN_SOUP)
def test_token_soup_raises_only_spec_error(text):
    compile_and_load(text)


# a minimal valid spec with holes: token soups in the places statements go
SKELETON = """
bvec origin {{ pos(0, 0, 1); orient(0, 1, 0); }}
ellipsoidBody F(double l, bool left) {{ innerLam(l, l, l); outerLam(2*l, 2*l, 2*l); {fn}
    bvec j {{ pos(0, 0, l); orient(1, 0, 0); }} }}
rigidBodySystem s {{
    ellipsoidBody b {{ innerLam(1, 1, 1); outerLam(1, 1, 1); {body}
        bvec a {{ pos(0, 0, 0); orient(0, 1, 0); {bvec} }}
        bvec k {{ pos(0, 1, 0); orient(1, 0, 0); }} }}
    F c(0.5, true);
    {system}
    constraint revolute(b.k, c.j, 10);
}}
constraint revolute(s.b.a, origin);
"""
STATEMENTS = st.lists(
    st.sampled_from(KEYWORDS + PUNCT + NAMES + NUMBERS + ["a", "k", "j", "b", "c", "l", "left"]), max_size=25
).map(" ".join)


@settings(max_examples=_n(200), **SETTINGS)
@given(STATEMENTS, st.sampled_from(["fn", "body", "bvec", "system"]))
def test_token_soup_inside_a_valid_spec(soup, where):
    holes = dict.fromkeys(("fn", "body", "bvec", "system"), "")
    holes[where] = soup
    compile_and_load(SKELETON.format(**holes))


def test_the_skeleton_compiles():
    holes = dict.fromkeys(("fn", "body", "bvec", "system"), "")
    robot = kms2pin.load(SKELETON.format(**holes))
    assert robot.bodies == ("b", "c")


# ----------------------------------------------------------------------------- mutations


@st.composite
def mutated_spec(draw) -> str:
    name = draw(st.sampled_from(SPEC_NAMES))
    toks = tokens(SPEC_TEXT[name])
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(st.sampled_from(
            ["del_tok", "dup_tok", "swap_tok", "del_chr", "dup_chr", "swap_chr", "number", "rename", "insert"]
        ))  # fmt: skip
        i = draw(st.integers(0, len(toks) - 1))
        if kind == "del_tok":
            del toks[i]
        elif kind == "dup_tok":
            toks.insert(i, toks[i])
        elif kind == "swap_tok":
            j = draw(st.integers(0, len(toks) - 1))
            toks[i], toks[j] = toks[j], toks[i]
        elif kind in ("del_chr", "dup_chr", "swap_chr"):
            text = "".join(toks)
            k = draw(st.integers(0, len(text) - 2))
            if kind == "del_chr":
                text = text[:k] + text[k + 1 :]
            elif kind == "dup_chr":
                text = text[:k] + text[k] + text[k:]
            else:
                text = text[:k] + text[k + 1] + text[k] + text[k + 2 :]
            toks = tokens(text)
        elif kind == "number":
            numbers = [k for k, t in enumerate(toks) if _NUMBER.match(t)]
            k = numbers[i % len(numbers)]
            toks[k] = draw(st.sampled_from(BIG_NUMBERS) | st.floats(0, 1e6).map(repr))
        elif kind == "rename":
            names = sorted({t for t in toks if _NAME.match(t)})
            old = draw(st.sampled_from(names))
            new = draw(st.sampled_from(names + NAMES))
            if draw(st.booleans()):  # every occurrence, or just one
                toks = [new if t == old else t for t in toks]
            else:
                where = [k for k, t in enumerate(toks) if t == old]
                toks[where[i % len(where)]] = new
        else:
            toks.insert(i, draw(st.sampled_from(KEYWORDS + PUNCT + NAMES + NUMBERS)))
        if not toks:
            toks = [" "]
    return "".join(toks)


@settings(max_examples=_n(350), **SETTINGS)
@given(mutated_spec())
def test_mutated_thesis_specs_raise_only_spec_error(text):
    compile_and_load(text)


@pytest.mark.parametrize(
    "snippet",
    [
        "double x = " + "(" * 3000 + "1" + ")" * 3000 + ";",
        "double x = " + "-" * 3000 + "1;",
        "bool x = " + "!" * 3000 + "true;",
        "double x = 1" + "+1" * 3000 + ";",
        "double x = " + "true ? " * 1000 + "1" + " : 2" * 1000 + ";",
        "if (true) " * 2000 + ";",
        "{" * 3000 + "}" * 3000,
        "double x = 1e400;",
        "double x = 1e308 * 10;",
        "double x = 0 / 0;",
        "double x = sqrt(-1);",
        "double x = fmod(1, 0);",
        "double x = tan(90);",
        "double x = log(0);",
        "double x = pow(-8, 1/3);",
        "double x = acos(2);",
        "double x = 5 % 0;",
        "double x = exp(1e6);",
        "\x00\ufeff\u202e",
    ],
    ids=lambda s: s[:24],
)
def test_pathological_inputs_are_spec_errors(snippet):
    with pytest.raises(kms2pin.SpecError):
        kms2pin.parse_text(snippet)


TOO_LARGE = r"innerLam semi-axes must be at most 1e\+06, got \(1e\+300, 1, 1\)"
TOO_SMALL = r"innerLam semi-axes must be at least 1e-06, got \(1e-300, 1, 1\)"
FAR = r"pos coordinates of 'a' of body 'b' must be within \+-1e\+06, got \(1e\+300, 0, 0\)"
ZERO_ORIENT = r"orient vector of 'a' of body 'b' is zero; a bound vector needs a direction"


@pytest.mark.parametrize(
    "inner, outer, pos, orient, angle, refused",
    [
        ("1e300, 1, 1", "1e300, 2, 2", "0, 0, 0", "1, 0, 0", "0", TOO_LARGE),
        ("1, 1, 1", "2, 2, 2", "1e300, 0, 0", "1, 0, 0", "0", FAR),
        ("1e-300, 1, 1", "1, 2, 2", "0, 0, 0", "1, 0, 0", "0", TOO_SMALL),
        ("1e-6, 1e-6, 1e6", "1e-6, 1e6, 1e6", "1e6, -1e6, 1e6", "1, 0, 0", "0", None),
        ("1, 1, 1", "2, 2, 2", "0, 0, 0", "1e300, 1e300, 1", "0", None),
        ("1, 1, 1", "2, 2, 2", "0, 0, 0", "1e-300, 0, 0", "0", ZERO_ORIENT),
        ("1e-6, 1, 1", "1, 2, 2", "0, 0, 0", "0, 0, 1e-320", "0", ZERO_ORIENT),
        ("1, 1, 1", "2, 2, 2", "0, 0, 0", "1, 0, 0", "1e18", None),
        ("1, 1, 1", "1, 1, 1", "0, 0, 0", "-1, 0, 0", "-1e300", None),
    ],
)
def test_extreme_but_legal_numbers_compile_and_load_or_are_refused_with_a_clear_message(
    inner, outer, pos, orient, angle, refused
):
    text = f"""
    rigidBodySystem s {{
        ellipsoidBody b {{ innerLam({inner}); outerLam({outer});
            bvec a {{ pos({pos}); orient({orient}); }} }}
    }}
    bvec o {{ pos(0, 0, 0); orient(1, 0, 0); }}
    constraint revolute(s.b.a, o, {angle});
    """
    if refused is not None:  # absurd values: a located message naming the problem
        with pytest.raises(kms2pin.SpecError, match=refused) as err:
            kms2pin.parse_text(text)
        assert str(err.value).startswith("<string>:")
        return
    spec = kms2pin.parse_text(text)
    o = np.array(spec.systems[0].bodies[0].bvecs["a"].orient)
    assert np.isfinite(o).all() and abs(np.linalg.norm(o) - 1) < 1e-12
    v = np.array([float(x) for x in orient.split(",")])
    v /= np.abs(v).max()  # scaled first: the norm of (1e300, 1e300, 1) overflows
    np.testing.assert_allclose(o, v / np.linalg.norm(v), rtol=0, atol=1e-15)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the accepted ranges load without a NumPy warning
        robot = kms2pin.load(text)
        poses = robot.body_poses(robot.q_rest)
    assert all(np.isfinite(P.homogeneous).all() for P in poses)
