# The photometric model family: Itokawa rendered with each law, fitted with
# each; Hapke over a phase-angle sweep fitted with the paper's Minnaert
# estimator (results/tables/model_mismatch.*).

MODEL_SETTINGS = config["model_mismatch"]
# Table 1's light angles carry the cross-fits; the Hapke sets carry the phase sweep.
CROSS_FIT_SETS = [name for name, (law, angle) in MODEL_SETS.items() if angle in [float(a) for a in config["light_angles_deg"]]]
SWEEP_SETS = [name for name, (law, angle) in MODEL_SETS.items() if law == "hapke" and angle in [float(a) for a in MODEL_SETTINGS["phase_angles_deg"]]]
# The sensor of the noisy cross-fits; none when noise_level is null or noise_levels empty.
MODEL_SENSOR = (
    named_entry(config, "noise_levels", MODEL_SETTINGS["noise_level"])
    if MODEL_SETS and MODEL_SETTINGS["noise_level"] and config["noise_levels"]
    else None
)
MODEL_BENCHMARKS = [
    *expand("benchmarks/render_model_set/{model_set}.tsv", model_set=MODEL_SETS),
    *expand("benchmarks/fit_model_set/{model_set}.tsv", model_set=CROSS_FIT_SETS),
    *expand("benchmarks/phase_sweep_set/{model_set}.tsv", model_set=SWEEP_SETS),
]


def model_set_law(wildcards):
    return MODEL_SETS[wildcards.model_set][0]


def model_set_angle(wildcards):
    return MODEL_SETS[wildcards.model_set][1]


def model_set_geometry(wildcards):
    return f"results/observations/geometry_light{MODEL_SETS[wildcards.model_set][1]:g}.npz"


def model_set_seed(wildcards):
    """Each set's own seed, from the experiment's seed and the set's name."""
    return (MODEL_SETTINGS["seed"] * 1_000_003 + sorted(MODEL_SETS).index(wildcards.model_set)) % 2**32


wildcard_constraints:
    model_set="(" + "|".join(MODEL_SETTINGS["models"]) + ")_light[^/_]+",


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
        samples_per_pixel=MODEL_SETTINGS["samples_per_pixel"],
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
        geometry=model_set_geometry,
        images=rules.render_model_set.output.images,
    output:
        json="results/models/fits/{model_set}.json",
    params:
        law=model_set_law,
        light_angle_deg=model_set_angle,
        settings=MODEL_SETTINGS,
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
        geometry=model_set_geometry,
        images=rules.render_model_set.output.images,
    output:
        json="results/models/phase_sweep/{model_set}.json",
    params:
        light_angle_deg=model_set_angle,
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
            *expand("results/models/fits/{model_set}.json", model_set=CROSS_FIT_SETS),
            *expand("results/models/phase_sweep/{model_set}.json", model_set=SWEEP_SETS),
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
