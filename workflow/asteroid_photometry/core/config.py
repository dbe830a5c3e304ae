"""Validate the workflow configuration against ``workflow/schemas/config.schema.yaml``.

Where it sits: the Snakefile calls :func:`validate_config` once on the merged
config (``configfile:`` plus ``--configfile`` plus ``--config``) before any
rule uses it. It fills the schema's defaults and turns jsonschema's errors
into one :class:`ConfigError` whose message names every offending key by its
path, e.g. ``config key 'observations.min_cos_incidence': 1.5 is greater than
or equal to the maximum of 1``, and lists the allowed keys when a key is
unknown (a typo must not pass silently).

Snakemake parses ``--config`` values with int, float and then YAML's
BaseLoader, so ``--config 'albedos=[0.6]'`` arrives as ``['0.6']`` (strings
inside lists and mappings). Before validating, strings are therefore read as
numbers wherever the schema asks for a number and does not allow a string,
the YAML spellings of null (``null``, ``~``, the empty string) become
``None`` wherever the schema allows null, and ``true`` / ``false`` (any of
YAML's or Python's spellings) become booleans wherever the schema asks for a
boolean and does not allow a string.
"""

import copy
import difflib
import functools
import math
from collections.abc import Mapping
from pathlib import Path

import jsonschema
import yaml

__all__ = ["SCHEMA_PATH", "ConfigError", "load_schema", "renders_own_sets", "table2_conditions", "validate_config"]

SCHEMA_PATH = Path(__file__).resolve().parents[2] / "schemas" / "config.schema.yaml"

_NULL_SPELLINGS = {"", "~", "null", "Null", "NULL"}
# YAML 1.2's spellings of the booleans, and Python's (a nested --config value is YAML or a Python literal).
_BOOLEAN_SPELLINGS = {"true": True, "True": True, "TRUE": True, "false": False, "False": False, "FALSE": False}


class ConfigError(ValueError):
    """The workflow configuration does not satisfy the schema."""


@functools.lru_cache(maxsize=None)
def _cached_schema(path):
    schema = yaml.safe_load(Path(path).read_text())
    jsonschema.Draft202012Validator.check_schema(schema)
    return schema


def load_schema(path=SCHEMA_PATH):
    """Return (a private copy of) the config JSON Schema, checked against the 2020-12 meta-schema."""
    return copy.deepcopy(_cached_schema(str(path)))


def _fill_defaults(validator_class):
    """Extend a validator class so that validating also inserts each property's ``default``.

    The recipe from the jsonschema FAQ (the same one snakemake.utils.validate
    uses), with the default deep-copied so that filled-in objects such as
    ``observations`` never alias the schema.
    """
    validate_properties = validator_class.VALIDATORS["properties"]

    def set_defaults(validator, properties, instance, schema):
        if isinstance(instance, dict):
            for key, subschema in properties.items():
                if "default" in subschema and key not in instance:
                    instance[key] = copy.deepcopy(subschema["default"])
        yield from validate_properties(validator, properties, instance, schema)

    return jsonschema.validators.extend(validator_class, {"properties": set_defaults})


_DefaultFillingValidator = _fill_defaults(jsonschema.Draft202012Validator)


def _schema_types(schema):
    types = schema.get("type", [])
    return {types} if isinstance(types, str) else set(types)


def _coerce(value, schema):
    """Read command-line strings as the numbers / nulls the schema asks for (see module docstring)."""
    types = _schema_types(schema)
    if isinstance(value, str):
        if "null" in types and value.strip() in _NULL_SPELLINGS:
            return None
        if "boolean" in types and "string" not in types and value.strip() in _BOOLEAN_SPELLINGS:
            return _BOOLEAN_SPELLINGS[value.strip()]
        if "string" not in types and types & {"integer", "number"}:
            text = value.strip()
            try:
                return int(text)
            except ValueError:
                pass
            if "number" in types:
                try:
                    number = float(text)
                except ValueError:
                    return value
                return number if math.isfinite(number) else value
        return value
    if isinstance(value, float) and "integer" in types and "number" not in types and value.is_integer():
        return int(value)  # 36.0 is a valid JSON integer; hand the workflow an int
    if isinstance(value, list) and "array" in types and isinstance(schema.get("items"), dict):
        return [_coerce(item, schema["items"]) for item in value]
    if isinstance(value, dict) and "object" in types:
        properties = schema.get("properties", {})
        return {key: _coerce(item, properties[key]) if key in properties else item for key, item in value.items()}
    return value


def _key_path(path):
    """Render a jsonschema path deque as ``observations.min_cos_incidence`` or ``albedos[1]``."""
    text = ""
    for part in path:
        if isinstance(part, int):
            text += f"[{part}]"
        else:
            text += f".{part}" if text else str(part)
    return text


def _describe(error):
    """One line naming the offending key for one jsonschema error."""
    where = _key_path(error.absolute_path)
    prefix = f"{where}." if where else ""
    if error.validator == "additionalProperties":
        allowed = sorted(error.schema.get("properties", {}))
        unknown = sorted(set(error.instance) - set(allowed))
        line = "unknown config key(s): {} (allowed: {})".format(
            ", ".join(f"'{prefix}{key}'" for key in unknown),
            ", ".join(f"'{prefix}{key}'" for key in allowed),
        )
        for key in unknown:
            match = difflib.get_close_matches(str(key), allowed, n=1)
            if match:
                line += f"; did you mean '{prefix}{match[0]}' instead of '{prefix}{key}'?"
        return line
    if error.validator == "required":
        missing = [key for key in error.validator_value if key not in error.instance]
        return "missing required config key(s): " + ", ".join(f"'{prefix}{key}'" for key in missing)
    return f"config key '{where or '<top level>'}': {error.message}"


def validate_config(config):
    """Validate ``config`` against the schema, fill in defaults, and return it.

    Returns the validated config with command-line strings coerced (see the
    module docstring) and every missing key that has a default filled in.
    ``config`` itself is updated in place as well, as snakemake.utils.validate
    does, so the Snakefile's global ``config`` sees the defaults.

    Raises:
        ConfigError: naming each offending key by its path, one problem a line.
    """
    if not isinstance(config, Mapping):
        raise ConfigError(f"the config must be a mapping of keys to values, not {type(config).__name__}")
    schema = _cached_schema(str(SCHEMA_PATH))
    candidate = _coerce(copy.deepcopy(dict(config)), schema)
    errors = sorted(
        _DefaultFillingValidator(schema).iter_errors(candidate),
        key=lambda error: (_key_path(error.absolute_path), error.validator),
    )
    if errors:
        problems = list(dict.fromkeys(_describe(error) for error in errors))
        if len(problems) == 1:
            raise ConfigError(problems[0])
        raise ConfigError(f"{len(problems)} config problems:\n" + "\n".join(f"  - {line}" for line in problems))
    _check_cross_references(candidate)
    if isinstance(config, dict):
        config.update(candidate)
    return candidate


def _check_cross_references(config):
    """What a JSON Schema cannot say: a key that names an entry of another key, or must exceed what another implies."""
    _check_imaging_conditions(config)
    max_turn = config.get("reconstruction", {}).get("match_max_turn_deg")
    if max_turn is not None and "n_images" in config and max_turn < 360.0 / config["n_images"]:
        raise ConfigError(
            f"config key 'reconstruction.match_max_turn_deg': {max_turn:g} deg pairs no image with another "
            f"(the body turns {360.0 / config['n_images']:g} deg between images at n_images {config['n_images']}); "
            f"set it to at least that, or null to match every pair"
        )
    models = config.get("model_mismatch", {})
    level_names = [level.get("name") for level in config.get("noise_levels", [])]
    # As for the Monte Carlo: an empty noise_levels turns the noisy cross-fits off, a name that is not there is a mistake.
    if models.get("enabled") and models.get("noise_level") is not None and level_names and models["noise_level"] not in level_names:
        raise ConfigError(
            f"config key 'model_mismatch.noise_level': {models['noise_level']!r} is not the name of a 'noise_levels' entry "
            f"(names: {level_names}); name one, or null for noiseless cross-fits only"
        )
    for key, what in (("parameters", "its parameters"), ("fit", "its per_point / global lists")):
        lacking = [law for law in models.get("models", []) if law not in models.get(key, {})] if models.get("enabled") else []
        if lacking:
            raise ConfigError(f"config key 'model_mismatch.{key}': no entry for {lacking} (each law in model_mismatch.models needs {what})")
    for law, placement in models.get("fit", {}).items() if models.get("enabled") else ():
        from asteroid_photometry.reflectance.laws import get_model

        unknown = [name for name in placement.get("per_point", []) + placement.get("global", []) if name not in get_model(law).parameters]
        if unknown:
            raise ConfigError(f"config key 'model_mismatch.fit.{law}': {unknown} are not parameters of {law} ({', '.join(get_model(law).parameters)})")
    study = config.get("noise_monte_carlo", {})
    names = [level.get("name") for level in config.get("noise_levels", [])]
    # An empty noise_levels turns the noise off, the Monte Carlo with it; a name that is not there is a mistake.
    if study.get("realisations", 0) > 0 and names and study["level"] not in names:
        raise ConfigError(
            f"config key 'noise_monte_carlo.level': {study['level']!r} is not the name of a 'noise_levels' entry "
            f"(names: {names}); name one, or set noise_monte_carlo.realisations to 0"
        )


#: The views' latitude and the phase angle: the ranges of the config keys 'view_latitude_deg' and 'light_angles_deg'.
MAX_VIEW_LATITUDE_DEG = 80.0
MAX_PHASE_DEG = 80.0


def _check_imaging_conditions(config):
    """Table 2's imaging conditions: unique names, names of existing noise levels and surface maps, what the rules run."""
    if not config.get("reconstruction", {}).get("enabled", True):
        return
    conditions = config.get("imaging_conditions", [])
    names = [entry["name"] for entry in conditions]
    repeated = sorted({name for name in names if names.count(name) > 1})
    if repeated:
        raise ConfigError(f"config key 'imaging_conditions': the names must be unique, {repeated} repeated")
    level_names = [level.get("name") for level in config.get("noise_levels", [])]
    map_names = [entry.get("name") for entry in config.get("surface_maps", [])]
    uses_priors = True in config.get("reconstruction", {}).get("priors", [True])
    for position, entry in enumerate(conditions):
        where = f"config key 'imaging_conditions[{position}]' ({entry['name']})"
        # As for the Monte Carlo: an empty noise_levels (surface_maps) turns the conditions that need one off
        # (table2_conditions), a name that is not there is a mistake.
        if entry.get("sensor_level") is not None and level_names and entry["sensor_level"] not in level_names:
            raise ConfigError(f"{where}: sensor_level {entry['sensor_level']!r} is not the name of a 'noise_levels' entry (names: {level_names})")
        if entry.get("surface_map") is not None and map_names and entry["surface_map"] not in map_names:
            raise ConfigError(f"{where}: surface_map {entry['surface_map']!r} is not the name of a 'surface_maps' entry (names: {map_names})")
        # Views and Sun out of the configured geometry (the condition renders its own sets): still in the ranges
        # of the configured geometry's own keys.
        latitude = config.get("view_latitude_deg", 0.0) + entry.get("view_latitude_deg", 0.0)
        if entry.get("view_latitude_deg", 0.0) and not -MAX_VIEW_LATITUDE_DEG <= latitude <= MAX_VIEW_LATITUDE_DEG:
            raise ConfigError(
                f"{where}: view_latitude_deg {entry['view_latitude_deg']:g} puts the views at latitude {latitude:g} "
                f"(with the config key 'view_latitude_deg' {config.get('view_latitude_deg', 0.0):g}); the sum must lie in "
                f"[-{MAX_VIEW_LATITUDE_DEG:g}, {MAX_VIEW_LATITUDE_DEG:g}]"
            )
        tilt = entry.get("light_out_of_plane_deg", 0.0)
        if tilt:
            phase = max(math.degrees(math.acos(math.cos(math.radians(angle)) * math.cos(math.radians(tilt)))) for angle in config.get("light_angles_deg", [0.0]))
            if phase > MAX_PHASE_DEG:
                raise ConfigError(
                    f"{where}: light_out_of_plane_deg {tilt:g} with the light angles {config.get('light_angles_deg')} gives a phase angle of "
                    f"{phase:.1f} deg, more than {MAX_PHASE_DEG:g} (the limit of 'light_angles_deg')"
                )
        if uses_priors and entry.get("prior_sigma_m", 1.0) == 0.0:
            raise ConfigError(f"{where}: prior_sigma_m 0 gives no navigation priors, but reconstruction.priors asks for a reconstruction with them")


def condition_sets(conditions: dict, base_sets: list) -> dict:
    """The base sets each of Table 2's ``conditions`` (by name) runs on: its ``sets``, in the order of
    ``base_sets``, or all of them where ``sets`` is null; :class:`ConfigError` for a set id not among them."""
    chosen = {}
    for name, entry in conditions.items():
        wanted = entry.get("sets")
        unknown = [set_id for set_id in wanted or [] if set_id not in base_sets]
        if unknown:
            raise ConfigError(
                f"config key 'imaging_conditions' ({name}): sets {unknown} are not base sets of this config "
                f"(its {len(base_sets)} base sets are named as {base_sets[0]!r}: light angle, albedo, k)"
            )
        chosen[name] = [set_id for set_id in base_sets if wanted is None or set_id in wanted]
    return chosen


#: The imaging-condition keys that change the rendered images, not only how a camera records them.
CONDITION_RENDER_KEYS = ("view_latitude_deg", "light_out_of_plane_deg", "relief")


def renders_own_sets(condition: dict) -> bool:
    """Whether an ``imaging_conditions`` entry renders its own copy of each set it starts from: views at another
    latitude, the Sun out of the camera's x-z plane or relief below the shape model's facets (``CONDITION_RENDER_KEYS``)."""
    return any(condition.get(key) for key in CONDITION_RENDER_KEYS)


def table2_conditions(config) -> dict:
    """The imaging conditions Table 2 runs, by name: all of ``imaging_conditions`` but those that need a
    noise level or a surface map when ``noise_levels`` or ``surface_maps`` is empty (that turns them off)."""
    if not config["reconstruction"]["enabled"]:
        return {}
    return {
        entry["name"]: entry for entry in config["imaging_conditions"]
        if not (entry.get("sensor_level") and not config["noise_levels"]) and not (entry.get("surface_map") and not config["surface_maps"])
    }
