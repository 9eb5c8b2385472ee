"""Long functions in the package, and whether each has its reason written beside it (issue 19).

Usage: .venv/bin/python benchmarks/bench_code_shape.py [--root src/evdense] [--max-lines 80]

Lists every function or method of more than ``--max-lines`` lines (from ``def`` to its last
line) and whether the comment block right above it (or above its decorators) gives a reason
("Over 80 lines ..." or "About 80 lines ..."). Prints the count without a reason last; issue 19's
target is 0.
"""

from __future__ import annotations

import argparse
import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def comment_above(lines: list[str], first: int) -> str:
    """The comment block that ends on the line before 1-based line ``first``."""
    out: list[str] = []
    i = first - 2
    while i >= 0 and lines[i].lstrip().startswith("#"):
        out.insert(0, lines[i].strip().lstrip("#").strip())
        i -= 1
    return " ".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", default=str(ROOT / "src" / "evdense"))
    ap.add_argument("--max-lines", type=int, default=80)
    args = ap.parse_args()
    rows = []
    for path in sorted(Path(args.root).rglob("*.py")):
        lines = path.read_text().splitlines()
        for node in ast.walk(ast.parse("\n".join(lines))):
            if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            n = node.end_lineno - node.lineno + 1
            if n <= args.max_lines:
                continue
            first = min([node.lineno] + [d.lineno for d in node.decorator_list])
            why = comment_above(lines, first)
            ok = why.startswith(("Over 80 lines", "About 80 lines"))
            rows.append((n, f"{path.relative_to(ROOT)}:{node.lineno}", node.name, ok))
    print("| lines | where | function | reason written |\n| --- | --- | --- | --- |")
    for n, where, name, ok in sorted(rows, reverse=True):
        print(f"| {n} | {where} | {name} | {'yes' if ok else 'NO'} |")
    missing = sum(not r[3] for r in rows)
    print(
        f"\n{len(rows)} functions over {args.max_lines} lines; {missing} without a written reason"
    )


if __name__ == "__main__":
    main()
