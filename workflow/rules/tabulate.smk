# Stage 5: tables, plots and the runtime summary.


rule tabulate_table1:
    input:
        summaries=expand("results/fits/{set_id}/{method}.json", set_id=BASE_SETS, method=ESTIMATORS),
        paper=workflow.source_path("../resources/paper_table1.csv"),
    output:
        csv=report("results/tables/table1.csv", caption="../report/table1.rst", category="Tables"),
        markdown="results/tables/table1.md",
    log:
        "logs/tabulate_table1.log",
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/tabulate_table1.py"


rule plot_table1:
    input:
        table=rules.tabulate_table1.output.csv,
        estimates=expand("results/fits/{set_id}/{method}.npz", set_id=BASE_SETS, method=ESTIMATORS),
    output:
        light=report("results/plots/light_angle.png", caption="../report/plots.rst", category="Plots"),
        albedo=report("results/plots/albedo.png", caption="../report/plots.rst", category="Plots"),
        minnaert_k=report("results/plots/minnaert_k.png", caption="../report/plots.rst", category="Plots"),
        per_point=report("results/plots/per_point_errors.png", caption="../report/per_point.rst", category="Plots"),
    log:
        "logs/plot_table1.log",
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/plot_table1.py"


rule tabulate_runtime:
    input:
        benchmarks=lambda wildcards: [
            *expand("benchmarks/render/{set_id}.tsv", set_id=[i for i, s in SETS.items() if not s.noise_level]),
            *expand("benchmarks/observation_geometry/{light_tag}.tsv", light_tag=LIGHT_ANGLE_OF_TAG),
            *expand("benchmarks/add_noise/{set_id}.tsv", set_id=SWEEPS.get("noise", [])),
            *expand("benchmarks/observe/{set_id}.tsv", set_id=SETS),
            *expand("benchmarks/fit/{set_id}/{method}.tsv", set_id=SETS, method=ESTIMATORS),
            *expand("benchmarks/noise_monte_carlo/{set_id}.tsv", set_id=MONTE_CARLO_SETS),
            *expand("benchmarks/geometry_sensitivity/{set_id}.tsv", set_id=SENSITIVITY_SETS),
            *expand("benchmarks/reconstruct/{set_id}/priors-{priors}.tsv", set_id=BASE_SETS, priors=PRIOR_SETTINGS),
            *expand("benchmarks/register_cloud/{set_id}/priors-{priors}.tsv", set_id=BASE_SETS, priors=PRIOR_SETTINGS),
            *expand("benchmarks/refine_cloud/{set_id}/priors-{priors}.tsv", set_id=BASE_SETS, priors=PRIOR_SETTINGS),
            *expand(
                "benchmarks/fit_cloud/{set_id}/priors-{priors}/{method}.tsv",
                set_id=BASE_SETS,
                priors=PRIOR_SETTINGS,
                method=ESTIMATORS,
            ),
            *MODEL_BENCHMARKS,
        ],
        # The fits' own wall-clock seconds, kept out of the science tables.
        summaries=[
            *expand("results/fits/{set_id}/{method}.json", set_id=SETS, method=ESTIMATORS),
            *expand("results/fits_cloud/{set_id}/priors-{priors}/{method}.json", set_id=BASE_SETS, priors=PRIOR_SETTINGS, method=ESTIMATORS),
        ],
    output:
        csv=report("results/tables/runtime.csv", caption="../report/runtime.rst", category="Tables"),
        fit_timing=report("results/tables/fit_timing.csv", caption="../report/runtime.rst", category="Tables"),
    log:
        "logs/tabulate_runtime.log",
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/tabulate_runtime.py"


rule tabulate_sweep:
    input:
        summaries=lambda wildcards: expand(
            "results/fits/{set_id}/{method}.json", set_id=SWEEPS[wildcards.sweep], method=ESTIMATORS
        ),
    output:
        csv=report("results/tables/{sweep}.csv", caption="../report/sweep.rst", category="Tables"),
        markdown="results/tables/{sweep}.md",
    params:
        sweep=lambda wildcards: wildcards.sweep,
    log:
        "logs/tabulate_sweep/{sweep}.log",
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/tabulate_sweep.py"


rule plot_error_map:
    input:
        shape=rules.prepare_shape.output.npz,
        estimates=lambda wildcards: f"results/fits/{error_map_set(wildcards)}/{ESTIMATORS[0]}.npz",
    output:
        png=report("results/plots/error_map_{map_name}.png", caption="../report/error_map.rst", category="Plots"),
    params:
        title=lambda wildcards: f"{error_map_set(wildcards)}, {ESTIMATORS[0]}: per-point errors on the body",
    log:
        "logs/plot_error_map/{map_name}.log",
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/plot_error_map.py"


rule plot_noise:
    input:
        table="results/tables/noise.csv",
    output:
        png=report("results/plots/noise_against_bound.png", caption="../report/noise_plot.rst", category="Plots"),
    log:
        "logs/plot_noise.log",
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/plot_noise.py"


rule tabulate_noise_monte_carlo:
    input:
        draws=expand("results/noise_monte_carlo/{set_id}.csv", set_id=MONTE_CARLO_SETS),
    output:
        csv=report("results/tables/noise_monte_carlo.csv", caption="../report/noise_monte_carlo.rst", category="Tables"),
        markdown="results/tables/noise_monte_carlo.md",
    log:
        "logs/tabulate_noise_monte_carlo.log",
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/tabulate_noise_monte_carlo.py"


rule tabulate_geometry_sensitivity:
    input:
        rows=expand("results/geometry_sensitivity/{set_id}.csv", set_id=SENSITIVITY_SETS),
    output:
        csv=report("results/tables/geometry_sensitivity.csv", caption="../report/geometry_sensitivity.rst", category="Tables"),
        markdown="results/tables/geometry_sensitivity.md",
        png=report("results/plots/geometry_sensitivity.png", caption="../report/geometry_sensitivity.rst", category="Plots"),
    log:
        "logs/tabulate_geometry_sensitivity.log",
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/tabulate_geometry_sensitivity.py"
