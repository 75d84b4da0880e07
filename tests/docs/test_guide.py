"""The user guide (mkdocs.yml, docs/): generated pages complete, no dangling citations, a strict build."""

from __future__ import annotations

import argparse
import importlib.util
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[2]


def _reference():
    spec = importlib.util.spec_from_file_location("docs_reference", REPO / "docs" / "_gen" / "reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _schema_properties(node, found):
    """Every (property name, node) anywhere in the schema, $defs included."""
    if isinstance(node, dict):
        for name, sub in (node.get("properties") or {}).items():
            found.append((name, sub))
        for value in node.values():
            _schema_properties(value, found)
    elif isinstance(node, list):
        for value in node:
            _schema_properties(value, found)
    return found


def test_config_reference_lists_every_schema_key_with_its_default():
    """Every key of the schema is a row of the generated page, with the schema's default and description."""
    ref = _reference()
    page = ref.config_reference()
    schema = yaml.safe_load(ref.SCHEMA.read_text())
    rows = [line for line in page.splitlines() if line.startswith("| `")]
    last = {}
    for line in rows:
        path = line.split("`")[1]
        last.setdefault(re.split(r"[.\[]", path.replace("[]", ""))[-1], []).append(line)
    for name, node in _schema_properties(schema, []):
        assert name in last, f"schema key {name!r} is not in the configuration reference"
        if "default" in node:
            import json

            cell = f"`{json.dumps(node['default'], ensure_ascii=False)}`"
            assert any(cell in row for row in last[name]), f"{name}: default {cell} not shown"
        if isinstance(node.get("description"), str):
            words = " ".join(node["description"].split())[:30].replace("<", "&lt;").replace(">", "&gt;")
            assert any(words.replace("*", "\\*") in row for row in last[name]), f"{name}: description missing"


def test_cli_reference_lists_every_command_and_option():
    """Every subcommand and every option string of the cvsflow parser is on the generated page."""
    from cvsflow.cli import build_parser

    page = _reference().cli_reference()
    stack = [((), build_parser())]
    while stack:
        path, parser = stack.pop()
        if path:
            assert f"## `cvsflow {' '.join(path)}`" in page, path
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                stack += [((*path, name), sub) for name, sub in action.choices.items()]
            for option in action.option_strings:
                assert option in page, (path, option)


def test_no_citation_of_documents_the_repository_does_not_hold():
    """Code and docs cite only documents in the repository (the former design and style notes are not)."""
    cited = re.compile(r"\b(design|style)\.md\b")
    offenders = []
    for root in ("cvsflow", "docs", "tests", "bench", "config"):
        for path in (REPO / root).rglob("*"):
            if path.suffix in {".py", ".md", ".smk", ".rst", ".yaml"}:
                text = path.read_text(encoding="utf-8", errors="replace")
                offenders += [f"{path.relative_to(REPO)}:{i}" for i, line in enumerate(text.splitlines(), 1)
                              if cited.search(line) and path != Path(__file__)]
    for name in ("README.md", "Snakefile", "Makefile", "mkdocs.yml"):
        text = (REPO / name).read_text()
        offenders += [f"{name}:{i}" for i, line in enumerate(text.splitlines(), 1) if cited.search(line)]
    assert not offenders, offenders


def test_guide_builds_with_warnings_as_errors(tmp_path):
    """`mkdocs build --strict` succeeds (CI installs the docs extra and runs it; skipped without mkdocs)."""
    pytest.importorskip("mkdocs")
    pytest.importorskip("material")
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-q", "-d", str(tmp_path / "site")],
                          cwd=REPO, capture_output=True, text=True, timeout=300,
                          env={"NO_MKDOCS_2_WARNING": "1", "PATH": "/usr/bin:/bin"})
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert (tmp_path / "site" / "reference" / "config" / "index.html").is_file()
