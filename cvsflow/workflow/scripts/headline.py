"""Headline numbers of every session and flight: headline.csv and the landing page (rule headline)."""

from pathlib import Path

from cvsflow.evaluate import (
    flight_headline,
    flight_verdict,
    headline_rst,
    headline_table,
    median_distance_m,
    pose_fit_headline,
    rig_headline,
    session_headline,
    session_verdict,
    verdict_rst,
)
from cvsflow.io.files import atomic_output, image_data_uri, read_parquet, read_yaml
from cvsflow.io.logs import stage_logging

with stage_logging(snakemake.log[0], "headline") as log:
    inp = dict(snakemake.input.items())

    def load(key):
        return read_yaml(inp[key]) if key in inp else None

    rows, preambles = [], {}
    for s in snakemake.params.sessions:
        loaded = dict(camera=load(f"{s}/camera"), sync=load(f"{s}/sync"), se3=load(f"{s}/se3"),
                      seed=load(f"{s}/seed"), comparison=load(f"{s}/comparison"),
                      corners=load(f"{s}/corners"), mocap_repair=load(f"{s}/mocap_repair"))
        rows += session_headline(
            s, camera_from=snakemake.params.camera_from.get(s), truth=load(f"{s}/truth"),
            mocap_import=load(f"{s}/mocap_import"), **loaded)
        if f"{s}/pose_fit" in inp:  # a camera-pose session: the pose-level fit instead of se3
            rows += pose_fit_headline(s, load(f"{s}/pose_fit"), heldout=load(f"{s}/pose_fit_heldout"))
        heldout = read_parquet(inp[f"{s}/heldout"]) if f"{s}/heldout" in inp else None
        verdict = session_verdict(s, distance_m=median_distance_m(heldout), **loaded)
        bands = image_data_uri(inp[f"{s}/bands"]) if f"{s}/bands" in inp else None
        preambles[s] = verdict_rst(verdict, bands, "held-out error per axis over time, stated bands")
        log.info("session %s: %s", s, verdict["text"])
    for f in snakemake.params.flights:
        rows += flight_headline(f, load(f"flight {f}/stats"))
        verdict = flight_verdict(f, load(f"flight {f}/stats"))
        errors = image_data_uri(inp[f"flight {f}/errors"]) if f"flight {f}/errors" in inp else None
        preambles[f"flight {f}"] = verdict_rst(verdict, errors, "on-board error per axis, reference band")
    # rig sessions from the input keys (no params: a config without rigs keeps its headline job)
    for rig in dict.fromkeys(k[len("rig "):].split("/")[0] for k in inp if k.startswith("rig ")):
        rows += rig_headline(rig, load(f"rig {rig}/result"), heldout=load(f"rig {rig}/heldout"),
                             truth=load(f"rig {rig}/truth"))
    table = headline_table(rows)
    log.info("%d headline rows over %d sessions and flights", len(table), table["session"].nunique())
    with atomic_output(snakemake.output.table) as tmp:
        table.to_csv(tmp, index=False, float_format="%.8g")
    with atomic_output(snakemake.output.rst) as tmp:
        Path(tmp).write_text(headline_rst(rows, preambles))
