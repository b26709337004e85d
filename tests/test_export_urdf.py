"""The URDF of every thesis spec passes urdfdom's check_urdf and loads in Pinocchio."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pinocchio as pin

import kms2pin
from kms2pin.cli import main


def _check_urdf() -> str:
    exe = Path(sys.executable).with_name("check_urdf")
    return str(exe) if exe.exists() else (shutil.which("check_urdf") or "check_urdf")


def test_every_spec_exports_a_urdf_that_check_urdf_accepts(spec_path, tmp_path):
    assert main(["export", str(spec_path), "-o", str(tmp_path)]) == 0
    urdfs = list(tmp_path.glob("*.urdf"))
    assert len(urdfs) == 1
    out = subprocess.run([_check_urdf(), str(urdfs[0])], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "Successfully Parsed XML" in out.stdout
    assert (tmp_path / "meshes" / "unit_sphere.obj").exists()


def test_exported_files_load_with_pinocchio_urdf_and_geometry_parsers(spec_path, tmp_path):
    main(["export", str(spec_path), "-o", str(tmp_path)])
    urdf = next(tmp_path.glob("*.urdf"))
    model = pin.buildModelFromUrdf(str(urdf))
    robot = kms2pin.load(spec_path)
    assert model.nq == robot.model.nq
    geom = pin.buildGeomFromUrdf(model, str(urdf), pin.GeometryType.VISUAL, package_dirs=[str(tmp_path)])
    assert geom.ngeoms == 2 * len(robot.bodies)
    srdf = urdf.with_suffix(".srdf")
    pin.loadReferenceConfigurations(model, str(srdf), False)
    assert (model.referenceConfigurations["rest"] == robot.q_rest).all()
