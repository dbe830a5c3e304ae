# Asteroid photometry: reproduce Table 1 of Koizumi et al. (see README.md).
from snakemake.utils import min_version

min_version("9.0")


configfile: "config/config.yaml"


report: "workflow/report/landing.rst"


include: "workflow/rules/common.smk"
include: "workflow/rules/shape.smk"
include: "workflow/rules/render.smk"
include: "workflow/rules/observe.smk"
include: "workflow/rules/fit.smk"
include: "workflow/rules/monte_carlo.smk"
include: "workflow/rules/reconstruct.smk"
include: "workflow/rules/sensitivity.smk"
include: "workflow/rules/models.smk"
include: "workflow/rules/tabulate.smk"
include: "workflow/rules/summary.smk"


# Rules of a few seconds that only prepare the inputs (the shape model, its
# download: compute nodes often have no network; the cameras) or gather results
# into tables and plots: they run in Snakemake's own process under any
# executor, never as cluster jobs. A new tabulate or plot rule belongs here.
localrules:
    all,
    fetch_shape_model,
    prepare_shape,
    imaging_geometry,
    condition_geometry,
    tabulate_table1,
    plot_table1,
    tabulate_runtime,
    tabulate_sweep,
    plot_error_map,
    plot_noise,
    tabulate_noise_monte_carlo,
    tabulate_geometry_sensitivity,
    tabulate_model_mismatch,
    tabulate_table2,
    plot_table2,
    summary,


# The optional outputs, each only when its part of the experiment is configured.
OPTIONAL_TARGETS = [
    *([rules.plot_noise.output.png] if "noise" in SWEEPS else []),
    *([rules.tabulate_table2.output.csv, rules.plot_table2.output.stages] if PRIOR_SETTINGS else []),
    *([rules.tabulate_noise_monte_carlo.output.csv] if MONTE_CARLO_SETS else []),
    *([rules.tabulate_geometry_sensitivity.output.csv] if SENSITIVITY_SETS else []),
    *([rules.tabulate_model_mismatch.output.csv] if MODEL_SETS else []),
]


rule all:
    input:
        rules.tabulate_table1.output,
        rules.plot_table1.output,
        rules.tabulate_runtime.output,
        rules.summary.output,
        expand(rules.tabulate_sweep.output.csv, sweep=SWEEPS),
        OPTIONAL_TARGETS,
        expand(rules.plot_error_map.output.png, map_name=[m["name"] for m in config["surface_maps"]]),
