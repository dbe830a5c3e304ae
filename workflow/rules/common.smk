# Helpers shared by the rules: config validation, the image sets, paths.
import sys
from pathlib import Path

# The library, for the Snakefile itself (rule scripts find it through
# workflow/scripts/_workflow_path.py).
WORKFLOW_DIR = Path(workflow.basedir) / "workflow"
sys.path.insert(0, str(WORKFLOW_DIR))

from asteroid_photometry.config import validate_config, ConfigError
from asteroid_photometry.experiment import image_sets

try:
    config.update(validate_config(config))
except ConfigError as error:
    raise WorkflowError(f"invalid configuration: {error}") from None

SETS = image_sets(config)
LIGHT_TAGS = sorted({s.light_tag for s in SETS.values()})
ESTIMATORS = config["estimators"]


wildcard_constraints:
    set_id="light[^/_]+_albedo[^/_]+_k[^/_]+",
    light_tag="light[^/_]+",
    method="|".join(ESTIMATORS),


def image_set(wildcards):
    return SETS[wildcards.set_id]


def shape_model_file(wildcards):
    """The local copy named by shape_model_path, or the verified download."""
    if config["shape_model_path"]:
        return config["shape_model_path"]
    return f"resources/shape/{config['shape_model']}.tab"
