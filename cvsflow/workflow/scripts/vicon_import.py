"""Read the motion-capture export into a marker table in metres (rule vicon_import)."""

from cvsflow.io.files import write_parquet
from cvsflow.io.logs import stage_logging
from cvsflow.io.mocap.formats import read_markers
from cvsflow.plausibility import check_marker_scale

with stage_logging(snakemake.log[0], "vicon_import") as log:
    markers = snakemake.params.markers
    names = markers["camera"]["names"] + markers["board"]["names"]
    # mocap.format; absent in older callers of this script (tests/unit/test_plausibility.py)
    fmt = getattr(snakemake.params, "mocap_format", "auto")
    table = read_markers(snakemake.input[0], names, format=fmt)
    log.info("%d samples at %g Hz", len(table), table.attrs["rate_hz"])
    for warning in check_marker_scale(table, markers, snakemake.input[0], snakemake.params.max_scale_ratio):
        log.warning(warning)
    write_parquet(table, snakemake.output[0])
