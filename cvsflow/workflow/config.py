"""Where the shipped workflow's files are, and the checks a config passes before any job.

The workflow is package data: ``cvsflow run`` and the repository's Snakefile both run
:data:`SNAKEFILE`, with the profiles in :data:`PROFILES` (``default``, ``slurm``); the
demo's config is :data:`DEMO_CONFIG` (the repository's ``config/config.yaml`` links to it).
A config that the schema refuses stops the run with one line naming the key
(:func:`schema_error`), not with Snakemake's dump of the whole schema.
"""

from __future__ import annotations

from pathlib import Path

from cvsflow.exceptions import ConfigError

#: The folder of the shipped workflow (Snakefile, rules, scripts, schemas, report, profiles).
WORKFLOW_DIR = Path(__file__).resolve().parent
#: The workflow's Snakefile (no ``configfile:``: the caller names the config).
SNAKEFILE = WORKFLOW_DIR / "Snakefile"
#: The config schema (JSON Schema 2020-12 in YAML; its defaults fill every key left out).
SCHEMA = WORKFLOW_DIR / "schemas" / "config.schema.yaml"
#: Snakemake workflow profiles: ``default`` (a workstation), ``slurm`` (a SLURM cluster).
PROFILES = WORKFLOW_DIR / "profiles"
#: The demo's config (a rendered session and flight); the repository's config/config.yaml.
DEMO_CONFIG = WORKFLOW_DIR / "demo.yaml"


def _sources(configfiles) -> str:
    """`` (a.yaml, b.yaml)`` naming the config files, or nothing when there are none."""
    names = [str(f) for f in configfiles or ()]
    return f" ({', '.join(names)})" if names else ""


def require_sessions(config: dict, configfiles=()) -> None:
    """Stop a config that has no session: the workflow would have nothing to run.

    Parameters
    ----------
    config : dict
        The loaded config (before or after validation).
    configfiles : sequence of str or Path
        The files it was read from, named in the message.

    Returns
    -------
    None

    Raises
    ------
    ConfigError
        No ``sessions`` key, or an empty or non-mapping one.
    """
    sessions = config.get("sessions") if isinstance(config, dict) else None
    if isinstance(sessions, dict) and sessions:
        return
    got = "no sessions key" if sessions is None else f"sessions: {sessions!r}"
    raise ConfigError(
        f"config{_sources(configfiles)}: {got}; expected a sessions: mapping with at least one "
        "session (`cvsflow init DIR` writes one from a recording folder; `cvsflow demo DIR` "
        "writes a complete example)"
    )


def schema_error(error, configfiles=()) -> ConfigError:
    """One line naming the key a schema validation refused, what is wrong and what is expected.

    Parameters
    ----------
    error : Exception
        Snakemake's ``WorkflowError`` from ``snakemake.utils.validate`` (the jsonschema
        ``ValidationError`` is its context) or the ``ValidationError`` itself.
    configfiles : sequence of str or Path
        The config files, named in the message.

    Returns
    -------
    ConfigError
        ``config (FILES): KEY.PATH: what is wrong (the key's description; for an unknown
        key, the keys allowed there)``; the error itself when it carries no validation error.
    """
    found = error
    while found is not None and not hasattr(found, "absolute_path"):
        found = found.__context__ or found.__cause__
    if found is None:
        return ConfigError(f"config{_sources(configfiles)}: {error}")
    where = ".".join(str(p) for p in found.absolute_path) or "top level"
    schema = found.schema if isinstance(found.schema, dict) else {}
    if found.validator == "additionalProperties" and "properties" in schema:
        hint = f"expected one of {sorted(schema['properties'])}"
    else:
        hint = " ".join(str(schema.get("description", "")).split())
    hint = f" ({hint})" if hint else ""
    return ConfigError(f"config{_sources(configfiles)}: {where}: {found.message}{hint}")
