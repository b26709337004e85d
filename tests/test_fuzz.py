"""Fuzzing what a user can give: whatever the input, one error type or success.

Random text, random soups of the language's tokens and random mutations of the
four thesis specs go through ``kms2pin.parse_text`` and ``kms2pin.load`` (which
also writes the URDF and builds the Pinocchio model).  The only exception allowed
is :class:`kms2pin.SpecError`; when a mutated spec compiles, loading it and
evaluating its rest pose must work too.  Camera files, pose files and trajectory
CSVs (mutated valid ones, random JSON, random bytes) raise only CameraError or
InputDataError, and what they accept is finite and usable.  The joint-control
page, sent any request, answers without a traceback and stays up.

KMS2PIN_FUZZ_SCALE=10 multiplies the number of examples (for a longer bug hunt).
"""

from __future__ import annotations

import json
import math
import os
import re
import socket
import warnings

import numpy as np
import pytest
from conftest import SPEC_NAMES, SPECS
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

import kms2pin
from kms2pin.ecm import Camera
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


# ----------------------------------------------------------------------------- the other files a user gives
# Camera files, pose files and trajectory CSVs: whatever they hold, reading them raises the
# layer's one error type (CameraError, InputDataError) or gives finite, usable values.

JSON_LEAVES = (st.none() | st.booleans() | st.integers(-(2**70), 2**70) | st.floats(allow_nan=True)
               | st.text(max_size=8) | st.sampled_from([0, -1, 1e-300, 1e308, 8192, 8193, -0.0, 2**63]))
JSON_VALUES = st.recursive(JSON_LEAVES, lambda inner: st.lists(inner, max_size=4)
                           | st.dictionaries(st.text(max_size=6), inner, max_size=4), max_leaves=12)
CAMERA = {"name": "c", "width": 64, "height": 48, "K": [[60.0, 0, 31.5], [0, 60.0, 23.5], [0, 0, 1]],
          "world_T_camera": {"rotation": [[-1, 0, 0], [0, -1, 0], [0, 0, 1]], "translation": [0, 0, -3]},
          "dist": [0.01, 0, 0, 0]}


def _paths(value, prefix=()):
    """Every place in a JSON value (a tuple of keys and indices), the value itself first."""
    yield prefix
    items = value.items() if isinstance(value, dict) else enumerate(value) if isinstance(value, list) else ()
    for k, v in items:
        yield from _paths(v, (*prefix, k))


@st.composite
def mutated_json(draw, valid):
    """``valid`` with one to three places replaced by random JSON (or deleted), or random JSON."""
    if draw(st.integers(0, 9)) == 0:
        return draw(JSON_VALUES)
    value = json.loads(json.dumps(valid))
    for _ in range(draw(st.integers(1, 3))):
        path = draw(st.sampled_from(list(_paths(value))))
        if not path:
            return draw(JSON_VALUES)
        parent = value
        for k in path[:-1]:
            parent = parent[k]
        if isinstance(parent, dict) and draw(st.booleans()):
            del parent[path[-1]]
        else:
            parent[path[-1]] = draw(JSON_VALUES)
    return value


def _write(tmp_path_factory, text: str | bytes, suffix: str):
    path = tmp_path_factory.mktemp("fuzz") / f"file{suffix}"
    path.write_bytes(text if isinstance(text, bytes) else text.encode("utf-8", "surrogatepass"))
    return path


@settings(max_examples=_n(300), **SETTINGS)
@given(mutated_json(CAMERA) | mutated_json([CAMERA, CAMERA]))
def test_camera_files_raise_only_camera_error(tmp_path_factory, value):
    path = _write(tmp_path_factory, json.dumps(value), ".json")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a camera that is accepted works without NumPy warnings
        try:
            cameras = Camera.list_from_json(path)
        except kms2pin.CameraError as err:
            assert str(err).startswith(str(path)), err
            return
        for cam in cameras:
            _check_projection(cam)


@settings(max_examples=_n(100), **SETTINGS)
@given(st.binary(max_size=300) | st.text(max_size=300).map(lambda t: t.encode("utf-8", "surrogatepass")))
def test_camera_files_of_random_bytes_raise_only_camera_error(tmp_path_factory, data):
    path = _write(tmp_path_factory, data, ".json")
    try:
        cameras = Camera.list_from_json(path)
    except kms2pin.CameraError as err:
        assert str(err).startswith(str(path)), err
        return
    for cam in cameras:  # random bytes that happen to be a camera: it projects as the pinhole model says
        _check_projection(cam)


def _brown_projection(cam: Camera, p: np.ndarray) -> np.ndarray:
    """Pixels of world points ``p`` by the pinhole and Brown-Conrady model written out
    (OpenCV's k1, k2, p1, p2, k3), from the camera's K, pose and dist; NaN at or behind it."""
    R, t, K = cam.world_R_camera, cam.world_T_camera.translation, cam.K
    d = np.zeros(5) if cam.dist is None else np.r_[cam.dist, np.zeros(5)][:5]
    k1, k2, p1, p2, k3 = d
    out = np.full((len(p), 2), np.nan)
    for n, x in enumerate(p):
        c = R.T @ (x - t)
        if c[2] <= 0:
            continue
        u, v = c[0] / c[2], c[1] / c[2]
        r2 = u * u + v * v
        radial = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2 ** 3
        ud = u * radial + 2 * p1 * u * v + p2 * (r2 + 2 * u * u)
        vd = v * radial + p1 * (r2 + 2 * v * v) + 2 * p2 * u * v
        out[n] = K[0, 0] * ud + K[0, 2], K[1, 1] * vd + K[1, 2]
    return out


POINTS = np.array([[0.1, 0.2, 1.0], [0.0, 0.0, 5.0], [-2.0, 1.0, -4.0], [3.0, -1.0, 0.5]])


def _check_projection(cam: Camera) -> None:
    assert 1 <= cam.width <= 8192 and 1 <= cam.height <= 8192
    px = cam.project(POINTS)
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")  # the model written out may overflow where OpenCV's does too
        expected = _brown_projection(cam, POINTS)
    if cam.dist is not None and len(cam.dist) > 5:  # the rational and thin-prism terms: not written out here
        expected[np.isfinite(expected).all(axis=1)] = px[np.isfinite(expected).all(axis=1)]
    np.testing.assert_allclose(px, expected, rtol=1e-9, atol=1e-9)
    assert np.array_equal(np.isnan(px).any(axis=1), cam.depth(POINTS) <= 0)  # NaN exactly behind the camera


@st.composite
def valid_camera(draw) -> dict:
    """A camera file's dict within every field's range: focal lengths, principal point,
    a rotation from a random quaternion, a translation, no or 4 or 5 distortion terms."""
    f = st.floats(1.0, 5000.0)
    quat = np.array(draw(st.lists(st.floats(-1.0, 1.0), min_size=4, max_size=4)))
    quat = quat / np.linalg.norm(quat) if np.linalg.norm(quat) > 1e-3 else np.array([0.0, 0.0, 0.0, 1.0])
    import pinocchio as pin

    R = pin.Quaternion(quat[3], quat[0], quat[1], quat[2]).toRotationMatrix()
    cam = {"name": "c", "width": draw(st.integers(1, 4000)), "height": draw(st.integers(1, 4000)),
           "K": [[draw(f), 0, draw(st.floats(-1000, 1000))], [0, draw(f), draw(st.floats(-1000, 1000))], [0, 0, 1]],
           "world_T_camera": {"rotation": R.tolist(),
                              "translation": draw(st.lists(st.floats(-100, 100), min_size=3, max_size=3))}}
    n = draw(st.sampled_from([None, 4, 5]))
    if n is not None:
        cam["dist"] = draw(st.lists(st.floats(-0.5, 0.5), min_size=n, max_size=n))
    return cam


@settings(max_examples=_n(200), **SETTINGS)
@given(valid_camera())
def test_a_valid_camera_file_is_read_and_projects_as_the_pinhole_and_distortion_model_say(tmp_path_factory, value):
    path = _write(tmp_path_factory, json.dumps(value), ".json")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        (cam,) = Camera.list_from_json(path)
    np.testing.assert_array_equal(cam.K, np.array(value["K"], dtype=float))
    assert (cam.width, cam.height) == (value["width"], value["height"])
    _check_projection(cam)


POSE = {"joints": {"leftThigh_hip": 70, "leftShin_knee": 30},
        "root": {"position": [0, 0, 8], "quaternion_xyzw": [0, 0, 0, 1]}}
POSE_ROTATION = {"root": {"position": [0.5, 0, 8], "rotation": [[1, 0, 0], [0, 0, -1], [0, 1, 0]]}}


@pytest.fixture(scope="module")
def walker():
    return kms2pin.load(SPECS / "lowerbody.kms", root="free")


@settings(max_examples=_n(300), **SETTINGS)
@given(value=mutated_json(POSE) | mutated_json(POSE_ROTATION))
def test_pose_files_raise_only_input_data_error(tmp_path_factory, walker, value):
    from kms2pin.video.init import read_pose_json

    path = _write(tmp_path_factory, json.dumps(value), ".json")
    try:
        q = read_pose_json(walker, path)
    except kms2pin.InputDataError as err:
        assert str(err).startswith(str(path)), err
        return
    assert q.shape == (walker.nq,) and np.isfinite(q).all()
    assert abs(np.linalg.norm(q[3:7]) - 1) < 1e-9
    assert np.isfinite(walker.maximal_coordinates(q)).all()


CSV_CELLS = st.sampled_from(["0", "1.5", "-90", "1e308", "-1e308", "1e999", "nan", "inf", "", " ", "x", '"',
                             "0x10", "1,2", "\x00", "١٢", "1e-320"]) | st.floats(allow_nan=True).map(repr)


@st.composite
def trajectory_csv(draw, columns) -> str:
    header = list(columns)
    if draw(st.booleans()):
        header = draw(st.permutations(header))
    if draw(st.integers(0, 4)) == 0:
        header = draw(st.lists(st.sampled_from([*columns, "frame", "x", ""]), max_size=len(columns) + 2))
    rows = draw(st.lists(st.lists(CSV_CELLS, min_size=max(len(header) - 1, 0), max_size=len(header) + 1), max_size=4))
    sep = draw(st.sampled_from(["\n", "\r\n", "\r"]))
    return sep.join(",".join(r) for r in [header, *rows]) + draw(st.sampled_from(["", sep]))


@settings(max_examples=_n(300), **SETTINGS)
@given(st.data())
def test_trajectory_csvs_raise_only_input_data_error(tmp_path_factory, walker, data):
    from kms2pin.ecm import Trajectory

    columns = Trajectory.columns(walker)
    text = data.draw(trajectory_csv(columns) | st.text(max_size=200))
    path = _write(tmp_path_factory, text, ".csv")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        try:
            traj = Trajectory.from_csv(walker, path)
        except kms2pin.InputDataError as err:
            assert str(err).startswith(str(path)), err
            return
        assert np.isfinite(traj.q).all()
        for q in traj.q:
            assert abs(np.linalg.norm(q[3:7]) - 1) < 1e-9
            assert np.isfinite(walker.maximal_coordinates(q)).all()


@pytest.fixture(scope="module")
def walker_csv(walker, tmp_path_factory) -> tuple[str, np.ndarray]:
    """A trajectory CSV of three random poses as ``to_csv`` writes it, and their configurations."""
    from kms2pin.ecm import Trajectory
    from kms2pin.ecm.motions import make_motion

    q = make_motion(walker, "random", 3, np.random.default_rng(5))
    path = tmp_path_factory.mktemp("csv") / "walk.csv"
    Trajectory(walker, q).to_csv(path)
    return path.read_text(), q


@settings(max_examples=_n(300), **SETTINGS)
@given(st.data())
def test_a_trajectory_csv_with_one_cell_changed_reads_to_its_poses_or_names_the_cell(tmp_path_factory, walker,
                                                                                     walker_csv, data):
    """A valid file with one data cell replaced: either an InputDataError naming the file and
    the cell's line and column, or the poses the cells say (a scaled root quaternion read as
    the same rotation, every body pose finite), the other frames unchanged."""
    from kms2pin.ecm import Trajectory

    text, q = walker_csv
    lines = text.splitlines()
    header = lines[0].split(",")
    row = data.draw(st.integers(1, len(lines) - 1))
    col = data.draw(st.integers(1, len(header) - 1))  # not the frame number
    cell = data.draw(CSV_CELLS.filter(lambda c: "," not in c and '"' not in c and "\x00" not in c))
    cells = lines[row].split(",")
    cells[col] = cell
    lines[row] = ",".join(cells)
    path = _write(tmp_path_factory, "\n".join(lines) + "\n", ".csv")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        try:
            traj = Trajectory.from_csv(walker, path)
        except kms2pin.InputDataError as err:
            assert str(err).startswith(f"{path}:{row + 1}:"), err
            event("refused")
            return
    event("read")
    assert traj.q.shape == q.shape and np.isfinite(traj.q).all()
    others = [k for k in range(len(q)) if k != row - 1]
    np.testing.assert_allclose(traj.q[others], q[others], atol=1e-6)  # the CSV's printed digits
    value = float(cell)
    name = header[col]
    if name.startswith("root_q"):  # the quaternion renormalized: the same rotation as the cells say
        cells_q = np.array([float(c) for c in lines[row].split(",")[4:8]])
        cells_q /= np.abs(cells_q).max()  # scaled first: 1e308 squared overflows
        assert abs(np.linalg.norm(traj.q[row - 1, 3:7]) - 1) < 1e-12
        np.testing.assert_allclose(np.abs(traj.q[row - 1, 3:7] @ cells_q) / np.linalg.norm(cells_q), 1, atol=1e-9)
    elif name.startswith("root_"):
        assert traj.q[row - 1, "xyz".index(name[-1])] == value
    else:
        np.testing.assert_allclose(walker.coordinates(traj.q[row - 1])[col - 1], value, rtol=1e-12, atol=1e-9)
    assert np.isfinite(walker.maximal_coordinates(traj.q[row - 1])).all()


# ----------------------------------------------------------------------------- the joint-control page
# Whatever arrives on its socket, the page answers with a status and JSON (or the standard
# library's error page for a broken request line), prints no traceback, and stays up.


@pytest.fixture(scope="module")
def control_page():
    from kms2pin.viewer import JointControl

    ctl = JointControl(kms2pin.load(SPECS / "lowerbody.kms"))
    try:
        yield ctl
    finally:
        ctl.close()


def _exchange(port: int, raw: bytes) -> bytes:
    """Send ``raw``, close our side, and return the answer: b"" when the server, having
    refused the request early, closed the connection with data of it unread (a reset)."""
    data = b""
    with socket.create_connection(("127.0.0.1", port), timeout=20) as s:
        try:
            s.sendall(raw)
            s.shutdown(socket.SHUT_WR)  # everything is sent: the server sees the end of it
        except (BrokenPipeError, ConnectionResetError, OSError):
            pass  # already answered and closed
        try:
            while chunk := s.recv(65536):
                data += chunk
        except ConnectionResetError:
            pass
    return data


HEADER_LINES = st.sampled_from([
    "Content-Type: application/json", "Content-Length: -1", "Content-Length: 99999999", "Content-Length: x",
    "Content-Length: 3", "Content-Length: 0", "Transfer-Encoding: chunked", "Origin: http://attacker.example",
    "Origin: null", "Host: attacker.example", "Host: ", "Connection: keep-alive", "Expect: 100-continue",
])
BODIES = (JSON_VALUES.map(lambda v: json.dumps(v).encode())
          | st.fixed_dictionaries({"name": st.sampled_from(["leftShin_knee", "rightThigh_hip", "x"]) | JSON_LEAVES,
                                   "deg": JSON_LEAVES}).map(lambda v: json.dumps(v).encode())
          | st.builds(lambda d: json.dumps({"pose": d}).encode(), st.text(max_size=40) | JSON_LEAVES)
          | st.builds(lambda d: json.dumps({"view": d}).encode(), st.sampled_from(["front", "side", "sid"]) | JSON_LEAVES)
          | st.binary(max_size=200)
          | st.integers(1, 40000).map(lambda n: b"[" * n + b"]" * n))


# capfd is read (and so emptied) by every example
HTTP_SETTINGS = {**SETTINGS, "suppress_health_check": [HealthCheck.too_slow, HealthCheck.function_scoped_fixture]}


@settings(max_examples=_n(200), **HTTP_SETTINGS)
@given(method=st.sampled_from(["GET", "POST", "PUT", "DELETE", "HEAD"]),
       path=st.sampled_from(["/", "/state", "/joint", "/pose", "/reset", "/camera", "/x", "/joint?x=1", "//"]),
       headers=st.lists(HEADER_LINES, max_size=3), body=BODIES, with_length=st.booleans())
def test_the_joint_control_page_survives_any_request(control_page, capfd, method, path, headers, body, with_length):
    port = int(control_page.url.rsplit(":", 1)[1].strip("/"))
    lines = [f"{method} {path} HTTP/1.1"]
    if not any(h.startswith("Host:") for h in headers):
        lines.append(f"Host: 127.0.0.1:{port}")
    if with_length and not any(h.startswith("Content-Length") for h in headers):
        lines.append(f"Content-Length: {len(body)}")
    raw = ("\r\n".join(lines + headers) + "\r\n\r\n").encode() + body
    answer = _exchange(port, raw)
    status = int(answer.split(b" ", 2)[1]) if answer else 0  # 0: refused early, the answer lost in a reset
    assert status in (0, 200, 400, 403, 404, 408, 411, 413, 501), answer[:300]
    if status == 200 and method == "POST":
        state = json.loads(answer.split(b"\r\n\r\n", 1)[1])
        assert all(math.isfinite(j["deg"]) for j in state["joints"])
    assert np.isfinite(control_page.q).all()
    ok = _exchange(port, f"GET /state HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n\r\n".encode())
    assert ok.startswith(b"HTTP/1.0 200"), ok[:200]
    assert "Traceback" not in capfd.readouterr().err


@settings(max_examples=_n(60), **HTTP_SETTINGS)
@given(st.binary(max_size=400))
def test_the_joint_control_page_survives_random_bytes(control_page, capfd, raw):
    port = int(control_page.url.rsplit(":", 1)[1].strip("/"))
    _exchange(port, raw)
    ok = _exchange(port, f"GET /state HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n\r\n".encode())
    assert ok.startswith(b"HTTP/1.0 200"), ok[:200]
    assert "Traceback" not in capfd.readouterr().err
