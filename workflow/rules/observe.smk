# Stage 3: which points each image sees on a pure pixel (no light needed), then
# their brightness and the selection made with the light estimated from it.


rule observation_geometry:
    input:
        shape=rules.prepare_shape.output.npz,
        cameras=rules.imaging_geometry.output.cameras,
    output:
        npz="results/observations/geometry.npz",
    params:
        observations=CANDIDATE_SETTINGS,
    threads: 2
    log:
        "logs/observation_geometry.log",
    benchmark:
        "benchmarks/observation_geometry/geometry.tsv"
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/observation_geometry.py"


rule observe:
    input:
        geometry=rules.observation_geometry.output.npz,
        images=rules.render.output.images,
        shape=rules.prepare_shape.output.npz,
        cameras=rules.imaging_geometry.output.cameras,
    output:
        npz="results/observations/{set_id}.npz",
    params:
        observations=config["observations"],
    log:
        "logs/observe/{set_id}.log",
    benchmark:
        "benchmarks/observe/{set_id}.tsv"
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/observe.py"
