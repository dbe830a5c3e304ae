# Table 2, from images alone: features and matches, sparse reconstruction,
# registration to the shape model, refinement, the estimators on the
# reconstructed cloud, each from the mission set (rule mission) and no truth;
# then the scoring, which alone reads the truth.


# The 8-bit images, SIFT features and verified matches of a set: once for both prior settings (the priors
# enter only the mapper and the final adjustment).
rule match_features:
    input:
        mission=rules.mission.output.mission,
    output:
        features=directory("results/features/{imaging}/{set_id}"),
    params:
        settings=reconstruction_settings("match_features"),
    # One thread: the matching runs on one whatever this says (reconstruct.MATCHING_THREADS), and two
    # of these jobs at once keep both cores busier than one whose extraction runs on two.
    threads: 1
    log:
        "logs/match_features/{imaging}/{set_id}.log",
    benchmark:
        "benchmarks/match_features/{imaging}/{set_id}.tsv"
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/match_features.py"


rule reconstruct:
    input:
        mission=rules.mission.output.mission,
        features=rules.match_features.output.features,
    output:
        model=directory("results/reconstruction/{imaging}/{set_id}/priors-{priors}"),
    params:
        use_priors=lambda wildcards: wildcards.priors == "on",
        settings=reconstruction_settings("reconstruct"),
    # The mapper and bundle adjustments run on one thread (reconstruct.MAPPING_THREADS).
    threads: 1
    log:
        "logs/reconstruct/{imaging}/{set_id}/priors-{priors}.log",
    benchmark:
        "benchmarks/reconstruct/{imaging}/{set_id}/priors-{priors}.tsv"
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/reconstruct.py"


rule register_cloud:
    input:
        model=rules.reconstruct.output.model,
        shape=rules.prepare_shape.output.npz,
    output:
        npz="results/registration/{imaging}/{set_id}/priors-{priors}.npz",
        summary="results/registration/{imaging}/{set_id}/priors-{priors}.json",
    params:
        settings=reconstruction_settings("register"),
    log:
        "logs/register_cloud/{imaging}/{set_id}/priors-{priors}.log",
    benchmark:
        "benchmarks/register_cloud/{imaging}/{set_id}/priors-{priors}.tsv"
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/register_cloud.py"


rule refine_cloud:
    input:
        registration=rules.register_cloud.output.npz,
        model=rules.reconstruct.output.model,
        mission=rules.mission.output.mission,
    output:
        npz="results/refined_cloud/{imaging}/{set_id}/priors-{priors}.npz",
    params:
        settings=reconstruction_settings("refine"),
    log:
        "logs/refine_cloud/{imaging}/{set_id}/priors-{priors}.log",
    benchmark:
        "benchmarks/refine_cloud/{imaging}/{set_id}/priors-{priors}.tsv"
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/refine_cloud.py"


# The light of a shape from shading on the cloud's whole surface, every pixel of every image (a stage of its own: a
# minute or two a set); where it applies (the refinement's k not near 0.5) the paper's
# estimator's final fit holds it instead of the refinement's (docs/table2.md, section 13).
rule mesh_light:
    input:
        registration=rules.register_cloud.output.npz,
        model=rules.reconstruct.output.model,
        mission=rules.mission.output.mission,
        refined=rules.refine_cloud.output.npz,
    output:
        npz="results/mesh_light/{imaging}/{set_id}/priors-{priors}.npz",
    threads: 1
    log:
        "logs/mesh_light/{imaging}/{set_id}/priors-{priors}.log",
    benchmark:
        "benchmarks/mesh_light/{imaging}/{set_id}/priors-{priors}.tsv"
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/mesh_light.py"


# The refined cloud the final fit and its scoring read: the refinement's, or on noise-free images under the mesh fit's
# light, its points' normals fitted again under that light (docs/table2.md, section 15).
rule final_cloud:
    input:
        registration=rules.register_cloud.output.npz,
        model=rules.reconstruct.output.model,
        mission=rules.mission.output.mission,
        refined=rules.refine_cloud.output.npz,
        mesh_light=rules.mesh_light.output.npz,
    output:
        npz="results/final_cloud/{imaging}/{set_id}/priors-{priors}.npz",
    params:
        settings=reconstruction_settings("refine"),
    log:
        "logs/final_cloud/{imaging}/{set_id}/priors-{priors}.log",
    benchmark:
        "benchmarks/final_cloud/{imaging}/{set_id}/priors-{priors}.tsv"
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/final_cloud.py"


# One job per cloud runs every estimator (config estimators, in order) and scores them: the cloud's inputs, its
# samples of the images and the truth are read once, not once per estimator. Each estimator keeps its own files.
CLOUD_ESTIMATES = "results/estimates_cloud/{imaging}/{set_id}/priors-{priors}/{method}.npz"
CLOUD_SUMMARY = "results/fits_cloud/{imaging}/{set_id}/priors-{priors}/{method}.json"
CLOUD_ERRORS = "results/fits_cloud/{imaging}/{set_id}/priors-{priors}/{method}.npz"


rule estimate_cloud:
    input:
        registration=rules.register_cloud.output.npz,
        registration_summary=rules.register_cloud.output.summary,
        model=rules.reconstruct.output.model,
        mission=rules.mission.output.mission,
        refined=rules.refine_cloud.output.npz,
        final_cloud=rules.final_cloud.output.npz,
        mesh_light=rules.mesh_light.output.npz,
    output:
        estimates=expand(CLOUD_ESTIMATES, method=ESTIMATORS, allow_missing=True),
    params:
        methods=ESTIMATORS,
        settings=reconstruction_settings("cloud"),
    log:
        "logs/estimate_cloud/{imaging}/{set_id}/priors-{priors}.log",
    benchmark:
        "benchmarks/estimate_cloud/{imaging}/{set_id}/priors-{priors}.tsv"
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/estimate_cloud.py"


# Scoring: the only rule of Table 2 that reads the truth (the mission set's truth file, the rendered set).
rule score_cloud:
    input:
        estimates=rules.estimate_cloud.output.estimates,
        registration=rules.register_cloud.output.npz,
        registration_summary=rules.register_cloud.output.summary,
        model=rules.reconstruct.output.model,
        mission=rules.mission.output.mission,
        refined=rules.refine_cloud.output.npz,
        final_cloud=rules.final_cloud.output.npz,
        shape=rules.prepare_shape.output.npz,
        truth=rules.mission.output.truth,
        render_truth=condition_render_dir,
    output:
        summary=expand(CLOUD_SUMMARY, method=ESTIMATORS, allow_missing=True),
        errors=expand(CLOUD_ERRORS, method=ESTIMATORS, allow_missing=True),
    params:
        methods=ESTIMATORS,
        settings=reconstruction_settings("cloud"),
    log:
        "logs/score_cloud/{imaging}/{set_id}/priors-{priors}.log",
    benchmark:
        "benchmarks/score_cloud/{imaging}/{set_id}/priors-{priors}.tsv"
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/score_cloud.py"


rule tabulate_table2:
    input:
        summaries=per_condition(CLOUD_SUMMARY, priors=PRIOR_SETTINGS, method=ESTIMATORS),
    output:
        csv=report("results/tables/table2.csv", caption="../report/table2.rst", category="Tables"),
        markdown="results/tables/table2.md",
    log:
        "logs/tabulate_table2.log",
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/tabulate_table2.py"


rule plot_table2:
    input:
        table=rules.tabulate_table2.output.csv,
        cloud_errors=CLOUD_ERRORS.format(
            imaging=TABLE2_PLOT_CONDITION, set_id=TABLE2_PLOT_SET, priors=PRIOR_SETTINGS[0] if PRIOR_SETTINGS else "on", method=TABLE2_PLOT_METHOD
        ),
    output:
        stages=report("results/plots/table2_errors.png", caption="../report/table2_plots.rst", category="Plots"),
        cloud=report("results/plots/table2_cloud_errors.png", caption="../report/table2_plots.rst", category="Plots"),
        conditions=report("results/plots/table2_conditions.png", caption="../report/table2_plots.rst", category="Plots"),
    params:
        method=TABLE2_PLOT_METHOD,
        title=f"{TABLE2_PLOT_SET}, imaging {TABLE2_PLOT_CONDITION}, priors {PRIOR_SETTINGS[0] if PRIOR_SETTINGS else 'on'}, {TABLE2_PLOT_METHOD}: the reconstructed cloud's per-point errors",
    log:
        "logs/plot_table2.log",
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/plot_table2.py"
