"""mkdocs hook: adds the generated reference pages (docs/_gen/reference.py) to the guide."""

from __future__ import annotations

import sys
from pathlib import Path

from mkdocs.structure.files import File

sys.path.insert(0, str(Path(__file__).resolve().parent))
from reference import cli_reference, config_reference  # noqa: E402

#: Generated page (path in the guide) -> the function that writes it.
PAGES = {"reference/config.md": config_reference, "reference/cli.md": cli_reference}


def on_files(files, config):
    """Add every generated page to the guide's files (mkdocs 1.6 ``File.generated``)."""
    for path, make in PAGES.items():
        files.append(File.generated(config, path, content=make()))
    return files
