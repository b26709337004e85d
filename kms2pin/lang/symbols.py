"""What the analysis of a spec works with: values that already failed (:data:`POISON`),
the error a statement raises (:class:`Fail`), scopes and their symbols, the bodies, bound
vectors, systems and joints being built, and the :class:`Reporter` that collects the
diagnostics with the body-function calls they happened in."""

from __future__ import annotations

from dataclasses import dataclass, field

from ..errors import Diagnostic
from ..model import Loc


class Poison:
    """The value of an expression that already produced an error."""

    def __repr__(self) -> str:
        return "<poison>"


POISON = Poison()


class Fail(Exception):
    def __init__(self, loc: Loc, message: str):
        self.loc, self.message = loc, message


Calls = tuple[tuple[Loc, str], ...]  # body-function calls being run, innermost first: (call site, note)


# the accepted ranges (docs/language.md, 'Numbers'): semi-axes in [MIN_LENGTH, MAX_LENGTH],
# bound-vector positions and prismatic offsets within +-MAX_LENGTH.  Larger bodies overflow
# the URDF's inertia (mass ~ a b c, inertia ~ m a^2), smaller ones underflow it to zero.
MAX_LENGTH = 1e6
MIN_LENGTH = 1e-6


# --- things being built


@dataclass
class BvecB:
    name: str
    loc: Loc
    body: BodyB | None
    pos: tuple | None = None
    pos_loc: Loc | None = None
    orient: tuple | None = None
    orient_loc: Loc | None = None
    poisoned: bool = False
    calls: Calls = ()  # the calls that ran its definition


@dataclass
class BodyB:
    name: str
    loc: Loc
    system: SystemB
    inner: tuple | None = None
    inner_loc: Loc | None = None
    outer: tuple | None = None
    outer_loc: Loc | None = None
    bvecs: dict[str, BvecB] = field(default_factory=dict)
    poisoned: bool = False  # broken: no message about it, and references to it are silent
    failed: bool = False  # a statement in it failed: no "has no innerLam" echo
    calls: Calls = ()  # where its name is
    def_calls: Calls = ()  # inside its braces: one call more for an instantiated body


@dataclass
class SystemB:
    name: str
    loc: Loc
    bodies: dict[str, BodyB] = field(default_factory=dict)


@dataclass
class JointB:
    kind: str
    ends: tuple[BvecB, BvecB]
    angle: float
    loc: Loc
    end_locs: tuple[Loc, Loc]
    limits: tuple[float, float] | None = None
    rotation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    offset: float = 0.0
    value_loc: Loc | None = None  # the rest value's argument, if given


@dataclass
class Sym:
    kind: str  # var | body | bvec | func | system
    loc: Loc
    type: str = ""
    value: object = None
    scope: Scope | None = None  # for body functions: the defining scope


class Scope:
    def __init__(self, parent: Scope | None = None):
        self.parent = parent
        self.names: dict[str, Sym] = {}

    def lookup(self, name: str) -> Sym | None:
        s: Scope | None = self
        while s is not None:
            if name in s.names:
                return s.names[name]
            s = s.parent
        return None

    def snapshot(self) -> Scope:
        """The names declared so far (C++: a function sees what is declared before it).
        The symbols are shared, so later assignments to them are still seen."""
        copy = Scope(self.parent.snapshot() if self.parent is not None else None)
        copy.names = dict(self.names)
        return copy

    def visible(self, kind: str | None = None) -> list[str]:
        out: list[str] = []
        s: Scope | None = self
        while s is not None:
            out.extend(n for n, sym in s.names.items() if kind is None or sym.kind == kind)
            s = s.parent
        return out


@dataclass
class Ctx:
    """Where a statement runs: 'top', 'system', 'body' or 'bvec'."""

    where: str
    system: SystemB | None = None
    body: BodyB | None = None
    bvec: BvecB | None = None


KIND_WORDS = {
    "var": "a variable",
    "body": "a body",
    "bvec": "a bound vector",
    "func": "a body function",
    "system": "a rigidBodySystem",
}


class Reporter:
    """The diagnostics of one spec: each error with a note per body-function call it
    happened in; ``calls`` are the calls being run, innermost first."""

    def __init__(self, text: str, path: str):
        self.path = path
        self.lines = text.splitlines()
        self.diags: list[list[Diagnostic]] = []  # each error with its notes
        self.calls: Calls = ()

    def error(self, loc: Loc, message: str, calls: Calls | None = None) -> None:
        """Record an error, followed by one note per body-function call it happened in
        (by default the calls being run)."""
        notes = [self.diagnostic(at, note, "note") for at, note in (self.calls if calls is None else calls)]
        self.diags.append([self.diagnostic(loc, message), *notes])

    def diagnostic(self, loc: Loc, message: str, severity: str = "error") -> Diagnostic:
        line = max(loc.line, 1)
        src = self.lines[line - 1] if line <= len(self.lines) else ""
        return Diagnostic(self.path, line, max(loc.column, 1), message, src, severity)
