# The noise Monte Carlo: each base set drawn many times at one sensor level,
# the errors scored against the Cramer-Rao bound.


rule noise_monte_carlo:
    input:
        geometry=rules.observation_geometry.output.npz,
        images=RENDERED_SET_DIR,
        shape=rules.prepare_shape.output.npz,
        cameras=rules.imaging_geometry.output.cameras,
    output:
        csv="results/noise_monte_carlo/{set_id}.csv",
    params:
        image_set=image_set,
        sensor=lambda wildcards: named_entry(config, "noise_levels", config["noise_monte_carlo"]["level"]),
        seed=monte_carlo_seed,
        realisations=config["noise_monte_carlo"]["realisations"],
        observations=config["observations"],
    threads: 1
    log:
        "logs/noise_monte_carlo/{set_id}.log",
    benchmark:
        "benchmarks/noise_monte_carlo/{set_id}.tsv"
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/noise_monte_carlo.py"


rule tabulate_noise_monte_carlo:
    input:
        draws=expand(rules.noise_monte_carlo.output.csv, set_id=MONTE_CARLO_SETS),
    output:
        csv=report("results/tables/noise_monte_carlo.csv", caption="../report/noise_monte_carlo.rst", category="Tables"),
        markdown="results/tables/noise_monte_carlo.md",
    log:
        "logs/tabulate_noise_monte_carlo.log",
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/tabulate_noise_monte_carlo.py"
