# Stage 3: which points each image sees on a pure pixel, then their brightness.


rule observation_geometry:
    input:
        shape=rules.prepare_shape.output.npz,
        cameras=rules.imaging_geometry.output.cameras,
    output:
        npz="results/observations/geometry_{light_tag}.npz",
    params:
        light_angle_deg=lambda wildcards: LIGHT_ANGLE_OF_TAG[wildcards.light_tag],
        observations=config["observations"],
    threads: 2
    log:
        "logs/observation_geometry/{light_tag}.log",
    benchmark:
        "benchmarks/observation_geometry/{light_tag}.tsv"
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/observation_geometry.py"


rule observe:
    input:
        geometry=observation_geometry_of_set,
        images=rules.render.output.images,
    output:
        npz="results/observations/{set_id}.npz",
    log:
        "logs/observe/{set_id}.log",
    benchmark:
        "benchmarks/observe/{set_id}.tsv"
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/observe.py"
