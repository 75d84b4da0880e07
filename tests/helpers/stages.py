"""Running one workflow script in the test process, with a stand-in for Snakemake's object."""

import runpy
from pathlib import Path
from types import SimpleNamespace

SCRIPTS = Path(__file__).resolve().parents[2] / "cvsflow" / "workflow" / "scripts"


class Named(list):
    """Stand-in for Snakemake's Namedlist: positional and named access."""

    def __init__(self, **named):
        super().__init__(str(v) for v in named.values())
        self.__dict__.update({k: str(v) for k, v in named.items()})

    def __getitem__(self, key):
        return self.__dict__[key] if isinstance(key, str) else super().__getitem__(key)

    def get(self, key, default=None):
        """The named item, or ``default`` (as Namedlist.get)."""
        return self.__dict__.get(key, default)


def run_stage(script, tmp_path, inputs, outputs, params, threads=1):
    """Run a workflow script with a fake ``snakemake`` object; return the log path."""
    log = tmp_path / "logs" / f"{script}.log"
    sm = SimpleNamespace(input=Named(**inputs), output=Named(**outputs), params=SimpleNamespace(**params),
                         log=[str(log)], threads=threads, wildcards=SimpleNamespace())
    runpy.run_path(str(SCRIPTS / f"{script}.py"), init_globals={"snakemake": sm})
    return log
