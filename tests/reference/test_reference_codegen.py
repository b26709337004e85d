"""Generated C and Python (thesis §3.2.2) against the SymPy model, and the codegen CLI."""

from __future__ import annotations

import ctypes
import importlib.util
import shutil
import subprocess

import numpy as np
import pytest
from conftest import skip_or_fail_in_ci

from kms2pin.cli import build_parser, main
from kms2pin.reference import generate_c, generate_python, symbolic_model

from ._support import SPECS, load_system

SEED = 314


def _random_points(model, rng, count=5):
    """Points anywhere (not only valid ones), so every term of every entry matters."""
    return [rng.normal(size=model.nq) for _ in range(count)]


def _assert_close(actual, expected):
    scale = max(1.0, float(np.max(np.abs(expected))))
    np.testing.assert_allclose(actual, expected, rtol=1e-12, atol=1e-12 * scale)


def _load_python(path, name):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def compiler():
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        skip_or_fail_in_ci("no C compiler (cc or gcc) on PATH")
    return cc


_SLOW = pytest.mark.slow


@pytest.mark.parametrize(
    "spec_name, root",
    [
        ("puma600", "spec"),
        ("lowerbody", "spec"),
        ("fullbody", "spec"),
        ("jplhand", "spec"),
        ("fullbody", "free"),
        ("mixed", "spec"),  # spherical and prismatic rows (the line rows are cubic)
        ("gantry", "spec"),
        pytest.param("human", "spec", marks=_SLOW),
        pytest.param("puma600", "free", marks=_SLOW),
        pytest.param("lowerbody", "free", marks=_SLOW),
        pytest.param("jplhand", "free", marks=_SLOW),
    ],
)
def test_generated_c_compiles_and_matches_the_sympy_model(spec_name, root, compiler, tmp_path):
    system = load_system(spec_name)
    model = symbolic_model(system, root)
    header, source = generate_c(model)
    (tmp_path / f"{system.name}_constraints.h").write_text(header)
    (tmp_path / f"{system.name}_constraints.c").write_text(source)
    lib_path = tmp_path / "libkms.so"
    out = subprocess.run(
        [
            compiler,
            "-shared",
            "-fPIC",
            "-O1",
            "-Wall",
            "-Werror",
            "-o",
            str(lib_path),
            str(tmp_path / f"{system.name}_constraints.c"),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr
    lib = ctypes.CDLL(str(lib_path))
    dptr = ctypes.POINTER(ctypes.c_double)
    lib.kms_constraints.argtypes = [dptr, dptr]
    lib.kms_jacobian.argtypes = [dptr, dptr]
    labels = (ctypes.c_char_p * model.nc).in_dll(lib, "kms_constraint_labels")
    assert [s.decode() for s in labels] == list(model.labels)
    lam_C, lam_Cq = model.lambdified()
    for q in _random_points(model, np.random.default_rng(SEED)):
        C = np.empty(model.nc)
        Cq = np.empty(model.nc * model.nq)
        lib.kms_constraints(q.ctypes.data_as(dptr), C.ctypes.data_as(dptr))
        lib.kms_jacobian(q.ctypes.data_as(dptr), Cq.ctypes.data_as(dptr))
        _assert_close(C, lam_C(q))
        _assert_close(Cq.reshape(model.nc, model.nq), lam_Cq(q))
        _assert_close(C, model.C(q))
        _assert_close(Cq.reshape(model.nc, model.nq), model.C_q(q))


def test_generated_python_matches_the_sympy_model(spec_name, root, tmp_path):
    system = load_system(spec_name)
    model = symbolic_model(system, root)
    path = tmp_path / f"{system.name}_constraints.py"
    path.write_text(generate_python(model))
    mod = _load_python(path, f"gen_{spec_name}_{root}")
    assert (mod.NQ, mod.NC, mod.N_BODIES, mod.DOF, mod.ROOT) == (model.nq, model.nc, model.n_bodies, model.dof, root)
    assert mod.LABELS == model.labels and mod.COORDINATES == model.coordinate_labels
    lam_C, lam_Cq = model.lambdified()
    for q in _random_points(model, np.random.default_rng(SEED + 1)):
        _assert_close(mod.kms_constraints(q), lam_C(q))
        _assert_close(mod.kms_jacobian(q.reshape(-1, 7)), lam_Cq(q))


def test_generated_c_declares_the_sizes_and_labels_every_row():
    model = symbolic_model(load_system("fullbody"))
    header, source = generate_c(model)
    assert "#define KMS_NQ 105" in header and "#define KMS_NC 123" in header and "#define KMS_DOF 12" in header
    assert "void kms_jacobian(const double q[KMS_NQ], double Cq[KMS_NC * KMS_NQ]);" in header
    assert '#include "fullBody_constraints.h"' in source
    for r, label in enumerate(model.labels):
        assert f"C[{r}] = " in source and f"/* {label} */" in source


def test_codegen_cli_writes_c_files_and_prints_their_paths(tmp_path, capsys):
    assert main(["codegen", str(SPECS / "puma600.kms"), "--lang", "c", "-o", str(tmp_path)]) == 0
    printed = capsys.readouterr().out.split()
    assert printed == [str(tmp_path / "puma600_constraints.h"), str(tmp_path / "puma600_constraints.c")]
    header, source = generate_c(symbolic_model(load_system("puma600")))
    assert (tmp_path / "puma600_constraints.h").read_text() == header
    assert (tmp_path / "puma600_constraints.c").read_text() == source


def test_codegen_cli_writes_a_python_module_for_the_free_root(tmp_path, capsys):
    code = main(["codegen", str(SPECS / "jplhand.kms"), "--lang", "python", "--root", "free", "-o", str(tmp_path)])
    assert code == 0
    path = tmp_path / "JPLHand_constraints.py"
    assert capsys.readouterr().out.split() == [str(path)]
    mod = _load_python(path, "gen_cli_jplhand")
    assert mod.ROOT == "free" and mod.DOF == 16


def test_codegen_cli_reports_a_broken_spec_with_its_location_and_exits_1(tmp_path, capsys):
    bad = tmp_path / "bad.kms"
    bad.write_text(
        "bvec origin { pos(0,0,0); orient(1,0,0); }\n"
        "rigidBodySystem s {\n"
        "    ellipsoidBody a { innerLam(1,1,1); outerLam(1,1,1); bvec b { pos(0,0,0); orient(1,0,0); } }\n"
        "}\n"
        "constraint revolute(s.a.c, origin);\n"
    )
    out_dir = tmp_path / "out"
    assert main(["codegen", str(bad), "-o", str(out_dir)]) == 1
    err = capsys.readouterr().err
    assert f"{bad}:5:" in err and "error:" in err and "'c'" in err
    assert not out_dir.exists()


def test_codegen_cli_unknown_system_exits_1_and_missing_file_exits_2(tmp_path, capsys):
    assert main(["codegen", str(SPECS / "puma600.kms"), "--system", "puma60", "-o", str(tmp_path)]) == 1
    assert "did you mean 'puma600'" in capsys.readouterr().err
    assert main(["codegen", str(tmp_path / "nope.kms"), "-o", str(tmp_path)]) == 2


def test_codegen_is_a_sub_command_with_its_options():
    help_text = build_parser().format_help()
    assert "codegen" in help_text
    args = build_parser().parse_args(["codegen", "m.kms", "--lang", "python", "--root", "free", "-o", "out"])
    assert (args.lang, args.root, args.output, args.system) == ("python", "free", "out", None)
