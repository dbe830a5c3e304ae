# Stage 6: the headline numbers of every table the run made, in one page (results/summary.md).


def summary_tables(wildcards):
    """The result tables of `rule all`, by name: the optional ones under the conditions of OPTIONAL_TARGETS."""
    tables = {"table1": rules.tabulate_table1.output.csv, "runtime": rules.tabulate_runtime.output.csv}
    tables.update({sweep: f"results/tables/{sweep}.csv" for sweep in SWEEPS})
    if PRIOR_SETTINGS:
        tables["table2"] = rules.tabulate_table2.output.csv
    if MONTE_CARLO_SETS:
        tables["noise_monte_carlo"] = rules.tabulate_noise_monte_carlo.output.csv
    if SENSITIVITY_SETS:
        tables["geometry_sensitivity"] = rules.tabulate_geometry_sensitivity.output.csv
    if MODEL_SETS:
        tables["model_mismatch"] = rules.tabulate_model_mismatch.output.csv
    return tables


rule summary:
    input:
        unpack(summary_tables),
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
