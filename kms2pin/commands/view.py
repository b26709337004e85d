"""Show a model in meshcat with joint sliders (the thesis's GUI, §3.2.3), or write
a standalone HTML page / a PNG picture of it.

Without --no-serve, a meshcat server and a joint-control page are started on
127.0.0.1 (this machine only; --host to listen elsewhere) and their URLs printed; the command then runs until interrupted
(Ctrl-C).  --pose takes joint coordinates: revolute angles in degrees, e.g.
--pose leftThigh_hip=60 leftShin_knee=40; a spherical joint's X-Y-Z angles in
degrees as three coordinates, e.g. --pose hip_x=20 hip_y=-10 hip_z=5; a prismatic
joint's offset in spec length units, e.g. --pose carriage_rail=0.25 (the control
page shows the current configuration in this form).
"""

from __future__ import annotations

import argparse
import re
import signal
import socket
import sys
import time

from ..errors import UsageError
from ..robot import Robot
from ._common import add_spec_argument, number, read_model

NAME = "view"
HELP = "show a model in meshcat with joint sliders, or write --html / --png pictures"


def _size(text: str) -> tuple[int, int]:
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    if not m or not (16 <= int(m[1]) <= 8192 and 16 <= int(m[2]) <= 8192):
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT between 16 and 8192 pixels, not '{text}'")
    return int(m[1]), int(m[2])


def add_arguments(p: argparse.ArgumentParser) -> None:
    from ..viewer.scene import VIEWS

    add_spec_argument(p)
    p.add_argument("--pose", nargs="+", action="extend", default=[], metavar="JOINT=VALUE",
                   help="joint coordinates: revolute angles and a spherical joint's X-Y-Z angles "
                        "(JOINT_x, JOINT_y, JOINT_z) in degrees, prismatic offsets in spec length units "
                        "(default: the spec's rest pose)")
    p.add_argument("--html", metavar="OUT.html", help="write a standalone page (opens without a server)")
    p.add_argument("--png", metavar="OUT.png", help="write a picture (headless Chromium)")
    p.add_argument("--size", type=_size, default=(800, 800), metavar="WxH",
                   help="picture size for --png (default 800x800)")
    p.add_argument("--camera", choices=tuple(VIEWS), default="front",
                   help="front (along +z, y up), side (along -x), top (down -y) or iso (default: front)")
    p.add_argument("--root", choices=("spec", "free"), default="spec",
                   help="'free': replace the joint to the inertial frame by a floating base")
    p.add_argument("--system", help="which rigidBodySystem, if the spec has several")
    p.add_argument("--no-serve", action="store_true", help="only write --html/--png, start no server")
    p.add_argument("--port", type=number(0, 65535, whole=True), default=0,
                   help="port of the joint-control page (default: any free port)")
    p.add_argument("--host", default="127.0.0.1", metavar="ADDRESS",
                   help="address the meshcat viewer and the joint-control page listen on (default 127.0.0.1: "
                        "this machine only; another one, e.g. 0.0.0.0, lets other machines see and move the "
                        "model, and a warning says so)")


def _check_host(host: str) -> None:
    """UsageError unless this machine can listen on ``host`` (an address of one of its
    interfaces, or a name for one), before any server is started and waited for."""
    try:
        infos = socket.getaddrinfo(host, 0, type=socket.SOCK_STREAM)
    except (socket.gaierror, UnicodeError) as err:
        raise UsageError(f"--host {host!r}: not an address or a known host name ({err})") from None
    for family, kind, proto, _, address in infos:
        try:
            with socket.socket(family, kind, proto) as s:
                s.bind(address)
                return
        except OSError as err:
            why = err.strerror or str(err)
    raise UsageError(f"--host {host!r}: not an address of this machine ({why}); 127.0.0.1 is this machine only, "
                     "0.0.0.0 every interface")


def run(args: argparse.Namespace) -> int:
    from ..viewer import JointControl, PoseError, RobotView, parse_pose
    from ..viewer._meshcat_server import is_loopback

    if args.no_serve and not (args.html or args.png):
        raise UsageError("--no-serve needs --html or --png (there is nothing else to do)")
    spec = read_model(args.spec)
    robot = Robot(spec, spec.system(args.system), args.root)
    try:
        q = parse_pose(robot, args.pose or None)
    except PoseError as err:
        raise UsageError(f"--pose: {err}") from None
    width, height = args.size
    aspect = width / height if args.png else 16 / 10
    if not args.no_serve:
        _check_host(args.host)
    if not args.no_serve and not is_loopback(args.host):
        print(f"warning: --host {args.host}: the viewer and the joint-control page are open to other machines "
              "on the network (anyone who reaches them can see and move the model)", file=sys.stderr)
    view = RobotView(robot, q, camera=args.camera, aspect=aspect, serve=not args.no_serve, host=args.host)
    control = None
    try:
        if args.html:
            print(f"wrote {view.write_html(args.html)}")
        if args.png:
            print(f"wrote {view.write_png(args.png, width, height)}")
        if args.no_serve:
            return 0
        if args.png:
            view.camera(args.camera, 16 / 10)
        control = JointControl(robot, view, host=args.host, port=args.port)
        _serve_until_interrupted([f"meshcat viewer:  {view.url}", f"joint control:   {control.url}",
                                  "press Ctrl-C to stop"])
        return 0
    finally:
        if control is not None:
            control.close()
        view.close()


def _serve_until_interrupted(ready: list[str]) -> None:
    """Print the ``ready`` lines, then serve until Ctrl-C or SIGTERM.  The SIGTERM handler
    is in place before the lines go out: a supervisor that stops the viewer as soon as it
    reads them gets a clean stop (exit 0, the servers closed), not a kill."""

    def on_term(signum, frame):
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, on_term)
    try:
        print("\n".join(ready), flush=True)
        while True:
            time.sleep(0.5)
    except KeyboardInterrupt:
        print("stopped", file=sys.stderr)
    finally:
        signal.signal(signal.SIGTERM, previous)
