"""AST -> :class:`~kms2pin.model.ModelSpec`: evaluation, name resolution and every check.

The spec is executed once, top to bottom, like the thesis's compiler did (§3.1.1,
§3.2.1): variables follow C++ block scoping, body functions run in their own
scope (their parameters plus the scope they were defined in), and the kinematic
checks run when the whole file has been read.  Errors are collected, not
raised one at a time; a statement that fails leaves "poisoned" values behind so
one mistake does not cascade into many messages.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

import numpy as np

from ..errors import Diagnostic, SpecError, did_you_mean
from ..model import WORLD, Body, BoundVector, Joint, Loc, ModelSpec, System
from . import ast as A


class _Poison:
    """The value of an expression that already produced an error."""

    def __repr__(self) -> str:
        return "<poison>"


POISON = _Poison()


class _Fail(Exception):
    def __init__(self, loc: Loc, message: str):
        self.loc, self.message = loc, message


Calls = tuple[tuple[Loc, str], ...]  # body-function calls being run, innermost first: (call site, note)


# --- maths functions; trigonometry in degrees (thesis Display 4.4 uses cos(offsetAngle))

_D2R = math.pi / 180.0


# exact where the value is 0, +-1/2 or +-1, so that sin(30) == 0.5 and cos(90) == 0
# (then orient(cos(a), sin(a), 0) lies exactly on an axis for a = 0, 90, 180, ...)
_EXACT = {
    "sin": (360.0, {0.0: 0.0, 30.0: 0.5, 90.0: 1.0, 150.0: 0.5, 180.0: 0.0, 210.0: -0.5, 270.0: -1.0, 330.0: -0.5}),
    "cos": (360.0, {0.0: 1.0, 60.0: 0.5, 90.0: 0.0, 120.0: -0.5, 180.0: -1.0, 240.0: -0.5, 270.0: 0.0, 300.0: 0.5}),
    "tan": (180.0, {0.0: 0.0, 45.0: 1.0, 135.0: -1.0}),
}


def _trig(name: str, fn):
    period, table = _EXACT[name]

    def f(x: float) -> float:
        r = math.fmod(x, period)  # exact; |r| < period, sign of x
        key = r + period if r < 0 else r
        if key in table:
            return table[key]
        if name == "tan" and key == 90.0:
            raise ValueError("tan(90) is infinite")
        return fn(r * _D2R)

    return f


def _fn_table() -> dict[str, tuple[int, object]]:
    return {
        "sin": (1, _trig("sin", math.sin)),
        "cos": (1, _trig("cos", math.cos)),
        "tan": (1, _trig("tan", math.tan)),
        "asin": (1, lambda x: math.degrees(math.asin(x))),
        "acos": (1, lambda x: math.degrees(math.acos(x))),
        "atan": (1, lambda x: math.degrees(math.atan(x))),
        "atan2": (2, lambda y, x: math.degrees(math.atan2(y, x))),
        "sqrt": (1, math.sqrt),
        "abs": (1, abs),
        "fabs": (1, abs),
        "pow": (2, math.pow),
        "exp": (1, math.exp),
        "log": (1, math.log),
        "log10": (1, math.log10),
        "floor": (1, math.floor),
        "ceil": (1, math.ceil),
        "min": (2, min),
        "max": (2, max),
        "fmod": (2, math.fmod),
    }


FUNCTIONS = _fn_table()
STATEMENTS = {"innerLam": "body", "outerLam": "body", "pos": "bvec", "orient": "bvec"}
JOINT_KINDS = ("fixed", "revolute", "spherical", "prismatic")
# per joint type: argument counts, the signature shown, what each argument after the two
# ends is and its unit
_SIGNATURES = {
    "fixed": ((2,), "fixed(a, b)", (), ""),
    "revolute": (
        (2, 3, 5),
        "revolute(a, b[, defaultAngle[, lower, upper]])",
        ("a joint angle", "a lower joint limit", "an upper joint limit"),
        "degrees",
    ),
    "spherical": ((2, 5), "spherical(a, b[, rx, ry, rz])", ("a rotation vector component",) * 3, "degrees"),
    "prismatic": (
        (2, 3, 5),
        "prismatic(a, b[, offset[, lower, upper]])",
        ("a joint offset", "a lower joint limit", "an upper joint limit"),
        "spec length units",
    ),
}
# the accepted ranges (docs/language.md, 'Numbers'): semi-axes in [MIN_LENGTH, MAX_LENGTH],
# bound-vector positions and prismatic offsets within +-MAX_LENGTH.  Larger bodies overflow
# the URDF's inertia (mass ~ a b c, inertia ~ m a^2), smaller ones underflow it to zero.
MAX_LENGTH = 1e6
MIN_LENGTH = 1e-6


# --- things being built


@dataclass
class _BvecB:
    name: str
    loc: Loc
    body: _BodyB | None
    pos: tuple | None = None
    pos_loc: Loc | None = None
    orient: tuple | None = None
    orient_loc: Loc | None = None
    poisoned: bool = False
    calls: Calls = ()  # the calls that ran its definition


@dataclass
class _BodyB:
    name: str
    loc: Loc
    system: _SystemB
    inner: tuple | None = None
    inner_loc: Loc | None = None
    outer: tuple | None = None
    outer_loc: Loc | None = None
    bvecs: dict[str, _BvecB] = field(default_factory=dict)
    poisoned: bool = False  # broken: no message about it, and references to it are silent
    failed: bool = False  # a statement in it failed: no "has no innerLam" echo
    calls: Calls = ()  # where its name is
    def_calls: Calls = ()  # inside its braces: one call more for an instantiated body


@dataclass
class _SystemB:
    name: str
    loc: Loc
    bodies: dict[str, _BodyB] = field(default_factory=dict)


@dataclass
class _JointB:
    kind: str
    ends: tuple[_BvecB, _BvecB]
    angle: float
    loc: Loc
    end_locs: tuple[Loc, Loc]
    limits: tuple[float, float] | None = None
    rotation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    offset: float = 0.0
    value_loc: Loc | None = None  # the rest value's argument, if given


@dataclass
class _Sym:
    kind: str  # var | body | bvec | func | system
    loc: Loc
    type: str = ""
    value: object = None
    scope: _Scope | None = None  # for body functions: the defining scope


class _Scope:
    def __init__(self, parent: _Scope | None = None):
        self.parent = parent
        self.names: dict[str, _Sym] = {}

    def lookup(self, name: str) -> _Sym | None:
        s: _Scope | None = self
        while s is not None:
            if name in s.names:
                return s.names[name]
            s = s.parent
        return None

    def snapshot(self) -> _Scope:
        """The names declared so far (C++: a function sees what is declared before it).
        The symbols are shared, so later assignments to them are still seen."""
        copy = _Scope(self.parent.snapshot() if self.parent is not None else None)
        copy.names = dict(self.names)
        return copy

    def visible(self, kind: str | None = None) -> list[str]:
        out: list[str] = []
        s: _Scope | None = self
        while s is not None:
            out.extend(n for n, sym in s.names.items() if kind is None or sym.kind == kind)
            s = s.parent
        return out


@dataclass
class _Ctx:
    """Where a statement runs: 'top', 'system', 'body' or 'bvec'."""

    where: str
    system: _SystemB | None = None
    body: _BodyB | None = None
    bvec: _BvecB | None = None


_KIND_WORDS = {
    "var": "a variable",
    "body": "a body",
    "bvec": "a bound vector",
    "func": "a body function",
    "system": "a rigidBodySystem",
}


class Analyzer:
    """Runs a parsed spec and builds its :class:`ModelSpec` (raises SpecError)."""

    def __init__(self, text: str, path: str):
        self.path = path
        self.text = text
        self.lines = text.splitlines()
        self.diags: list[list[Diagnostic]] = []  # each error with its notes
        self.systems: list[_SystemB] = []
        self.inertial: dict[str, _BvecB] = {}
        self.joints: list[_JointB] = []
        self.constraint_failed = False  # then reachability errors would only echo it
        self.dry = 0  # > 0: only type-check (the operand a short circuit or '?:' skips)
        self.calls: Calls = ()

    # ---------------------------------------------------------------- errors
    def error(self, loc: Loc, message: str, calls: Calls | None = None) -> None:
        """Record an error, followed by one note per body-function call it happened in
        (by default the calls being run)."""
        notes = [self.diagnostic(at, note, "note") for at, note in (self.calls if calls is None else calls)]
        self.diags.append([self.diagnostic(loc, message), *notes])

    def diagnostic(self, loc: Loc, message: str, severity: str = "error") -> Diagnostic:
        line = max(loc.line, 1)
        src = self.lines[line - 1] if line <= len(self.lines) else ""
        return Diagnostic(self.path, line, max(loc.column, 1), message, src, severity)

    # ---------------------------------------------------------------- driver
    def run(self, stmts: tuple[A.Node, ...]) -> ModelSpec:
        top = _Scope()
        self.exec_block(stmts, top, _Ctx("top"))
        systems = self.finish()
        if not self.diags and not systems:
            self.error(Loc(1, 1), "the spec defines no rigidBodySystem")
        if self.diags:
            # a body function runs once per instantiation: report each mistake in it once,
            # with the notes of the first call that made it
            unique: dict[tuple, list[Diagnostic]] = {}
            for error, *notes in self.diags:
                unique.setdefault((error.line, error.column, error.message), [error, *notes])
            ordered = sorted(unique.values(), key=lambda ds: (ds[0].line, ds[0].column))
            raise SpecError([d for ds in ordered for d in ds])
        inertial = {n: self.freeze_bvec(b) for n, b in self.inertial.items()}
        return ModelSpec(tuple(systems), inertial, self.path, self.text)

    def exec_block(self, stmts: Iterable[A.Node], scope: _Scope, ctx: _Ctx) -> None:
        for s in stmts:
            try:
                self.exec(s, scope, ctx)
            except _Fail as f:
                self.error(f.loc, f.message)
                self.poison(ctx, s)
            except RecursionError:
                self.error(s.loc, "this statement is nested too deeply")
                self.poison(ctx, s)

    @staticmethod
    def poison(ctx: _Ctx, s: A.Node) -> None:
        """Statement ``s`` building a body or bvec failed: its owner is incomplete, so
        later checks of it (no innerLam, no pos, ...) would only echo the first error."""
        if ctx.bvec is not None:
            ctx.bvec.poisoned = True
        elif ctx.body is not None:
            if isinstance(s, A.If):  # a skipped branch may have declared bvecs
                ctx.body.poisoned = True
            else:
                ctx.body.failed = True

    def declare(self, scope: _Scope, name: str, sym: _Sym, loc: Loc) -> bool:
        old = scope.names.get(name)
        if old is not None:
            self.error(
                loc,
                f"'{name}' is already declared in this scope, as {_KIND_WORDS[old.kind]} "
                f"(line {old.loc.line})",
            )
            return False
        scope.names[name] = sym
        return True

    # ---------------------------------------------------------------- statements
    def exec(self, s: A.Node, scope: _Scope, ctx: _Ctx) -> None:
        if isinstance(s, A.Empty):
            return
        if isinstance(s, A.VarDecl):
            value: object = None
            if s.init is not None:
                try:
                    t, value = self.eval(s.init, scope)
                except _Fail as f:
                    self.error(f.loc, f.message)
                    t, value = s.type, POISON
                except RecursionError:  # still declare the variable: no 'unknown variable' echo
                    self.error(s.init.loc, "this expression is nested too deeply")
                    t, value = s.type, POISON
                if t != s.type and value is not POISON:
                    self.error(s.init.loc, f"cannot initialize {s.type} '{s.name}' with a {t} value")
                    value = POISON
            self.declare(scope, s.name, _Sym("var", s.name_loc, s.type, value), s.name_loc)
            return
        if isinstance(s, A.Assign):
            self.exec_assign(s, scope)
            return
        if isinstance(s, A.If):
            t, v = self.eval(s.test, scope)
            if t != "bool":
                raise _Fail(s.test.loc, f"an if condition must be bool, not {t}")
            if v is POISON:  # unknown branch: what it would declare is unknown too
                self.poison(ctx, s)
                return
            branch = s.then if v else s.other
            if branch is not None:
                self.exec_block((branch,), _Scope(scope), ctx)
            return
        if isinstance(s, A.Block):
            self.exec_block(s.body, _Scope(scope), ctx)
            return
        if isinstance(s, A.CallStmt):
            self.exec_call_stmt(s, scope, ctx)
            return
        if isinstance(s, A.BvecDef):
            self.exec_bvec(s, scope, ctx)
            return
        if isinstance(s, A.BodyLiteral):
            self.need(ctx, ("system",), s.loc, "an ellipsoidBody", "inside a rigidBodySystem")
            body = self.new_body(s.name, s.name_loc, scope, ctx)
            self.exec_block(s.body, _Scope(scope), _Ctx("body", ctx.system, body))
            return
        if isinstance(s, A.BodyFuncDef):
            self.need(ctx, ("top", "system"), s.loc, "a body function", "at top level or in a rigidBodySystem")
            names = set()
            for p in s.params:
                if p.name in names:
                    self.error(p.loc, f"parameter '{p.name}' is declared twice")
                names.add(p.name)
            self.declare(scope, s.name, _Sym("func", s.name_loc, value=s, scope=scope.snapshot()), s.name_loc)
            return
        if isinstance(s, A.BodyInstance):
            self.exec_instance(s, scope, ctx)
            return
        if isinstance(s, A.SystemDef):
            self.need(ctx, ("top",), s.loc, "a rigidBodySystem", "at top level")
            system = _SystemB(s.name, s.name_loc)
            if self.declare(scope, s.name, _Sym("system", s.name_loc, value=system), s.name_loc):
                self.systems.append(system)
            self.exec_block(s.body, _Scope(scope), _Ctx("system", system))
            return
        if isinstance(s, A.Constraint):
            self.exec_constraint(s, scope, ctx)
            return
        raise _Fail(s.loc, "unsupported statement")  # pragma: no cover - grammar has no more

    def need(self, ctx: _Ctx, allowed: tuple[str, ...], loc: Loc, what: str, where: str) -> None:
        if ctx.where not in allowed:
            inside = {"top": "at top level", "system": "in a rigidBodySystem", "body": "in an ellipsoidBody", "bvec": "in a bvec"}
            raise _Fail(loc, f"{what} is not allowed {inside[ctx.where]}; it belongs {where}")

    def exec_assign(self, s: A.Assign, scope: _Scope) -> None:
        sym = scope.lookup(s.name)
        if sym is None:
            raise _Fail(s.loc, f"unknown variable '{s.name}'{did_you_mean(s.name, scope.visible('var'))}")
        if sym.kind != "var":
            raise _Fail(s.loc, f"cannot assign to '{s.name}': it is {_KIND_WORDS[sym.kind]}, not a variable")
        t, v = self.eval(s.value, scope)
        if v is POISON:
            sym.value = POISON
            return
        if t != sym.type:
            raise _Fail(s.value.loc, f"cannot assign a {t} value to {sym.type} '{s.name}'")
        if s.op != "=":
            if sym.type != "double":
                raise _Fail(s.loc, f"'{s.op}' needs a double, but '{s.name}' is bool")
            if sym.value is None:
                raise _Fail(s.loc, f"variable '{s.name}' is used before it is given a value")
            if sym.value is POISON:
                return
            v = self.arith(s.op[0], sym.value, v, s.loc)
        sym.value = v

    def exec_call_stmt(self, s: A.CallStmt, scope: _Scope, ctx: _Ctx) -> None:
        if s.func not in STATEMENTS:
            if s.func in FUNCTIONS:
                raise _Fail(s.loc, f"the value of '{s.func}(...)' is not used; a statement here does nothing")
            names = list(STATEMENTS) + list(FUNCTIONS)
            raise _Fail(s.loc, f"unknown statement '{s.func}'{did_you_mean(s.func, names)}")
        owner = STATEMENTS[s.func]
        if ctx.where != owner:
            where = "an ellipsoidBody" if owner == "body" else "a bvec block"
            raise _Fail(s.loc, f"'{s.func}' is only allowed inside {where}")
        if len(s.args) != 3:
            raise _Fail(s.loc, f"'{s.func}' takes 3 arguments (x, y, z), not {len(s.args)}")
        vals = []
        poisoned = False
        for a in s.args:
            t, v = self.eval(a, scope)
            if v is POISON:
                poisoned = True
                continue
            if t != "double":
                raise _Fail(a.loc, f"'{s.func}' takes doubles; this argument is {t}")
            vals.append(float(v))
        if poisoned:  # an earlier error: this statement is incomplete, say nothing more
            if owner == "body":
                ctx.body.failed = True
            else:
                ctx.bvec.poisoned = True
            return
        value = tuple(vals)
        if s.func == "innerLam":
            ctx.body.inner, ctx.body.inner_loc = value, s.loc
        elif s.func == "outerLam":
            ctx.body.outer, ctx.body.outer_loc = value, s.loc
        elif s.func == "pos":
            ctx.bvec.pos, ctx.bvec.pos_loc = value, s.loc
        else:
            ctx.bvec.orient, ctx.bvec.orient_loc = value, s.loc

    def exec_bvec(self, s: A.BvecDef, scope: _Scope, ctx: _Ctx) -> None:
        self.need(ctx, ("top", "system", "body"), s.loc, "a bvec", "in an ellipsoidBody or at top level")
        bvec = _BvecB(s.name, s.name_loc, ctx.body, calls=self.calls)
        if ctx.where == "body":
            body = ctx.body
            if s.name in body.bvecs:
                old = body.bvecs[s.name]
                self.error(s.name_loc, f"body '{body.name}' already has a bound vector '{s.name}' (line {old.loc.line})")
            elif self.declare(scope, s.name, _Sym("bvec", s.name_loc, value=bvec), s.name_loc):
                body.bvecs[s.name] = bvec
        else:
            if self.declare(scope, s.name, _Sym("bvec", s.name_loc, value=bvec), s.name_loc):
                self.inertial.setdefault(s.name, bvec)
        self.exec_block(s.body, _Scope(scope), _Ctx("bvec", ctx.system, ctx.body, bvec))

    def new_body(self, name: str, loc: Loc, scope: _Scope, ctx: _Ctx) -> _BodyB:
        system = ctx.system
        body = _BodyB(name, loc, system, calls=self.calls, def_calls=self.calls)
        if name == WORLD:
            self.error(loc, f"'{WORLD}' cannot name a body: the URDF uses it for the inertial frame")
            body.poisoned = True  # still declared, so references to it stay quiet
        if name in system.bodies:
            old = system.bodies[name]
            self.error(loc, f"system '{system.name}' already has a body '{name}' (line {old.loc.line})")
            body.poisoned = True
        elif self.declare(scope, name, _Sym("body", loc, value=body), loc):
            system.bodies[name] = body
        else:
            body.poisoned = True
        return body

    def exec_instance(self, s: A.BodyInstance, scope: _Scope, ctx: _Ctx) -> None:
        try:
            self.instantiate(s, scope, ctx)
        except _Fail:
            # declare the body anyway (poisoned) so references to it do not cascade
            if ctx.where == "system" and s.name not in ctx.system.bodies and s.name not in scope.names:
                self.new_body(s.name, s.name_loc, scope, ctx).poisoned = True
            raise

    def instantiate(self, s: A.BodyInstance, scope: _Scope, ctx: _Ctx) -> None:
        sym = scope.lookup(s.func)
        if sym is None or sym.kind != "func":
            if sym is None:
                msg = f"unknown body function '{s.func}'{did_you_mean(s.func, scope.visible('func'))}"
            else:
                msg = f"'{s.func}' is {_KIND_WORDS[sym.kind]}, not a body function"
            raise _Fail(s.loc, msg)
        self.need(ctx, ("system",), s.loc, "a body instantiation", "inside a rigidBodySystem")
        fdef: A.BodyFuncDef = sym.value
        if len(s.args) != len(fdef.params):
            plist = ", ".join(f"{p.type} {p.name}" for p in fdef.params)
            raise _Fail(
                s.loc,
                f"body function '{fdef.name}' takes {len(fdef.params)} argument"
                f"{'s' if len(fdef.params) != 1 else ''} ({plist}), but {len(s.args)} "
                f"{'were' if len(s.args) != 1 else 'was'} given",
            )
        fscope = _Scope(sym.scope)
        poisoned = False
        for i, (p, a) in enumerate(zip(fdef.params, s.args), start=1):
            t, v = self.eval(a, scope)
            if v is POISON:
                poisoned = True
            elif t != p.type:
                raise _Fail(
                    a.loc,
                    f"argument {i} of '{fdef.name}' ('{p.name}') must be {p.type}, not {t}",
                )
            fscope.names[p.name] = _Sym("var", p.loc, p.type, v)
        body = self.new_body(s.name, s.name_loc, scope, ctx)
        body.poisoned = body.poisoned or poisoned
        outer = self.calls
        self.calls = body.def_calls = ((s.loc, f"in call '{s.func} {s.name}(...)'"), *outer)
        try:
            self.exec_block(fdef.body, fscope, _Ctx("body", ctx.system, body))
        finally:
            self.calls = outer

    def exec_constraint(self, s: A.Constraint, scope: _Scope, ctx: _Ctx) -> None:
        try:
            self.add_constraint(s, scope, ctx)
        except _Fail:
            self.constraint_failed = True
            raise

    def add_constraint(self, s: A.Constraint, scope: _Scope, ctx: _Ctx) -> None:
        self.need(ctx, ("top", "system"), s.loc, "a constraint", "in a rigidBodySystem or at top level")
        if s.kind not in JOINT_KINDS:
            raise _Fail(
                s.kind_loc,
                f"unknown joint type '{s.kind}'{did_you_mean(s.kind, JOINT_KINDS)}; "
                "the language has fixed, revolute, spherical and prismatic joints",
            )
        counts, signature, whats, unit = _SIGNATURES[s.kind]
        if len(s.args) not in counts:
            shown = " or ".join(", ".join(map(str, counts)).rsplit(", ", 1))
            raise _Fail(
                s.loc,
                f"constraint {signature} takes {shown} arguments, not {len(s.args)}",
            )
        ends = [self.resolve_bvec(a, scope, ctx) for a in s.args[:2]]
        values = []
        for node, what in zip(s.args[2:], whats):
            t, v = self.eval(node, scope)
            if v is POISON:
                return
            if t != "double":
                raise _Fail(node.loc, f"{what} must be a double ({unit}), not {t}")
            values.append(float(v))
        joint = _JointB(s.kind, (ends[0], ends[1]), 0.0, s.loc, (s.args[0].loc, s.args[1].loc))
        joint.value_loc = s.args[2].loc if len(s.args) > 2 else None
        if s.kind == "spherical":
            joint.rotation = tuple(values) if values else (0.0, 0.0, 0.0)
        elif s.kind == "prismatic":
            for node, v in zip(s.args[2:], values):
                if abs(v) > MAX_LENGTH:
                    raise _Fail(node.loc, f"a prismatic offset or limit must be at most {MAX_LENGTH:g} in size, not {v:g}")
            joint.offset = values[0] if values else 0.0
            joint.limits = self.checked_limits(s, values, "offset", "", "")
        elif s.kind == "revolute":
            joint.angle = values[0] if values else 0.0
            joint.limits = self.checked_limits(s, values, "angle", " deg", " deg")
        if all(e is not None for e in ends):
            self.joints.append(joint)

    @staticmethod
    def checked_limits(s: A.Constraint, values: list[float], what: str, unit: str, span_unit: str):
        """(lower, upper) of a revolute or prismatic joint with 5 arguments, checked; else None.
        ``values`` are the evaluated arguments after the two ends."""
        if len(values) != 3:
            return None
        rest, lower, upper = values
        if not lower < upper:
            raise _Fail(
                s.args[3].loc,
                f"the lower joint limit ({lower:g}{unit}) must be below the upper one ({upper:g}{unit}); "
                "a joint that cannot move is constraint fixed(a, b)",
            )
        if s.kind == "revolute" and upper - lower > 360.0:
            raise _Fail(
                s.args[3].loc,
                f"joint limits {lower:g}..{upper:g} deg span more than a full turn; "
                "leave them out for a joint without limits",
            )
        if not lower <= rest <= upper:
            raise _Fail(
                s.args[2].loc,
                f"the default {what} {rest:g}{span_unit} is outside the joint limits {lower:g}..{upper:g}{span_unit}",
            )
        return lower, upper

    def resolve_bvec(self, node: A.Node, scope: _Scope, ctx: _Ctx) -> _BvecB | None:
        if not isinstance(node, A.Name):
            raise _Fail(node.loc, "expected a bound vector: body.bvec, system.body.bvec or an inertial bvec name")
        parts, locs = node.parts, node.part_locs
        if len(parts) > 3:
            raise _Fail(node.loc, f"'{node.text}' has too many parts; write system.body.bvec at most")
        if len(parts) == 1:
            sym = scope.lookup(parts[0])
            if sym is not None and sym.kind == "bvec" and sym.value.body is None:
                return sym.value
            if sym is not None and sym.kind == "body":
                body: _BodyB = sym.value
                raise _Fail(locs[0], f"'{parts[0]}' is a body; name one of its bound vectors: "
                            + ", ".join(f"{parts[0]}.{b}" for b in body.bvecs))
            if sym is not None:
                raise _Fail(locs[0], f"'{parts[0]}' is {_KIND_WORDS[sym.kind]}, not an inertial bound vector")
            inertial = [n for n in scope.visible("bvec") if scope.lookup(n).value.body is None]
            raise _Fail(locs[0], f"unknown inertial bound vector '{parts[0]}'{did_you_mean(parts[0], inertial)}")
        if len(parts) == 3:
            sym = scope.lookup(parts[0])
            if sym is None or sym.kind != "system":
                systems = scope.visible("system")
                if sym is None:
                    raise _Fail(locs[0], f"unknown rigidBodySystem '{parts[0]}'{did_you_mean(parts[0], systems)}")
                raise _Fail(locs[0], f"'{parts[0]}' is {_KIND_WORDS[sym.kind]}, not a rigidBodySystem")
            system: _SystemB = sym.value
            body = system.bodies.get(parts[1])
            if body is None:
                raise _Fail(
                    locs[1],
                    f"system '{system.name}' has no body '{parts[1]}'{did_you_mean(parts[1], system.bodies)}",
                )
            return self.body_bvec(body, parts[2], locs[2])
        sym = scope.lookup(parts[0])
        if sym is None:
            for system in self.systems:
                if parts[0] in system.bodies and system is not ctx.system:
                    raise _Fail(
                        locs[0],
                        f"body '{parts[0]}' belongs to rigidBodySystem '{system.name}'; "
                        f"outside it, write {system.name}.{node.text}",
                    )
            raise _Fail(locs[0], f"unknown body '{parts[0]}'{did_you_mean(parts[0], scope.visible('body'))}")
        if sym.kind == "system":
            raise _Fail(locs[0], f"'{parts[0]}' is a rigidBodySystem; write {parts[0]}.body.bvec")
        if sym.kind != "body":
            raise _Fail(locs[0], f"'{parts[0]}' is {_KIND_WORDS[sym.kind]}, not a body")
        return self.body_bvec(sym.value, parts[1], locs[1])

    def body_bvec(self, body: _BodyB, name: str, loc: Loc) -> _BvecB | None:
        if body.poisoned and name not in body.bvecs:
            return None
        bvec = body.bvecs.get(name)
        if bvec is None:
            raise _Fail(loc, f"body '{body.name}' has no bound vector '{name}'{did_you_mean(name, body.bvecs)}")
        return bvec

    # ---------------------------------------------------------------- expressions
    def eval(self, e: A.Node, scope: _Scope) -> tuple[str, object]:
        if isinstance(e, A.Number):
            if not math.isfinite(e.value):
                raise _Fail(e.loc, "this number is too large")
            return "double", POISON if self.dry else e.value
        if isinstance(e, A.Bool):
            return "bool", POISON if self.dry else e.value
        if isinstance(e, A.Name):
            if len(e.parts) > 1:
                raise _Fail(e.loc, f"'{e.text}' is a bound-vector reference; only a constraint can use it")
            sym = scope.lookup(e.parts[0])
            if sym is None:
                raise _Fail(e.loc, f"unknown variable '{e.parts[0]}'{did_you_mean(e.parts[0], scope.visible('var'))}")
            if sym.kind != "var":
                raise _Fail(e.loc, f"'{e.parts[0]}' is {_KIND_WORDS[sym.kind]}, not a variable")
            if self.dry:
                return sym.type, POISON
            if sym.value is None:
                raise _Fail(e.loc, f"variable '{e.parts[0]}' is used before it is given a value")
            return sym.type, sym.value
        if isinstance(e, A.UnOp):
            t, v = self.eval(e.operand, scope)
            if e.op == "!":
                if t != "bool":
                    raise _Fail(e.loc, f"'!' needs a bool, not {t}")
                return "bool", POISON if v is POISON else (not v)
            if t != "double":
                raise _Fail(e.loc, f"unary '{e.op}' needs a double, not {t}")
            return "double", POISON if v is POISON else (-v if e.op == "-" else v)
        if isinstance(e, A.BinOp):
            # 1 + 2 + ... + n is deep on the left but not nested: a loop, not recursion
            chain = []
            while isinstance(e, A.BinOp):
                chain.append(e)
                e = e.left
            t, v = self.eval(e, scope)
            for node in reversed(chain):
                t, v = self.eval_binop(node, t, v, scope)
            return t, v
        if isinstance(e, A.Cond):
            t, v = self.eval(e.test, scope)
            if t != "bool":
                raise _Fail(e.test.loc, f"the condition of '?:' must be bool, not {t}")
            t1, v1 = self.eval_dry(e.then, scope, v is POISON or not v)
            t2, v2 = self.eval_dry(e.other, scope, v is POISON or bool(v))
            if t1 != t2:
                raise _Fail(e.loc, f"the two branches of '?:' differ in type ({t1} and {t2})")
            if v is POISON:
                return t1, POISON
            return t1, v1 if v else v2
        if isinstance(e, A.Call):
            return self.eval_call(e, scope)
        raise _Fail(e.loc, "this is not an expression")

    def eval_dry(self, e: A.Node, scope: _Scope, dry: bool = True) -> tuple[str, object]:
        """Evaluate ``e``, or with ``dry`` only type-check it: its value is POISON and
        no value error (division by zero, sqrt(-1), ...) is raised."""
        self.dry += dry
        try:
            return self.eval(e, scope)
        finally:
            self.dry -= dry

    def eval_binop(self, e: A.BinOp, tl: str, vl: object, scope: _Scope) -> tuple[str, object]:
        """``e`` whose left operand has the value ``vl`` of type ``tl``."""
        op = e.op
        if op in ("&&", "||"):
            if tl != "bool":
                raise _Fail(e.left.loc, f"'{op}' needs bool operands; the left one is {tl}")
            if vl is not POISON and ((op == "&&" and not vl) or (op == "||" and vl)):
                tr, _ = self.eval_dry(e.right, scope)  # short circuit: type-check only
                if tr != "bool":
                    raise _Fail(e.right.loc, f"'{op}' needs bool operands; the right one is {tr}")
                return "bool", vl
            tr, vr = self.eval(e.right, scope)
            if tr != "bool":
                raise _Fail(e.right.loc, f"'{op}' needs bool operands; the right one is {tr}")
            return "bool", POISON if POISON in (vl, vr) else vr
        tr, vr = self.eval(e.right, scope)
        if op in ("==", "!="):
            if tl != tr:
                raise _Fail(e.loc, f"cannot compare {tl} with {tr}")
            if POISON in (vl, vr):
                return "bool", POISON
            return "bool", (vl == vr) if op == "==" else (vl != vr)
        if tl != "double" or tr != "double":
            bad = e.left.loc if tl != "double" else e.right.loc
            raise _Fail(bad, f"'{op}' needs double operands, not {tl} and {tr}")
        if POISON in (vl, vr):
            return ("bool" if op in ("<", ">", "<=", ">=") else "double"), POISON
        if op in ("<", ">", "<=", ">="):
            return "bool", {"<": vl < vr, ">": vl > vr, "<=": vl <= vr, ">=": vl >= vr}[op]
        return "double", self.arith(op, vl, vr, e.loc)

    def arith(self, op: str, a: float, b: float, loc: Loc) -> float:
        try:
            if op == "+":
                r = a + b
            elif op == "-":
                r = a - b
            elif op == "*":
                r = a * b
            elif op == "/":
                r = a / b
            else:
                r = math.fmod(a, b)
        except ZeroDivisionError:
            raise _Fail(loc, "division by zero") from None
        except ValueError:
            raise _Fail(loc, f"'{op}' is undefined for {a:g} and {b:g}") from None
        if not math.isfinite(r):
            raise _Fail(loc, f"'{op}' overflows ({a:g} {op} {b:g})")
        return float(r)

    def eval_call(self, e: A.Call, scope: _Scope) -> tuple[str, object]:
        if e.func not in FUNCTIONS:
            sym = scope.lookup(e.func)
            if sym is not None and sym.kind == "func":
                raise _Fail(e.loc, f"body function '{e.func}' makes a body; write '{e.func} name(...);' in a rigidBodySystem")
            if e.func in STATEMENTS:
                raise _Fail(e.loc, f"'{e.func}' is a statement and has no value")
            raise _Fail(e.loc, f"unknown function '{e.func}'{did_you_mean(e.func, FUNCTIONS)}")
        nargs, fn = FUNCTIONS[e.func]
        if len(e.args) != nargs:
            raise _Fail(e.loc, f"'{e.func}' takes {nargs} argument{'s' if nargs > 1 else ''}, not {len(e.args)}")
        vals = []
        poisoned = False
        for a in e.args:
            t, v = self.eval(a, scope)
            if t != "double":
                raise _Fail(a.loc, f"'{e.func}' takes doubles; this argument is {t}")
            poisoned = poisoned or v is POISON
            vals.append(v)
        if poisoned:
            return "double", POISON
        try:
            r = fn(*vals)
        except (ValueError, ZeroDivisionError):
            shown = ", ".join(f"{v:g}" for v in vals)
            raise _Fail(e.loc, f"'{e.func}({shown})' is undefined") from None
        except OverflowError:
            raise _Fail(e.loc, f"'{e.func}' overflows") from None
        r = float(r)
        if not math.isfinite(r):
            raise _Fail(e.loc, f"'{e.func}' overflows")
        return "double", r

    # ---------------------------------------------------------------- checks
    def joint_system(self, j: _JointB) -> _SystemB | None:
        systems = []
        for e in j.ends:
            if e.body is not None and e.body.system not in systems:
                systems.append(e.body.system)
        return systems[0] if len(systems) == 1 else None

    def finish(self) -> list[System]:
        for j in self.joints:
            names = sorted({e.body.system.name for e in j.ends if e.body is not None})
            if len(names) > 1:
                self.error(j.loc, f"a joint cannot connect two rigidBodySystems ({' and '.join(names)})")
            elif not names:
                self.error(j.loc, "this joint connects two inertial bound vectors and no body")
        for system in self.systems:
            for body in system.bodies.values():
                self.check_body(body)
        for b in self.inertial.values():
            self.check_bvec(b)
        return [s for s in (self.build_system(sys) for sys in self.systems) if s is not None]

    def check_body(self, body: _BodyB) -> None:
        for bv in body.bvecs.values():
            self.check_bvec(bv)
        if body.poisoned:
            return
        for what, lam, loc in (("innerLam", body.inner, body.inner_loc), ("outerLam", body.outer, body.outer_loc)):
            if lam is None:
                if not body.failed:
                    self.error(body.loc, f"body '{body.name}' has no {what}(x, y, z)", body.calls)
                body.poisoned = True
            elif min(lam) <= 0:
                self.error(loc, f"{what} semi-axes must be positive, got ({_fmt(lam)})", body.def_calls)
                body.poisoned = True
            elif min(lam) < MIN_LENGTH:
                self.error(loc, f"{what} semi-axes must be at least {MIN_LENGTH:g}, got ({_fmt(lam)})", body.def_calls)
                body.poisoned = True
            elif max(lam) > MAX_LENGTH:
                self.error(loc, f"{what} semi-axes must be at most {MAX_LENGTH:g}, got ({_fmt(lam)})", body.def_calls)
                body.poisoned = True
        if body.poisoned:
            return
        if any(o < i for o, i in zip(body.outer, body.inner)):
            self.error(
                body.outer_loc,
                f"the outer ellipsoid ({_fmt(body.outer)}) of body '{body.name}' does not enclose "
                f"the inner one ({_fmt(body.inner)}): each outerLam semi-axis must be >= the innerLam one",
                body.def_calls,
            )
            body.poisoned = True

    def check_bvec(self, bv: _BvecB) -> None:
        if bv.poisoned:
            return
        owner = f" of body '{bv.body.name}'" if bv.body else ""
        for what, val in (("pos", bv.pos), ("orient", bv.orient)):
            if val is None:
                self.error(bv.loc, f"bound vector '{bv.name}'{owner} has no {what}(x, y, z)", bv.calls)
                bv.poisoned = True
        if bv.pos is not None and max(abs(x) for x in bv.pos) > MAX_LENGTH:
            self.error(bv.pos_loc, f"pos coordinates of '{bv.name}'{owner} must be within +-{MAX_LENGTH:g}, "
                                   f"got ({_fmt(bv.pos)})", bv.calls)
            bv.poisoned = True
        if bv.orient is not None and _norm(bv.orient) < 1e-12:
            self.error(
                bv.orient_loc,
                f"orient vector of '{bv.name}'{owner} is zero; a bound vector needs a direction",
                bv.calls,
            )
            bv.poisoned = True

    def freeze_bvec(self, bv: _BvecB) -> BoundVector:
        o = np.asarray(bv.orient, dtype=float)
        o = o / np.max(np.abs(o))  # first scale, so that huge or tiny vectors do not overflow
        o = o / np.linalg.norm(o)
        return BoundVector(
            bv.name,
            tuple(float(x) for x in bv.pos),
            tuple(float(x) for x in o),
            bv.body.name if bv.body else None,
            bv.loc,
        )

    def build_system(self, sb: _SystemB) -> System | None:
        """Check the joint graph of one system and orient it as a spanning tree plus loop
        closures (thesis §3.2.1, §4.2): breadth first from the inertial frame, each body's
        joints in spec order; a joint that reaches a body already reached closes a loop."""
        joints = [j for j in self.joints if self.joint_system(j) is sb]
        bad = False
        adjacency: dict[str | None, list[tuple[str | None, _JointB]]] = {None: []}
        for b in sb.bodies:
            adjacency[b] = []
        seen_pairs: dict[frozenset, _JointB] = {}
        for j in joints:  # in spec order
            a = j.ends[0].body.name if j.ends[0].body else None
            b = j.ends[1].body.name if j.ends[1].body else None
            if a == b:
                self.error(j.loc, f"this joint connects body '{a}' to itself")
                bad = True
                continue
            pair = frozenset((a, b))
            if pair in seen_pairs:
                names = " and ".join("the inertial frame" if n is None else f"'{n}'" for n in (a, b))
                self.error(j.loc, f"a second joint between {names} (the first is on line {seen_pairs[pair].loc.line})")
                bad = True
                continue
            seen_pairs[pair] = j
            bad = bad or j.ends[0].poisoned or j.ends[1].poisoned
            adjacency[a].append((b, j))
            adjacency[b].append((a, j))
        children, closures = self.spanning_tree(adjacency)
        if not adjacency[None]:
            if not self.constraint_failed:
                self.error(sb.loc, f"rigidBodySystem '{sb.name}' has no joint to the inertial frame")
            return None
        # preorder, each body's children in spec order; an explicit stack, not recursion,
        # so a chain of any length is traversed
        order: list[tuple[str, _JointB, str | None]] = []
        stack = [(c, j, None) for c, j in reversed(children[None])]
        while stack:
            child, j, parent = stack.pop()
            order.append((child, j, parent))
            stack.extend((c, k, child) for c, k in reversed(children.get(child, [])))
        reached = {name for name, _, _ in order}
        for name, body in sb.bodies.items():
            if name not in reached and not body.poisoned and not self.constraint_failed:
                self.error(
                    body.loc,
                    f"body '{name}' has no path to the inertial frame (no chain of joints connects it)",
                    body.calls,
                )
                bad = True
        for j in closures:
            if j.value_loc is not None:
                self.error(j.value_loc, f"this {j.kind} joint closes a kinematic loop, and a loop-closing joint takes "
                                        "no rest value or limits: its value follows from the joints of the tree "
                                        "(leave them out, or write the joints so that another one closes the loop)")
                bad = True
        if bad or self.diags or any(sb.bodies[n].poisoned for n, _, _ in order):
            return None  # with any error there is no model (and bvecs may be incomplete)
        return self.frozen_system(sb, order, closures)

    def spanning_tree(self, adjacency: Mapping[str | None, list[tuple[str | None, _JointB]]]):
        """Breadth first from the inertial frame (None), each node's joints in spec order:
        (each node's tree children as (child, joint) in spec order, the closures in spec order)."""
        rank = {id(j): i for i, j in enumerate(self.joints)}
        children: dict[str | None, list[tuple[str, _JointB]]] = {}
        reached: set[str | None] = {None}
        done: set[int] = set()
        closures = []
        queue: deque[str | None] = deque([None])
        while queue:
            node = queue.popleft()
            for other, j in sorted(adjacency[node], key=lambda t: rank[id(t[1])]):
                if id(j) in done:
                    continue
                done.add(id(j))
                if other in reached:
                    closures.append(j)
                    continue
                reached.add(other)
                children.setdefault(node, []).append((other, j))
                queue.append(other)
        children.setdefault(None, [])
        return children, sorted(closures, key=lambda j: rank[id(j)])

    def frozen_system(self, sb: _SystemB, order, closures: list[_JointB]) -> System:
        """The checked system: bodies in preorder with their tree joints, then the closures
        (parent: the first argument's body, child: the second's)."""
        bodies = []
        out_joints = []
        frozen_bvecs: dict[str, dict[str, BoundVector]] = {}
        used: set[str] = set()
        for name, j, parent in order:
            b = sb.bodies[name]
            bvecs = frozen_bvecs[name] = {n: self.freeze_bvec(v) for n, v in b.bvecs.items()}
            bodies.append(Body(name, b.inner, b.outer, bvecs, sb.name, b.loc))
            child_end = j.ends[0] if (j.ends[0].body and j.ends[0].body.name == name) else j.ends[1]
            parent_end = j.ends[1] if child_end is j.ends[0] else j.ends[0]
            jname = self.joint_name(name, child_end.name, j.kind, used, sb.bodies)
            out_joints.append(
                Joint(jname, j.kind, parent, name, self.freeze_bvec(parent_end), bvecs[child_end.name], j.angle,
                      j.loc, j.limits, j.rotation, j.offset)
            )

        def end(e: _BvecB) -> BoundVector:
            return frozen_bvecs[e.body.name][e.name] if e.body is not None else self.freeze_bvec(e)

        out_closures = []
        for j in closures:
            parent, child = (e.body.name if e.body is not None else None for e in j.ends)
            jname = self.joint_name(child or WORLD, j.ends[1].name, j.kind, used, sb.bodies)
            out_closures.append(Joint(jname, j.kind, parent, child, end(j.ends[0]), end(j.ends[1]), loc=j.loc))
        return System(sb.name, tuple(bodies), tuple(out_joints), sb.loc, tuple(out_closures))

    def joint_name(self, body: str, bvec: str, kind: str, used: set[str], bodies: Mapping[str, object]) -> str:
        """``<body>_<bvec>``, with a suffix ``_2``, ``_3``, ... if taken (body 'a_b' + bvec 'c' and
        body 'a' + bvec 'b_c'; a spherical joint also takes the names of its three URDF joints
        and two links, :func:`kms2pin.urdf.spherical_parts`); recorded in ``used``."""
        jname, k = f"{body}_{bvec}", 2
        while not self.names_free(jname, kind, used, bodies):
            jname, k = f"{body}_{bvec}_{k}", k + 1
        used.add(jname)
        if kind == "spherical":
            used.update(f"{jname}_{a}" for a in "xyz")
        return jname

    @staticmethod
    def names_free(name: str, kind: str, used: set[str], bodies: Mapping[str, object]) -> bool:
        """Whether joint ``name`` (with a spherical joint's URDF joints ``name_x|y|z`` and
        links ``name_x_link``, ``name_y_link``) clashes with no joint and no body so far."""
        if kind != "spherical":
            return name not in used
        derived = [name, *(f"{name}_{a}" for a in "xyz")]
        links = [f"{name}_{a}_link" for a in "xy"]
        return not any(n in used for n in derived) and not any(n in bodies or n == WORLD for n in links)


def _norm(v) -> float:
    """Euclidean norm without overflow for huge components (math.hypot scales)."""
    return math.hypot(*v)


def _fmt(v) -> str:
    return ", ".join(f"{x:g}" for x in v)


def analyze(stmts: tuple[A.Node, ...], text: str, path: str) -> ModelSpec:
    """Execute a parsed spec and return its model (raises SpecError with every error)."""
    return Analyzer(text, path).run(stmts)
