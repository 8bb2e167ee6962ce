"""Lane form of per-trajectory code: the kernel integrates W trajectories at once.

The kernel keeps a group of W trajectories in structure-of-arrays form (element i of lane k
at index i * W + k), so that each arithmetic instruction works on W trajectories (kernel.WIDTH:
eight, two AVX2 registers of four doubles). Hooks and the kernel's own sections are written for ONE trajectory with flat
element indexing (`out[j]`, `p[0]`, `ctx[CTX_R]`); this module rewrites such code for lane k:
every subscript of a lane array, `a[i]`, becomes `a[i * W + k]`. The physics is written once.

Rules for a hook (checked; `HookFormError` names the hook and the rule):
  - index its array arguments one element at a time (no slices, no `a.shape`, no passing an
    array on to another function);
  - return nothing (`return` ends the hook early, for this lane only).
"""

from __future__ import annotations

import ast
import builtins
import inspect
import textwrap
import types
from collections.abc import Callable, Iterable

LANE = "k"  # the lane variable of the generated kernel


class HookFormError(ValueError):
    """A hook (or kernel section) that cannot be rewritten into lane form."""


class _ToLane(ast.NodeTransformer):
    def __init__(self, arrays: set[str], width: int, lane: str, where: str) -> None:
        self.arrays, self.width, self.lane, self.where = arrays, width, lane, where

    def visit_Subscript(self, node: ast.Subscript) -> ast.AST:
        self.generic_visit(node)
        if isinstance(node.value, ast.Name) and node.value.id in self.arrays:
            if isinstance(node.slice, (ast.Slice, ast.Tuple)):
                raise HookFormError(f"{self.where}: `{ast.unparse(node)}`: index lane arrays one element at a time")
            node.slice = ast.BinOp(ast.BinOp(node.slice, ast.Mult(), ast.Constant(self.width)), ast.Add(),
                                   ast.Name(self.lane, ast.Load()))
        return node


def _check_bare(tree: ast.AST, arrays: set[str], where: str) -> None:
    """Lane arrays may only appear subscripted."""
    allowed = {id(node.value) for node in ast.walk(tree)
               if isinstance(node, ast.Subscript) and isinstance(node.value, ast.Name)}
    for node in ast.walk(tree):
        if isinstance(node, ast.Name) and node.id in arrays and id(node) not in allowed:
            raise HookFormError(f"{where}: array `{node.id}` used whole; index it one element at a time")


def lane_block(code: str, arrays: Iterable[str], width: int, where: str = "kernel section",
               uses_lane: bool = False) -> str:
    """Per-trajectory statements -> `for k in range(width):` over the lanes, arrays re-indexed.
    `uses_lane`: the code reads the lane number k itself (e.g. to pick its trajectory)."""
    arrays = set(arrays)
    tree = ast.parse(textwrap.dedent(code))
    _check_bare(tree, arrays, where)
    for node in ast.walk(tree):
        if not uses_lane and isinstance(node, ast.Name) and node.id == LANE:
            raise HookFormError(f"{where}: `{LANE}` is the lane variable; name the loop otherwise")
    tree = _ToLane(arrays, width, LANE, where).visit(tree)
    body = ast.unparse(ast.fix_missing_locations(tree))
    return f"for {LANE} in range({width}):\n" + textwrap.indent(body, "    ")


def lane_function(fn: Callable, name: str, width: int, prefix: str) -> tuple[str, dict[str, tuple[object, str]]]:
    """Source of `name(<fn's arguments>, k)`: fn applied to lane k of lane arrays of width W.

    Every argument of a hook is an array (terms.py). Each global the hook reads is renamed
    prefix + its name, so it can clash neither with the kernel's own names nor with another
    module's. Returns the source and {renamed global: (object, name in the hook's module)},
    which the generated module must import."""
    py = getattr(fn, "py_func", fn)
    where = f"hook {py.__module__}.{py.__name__}"
    if py.__code__.co_freevars:
        raise HookFormError(f"{where}: reads variables of an enclosing function ({', '.join(py.__code__.co_freevars)}); "
                            "hooks are module-level functions")
    try:
        tree = ast.parse(textwrap.dedent(inspect.getsource(py)))
    except (OSError, TypeError) as exc:  # pragma: no cover - hooks are always module functions
        raise HookFormError(f"{where}: source not available ({exc})") from exc
    func = tree.body[0]
    if not isinstance(func, ast.FunctionDef):
        raise HookFormError(f"{where}: not a plain function")
    for deco in func.decorator_list:
        target = deco.func if isinstance(deco, ast.Call) else deco
        if not (isinstance(target, ast.Name) and target.id in ("njit", "jit")):
            raise HookFormError(f"{where}: decorated with `{ast.unparse(deco)}`; hooks take numba's @njit only")
    args = func.args
    if args.posonlyargs or args.kwonlyargs or args.vararg or args.kwarg or args.defaults:
        raise HookFormError(f"{where}: arguments must be plain positional ones, as in terms.py")
    arrays = {a.arg for a in args.args}
    if LANE in arrays:
        raise HookFormError(f"{where}: an argument is named `{LANE}`, the lane variable")
    for node in ast.walk(func):
        if isinstance(node, ast.Return) and node.value is not None:
            raise HookFormError(f"{where}: hooks return nothing (they write into their arrays)")
        if isinstance(node, ast.Name) and node.id == LANE:
            raise HookFormError(f"{where}: uses the name `{LANE}`, the lane variable")
        if node is not func and isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda, ast.ClassDef)):
            raise HookFormError(f"{where}: defines a function or class inside; keep helpers at module level")
    _check_bare(func, arrays, where)
    func = _ToLane(arrays, width, LANE, where).visit(func)
    func.decorator_list = []
    func.name = name
    args.args.append(ast.arg(LANE))
    func.returns = None
    local = {a.arg for a in args.args}
    for node in ast.walk(func):
        if isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
            local.add(node.id)
    needed: dict[str, tuple[object, str]] = {}
    for node in ast.walk(func):
        if isinstance(node, ast.Name) and isinstance(node.ctx, ast.Load) and node.id not in local:
            if node.id in py.__globals__:
                needed[prefix + node.id] = (py.__globals__[node.id], node.id)
                node.id = prefix + node.id
            elif not hasattr(builtins, node.id):
                raise HookFormError(f"{where}: unknown name `{node.id}`")
    return ast.unparse(ast.fix_missing_locations(func)), needed


def import_line(alias: str, obj: object, name: str, module: str) -> str:
    """The import that binds `alias` to `obj`, which the hook's `module` knows as `name`."""
    if isinstance(obj, types.ModuleType):
        return f"import {obj.__name__} as {alias}"
    return f"from {module} import {name} as {alias}"
