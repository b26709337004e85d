"""``kms2pin check`` and ``kms2pin export`` (in-process through ``kms2pin.cli.main``)."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET

import pinocchio as pin
import pytest
from conftest import SPECS

import kms2pin
from kms2pin.cli import main

TWO_SYSTEMS = """
bvec origin { pos(0, 0, 0); orient(0, 0, 1); }
bvec elsewhere { pos(3, 0, 0); orient(0, 0, 1); }
rigidBodySystem alpha {
    ellipsoidBody a { innerLam(1, 1, 1); outerLam(1, 1, 1);
        bvec base { pos(0, 0, 0); orient(0, 0, 1); }
        bvec tip { pos(0, 0, 1); orient(1, 0, 0); } }
    ellipsoidBody b { innerLam(0.5, 0.5, 1); outerLam(0.5, 0.5, 1);
        bvec j { pos(0, 0, -1); orient(1, 0, 0); } }
    constraint revolute(a.tip, b.j, 30);
}
rigidBodySystem beta {
    ellipsoidBody c { innerLam(1, 1, 1); outerLam(2, 2, 2);
        bvec base { pos(0, 0, 0); orient(0, 0, 1); } }
}
constraint revolute(alpha.a.base, origin);
constraint fixed(beta.c.base, elsewhere);
"""


@pytest.fixture
def two_systems(tmp_path):
    path = tmp_path / "two.kms"
    path.write_text(TWO_SYSTEMS)
    return path


@pytest.fixture
def broken(tmp_path):
    path = tmp_path / "broken.kms"
    path.write_text(TWO_SYSTEMS.replace("a.tip, b.j", "a.tip, b.k"))
    return path


def listing(folder):
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


# ----------------------------------------------------------------------------- check


def test_check_prints_the_tree_and_the_dof(spec_path, capsys):
    assert main(["check", str(spec_path)]) == 0
    out = capsys.readouterr().out
    spec = kms2pin.parse(spec_path)
    (system,) = spec.systems
    count = {kind: sum(j.kind == kind for j in system.joints) for kind in ("revolute", "spherical", "prismatic", "fixed")}
    dof = count["revolute"] + 3 * count["spherical"] + count["prismatic"]
    shown = [k for k, n in count.items() if n or k in ("revolute", "fixed")]
    assert out.splitlines()[0] == (
        f"{spec_path}: rigidBodySystem '{system.name}': {len(system.bodies)} bodies, "
        f"{dof} degrees of freedom ({', '.join(f'{count[k]} {k}' for k in shown)} joints)"
    )
    assert out.splitlines()[1] == "inertial frame"
    for body in system.bodies:
        assert f" {body.name}  [" in out
    assert len(out.splitlines()) == 2 + len(system.bodies)


def test_check_tree_shows_nesting_and_rest_angles(capsys):
    assert main(["check", str(SPECS / "puma600.kms")]) == 0
    lines = capsys.readouterr().out.splitlines()[2:]
    assert [line.index("─") for line in lines] == [1, 4, 7, 10, 13]  # a chain
    assert "link1  [revolute 'link1_lowerLink', 1 DoF, axis (0, -1, 0) in base, rest 180 deg]" in lines[1]
    assert "manipulator  [fixed 'manipulator_lowerLink', 0 DoF" in lines[4] and "rest" not in lines[4]


def test_check_json_has_every_body(spec_path, capsys):
    assert main(["check", "--json", str(spec_path)]) == 0
    data = json.loads(capsys.readouterr().out)
    (system,) = kms2pin.parse(spec_path).systems
    (sj,) = data["systems"]
    assert sj["name"] == system.name
    assert [b["name"] for b in sj["bodies"]] == [b.name for b in system.bodies]
    assert sj["dof"] == system.dof
    for b, body, joint in zip(sj["bodies"], system.bodies, system.joints):
        assert b["inner"] == list(body.inner) and b["outer"] == list(body.outer)
        assert b["parent"] == joint.parent
        assert b["joint"]["type"] == joint.kind and b["joint"]["default_angle_deg"] == joint.default_angle
        assert b["joint"]["dof"] == {"fixed": 0, "revolute": 1, "spherical": 3, "prismatic": 1}[joint.kind]


def test_check_two_systems(two_systems, capsys):
    assert main(["check", str(two_systems)]) == 0
    out = capsys.readouterr().out
    assert "rigidBodySystem 'alpha': 2 bodies, 2 degrees of freedom" in out
    assert "rigidBodySystem 'beta': 1 bodies, 0 degrees of freedom" in out
    assert main(["check", "--json", str(two_systems)]) == 0
    assert [s["name"] for s in json.loads(capsys.readouterr().out)["systems"]] == ["alpha", "beta"]


def test_check_on_a_model_error_prints_nothing_on_stdout(broken, capsys):
    assert main(["check", "--json", str(broken)]) == 1
    out, err = capsys.readouterr()
    assert out == ""
    assert err.startswith(f"{broken}:") and "has no bound vector 'k'" in err


# ----------------------------------------------------------------------------- export


def test_export_writes_urdf_srdf_and_mesh(spec_path, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["export", str(spec_path), "-o", str(out)]) == 0
    (system,) = kms2pin.parse(spec_path).systems
    assert listing(out) == sorted(["meshes", "meshes/unit_sphere.obj", f"{system.name}.urdf", f"{system.name}.srdf"])
    printed = capsys.readouterr().out.split()
    assert sorted(printed) == sorted(
        str(out / p) for p in ("meshes/unit_sphere.obj", f"{system.name}.urdf", f"{system.name}.srdf")
    )
    robot = kms2pin.load(spec_path)
    assert (out / f"{system.name}.urdf").read_text() == robot.urdf
    assert (out / f"{system.name}.srdf").read_text() == robot.srdf
    model = pin.buildModelFromUrdf(str(out / f"{system.name}.urdf"))
    assert model.nv == robot.nv  # one URDF joint per degree of freedom (three per spherical joint)
    continuous = sum(1 for t in ET.parse(out / f"{system.name}.urdf").getroot().iter("joint") if t.get("type") == "continuous")
    assert model.nq == model.nv + continuous  # continuous joints: (cos, sin) in Pinocchio's parser
    links = {link.get("name") for link in ET.parse(out / f"{system.name}.urdf").getroot().iter("link")}
    between = {f"{j.name}_{a}_link" for j in system.joints if j.kind == "spherical" for a in "xy"}
    assert links == {"world", *robot.bodies, *between}
    assert (out / "meshes" / "unit_sphere.obj").read_text().startswith("# unit sphere")


def test_export_default_folder_is_urdf_out(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["export", str(SPECS / "puma600.kms")]) == 0
    assert (tmp_path / "urdf_out" / "puma600.urdf").is_file()


def test_export_two_systems_and_pick_one(two_systems, tmp_path, capsys):
    both, one = tmp_path / "both", tmp_path / "one"
    assert main(["export", str(two_systems), "-o", str(both)]) == 0
    assert listing(both) == ["alpha.srdf", "alpha.urdf", "beta.srdf", "beta.urdf", "meshes", "meshes/unit_sphere.obj"]
    assert main(["export", str(two_systems), "-o", str(one), "--system", "beta"]) == 0
    assert listing(one) == ["beta.srdf", "beta.urdf", "meshes", "meshes/unit_sphere.obj"]
    beta = ET.parse(one / "beta.urdf").getroot()
    assert beta.get("name") == "beta"
    assert {link.get("name") for link in beta.iter("link")} == {"world", "c"}
    assert pin.buildModelFromUrdf(str(one / "beta.urdf")).nq == 0  # fixed to the inertial frame


def test_export_unknown_system_is_an_error_and_writes_nothing(two_systems, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["export", str(two_systems), "-o", str(out), "--system", "gamma"]) == 1
    assert "no rigidBodySystem 'gamma'" in capsys.readouterr().err
    assert not out.exists()


def test_export_root_free_has_a_floating_joint_from_world(spec_path, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["export", str(spec_path), "-o", str(out), "--root", "free"]) == 0
    (system,) = kms2pin.parse(spec_path).systems
    urdf = ET.parse(out / f"{system.name}.urdf").getroot()
    links = {f"{j.name}_{a}_link" for j in system.joints[1:] if j.kind == "spherical" for a in "xy"}
    assert {link.get("name") for link in urdf.iter("link")} == {"world", *(b.name for b in system.bodies), *links}
    from_world = [j for j in urdf.iter("joint") if j.find("parent").get("link") == "world"]
    assert [(j.get("name"), j.get("type")) for j in from_world] == [("root_joint", "floating")]
    # the spec's joint to the inertial frame replaced; a spherical joint is three
    assert len(list(urdf.iter("joint"))) == 1 + sum(3 if j.kind == "spherical" else 1 for j in system.joints[1:])
    srdf = ET.parse(out / f"{system.name}.srdf").getroot()
    assert system.joints[0].name not in {j.get("name") for j in srdf.iter("joint")}
    model = pin.buildModelFromUrdf(str(out / f"{system.name}.urdf"))  # no free flyer to pass
    assert model.nv == kms2pin.load(spec_path, root="free").nv


def test_export_on_a_model_error_writes_nothing(broken, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["export", str(broken), "-o", str(out)]) == 1
    assert not out.exists()
    out.mkdir()
    assert main(["export", str(broken), "-o", str(out)]) == 1
    assert listing(out) == []  # the folder stays empty


def test_export_on_a_model_error_leaves_an_earlier_export_unchanged(two_systems, broken, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["export", str(two_systems), "-o", str(out)]) == 0
    (out / "notes.txt").write_text("mine")
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert main(["export", str(broken), "-o", str(out)]) == 1
    after = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert after == before
    assert not [p for p in out.rglob("*") if p.name.endswith(".tmp")]


def test_export_overwrites_an_earlier_export(two_systems, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["export", str(two_systems), "-o", str(out)]) == 0
    (out / "alpha.urdf").write_text("stale")
    assert main(["export", str(two_systems), "-o", str(out)]) == 0
    assert (out / "alpha.urdf").read_text().startswith("<?xml")
    assert not [p for p in out.rglob("*") if p.name.endswith(".tmp")]


def test_export_into_an_unusable_folder_is_a_model_error_not_a_traceback(two_systems, tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    assert main(["export", str(two_systems), "-o", str(blocker)]) == 1
    assert "cannot write to" in capsys.readouterr().err
    assert blocker.read_text() == "not a folder"


def test_version(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["--version"])
    assert exit_.value.code == 0
    assert capsys.readouterr().out.strip() == f"kms2pin {kms2pin.__version__}"


def test_exported_files_get_the_usual_permissions(tmp_path, capsys):
    import os

    umask = os.umask(0o022)
    try:
        assert main(["export", str(SPECS / "puma600.kms"), "-o", str(tmp_path)]) == 0
    finally:
        os.umask(umask)
    for p in (tmp_path / "puma600.urdf", tmp_path / "puma600.srdf", tmp_path / "meshes" / "unit_sphere.obj"):
        assert p.stat().st_mode & 0o777 == 0o644, oct(p.stat().st_mode)


def test_root_free_with_two_joints_to_the_inertial_frame(tmp_path, capsys):
    path = tmp_path / "two_roots.kms"
    path.write_text("""
    bvec o { pos(0, 0, 0); orient(1, 0, 0); }
    bvec p { pos(1, 0, 0); orient(1, 0, 0); }
    rigidBodySystem s {
        ellipsoidBody a { innerLam(1, 1, 1); outerLam(1, 1, 1); bvec j { pos(0, 0, 0); orient(1, 0, 0); } }
        ellipsoidBody b { innerLam(1, 1, 1); outerLam(1, 1, 1); bvec j { pos(0, 0, 0); orient(1, 0, 0); } }
    }
    constraint revolute(s.a.j, o);
    constraint revolute(s.b.j, p);
    """)
    assert main(["export", str(path), "-o", str(tmp_path / "spec")]) == 0
    assert main(["export", str(path), "-o", str(tmp_path / "free"), "--root", "free"]) == 1
    err = capsys.readouterr().err
    assert "2 such joints (a, b)" in err and "Traceback" not in err
    assert not (tmp_path / "free").exists()
