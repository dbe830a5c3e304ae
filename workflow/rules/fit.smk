# Stage 4: the estimators on each set.


# One job per set runs every estimator (config estimators, in order): a fit takes seconds, the start of a job (Python
# and the libraries) about as long, so one job per estimator spent most of its time starting. Each estimator keeps its
# own files.
FIT_ESTIMATES = "results/fits/{set_id}/{method}.npz"
FIT_SUMMARY = "results/fits/{set_id}/{method}.json"


rule fit:
    input:
        observations=rules.observe.output.npz,
    output:
        estimates=expand(FIT_ESTIMATES, method=ESTIMATORS, allow_missing=True),
        summaries=expand(FIT_SUMMARY, method=ESTIMATORS, allow_missing=True),
    params:
        image_set=image_set,
        methods=ESTIMATORS,
    threads: 1
    log:
        "logs/fit/{set_id}.log",
    benchmark:
        "benchmarks/fit/{set_id}.tsv"
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/fit.py"
