"""docs/failures.md: every row of its failure tables names the tests that reproduce it, and they exist."""

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
DOC = REPO / "docs" / "failures.md"
REF = re.compile(r"`(tests/[\w/]+\.py)::(test_\w+)(?:\[[^\]`]*\])?`")


def failure_rows(text: str) -> list[tuple[str, str]]:
    """(first cell, test cell) of every data row of a table whose last column is 'test'."""
    rows, in_table = [], False
    for line in text.splitlines():
        if not line.startswith("|"):
            in_table = False
            continue
        cells = [c.strip() for c in line.strip().strip("|").split(" | ")]
        if set(line) <= set("|-: "):
            continue
        if cells[-1] == "test":
            in_table = True
        elif in_table:
            rows.append((cells[0], cells[-1]))
    return rows


def test_every_failure_row_names_tests_that_exist():
    """Each row's test cell names at least one test as `tests/<path>.py::test_name`, and each such
    function is defined in that file: a row cannot outlive the test that reproduces it."""
    rows = failure_rows(DOC.read_text())
    assert len(rows) >= 40
    problems = []
    for case, cell in rows:
        refs = REF.findall(cell)
        if not refs:
            problems.append(f"{case[:60]!r}: names no test as `tests/...py::test_name`")
        for path, name in refs:
            file = REPO / path
            if not file.is_file():
                problems.append(f"{case[:60]!r}: {path} does not exist")
            elif not re.search(rf"^(?:async )?def {name}\(", file.read_text(), re.M):
                problems.append(f"{case[:60]!r}: no {name} in {path}")
    assert not problems, "\n".join(problems)


def test_a_row_without_its_test_is_found(tmp_path):
    """The check itself: a row naming a missing function or no test at all is reported."""
    text = ("| input | now | test |\n|---|---|---|\n"
            "| a | b | `tests/unit/test_failures_doc.py::test_no_such_test` |\n| c | d | none |\n")
    rows = failure_rows(text)
    assert [r[0] for r in rows] == ["a", "c"]
    assert REF.findall(rows[0][1]) == [("tests/unit/test_failures_doc.py", "test_no_such_test")]
    assert REF.findall(rows[1][1]) == []
