# Helpers shared by the rules: config validation, the image sets, paths.
import os
import sys
from pathlib import Path

WORKFLOW_DIR = Path(workflow.basedir) / "workflow"
# Rule scripts run in their own Python processes: give them the library.
os.environ["PYTHONPATH"] = os.pathsep.join(
    [str(WORKFLOW_DIR)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]
)
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
