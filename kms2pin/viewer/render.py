"""Standalone HTML and PNG output: meshcat's static page, screenshotted by headless Chromium."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import tempfile
from pathlib import Path

import numpy as np

from .errors import ViewerError

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable", "chrome")
CHROMIUM_FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--use-gl=angle",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
    "--hide-scrollbars",
)
# For pictures: meshcat's control panel (dat.GUI) hidden, plain white page.
SCREENSHOT_CSS = "<style>.dg.ac, .dg.main { display: none !important; } html, body { background: #ffffff; }</style>"


def find_chromium() -> str | None:
    """Path of a Chromium/Chrome executable: ``$KMS2PIN_CHROMIUM``, else the PATH, else None."""
    env = os.environ.get("KMS2PIN_CHROMIUM")
    if env:
        return env if (os.path.isfile(env) and os.access(env, os.X_OK)) else None
    for name in CHROMIUM_NAMES:
        found = shutil.which(name)
        if found:
            return found
    return None


_UMASK = os.umask(0o022)
os.umask(_UMASK)  # read once, at import (changing the umask is not thread-safe)


def _write_atomically(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp makes 0600 files; give the usual permissions
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def write_html(html: str, path: str | os.PathLike) -> Path:
    """Write a standalone page (e.g. ``vis.static_html()``) to ``path``."""
    path = Path(path)
    try:
        _write_atomically(path, html.encode("utf-8"))
    except OSError as err:
        raise ViewerError(f"cannot write {path}: {err.strerror or err}") from None
    return path


def for_screenshot(html: str) -> str:
    """The page with meshcat's control panel hidden and a white background."""
    return html.replace("</body>", SCREENSHOT_CSS + "\n</body>", 1) if "</body>" in html else html + SCREENSHOT_CSS


def screenshot(html_path: str | os.PathLike, png_path: str | os.PathLike, width: int = 800, height: int = 800,
               timeout: float = 60.0, budget_ms: int = 3000) -> Path:
    """Render ``html_path`` (a standalone page, or an ``http://`` URL) with headless
    Chromium into ``png_path``.

    Uses SwiftShader WebGL, a fresh profile in a temporary directory and
    ``--virtual-time-budget`` of ``budget_ms``.  Raises :class:`ViewerError` if
    Chromium is missing, fails, or takes longer than ``timeout`` seconds (then
    its whole process group is killed).
    """
    target, shown = _target(html_path)
    png_path = Path(png_path)
    width, height = int(width), int(height)
    if width <= 0 or height <= 0:
        raise ViewerError(f"picture size must be positive, not {width}x{height}")
    try:
        png_path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise ViewerError(f"cannot write {png_path}: {err.strerror or err}") from None
    with tempfile.TemporaryDirectory(prefix="kms2pin-chromium-") as tmp:
        out = Path(tmp) / "shot.png"
        _, err, code = _run_chromium(tmp, [f"--screenshot={out}", f"--window-size={width},{height}",
                                           f"--virtual-time-budget={int(budget_ms)}", target], timeout, shown)
        if not out.is_file() or out.stat().st_size == 0:
            tail = "\n".join(err.strip().splitlines()[-8:])
            raise ViewerError(f"chromium wrote no screenshot of {shown} (exit {code})" + (f":\n{tail}" if tail else ""))
        try:
            _write_atomically(png_path, out.read_bytes())
        except OSError as err:
            raise ViewerError(f"cannot write {png_path}: {err.strerror or err}") from None
    return png_path


def dump_dom(url: str, timeout: float = 60.0, budget_ms: int = 3000, width: int = 1200, height: int = 800) -> str:
    """The DOM of ``url`` (page or file) after its scripts ran for ``budget_ms`` of
    virtual time (headless Chromium ``--dump-dom``)."""
    target, shown = _target(url)
    with tempfile.TemporaryDirectory(prefix="kms2pin-chromium-") as tmp:
        out, err, code = _run_chromium(tmp, ["--dump-dom", f"--window-size={width},{height}",
                                             f"--virtual-time-budget={int(budget_ms)}", target], timeout, shown)
    if code != 0 or not out.strip():
        tail = "\n".join(err.strip().splitlines()[-8:])
        raise ViewerError(f"chromium could not load {shown} (exit {code})" + (f":\n{tail}" if tail else ""))
    return out


def _target(page: str | os.PathLike) -> tuple[str, str]:
    text = os.fspath(page)
    if text.startswith(("http://", "https://", "file://")):
        return text, text
    path = Path(text).resolve()
    if not path.is_file():
        raise ViewerError(f"cannot render {path}: no such file")
    return path.as_uri(), path.name


def _run_chromium(tmp: str, args: list[str], timeout: float, shown: str) -> tuple[str, str, int]:
    exe = find_chromium()
    if exe is None:
        raise ViewerError("cannot render: no Chromium found (install the 'chromium' package, "
                          "or set KMS2PIN_CHROMIUM to a Chromium/Chrome executable)")
    cmd = [exe, *CHROMIUM_FLAGS, f"--user-data-dir={Path(tmp) / 'profile'}", *args]
    proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            start_new_session=True, cwd=tmp)
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        _kill_group(proc)
        raise ViewerError(f"chromium did not finish with {shown} within {timeout:g} s") from None
    finally:
        _kill_group(proc)  # helpers (GPU, zygote) that outlived the browser
    return out.decode("utf-8", "replace"), err.decode("utf-8", "replace"), proc.returncode


def _kill_group(proc: subprocess.Popen) -> None:
    try:
        os.killpg(proc.pid, signal.SIGKILL)  # the session chromium was started in (our own)
    except (ProcessLookupError, PermissionError):
        pass
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        pass


def render_png(html: str, png_path: str | os.PathLike, width: int = 800, height: int = 800,
               timeout: float = 60.0) -> Path:
    """Screenshot a standalone page given as text (panel hidden, white background)."""
    with tempfile.TemporaryDirectory(prefix="kms2pin-page-") as tmp:
        page = Path(tmp) / "scene.html"
        page.write_text(for_screenshot(html), encoding="utf-8")
        return screenshot(page, png_path, width, height, timeout=timeout)


def read_png(path: str | os.PathLike) -> np.ndarray:
    """An RGB uint8 image (H, W, 3)."""
    import cv2

    img = cv2.imread(os.fspath(path), cv2.IMREAD_COLOR)
    if img is None:
        raise ViewerError(f"cannot read image {path}")
    return img[:, :, ::-1].copy()


def inner_mask(img: np.ndarray) -> np.ndarray:
    """Pixels of the (lit, possibly behind the translucent outer shell) inner-ellipsoid
    orange: red clearly above green above blue.  Boolean (H, W)."""
    c = img.astype(np.int32)
    r, gr, b = c[..., 0], c[..., 1], c[..., 2]
    return (r - b > 60) & (r > gr + 15) & (gr > b + 10) & (r > 90)


def red_mask(img: np.ndarray) -> np.ndarray:
    """Pixels of the red spring arrows: strongly red, little green and blue."""
    c = img.astype(np.int32)
    r, gr, b = c[..., 0], c[..., 1], c[..., 2]
    return (r > 110) & (r > 2.2 * gr + 20) & (r > 2.2 * b + 20)


def mask_box(mask: np.ndarray) -> tuple[int, int, int, int] | None:
    """(row_min, row_max, col_min, col_max) of a mask, or None if empty."""
    rows, cols = np.nonzero(mask)
    if not len(rows):
        return None
    return int(rows.min()), int(rows.max()), int(cols.min()), int(cols.max())
