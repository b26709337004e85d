"""The tracks beside in worker processes (``Tracker(..., jobs=N)``, ``track --jobs N``)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

from kms2pin.ecm.tracker import Tracker
from kms2pin.ecm.workers import FORK, RemoteTrack, usable_cores
from kms2pin.errors import InputDataError, OptionError

from ._tracking import DIR
from .test_second_track import WEAK, _scene

pytestmark = pytest.mark.skipif(not FORK, reason="no fork start method here: every track runs in one process")

#: three tracks beside a weak first one, each with its own changes
TRACKS = "max_iterations=2; max_iterations=8,min_iterations=3; max_iterations=3,limb_search=true"
CHANGES = ({"max_iterations": 2}, {"max_iterations": 8, "min_iterations": 3},
           {"max_iterations": 3, "limb_search": True})


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:  # a zombie (ended, not yet reaped) is not running
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return True


def _ended(pids: list[int], within_s: float = 10.0) -> bool:
    """Whether every process of ``pids`` has ended within ``within_s`` seconds."""
    deadline = time.monotonic() + within_s
    while any(_alive(p) for p in pids) and time.monotonic() < deadline:
        time.sleep(0.05)
    return not any(_alive(p) for p in pids)


def _pids(tracker: Tracker) -> list[int]:
    return [c.process.pid for c in tracker._beside._children]


@pytest.mark.parametrize("jobs", [2, 3, 4])
def test_tracks_in_several_processes_are_the_tracks_of_one_to_the_last_bit(jobs):
    """Each track beside, run in a child process, is the track a tracker of its own makes of
    the same frames (its pose after every frame, through a calibration, a frame with no
    mask and a restart), and each frame's result is the one-process tracker's."""
    robot, qs, cams, masks = _scene(8)
    masks.insert(3, [np.zeros_like(m) for m in masks[0]])
    alone = [Tracker(robot, cams, q0=qs[0], **{**WEAK, **c}) for c in CHANGES]
    one = Tracker(robot, cams, q0=qs[0], **WEAK, second_track=TRACKS)
    with Tracker(robot, cams, q0=qs[0], **WEAK, second_track=TRACKS, jobs=jobs) as many:
        assert many.jobs == jobs and one.jobs == 1 and len(_pids(many)) == jobs - 1
        here = [i for i in (1, 2, 3) if i % jobs == 0]  # track i runs in process i % jobs, 0 this one
        assert [isinstance(t, RemoteTrack) for t in many.tracks_beside] == [i not in here for i in (1, 2, 3)]
        for t in (*alone, one, many):
            t.calibrate(masks[0])
        for k, m in enumerate(masks):
            if k == 6:
                for t in (*alone, one, many):
                    t.restart(qs[5])
            for t in alone:
                t.step(m)
            a, b = one.step(m), many.step(m)
            np.testing.assert_array_equal(b.q, a.q)
            assert (b.fit, b.flags, b.iterations, b.converged) == (a.fit, a.flags, a.iterations, a.converged)
            for t, other, mine in zip(many.tracks_beside, alone, one.tracks_beside):
                np.testing.assert_array_equal(t.q, other.q)
                np.testing.assert_array_equal(t.q, mine.q)
        np.testing.assert_array_equal(many.scales, one.scales)
        pids = _pids(many)
    assert _ended(pids)


def test_the_processes_end_on_close_and_the_tracker_then_says_why_it_cannot_go_on():
    robot, qs, cams, masks = _scene(2)
    t = Tracker(robot, cams, q0=qs[0], **WEAK, second_track=TRACKS, jobs=2)
    pids = _pids(t)
    assert pids and all(_alive(p) for p in pids)
    t.step(masks[0])
    t.close()
    t.close()  # twice: nothing more to do
    assert _ended(pids)
    with pytest.raises(RuntimeError, match=r"processes were closed \(Tracker.close\)"):
        t.step(masks[1])
    # one process asked, or no track beside: nothing forked, close does nothing
    for tr in (Tracker(robot, cams, q0=qs[0], **WEAK, second_track=TRACKS),
               Tracker(robot, cams, q0=qs[0], **WEAK, jobs=4)):
        assert tr.jobs == 1 and not _pids(tr)
        tr.close()
        tr.step(masks[1])
    # more processes than tracks: one a track
    assert Tracker(robot, cams, q0=qs[0], **WEAK, second_track="max_iterations=2", jobs=8).jobs == 2


def test_a_user_mistake_in_the_masks_is_the_same_error_and_the_tracks_stay_in_step():
    robot, qs, cams, masks = _scene(4)
    one = Tracker(robot, cams, q0=qs[0], **WEAK, second_track=TRACKS)
    with Tracker(robot, cams, q0=qs[0], **WEAK, second_track=TRACKS, jobs=3) as many:
        bad = [masks[1][0][:-2], masks[1][1]]  # camera 0's mask two rows short
        for k, m in enumerate(masks):
            if k == 2:
                errors = []
                for t in (one, many):
                    with pytest.raises(InputDataError) as err:
                        t.step(bad, source="clip.avi: frame 2")
                    errors.append(str(err.value))
                assert errors[0] == errors[1] and "clip.avi: frame 2" in errors[0]
            a, b = one.step(m), many.step(m)
            np.testing.assert_array_equal(b.q, a.q)
            for t, mine in zip(many.tracks_beside, one.tracks_beside):
                np.testing.assert_array_equal(t.q, mine.q)


def test_a_process_that_dies_is_named_with_its_tracks_and_how_it_ended():
    robot, qs, cams, masks = _scene(2)
    with Tracker(robot, cams, q0=qs[0], **WEAK, second_track=TRACKS, jobs=2) as t:
        t.step(masks[0])
        (pid,) = _pids(t)
        os.kill(pid, signal.SIGKILL)
        with pytest.raises(ChildProcessError, match=rf"tracks the second track, the fourth track \(pid {pid}\) "
                                                    r"was killed by signal 9: .*--jobs 1"):
            t.step(masks[1])


def test_the_processes_ignore_ctrl_c_and_end_with_a_parent_that_ends_without_closing_them(tmp_path):
    """Ctrl-C reaches every process of the terminal's group: the children leave it to the
    parent.  A parent killed (no close, no exit handlers) leaves no child behind."""
    robot, qs, cams, masks = _scene(2)
    with Tracker(robot, cams, q0=qs[0], **WEAK, second_track=TRACKS, jobs=2) as t:
        os.kill(_pids(t)[0], signal.SIGINT)
        time.sleep(0.2)
        t.step(masks[0])
        assert all(_alive(p) for p in _pids(t))
    script = tmp_path / "orphan.py"
    script.write_text(textwrap.dedent(f"""
        import json, os
        from kms2pin.ecm.camera import Camera
        from kms2pin.ecm.tracker import Tracker
        from kms2pin.robot import load
        robot = load({str(DIR / "lowerbody.kms")!r}, root="free")
        cams = [Camera.look_at(position=robot.q_rest[:3] + [0.0, 0.5, 6.0], target=robot.q_rest[:3], width=80,
                               height=60)]
        t = Tracker(robot, cams, second_track="max_iterations=4; max_iterations=5", jobs=3)
        print(json.dumps([c.process.pid for c in t._beside._children]), flush=True)
        os._exit(0)
    """))
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    pids = json.loads(out.stdout)
    assert len(pids) == 2
    assert _ended(pids, 15)


@pytest.mark.parametrize("jobs", [0, -1, 1.5, True, "2"])
def test_jobs_must_be_a_whole_number_of_processes(jobs):
    robot, qs, cams, _ = _scene(1)
    with pytest.raises(OptionError, match="jobs must be a whole number of processes, at least 1"):
        Tracker(robot, cams, q0=qs[0], **WEAK, second_track="max_iterations=2", jobs=jobs)


def test_usable_cores_are_the_affinity():
    assert usable_cores() == len(os.sched_getaffinity(0)) >= 1


def test_a_child_ended_by_sigterm_ends_quietly_and_the_tracker_says_it_cannot_go_on(capfd):
    robot, qs, cams, masks = _scene(3)
    with Tracker(robot, cams, q0=qs[0], **WEAK, second_track=TRACKS, jobs=2) as t:
        t.step(masks[0])
        (pid,) = _pids(t)
        os.kill(pid, signal.SIGTERM)
        with pytest.raises(ChildProcessError, match=r"was killed by signal 15"):
            t.step(masks[1])
        with pytest.raises(RuntimeError, match="left out of step by ChildProcessError"):
            t.step(masks[2])
        with pytest.raises(RuntimeError, match="left out of step"):
            t.restart(qs[0])
    assert "Traceback" not in capfd.readouterr().err


class _Interrupted:
    """A child's pipe end whose next answer is interrupted (Ctrl-C while waiting for it)."""

    def __init__(self, conn):
        self.conn = conn

    def __getattr__(self, name):
        return getattr(self.conn, name)

    def recv(self):
        raise KeyboardInterrupt


def test_an_interrupt_while_waiting_for_the_children_ends_them_rather_than_leave_them_a_frame_behind():
    robot, qs, cams, masks = _scene(3)
    one = Tracker(robot, cams, q0=qs[0], **WEAK, second_track=TRACKS)
    with Tracker(robot, cams, q0=qs[0], **WEAK, second_track=TRACKS, jobs=3) as t:
        np.testing.assert_array_equal(t.step(masks[0]).q, one.step(masks[0]).q)
        pids = _pids(t)
        child = t._beside._children[0]
        child.conn = _Interrupted(child.conn)
        with pytest.raises(KeyboardInterrupt):
            t.step(masks[1])
        with pytest.raises(RuntimeError, match="left out of step by KeyboardInterrupt"):
            t.step(masks[2])
    assert _ended(pids)
