# Stage 5: tables, plots and the runtime summary.


rule tabulate_table1:
    input:
        summaries=expand(FIT_SUMMARY, set_id=BASE_SETS, method=ESTIMATORS),
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
        estimates=expand(FIT_ESTIMATES, set_id=BASE_SETS, method=ESTIMATORS),
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
            *expand(rules.render.benchmark, set_id=[i for i, s in SETS.items() if not s.noise_level]),
            rules.observation_geometry.benchmark,
            *[rules.add_noise.benchmark.format(clean_id=clean_id, level=level) for clean_id, level in map(split_noisy_set, SWEEPS.get("noise", []))],
            *expand(rules.observe.benchmark, set_id=SETS),
            *expand(rules.fit.benchmark, set_id=SETS),
            *expand(rules.noise_monte_carlo.benchmark, set_id=MONTE_CARLO_SETS),
            *expand(rules.geometry_sensitivity.benchmark, set_id=SENSITIVITY_SETS),
            *[rules.render_condition.benchmark.format(**job) for job in condition_render_jobs()],
            *per_condition(rules.mission.benchmark),
            *(per_condition(rules.match_features.benchmark) if PRIOR_SETTINGS else []),
            *per_condition(rules.reconstruct.benchmark, priors=PRIOR_SETTINGS),
            *per_condition(rules.register_cloud.benchmark, priors=PRIOR_SETTINGS),
            *per_condition(rules.refine_cloud.benchmark, priors=PRIOR_SETTINGS),
            *per_condition(rules.mesh_light.benchmark, priors=PRIOR_SETTINGS),
            *per_condition(rules.final_cloud.benchmark, priors=PRIOR_SETTINGS),
            *per_condition(rules.estimate_cloud.benchmark, priors=PRIOR_SETTINGS),
            *per_condition(rules.score_cloud.benchmark, priors=PRIOR_SETTINGS),
            *expand(rules.render_model_set.benchmark, model_set=MODEL_SETS),
            *expand(rules.fit_model_set.benchmark, model_set=CROSS_FIT_SETS),
            *expand(rules.phase_sweep_set.benchmark, model_set=SWEEP_SETS),
        ],
        # The fits' own wall-clock seconds, kept out of the science tables.
        summaries=lambda wildcards: [
            *expand(FIT_SUMMARY, set_id=SETS, method=ESTIMATORS),
            *per_condition(CLOUD_SUMMARY, priors=PRIOR_SETTINGS, method=ESTIMATORS),
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
            FIT_SUMMARY, set_id=SWEEPS[wildcards.sweep], method=ESTIMATORS
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
        estimates=lambda wildcards: FIT_ESTIMATES.format(set_id=error_map_set(wildcards), method=ESTIMATORS[0]),
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
        table=rules.tabulate_sweep.output.csv.format(sweep="noise"),
    output:
        png=report("results/plots/noise_against_bound.png", caption="../report/noise_plot.rst", category="Plots"),
    log:
        "logs/plot_noise.log",
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/plot_noise.py"
