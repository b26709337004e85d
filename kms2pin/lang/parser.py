"""Text -> AST with positions, using the Lark grammar in ``grammar.lark``."""

from __future__ import annotations

import re
from functools import lru_cache

from lark import Lark, Token, Transformer
from lark.exceptions import UnexpectedCharacters, UnexpectedEOF, UnexpectedInput, UnexpectedToken

from ..errors import Diagnostic, SpecError
from ..model import Loc
from . import ast as A

_TERMINAL_WORDS = {
    "NAME": "a name",
    "NUMBER": "a number",
    "TYPE": "'double' or 'bool'",
    "ASSIGN_OP": "'='",
    "ADD_OP": "'+' or '-'",
    "MUL_OP": "'*', '/' or '%'",
    "REL_OP": "a comparison",
    "EQ_OP": "'==' or '!='",
    "UNARY_OP": "'!'",
    "OR": "'||'",
    "AND": "'&&'",
    "$END": "end of file",
}

# the lexer's view of comments, so an unclosed '/*' (which it reads as '/' and '*') can be named
_COMMENTS = re.compile(r"//[^\n]*|/\*.*?\*/|(/\*)", re.S)


def _loc(meta_or_token) -> Loc:
    return Loc(getattr(meta_or_token, "line", 0) or 0, getattr(meta_or_token, "column", 0) or 0)


class _ToAst(Transformer):
    """Builds :mod:`kms2pin.lang.ast` nodes while parsing (Lark's inline LALR
    transformer: no parse tree); every node's location is its first token's."""

    def start(self, items):
        return tuple(items)

    def empty(self, items):
        return A.Empty(_loc(items[0]))

    def var_decl(self, items):
        type_, name = items[0], items[1]
        init = items[2] if len(items) > 2 else None
        return A.VarDecl(_loc(type_), str(type_), str(name), _loc(name), init)

    def assign(self, items):
        name, op, value = items
        return A.Assign(_loc(name), str(name), str(op), value)

    def if_stmt(self, items):
        kw, test, then, other = items
        return A.If(_loc(kw), test, then, other)

    def block(self, items):
        brace, *body = items
        return A.Block(_loc(brace), tuple(body))

    def call_stmt(self, items):
        name, args = items
        return A.CallStmt(_loc(name), str(name), tuple(args or ()))

    def bvec_def(self, items):
        kw, name, *body = items
        return A.BvecDef(_loc(kw), str(name), _loc(name), tuple(body))

    def body_literal(self, items):
        kw, name, *body = items
        return A.BodyLiteral(_loc(kw), str(name), _loc(name), tuple(body))

    def body_func_def(self, items):
        kw, name, params, *body = items
        return A.BodyFuncDef(_loc(kw), str(name), _loc(name), tuple(params or ()), tuple(body))

    def body_instance(self, items):
        func, name, args = items
        return A.BodyInstance(_loc(func), str(func), str(name), _loc(name), tuple(args or ()))

    def system_def(self, items):
        kw, name, *body = items
        return A.SystemDef(_loc(kw), str(name), _loc(name), tuple(body))

    def constraint(self, items):
        kw, kind, args = items
        return A.Constraint(_loc(kw), str(kind), _loc(kind), tuple(args or ()))

    def params(self, items):
        return tuple(items)

    def param(self, items):
        type_, name = items
        return A.Param(_loc(name), str(type_), str(name))

    def args(self, items):
        return tuple(items)

    def cond(self, items):
        return A.Cond(items[0].loc, *items)

    def binop(self, items):
        left, op, right = items
        return A.BinOp(_loc(op), str(op), left, right)

    def unop(self, items):
        op, operand = items
        return A.UnOp(_loc(op), str(op), operand)

    def number(self, items):
        return A.Number(_loc(items[0]), float(items[0]))

    def true(self, items):
        return A.Bool(_loc(items[0]), True)

    def false(self, items):
        return A.Bool(_loc(items[0]), False)

    def dotted(self, items):
        return A.Name(_loc(items[0]), tuple(str(t) for t in items), tuple(_loc(t) for t in items))

    def call(self, items):
        name, args = items
        return A.Call(_loc(name), str(name), tuple(args or ()))


@lru_cache(maxsize=1)
def _parser() -> Lark:
    return Lark.open(
        "grammar.lark",
        rel_to=__file__,
        parser="lalr",
        maybe_placeholders=True,
        transformer=_ToAst(),
        cache=True,
    )


def _describe_expected(parser: Lark, expected: set[str]) -> str:
    words = []
    for name in sorted(expected):
        if name in _TERMINAL_WORDS:
            words.append(_TERMINAL_WORDS[name])
            continue
        try:
            pattern = parser.get_terminal(name).pattern
        except KeyError:
            words.append(name)
            continue
        words.append(f"'{pattern.value}'" if pattern.type == "str" else name.lower())
    words = sorted(set(words))
    if len(words) == 1:
        return words[0]
    return "one of " + ", ".join(words)


def _describe_token(tok: Token) -> str:
    if tok.type == "$END":
        return "end of file"
    return f"'{tok}'"


def _unterminated_comment(text: str) -> int | None:
    """Offset of the first '/*' that is never closed, or None."""
    for m in _COMMENTS.finditer(text):
        if m.group(1):
            return m.start()
    return None


def _error_offset(err: UnexpectedInput, text: str) -> int:
    if isinstance(err, UnexpectedCharacters):
        return err.pos_in_stream
    tok = getattr(err, "token", None)
    if tok is None or tok.type == "$END" or tok.start_pos is None:
        return len(text)
    return tok.start_pos


def _syntax_diagnostic(err: UnexpectedInput, text: str, path: str) -> Diagnostic:
    parser = _parser()
    lines = text.splitlines()
    comment = _unterminated_comment(text)
    if comment is not None and comment <= _error_offset(err, text):
        line = text.count("\n", 0, comment) + 1
        col = comment - (text.rfind("\n", 0, comment) + 1) + 1
        return Diagnostic(path, line, col, "unterminated comment", lines[line - 1])
    if isinstance(err, UnexpectedCharacters):
        line, col = err.line, err.column
        ch = text[err.pos_in_stream] if 0 <= err.pos_in_stream < len(text) else "?"
        message = f"unexpected character {ch!r}"
    elif isinstance(err, (UnexpectedToken, UnexpectedEOF)):
        expected = set(getattr(err, "expected", None) or getattr(err, "accepts", None) or ())
        tok = err.token
        line, col = getattr(tok, "line", None), getattr(tok, "column", None)
        what = _describe_expected(parser, expected) if expected else "something else"
        if tok is None or tok.type == "$END" or line is None:
            line = max(len(lines), 1)
            col = len(lines[-1]) + 1 if lines else 1
            message = f"unexpected end of file; expected {what}"
        else:
            message = f"unexpected {_describe_token(tok)}; expected {what}"
            prev = (getattr(err, "token_history", None) or [None])[-1]
            ends_statement = prev is not None and prev.type not in ("SEMI", "LBRACE", "RBRACE")
            if expected & {"SEMICOLON", "SEMI"} and ends_statement and prev.end_line is not None:
                if prev.end_line != line:
                    line, col = prev.end_line, prev.end_column
                    message = f"expected ';' after {_describe_token(prev)}"
    else:  # pragma: no cover - Lark has no other kinds
        line, col, message = getattr(err, "line", 1), getattr(err, "column", 1), str(err)
    line = max(int(line or 1), 1)
    col = max(int(col or 1), 1)
    source = lines[line - 1] if 0 < line <= len(lines) else ""
    return Diagnostic(path, line, col, f"syntax error: {message}", source)


def parse_text(text: str, path: str = "<string>") -> tuple[A.Node, ...]:
    """Parse spec text into a tuple of top-level statements (raises SpecError)."""
    try:
        return _parser().parse(text)
    except UnexpectedInput as err:
        raise SpecError([_syntax_diagnostic(err, text, path)]) from None
