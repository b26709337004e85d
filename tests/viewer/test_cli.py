"""``kms2pin view``: --html / --png outputs, --pose errors, serving."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import urllib.request

import numpy as np
import pytest

from kms2pin.cli import main
from kms2pin.viewer import read_png
from kms2pin.viewer.render import inner_mask

from ._util import SPECS, load, page_commands


def test_html_is_standalone_with_native_ellipsoids(tmp_path, capsys):
    out = tmp_path / "fullbody.html"
    assert main(["view", str(SPECS / "fullbody.kms"), "--no-serve", "--html", str(out),
                 "--pose", "leftThigh_hip=40", "rightShin_knee=60"]) == 0
    assert str(out) in capsys.readouterr().out
    html = out.read_text()
    assert "MeshCat.Viewer" in html and "viewer.connect()" not in html  # opens without a server
    robot = load("fullbody")
    cmds = page_commands(html)
    objects = [c for c in cmds if c["type"] == "set_object"]
    geometry_types = {g["type"] for c in objects for g in c["object"].get("geometries", [])}
    assert geometry_types <= {"SphereGeometry", "CylinderGeometry"}, "no URDF meshes drawn as well"
    # one inner and one outer ellipsoid per body, each a unit sphere scaled once by its semi-axes
    for kind in ("inner", "outer"):
        for body in robot.bodies:
            (c,) = [c for c in objects if c["path"].endswith(f"/bodies/{body}/{kind}")]
            scale = np.array(c["object"]["object"]["matrix"]).reshape(4, 4)
            semi = robot.inner(body) if kind == "inner" else robot.outer(body)
            np.testing.assert_allclose(np.diag(scale)[:3], semi)
            assert c["object"]["geometries"][0]["radius"] == 1.0
    body_tf = [c for c in cmds if c["type"] == "set_transform" and "/bodies/" in c["path"]
               and c["path"].rsplit("/bodies/", 1)[1] in robot.bodies]
    assert len({c["path"] for c in body_tf}) == len(robot.bodies)
    for c in body_tf:  # rigid transforms only: no second scaling
        R = np.array(c["matrix"]).reshape(4, 4).T[:3, :3]
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-9)
    # the bodies where the robot puts them at the pose asked for: each body's placement
    # relative to the first (whatever the scene's own placement), as Pinocchio's
    q = robot.with_coordinates(robot.q_rest, {"leftThigh_hip": 40, "rightShin_knee": 60})
    drawn = {c["path"].rsplit("/bodies/", 1)[1]: np.array(c["matrix"]).reshape(4, 4).T for c in body_tf}
    first = robot.bodies[0]
    for body in robot.bodies:
        expected = robot.body_pose(q, first).inverse() * robot.body_pose(q, body)
        np.testing.assert_allclose(np.linalg.inv(drawn[first]) @ drawn[body], expected.homogeneous, atol=1e-9)
    rest = robot.body_pose(robot.q_rest, "rightThigh").inverse() * robot.body_pose(robot.q_rest, "rightShin")
    assert not np.allclose(np.linalg.inv(drawn["rightThigh"]) @ drawn["rightShin"], rest.homogeneous, atol=1e-3)


@pytest.mark.browser
def test_png_is_written(tmp_path, capsys):
    out = tmp_path / "puma.png"
    assert main(["view", str(SPECS / "puma600.kms"), "--no-serve", "--png", str(out), "--size", "300x240",
                 "--camera", "iso"]) == 0
    img = read_png(out)
    assert img.shape == (240, 300, 3)
    assert inner_mask(img).sum() > 1000


@pytest.mark.parametrize(("pose", "message"), [
    ("leftShin_kne=10", "did you mean 'leftShin_knee'"),
    ("leftShin_knee=ten", "not a number"),
    ("trunk_waist=1", "fixed"),
])
def test_bad_pose_exits_2(tmp_path, capsys, pose, message):
    code = main(["view", str(SPECS / "lowerbody.kms"), "--no-serve", "--html", str(tmp_path / "x.html"),
                 "--pose", pose])
    err = capsys.readouterr().err
    assert code == 2
    assert "kms2pin view: error: --pose:" in err and message in err
    assert not (tmp_path / "x.html").exists()


def test_usage_and_model_errors(tmp_path, capsys):
    spec = str(SPECS / "lowerbody.kms")
    assert main(["view", spec, "--no-serve"]) == 2
    assert "--no-serve needs --html or --png" in capsys.readouterr().err
    assert main(["view", str(tmp_path / "missing.kms"), "--no-serve", "--html", "x.html"]) == 2
    capsys.readouterr()
    assert main(["view", spec, "--system", "lowerBody", "--no-serve", "--html", str(tmp_path / "x.html")]) == 1
    assert "lowerBodyBipedal" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(["view", spec, "--camera", "back"])
    assert exc.value.code == 2


def test_serve_prints_urls_and_stops_cleanly():
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen([sys.executable, "-m", "kms2pin.cli", "view", str(SPECS / "puma600.kms"),
                             "--pose", "link2_lowerLink=45"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        lines = [proc.stdout.readline() for _ in range(3)]
        urls = {line.split(":", 1)[0]: line.split()[-1] for line in lines if "http" in line}
        viewer, control = urls["meshcat viewer"], urls["joint control"]
        with urllib.request.urlopen(viewer, timeout=10) as res:
            assert res.status == 200
        with urllib.request.urlopen(control + "state", timeout=10) as res:
            assert "link2_lowerLink=45" in json.loads(res.read())["pose"]
        req = urllib.request.Request(control + "joint", method="POST",
                                     data=json.dumps({"name": "link3_lowerLink", "deg": 30}).encode())
        with urllib.request.urlopen(req, timeout=10) as res:
            assert "link3_lowerLink=30" in json.loads(res.read())["pose"]
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=15) == 0
        with pytest.raises(OSError):  # the meshcat server went down with it
            urllib.request.urlopen(viewer, timeout=3)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stdout.close()
        proc.stderr.close()


def test_a_host_this_machine_cannot_listen_on_is_a_usage_error_at_once(capsys):
    """--host with an address of no interface here (TEST-NET-3, RFC 5737): refused before a
    server starts (it once waited 30 s for a server that could not start)."""
    assert main(["view", str(SPECS / "lowerbody.kms"), "--host", "203.0.113.7"]) == 2
    err = capsys.readouterr().err
    assert "--host '203.0.113.7': not an address of this machine" in err
    assert "warning" not in err
