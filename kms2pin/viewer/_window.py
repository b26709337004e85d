"""meshcat windows that clean up after themselves, and one that needs no server.

meshcat's own :class:`meshcat.visualizer.ViewerWindow` starts its server (which
listens on every interface and outlives a killed parent) with
stdout and stderr piped and never reads them again.  The server writes a line
to stderr for every browser connection, so after a few hundred connections the
pipe is full and the server blocks for good; its ``close()`` does not exist
(``Visualizer.close()`` raises AttributeError) and the server only dies at
interpreter exit.  :class:`ServerWindow` starts the same server, kept local and
tied to this process (:mod:`kms2pin.viewer._meshcat_server`), with stderr
discarded and stdout drained, puts a timeout on every request, and stops the
server in :meth:`ServerWindow.close`.

:class:`RecordingWindow` is a drop-in window without any process: it keeps the
scene tree exactly as the server does and builds the same standalone page for
``Visualizer.static_html()``.  It is what ``kms2pin view --no-serve`` and the
figure scripts use.
"""

from __future__ import annotations

import os
import subprocess
import threading
import time
from pathlib import Path

import meshcat
import umsgpack
import zmq
from meshcat.servers.tree import SceneTree, find_node, walk

from .._child import helper_command
from . import _meshcat_server
from .errors import ViewerError

MESHCAT_COMMANDS = ("set_transform", "set_object", "delete", "set_property", "set_animation")
VIEWER_JS = Path(meshcat.__file__).resolve().parent / "viewer" / "dist" / "main.min.js"


def _command_js(data: bytes) -> str:
    import base64

    return (
        '\nfetch("data:application/octet-binary;base64,' + base64.b64encode(data).decode("ascii") + '")\n'
        "    .then(res => res.arrayBuffer())\n"
        "    .then(buffer => viewer.handle_command_bytearray(new Uint8Array(buffer)));\n"
    )


def static_page(commands_js: str) -> str:
    """The standalone page meshcat's server builds for ``get_scene`` (same layout)."""
    js = VIEWER_JS.read_text(encoding="utf-8")
    return f"""
<!DOCTYPE html>
<html>
    <head> <meta charset=utf-8> <title>MeshCat</title> </head>
    <body>
        <div id="meshcat-pane">
        </div>
        <script>
            {js}
        </script>
        <script>
            var viewer = new MeshCat.Viewer(document.getElementById("meshcat-pane"));
            {commands_js}
        </script>
         <style>
            body {{margin: 0; }}
            #meshcat-pane {{
                width: 100vw;
                height: 100vh;
                overflow: hidden;
            }}
        </style>
        <script id="embedded-json"></script>
    </body>
</html>
"""


class RecordingWindow:
    """A meshcat window with no server: it records the scene and exports it.

    ``Visualizer(window=RecordingWindow())`` accepts every drawing command;
    ``static_html()`` returns the standalone page (meshcat's static export).
    ``web_url`` is None and nothing is served.
    """

    web_url = None
    server_proc = None

    def __init__(self) -> None:
        self.tree = SceneTree()
        self.sent: list[dict] = []  # every lowered command, in order (for tests)

    def send(self, command) -> None:
        data = command.lower()
        self.sent.append(data)
        kind = data["type"]
        if kind not in MESHCAT_COMMANDS:
            raise ViewerError(f"unsupported meshcat command {kind!r}")
        path = [p for p in data["path"].split("/") if p]
        packed = umsgpack.packb(data)
        if kind == "set_transform":
            find_node(self.tree, path).transform = packed
        elif kind == "set_object":
            node = find_node(self.tree, path)
            node.object = packed
            node.properties = []
        elif kind == "set_property":
            find_node(self.tree, path).properties.append(packed)
        elif kind == "set_animation":
            find_node(self.tree, path).animation = packed
        elif kind == "delete":
            if path:
                parent = find_node(self.tree, path[:-1])
                parent.pop(path[-1], None)
            else:
                self.tree = SceneTree()

    def get_scene(self) -> str:
        commands, animations = [], []
        for node in walk(self.tree):
            if node.object is not None:
                commands.append(_command_js(node.object))
            commands.extend(_command_js(p) for p in node.properties)
            if node.transform is not None:
                commands.append(_command_js(node.transform))
            if node.animation is not None:  # after the objects it animates
                animations.append(_command_js(node.animation))
        return static_page("".join(commands + animations))

    def wait(self) -> str:  # nothing can connect
        raise ViewerError("a recording (no-server) meshcat window has no browser to wait for")

    def get_image(self):
        raise ViewerError("a recording (no-server) meshcat window cannot capture images; use kms2pin.viewer.screenshot")

    def close(self) -> None:
        pass


class ServerWindow:
    """A meshcat server subprocess plus a ZMQ connection to it (see module docstring).

    The server (:mod:`kms2pin.viewer._meshcat_server`) listens on ``host`` only
    (127.0.0.1: this machine), answers only its own address there, and exits when
    this process is gone, even killed with SIGKILL.
    Attributes: ``server_proc`` (the subprocess), ``zmq_url``, ``web_url``.
    Every request times out after ``timeout`` seconds with a :class:`ViewerError`.
    """

    def __init__(self, timeout: float = 20.0, start_timeout: float = 30.0, host: str = "127.0.0.1") -> None:
        self.timeout = timeout
        self.lock = threading.RLock()  # one REQ socket: one request at a time
        self.server_proc = subprocess.Popen(
            helper_command(_meshcat_server.__file__, host, str(os.getpid())),
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            start_new_session=True,  # Ctrl-C in a terminal reaches this process, which then stops the server
        )
        urls: dict[str, str] = {}
        ready = threading.Event()

        def drain() -> None:  # read the two URL lines, then keep the pipe empty
            for raw in self.server_proc.stdout:
                line = raw.decode("utf-8", "replace").strip()
                for key in ("zmq_url", "web_url"):
                    if line.startswith(key + "="):
                        urls[key] = line[len(key) + 1:]
                if len(urls) == 2:
                    ready.set()
            ready.set()

        self._drain = threading.Thread(target=drain, name="meshcat-stdout", daemon=True)
        self._drain.start()
        if not ready.wait(start_timeout) or len(urls) != 2:
            self._kill()
            raise ViewerError(f"the meshcat server did not start within {start_timeout:g} s")
        self.zmq_url, self.web_url = urls["zmq_url"], urls["web_url"]
        self.context = zmq.Context()
        self._connect()

    def _connect(self) -> None:
        self.zmq_socket = self.context.socket(zmq.REQ)
        ms = int(self.timeout * 1000)
        self.zmq_socket.setsockopt(zmq.RCVTIMEO, ms)
        self.zmq_socket.setsockopt(zmq.SNDTIMEO, ms)
        self.zmq_socket.setsockopt(zmq.LINGER, 0)
        self.zmq_socket.connect(self.zmq_url)

    def _request(self, frames: list[bytes]) -> bytes:
        with self.lock:
            if self.server_proc.poll() is not None:
                raise ViewerError(f"the meshcat server has exited (status {self.server_proc.returncode})")
            try:
                self.zmq_socket.send_multipart(frames)
                return self.zmq_socket.recv()
            except zmq.error.Again:
                self.zmq_socket.close()
                self._connect()  # a REQ socket that timed out cannot be reused
                raise ViewerError(f"the meshcat server did not answer within {self.timeout:g} s") from None

    def send(self, command) -> None:
        data = command.lower()
        self._request([data["type"].encode("utf-8"), data["path"].encode("utf-8"), umsgpack.packb(data)])

    def get_scene(self) -> str:
        return self._request([b"get_scene"]).decode("utf-8")

    def wait(self) -> str:
        return self._request([b"wait"]).decode("utf-8")

    def get_image(self):
        raise ViewerError("meshcat's get_image hangs without a connected browser; use kms2pin.viewer.screenshot")

    @property
    def alive(self) -> bool:
        return self.server_proc.poll() is None

    def _kill(self) -> None:
        proc = self.server_proc
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=5)
        if proc.stdout is not None:
            proc.stdout.close()

    def close(self) -> None:
        """Stop the server process (idempotent)."""
        with self.lock:
            sock = getattr(self, "zmq_socket", None)
            if sock is not None and not sock.closed:
                sock.close(linger=0)
            self._kill()
            ctx = getattr(self, "context", None)
            if ctx is not None and not ctx.closed:
                ctx.term()


def wait_until(predicate, timeout: float, interval: float = 0.05) -> bool:
    """Poll ``predicate`` until it is true or ``timeout`` seconds pass."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(interval)
    return bool(predicate())
