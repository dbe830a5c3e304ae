# Stage 2: render every image set with the Minnaert BSDF in Mitsuba, and
# record the noisy sets as a sensor would.


rule render:
    input:
        shape=rules.prepare_shape.output.npz,
        cameras=rules.imaging_geometry.output.cameras,
    output:
        images=directory(RENDERED_SET_DIR),
    wildcard_constraints:
        set_id=RENDERED_SET,
    params:
        image_set=image_set,
        surface_map=surface_map_spec,
        samples_per_pixel=config["samples_per_pixel"],
        mitsuba_variant=config["mitsuba_variant"],
    threads: 2
    log:
        "logs/render/{set_id}.log",
    benchmark:
        "benchmarks/render/{set_id}.tsv"
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/render.py"


rule add_noise:
    input:
        images=RENDERED_SET_DIR.format(set_id="{clean_id}"),
    output:
        images=directory(RENDERED_SET_DIR.format(set_id="{clean_id}_noise-{level}")),
    wildcard_constraints:
        clean_id=RENDERED_SET,
        level=NAME,
    params:
        sensor=noise_level_spec,
        seed=noise_seed,
    log:
        "logs/add_noise/{clean_id}_noise-{level}.log",
    benchmark:
        "benchmarks/add_noise/{clean_id}_noise-{level}.tsv"
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/add_noise.py"


# What a mission would know of a base set under one imaging condition (the images as its camera records
# them, the navigation priors, the sensor model), and the truth beside it: Table 2 starts from the first.
rule mission:
    input:
        images=condition_render_dir,
    output:
        mission=directory(MISSION_SET_DIR),
        truth="results/truth/mission/{imaging}/{set_id}.json",
    wildcard_constraints:
        set_id=RENDERED_SET,
    params:
        condition=lambda wildcards: CONDITIONS[wildcards.imaging],
        noise_levels=config["noise_levels"],
        seed=mission_seed,
        prior_seed=config["reconstruction"]["prior_seed"],
    log:
        "logs/mission/{imaging}/{set_id}.log",
    benchmark:
        "benchmarks/mission/{imaging}/{set_id}.tsv"
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/mission.py"
