"""Expressions of the language: C-like arithmetic and logic on doubles and bools, and the
maths functions (trigonometry in degrees), evaluated with type checks and value errors
that point at the operand (:class:`Fail`); a value that already failed (:data:`POISON`)
passes through silently."""

from __future__ import annotations

import math

from ..errors import did_you_mean
from ..model import Loc
from . import ast as A
from .symbols import KIND_WORDS, POISON, Fail, Scope

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
#: statements that look like calls, and the block each belongs in
STATEMENTS = {"innerLam": "body", "outerLam": "body", "pos": "bvec", "orient": "bvec"}


class Expressions:
    """Evaluates expressions in a scope; ``dry`` > 0: only type-check (the operand a short
    circuit or '?:' skips)."""

    def __init__(self):
        self.dry = 0

    def eval(self, e: A.Node, scope: Scope) -> tuple[str, object]:
        if isinstance(e, A.Number):
            if not math.isfinite(e.value):
                raise Fail(e.loc, "this number is too large")
            return "double", POISON if self.dry else e.value
        if isinstance(e, A.Bool):
            return "bool", POISON if self.dry else e.value
        if isinstance(e, A.Name):
            if len(e.parts) > 1:
                raise Fail(e.loc, f"'{e.text}' is a bound-vector reference; only a constraint can use it")
            sym = scope.lookup(e.parts[0])
            if sym is None:
                raise Fail(e.loc, f"unknown variable '{e.parts[0]}'{did_you_mean(e.parts[0], scope.visible('var'))}")
            if sym.kind != "var":
                raise Fail(e.loc, f"'{e.parts[0]}' is {KIND_WORDS[sym.kind]}, not a variable")
            if self.dry:
                return sym.type, POISON
            if sym.value is None:
                raise Fail(e.loc, f"variable '{e.parts[0]}' is used before it is given a value")
            return sym.type, sym.value
        if isinstance(e, A.UnOp):
            t, v = self.eval(e.operand, scope)
            if e.op == "!":
                if t != "bool":
                    raise Fail(e.loc, f"'!' needs a bool, not {t}")
                return "bool", POISON if v is POISON else (not v)
            if t != "double":
                raise Fail(e.loc, f"unary '{e.op}' needs a double, not {t}")
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
                raise Fail(e.test.loc, f"the condition of '?:' must be bool, not {t}")
            t1, v1 = self.eval_dry(e.then, scope, v is POISON or not v)
            t2, v2 = self.eval_dry(e.other, scope, v is POISON or bool(v))
            if t1 != t2:
                raise Fail(e.loc, f"the two branches of '?:' differ in type ({t1} and {t2})")
            if v is POISON:
                return t1, POISON
            return t1, v1 if v else v2
        if isinstance(e, A.Call):
            return self.eval_call(e, scope)
        raise Fail(e.loc, "this is not an expression")

    def eval_dry(self, e: A.Node, scope: Scope, dry: bool = True) -> tuple[str, object]:
        """Evaluate ``e``, or with ``dry`` only type-check it: its value is POISON and
        no value error (division by zero, sqrt(-1), ...) is raised."""
        self.dry += dry
        try:
            return self.eval(e, scope)
        finally:
            self.dry -= dry

    def eval_binop(self, e: A.BinOp, tl: str, vl: object, scope: Scope) -> tuple[str, object]:
        """``e`` whose left operand has the value ``vl`` of type ``tl``."""
        op = e.op
        if op in ("&&", "||"):
            if tl != "bool":
                raise Fail(e.left.loc, f"'{op}' needs bool operands; the left one is {tl}")
            if vl is not POISON and ((op == "&&" and not vl) or (op == "||" and vl)):
                tr, _ = self.eval_dry(e.right, scope)  # short circuit: type-check only
                if tr != "bool":
                    raise Fail(e.right.loc, f"'{op}' needs bool operands; the right one is {tr}")
                return "bool", vl
            tr, vr = self.eval(e.right, scope)
            if tr != "bool":
                raise Fail(e.right.loc, f"'{op}' needs bool operands; the right one is {tr}")
            return "bool", POISON if POISON in (vl, vr) else vr
        tr, vr = self.eval(e.right, scope)
        if op in ("==", "!="):
            if tl != tr:
                raise Fail(e.loc, f"cannot compare {tl} with {tr}")
            if POISON in (vl, vr):
                return "bool", POISON
            return "bool", (vl == vr) if op == "==" else (vl != vr)
        if tl != "double" or tr != "double":
            bad = e.left.loc if tl != "double" else e.right.loc
            raise Fail(bad, f"'{op}' needs double operands, not {tl} and {tr}")
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
            raise Fail(loc, "division by zero") from None
        except ValueError:
            raise Fail(loc, f"'{op}' is undefined for {a:g} and {b:g}") from None
        if not math.isfinite(r):
            raise Fail(loc, f"'{op}' overflows ({a:g} {op} {b:g})")
        return float(r)

    def eval_call(self, e: A.Call, scope: Scope) -> tuple[str, object]:
        if e.func not in FUNCTIONS:
            sym = scope.lookup(e.func)
            if sym is not None and sym.kind == "func":
                raise Fail(e.loc, f"body function '{e.func}' makes a body; write '{e.func} name(...);' in a rigidBodySystem")
            if e.func in STATEMENTS:
                raise Fail(e.loc, f"'{e.func}' is a statement and has no value")
            raise Fail(e.loc, f"unknown function '{e.func}'{did_you_mean(e.func, FUNCTIONS)}")
        nargs, fn = FUNCTIONS[e.func]
        if len(e.args) != nargs:
            raise Fail(e.loc, f"'{e.func}' takes {nargs} argument{'s' if nargs > 1 else ''}, not {len(e.args)}")
        vals = []
        poisoned = False
        for a in e.args:
            t, v = self.eval(a, scope)
            if t != "double":
                raise Fail(a.loc, f"'{e.func}' takes doubles; this argument is {t}")
            poisoned = poisoned or v is POISON
            vals.append(v)
        if poisoned:
            return "double", POISON
        try:
            r = fn(*vals)
        except (ValueError, ZeroDivisionError):
            shown = ", ".join(f"{v:g}" for v in vals)
            raise Fail(e.loc, f"'{e.func}({shown})' is undefined") from None
        except OverflowError:
            raise Fail(e.loc, f"'{e.func}' overflows") from None
        r = float(r)
        if not math.isfinite(r):
            raise Fail(e.loc, f"'{e.func}' overflows")
        return "double", r
