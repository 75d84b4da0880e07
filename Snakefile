# cvsflow: the accuracy of a webcam + chessboard pose system, measured against Vicon.
from snakemake.utils import min_version, validate

min_version("9.0")


configfile: "config/config.yaml"


validate(config, "workflow/schemas/config.schema.yaml")


include: "workflow/rules/common.smk"
include: "workflow/rules/synth.smk"
include: "workflow/rules/camera.smk"
include: "workflow/rules/vicon.smk"
include: "workflow/rules/align.smk"
include: "workflow/rules/optimise.smk"
include: "workflow/rules/analyse.smk"
include: "workflow/rules/evaluate.smk"
include: "workflow/rules/summary.smk"
include: "workflow/rules/flight.smk"
include: "workflow/rules/rig.smk"


report: "workflow/report/workflow.rst"


rule all:
    default_target: True
    input:
        all_targets(),
