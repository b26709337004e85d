"""Abstract syntax of the model language; every node carries its source location."""

from __future__ import annotations

from dataclasses import dataclass

from ..model import Loc


@dataclass(frozen=True)
class Node:
    loc: Loc


# --- expressions


@dataclass(frozen=True)
class Number(Node):
    value: float


@dataclass(frozen=True)
class Bool(Node):
    value: bool


@dataclass(frozen=True)
class Name(Node):
    """A possibly dotted name: ``x``, ``body.bvec`` or ``system.body.bvec``."""

    parts: tuple[str, ...]
    part_locs: tuple[Loc, ...]

    @property
    def text(self) -> str:
        return ".".join(self.parts)


@dataclass(frozen=True)
class Call(Node):
    func: str
    args: tuple[Node, ...]


@dataclass(frozen=True)
class BinOp(Node):
    op: str
    left: Node
    right: Node


@dataclass(frozen=True)
class UnOp(Node):
    op: str
    operand: Node


@dataclass(frozen=True)
class Cond(Node):
    test: Node
    then: Node
    other: Node


# --- statements


@dataclass(frozen=True)
class VarDecl(Node):
    type: str
    name: str
    name_loc: Loc
    init: Node | None


@dataclass(frozen=True)
class Assign(Node):
    name: str
    op: str
    value: Node


@dataclass(frozen=True)
class If(Node):
    test: Node
    then: Node
    other: Node | None


@dataclass(frozen=True)
class Block(Node):
    body: tuple[Node, ...]


@dataclass(frozen=True)
class CallStmt(Node):
    """``innerLam(...)``, ``outerLam(...)``, ``pos(...)``, ``orient(...)``."""

    func: str
    args: tuple[Node, ...]


@dataclass(frozen=True)
class BvecDef(Node):
    name: str
    name_loc: Loc
    body: tuple[Node, ...]


@dataclass(frozen=True)
class BodyLiteral(Node):
    name: str
    name_loc: Loc
    body: tuple[Node, ...]


@dataclass(frozen=True)
class Param(Node):
    type: str
    name: str


@dataclass(frozen=True)
class BodyFuncDef(Node):
    name: str
    name_loc: Loc
    params: tuple[Param, ...]
    body: tuple[Node, ...]


@dataclass(frozen=True)
class BodyInstance(Node):
    func: str
    name: str
    name_loc: Loc
    args: tuple[Node, ...]


@dataclass(frozen=True)
class SystemDef(Node):
    name: str
    name_loc: Loc
    body: tuple[Node, ...]


@dataclass(frozen=True)
class Constraint(Node):
    kind: str
    kind_loc: Loc
    args: tuple[Node, ...]


@dataclass(frozen=True)
class Empty(Node):
    pass
