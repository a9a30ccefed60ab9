"""Comments say why: no comment or docstring in the library quotes a measurement (it goes on docs/results.md with
its command, and the code points to the benchmark by name)."""

import ast
import io
import re
import tokenize
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LIBRARY = ("models", "recordings", "perception", "outputs", "runtime", "pipeline")
# A machine's load, a date, a speed-up, a seed tally, a step time, a fault count.
MEASURED = re.compile(
    r"\bload \d|\b20\d\d-\d\d-\d\d\b|\d(\.\d+)?x (faster|slower)|\d+ of \d+ seeds|\bseeds \d+-\d+|"
    r"\d(\.\d+)? ?ms (a|per) |\d[\d,]* (minor )?faults|\bmeasured[:,]? \d",
    re.I,
)


def texts(path: Path):
    """(line, text) of every comment and docstring of a Python file."""
    source = path.read_text()
    for token in tokenize.generate_tokens(io.StringIO(source).readline):
        if token.type == tokenize.COMMENT:
            yield token.start[0], token.string
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            doc = ast.get_docstring(node, clean=False)
            if doc:
                yield from ((node.body[0].lineno + i, line) for i, line in enumerate(doc.splitlines()))


def test_no_comment_in_the_library_quotes_a_measurement():
    found = [
        f"{path.relative_to(ROOT)}:{line}: {text.strip()}"
        for folder in LIBRARY
        for path in sorted((ROOT / folder).rglob("*.py"))
        for line, text in texts(path)
        if MEASURED.search(text)
    ]
    assert not found, "measured figures in comments (move them to docs/results.md):\n" + "\n".join(found)


def test_the_check_finds_what_it_looks_for():
    for text in ("load 2.7-3.4 on 2 cores", "measured 2026-11-22", "1.4x faster", "2 of 10 seeds", "0.5 ms a step"):
        assert MEASURED.search(text), text
    assert not MEASURED.search("(B, d, M, dy): one row per time step, at most 10 observations")
