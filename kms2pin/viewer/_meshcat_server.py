"""meshcat's server, kept local and tied to its parent (run in a child process by
:class:`kms2pin.viewer._window.ServerWindow`).

``meshcat.servers.zmqserver`` listens on every interface (``app.listen(port)`` with
no address: ``0.0.0.0`` and ``[::]``) while it prints ``127.0.0.1`` in its URL, and
lives on when the process that started it is killed.  This runs the same bridge,
but:

- its web server listens on ``HOST`` only (127.0.0.1 unless asked otherwise), and
  its ZeroMQ command socket on 127.0.0.1 whatever ``HOST`` is;
- bound to a loopback address, it answers only requests whose ``Host`` is its own
  address (``127.0.0.1:PORT`` or ``localhost:PORT``) and websockets whose ``Origin``
  is that too: a page of another site, even under a DNS name rebound to 127.0.0.1,
  gets 403;
- a watchdog thread ends the process once its parent (``PARENT_PID``) is gone,
  however the parent died (SIGKILL included): it polls ``os.getppid()``, which
  changes when the parent dies.

Usage: ``main([HOST, PARENT_PID])``; prints ``zmq_url=...`` and ``web_url=...`` as
meshcat's server does.
"""

from __future__ import annotations

import ipaddress
import os
import threading
import time

WATCH_INTERVAL = 0.2  # seconds between two looks at the parent


def _watch(parent: int) -> None:
    while os.getppid() == parent:
        time.sleep(WATCH_INTERVAL)
    os._exit(0)


def is_loopback(host: str) -> bool:
    """True for 127.x.x.x, ::1 and 'localhost'."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def own_hosts(host: str, port: int) -> set[str]:
    """The ``Host`` values a browser sends to ``host:port`` bound on loopback."""
    names = {host, "localhost", "127.0.0.1"} if host != "::1" else {"[::1]", "localhost"}
    return {f"{n}:{port}" for n in names}


def main(argv: list[str]) -> int:
    host, parent = argv[0], int(argv[1])
    if os.getppid() != parent:  # the parent died before this started
        return 0
    threading.Thread(target=_watch, args=(parent,), name="parent-watchdog", daemon=True).start()

    import warnings
    from urllib.parse import urlsplit

    with warnings.catch_warnings():  # meshcat's server module imports a deprecated pyzmq API
        warnings.simplefilter("ignore", DeprecationWarning)
        import tornado.web
        from meshcat.servers import zmqserver as z

    local = is_loopback(host)

    def allowed(bridge, request_host: str | None) -> bool:
        return not local or (request_host or "").lower() in own_hosts(host, bridge.fileserver_port)

    class Static(z.StaticFileHandlerNoCache):
        def prepare(self):
            if not allowed(self.bridge, self.request.host):
                raise tornado.web.HTTPError(403)

        def initialize(self, bridge=None, **kw):
            self.bridge = bridge
            super().initialize(**kw)

    class WebSocket(z.WebSocketHandler):
        def check_origin(self, origin: str) -> bool:
            return allowed(self.bridge, self.request.host) and allowed(self.bridge, urlsplit(origin).netloc)

    class Bridge(z.ZMQWebSocketBridge):
        def setup_zmq(self, url: str):  # the command socket stays on loopback, whatever HOST is
            return super().setup_zmq(url.replace(f"//{self.host}:", "//127.0.0.1:"))

        def make_app(self):
            app = tornado.web.Application([
                (r"/static/(.*)", Static, {"path": z.VIEWER_ROOT, "default_filename": z.VIEWER_HTML, "bridge": self}),
                (r"/", WebSocket, {"bridge": self}),
            ])
            listen = app.listen
            app.listen = lambda port, **kw: listen(port, address=self.host, **kw)
            return app

    bridge = Bridge(host=host)
    print(f"zmq_url={bridge.zmq_url}")
    print(f"web_url={bridge.web_url}", flush=True)
    try:
        bridge.run()
    except KeyboardInterrupt:
        pass
    return 0
