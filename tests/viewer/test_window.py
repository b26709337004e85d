"""meshcat windows: the server-less recording window exports what the server does,
and the server is really stopped."""

from __future__ import annotations

import numpy as np

from kms2pin.viewer import RobotView, new_visualizer, visualizer
from kms2pin.viewer.render import for_screenshot

from ._util import page_commands, without_uuids


def test_recording_window_exports_the_same_scene_as_the_server(lowerbody):
    with visualizer(serve=True) as served:
        proc = served.window.server_proc
        assert proc.stderr is None, "the server's stderr is not a pipe nobody reads"
        recorded = new_visualizer(serve=False)
        views = [RobotView(lowerbody, vis=v, camera="side") for v in (served, recorded)]
        for v in views:
            v.set_configuration(lowerbody.random_configuration(np.random.default_rng(0), 40))
        a, b = (without_uuids(page_commands(v.static_html())) for v in views)
        assert a == b and len(a) > 3 * len(lowerbody.bodies)
    assert proc.poll() is not None, "the context manager stops the server"


def test_close_is_idempotent_and_views_own_their_server(lowerbody):
    view = RobotView(lowerbody, serve=True)
    proc = view.vis.window.server_proc
    assert view.url.startswith("http://127.0.0.1:")
    view.close()
    view.close()
    assert proc.poll() is not None
    offline = RobotView(lowerbody)
    assert offline.url is None
    offline.close()


def test_screenshot_page_hides_meshcat_controls():
    html = "<html><body><div></div></body></html>"
    out = for_screenshot(html)
    assert ".dg.ac" in out and out.index(".dg.ac") < out.index("</body>")


def test_server_keeps_answering_after_many_browser_connections():
    """meshcat's own launcher pipes the server's stderr and never reads it: the
    server logs every websocket connection there and blocks for good after a few
    hundred.  Ours discards stderr."""
    import asyncio

    from tornado.websocket import websocket_connect

    async def connect(url: str, n: int) -> None:
        for _ in range(n):
            ws = await websocket_connect(url)
            ws.close()

    with visualizer(serve=True) as vis:
        url = vis.window.web_url.replace("http://", "ws://").replace("/static/", "/")
        asyncio.run(asyncio.wait_for(connect(url, 1000), 60))
        vis["probe"].set_transform(np.eye(4))  # raises ViewerError after the window's timeout if stuck
        assert "MeshCat" in vis.static_html()


def test_written_files_get_normal_permissions(tmp_path):
    import os

    from kms2pin.viewer.render import write_html

    path = write_html("<html></html>", tmp_path / "page.html")
    umask = os.umask(0)
    os.umask(umask)
    assert path.stat().st_mode & 0o777 == 0o666 & ~umask
