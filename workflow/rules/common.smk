# Helpers shared by the rules: config validation, the image sets, paths.
import sys
from pathlib import Path

# The library, for the Snakefile itself (rule scripts find it through
# workflow/scripts/_workflow_path.py). Found beside this file, not from the
# working directory, so that the workflow also runs as a module of another
# workflow (`module ...: snakefile: <this checkout>/Snakefile`).
_basedir = workflow.current_basedir.get_path_or_uri(secret_free=True)
if "://" in _basedir:
    raise WorkflowError(
        "this workflow imports its Python library (workflow/asteroid_photometry) from beside its rules, "
        "which needs a local copy: clone the repository and point the module's snakefile at the clone's "
        f"Snakefile (rules found at {_basedir})"
    )
WORKFLOW_DIR = Path(_basedir).resolve().parent
if str(WORKFLOW_DIR) not in sys.path:
    sys.path.insert(0, str(WORKFLOW_DIR))

from asteroid_photometry.core.config import condition_sets, renders_own_sets, table2_conditions, validate_config, ConfigError
from asteroid_photometry.world.image_sets import condition_rendered_set, image_sets, named_entry
from asteroid_photometry.world.shape import get_shape_model_spec
from asteroid_photometry.experiments.mismatch import model_sets
from asteroid_photometry.experiments.table2 import stage_settings
from asteroid_photometry.core.footprint import estimate_footprint, footprint_warnings
from asteroid_photometry.core.allocator import with_allocator_env

# Every job this process starts inherits its environment: large arrays reused instead of mapped afresh
# (asteroid_photometry/core/allocator.py; a value the user set wins).
with_allocator_env()

try:
    config.update(validate_config(config))
except ConfigError as error:
    raise WorkflowError(f"invalid configuration: {error}") from None

SETS = image_sets(config)
BASE_SETS = [set_id for set_id, s in SETS.items() if s.is_base]
SWEEPS = {
    "noise": [set_id for set_id, s in SETS.items() if s.noise_level],
    "surface_maps": [set_id for set_id, s in SETS.items() if s.surface_map],
}
SWEEPS = {sweep: ids for sweep, ids in SWEEPS.items() if ids}
PRIOR_SETTINGS = ["on" if use else "off" for use in config["reconstruction"]["priors"]] if config["reconstruction"]["enabled"] else []
# Table 2's imaging conditions, by name.
CONDITIONS = table2_conditions(config)
_CONDITIONS_OFF = sorted({entry["name"] for entry in config["imaging_conditions"]} - set(CONDITIONS)) if PRIOR_SETTINGS else []
if _CONDITIONS_OFF:
    logger.info(f"imaging conditions off (the noise level or surface map they need is turned off): {', '.join(_CONDITIONS_OFF)}")
# The base sets each condition runs on (its key sets; all by default).
try:
    CONDITION_SETS = condition_sets(CONDITIONS, BASE_SETS)
except ConfigError as error:
    raise WorkflowError(f"invalid configuration: {error}") from None


def per_condition(pattern, **wildcards):
    """expand() of a Table 2 path over every imaging condition and the base sets it runs on."""
    return [path for imaging, set_ids in CONDITION_SETS.items() for path in expand(pattern, imaging=imaging, set_id=set_ids, **wildcards)]


def condition_render_jobs():
    """The wildcards (set_id, imaging) of every render_condition job: the rendered set each own-render condition
    starts from for each base set it runs on, split at the condition's suffix."""
    jobs = []
    for imaging, entry in CONDITIONS.items():
        for set_id in CONDITION_SETS[imaging] if renders_own_sets(entry) else []:
            rendered, _, name = condition_rendered_set(set_id, entry).rpartition("_imaging-")
            jobs.append({"set_id": rendered, "imaging": name})
    return jobs


# The conditions that render their own copy of every set they start from (views, Sun or relief of their own).
OWN_RENDER_CONDITIONS = [name for name, entry in CONDITIONS.items() if renders_own_sets(entry)]
# The cloud drawn in Table 2's figure: the first condition's.
TABLE2_PLOT_CONDITION = next(iter(CONDITIONS), "ideal")
# An empty noise_levels turns the noise off, and the noise Monte Carlo with it.
MONTE_CARLO_SETS = BASE_SETS if config["noise_monte_carlo"]["realisations"] > 0 and config["noise_levels"] else []
# The geometry sensitivity study explains Table 2: it runs with it.
SENSITIVITY_SETS = BASE_SETS if config["geometry_sensitivity"]["enabled"] and PRIOR_SETTINGS else []


def reconstruction_settings(stage):
    """The reconstruction keys one Table 2 stage reads (declared beside the stage, in the library): a change to
    another key leaves that stage's outputs standing (Snakemake reruns a job when its params change)."""
    return stage_settings(config["reconstruction"], stage)


# The model-mismatch experiment's sets ({name: (law, light angle)}).
MODEL_SETS = model_sets(config["model_mismatch"], config["light_angles_deg"]) if config["model_mismatch"]["enabled"] else {}
# The observation keys the candidate observations depend on (no light: the incidence cut is made per set,
# with the light estimated from its images), so that a change to min_cos_incidence leaves them standing.
CANDIDATE_SETTINGS = {key: value for key, value in config["observations"].items() if key != "min_cos_incidence"}
ESTIMATORS = config["estimators"]

# The disk and memory the configured run needs, against what this machine
# has: in the log of every run, dry runs included (make footprint).
FOOTPRINT = estimate_footprint(config, SETS, len(PRIOR_SETTINGS), len(ESTIMATORS), n_model_sets=len(MODEL_SETS), conditions=CONDITIONS, condition_sets=CONDITION_SETS)
logger.info(FOOTPRINT.summary())
try:
    PARALLEL_JOBS = int(workflow.cores)
except (WorkflowError, TypeError, ValueError):
    PARALLEL_JOBS = 1
for _warning in footprint_warnings(FOOTPRINT, Path.cwd(), PARALLEL_JOBS):
    logger.warning(f"warning: {_warning}")
# Table 2's figures: the paper's estimator (or the first one), the cloud of the last base set.
TABLE2_PLOT_METHOD = "koizumi_lm" if "koizumi_lm" in ESTIMATORS else ESTIMATORS[0]
TABLE2_PLOT_SET = CONDITION_SETS[TABLE2_PLOT_CONDITION][-1] if CONDITIONS else BASE_SETS[-1]
NAME = "[A-Za-z0-9-]+"
RENDERED_SET = f"light[^/_]+_albedo[^/_]+_k[^/_]+(_map-{NAME})?"


wildcard_constraints:
    set_id=f"{RENDERED_SET}(_noise-{NAME})?",
    method="|".join(ESTIMATORS),
    sweep="|".join(SWEEPS) or "none",
    priors="on|off",
    imaging="|".join(CONDITIONS) or "none",
    latitude="-?[0-9.e+-]+",


# A set's rendered images and the renderer's record of them (true poses, light, albedo, k): written by rule
# render (clean sets) or add_noise (noisy ones). Truth: only the world and the scoring rules read it.
RENDERED_SET_DIR = "results/truth/render/{set_id}"
# A set as a mission knows it under one imaging condition, written by the mission rule; the image-only path starts here.
MISSION_SET_DIR = "results/mission/{imaging}/{set_id}"


# A set rendered anew for an imaging condition of its own views, Sun or relief (rule render_condition), from
# the base set or its surface-map variant (``set_id``); truth as RENDERED_SET_DIR.
CONDITION_RENDER_DIR = RENDERED_SET_DIR.format(set_id="{set_id}_imaging-{imaging}")
# The cameras of a condition whose views lie at another latitude (rule condition_geometry).
CONDITION_CAMERAS = "results/truth/geometry/cameras_lat{latitude}.json"


def condition_render_dir(wildcards):
    """The rendered set an imaging condition starts from: the base set, or its variant with the condition's surface map,
    or the condition's own render of either (world.image_sets.condition_rendered_set)."""
    return RENDERED_SET_DIR.format(set_id=condition_rendered_set(wildcards.set_id, CONDITIONS[wildcards.imaging]))


def condition_latitude(imaging):
    """The latitude of a condition's views: the config's, plus the condition's own."""
    return config["view_latitude_deg"] + CONDITIONS[imaging]["view_latitude_deg"]


def condition_cameras(wildcards):
    """The cameras a condition's own render uses: the configured ones, or those of its latitude."""
    if not CONDITIONS[wildcards.imaging]["view_latitude_deg"]:
        return rules.imaging_geometry.output.cameras
    return CONDITION_CAMERAS.format(latitude=f"{condition_latitude(wildcards.imaging):g}")


def mission_condition(wildcards):
    """The condition as the mission stage takes it, without its relief, which only the renderer reads (a relief
    changed or added renders the sets again, and the mission sets follow through their input), and without the
    sets it runs on (a set added to them leaves the others' mission sets standing)."""
    return {key: value for key, value in CONDITIONS[wildcards.imaging].items() if key not in ("relief", "sets")}


def mission_seed(wildcards):
    """The seed of a mission set's degradations: noise_seed, the set's own seed and the condition's place in the list."""
    return [config["noise_seed"], SETS[wildcards.set_id].seed, list(CONDITIONS).index(wildcards.imaging)]


def mission_prior_seed(wildcards):
    """The seed of a mission set's navigation errors: reconstruction.prior_seed, the set's own seed and the condition's
    place in the list. Each set and condition draws its own, as it does its noise and gains: one draw shared by every set
    would put the same navigation error under every row of Table 2."""
    return [config["reconstruction"]["prior_seed"], *mission_seed(wildcards)[1:]]


def split_noisy_set(set_id):
    """``(clean_id, level)`` of a noisy set's id."""
    clean_id, level = set_id.rsplit("_noise-", 1)
    return clean_id, level


def image_set(wildcards):
    return SETS[wildcards.set_id]


def surface_map_spec(wildcards):
    """The surface_maps entry a set is rendered with, or None for a uniform surface."""
    name = SETS[wildcards.set_id].surface_map
    return named_entry(config, "surface_maps", name) if name else None


def noise_level_spec(wildcards):
    return named_entry(config, "noise_levels", wildcards.level)


def seed_of_noisy_set(clean_id, level):
    """Each noisy set draws from its own seed, derived from noise_seed and the set."""
    return (config["noise_seed"] * 1_000_003 + SETS[f"{clean_id}_noise-{level}"].seed) % 2**32


def noise_seed(wildcards):
    return seed_of_noisy_set(wildcards.clean_id, wildcards.level)


def monte_carlo_seed(wildcards):
    """The noise Monte Carlo's seed for a base set: the seed its noisy variant of that level draws from."""
    return seed_of_noisy_set(wildcards.set_id, config["noise_monte_carlo"]["level"])


def shape_model_file(wildcards):
    """The copy named by shape_model_path, else the shipped copy or the verified download (shape_model_source)."""
    if config["shape_model_path"]:
        return config["shape_model_path"]
    if config["shape_model_source"] == "download":
        return f"resources/shape/{config['shape_model']}.tab"
    return str(get_shape_model_spec(config["shape_model"]).shipped_path)


def error_map_set(wildcards):
    """The set whose per-point errors are drawn for a surface map: the last base set's variant."""
    return next(i for i, s in reversed(list(SETS.items())) if s.surface_map == wildcards.map_name and not s.noise_level)


# The model-mismatch experiment (rules/models.smk).
MODEL_SETTINGS = config["model_mismatch"]
# Table 1's light angles carry the cross-fits; the Hapke sets carry the phase sweep.
CROSS_FIT_SETS = [name for name, (law, angle) in MODEL_SETS.items() if angle in [float(a) for a in config["light_angles_deg"]]]
SWEEP_SETS = [name for name, (law, angle) in MODEL_SETS.items() if law == "hapke" and angle in [float(a) for a in MODEL_SETTINGS["phase_angles_deg"]]]
# The sensor of the noisy cross-fits; none when noise_level is null or noise_levels empty.
MODEL_SENSOR = (
    named_entry(config, "noise_levels", MODEL_SETTINGS["noise_level"])
    if MODEL_SETS and MODEL_SETTINGS["noise_level"] and config["noise_levels"]
    else None
)


def model_set_law(wildcards):
    return MODEL_SETS[wildcards.model_set][0]


def model_set_angle(wildcards):
    return MODEL_SETS[wildcards.model_set][1]


def model_set_seed(wildcards):
    """Each set's own seed, from the experiment's seed and the set's name."""
    return (MODEL_SETTINGS["seed"] * 1_000_003 + sorted(MODEL_SETS).index(wildcards.model_set)) % 2**32


wildcard_constraints:
    model_set="(" + "|".join(MODEL_SETTINGS["models"]) + ")_light[^/_]+",
