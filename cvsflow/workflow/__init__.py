"""The Snakemake workflow shipped in the package (Snakefile, rules, scripts, schemas, report) and its
session logic.
"""
