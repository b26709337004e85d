"""Interactive joint control (thesis §3.2.3, §4.1: "model configurations were generated
by interactively manipulating joint angles with the graphical interface").

:class:`JointControl` serves a small page (Python's ``http.server`` in a thread)
with one slider per joint coordinate (a revolute joint's angle, a spherical joint's
three X-Y-Z angles, a prismatic joint's offset), the meshcat viewer in an ``<iframe>``, a
reset-to-rest button, camera buttons and the configuration as a ``--pose``
string.  Slider moves POST to the server, which updates :attr:`JointControl.q`
and sends one ``set_transform`` per body to meshcat (no geometry upload).

HTTP interface (JSON in, JSON out; errors are ``{"error": message}``):

* ``GET /``        the page (``/?pose=name=deg,name=deg`` moves those sliders on load)
* ``GET /state``   ``{"joints": [{"name", "value", "unit", "min", "max"}], "pose", "meshcat_url",
  "updates"}`` (angular coordinates also carry their value as ``"deg"``)
* ``POST /joint``  ``{"name": coordinate, "deg": angle}`` (or ``"value"``: degrees, or spec length
  units for a prismatic joint)
* ``POST /pose``   ``{"pose": "name=deg name=deg ..."}``
* ``POST /reset``  back to the rest pose
* ``POST /camera`` ``{"view": "front" | "side" | "top" | "iso"}`` re-frames the current pose

The page answers only itself (:func:`check_request`): bound to a loopback address
(the default, 127.0.0.1), a request whose ``Host`` is not its own address gets 403
(a DNS name rebound to 127.0.0.1 cannot read ``/state``), and so does one whose
``Origin``, when present, is not its own origin (a page of another site cannot move
a joint through the user's browser).  A POST body must come with a valid
``Content-Length`` (missing: 411; not a whole number >= 0: 400) of at most
:data:`MAX_BODY` bytes (413), refused before anything is read; a body that is not
a JSON object of the right fields and types, or is nested too deeply, is 400.
"""

from __future__ import annotations

import html
import json
import math
import threading
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from urllib.parse import urlsplit

import meshcat
import numpy as np

from ..errors import Kms2pinError
from ..jsonfile import parse_json
from ..robot import Robot
from ._meshcat_server import is_loopback, own_hosts
from .errors import PoseError, ViewerError
from .pose import joint_angles_deg, joint_sliders, parse_pose, pose_string, slider_values
from .robot_view import RobotView

MAX_BODY = 64 * 1024
READ_TIMEOUT = 30.0  # seconds a request may take to arrive


class JointControl:
    """Sliders for ``robot``'s joint coordinates, driving a meshcat scene.

    Args:
        robot: the compiled robot.
        vis: a :class:`RobotView` or a meshcat Visualizer with a server (the robot
            is drawn into it); None starts a new meshcat server, owned and
            stopped by :meth:`close`.
        q: initial configuration (default rest).
        host, port: where the control page listens (port 0: any free port).

    Attributes: :attr:`url` (the control page), :attr:`meshcat_url`, :attr:`q`,
    :attr:`transform_log` (every ``(path, 4x4)`` sent to meshcat).
    """

    def __init__(self, robot: Robot, vis: RobotView | meshcat.Visualizer | None = None, q=None, *,
                 camera: str = "front", host: str = "127.0.0.1", port: int = 0):
        self.robot = robot
        self.joints = joint_sliders(robot)
        self._by_name = {j.name: j for j in self.joints}
        self._lock = threading.RLock()
        self.updates = 0
        if isinstance(vis, RobotView):
            self.view, self._owns_view = vis, False
            if q is not None:
                self.view.set_configuration(q)
        else:
            self.view = RobotView(robot, q, vis, camera=camera, aspect=16 / 10, serve=vis is None)
            self._owns_view = vis is None
        self.vis = self.view.vis
        self._rest = np.array(robot.q_rest, dtype=float)
        try:
            self._httpd = ThreadingHTTPServer((host, port), _handler_for(self))
        except OSError as err:
            self._close_view()
            raise ViewerError(f"cannot serve the control page on {host}:{port}: {err.strerror or err}") from None
        self._httpd.daemon_threads = True
        self._thread = threading.Thread(target=self._httpd.serve_forever, name="kms2pin-joint-control",
                                        kwargs={"poll_interval": 0.1}, daemon=True)
        self._thread.start()
        self._closed = False

    # ------------------------------------------------------------------ state
    @property
    def url(self) -> str:
        host, port = self._httpd.server_address[:2]
        return f"http://{host}:{port}/"

    @property
    def meshcat_url(self) -> str | None:
        return self.view.url

    @property
    def q(self) -> np.ndarray:
        with self._lock:
            return self.view.q

    @property
    def transform_log(self) -> list[tuple[str, np.ndarray]]:
        return self.view.drawing.transform_log

    def angles_deg(self) -> dict[str, float]:
        return joint_angles_deg(self.robot, self.q)

    def pose(self) -> str:
        return pose_string(self.robot, self.q)

    def state(self) -> dict:
        with self._lock:
            values = slider_values(self.robot, self.view.q)
            return {
                "model": self.robot.system.name,
                "joints": [{"name": j.name, "value": values[j.name], "unit": j.unit, "min": j.lower, "max": j.upper,
                            **({"deg": values[j.name]} if j.unit == "deg" else {})} for j in self.joints],
                "pose": pose_string(self.robot, self.view.q),
                "meshcat_url": self.meshcat_url,
                "updates": self.updates,
            }

    # ------------------------------------------------------------------ changes
    def _apply(self, q: np.ndarray) -> None:
        with self._lock:
            self.view.set_configuration(q)
            self.updates += 1

    def set_joint(self, name: str, deg: float) -> np.ndarray:
        """Set one joint coordinate (a slider: degrees, wrapped into [-180, 180] unless the
        joint has limits, which it must then respect; spec length units for a prismatic
        joint) and redraw."""
        try:
            deg = float(deg)
        except (TypeError, ValueError):
            raise PoseError(f"value of joint '{name}' is not a number: {deg!r}") from None
        if not math.isfinite(deg):
            raise PoseError(f"value of joint '{name}' must be finite, not {deg!r}")
        with self._lock:
            q = parse_pose(self.robot, f"{name}={deg!r}", self.view.q)
            self._apply(q)
            return q.copy()

    def set_pose(self, pose: str) -> np.ndarray:
        """Apply a ``--pose`` string (``name=deg ...``) to the current configuration."""
        with self._lock:
            q = parse_pose(self.robot, pose, self.view.q)
            self._apply(q)
            return q.copy()

    def set_configuration(self, q: np.ndarray) -> None:
        self._apply(self.robot._check_q(q).copy())

    def reset(self) -> np.ndarray:
        """Back to the rest pose."""
        self._apply(self._rest.copy())
        return self._rest.copy()

    def camera(self, view: str) -> None:
        with self._lock:
            self.view.camera(view)

    # ------------------------------------------------------------------ lifetime
    def _close_view(self) -> None:
        if self._owns_view:
            self.view.close()

    def close(self) -> None:
        """Stop the control page (and the meshcat server if this control started it)."""
        if getattr(self, "_closed", True):
            return
        self._closed = True
        self._httpd.shutdown()
        self._httpd.server_close()
        self._thread.join(timeout=5)
        self._close_view()

    def __enter__(self) -> JointControl:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ page
    def page(self) -> str:
        rows = []
        for j in self.joints:
            n = html.escape(j.name)
            unit, step = ("&deg;", "0.5") if j.unit == "deg" else ("", f"{(j.upper - j.lower) / 500:.3g}")
            rows.append(
                f'<div class="joint"><label for="j-{n}">{n} <span class="range">[{j.lower:g}{unit}, '
                f'{j.upper:g}{unit}]</span></label>'
                f'<div class="row"><input type="range" id="j-{n}" data-joint="{n}" min="{j.lower:g}" '
                f'max="{j.upper:g}" step="{step}" value="0"><output id="o-{n}">0</output></div></div>'
            )
        meshcat_url = self.meshcat_url or ""
        frame = (f'<iframe id="viewer" src="{html.escape(meshcat_url)}"></iframe>' if meshcat_url
                 else '<div id="viewer">(no meshcat server)</div>')
        title = html.escape(f"kms2pin: {self.robot.system.name}")
        return _PAGE.replace("%TITLE%", title).replace("%ROWS%", "\n".join(rows)).replace("%FRAME%", frame) \
            .replace("%MESHCAT%", html.escape(meshcat_url))


class RequestError(Exception):
    """A request the page refuses: HTTP ``status`` and a message."""

    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status = status


def check_request(headers, server_host: str, port: int) -> None:
    """Raise RequestError(403) unless the request is for this page from this page
    (module docstring); ``server_host`` and ``port`` are where it listens."""
    host = (headers.get("Host") or "").lower()
    if is_loopback(server_host) and host not in own_hosts(server_host, port):
        raise RequestError(HTTPStatus.FORBIDDEN, f"this page answers only to its own address, not Host {host!r}")
    origin = headers.get("Origin")
    if origin is not None and urlsplit(origin.lower())[:2] != ("http", host):
        raise RequestError(HTTPStatus.FORBIDDEN, f"cross-origin request from {origin!r} refused")


def read_body(headers, rfile) -> dict:
    """The JSON object of a POST body (module docstring); RequestError otherwise."""
    if headers.get("Transfer-Encoding"):
        raise RequestError(HTTPStatus.LENGTH_REQUIRED, "a chunked body is not accepted; send Content-Length")
    text = headers.get("Content-Length")
    if text is None:
        raise RequestError(HTTPStatus.LENGTH_REQUIRED, "Content-Length is required")
    if not text.strip().isdigit():
        raise RequestError(HTTPStatus.BAD_REQUEST, f"bad Content-Length {text!r}")
    n = int(text)
    if n > MAX_BODY:
        raise RequestError(HTTPStatus.REQUEST_ENTITY_TOO_LARGE, f"request too large ({n} bytes; at most {MAX_BODY})")
    try:
        raw = rfile.read(n) if n else b""
    except TimeoutError:
        raise RequestError(HTTPStatus.REQUEST_TIMEOUT, f"the body did not arrive within {READ_TIMEOUT:g} s") from None
    if len(raw) != n:
        raise RequestError(HTTPStatus.BAD_REQUEST, f"body shorter than its Content-Length ({len(raw)} of {n} bytes)")
    try:
        data = parse_json(raw.decode("utf-8"), PoseError, "request body") if raw.strip() else {}
    except UnicodeDecodeError:
        raise RequestError(HTTPStatus.BAD_REQUEST, "bad request: the body is not UTF-8") from None
    except PoseError as err:
        raise RequestError(HTTPStatus.BAD_REQUEST, f"bad request: {err}") from None
    if not isinstance(data, dict):
        raise RequestError(HTTPStatus.BAD_REQUEST, "bad request: expected a JSON object")
    return data


def _field(data: dict, key: str, kind: type | tuple[type, ...], what: str, default=None):
    """``data[key]`` (or ``default``) if it is a ``kind`` (not a bool), else RequestError(400)."""
    value = data.get(key, default)
    if isinstance(value, bool) or not isinstance(value, kind):
        raise RequestError(HTTPStatus.BAD_REQUEST, f"bad request: '{key}' must be {what}, not {value!r:.60}")
    return value


def _handler_for(control: JointControl):
    class Handler(BaseHTTPRequestHandler):
        server_version = "kms2pin-joint-control"
        timeout = READ_TIMEOUT  # a client that stops sending does not hold a thread forever

        def log_message(self, fmt, *args):  # quiet
            pass

        def _checked(self) -> bool:
            """The Host/Origin check: False (403 sent) if the request is not for this page."""
            try:
                check_request(self.headers, *self.server.server_address[:2])
            except RequestError as err:
                self._refuse(err)
                return False
            return True

        def _refuse(self, err: RequestError) -> None:
            self.close_connection = True  # a body that was not read must not be taken for the next request
            self._json(err.status, {"error": str(err)})

        def _send(self, status: int, body: bytes, ctype: str) -> None:
            self.send_response(status)
            self.send_header("Content-Type", ctype)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            self.end_headers()
            self.wfile.write(body)

        def _json(self, status: int, obj) -> None:
            self._send(status, json.dumps(obj).encode("utf-8"), "application/json")

        def do_GET(self):  # noqa: N802
            if not self._checked():
                return
            path = self.path.split("?", 1)[0]
            if path in ("/", "/index.html"):
                self._send(200, control.page().encode("utf-8"), "text/html; charset=utf-8")
            elif path == "/state":
                self._json(200, control.state())
            else:
                self._json(404, {"error": f"no such page: {path}"})

        def do_POST(self):  # noqa: N802
            if not self._checked():
                return
            path = self.path.split("?", 1)[0]
            try:
                data = read_body(self.headers, self.rfile)
                if path == "/joint":
                    if "name" not in data or ("deg" not in data and "value" not in data):
                        raise RequestError(HTTPStatus.BAD_REQUEST, 'expected {"name": joint, "deg": angle} (or "value")')
                    key = "deg" if "deg" in data else "value"
                    control.set_joint(_field(data, "name", str, "a string"), _field(data, key, (int, float), "a number"))
                elif path == "/pose":
                    control.set_pose(_field(data, "pose", str, "a string", ""))
                elif path == "/reset":
                    control.reset()
                elif path == "/camera":
                    control.camera(_field(data, "view", str, "a string", "front"))
                else:
                    raise RequestError(HTTPStatus.NOT_FOUND, f"no such action: {path}")
            except RequestError as err:
                self._refuse(err)
                return
            except Kms2pinError as err:
                self._json(400, {"error": str(err)})
                return
            except Exception as err:  # noqa: BLE001 - the page stays up; the browser shows the error
                self._json(500, {"error": f"internal error: {type(err).__name__}: {err}"})
                return
            self._json(200, control.state())

    return Handler


_PAGE = r"""<!DOCTYPE html>
<html>
<head>
<meta charset="utf-8">
<title>%TITLE%</title>
<style>
  html, body { margin: 0; height: 100%; font: 13px/1.35 system-ui, sans-serif; }
  #wrap { display: flex; height: 100vh; }
  #panel { width: 330px; overflow-y: auto; padding: 10px 12px; box-sizing: border-box; border-right: 1px solid #ccc; }
  #viewer { flex: 1; border: none; height: 100%; }
  h1 { font-size: 15px; margin: 0 0 8px; }
  .joint { margin: 6px 0; }
  .joint label { display: block; font-family: monospace; }
  .range { color: #777; }
  .row { display: flex; align-items: center; gap: 6px; }
  .row input { flex: 1; }
  .row output { width: 52px; text-align: right; font-family: monospace; }
  textarea { width: 100%; height: 92px; font-family: monospace; font-size: 12px; box-sizing: border-box; }
  button { margin: 2px 2px 2px 0; }
  #error { color: #b00; white-space: pre-wrap; }
</style>
</head>
<body>
<div id="wrap">
<div id="panel">
  <h1>%TITLE%</h1>
  <div>
    <button id="reset">reset to rest</button>
    camera:
    <button class="cam" data-view="front">front</button><button class="cam" data-view="side">side</button><button class="cam" data-view="top">top</button><button class="cam" data-view="iso">iso</button>
  </div>
  %ROWS%
  <p>Configuration (<code>--pose</code>; edit and apply, or paste on the command line):</p>
  <textarea id="pose" spellcheck="false"></textarea>
  <button id="apply">apply pose</button> <button id="copy">copy</button>
  <div id="error"></div>
  <p><a href="%MESHCAT%" target="_blank">open the meshcat viewer alone</a></p>
</div>
%FRAME%
</div>
<script>
"use strict";
const sliders = Array.from(document.querySelectorAll("input[type=range]"));
const poseBox = document.getElementById("pose");
const errorBox = document.getElementById("error");
let inFlight = false, pending = null;

function fmt(x) { return (Math.round(x * 1000) / 1000).toString(); }

function show(state) {
  for (const j of state.joints) {
    const s = document.getElementById("j-" + j.name);
    if (s && document.activeElement !== s) s.value = j.value;
    const o = document.getElementById("o-" + j.name);
    if (o) o.textContent = fmt(j.value);
  }
  if (document.activeElement !== poseBox) poseBox.value = state.pose;
}

async function post(path, body) {
  const res = await fetch(path, {method: "POST", headers: {"Content-Type": "application/json"},
                                 body: JSON.stringify(body || {})});
  const data = await res.json();
  if (!res.ok) { errorBox.textContent = data.error || res.statusText; return null; }
  errorBox.textContent = "";
  show(data);
  return data;
}

async function pump() {
  if (inFlight || pending === null) return;
  const job = pending; pending = null; inFlight = true;
  try { await post("/joint", job); } catch (e) { errorBox.textContent = String(e); }
  inFlight = false;
  pump();
}

for (const s of sliders) {
  s.addEventListener("input", () => {
    document.getElementById("o-" + s.dataset.joint).textContent = fmt(parseFloat(s.value));
    pending = {name: s.dataset.joint, value: parseFloat(s.value)};
    pump();
  });
}
document.getElementById("reset").addEventListener("click", () => post("/reset"));
document.getElementById("apply").addEventListener("click", () => { poseBox.blur(); post("/pose", {pose: poseBox.value}); });
document.getElementById("copy").addEventListener("click", () => { poseBox.select(); document.execCommand("copy"); });
for (const b of document.querySelectorAll("button.cam")) {
  b.addEventListener("click", () => post("/camera", {view: b.dataset.view}));
}
// /?pose=name=deg,name=deg moves those sliders as a user would (input events), e.g. a shared link
function slidersFromQuery() {
  const pose = new URLSearchParams(location.search).get("pose");
  if (!pose) return;
  for (const item of pose.split(/[\s,;]+/).filter(x => x)) {
    const [name, deg] = item.split("=");
    const s = document.getElementById("j-" + name);
    if (!s || isNaN(parseFloat(deg))) { errorBox.textContent = "?pose: cannot set '" + item + "'"; continue; }
    s.value = deg;
    s.dispatchEvent(new Event("input"));
  }
}
fetch("/state").then(r => r.json()).then(state => { show(state); slidersFromQuery(); });
</script>
</body>
</html>
"""
