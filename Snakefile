# The repository's entry: the demo config, then the workflow that ships in the package
# (`cvsflow run CONFIG` runs that workflow on a config of yours, from any folder).
configfile: "config/config.yaml"


include: "cvsflow/workflow/Snakefile"


# An included file's default target does not carry over: name it here.
rule default:
    default_target: True
    input:
        rules.all.input,
