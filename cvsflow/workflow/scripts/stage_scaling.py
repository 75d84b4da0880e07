"""Time per stage against session length, from bench/bench_scaling.py's table (rule stage_scaling)."""

from cvsflow.io.files import read_csv_table, save_figure
from cvsflow.io.logs import stage_logging
from cvsflow.plots.timing import BENCHMARK_COLUMNS, plot_stage_scaling, prefer_whole_runs

with stage_logging(snakemake.log[0], "stage_scaling") as log:
    table = prefer_whole_runs(read_csv_table(snakemake.input.table, BENCHMARK_COLUMNS))
    log.info("%d stages, session lengths %s s", table["stage"].nunique(),
             ", ".join(f"{v:g}" for v in sorted(table["duration_s"].unique())))
    save_figure(plot_stage_scaling(table), snakemake.output.fig)
