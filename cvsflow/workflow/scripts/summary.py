"""One table over every optimiser run: focal lengths, P̄, error spread, truth where known (rule summary)."""

import json
from pathlib import Path

import pandas as pd

from cvsflow import plots
from cvsflow.evaluate import summary_row
from cvsflow.io.files import atomic_output, draw_figure, read_parquet, read_yaml
from cvsflow.io.logs import stage_logging

with stage_logging(snakemake.log[0], "summary") as log:
    inp = dict(snakemake.input.items())
    rows = []
    for session, method, finit in snakemake.params.runs:
        key = f"{session}/{method}/{finit}"
        truth = read_yaml(inp[f"{session}/truth"]) if f"{session}/truth" in inp else None
        rows.append(summary_row(
            session, method, finit,
            read_yaml(inp[f"{key}/result"]),
            json.loads(Path(inp[f"{key}/stats"]).read_text()),
            truth,
            read_parquet(inp[f"{session}/pairs"]) if truth else None,
            read_parquet(inp[f"{session}/truth_frames"]) if truth else None,
        ))
    table = pd.DataFrame(rows)
    log.info("%d runs summarised", len(table))
    with atomic_output(snakemake.output.table) as tmp:
        table.to_csv(tmp, index=False, float_format="%.6g")
    draw_figure(snakemake.output, "sweep", lambda: plots.summary.plot_sweep(table))
    draw_figure(snakemake.output, "sessions", lambda: plots.summary.plot_sessions(table))
