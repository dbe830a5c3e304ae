# Asteroid photometry: reproduce Table 1 of Koizumi et al. (see README.md).
from snakemake.utils import min_version

min_version("9.0")


configfile: "config/config.yaml"


include: "workflow/rules/common.smk"
include: "workflow/rules/shape.smk"
include: "workflow/rules/render.smk"
include: "workflow/rules/observe.smk"
include: "workflow/rules/fit.smk"
include: "workflow/rules/tabulate.smk"
include: "workflow/rules/reconstruct.smk"


rule all:
    input:
        rules.tabulate_table1.output,
        rules.plot_table1.output,
        rules.tabulate_runtime.output,
        expand("results/tables/{sweep}.csv", sweep=SWEEPS),
        expand("results/plots/noise_against_bound.png", _=[1] if "noise" in SWEEPS else []),
        expand("results/tables/table2.csv", _=[1] if PRIOR_SETTINGS else []),
        expand("results/plots/table2_errors.png", _=[1] if PRIOR_SETTINGS else []),
        expand("results/tables/noise_monte_carlo.csv", _=[1] if MONTE_CARLO_SETS else []),
        expand("results/plots/error_map_{map_name}.png", map_name=[m["name"] for m in config["surface_maps"]]),
