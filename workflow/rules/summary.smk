# Stage 6: the headline numbers of every table the run made, in one page (results/summary.md).

# The result tables of `rule all`, by name; the optional ones under the conditions of OPTIONAL_TARGETS.
SUMMARY_TABLES = {
    "table1": rules.tabulate_table1.output.csv,
    "runtime": rules.tabulate_runtime.output.csv,
    **{sweep: rules.tabulate_sweep.output.csv.format(sweep=sweep) for sweep in SWEEPS},
    **({"table2": rules.tabulate_table2.output.csv} if PRIOR_SETTINGS else {}),
    **({"noise_monte_carlo": rules.tabulate_noise_monte_carlo.output.csv} if MONTE_CARLO_SETS else {}),
    **({"geometry_sensitivity": rules.tabulate_geometry_sensitivity.output.csv} if SENSITIVITY_SETS else {}),
    **({"model_mismatch": rules.tabulate_model_mismatch.output.csv} if MODEL_SETS else {}),
}


rule summary:
    input:
        **SUMMARY_TABLES,
        paper=workflow.source_path("../resources/paper_table1.csv"),
    output:
        report("results/summary.md", caption="../report/summary.rst", category="Summary"),
    params:
        config=config,
        configfiles=[str(path) for path in workflow.configfiles],
    log:
        "logs/summary.log",
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/write_summary.py"
