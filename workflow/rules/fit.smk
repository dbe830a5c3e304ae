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
