"""An independent reading of BVH for the tests: a small parser of well-formed files and
forward kinematics written out with rotation matrices, sharing no code with kms2pin.bvh.

A joint's frame is F_J = F_parent Trans(t_J) R_J: t_J its OFFSET with the components that
it has position channels for replaced by their values, R_J the product of its rotation
channels in the order the file lists them (``Zrotation Yrotation Xrotation``: Rz Ry Rx)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np


def _axis(letter: str, degrees: float) -> np.ndarray:
    c, s = math.cos(math.radians(degrees)), math.sin(math.radians(degrees))
    if letter == "X":
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    if letter == "Y":
        return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


class Bvh:
    """``joints``: name -> (parent name or None, offset, channels); ``ends``: joint name ->
    End Site offsets; ``frames``: (T, channels); ``frame_time``."""

    def __init__(self, text: str):
        self.joints: dict[str, list] = {}
        self.ends: dict[str, list] = {}
        head, motion = text.split("MOTION", 1)
        words = head.replace("{", " { ").replace("}", " } ").split()[1:]  # after HIERARCHY
        stack: list = []
        current = None
        k = 0
        while k < len(words):
            word = words[k]
            if word in ("ROOT", "JOINT"):  # the name: every word up to the brace
                end = words.index("{", k)
                current = " ".join(words[k + 1 : end])
                self.joints[current] = [stack[-1] if stack else None, None, ()]
                self.ends[current] = []
                k = end
                continue
            if word == "End":  # End Site
                current, k = ("end", stack[-1]), k + 2
                continue
            if word == "{":
                stack.append(current)
            elif word == "}":
                stack.pop()
            elif word == "OFFSET":
                offset = np.array([float(x) for x in words[k + 1 : k + 4]])
                if isinstance(current, tuple):
                    self.ends[current[1]].append(offset)
                else:
                    self.joints[current][1] = offset
                k += 3
            elif word == "CHANNELS":
                n = int(words[k + 1])
                self.joints[current][2] = tuple(words[k + 2 : k + 2 + n])
                k += 1 + n
            k += 1
        lines = iter(motion.splitlines()[1:])
        self.frames_declared = int(next(lines).split(":")[1])
        self.frame_time = float(next(lines).split(":")[1])
        self.frames = np.array([[float(x) for x in line.split()] for line in lines if line.strip()])

    @classmethod
    def read(cls, path: str | Path) -> Bvh:
        return cls(Path(path).read_text())

    def world(self, frame: int, scale: float = 1.0, turn: np.ndarray | None = None):
        """Every joint's world point and rotation, and every End Site's point (name ->
        list), at ``frame``; lengths times ``scale``, then turned by ``turn`` (a rotation matrix)."""
        turn = np.eye(3) if turn is None else turn
        values = iter(self.frames[frame])
        points, rotations = {}, {}
        for name, (parent, offset, channels) in self.joints.items():
            t = offset.copy()
            R = np.eye(3)
            for channel in channels:
                v = next(values)
                if channel.endswith("position"):
                    t["XYZ".index(channel[0])] = v
                else:
                    R = R @ _axis(channel[0], v)
            if parent is None:
                points[name], rotations[name] = t, R
            else:
                points[name] = points[parent] + rotations[parent] @ t
                rotations[name] = rotations[parent] @ R
        ends = {n: [turn @ (scale * (points[n] + rotations[n] @ e)) for e in es] for n, es in self.ends.items()}
        return ({n: turn @ (scale * p) for n, p in points.items()},
                {n: turn @ R @ turn.T for n, R in rotations.items()}, ends)

    def rest_height(self, scale: float = 1.0, up: int = 1) -> float:
        """The vertical extent (along axis ``up``) of the joints and End Sites at rest (every channel 0)."""
        saved = self.frames
        self.frames = np.zeros((1, saved.shape[1] if saved.size else sum(len(j[2]) for j in self.joints.values())))
        try:
            points, _, ends = self.world(0, scale)
        finally:
            self.frames = saved
        ys = [p[up] for p in points.values()] + [e[up] for es in ends.values() for e in es]
        return max(ys) - min(ys)
