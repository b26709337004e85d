"""The local servers are local and answer only their own page (real sockets, real processes).

``kms2pin view`` starts a meshcat server and the joint-control page: both listen on
127.0.0.1 only (read from the kernel's socket table), and both are gone within
seconds of ``view`` being killed with SIGKILL.  The control page refuses a foreign
``Host`` or ``Origin`` (403), a missing, bad or too large ``Content-Length`` without
reading the body (411, 400, 413), and malformed JSON (400), and stays up; meshcat's
own page and websocket refuse a foreign ``Host`` or ``Origin`` too.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from urllib.parse import urlsplit

import pytest

from kms2pin.viewer import JointControl

from ._util import load

pytestmark = pytest.mark.skipif(not os.path.exists("/proc/net/tcp"), reason="reads Linux's socket table")


def listening_addresses(port: int) -> set[str]:
    """The local addresses with a TCP socket listening on ``port`` (IPv4 and IPv6)."""
    found = set()
    for table, width in (("/proc/net/tcp", 8), ("/proc/net/tcp6", 32)):
        if not os.path.exists(table):
            continue
        with open(table) as f:
            for line in f.readlines()[1:]:
                fields = line.split()
                address, hex_port = fields[1].split(":")
                if fields[3] == "0A" and int(hex_port, 16) == port:  # 0A: LISTEN
                    raw = bytes.fromhex(address)
                    if width == 8:
                        found.add(socket.inet_ntop(socket.AF_INET, raw[::-1]))
                    else:  # four little-endian 32-bit words
                        words = b"".join(raw[i : i + 4][::-1] for i in range(0, 16, 4))
                        found.add(socket.inet_ntop(socket.AF_INET6, words))
    return found


def request(port: int, head: str, body: bytes = b"", shut: bool = False, timeout: float = 5.0) -> tuple[int, str]:
    """Send ``head`` (request line and headers, without the blank line) and ``body`` on a
    raw socket; (status, body of the answer).  ``shut``: close our side after sending."""
    if "\nConnection:" not in head:
        head += "\nConnection: close"
    with socket.create_connection(("127.0.0.1", port), timeout=timeout) as s:
        s.sendall(head.replace("\n", "\r\n").encode() + b"\r\n\r\n" + body)
        if shut:
            s.shutdown(socket.SHUT_WR)
        data = b""
        while True:
            chunk = s.recv(65536)
            if not chunk:
                break
            data += chunk
    status = int(data.split(b" ", 2)[1])
    return status, data.split(b"\r\n\r\n", 1)[1].decode("utf-8", "replace")


def post(port: int, path: str, body: bytes, host: str | None = None, extra: str = "") -> tuple[int, str]:
    host = host or f"127.0.0.1:{port}"
    head = f"POST {path} HTTP/1.1\nHost: {host}\nContent-Type: application/json\nContent-Length: {len(body)}{extra}"
    return request(port, head, body)


@pytest.fixture(scope="module")
def control():
    ctl = JointControl(load("lowerbody"))
    try:
        yield ctl
    finally:
        ctl.close()


@pytest.fixture
def port(control) -> int:
    return urlsplit(control.url).port


def test_the_control_page_answers_its_own_address(control, port):
    assert request(port, f"GET /state HTTP/1.1\nHost: 127.0.0.1:{port}")[0] == 200
    assert request(port, f"GET /state HTTP/1.1\nHost: localhost:{port}")[0] == 200


@pytest.mark.parametrize("headers", [
    "Host: attacker.example:{port}",  # a DNS name rebound to 127.0.0.1
    "Host: 127.0.0.1:{port}\nOrigin: http://attacker.example",
    "Host: 127.0.0.1:{port}\nOrigin: http://127.0.0.1:1",  # another local page
])
def test_a_foreign_host_or_origin_is_refused(control, port, headers):
    hdrs = headers.format(port=port)
    status, body = request(port, f"GET /state HTTP/1.1\n{hdrs}")
    assert status == 403 and "error" in json.loads(body)
    q = control.q
    status, _ = request(port, f"POST /joint HTTP/1.1\n{hdrs}\nContent-Length: 36", b'{"name": "leftShin_knee", "deg": 77}')
    assert status == 403
    assert (control.q == q).all()  # nothing moved


def test_a_post_from_the_page_itself_is_served(control, port):
    status, body = post(port, "/joint", b'{"name": "leftShin_knee", "deg": 12}', extra=f"\nOrigin: http://127.0.0.1:{port}")
    assert status == 200
    assert {j["name"]: j["deg"] for j in json.loads(body)["joints"]}["leftShin_knee"] == pytest.approx(12)


@pytest.mark.parametrize("length, status", [("-1", 400), ("abc", 400), ("1e3", 400), ("300000000", 413)])
def test_a_bad_or_huge_content_length_is_refused_without_reading(control, port, length, status):
    t0 = time.monotonic()
    got, body = request(port, f"POST /joint HTTP/1.1\nHost: 127.0.0.1:{port}\nContent-Length: {length}")
    assert got == status, body
    assert time.monotonic() - t0 < 3  # answered at once: nothing was waited for or read
    assert request(port, f"GET /state HTTP/1.1\nHost: 127.0.0.1:{port}")[0] == 200


@pytest.mark.parametrize("header", ["", "\nTransfer-Encoding: chunked"])
def test_a_missing_content_length_is_length_required(control, port, header):
    status, body = request(port, f"POST /reset HTTP/1.1\nHost: 127.0.0.1:{port}{header}")
    assert status == 411 and "Content-Length" in json.loads(body)["error"]


def test_a_body_shorter_than_its_length_is_refused(control, port):
    status, body = request(port, f"POST /reset HTTP/1.1\nHost: 127.0.0.1:{port}\nContent-Length: 10", b"{}",
                           shut=True)
    assert status == 400 and "shorter" in json.loads(body)["error"]


@pytest.mark.parametrize("body, message", [
    (b"{not json", "not valid JSON"),
    (b"[" * 30000 + b"]" * 30000, "nested too deeply"),
    (b"\xff\xfe", "not UTF-8"),
    (b"[1, 2]", "expected a JSON object"),
    (b'{"name": 5, "deg": 1}', "'name' must be a string"),
    (b'{"name": "leftShin_knee", "deg": true}', "'deg' must be a number"),
    (b'{"name": "leftShin_knee", "deg": 1e999}', "must be finite"),
])
def test_malformed_json_is_400_and_the_page_stays_up(control, port, body, message, capfd):
    status, answer = post(port, "/joint", body)
    assert status == 400 and message in json.loads(answer)["error"]
    assert request(port, f"GET /state HTTP/1.1\nHost: 127.0.0.1:{port}")[0] == 200
    assert "Traceback" not in capfd.readouterr().err


@pytest.mark.parametrize("path, body, message", [
    ("/pose", b'{"pose": 3}', "'pose' must be a string"),
    ("/camera", b'{"view": []}', "'view' must be a string"),
])
def test_wrong_types_are_400(control, port, path, body, message):
    status, answer = post(port, path, body)
    assert status == 400 and message in json.loads(answer)["error"]


def test_meshcat_answers_only_its_own_address(control):
    url = urlsplit(control.meshcat_url)
    mport = url.port
    assert listening_addresses(mport) == {"127.0.0.1"}
    assert listening_addresses(urlsplit(control.vis.window.zmq_url).port) == {"127.0.0.1"}  # its command socket
    assert request(mport, f"GET /static/ HTTP/1.1\nHost: 127.0.0.1:{mport}")[0] == 200
    assert request(mport, f"GET /static/ HTTP/1.1\nHost: attacker.example:{mport}")[0] == 403
    upgrade = (f"GET / HTTP/1.1\nHost: 127.0.0.1:{mport}\nUpgrade: websocket\nConnection: Upgrade\n"
               "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\nSec-WebSocket-Version: 13")
    for origin, status in ((f"http://127.0.0.1:{mport}", b"101"), ("http://attacker.example", b"403")):
        with socket.create_connection(("127.0.0.1", mport), timeout=5) as s:
            s.sendall(f"{upgrade}\nOrigin: {origin}".replace("\n", "\r\n").encode() + b"\r\n\r\n")
            assert s.recv(100).startswith(b"HTTP/1.1 " + status)


def wait_closed(port: int, timeout: float = 10.0) -> float:
    """Seconds until nothing listens on ``port`` (fails after ``timeout``)."""
    t0 = time.monotonic()
    while listening_addresses(port):
        assert time.monotonic() - t0 < timeout, f"port {port} still listening after {timeout} s"
        time.sleep(0.05)
    return time.monotonic() - t0


@pytest.mark.slow
def test_view_listens_on_loopback_only_and_its_servers_die_with_it_on_sigkill(tmp_path):
    from conftest import SPECS

    proc = subprocess.Popen([sys.executable, "-m", "kms2pin.cli", "view", str(SPECS / "lowerbody.kms")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        lines = [proc.stdout.readline() for _ in range(2)]
        urls = dict(line.split(":", 1) for line in lines)
        meshcat = urlsplit(urls["meshcat viewer"].strip())
        page = urlsplit(urls["joint control"].strip())
        assert meshcat.hostname == page.hostname == "127.0.0.1"
        assert listening_addresses(meshcat.port) == {"127.0.0.1"}  # not 0.0.0.0, not [::]
        assert listening_addresses(page.port) == {"127.0.0.1"}
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    print(f"meshcat server gone {wait_closed(meshcat.port):.2f} s after SIGKILL of view")
    assert not listening_addresses(page.port)


@pytest.mark.slow
def test_view_host_option_listens_elsewhere_with_a_warning(tmp_path):
    from conftest import SPECS

    proc = subprocess.Popen([sys.executable, "-m", "kms2pin.cli", "view", str(SPECS / "lowerbody.kms"),
                             "--host", "0.0.0.0"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        lines = [proc.stdout.readline() for _ in range(2)]
        meshcat = urlsplit(lines[0].split(":", 1)[1].strip())
        assert listening_addresses(meshcat.port) == {"0.0.0.0"}
    finally:
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=30)
    assert "warning: --host 0.0.0.0: the viewer and the joint-control page are open to other machines" in err
    assert proc.returncode == 0
    wait_closed(meshcat.port)
