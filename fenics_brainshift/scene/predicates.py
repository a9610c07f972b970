"""Coordinate predicates such as ``z < 0.01 or y > 0.05``, parsed without eval.

The text is parsed by Python's ``ast`` and walked by a small interpreter that knows only
numbers, the names x, y, z, arithmetic (+ - * / **), comparisons (chained too), and/or/not,
parentheses and abs(a), sqrt(a), min(a, b, ...), max(a, b, ...). Anything else, a call with
the wrong number of arguments, or a number that overflows is rejected with a message that
says what is allowed. The result is vectorised: it takes coordinates of shape (3, N) and returns a
boolean array of length N.
"""

from __future__ import annotations

import ast
import functools
import math
import operator
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from .checks import did_you_mean

_BINARY = {
    ast.Add: operator.add,
    ast.Sub: operator.sub,
    ast.Mult: operator.mul,
    ast.Div: operator.truediv,
    ast.Pow: operator.pow,
}
_COMPARE = {
    ast.Lt: operator.lt,
    ast.LtE: operator.le,
    ast.Gt: operator.gt,
    ast.GtE: operator.ge,
}
# name: (function of a list of arguments, fewest arguments, most arguments or None)
_FUNCTIONS = {
    "abs": (lambda args: np.abs(args[0]), 1, 1),
    "sqrt": (lambda args: np.sqrt(args[0]), 1, 1),
    "min": (lambda args: functools.reduce(np.minimum, args), 2, None),
    "max": (lambda args: functools.reduce(np.maximum, args), 2, None),
}
_NAMES = {"x": 0, "y": 1, "z": 2}
# Bounds that keep the parser and the interpreter (both recursive) far inside Python's stack:
# the bundled scenes' conditions are at most 101 characters and 8 levels deep
MAX_LENGTH = 2000  # characters
MAX_DEPTH = 40  # nested operations
ALLOWED = "numbers, x, y, z, + - * / **, < <= > >=, and, or, not, ( ), abs(a), sqrt(a), min(a, b, ...), max(a, b, ...)"


class PredicateError(InputError):
    """A condition that cannot be used; the caller prefixes the field's name."""


@dataclass(frozen=True)
class Predicate:
    """A parsed coordinate predicate; call it with x of shape (3, N)."""

    text: str
    _tree: ast.AST

    def __call__(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x)
        with np.errstate(all="ignore"):  # x**-1 at x = 0 is inf, and inf compares as it should
            value = _evaluate(self._tree, x)
        if np.ndim(value) == 0 or np.asarray(value).dtype != bool:
            raise PredicateError(f"'{self.text}' is not a condition (use < <= > >=)")
        return np.broadcast_to(value, x.shape[1:]).copy()


def parse_predicate(text: str) -> Predicate:
    """Parse and check a predicate; raises PredicateError naming what is wrong."""
    if not isinstance(text, str) or not text.strip():
        raise PredicateError("must be a non-empty condition such as 'z < 0.01'")
    short = text if len(text) <= 60 else text[:57] + "..."
    if len(text) > MAX_LENGTH:
        raise PredicateError(
            f"'{short}' is {len(text)} characters long (at most {MAX_LENGTH}); write a shorter condition"
        )
    if "\x00" in text:  # (Python's parser refuses it, as ValueError before 3.12 and SyntaxError since)
        raise PredicateError(f"'{short.encode('unicode_escape').decode()}' holds a NUL character; remove it")
    try:
        tree = ast.parse(text.strip(), mode="eval").body
    except SyntaxError as exc:
        raise PredicateError(f"cannot parse '{short}': {exc.msg}") from None
    except (RecursionError, MemoryError):  # (ast's own recursion, before the depth can be measured)
        raise PredicateError(f"'{short}' is nested too deep (at most {MAX_DEPTH} levels); simplify it") from None
    if (depth := _depth(tree)) > MAX_DEPTH:
        raise PredicateError(f"'{short}' is nested {depth} levels deep (at most {MAX_DEPTH}); simplify it")
    _check(tree, short)
    pred = Predicate(text, tree)
    pred(np.zeros((3, 1)))  # type-check on a probe point: conditions only
    return pred


def _depth(tree: ast.AST) -> int:
    """The depth of the tree's expressions (operators and contexts not counted), measured
    without recursion."""
    deepest, stack = 0, [(tree, 1)]
    while stack:
        node, level = stack.pop()
        deepest = max(deepest, level)
        stack.extend((child, level + isinstance(child, ast.expr)) for child in ast.iter_child_nodes(node))
    return deepest


def _check(node: ast.AST, text: str) -> None:
    ok = (
        ast.BoolOp,
        ast.UnaryOp,
        ast.BinOp,
        ast.Compare,
        ast.Name,
        ast.Constant,
        ast.Call,
        ast.And,
        ast.Or,
        ast.Not,
        ast.USub,
        ast.UAdd,
        ast.Load,
        *_BINARY,
        *_COMPARE,
    )
    for sub in ast.walk(node):
        if not isinstance(sub, ok):
            raise PredicateError(f"'{text}' uses {type(sub).__name__}; allowed: {ALLOWED}")
        if isinstance(sub, ast.Name) and sub.id not in _NAMES and sub.id not in _FUNCTIONS:
            hint = did_you_mean(sub.id, [*_NAMES, *_FUNCTIONS])
            raise PredicateError(f"'{text}' uses unknown name '{sub.id}';{hint} allowed: {ALLOWED}")
        if isinstance(sub, ast.Constant) and (isinstance(sub.value, bool) or not isinstance(sub.value, (int, float))):
            raise PredicateError(f"'{text}' has a non-numeric constant {sub.value!r}")
        if isinstance(sub, ast.Constant) and not _finite(sub.value):
            raise PredicateError(f"'{text}': the number {str(sub.value)[:20]}... is out of range")
        if isinstance(sub, ast.BinOp) and isinstance(sub.op, ast.Pow):
            base, power = (_constant(n) for n in (sub.left, sub.right))
            if base is not None and power is not None and not _finite_power(base, power):
                raise PredicateError(f"'{text}': {ast.unparse(sub)} is out of range")
        if isinstance(sub, ast.Call):
            if not isinstance(sub.func, ast.Name) or sub.func.id not in _FUNCTIONS or sub.keywords:
                raise PredicateError(f"'{text}' calls something other than {list(_FUNCTIONS)}")
            name, count = sub.func.id, len(sub.args)
            _, fewest, most = _FUNCTIONS[name]
            if count < fewest or (most is not None and count > most):
                wanted = f"exactly {fewest}" if most == fewest else f"at least {fewest}"
                raise PredicateError(
                    f"'{text}': {name}() takes {wanted} argument{'s' if fewest > 1 else ''} (got {count})"
                )


def _finite(value) -> bool:
    try:
        return math.isfinite(float(value))
    except OverflowError:  # an integer literal too large for a float
        return False


def _constant(node: ast.AST):
    """The value of a numeric literal, signed or not; None for anything else."""
    if isinstance(node, ast.Constant) and isinstance(node.value, (int, float)):
        return float(node.value)
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, (ast.USub, ast.UAdd)):
        value = _constant(node.operand)
        return None if value is None else (-value if isinstance(node.op, ast.USub) else value)
    return None


def _finite_power(base: float, power: float) -> bool:
    try:
        return math.isfinite(math.pow(base, power))
    except (OverflowError, ValueError):  # 10**400; a negative base to a fractional power
        return False


def _evaluate(node: ast.AST, x: np.ndarray):
    if isinstance(node, ast.Constant):
        return np.float64(node.value)  # numpy arithmetic: overflow gives inf, not an exception
    if isinstance(node, ast.Name):
        if node.id not in _NAMES:
            raise PredicateError(f"'{node.id}' is a function; call it like {node.id}(x)")
        return x[_NAMES[node.id]]
    if isinstance(node, ast.UnaryOp):
        value = _evaluate(node.operand, x)
        if isinstance(node.op, ast.Not):
            return np.logical_not(value)
        return -value if isinstance(node.op, ast.USub) else value
    if isinstance(node, ast.BinOp):
        return _BINARY[type(node.op)](_evaluate(node.left, x), _evaluate(node.right, x))
    if isinstance(node, ast.BoolOp):
        combine = np.logical_and if isinstance(node.op, ast.And) else np.logical_or
        result = _evaluate(node.values[0], x)
        for value in node.values[1:]:
            result = combine(result, _evaluate(value, x))
        return result
    if isinstance(node, ast.Compare):
        left = _evaluate(node.left, x)
        result = True
        for op, right_node in zip(node.ops, node.comparators):
            right = _evaluate(right_node, x)
            result = np.logical_and(result, _COMPARE[type(op)](left, right))
            left = right
        return result
    if isinstance(node, ast.Call):
        function = _FUNCTIONS[node.func.id][0]
        return function([_evaluate(a, x) for a in node.args])
    raise PredicateError(f"unsupported expression {ast.dump(node)}")
