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


# An imaging condition with views, Sun or relief of its own renders its own copy of each set it starts from.
rule render_condition:
    input:
        shape=rules.prepare_shape.output.npz,
        cameras=condition_cameras,
    output:
        images=directory(CONDITION_RENDER_DIR),
    wildcard_constraints:
        set_id=RENDERED_SET,
        imaging="|".join(OWN_RENDER_CONDITIONS) or "none",
    params:
        image_set=image_set,
        surface_map=surface_map_spec,
        light_out_of_plane_deg=lambda wildcards: CONDITIONS[wildcards.imaging]["light_out_of_plane_deg"],
        relief=lambda wildcards: CONDITIONS[wildcards.imaging]["relief"],
        samples_per_pixel=config["samples_per_pixel"],
        mitsuba_variant=config["mitsuba_variant"],
    threads: 2
    log:
        "logs/render_condition/{set_id}_imaging-{imaging}.log",
    benchmark:
        "benchmarks/render_condition/{set_id}_imaging-{imaging}.tsv"
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/render_condition.py"


# The cameras of an imaging condition whose views lie at another latitude.
rule condition_geometry:
    input:
        shape=rules.prepare_shape.output.npz,
    output:
        cameras=CONDITION_CAMERAS,
    params:
        n_images=config["n_images"],
        image_size=config["image_size"],
        camera_distance_km=config["camera_distance_km"],
        view_latitude_deg=lambda wildcards: float(wildcards.latitude),
    log:
        "logs/condition_geometry/lat{latitude}.log",
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/imaging_geometry.py"


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
        condition=mission_condition,
        noise_levels=config["noise_levels"],
        seed=mission_seed,
        prior_seed=mission_prior_seed,
    log:
        "logs/mission/{imaging}/{set_id}.log",
    benchmark:
        "benchmarks/mission/{imaging}/{set_id}.tsv"
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/mission.py"
