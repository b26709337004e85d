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
"""

from __future__ import annotations

import os
import re
import sys
import tempfile
import warnings
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from ..errors import InputDataError

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


def read_image(path: str | os.PathLike, flags: int = cv2.IMREAD_COLOR) -> np.ndarray:
    """Read one image; a missing file raises FileNotFoundError, an undecodable one InputDataError."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(2, "no such file", str(path))
    try:
        data = np.fromfile(str(path), dtype=np.uint8)
    except OSError as e:
        raise InputDataError(f"{path}: cannot read image: {e.strerror or e}") from None
    img = cv2.imdecode(data, flags) if data.size else None
    if img is None:
        raise InputDataError(f"{path}: not a readable image (empty, truncated or unknown format)")
    if img.dtype != np.uint8:  # 16-bit PNG/TIFF, float EXR: scale to 8 bits
        img = cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    return img


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
        if self.is_folder:
            self.files = list_images(self.path)
            if not self.files:
                exts = ", ".join(sorted(e.lstrip(".") for e in IMAGE_EXTENSIONS))
                raise InputDataError(f"{self.path}: folder holds no images ({exts})")
            self.len_hint: int | None = len(self.files)
        else:
            self.files = []
            cap = self._open()
            n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
            fps = float(cap.get(cv2.CAP_PROP_FPS))
            cap.release()
            self.len_hint = n if n > 0 else None
            self.fps = fps if fps > 0 else None

    def _open(self) -> cv2.VideoCapture:
        cap = cv2.VideoCapture(str(self.path))
        if not cap.isOpened():
            cap.release()
            raise InputDataError(
                f"{self.path}: cannot open as a video (unknown format, unsupported codec or truncated file)"
            )
        return cap

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
            elif img.shape[:2] != shape:
                raise InputDataError(
                    f"{f}: frame {i} is {img.shape[1]}x{img.shape[0]} pixels, but the first image "
                    f"{first.name} is {shape[1]}x{shape[0]}; all images of a sequence must have one size"
                )
            self.frames_read = i + 1
            yield i, img

    def _iter_video(self) -> Iterator[tuple[int, np.ndarray]]:
        cap = self._open()
        try:
            i = 0
            while True:
                ok, img = cap.read()
                if not ok or img is None:
                    break
                if img.ndim == 2:
                    img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
                self.frames_read = i + 1
                yield i, img
                i += 1
        finally:
            cap.release()
        if self.frames_read == 0:
            raise InputDataError(f"{self.path}: no frame could be decoded (empty, corrupt or truncated video)")
        if self.len_hint is not None and self.frames_read < self.len_hint:
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


def check_mask_sizes(per_cam: list[dict[int, Path]], numbers: list[int], shapes: list[tuple[int, int]],
                     names: list[str]) -> None:
    """Before anything is written: every mask's size (H, W) against its camera's
    ``shapes``, from its PNG header (a file that is not a PNG is decoded instead)."""
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
            else:
                read_mask(path, f, shape, name)


def read_mask(path: Path, frame: int, shape: tuple[int, int], name: str = "") -> np.ndarray:
    """Frame ``frame``'s mask (bool, (H, W) = ``shape``) from a PNG: non-zero is
    foreground; a grey image is thresholded at 127 (with a note on stderr)."""
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise InputDataError(f"{path}: frame {frame}: cannot read the image (not a PNG, or damaged)")
    if img.ndim == 3:
        img = cv2.cvtColor(img[..., :3], cv2.COLOR_BGR2GRAY)
    if img.shape != shape:
        raise _size_error(path, frame, img.shape[1], img.shape[0], shape, name)
    scale = 255 if img.dtype == np.uint8 else np.iinfo(img.dtype).max if img.dtype.kind in "ui" else 1
    vals = np.unique(img)
    if not np.all(np.isin(vals, (0, scale))) and not np.all(np.isin(vals, (0, 1))):
        print(f"note: {path}: frame {frame}: not a binary mask; thresholded at 127", file=sys.stderr)
        return img > 127 * scale / 255
    return img > 0
