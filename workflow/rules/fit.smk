# Stage 4: the estimators, each on each set.


rule fit:
    input:
        observations=rules.observe.output.npz,
    output:
        estimates="results/fits/{set_id}/{method}.npz",
        summary="results/fits/{set_id}/{method}.json",
    params:
        image_set=image_set,
    threads: 1
    log:
        "logs/fit/{set_id}/{method}.log",
    benchmark:
        "benchmarks/fit/{set_id}/{method}.tsv"
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/fit.py"


rule noise_monte_carlo:
    input:
        geometry=lambda wildcards: f"results/observations/geometry_{SETS[wildcards.set_id].light_tag}.npz",
        images="results/render/{set_id}",
    output:
        csv="results/noise_monte_carlo/{set_id}.csv",
    params:
        image_set=image_set,
        sensor=lambda wildcards: named_entry(config, "noise_levels", config["noise_monte_carlo"]["level"]),
        seed=monte_carlo_seed,
        realisations=config["noise_monte_carlo"]["realisations"],
    threads: 1
    log:
        "logs/noise_monte_carlo/{set_id}.log",
    benchmark:
        "benchmarks/noise_monte_carlo/{set_id}.tsv"
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/noise_monte_carlo.py"


# What the estimator needs from the geometry: Table 1's observations with
# tilted normals, and the true surface sampled as Table 2's cloud is.
rule geometry_sensitivity:
    input:
        observations=rules.observe.output.npz,
        images="results/render/{set_id}",
        shape=rules.prepare_shape.output.npz,
    output:
        csv="results/geometry_sensitivity/{set_id}.csv",
    params:
        image_set=image_set,
        settings=config["geometry_sensitivity"],
        observations=config["observations"],
        cloud=reconstruction_settings("cloud"),
    threads: 1
    log:
        "logs/geometry_sensitivity/{set_id}.log",
    benchmark:
        "benchmarks/geometry_sensitivity/{set_id}.tsv"
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/geometry_sensitivity.py"
