"""Count the refused inputs the test suite covers: ``python tests/refusals.py``.

A refused input is a ``with pytest.raises(...)`` block (the API or the command line's usage
errors, ``SystemExit``) or a command-line run asserted to exit with 1 (``main([...]) == 1``),
counted once per place in the tests, and once per parameter of a parametrized test. Warnings
(``pytest.warns``) are counted apart: inputs accepted, but said to be wrong.
"""

from __future__ import annotations

import ast
import sys
from collections import Counter
from pathlib import Path

HERE = Path(__file__).resolve().parent


def _params(function: ast.FunctionDef) -> int:
    """How many times a test runs: the product of its parametrize lists' lengths."""
    runs = 1
    for deco in function.decorator_list:
        if (isinstance(deco, ast.Call) and getattr(deco.func, "attr", "") == "parametrize"
                and len(deco.args) > 1 and isinstance(deco.args[1], ast.List | ast.Tuple)):
            runs *= len(deco.args[1].elts)
    return runs


def _is_call(node: ast.AST, name: str) -> bool:
    return isinstance(node, ast.Call) and (getattr(node.func, "attr", None) == name
                                           or getattr(node.func, "id", None) == name)


def count(folder: Path = HERE) -> Counter[str]:
    """``refused`` and ``warned`` inputs, and ``files`` that hold any."""
    out: Counter[str] = Counter()
    for path in sorted(folder.glob("test_*.py")):
        tree = ast.parse(path.read_text())
        found = False
        for function in [n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)
                         and n.name.startswith("test_")]:
            runs = _params(function)
            for node in ast.walk(function):
                if isinstance(node, ast.With):
                    for item in node.items:
                        if _is_call(item.context_expr, "raises"):
                            out["refused"] += runs
                            found = True
                        elif _is_call(item.context_expr, "warns"):
                            out["warned"] += runs
                elif (isinstance(node, ast.Compare) and _is_call(node.left, "main")
                      and isinstance(node.ops[0], ast.Eq)
                      and isinstance(node.comparators[0], ast.Constant)
                      and node.comparators[0].value == 1):
                    out["refused"] += runs
                    found = True
        out["files"] += found
    return out


if __name__ == "__main__":
    counts = count(Path(sys.argv[1]) if len(sys.argv) > 1 else HERE)
    print(f"refused inputs: {counts['refused']} (in {counts['files']} test files); "
          f"inputs accepted with a warning: {counts['warned']}")
