"""Read the motion-capture export into a marker table in metres (rule mocap_import)."""

from cvsflow.io.files import write_parquet, write_yaml
from cvsflow.io.logs import stage_logging
from cvsflow.io.mocap.formats import read_markers
from cvsflow.io.mocap.markers import import_summary
from cvsflow.plausibility import check_marker_scale

with stage_logging(snakemake.log[0], "mocap_import") as log:
    markers = snakemake.params.markers
    names = markers["camera"]["names"] + markers["board"]["names"]
    # mocap.format; absent in older callers of this script (tests/unit/test_plausibility.py)
    fmt = getattr(snakemake.params, "mocap_format", "auto")
    table = read_markers(snakemake.input[0], names, format=fmt)
    log.info("%d samples at %g Hz", len(table), table.attrs["rate_hz"])
    summary = import_summary(table, snakemake.input[0])
    for warning in check_marker_scale(table, markers, snakemake.input[0], snakemake.params.max_scale_ratio):
        log.warning(warning)
        summary["warnings"].append(warning)
    write_parquet(table, snakemake.output.markers)
    write_yaml(summary, snakemake.output.summary)  # a file cut short: both counts, for the headline
