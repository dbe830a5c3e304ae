# What the estimator needs from the geometry: Table 1's observations with
# tilted normals, and the true surface sampled as Table 2's cloud is.
rule geometry_sensitivity:
    input:
        observations=rules.observe.output.npz,
        images=RENDERED_SET_DIR,
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


rule tabulate_geometry_sensitivity:
    input:
        rows=expand(rules.geometry_sensitivity.output.csv, set_id=SENSITIVITY_SETS),
    output:
        csv=report("results/tables/geometry_sensitivity.csv", caption="../report/geometry_sensitivity.rst", category="Tables"),
        markdown="results/tables/geometry_sensitivity.md",
        png=report("results/plots/geometry_sensitivity.png", caption="../report/geometry_sensitivity.rst", category="Plots"),
    log:
        "logs/tabulate_geometry_sensitivity.log",
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/tabulate_geometry_sensitivity.py"
