# Stage 2: render every image set with the Minnaert BSDF in Mitsuba.


rule render:
    input:
        shape=rules.prepare_shape.output.npz,
        cameras=rules.imaging_geometry.output.cameras,
    output:
        images=directory("results/render/{set_id}"),
    params:
        image_set=image_set,
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
