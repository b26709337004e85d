"""Video decoding cannot take the process down (kms2pin/video/_decoder.py, io.py).

An uncompressed bottom-up 24-bit ("DIB ") AVI crashes OpenCV's FFmpeg backend
(SIGABRT, "malloc_consolidate(): invalid chunk size") in its first ``read()``.  The
AVIs here are written byte by byte from the RIFF/AVI and BITMAPINFOHEADER layouts
(rows padded to 4 bytes, bottom-up for a positive height), so what kms2pin decodes
is checked against the pixels that went in.  A decoder that crashes, or hangs, is
stood in for by a small script in its place.
"""

from __future__ import annotations

import struct
import textwrap
import types

import cv2
import numpy as np
import pytest

from kms2pin.cli import main
from kms2pin.errors import InputDataError
from kms2pin.video import io as video_io
from kms2pin.video import read_frames
from kms2pin.video._decoder import RECORD


def _chunk(fourcc: bytes, data: bytes) -> bytes:
    return fourcc + struct.pack("<I", len(data)) + data + (b"\0" if len(data) % 2 else b"")


def dib_avi(frames: np.ndarray, bits: int = 24, bottom_up: bool = True) -> bytes:
    """An uncompressed AVI (one 'vids' stream, handler 'DIB ', BI_RGB) of ``frames``
    (N, H, W, bits/8) uint8 BGR(X), with an idx1 index."""
    n, h, w = frames.shape[:3]
    row = (w * bits // 8 + 3) & ~3
    size = row * h
    avih = struct.pack("<14I", 40000, size * 25, 0, 0x10, n, 0, 1, size, w, h, 0, 0, 0, 0)
    strh = b"vids" + b"DIB " + struct.pack("<IHHIIIIIIIIhhhh", 0, 0, 0, 0, 1, 25, 0, n, size, 0xFFFFFFFF, 0,
                                           0, 0, w, h)
    strf = struct.pack("<IiiHHIIiiII", 40, w, h if bottom_up else -h, 1, bits, 0, size, 0, 0, 0, 0)
    strl = _chunk(b"LIST", b"strl" + _chunk(b"strh", strh) + _chunk(b"strf", strf))
    hdrl = _chunk(b"LIST", b"hdrl" + _chunk(b"avih", avih) + strl)
    movi, idx = b"", b""
    for f in frames:
        rows = b"".join(r.tobytes().ljust(row, b"\0") for r in (f[::-1] if bottom_up else f))
        idx += b"00db" + struct.pack("<III", 0x10, 4 + len(movi), len(rows))
        movi += _chunk(b"00db", rows)
    body = b"AVI " + hdrl + _chunk(b"LIST", b"movi" + movi) + _chunk(b"idx1", idx)
    return b"RIFF" + struct.pack("<I", len(body)) + body


def moving_square(n: int, h: int, w: int, channels: int = 3) -> np.ndarray:
    """A textured background with a bright square crossing it (BGR(X) uint8)."""
    rng = np.random.default_rng(0)
    background = rng.integers(20, 90, (h, w, channels), dtype=np.uint8)
    frames = np.repeat(background[None], n, axis=0)
    for k in range(n):
        x = 2 + (k * (w - 16)) // max(n - 1, 1)
        frames[k, h // 3 : h // 3 + 12, x : x + 12] = 230
    return frames


@pytest.mark.parametrize("width, height, bits, bottom_up", [
    (48, 48, 24, True),  # the crashing kind
    (47, 31, 24, True),  # rows padded from 141 to 144 bytes
    (47, 31, 24, False),
    (33, 17, 32, True),
])
def test_uncompressed_avis_are_read_pixel_for_pixel(tmp_path, width, height, bits, bottom_up):
    frames = moving_square(6, height, width, bits // 8)
    path = tmp_path / "raw.avi"
    path.write_bytes(dib_avi(frames, bits, bottom_up))
    got = [img for _, img in read_frames(path)]
    assert len(got) == len(frames)
    for img, f in zip(got, frames):
        np.testing.assert_array_equal(img, f[:, :, :3])


@pytest.fixture
def dib_video(tmp_path):
    path = tmp_path / "demo.avi"
    path.write_bytes(dib_avi(moving_square(40, 48, 48)))
    return path


def test_segment_on_a_dib_avi_segments_the_square(dib_video, tmp_path, capsys):
    out = tmp_path / "masks"
    assert main(["segment", str(dib_video), "-o", str(out), "--no-progress", "--learn-frames", "20"]) == 0
    masks = sorted(out.glob("frame_*.png"))
    assert len(masks) == 40
    truth = moving_square(40, 48, 48)[..., 0] == 230
    ious = []
    for m, t in zip(masks, truth):
        got = cv2.imread(str(m), cv2.IMREAD_GRAYSCALE) > 0
        ious.append((got & t).sum() / max((got | t).sum(), 1))
    assert np.median(ious) > 0.8, ious


def test_track_video_on_a_dib_avi_runs_to_the_end(dib_video, tmp_path, capsys):
    from conftest import SPECS

    cam = tmp_path / "cam.json"
    assert main(["camera", "make", "--width", "48", "--height", "48", "--fov", "40", "-o", str(cam)]) == 0
    out = tmp_path / "track"
    code = main(["track", str(SPECS / "lowerbody.kms"), "--video", str(dib_video), "--camera", str(cam),
                 "-o", str(out), "--no-progress", "--no-video"])
    err = capsys.readouterr().err
    assert code == 0, err
    assert len((out / "trajectory.csv").read_text().splitlines()) == 41
    masks = sorted((out / "masks" / "cam0").glob("frame_*.png"))
    assert len(masks) == 40
    truth = moving_square(40, 48, 48)[..., 0] == 230  # the masks it tracked are the square's
    ious = [((m := cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) > 0) & t).sum() / max((m | t).sum(), 1)
            for p, t in zip(masks, truth)]
    assert np.median(ious) > 0.8, ious
    from kms2pin import load
    from kms2pin.ecm import Trajectory

    traj = Trajectory.from_csv(load(SPECS / "lowerbody.kms", root="free"), out / "trajectory.csv")
    assert len(traj) == 40 and np.isfinite(traj.q).all()


# ----------------------------------------------------------------------------- decoders that crash or hang


def fake_decoder(tmp_path, monkeypatch, body: str) -> None:
    """Put a script whose ``main`` is ``body`` in the real decoder's place."""
    script = tmp_path / "fake_decoder.py"
    script.write_text(textwrap.dedent("""
        import json, os, struct, sys, time
        RECORD = struct.Struct("<IIII")

        def header(out):
            out.write(b'{"ok": true, "frames": 10, "fps": 25.0, "raw": false, "width": 8, "height": 6}\\n')
            out.flush()

        def frame(out, value):
            out.write(RECORD.pack(6, 8, 3, 0) + bytes([value]) * 144)
            out.flush()

        def main(argv):
            mode, path = argv
            out = sys.stdout.buffer
    """) + textwrap.indent(textwrap.dedent(body), "    "))
    monkeypatch.setattr(video_io, "_decoder", types.SimpleNamespace(__file__=str(script), RECORD=RECORD))


def test_a_decoder_crash_on_the_first_frame_is_a_located_error(tmp_path, monkeypatch, capsys):
    fake_decoder(tmp_path, monkeypatch, "header(out)\nos.abort()\n")
    video = tmp_path / "bad.avi"
    video.write_bytes(b"RIFF")
    code = main(["segment", str(video), "-o", str(tmp_path / "m"), "--no-progress"])
    err = capsys.readouterr().err
    assert code == 1
    assert err.startswith(f"{video}: frame 0: the video decoder (OpenCV/FFmpeg) crashed (SIGABRT); the file is "
                          "damaged or in a form the decoder cannot read")
    assert len(err.strip().splitlines()) == 1
    assert not (tmp_path / "m").exists()


def test_a_decoder_crash_later_keeps_the_frames_before_it(tmp_path, monkeypatch, capsys):
    fake_decoder(tmp_path, monkeypatch, """
        header(out)
        for k in range(1 if mode == "probe" else 4):
            frame(out, 10 * k)
        if mode == "probe":
            out.write(RECORD.pack(0, 0, 0, 0))
            return 0
        os.kill(os.getpid(), 11)
    """)
    video = tmp_path / "bad.avi"
    video.write_bytes(b"RIFF")
    src = video_io.open_frames(video)
    assert src.frame_size == (8, 6) and src.len_hint == 10
    frames = [img for _, img in src]
    assert [int(f[0, 0, 0]) for f in frames] == [0, 10, 20, 30]
    assert src.stopped_early == (f"{video}: stopped at frame 4 (frames 0-3 read): the video decoder "
                                 "(OpenCV/FFmpeg) crashed (SIGSEGV)")


def test_a_decoder_that_hangs_is_stopped(tmp_path, monkeypatch):
    fake_decoder(tmp_path, monkeypatch, "header(out)\ntime.sleep(600)\n")
    monkeypatch.setattr(video_io, "STALL_TIMEOUT", 0.5)
    video = tmp_path / "slow.avi"
    video.write_bytes(b"RIFF")
    with pytest.raises(InputDataError, match=r"slow.avi: frame 0: the video decoder stopped responding for 0.5 s"):
        video_io.open_frames(video)


def test_frames_larger_than_8192_pixels_are_refused_before_decoding(tmp_path, capsys):
    path = tmp_path / "wide.avi"
    path.write_bytes(dib_avi(np.zeros((2, 1, 8200, 3), np.uint8)))
    code = main(["segment", str(path), "-o", str(tmp_path / "m"), "--no-progress"])
    assert code == 1
    assert capsys.readouterr().err.strip() == (f"{path}: the video's frame is 8200x1 pixels; at most 8192 pixels "
                                               "a side are supported (scale it down first)")


def test_a_fifo_as_the_video_is_refused_at_once(tmp_path, capsys):
    fifo = tmp_path / "video.avi"
    import os

    os.mkfifo(fifo)
    assert main(["segment", str(fifo), "-o", str(tmp_path / "m"), "--no-progress"]) == 1
    assert capsys.readouterr().err.strip() == (f"{fifo}: not a regular file (a video must be a file or a folder "
                                               "of images)")
