"""AST -> :class:`~kms2pin.model.ModelSpec`: the statements executed, names resolved.

The spec is executed once, top to bottom, like the thesis's compiler did (§3.1.1,
§3.2.1): variables follow C++ block scoping, body functions run in their own
scope (their parameters plus the scope they were defined in), and the kinematic
checks run when the whole file has been read.  Errors are collected, not
raised one at a time; a statement that fails leaves "poisoned" values behind so
one mistake does not cascade into many messages.  Expressions are evaluated by
:mod:`.expressions`, the whole-spec checks and the spanning tree are :mod:`.systems`.
"""

from __future__ import annotations

from collections.abc import Iterable

from ..errors import Diagnostic, SpecError, did_you_mean
from ..model import WORLD, Loc, ModelSpec
from . import ast as A
from .expressions import FUNCTIONS, STATEMENTS, Expressions
from .symbols import (
    KIND_WORDS,
    MAX_LENGTH,
    MIN_LENGTH,
    POISON,
    BodyB,
    BvecB,
    Ctx,
    Fail,
    JointB,
    Reporter,
    Scope,
    Sym,
    SystemB,
)
from .systems import SystemBuilder, freeze_bvec

__all__ = ["FUNCTIONS", "JOINT_KINDS", "MAX_LENGTH", "MIN_LENGTH", "STATEMENTS", "Analyzer", "analyze"]


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


class Analyzer:
    """Runs a parsed spec and builds its :class:`ModelSpec` (raises SpecError)."""

    def __init__(self, text: str, path: str):
        self.path = path
        self.text = text
        self.report = Reporter(text, path)
        self.values = Expressions()
        self.systems: list[SystemB] = []
        self.inertial: dict[str, BvecB] = {}
        self.joints: list[JointB] = []
        self.constraint_failed = False  # then reachability errors would only echo it

    # ---------------------------------------------------------------- driver
    def run(self, stmts: tuple[A.Node, ...]) -> ModelSpec:
        top = Scope()
        self.exec_block(stmts, top, Ctx("top"))
        systems = SystemBuilder(self.report, self.systems, self.inertial, self.joints, self.constraint_failed).finish()
        if not self.report.diags and not systems:
            self.report.error(Loc(1, 1), "the spec defines no rigidBodySystem")
        if self.report.diags:
            # a body function runs once per instantiation: report each mistake in it once,
            # with the notes of the first call that made it
            unique: dict[tuple, list[Diagnostic]] = {}
            for error, *notes in self.report.diags:
                unique.setdefault((error.line, error.column, error.message), [error, *notes])
            ordered = sorted(unique.values(), key=lambda ds: (ds[0].line, ds[0].column))
            raise SpecError([d for ds in ordered for d in ds])
        inertial = {n: freeze_bvec(b) for n, b in self.inertial.items()}
        return ModelSpec(tuple(systems), inertial, self.path, self.text)

    def exec_block(self, stmts: Iterable[A.Node], scope: Scope, ctx: Ctx) -> None:
        for s in stmts:
            try:
                self.exec(s, scope, ctx)
            except Fail as f:
                self.report.error(f.loc, f.message)
                _poison(ctx, s)
            except RecursionError:
                self.report.error(s.loc, "this statement is nested too deeply")
                _poison(ctx, s)

    def declare(self, scope: Scope, name: str, sym: Sym, loc: Loc) -> bool:
        old = scope.names.get(name)
        if old is not None:
            self.report.error(
                loc,
                f"'{name}' is already declared in this scope, as {KIND_WORDS[old.kind]} "
                f"(line {old.loc.line})",
            )
            return False
        scope.names[name] = sym
        return True

    # ---------------------------------------------------------------- statements
    def exec(self, s: A.Node, scope: Scope, ctx: Ctx) -> None:
        if isinstance(s, A.Empty):
            return
        if isinstance(s, A.VarDecl):
            value: object = None
            if s.init is not None:
                try:
                    t, value = self.values.eval(s.init, scope)
                except Fail as f:
                    self.report.error(f.loc, f.message)
                    t, value = s.type, POISON
                except RecursionError:  # still declare the variable: no 'unknown variable' echo
                    self.report.error(s.init.loc, "this expression is nested too deeply")
                    t, value = s.type, POISON
                if t != s.type and value is not POISON:
                    self.report.error(s.init.loc, f"cannot initialize {s.type} '{s.name}' with a {t} value")
                    value = POISON
            self.declare(scope, s.name, Sym("var", s.name_loc, s.type, value), s.name_loc)
            return
        if isinstance(s, A.Assign):
            self.exec_assign(s, scope)
            return
        if isinstance(s, A.If):
            t, v = self.values.eval(s.test, scope)
            if t != "bool":
                raise Fail(s.test.loc, f"an if condition must be bool, not {t}")
            if v is POISON:  # unknown branch: what it would declare is unknown too
                _poison(ctx, s)
                return
            branch = s.then if v else s.other
            if branch is not None:
                self.exec_block((branch,), Scope(scope), ctx)
            return
        if isinstance(s, A.Block):
            self.exec_block(s.body, Scope(scope), ctx)
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
            self.exec_block(s.body, Scope(scope), Ctx("body", ctx.system, body))
            return
        if isinstance(s, A.BodyFuncDef):
            self.need(ctx, ("top", "system"), s.loc, "a body function", "at top level or in a rigidBodySystem")
            names = set()
            for p in s.params:
                if p.name in names:
                    self.report.error(p.loc, f"parameter '{p.name}' is declared twice")
                names.add(p.name)
            self.declare(scope, s.name, Sym("func", s.name_loc, value=s, scope=scope.snapshot()), s.name_loc)
            return
        if isinstance(s, A.BodyInstance):
            self.exec_instance(s, scope, ctx)
            return
        if isinstance(s, A.SystemDef):
            self.need(ctx, ("top",), s.loc, "a rigidBodySystem", "at top level")
            system = SystemB(s.name, s.name_loc)
            if self.declare(scope, s.name, Sym("system", s.name_loc, value=system), s.name_loc):
                self.systems.append(system)
            self.exec_block(s.body, Scope(scope), Ctx("system", system))
            return
        if isinstance(s, A.Constraint):
            self.exec_constraint(s, scope, ctx)
            return
        raise Fail(s.loc, "unsupported statement")  # pragma: no cover - grammar has no more

    def need(self, ctx: Ctx, allowed: tuple[str, ...], loc: Loc, what: str, where: str) -> None:
        if ctx.where not in allowed:
            inside = {"top": "at top level", "system": "in a rigidBodySystem", "body": "in an ellipsoidBody", "bvec": "in a bvec"}
            raise Fail(loc, f"{what} is not allowed {inside[ctx.where]}; it belongs {where}")

    def exec_assign(self, s: A.Assign, scope: Scope) -> None:
        sym = scope.lookup(s.name)
        if sym is None:
            raise Fail(s.loc, f"unknown variable '{s.name}'{did_you_mean(s.name, scope.visible('var'))}")
        if sym.kind != "var":
            raise Fail(s.loc, f"cannot assign to '{s.name}': it is {KIND_WORDS[sym.kind]}, not a variable")
        t, v = self.values.eval(s.value, scope)
        if v is POISON:
            sym.value = POISON
            return
        if t != sym.type:
            raise Fail(s.value.loc, f"cannot assign a {t} value to {sym.type} '{s.name}'")
        if s.op != "=":
            if sym.type != "double":
                raise Fail(s.loc, f"'{s.op}' needs a double, but '{s.name}' is bool")
            if sym.value is None:
                raise Fail(s.loc, f"variable '{s.name}' is used before it is given a value")
            if sym.value is POISON:
                return
            v = self.values.arith(s.op[0], sym.value, v, s.loc)
        sym.value = v

    def exec_call_stmt(self, s: A.CallStmt, scope: Scope, ctx: Ctx) -> None:
        if s.func not in STATEMENTS:
            if s.func in FUNCTIONS:
                raise Fail(s.loc, f"the value of '{s.func}(...)' is not used; a statement here does nothing")
            names = list(STATEMENTS) + list(FUNCTIONS)
            raise Fail(s.loc, f"unknown statement '{s.func}'{did_you_mean(s.func, names)}")
        owner = STATEMENTS[s.func]
        if ctx.where != owner:
            where = "an ellipsoidBody" if owner == "body" else "a bvec block"
            raise Fail(s.loc, f"'{s.func}' is only allowed inside {where}")
        if len(s.args) != 3:
            raise Fail(s.loc, f"'{s.func}' takes 3 arguments (x, y, z), not {len(s.args)}")
        vals = []
        poisoned = False
        for a in s.args:
            t, v = self.values.eval(a, scope)
            if v is POISON:
                poisoned = True
                continue
            if t != "double":
                raise Fail(a.loc, f"'{s.func}' takes doubles; this argument is {t}")
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

    def exec_bvec(self, s: A.BvecDef, scope: Scope, ctx: Ctx) -> None:
        self.need(ctx, ("top", "system", "body"), s.loc, "a bvec", "in an ellipsoidBody or at top level")
        bvec = BvecB(s.name, s.name_loc, ctx.body, calls=self.report.calls)
        if ctx.where == "body":
            body = ctx.body
            if s.name in body.bvecs:
                old = body.bvecs[s.name]
                self.report.error(s.name_loc, f"body '{body.name}' already has a bound vector '{s.name}' (line {old.loc.line})")
            elif self.declare(scope, s.name, Sym("bvec", s.name_loc, value=bvec), s.name_loc):
                body.bvecs[s.name] = bvec
        else:
            if self.declare(scope, s.name, Sym("bvec", s.name_loc, value=bvec), s.name_loc):
                self.inertial.setdefault(s.name, bvec)
        self.exec_block(s.body, Scope(scope), Ctx("bvec", ctx.system, ctx.body, bvec))

    def new_body(self, name: str, loc: Loc, scope: Scope, ctx: Ctx) -> BodyB:
        system = ctx.system
        body = BodyB(name, loc, system, calls=self.report.calls, def_calls=self.report.calls)
        if name == WORLD:
            self.report.error(loc, f"'{WORLD}' cannot name a body: the URDF uses it for the inertial frame")
            body.poisoned = True  # still declared, so references to it stay quiet
        if name in system.bodies:
            old = system.bodies[name]
            self.report.error(loc, f"system '{system.name}' already has a body '{name}' (line {old.loc.line})")
            body.poisoned = True
        elif self.declare(scope, name, Sym("body", loc, value=body), loc):
            system.bodies[name] = body
        else:
            body.poisoned = True
        return body

    def exec_instance(self, s: A.BodyInstance, scope: Scope, ctx: Ctx) -> None:
        try:
            self.instantiate(s, scope, ctx)
        except Fail:
            # declare the body anyway (poisoned) so references to it do not cascade
            if ctx.where == "system" and s.name not in ctx.system.bodies and s.name not in scope.names:
                self.new_body(s.name, s.name_loc, scope, ctx).poisoned = True
            raise

    def instantiate(self, s: A.BodyInstance, scope: Scope, ctx: Ctx) -> None:
        sym = scope.lookup(s.func)
        if sym is None or sym.kind != "func":
            if sym is None:
                msg = f"unknown body function '{s.func}'{did_you_mean(s.func, scope.visible('func'))}"
            else:
                msg = f"'{s.func}' is {KIND_WORDS[sym.kind]}, not a body function"
            raise Fail(s.loc, msg)
        self.need(ctx, ("system",), s.loc, "a body instantiation", "inside a rigidBodySystem")
        fdef: A.BodyFuncDef = sym.value
        if len(s.args) != len(fdef.params):
            plist = ", ".join(f"{p.type} {p.name}" for p in fdef.params)
            raise Fail(
                s.loc,
                f"body function '{fdef.name}' takes {len(fdef.params)} argument"
                f"{'s' if len(fdef.params) != 1 else ''} ({plist}), but {len(s.args)} "
                f"{'were' if len(s.args) != 1 else 'was'} given",
            )
        fscope = Scope(sym.scope)
        poisoned = False
        for i, (p, a) in enumerate(zip(fdef.params, s.args), start=1):
            t, v = self.values.eval(a, scope)
            if v is POISON:
                poisoned = True
            elif t != p.type:
                raise Fail(
                    a.loc,
                    f"argument {i} of '{fdef.name}' ('{p.name}') must be {p.type}, not {t}",
                )
            fscope.names[p.name] = Sym("var", p.loc, p.type, v)
        body = self.new_body(s.name, s.name_loc, scope, ctx)
        body.poisoned = body.poisoned or poisoned
        outer = self.report.calls
        self.report.calls = body.def_calls = ((s.loc, f"in call '{s.func} {s.name}(...)'"), *outer)
        try:
            self.exec_block(fdef.body, fscope, Ctx("body", ctx.system, body))
        finally:
            self.report.calls = outer

    def exec_constraint(self, s: A.Constraint, scope: Scope, ctx: Ctx) -> None:
        try:
            self.add_constraint(s, scope, ctx)
        except Fail:
            self.constraint_failed = True
            raise

    def add_constraint(self, s: A.Constraint, scope: Scope, ctx: Ctx) -> None:
        self.need(ctx, ("top", "system"), s.loc, "a constraint", "in a rigidBodySystem or at top level")
        if s.kind not in JOINT_KINDS:
            raise Fail(
                s.kind_loc,
                f"unknown joint type '{s.kind}'{did_you_mean(s.kind, JOINT_KINDS)}; "
                "the language has fixed, revolute, spherical and prismatic joints",
            )
        counts, signature, whats, unit = _SIGNATURES[s.kind]
        if len(s.args) not in counts:
            shown = " or ".join(", ".join(map(str, counts)).rsplit(", ", 1))
            raise Fail(
                s.loc,
                f"constraint {signature} takes {shown} arguments, not {len(s.args)}",
            )
        ends = [self.resolve_bvec(a, scope, ctx) for a in s.args[:2]]
        values = []
        for node, what in zip(s.args[2:], whats):
            t, v = self.values.eval(node, scope)
            if v is POISON:
                return
            if t != "double":
                raise Fail(node.loc, f"{what} must be a double ({unit}), not {t}")
            values.append(float(v))
        joint = JointB(s.kind, (ends[0], ends[1]), 0.0, s.loc, (s.args[0].loc, s.args[1].loc))
        joint.value_loc = s.args[2].loc if len(s.args) > 2 else None
        if s.kind == "spherical":
            joint.rotation = tuple(values) if values else (0.0, 0.0, 0.0)
        elif s.kind == "prismatic":
            for node, v in zip(s.args[2:], values):
                if abs(v) > MAX_LENGTH:
                    raise Fail(node.loc, f"a prismatic offset or limit must be at most {MAX_LENGTH:g} in size, not {v:g}")
            joint.offset = values[0] if values else 0.0
            joint.limits = _checked_limits(s, values, "offset", "", "")
        elif s.kind == "revolute":
            joint.angle = values[0] if values else 0.0
            joint.limits = _checked_limits(s, values, "angle", " deg", " deg")
        if all(e is not None for e in ends):
            self.joints.append(joint)

    def resolve_bvec(self, node: A.Node, scope: Scope, ctx: Ctx) -> BvecB | None:
        if not isinstance(node, A.Name):
            raise Fail(node.loc, "expected a bound vector: body.bvec, system.body.bvec or an inertial bvec name")
        parts, locs = node.parts, node.part_locs
        if len(parts) > 3:
            raise Fail(node.loc, f"'{node.text}' has too many parts; write system.body.bvec at most")
        if len(parts) == 1:
            sym = scope.lookup(parts[0])
            if sym is not None and sym.kind == "bvec" and sym.value.body is None:
                return sym.value
            if sym is not None and sym.kind == "body":
                body: BodyB = sym.value
                raise Fail(locs[0], f"'{parts[0]}' is a body; name one of its bound vectors: "
                            + ", ".join(f"{parts[0]}.{b}" for b in body.bvecs))
            if sym is not None:
                raise Fail(locs[0], f"'{parts[0]}' is {KIND_WORDS[sym.kind]}, not an inertial bound vector")
            inertial = [n for n in scope.visible("bvec") if scope.lookup(n).value.body is None]
            raise Fail(locs[0], f"unknown inertial bound vector '{parts[0]}'{did_you_mean(parts[0], inertial)}")
        if len(parts) == 3:
            sym = scope.lookup(parts[0])
            if sym is None or sym.kind != "system":
                systems = scope.visible("system")
                if sym is None:
                    raise Fail(locs[0], f"unknown rigidBodySystem '{parts[0]}'{did_you_mean(parts[0], systems)}")
                raise Fail(locs[0], f"'{parts[0]}' is {KIND_WORDS[sym.kind]}, not a rigidBodySystem")
            system: SystemB = sym.value
            body = system.bodies.get(parts[1])
            if body is None:
                raise Fail(
                    locs[1],
                    f"system '{system.name}' has no body '{parts[1]}'{did_you_mean(parts[1], system.bodies)}",
                )
            return self.body_bvec(body, parts[2], locs[2])
        sym = scope.lookup(parts[0])
        if sym is None:
            for system in self.systems:
                if parts[0] in system.bodies and system is not ctx.system:
                    raise Fail(
                        locs[0],
                        f"body '{parts[0]}' belongs to rigidBodySystem '{system.name}'; "
                        f"outside it, write {system.name}.{node.text}",
                    )
            raise Fail(locs[0], f"unknown body '{parts[0]}'{did_you_mean(parts[0], scope.visible('body'))}")
        if sym.kind == "system":
            raise Fail(locs[0], f"'{parts[0]}' is a rigidBodySystem; write {parts[0]}.body.bvec")
        if sym.kind != "body":
            raise Fail(locs[0], f"'{parts[0]}' is {KIND_WORDS[sym.kind]}, not a body")
        return self.body_bvec(sym.value, parts[1], locs[1])

    def body_bvec(self, body: BodyB, name: str, loc: Loc) -> BvecB | None:
        if body.poisoned and name not in body.bvecs:
            return None
        bvec = body.bvecs.get(name)
        if bvec is None:
            raise Fail(loc, f"body '{body.name}' has no bound vector '{name}'{did_you_mean(name, body.bvecs)}")
        return bvec


def _poison(ctx: Ctx, s: A.Node) -> None:
    """Statement ``s`` building a body or bvec failed: its owner is incomplete, so
    later checks of it (no innerLam, no pos, ...) would only echo the first error."""
    if ctx.bvec is not None:
        ctx.bvec.poisoned = True
    elif ctx.body is not None:
        if isinstance(s, A.If):  # a skipped branch may have declared bvecs
            ctx.body.poisoned = True
        else:
            ctx.body.failed = True


def _checked_limits(s: A.Constraint, values: list[float], what: str, unit: str, span_unit: str):
    """(lower, upper) of a revolute or prismatic joint with 5 arguments, checked; else None.
    ``values`` are the evaluated arguments after the two ends."""
    if len(values) != 3:
        return None
    rest, lower, upper = values
    if not lower < upper:
        raise Fail(
            s.args[3].loc,
            f"the lower joint limit ({lower:g}{unit}) must be below the upper one ({upper:g}{unit}); "
            "a joint that cannot move is constraint fixed(a, b)",
        )
    if s.kind == "revolute" and upper - lower > 360.0:
        raise Fail(
            s.args[3].loc,
            f"joint limits {lower:g}..{upper:g} deg span more than a full turn; "
            "leave them out for a joint without limits",
        )
    if not lower <= rest <= upper:
        raise Fail(
            s.args[2].loc,
            f"the default {what} {rest:g}{span_unit} is outside the joint limits {lower:g}..{upper:g}{span_unit}",
        )
    return lower, upper


def analyze(stmts: tuple[A.Node, ...], text: str, path: str) -> ModelSpec:
    """Execute a parsed spec and return its model (raises SpecError with every error)."""
    return Analyzer(text, path).run(stmts)
