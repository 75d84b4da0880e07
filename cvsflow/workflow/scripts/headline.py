"""Headline numbers of every session and flight: headline.csv and the landing page (rule headline)."""

from pathlib import Path

from cvsflow.evaluate import flight_headline, headline_rst, headline_table, rig_headline, session_headline
from cvsflow.io.files import atomic_output, read_yaml
from cvsflow.io.logs import stage_logging

with stage_logging(snakemake.log[0], "headline") as log:
    inp = dict(snakemake.input.items())

    def load(key):
        return read_yaml(inp[key]) if key in inp else None

    rows = []
    for s in snakemake.params.sessions:
        rows += session_headline(
            s, camera=load(f"{s}/camera"), camera_from=snakemake.params.camera_from.get(s),
            sync=load(f"{s}/sync"), se3=load(f"{s}/se3"), seed=load(f"{s}/seed"),
            comparison=load(f"{s}/comparison"), truth=load(f"{s}/truth"),
            corners=load(f"{s}/corners"), mocap_repair=load(f"{s}/mocap_repair"),
            mocap_import=load(f"{s}/mocap_import"),
        )
    for f in snakemake.params.flights:
        rows += flight_headline(f, load(f"flight {f}/stats"))
    # rig sessions from the input keys (no params: a config without rigs keeps its headline job)
    for rig in dict.fromkeys(k[len("rig "):].split("/")[0] for k in inp if k.startswith("rig ")):
        rows += rig_headline(rig, load(f"rig {rig}/result"), heldout=load(f"rig {rig}/heldout"),
                             truth=load(f"rig {rig}/truth"))
    table = headline_table(rows)
    log.info("%d headline rows over %d sessions and flights", len(table), table["session"].nunique())
    with atomic_output(snakemake.output.table) as tmp:
        table.to_csv(tmp, index=False, float_format="%.8g")
    with atomic_output(snakemake.output.rst) as tmp:
        Path(tmp).write_text(headline_rst(rows))
