# Stage 1: the shape model (downloaded or local) and the imaging geometry.


rule fetch_shape_model:
    output:
        model="resources/shape/{model_name}.tab",
    params:
        model_name=lambda wildcards: wildcards.model_name,
    log:
        "logs/fetch_shape_model/{model_name}.log",
    retries: 3
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/fetch_shape_model.py"


rule prepare_shape:
    input:
        model=shape_model_file,
    output:
        npz="results/shape/model.npz",
    params:
        model_name=config["shape_model"],
    log:
        "logs/prepare_shape.log",
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/prepare_shape.py"


rule imaging_geometry:
    input:
        shape=rules.prepare_shape.output.npz,
    output:
        cameras="results/truth/geometry/cameras.json",
    params:
        n_images=config["n_images"],
        image_size=config["image_size"],
        camera_distance_km=config["camera_distance_km"],
        view_latitude_deg=config["view_latitude_deg"],
    log:
        "logs/imaging_geometry.log",
    conda:
        "../../envs/photometry.yaml"
    script:
        "../scripts/imaging_geometry.py"
