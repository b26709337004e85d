"""Reading BVH files: what a well-formed file holds, and every kind of broken file refused
with its file:line:col, the line and a caret, before anything is written."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from kms2pin.bvh import parse_bvh, read_bvh
from kms2pin.cli import main
from kms2pin.errors import BvhError

GOOD = """HIERARCHY
ROOT Hips
{
\tOFFSET 0 0 0
\tCHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
\tJOINT Left Thigh
\t{
\t\tOFFSET 1 -1 0
\t\tCHANNELS 3 Zrotation Xrotation Yrotation
\t\tEnd Site
\t\t{
\t\t\tOFFSET 0 -4 0
\t\t}
\t}
\tJOINT Spine
\t{
\t\tOFFSET 0 1 0
\t\tCHANNELS 1 Xrotation
\t\tEnd Site { OFFSET 0 3 0 }
\t}
}
MOTION
Frames: 3
Frame Time: 0.04
0 9 0 1 2 3 4 5 6 7
0.5 9 0 1 2 3 4 5 6 -7
1 9 0 1 2 3 4 5 6 8
"""


def test_a_well_formed_file_is_read_joint_by_joint():
    bvh = parse_bvh(GOOD, "good.bvh")
    assert [j.name for j in bvh.joints] == ["Hips", "Left Thigh", "Spine"]
    assert [j.parent for j in bvh.joints] == [None, 0, 0]
    assert [j.rotation_order for j in bvh.joints] == ["ZYX", "ZXY", "X"]
    assert [j.first for j in bvh.joints] == [0, 6, 9]
    assert bvh.joints[1].end_sites == ((0.0, -4.0, 0.0),) and bvh.joints[2].end_sites == ((0.0, 3.0, 0.0),)
    assert bvh.frame_time == 0.04 and bvh.motion.shape == (3, 10)
    np.testing.assert_array_equal(bvh.channels(bvh.joints[2])[:, 0], [7, -7, 8])


def _replace(old: str, new: str, count: int = 1) -> str:
    assert old in GOOD
    return GOOD.replace(old, new, count)


# (the file's text, line, column, message): a mistake of each kind
BROKEN = [
    (GOOD.replace("1 9 0 1 2 3 4 5 6 8\n", ""), 26, 1,
     "the motion ends after 2 of the 3 frames that 'Frames:' (line 23) declares: the file is truncated"),
    (_replace("0.5 9 0 1 2 3 4 5 6 -7", "0.5 9 0 1 2 3 4 5 6"), 26, 1,
     "frame 1 has 9 values, but the hierarchy's joints have 10 channels"),
    (_replace("0.5 9 0 1 2 3 4 5 6 -7", "0.5 9 0 1 2 3 4 5 6 -7 8"), 26, 1,
     "frame 1 has 11 values, but the hierarchy's joints have 10 channels"),
    (_replace("0.5 9 0 1 2 3", "0.5 9 0 1 2 x3"), 26, 13,
     "frame 1, channel 6 (Hips Xrotation): 'x3' is not a finite number"),
    (_replace("1 9 0 1 2 3 4 5 6 8", "1 9 0 1 2 3 4 5 nan 8"), 27, 17,
     "frame 2, channel 9 (Left Thigh Yrotation): 'nan' is not a finite number"),
    (GOOD.replace("MOTION", "ROOT Other\n{\n\tOFFSET 0 0 0\n\tCHANNELS 0\n}\nMOTION"), 22, 1,
     "a second ROOT: this file holds 2 skeletons (ROOT at lines 2, 22); kms2pin imports one, so split the file"),
    (_replace("CHANNELS 3 Zrotation Xrotation Yrotation", "CHANNELS 3 Zrotation Xrotation"), 10, 3,
     "CHANNELS 3 lists 2 channel(s) before 'End'"),
    (_replace("CHANNELS 3 Zrotation Xrotation Yrotation", "CHANNELS 3 Zrotation Xrot Yrotation"), 9, 24,
     "'Xrot' is not a channel (did you mean 'Xrotation'?); the channels are Xposition, Yposition, Zposition, "
     "Xrotation, Yrotation, Zrotation"),
    (_replace("CHANNELS 3 Zrotation Xrotation Yrotation", "CHANNELS 3 Zrotation Xrotation Xrotation"), 9, 34,
     "channel Xrotation is listed twice"),
    (_replace("CHANNELS 1 Xrotation", "CHANNELS 7 Xrotation"), 18, 12,
     "CHANNELS takes a channel count from 0 to 6, found '7'"),
    (_replace("\t\tOFFSET 1 -1 0\n", ""), 6, 1, "joint 'Left Thigh' has no OFFSET"),
    (_replace("\t\tCHANNELS 1 Xrotation\n", ""), 15, 1,
     "joint 'Spine' has no CHANNELS line (CHANNELS 0 for a joint that does not move)"),
    (_replace("OFFSET 1 -1 0", "OFFSET 1 -1 zero"), 8, 15, "expected a number (z of OFFSET), found 'zero'"),
    (_replace("JOINT Spine", "JOINT Left Thigh"), 15, 2, "a second joint named 'Left Thigh' (the first is at line 6)"),
    (_replace("Frames: 3", "Frames: three"), 23, 1, "expected 'Frames: N' (a whole number of frames)"),
    (_replace("Frames: 3\nFrame Time: 0.04\n0 9 0 1 2 3 4 5 6 7\n0.5 9 0 1 2 3 4 5 6 -7\n1 9 0 1 2 3 4 5 6 8\n",
              "Frames: 0\nFrame Time: 0.04\n"), 23, 1,
     "'Frames: 0': the file holds no motion (at least one frame is needed)"),
    (_replace("OFFSET 1 -1 0", "OFFSET 1e300 -1 0"), 8, 10,
     "expected a number (x of OFFSET), found '1e300', beyond +-1e+06, the largest value kms2pin takes (file units)"),
    (_replace("0.5 9 0 1", "0.5 -2e6 0 1"), 26, 5,
     "frame 1, channel 2 (Hips Yposition): '-2e6' is beyond +-1e+06, the largest value kms2pin takes"),
    (_replace("Frame Time: 0.04", "Frame Time: 0"), 24, 1,
     "expected 'Frame Time: T' (seconds a frame, a number above 0)"),
    (GOOD.split("MOTION")[0], 21, 1, "no MOTION section after the hierarchy"),
    (GOOD.split("\tJOINT Spine")[0], 14, 1, "expected OFFSET, CHANNELS, JOINT, End Site or '}', but the hierarchy "
                                             "ends at the end of the file"),
    (GOOD.replace("}\nMOTION", "MOTION"), 21, 1, "expected OFFSET, CHANNELS, JOINT, End Site or '}', but the "
                                                  "hierarchy ends before MOTION"),
    (GOOD + "1 2 3 4 5 6 7 8 9 10\n", 28, 1, "more frame lines than the 3 that 'Frames:' (line 23) declares"),
    ("", 1, 1, "expected HIERARCHY, but the hierarchy ends at the end of the file"),
    ("\x89PNG\r\n\x1a\n\x00\x00", 1, 1, "expected HIERARCHY at the start of a BVH file, found '\x89PNG'"),
]


@pytest.mark.parametrize(("text", "line", "column", "message"), BROKEN)
def test_a_broken_file_is_refused_with_its_line_and_column(tmp_path, capsys, text, line, column, message):
    path = tmp_path / "broken.bvh"
    path.write_text(text, encoding="latin-1")
    out = tmp_path / "out"
    assert main(["import", str(path), "-o", str(out)]) == 1
    err = capsys.readouterr().err
    first, source, caret = (err.splitlines() + ["", ""])[:3]
    # control characters reach the terminal as pictures of themselves (C1 ones as U+FFFD)
    harmless = {c: 0x2400 + c for c in range(32)} | {0x7F: 0x2421} | {c: 0xFFFD for c in range(0x80, 0xA0)}
    assert first == f"{path}:{line}:{column}: error: {message}".translate(harmless)
    shown = (text.splitlines() or [""])[line - 1]
    if shown:  # the line, then a caret under the column
        assert source == "    " + shown.expandtabs(4).translate(harmless)
        assert caret == "    " + " " * len(shown[: column - 1].expandtabs(4)) + "^"
    assert "Traceback" not in err
    assert not out.exists()


def test_a_joint_below_the_root_whose_position_channels_vary_is_refused_at_its_channels(tmp_path, capsys):
    text = _replace("CHANNELS 1 Xrotation", "CHANNELS 2 Xrotation Yposition").replace(
        "\n0 9 0 1 2 3 4 5 6 7\n", "\n0 9 0 1 2 3 4 5 6 7 1\n").replace(
        "5 6 -7\n", "5 6 -7 1\n").replace("5 6 8\n", "5 6 8 1.5\n")
    path = tmp_path / "slides.bvh"
    path.write_text(text)
    assert main(["import", str(path), "-o", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"{path}:18:1: error: joint 'Spine' moves: its position channels vary by up to 0.5 m "
                          "over the motion; kms2pin models the joints below the root as rotations about a point")
    assert not (tmp_path / "out").exists()


def test_missing_and_unreadable_files_are_usage_errors(tmp_path, capsys):
    assert main(["import", str(tmp_path / "nope.bvh"), "-o", str(tmp_path / "out")]) == 2
    assert "nope.bvh: no such file" in capsys.readouterr().err
    assert main(["import", str(tmp_path), "-o", str(tmp_path / "out")]) == 2
    assert "is a directory" in capsys.readouterr().err
    with pytest.raises(SystemExit) as stop:
        main(["import", str(tmp_path / "x.bvh"), "--scale", "0", "-o", str(tmp_path / "out")])
    assert stop.value.code == 2
    assert "--scale: expected a number > 0, got '0'" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_read_bvh_reads_a_latin_1_name(tmp_path):
    path = Path(tmp_path / "latin.bvh")
    path.write_bytes(GOOD.replace("Left Thigh", "Cuisse gauche \xe9").encode("latin-1"))
    assert read_bvh(path).joints[1].name == "Cuisse gauche \xe9"
    with pytest.raises(BvhError):
        parse_bvh("HIERARCHY\nJOINT x\n", "x.bvh")
