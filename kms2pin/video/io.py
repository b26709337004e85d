"""Reading frames from a video file or a folder of images, and writing masks.

:func:`open_frames` gives a :class:`FrameSource`: iterate it for ``(index, image)``
pairs (BGR ``uint8`` ``(H, W, 3)``, index from 0).  After the iteration,
:attr:`FrameSource.stopped_early` tells whether a video ended before the frame
count in its header (a truncated or corrupt file); the frames read up to that
point are good.  :func:`read_frames` is the same as a plain iterator that
warns (:class:`TruncatedVideoWarning`) instead.

A folder is read in natural name order (``frame_2.png`` before ``frame_10.png``;
zero-padded names sort the same either way); every image must have the size of
the first one.

A video is decoded in a child process (:mod:`kms2pin.video._decoder`), so a file
that crashes the decoder ends that process with a located error instead of this
one: :class:`FrameSource` first probes the file (its header and first frame), then
each iteration streams the frames from a new child.  Images and frames larger than
:data:`~kms2pin.userfile.MAX_IMAGE_SIDE` pixels a side are refused before they are
decoded where the header tells their size (videos, and images in the formats
Pillow identifies), after decoding otherwise.
"""

from __future__ import annotations

import fcntl
import io
import json
import os
import re
import select
import signal
import subprocess
import sys
import tempfile
import warnings
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from .._child import helper_command
from ..errors import InputDataError
from ..userfile import MAX_IMAGE_SIDE, read_user_file
from . import _decoder

#: the fewest pixels a side of a frame (OpenCV's background models fail on a single row or column)
MIN_IMAGE_SIDE = 2

IMAGE_EXTENSIONS = frozenset(
    {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp", ".ppm", ".pgm", ".pbm", ".pnm", ".jp2", ".exr", ".hdr"}
)
MASK_NAME = "frame_{:05d}.png"
_DIGITS = re.compile(r"(\d+)")


class TruncatedVideoWarning(UserWarning):
    """A video ended before the frame count its header announces."""


def natural_key(name: str) -> list:
    """Sort key comparing digit runs as numbers: ``a2 < a10``."""
    return [int(s) if s.isdigit() else s.lower() for s in _DIGITS.split(name)]


def list_images(folder: str | os.PathLike) -> list[Path]:
    """Image files of ``folder`` (by extension, not recursive) in natural name order."""
    folder = Path(folder)
    files = [p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS]
    return sorted(files, key=lambda p: natural_key(p.name))


MAX_IMAGE_BYTES = 512 * 2**20  # an image file: 512 MiB (8192 x 8192 pixels of 16-bit RGBA, uncompressed)


def _too_large(where: Path | str, width: int, height: int, what: str = "image") -> InputDataError:
    return InputDataError(f"{where}: the {what} is {width}x{height} pixels; at most {MAX_IMAGE_SIDE} pixels a side "
                          "are supported (scale it down first)")


def _header_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) from an image file's header, without decoding it (None if unknown)."""
    if data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR":
        return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    try:
        from PIL import Image
    except ImportError:  # pragma: no cover - Pillow comes with matplotlib
        return None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # Pillow's DecompressionBombWarning: we check the size ourselves
            with Image.open(io.BytesIO(data)) as im:
                return im.size
    except Exception:  # noqa: BLE001 - a format Pillow does not know: OpenCV decodes it below
        return None


def _quietly_decoded(data: bytes, flags: int) -> np.ndarray | None:
    """``cv2.imdecode`` without OpenCV's own warnings on stderr (a truncated PNG's "input
    buffer is incomplete"): the caller reports a bad image itself, with its file and frame."""
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(min(level, cv2.utils.logging.LOG_LEVEL_ERROR))
    try:
        return cv2.imdecode(np.frombuffer(data, dtype=np.uint8), flags)
    finally:
        cv2.utils.logging.setLogLevel(level)


def decode_image(path: str | os.PathLike, flags: int = cv2.IMREAD_UNCHANGED, where: str | None = None) -> np.ndarray:
    """``cv2.imdecode`` of the file ``path`` (a regular file; at most
    :data:`~kms2pin.userfile.MAX_IMAGE_SIDE` pixels a side, checked from the header
    before decoding where it tells).  A missing file raises FileNotFoundError, an
    unreadable, undecodable or too large one InputDataError starting with ``where``
    (default: the path)."""
    path = Path(path)
    where = str(path) if where is None else where
    if not path.exists():
        raise FileNotFoundError(2, "no such file", str(path))
    try:
        data = read_user_file(path, MAX_IMAGE_BYTES)
    except OSError as e:
        raise InputDataError(f"{where}: cannot read image: {e.strerror or e}") from None
    size = _header_size(data)
    if size is not None and max(size) > MAX_IMAGE_SIDE:
        raise _too_large(where, *size)
    img = _quietly_decoded(data, flags) if data else None
    if img is None:
        raise InputDataError(f"{where}: not a readable image (empty, truncated or unknown format)")
    if max(img.shape[:2]) > MAX_IMAGE_SIDE:
        raise _too_large(where, img.shape[1], img.shape[0])
    return img


def read_image(path: str | os.PathLike, flags: int = cv2.IMREAD_COLOR) -> np.ndarray:
    """Read one image as 8 bits (see :func:`decode_image` for the errors)."""
    img = decode_image(path, flags)
    if img.dtype != np.uint8:  # 16-bit PNG/TIFF, float EXR: scale to 8 bits
        img = cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    return img


# ---------------------------------------------------------------- videos, decoded in a child process

STALL_TIMEOUT = 120.0  # seconds without a byte from the decoder: it is taken to hang


class _DecoderStopped(Exception):
    """The decoder process ended without its end record (a crash) or reported an error."""


class _Decoder:
    """One child process running :mod:`kms2pin.video._decoder` on a video (``mode``
    ``probe`` or ``frames``): ``info`` is its header; :meth:`frames` yields images."""

    def __init__(self, path: Path, mode: str):
        self.path = path
        cmd = helper_command(_decoder.__file__, mode, os.fspath(path))
        self.proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                     stderr=subprocess.DEVNULL, bufsize=0)
        try:  # a frame in one pipe buffer, not 64 KiB at a time (Linux; 1 MiB is the default maximum)
            fcntl.fcntl(self.proc.stdout, getattr(fcntl, "F_SETPIPE_SZ", 1031), 1 << 20)
        except OSError:
            pass
        self.info = json.loads(self._line() or '{"ok": false, "error": "the video decoder did not start"}')

    def _wait(self) -> None:
        if not select.select([self.proc.stdout], [], [], STALL_TIMEOUT)[0]:
            self.close()
            raise _DecoderStopped(f"the video decoder stopped responding for {STALL_TIMEOUT:g} s")

    def _line(self) -> bytes:
        line = b""
        while not line.endswith(b"\n"):
            self._wait()
            byte = self.proc.stdout.read(1)
            if not byte:
                return b""  # ended: the caller asks why
            line += byte
        return line

    def _read_into(self, buf: memoryview) -> bool:
        got = 0
        while got < len(buf):
            self._wait()
            n = self.proc.stdout.readinto(buf[got:])
            if not n:
                return False
            got += n
        return True

    def _died(self) -> _DecoderStopped:
        code = self.proc.wait()
        if code < 0:
            try:
                name = signal.Signals(-code).name
            except ValueError:
                name = f"signal {-code}"
            return _DecoderStopped(f"the video decoder (OpenCV/FFmpeg) crashed ({name})")
        return _DecoderStopped(f"the video decoder ended unexpectedly (status {code})")

    def frames(self) -> Iterator[np.ndarray]:
        head = bytearray(_decoder.RECORD.size)
        while True:
            if not self._read_into(memoryview(head)):
                raise self._died()
            rows, cols, channels, flag = _decoder.RECORD.unpack(head)
            if rows == 0:
                if flag:
                    raise _DecoderStopped(json.loads(self._line() or b'{"error": "?"}')["error"])
                return
            if max(rows, cols) > MAX_IMAGE_SIDE:
                self.close()
                raise InputDataError(_too_large(self.path, cols, rows, "video's frame").args[0])
            if min(rows, cols) < MIN_IMAGE_SIDE:
                self.close()
                raise InputDataError(f"{self.path}: the video's frames are {cols}x{rows} pixels; at least "
                                     f"{MIN_IMAGE_SIDE}x{MIN_IMAGE_SIDE} are needed")
            img = np.empty((rows, cols, channels), dtype=np.uint8)
            if not self._read_into(memoryview(img).cast("B")):
                raise self._died()
            yield img

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()
        self.proc.stdout.close()


def _crash_advice(path: Path) -> str:
    return (f"the file is damaged or in a form the decoder cannot read; convert it, e.g. to a folder of PNG "
            f"images with `ffmpeg -i {path} frames/%05d.png`")


def probe_video(path: Path) -> dict:
    """The video's header (``frames``, ``fps``, ``width``, ``height``, ``raw``), after
    decoding its first frame in a child process; InputDataError if it cannot be opened,
    is too large or crashes the decoder."""
    dec = _Decoder(path, "probe")
    try:
        info = dec.info
        if not info.get("ok"):
            raise InputDataError(f"{path}: {info.get('error', 'cannot open as a video')}")
        if max(info["width"], info["height"]) > MAX_IMAGE_SIDE:
            raise _too_large(path, info["width"], info["height"], "video's frame")
        info["decoded"] = False
        try:
            for img in dec.frames():
                info["width"], info["height"], info["decoded"] = img.shape[1], img.shape[0], True
        except _DecoderStopped as err:
            raise InputDataError(f"{path}: frame 0: {err}; {_crash_advice(path)}") from None
        return info
    finally:
        dec.close()


class FrameSource:
    """Frames of a video file or of a folder of images (see the module docstring).

    ``len_hint`` is the frame count the source announces (None if unknown).
    After iterating: ``frames_read`` is the number of frames delivered and
    ``stopped_early`` a message (str) if a video stopped before its announced
    end, else None.
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        if not self.path.exists():
            raise FileNotFoundError(2, "no such file or folder", str(self.path))
        self.is_folder = self.path.is_dir()
        self.frames_read = 0
        self.stopped_early: str | None = None
        self.fps: float | None = None
        self.frame_size: tuple[int, int] | None = None  # (width, height) of a video's frames, from the probe
        if self.is_folder:
            self.files = list_images(self.path)
            if not self.files:
                exts = ", ".join(sorted(e.lstrip(".") for e in IMAGE_EXTENSIONS))
                raise InputDataError(f"{self.path}: folder holds no images ({exts})")
            self.len_hint: int | None = len(self.files)
        else:
            self.files = []
            if not self.path.is_file():  # a FIFO would block the decoder, a device never end
                raise InputDataError(f"{self.path}: not a regular file (a video must be a file or a folder of images)")
            info = probe_video(self.path)
            n, fps = info["frames"], info["fps"]
            self.len_hint = n if n > 0 else None
            self.fps = fps if fps > 0 else None
            if info["decoded"]:
                self.frame_size = (info["width"], info["height"])

    def __iter__(self) -> Iterator[tuple[int, np.ndarray]]:
        self.frames_read = 0
        self.stopped_early = None
        if self.is_folder:
            yield from self._iter_folder()
        else:
            yield from self._iter_video()

    def _iter_folder(self) -> Iterator[tuple[int, np.ndarray]]:
        shape = None
        first = None
        for i, f in enumerate(self.files):
            img = read_image(f)
            if shape is None:
                shape, first = img.shape[:2], f
                if min(shape) < MIN_IMAGE_SIDE:
                    raise InputDataError(f"{f}: frame {i} is {shape[1]}x{shape[0]} pixels; at least "
                                         f"{MIN_IMAGE_SIDE}x{MIN_IMAGE_SIDE} are needed")
            elif img.shape[:2] != shape:
                raise InputDataError(
                    f"{f}: frame {i} is {img.shape[1]}x{img.shape[0]} pixels, but the first image "
                    f"{first.name} is {shape[1]}x{shape[0]}; all images of a sequence must have one size"
                )
            self.frames_read = i + 1
            yield i, img

    def _iter_video(self) -> Iterator[tuple[int, np.ndarray]]:
        dec = _Decoder(self.path, "frames")
        stopped = None
        try:
            if not dec.info.get("ok"):
                raise InputDataError(f"{self.path}: {dec.info.get('error', 'cannot open as a video')}")
            for i, img in enumerate(dec.frames()):
                self.frames_read = i + 1
                yield i, img
        except _DecoderStopped as err:
            stopped = str(err)
        finally:
            dec.close()
        if self.frames_read == 0:
            why = f"{stopped}; {_crash_advice(self.path)}" if stopped else "empty, corrupt or truncated video"
            raise InputDataError(f"{self.path}: no frame could be decoded ({why})")
        if stopped:
            self.stopped_early = (f"{self.path}: stopped at frame {self.frames_read} (frames 0-{self.frames_read - 1} "
                                  f"read): {stopped}")
        elif self.len_hint is not None and self.frames_read < self.len_hint:
            self.stopped_early = (
                f"{self.path}: stopped at frame {self.frames_read} (frames 0-{self.frames_read - 1} read); "
                f"the file announces {self.len_hint} frames: truncated or corrupt video"
            )


def open_frames(path: str | os.PathLike) -> FrameSource:
    """A :class:`FrameSource` for a video file or a folder of images."""
    return FrameSource(path)


def read_frames(path: str | os.PathLike) -> Iterator[tuple[int, np.ndarray]]:
    """``(index, BGR image)`` of every frame of a video file or a folder of images.

    A video that ends early yields the frames it has and then warns with
    :class:`TruncatedVideoWarning`; nothing readable raises InputDataError.
    """
    src = FrameSource(path)
    yield from src
    if src.stopped_early:
        warnings.warn(src.stopped_early, TruncatedVideoWarning, stacklevel=2)


def write_png_atomically(path: str | os.PathLike, image: np.ndarray) -> None:
    """Encode ``image`` as PNG and move it into place (a reader never sees half a file)."""
    path = Path(path)
    ok, buf = cv2.imencode(".png", image)
    if not ok:  # pragma: no cover - cv2 encodes any uint8 image
        raise InputDataError(f"{path}: cannot encode PNG")
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(buf.tobytes())
        mask = os.umask(0)
        os.umask(mask)
        os.chmod(tmp, 0o666 & ~mask)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def write_mask(folder: str | os.PathLike, index: int, mask: np.ndarray) -> Path:
    """Write ``mask`` (bool or 0/255) as ``folder/frame_NNNNN.png`` (0/255, atomically)."""
    path = Path(folder) / MASK_NAME.format(index)
    img = np.where(np.asarray(mask) > 0, 255, 0).astype(np.uint8)
    write_png_atomically(path, img)
    return path


_MASK_RE = re.compile(r"^frame_(\d{5,})\.png$")


def remove_masks_from(folder: str | os.PathLike, first: int) -> int:
    """Delete ``folder``'s masks numbered ``first`` or more (an earlier, longer run's),
    so that the folder holds one sequence; returns how many."""
    folder = Path(folder)
    if not folder.is_dir():
        return 0
    stale = [p for p in folder.iterdir() if (m := _MASK_RE.match(p.name)) and int(m.group(1)) >= first]
    for p in stale:
        p.unlink()
    return len(stale)


# ---------------------------------------------------------------- mask folders
_FRAME_NUMBER = re.compile(r"(\d+)(?=\.png$)", re.IGNORECASE)
_PNG = b"\x89PNG\r\n\x1a\n"


def _frames_in(folder: Path) -> dict[int, Path]:
    frames: dict[int, Path] = {}
    for path in sorted(folder.glob("*.png")) + sorted(folder.glob("*.PNG")):
        if not path.is_file():  # a FIFO would block the header check, a device never end
            raise InputDataError(f"{path}: not a regular file")
        m = _FRAME_NUMBER.search(path.name)
        if m is None:
            raise InputDataError(f"{path}: cannot tell the frame number from the name (expected frame_NNNNN.png)")
        k = int(m.group(1))
        if k in frames and frames[k] != path:
            raise InputDataError(f"{path}: frame {k} appears twice (also {frames[k].name})")
        frames[k] = path
    return frames


def find_mask_frames(masks: Path, n_cameras: int) -> tuple[list[int], list[dict[int, Path]]]:
    """A mask folder's frame numbers and, per camera, frame -> file (``masks/camK/`` per
    camera, or the PNGs in ``masks`` for one); errors name gaps and missing files."""
    if not masks.exists():
        raise FileNotFoundError(2, "no such folder", str(masks))
    if not masks.is_dir():
        raise InputDataError(f"{masks}: --masks must be a folder")
    cam_dirs = [masks / f"cam{c}" for c in range(n_cameras)]
    if all(d.is_dir() for d in cam_dirs):
        per_cam = [_frames_in(d) for d in cam_dirs]
    elif n_cameras == 1:
        per_cam = [_frames_in(masks)]
    else:
        missing = [str(d) for d in cam_dirs if not d.is_dir()]
        raise InputDataError(f"{masks}: {n_cameras} cameras but no mask folder {', '.join(missing)}")
    where = cam_dirs if len(per_cam) > 1 or cam_dirs[0].is_dir() else [masks]
    for d, frames in zip(where, per_cam):
        if not frames:
            raise InputDataError(f"{d}: no PNG masks found")
    numbers = sorted(per_cam[0])
    for d, frames in zip(where, per_cam):
        nums = sorted(frames)
        gaps = sorted(set(range(nums[0], nums[-1] + 1)) - set(nums))
        if gaps:
            shown = ", ".join(map(str, gaps[:10])) + (" ..." if len(gaps) > 10 else "")
            raise InputDataError(f"{d}: missing frame(s) {shown} (frames {nums[0]}..{nums[-1]})")
        if nums != numbers:
            other = sorted(set(nums) ^ set(numbers))
            raise InputDataError(f"{d}: frames differ from {where[0]}: frame(s) {', '.join(map(str, other[:10]))}")
    return numbers, per_cam


def _size_error(path: Path, frame: int, width: int, height: int, shape: tuple[int, int], name: str) -> InputDataError:
    cam = f" {name}" if name else ""
    return InputDataError(f"{path}: frame {frame}: mask is {width}x{height} but camera{cam} is {shape[1]}x{shape[0]}")


def check_masks(per_cam: list[dict[int, Path]], numbers: list[int], shapes: list[tuple[int, int]],
                names: list[str]) -> None:
    """Before anything is written: every mask decodes, at its camera's size (H, W) in
    ``shapes`` (a PNG's size read from its header first, so a mask of the wrong size is
    refused as such even when it is also damaged)."""
    for pc, shape, name in zip(per_cam, shapes, names):
        for f in numbers:
            path = pc[f]
            try:
                with open(path, "rb") as fh:
                    head = fh.read(24)
            except OSError as err:
                raise InputDataError(f"{path}: frame {f}: cannot read: {err.strerror or err}") from None
            if head[:8] == _PNG and head[12:16] == b"IHDR":
                w, h = int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
                if (h, w) != shape:
                    raise _size_error(path, f, w, h, shape, name)
            img = decode_image(path, where=f"{path}: frame {f}")
            if img.shape[:2] != shape:
                raise _size_error(path, f, img.shape[1], img.shape[0], shape, name)


def read_mask(path: Path, frame: int, shape: tuple[int, int], name: str = "",
              noted: set | None = None) -> np.ndarray:
    """Frame ``frame``'s mask (bool, (H, W) = ``shape``) from a PNG: non-zero is
    foreground; a grey image is thresholded at 127 (with a note on stderr, once per
    path in ``noted`` if given: a run that reads a mask again says it once)."""
    img = decode_image(path, where=f"{path}: frame {frame}")  # refuses over 8192 pixels a side before decoding
    if img.ndim == 3:
        img = cv2.cvtColor(img[..., :3], cv2.COLOR_BGR2GRAY)
    if img.shape != shape:
        raise _size_error(path, frame, img.shape[1], img.shape[0], shape, name)
    scale = 255 if img.dtype == np.uint8 else np.iinfo(img.dtype).max if img.dtype.kind in "ui" else 1
    vals = np.unique(img)
    if not np.all(np.isin(vals, (0, scale))) and not np.all(np.isin(vals, (0, 1))):
        if noted is None or path not in noted:
            print(f"note: {path}: frame {frame}: not a binary mask; thresholded at 127", file=sys.stderr)
        if noted is not None:
            noted.add(path)
        return img > 127 * scale / 255
    return img > 0
