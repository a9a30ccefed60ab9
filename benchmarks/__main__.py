"""`python -m benchmarks [NAME [OPTIONS...] | all]`: list the benchmarks, run one, or run them all.

    python -m benchmarks                      # each benchmark's name and what it measures
    python -m benchmarks replay               # python -m benchmarks.bench_replay
    python -m benchmarks replay --steps 500   # the benchmark's own options follow its name (NAME --help)
    python -m benchmarks all                  # every one with its defaults, one after another (some take minutes),
                                              # but those that take hours (a module's `IN_ALL = False`): by name only

Each runs in its own process, as `python -m benchmarks.bench_NAME` would: the benchmarks set threads and
start processes of their own.
"""

from __future__ import annotations

import ast
import subprocess
import sys
import time
from pathlib import Path

FOLDER = Path(__file__).resolve().parent
PREFIX = "bench_"


def benchmarks() -> dict[str, str]:
    """Name -> the first line of its docstring, read from the source (importing one loads torch)."""
    found = {}
    for path in sorted(FOLDER.glob(f"{PREFIX}*.py")):
        doc = ast.get_docstring(ast.parse(path.read_text(encoding="utf-8"))) or ""
        found[path.stem.removeprefix(PREFIX)] = doc.splitlines()[0] if doc else ""
    return found


def in_all(name: str) -> bool:
    """Whether `all` runs benchmark `name`: unless its module sets `IN_ALL = False` (read from the source)."""
    tree = ast.parse((FOLDER / f"{PREFIX}{name}.py").read_text(encoding="utf-8"))
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", None) == "IN_ALL" for t in node.targets):
            return bool(ast.literal_eval(node.value))
    return True


def run(name: str, options: list[str]) -> int:
    """Run benchmark `name` with `options` in a new process; returns its exit status."""
    command = [sys.executable, "-m", f"benchmarks.{PREFIX}{name}", *options]
    print(f"== {name}: {' '.join(command[1:])}", flush=True)
    start = time.perf_counter()
    status = subprocess.run(command, cwd=FOLDER.parent).returncode
    print(f"== {name}: exit {status} after {time.perf_counter() - start:.1f} s", flush=True)
    return status


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    known = benchmarks()
    if not argv or argv[0] in ("-h", "--help"):
        width = max(map(len, known))
        print("benchmarks (python -m benchmarks NAME [OPTIONS...], or all):")
        print("\n".join(f"  {name:<{width}}  {line}" for name, line in known.items()))
        return 0
    name, options = argv[0], argv[1:]
    if name == "all":
        if options:
            print("python -m benchmarks all: takes no options (run one benchmark to give its options)", file=sys.stderr)
            return 2
        skipped = [each for each in known if not in_all(each)]
        if skipped:
            print(f"== not in all (hours with their defaults; run each by name): {', '.join(skipped)}", flush=True)
        failed = [each for each in known if each not in skipped and run(each, [])]
        if failed:
            print(f"failed: {', '.join(failed)}", file=sys.stderr)
        return 1 if failed else 0
    if name not in known:
        print(f"python -m benchmarks: no benchmark {name!r}; choose one of {', '.join(known)} or all", file=sys.stderr)
        return 2
    return run(name, options)


if __name__ == "__main__":
    sys.exit(main())
