"""Reading a file that a user names: a regular file under a size limit, read without
blocking; and the limits on what a user's files may hold.

A FIFO, a device (``/dev/zero``), a socket or a folder is refused at once (reading
one would hang or never end), and so is a file larger than the limit.  Every
refusal is an :class:`OSError` carrying the file name, so that the command line
reports it in one line (``PATH: reason``, exit status 2) as it does a missing file.
"""

from __future__ import annotations

import errno
import os
import stat

MAX_SPEC_BYTES = 16 * 2**20  # a spec: 16 MiB (a 10,000-body tree is about 2 MB)
MAX_DATA_BYTES = 64 * 2**20  # a camera, pose, metadata or trajectory file: 64 MiB
MAX_IMAGE_SIDE = 8192  # pixels: cameras, images, masks and video frames larger than this a side are refused

_KINDS = ((stat.S_ISFIFO, "a FIFO"), (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
          (stat.S_ISSOCK, "a socket"))


def _size(n: int) -> str:
    return f"{n / 2**20:.3g} MiB" if n >= 2**20 else f"{n} bytes"


def read_user_file(path: str | os.PathLike, limit: int) -> bytes:
    """The bytes of the regular file ``path``, at most ``limit`` of them.

    Raises FileNotFoundError, IsADirectoryError, PermissionError, ``OSError(ELOOP)``
    (a symbolic-link loop) as :func:`open` does; ``OSError(EINVAL)`` for a FIFO, a
    device or a socket (opened non-blocking, so a FIFO with no writer does not
    hang); ``OSError(EFBIG)`` for a file over ``limit`` bytes.
    """
    shown = os.fspath(path)
    fd = os.open(shown, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    try:
        mode = os.fstat(fd).st_mode
        if stat.S_ISDIR(mode):
            raise IsADirectoryError(errno.EISDIR, "is a directory", shown)
        if not stat.S_ISREG(mode):
            kind = next((name for test, name in _KINDS if test(mode)), "not a file")
            raise OSError(errno.EINVAL, f"not a regular file ({kind})", shown)
        with os.fdopen(fd, "rb", closefd=False) as f:
            data = f.read(limit + 1)  # st_size may lie (a file still growing, /proc): read one byte past the limit
    finally:
        os.close(fd)
    if len(data) > limit:
        raise OSError(errno.EFBIG, f"file too large (more than {_size(limit)}, the limit)", shown)
    return data
