"""Outputs are owned and never mixed (kms2pin/commands/_outputs.py), with real processes.

A run holds OUT/.kms2pin.lock (an flock, the file naming its PID and command) while it
lives: a second track, synth, segment or export into OUT is refused naming it; a lock
left by a killed run is taken over with a note.  SIGTERM stops ``track`` as Ctrl-C does
(exit status 143 and 130): every output (trajectory.csv, poses.npz, overlay.mp4) holds
the same frames, up to the last finished one, and meta.json says ``complete: false``.  Whole files are written under a temporary name and renamed.
"""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import SPECS, video_frames

from kms2pin.cli import main
from kms2pin.commands._outputs import LOCK_NAME, owned_output, replaced
from kms2pin.errors import OutputError

LOWER = SPECS / "lowerbody.kms"
HOLD = """
import sys, time
from kms2pin.commands._outputs import owned_output
with owned_output(sys.argv[1], "track"):
    print("locked", flush=True)
    time.sleep(120)
"""


def kms2pin(*argv, **kw) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "kms2pin.cli", *map(str, argv)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, **kw)


@pytest.fixture
def holder(tmp_path):
    """A live process holding ``tmp_path / "out"``'s lock; killed at the end."""
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-c", HOLD, str(out)], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "locked"
    yield out, proc
    proc.kill()
    proc.wait()


@pytest.fixture(scope="module")
def masks(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("masks")
    assert main(["synth", str(LOWER), "--frames", "40", "--noise", "0.02", "-o", str(d)]) == 0
    return d


def commands(masks: Path, out: Path) -> dict[str, list[str]]:
    return {
        "track": ["track", str(LOWER), "--masks", str(masks), "-o", str(out), "--no-progress"],
        "synth": ["synth", str(LOWER), "--frames", "2", "-o", str(out)],
        "segment": ["segment", str(masks / "cam0"), "-o", str(out), "--no-progress"],
        "export": ["export", str(LOWER), "-o", str(out)],
    }


@pytest.mark.parametrize("command", ["track", "synth", "segment", "export"])
def test_a_second_run_into_a_folder_a_live_run_writes_is_refused(holder, masks, command, capsys):
    out, proc = holder
    before = sorted(p.name for p in out.iterdir())
    assert main(commands(masks, out)[command]) == 1
    err = capsys.readouterr().err
    assert err.strip() == (f"{out}: kms2pin track, PID {proc.pid} is writing to this folder; wait for it to end or "
                           "choose another output folder")
    assert sorted(p.name for p in out.iterdir()) == before == [LOCK_NAME]
    assert (out / LOCK_NAME).read_text() == f"{proc.pid} track\n"


def test_a_lock_left_by_a_killed_run_is_taken_over_saying_so(holder, capsys):
    out, proc = holder
    (out / ".poses.x1y2z3.tmp.npz").write_bytes(b"half a file")  # what a killed run leaves
    proc.kill()
    proc.wait()
    assert (out / LOCK_NAME).read_text() == f"{proc.pid} track\n"  # SIGKILL: no clean-up ran
    assert main(["export", str(LOWER), "-o", str(out)]) == 0
    err = capsys.readouterr().err
    assert err.strip() == (f"note: {out}: taking over the lock of kms2pin track, PID {proc.pid}, which is no longer "
                           "running (its outputs there may be incomplete; removed its 1 temporary file(s))")
    assert sorted(p.name for p in out.iterdir()) == ["lowerBodyBipedal.srdf", "lowerBodyBipedal.urdf", "meshes"]


def test_a_run_that_fails_before_writing_leaves_no_folder(tmp_path, capsys):
    out = tmp_path / "a" / "b"
    assert main(["synth", str(LOWER), "--cameras", str(tmp_path / "missing.json"), "-o", str(out)]) == 2
    assert not (tmp_path / "a").exists()


@pytest.mark.parametrize("command", ["track", "synth", "segment", "export"])
def test_an_empty_output_path_is_refused_not_taken_for_the_current_folder(masks, tmp_path, monkeypatch, capsys,
                                                                          command):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "notes.txt").write_text("mine")
    argv = commands(masks, Path("PLACEHOLDER"))[command]
    assert main([a if a != "PLACEHOLDER" else "" for a in argv]) == 2
    assert "-o/--output: the output path is empty" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt"]  # nothing written, nothing removed


def test_track_does_not_replace_files_that_no_track_run_wrote(masks, tmp_path, capsys):
    """A folder holding a trajectory.csv and a smoothed.csv of the user's own (no meta.json of
    a track run): refused, both kept; with an earlier run's meta.json they are that run's,
    replaced with a note."""
    out = tmp_path / "out"
    out.mkdir()
    for name in ("trajectory.csv", "smoothed.csv"):
        (out / name).write_text("my own\n")
    argv = commands(masks, out)["track"] + ["--no-video"]
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert f"{out}: holds trajectory.csv, smoothed.csv but no meta.json of a kms2pin track run" in err, err
    assert all((out / n).read_text() == "my own\n" for n in ("trajectory.csv", "smoothed.csv"))
    assert not (out / "meta.json").exists()
    (out / "meta.json").write_text(json.dumps({"options": {}, "complete": True, "cameras": 1}))
    assert main(argv) == 0
    assert f"note: {out}: removed 2 file(s) of an earlier run" in capsys.readouterr().err
    assert not (out / "smoothed.csv").exists() and len((out / "trajectory.csv").read_text().splitlines()) == 41


def test_segment_into_its_input_folder_is_refused(masks, tmp_path, capsys):
    frames = tmp_path / "frames"
    shutil.copytree(masks / "cam0", frames)
    before = {p.name: p.read_bytes() for p in frames.iterdir()}
    assert main(["segment", str(frames), "-o", str(frames / "."), "--no-progress"]) == 2
    assert "is the input folder" in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in frames.iterdir()} == before


def test_the_lock_is_released_for_the_next_run_in_the_same_process(tmp_path):
    out = tmp_path / "out"
    with owned_output(out, "synth"):
        with pytest.raises(OutputError, match=rf"kms2pin synth, PID {os.getpid()} is writing to this folder"):
            with owned_output(out, "export"):
                pass
        (out / "kept").write_text("x")
    assert not (out / LOCK_NAME).exists()
    with owned_output(out, "export"):
        assert (out / LOCK_NAME).read_text() == f"{os.getpid()} export\n"


def test_replaced_keeps_the_old_file_when_the_writer_fails(tmp_path):
    path = tmp_path / "poses.npz"
    path.write_bytes(b"old")
    with pytest.raises(RuntimeError):
        with replaced(path) as tmp:
            assert tmp.parent == tmp_path and tmp.suffix == ".npz" and tmp.name.startswith(".poses.")
            tmp.write_bytes(b"half")
            raise RuntimeError("the writer died")
    assert path.read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["poses.npz"]
    with replaced(path) as tmp:
        np.savez(tmp, q=np.arange(3))  # np.savez keeps a name that ends in .npz as it is
    assert np.load(path)["q"].tolist() == [0, 1, 2]


@pytest.mark.slow
def test_two_tracks_into_one_folder_do_not_mix(masks, tmp_path):
    out = tmp_path / "out"
    first = kms2pin(*commands(masks, out)["track"])
    deadline = time.monotonic() + 60
    while not (out / "trajectory.csv").exists() and time.monotonic() < deadline:
        time.sleep(0.02)
    first.send_signal(signal.SIGSTOP)  # held mid-run, however fast it tracks
    try:
        second = kms2pin(*commands(masks, out)["track"])
        _, err2 = second.communicate(timeout=120)
    finally:
        first.send_signal(signal.SIGCONT)
    _, err1 = first.communicate(timeout=300)
    assert first.returncode == 0, err1
    assert second.returncode == 1 and f"PID {first.pid} is writing to this folder" in err2
    assert main(["evaluate", str(out), str(masks / "truth.csv")]) == 0


LONG = 400


@pytest.fixture(scope="module")
def long_masks(masks, tmp_path_factory) -> Path:
    """The 40 frames played forward and back to 400 (hard links): a run long enough that
    the signal always lands mid-run, however busy the machine is."""
    d = tmp_path_factory.mktemp("long_masks")
    shutil.copy(masks / "cameras.json", d)
    (d / "cam0").mkdir()
    cycle = list(range(40)) + list(range(38, 0, -1))
    for k in range(LONG):
        os.link(masks / "cam0" / f"frame_{cycle[k % len(cycle)]:05d}.png", d / "cam0" / f"frame_{k:05d}.png")
    return d


@pytest.mark.slow
@pytest.mark.parametrize("signum, status, said", [(signal.SIGTERM, 143, "terminated (SIGTERM)"),
                                                  (signal.SIGINT, 130, "interrupted")])
def test_sigterm_or_ctrl_c_during_track_leave_complete_outputs(long_masks, tmp_path, signum, status, said):
    out = tmp_path / "out"
    # a shell that runs the tests in the background hands its children SIGINT ignored,
    # which Python then keeps: give the run Ctrl-C's default, as a terminal does
    proc = kms2pin(*commands(long_masks, out)["track"], preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:  # wait for a few finished frames
        if (out / "trajectory.csv").exists() and len((out / "trajectory.csv").read_text().splitlines()) > 4:
            break
        time.sleep(0.02)
    proc.send_signal(signal.SIGSTOP)  # SIGTERM is delivered on SIGCONT, before the run can end
    proc.send_signal(signum)
    proc.send_signal(signal.SIGCONT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == status, err
    assert err.strip().endswith(f"kms2pin track: {said}")
    with open(out / "trajectory.csv") as f:
        rows = list(csv.DictReader(f))
    n = len(rows)
    assert 4 <= n < LONG
    assert f"interrupted after {n} frame(s)" in err
    meta = json.loads((out / "meta.json").read_text())
    assert meta["complete"] is False and meta["frames"] == LONG
    poses = np.load(out / "poses.npz")
    assert poses["q"].shape[0] == n
    np.testing.assert_allclose(np.degrees(poses["q"][:, 7]), [float(r["leftThigh_hip"]) for r in rows], atol=1e-6)
    assert len(video_frames(out / "overlay.mp4")) == n  # finalized: playable, one frame per tracked frame
    assert sorted(p.name for p in out.iterdir() if p.name.startswith(".")) == []  # no lock, no temporary file


def test_a_file_system_without_locks_is_written_with_a_note(tmp_path, monkeypatch, capsys):
    import errno
    import fcntl

    def no_locks(fd, op):
        raise OSError(errno.ENOLCK, os.strerror(errno.ENOLCK))

    monkeypatch.setattr(fcntl, "flock", no_locks)  # as on some network file systems
    assert main(["export", str(LOWER), "-o", str(tmp_path / "out")]) == 0
    assert capsys.readouterr().err.strip() == (f"note: {tmp_path / 'out'}: this file system does not lock files "
                                               f"({os.strerror(errno.ENOLCK)}); a second run into this folder will "
                                               "not be refused")
    assert not (tmp_path / "out" / LOCK_NAME).exists()
