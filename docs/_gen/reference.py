"""The user guide's generated pages: the configuration reference and the command reference.

Both are written when the guide is built (``docs/_gen/hooks.py``, an mkdocs hook), from the
sources themselves: the configuration page from ``cvsflow/workflow/schemas/config.schema.yaml``
(every key, its type, default and description), the command page from the ``cvsflow``
command's argparse parser (each subcommand's ``--help``). Nothing is committed, so neither page
can fall behind what it documents; ``tests/docs/test_guide.py`` checks that every key of the
schema appears. To read them without building the guide::

    .venv/bin/python docs/_gen/reference.py config   # or: cli
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import sys
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[2]
SCHEMA = REPO / "cvsflow" / "workflow" / "schemas" / "config.schema.yaml"

#: The shared definitions documented first, in this order, with the heading each gets (any other
#: definition with properties follows under its own name).
DEFS = (("board", "Board"), ("body", "Marker body"), ("rig_camera", "Rig camera"),
        ("synth", "Rendered session (synth)"))


def _md(text) -> str:
    """One table cell: one line, no HTML tags, no emphasis, no column breaks."""
    text = " ".join(str(text).split())
    for a, b in (("&", "&amp;"), ("<", "&lt;"), (">", "&gt;"), ("|", "\\|"), ("*", "\\*")):
        text = text.replace(a, b)
    return text


def _type(node: dict) -> str:
    if "$ref" in node:
        name = node["$ref"].rsplit("/", 1)[-1]
        if name == "pose6":
            return "pose6: [x, y, z, roll, pitch, yaw] (m, rad)"
        if node["$ref"].startswith("#/$defs/") and node["$ref"].count("/") == 2:
            return f"[{name}](#{name.replace('_', '-')})"
        return "as " + node["$ref"].removeprefix("#/$defs/").replace("/properties/", ".")
    if "enum" in node:
        return "one of " + ", ".join(f"`{v}`" for v in node["enum"])
    for key in ("anyOf", "oneOf"):
        if key in node and "type" not in node:
            return " or ".join(_type(n) for n in node[key])
    t = node.get("type", "")
    types = t if isinstance(t, list) else [t]
    out = []
    for t in types:
        if t == "array":
            items = node.get("items", {})
            n = ""
            if node.get("minItems") is not None and node.get("minItems") == node.get("maxItems"):
                n = f" of {node['minItems']}"
            out.append(f"list{n} of {_type(items) if items else 'values'}")
        elif t == "object" and "additionalProperties" in node and isinstance(
                node["additionalProperties"], dict):
            out.append("mapping of name to entry")
        else:
            out.append(str(t or "any"))
    text = " or ".join(out)
    bounds = [f"{k.replace('exclusiveMinimum', '>').replace('exclusiveMaximum', '<')} {node[k]}"
              for k in ("exclusiveMinimum", "exclusiveMaximum") if k in node]
    bounds += [f"{'≥' if k == 'minimum' else '≤'} {node[k]}" for k in ("minimum", "maximum") if k in node]
    return text + (f" ({', '.join(bounds)})" if bounds else "")


def _default(node: dict) -> str:
    if "default" not in node:
        return ""
    return f"`{json.dumps(node['default'], ensure_ascii=False)}`"


def _rows(node: dict, prefix: str, rows: list) -> None:
    """Rows (key path, type, default, description) of ``node``'s properties, depth first."""
    for key, sub in (node.get("properties") or {}).items():
        path = f"{prefix}.{key}" if prefix else key
        rows.append((path, _type(sub), _default(sub), sub.get("description", "")))
        if "properties" in sub:
            _rows(sub, path, rows)
        elif sub.get("type") == "array" and "properties" in (sub.get("items") or {}):
            _rows(sub["items"], f"{path}[]", rows)
        elif isinstance(entry := sub.get("additionalProperties"), dict) and "properties" in entry:
            rows.append((f"{path}.<name>", _type(entry), "", entry.get("description", "")))
            _rows(entry, f"{path}.<name>", rows)


def _table(rows: list) -> list[str]:
    out = ["| key | type | default | description |", "|---|---|---|---|"]
    for path, typ, default, desc in rows:
        out.append(f"| `{path}` | {_md(typ)} | {default} | {_md(desc)} |")
    return out


def config_reference(schema_path: Path = SCHEMA) -> str:
    """The configuration reference page (Markdown) of the schema at ``schema_path``.

    Parameters
    ----------
    schema_path : Path
        The workflow's JSON schema (YAML).

    Returns
    -------
    str
        One section per top-level block (``sessions``, ``calibrate``, ... ``flights``), then
        the shared definitions (board, marker body, rig camera, rendered session); each a
        table of key path, type, default and description.
    """
    schema = yaml.safe_load(Path(schema_path).read_text())
    out = ["# Configuration reference", "",
           "Generated from `cvsflow/workflow/schemas/config.schema.yaml` when this guide is built: "
           "it lists every key the workflow accepts. A key left out takes its default (filled in "
           "before any job runs); a key the schema does not know, or a value of the wrong type, "
           "stops the run with one line naming it.", "",
           _md(schema.get("description", "")), ""]
    for key, node in schema["properties"].items():
        out += [f"## `{key}`", ""]
        rows: list = [(key, _type(node), _default(node), node.get("description", ""))]
        if isinstance(node.get("additionalProperties"), dict):
            entry = node["additionalProperties"]
            rows.append((f"{key}.<name>", _type(entry), "", entry.get("description", "")))
            _rows(entry, f"{key}.<name>", rows)
        else:
            _rows(node, key, rows)
        out += _table(rows) + [""]
    defs = schema.get("$defs", {})
    out += ["## Shared definitions", ""]
    titles = dict(DEFS)
    for name in [n for n, _ in DEFS if n in defs] + sorted(set(defs) - set(titles)):
        node = defs[name]
        if "properties" not in node:
            continue  # pose6: spelled out where it is used
        title = titles.get(name, name.replace("_", " ").capitalize())
        out += [f"### {title} {{#{name.replace('_', '-')}}}", ""]
        if node.get("description"):
            out += [_md(node["description"]), ""]
        rows = []
        _rows(node, name, rows)
        out += _table(rows) + [""]
    return "\n".join(out)


def _subparsers(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()):
    """(command path, parser) of every subcommand, depth first."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield (*path, name), sub
                yield from _subparsers(sub, (*path, name))


def cli_reference() -> str:
    """The command reference page (Markdown): ``cvsflow --help`` and every subcommand's.

    Returns
    -------
    str
        One section per command with its help text as argparse prints it at 100 columns.
    """
    from cvsflow.cli import build_parser

    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = "100"  # argparse wraps to the terminal; the page must not depend on it
    try:
        parser = build_parser()
        out = ["# The `cvsflow` command", "",
               "Generated from the command's own parser when this guide is built; "
               "`cvsflow COMMAND --help` prints the same. Exit codes: 0 success, 1 a cvsflow error "
               "(one line naming the file, no traceback), 2 a usage error.", "",
               "## `cvsflow`", "", "```text", parser.format_help().rstrip(), "```", ""]
        for path, sub in _subparsers(parser):
            out += [f"## `cvsflow {' '.join(path)}`", "", "```text", sub.format_help().rstrip(), "```", ""]
    finally:
        if old is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = old
    return "\n".join(out)


def main(argv=None) -> int:
    """Print one generated page: ``config`` or ``cli``."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("page", choices=["config", "cli"])
    args = p.parse_args(argv)
    with contextlib.redirect_stderr(io.StringIO()):
        text = config_reference() if args.page == "config" else cli_reference()
    sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
