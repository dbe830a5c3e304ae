# The photometric model family: Itokawa rendered with each law, fitted with
# each; Hapke over a phase-angle sweep fitted with the paper's Minnaert
# estimator (results/tables/model_mismatch.*).


rule render_model_set:
    input:
        shape=rules.prepare_shape.output.npz,
        cameras=rules.imaging_geometry.output.cameras,
    output:
        images=directory("results/models/render/{model_set}"),
    params:
        law=model_set_law,
        law_params=lambda wildcards: MODEL_SETTINGS["parameters"][model_set_law(wildcards)],
        light_angle_deg=model_set_angle,
        mitsuba_variant=config["mitsuba_variant"],
        seed=model_set_seed,
    threads: 2
    log:
        "logs/render_model_set/{model_set}.log",
    benchmark:
        "benchmarks/render_model_set/{model_set}.tsv"
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/render_model_set.py"


rule fit_model_set:
    input:
        geometry=rules.observation_geometry.output.npz,
        images=rules.render_model_set.output.images,
        shape=rules.prepare_shape.output.npz,
        cameras=rules.imaging_geometry.output.cameras,
    output:
        json="results/models/fits/{model_set}.json",
    params:
        law=model_set_law,
        light_angle_deg=model_set_angle,
        observations=config["observations"],
        settings={key: MODEL_SETTINGS[key] for key in ("models", "parameters", "fit", "cross_fit_points", "max_iterations", "fisher_sigma")},
        sensor=MODEL_SENSOR,
        seed=model_set_seed,
    log:
        "logs/fit_model_set/{model_set}.log",
    benchmark:
        "benchmarks/fit_model_set/{model_set}.tsv"
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/fit_model_set.py"


rule phase_sweep_set:
    input:
        geometry=rules.observation_geometry.output.npz,
        images=rules.render_model_set.output.images,
        shape=rules.prepare_shape.output.npz,
        cameras=rules.imaging_geometry.output.cameras,
    output:
        json="results/models/phase_sweep/{model_set}.json",
    params:
        light_angle_deg=model_set_angle,
        observations=config["observations"],
    log:
        "logs/phase_sweep_set/{model_set}.log",
    benchmark:
        "benchmarks/phase_sweep_set/{model_set}.tsv"
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/phase_sweep_set.py"


rule tabulate_model_mismatch:
    input:
        rows=[
            *expand(rules.fit_model_set.output.json, model_set=CROSS_FIT_SETS),
            *expand(rules.phase_sweep_set.output.json, model_set=SWEEP_SETS),
        ],
    output:
        csv=report("results/tables/model_mismatch.csv", caption="../report/model_mismatch.rst", category="Tables"),
        markdown="results/tables/model_mismatch.md",
        phase=report("results/plots/model_mismatch_phase.png", caption="../report/model_mismatch.rst", category="Plots"),
        residuals=report("results/plots/model_mismatch_residuals.png", caption="../report/model_mismatch.rst", category="Plots"),
    log:
        "logs/tabulate_model_mismatch.log",
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/tabulate_model_mismatch.py"
