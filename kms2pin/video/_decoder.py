"""The video decoder that runs in a child process (started by :mod:`kms2pin.video.io`).

A damaged or unusual video can crash OpenCV's FFmpeg backend (an uncompressed,
bottom-up 24-bit "DIB " AVI aborts it with a corrupted heap), and a crash in the
process that decodes takes that process down.  So the decoding runs here, in a
child process that only imports the standard library, NumPy and OpenCV, and the
frames come back over a pipe; a crash ends the child, not the command.

Uncompressed AVIs (``BI_RGB``, 24 or 32 bits per pixel) are not decoded by FFmpeg
at all: their packets are read raw (``CAP_PROP_FORMAT = -1``) and unpacked here
(rows padded to 4 bytes, bottom-up when the height is positive, BGR(X)).

Output on stdout: one JSON line ``{"ok": true, "frames", "fps", "width",
"height", "raw"}`` (or ``{"ok": false, "error"}``), then per frame a 16-byte header
``<IIII`` (rows, cols, channels, 0) and the ``uint8`` pixels, and an end record:
``(0, 0, 0, 0)``, or ``(0, 0, 0, 1)`` followed by one JSON line ``{"error"}``.
``probe`` mode stops after the first frame.
"""

from __future__ import annotations

import json
import signal
import struct
import sys

RECORD = struct.Struct("<IIII")
BI_RGB = 0
DIB = int.from_bytes(b"DIB ", "little")


def _chunks(data: bytes, start: int, end: int):
    """(fourcc, payload start, payload size, list type or None) of the RIFF chunks in data[start:end]."""
    pos = start
    while pos + 8 <= min(end, len(data)):
        fcc, size = data[pos : pos + 4], struct.unpack_from("<I", data, pos + 4)[0]
        kind = data[pos + 8 : pos + 12] if fcc in (b"LIST", b"RIFF") else None
        yield fcc, pos + 8, size, kind
        pos += 8 + size + (size & 1)


def raw_avi_format(path: str) -> tuple[int, int, int] | None:
    """(width, height as stored - positive for bottom-up rows -, bits per pixel) of the
    first video stream of an uncompressed (BI_RGB, 24 or 32 bits) AVI, else None."""
    try:
        with open(path, "rb") as f:
            data = f.read(1 << 20)
    except OSError:
        return None
    if data[:4] != b"RIFF" or data[8:12] != b"AVI ":
        return None
    for fcc, at, size, kind in _chunks(data, 12, len(data)):
        if fcc != b"LIST" or kind != b"hdrl":
            continue
        for fcc2, at2, size2, kind2 in _chunks(data, at + 4, at + size):
            if fcc2 != b"LIST" or kind2 != b"strl":
                continue
            strh = strf = None
            for fcc3, at3, size3, _ in _chunks(data, at2 + 4, at2 + size2):
                if fcc3 == b"strh" and size3 >= 8:
                    strh = data[at3 : at3 + size3]
                elif fcc3 == b"strf" and size3 >= 40:
                    strf = data[at3 : at3 + size3]
            if strh is None or strh[:4] != b"vids":
                continue
            if strf is None or len(strf) < 40:
                return None
            _, width, height, _, bits, compression = struct.unpack_from("<IiiHHI", strf)
            if compression in (BI_RGB, DIB) and bits in (24, 32) and width > 0 and height != 0:
                return width, height, bits
            return None
    return None


def _unpack_dib(packet, width: int, height: int, bits: int):
    """The BGR image in a raw DIB packet, or None if the packet is too short."""
    import numpy as np

    channels = bits // 8
    stride = (width * channels + 3) & ~3
    rows = abs(height)
    buf = np.asarray(packet, dtype=np.uint8).ravel()
    if buf.size < stride * rows:
        return None
    img = buf[: stride * rows].reshape(rows, stride)[:, : width * channels].reshape(rows, width, channels)
    if height > 0:
        img = img[::-1]
    return np.ascontiguousarray(img[:, :, :3])


def _emit_header(out, info: dict) -> None:
    out.write((json.dumps(info) + "\n").encode())
    out.flush()


def _emit_end(out, error: str | None = None) -> None:
    out.write(RECORD.pack(0, 0, 0, 1 if error else 0))
    if error:
        out.write((json.dumps({"error": error}) + "\n").encode())
    out.flush()


def main(argv: list[str]) -> int:
    """``MODE PATH``: MODE ``probe`` (header and first frame) or ``frames`` (every frame)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent stops this process itself
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    mode, path = argv
    out = sys.stdout.buffer
    import cv2
    import numpy as np

    raw = raw_avi_format(path)
    cap = cv2.VideoCapture(path)
    if not cap.isOpened():
        _emit_header(out, {"ok": False, "error": "cannot open as a video (unknown format, unsupported codec "
                                                 "or truncated file)"})
        return 0
    if raw is not None:
        cap.set(cv2.CAP_PROP_FORMAT, -1)
    _emit_header(out, {"ok": True, "frames": int(cap.get(cv2.CAP_PROP_FRAME_COUNT)),
                       "fps": float(cap.get(cv2.CAP_PROP_FPS)), "raw": raw is not None,
                       "width": raw[0] if raw else int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)),
                       "height": abs(raw[1]) if raw else int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))})
    previous = None
    while True:
        ok, img = cap.read()
        if not ok or img is None:
            break
        if raw is not None:
            if img.size == 0 and previous is not None:  # an empty AVI chunk repeats the previous frame
                img = previous
            else:
                unpacked = _unpack_dib(img, *raw)
                if unpacked is None:
                    _emit_end(out, f"a frame holds {img.size} bytes, too few for {raw[0]}x{abs(raw[1])} "
                                   f"pixels of {raw[2]} bits")
                    return 0
                img = unpacked
        if img.ndim == 2:
            img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
        img = np.ascontiguousarray(img, dtype=np.uint8)
        previous = img
        out.write(RECORD.pack(img.shape[0], img.shape[1], img.shape[2], 0))
        out.write(memoryview(img).cast("B"))
        if mode == "probe":
            break
    cap.release()
    _emit_end(out)
    return 0
