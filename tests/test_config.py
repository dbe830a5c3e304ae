"""The config schema and the shipped configs agree, and bad configs fail with messages naming the key."""

import copy
import sys
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "workflow"))

from asteroid_photometry.core.config import SCHEMA_PATH, ConfigError, load_schema, validate_config  # noqa: E402

LAWS = ["lambert", "lommel_seeliger", "lunar_lambert", "minnaert", "hapke"]
SHIPPED_CONFIGS = [
    REPO / "config" / "config.yaml", REPO / "config" / "test.yaml", REPO / "config" / "tuning.yaml", REPO / "config" / "tuning_mid.yaml", REPO / "config" / "amica_ablation.yaml",
    REPO / "config" / "conditions_geometry.yaml", REPO / "config" / "oblique_ablation.yaml", REPO / "config" / "map_draws.yaml",
    REPO / "config" / "map_parts.yaml", REPO / "config" / "noise_draws.yaml",
    REPO / "config" / "amica_draws.yaml",
]


def _load(path):
    return yaml.safe_load(Path(path).read_text())


@pytest.fixture
def test_config():
    return _load(REPO / "config" / "test.yaml")


def _error(config):
    with pytest.raises(ConfigError) as caught:
        validate_config(config)
    return str(caught.value)


# --- the schema itself ---------------------------------------------------------


def _walk_object_schemas(schema, path="<top level>"):
    """Yield (key path, schema) for every object schema, the top level included."""
    if "object" in ([schema["type"]] if isinstance(schema.get("type"), str) else schema.get("type", [])):
        yield path, schema
    for key, subschema in schema.get("properties", {}).items():
        yield from _walk_object_schemas(subschema, key if path == "<top level>" else f"{path}.{key}")
    if isinstance(schema.get("items"), dict):
        yield from _walk_object_schemas(schema["items"], f"{path}[]")


def test_schema_forbids_unknown_keys_and_describes_every_key():
    schema = load_schema()
    objects = list(_walk_object_schemas(schema))
    assert [path for path, _ in objects] == ["<top level>", "observations", "noise_levels[]", "noise_monte_carlo", "surface_maps[]", "imaging_conditions[]", "imaging_conditions[].relief", "reconstruction", "geometry_sensitivity",
        "model_mismatch", "model_mismatch.parameters", *(f"model_mismatch.parameters.{law}" for law in LAWS),
        "model_mismatch.fit", *(f"model_mismatch.fit.{law}" for law in LAWS),
    ]
    for path, object_schema in objects:
        assert object_schema.get("additionalProperties") is False, path
        for key, subschema in object_schema["properties"].items():
            assert subschema.get("description", "").strip(), f"{path}: {key} has no description"
            assert "type" in subschema, f"{path}: {key} has no type"


def test_every_key_is_required_or_has_a_default():
    schema = load_schema()
    for path, object_schema in _walk_object_schemas(schema):
        required = set(object_schema.get("required", []))
        for key, subschema in object_schema["properties"].items():
            assert (key in required) != ("default" in subschema), f"{path}: {key}"


def test_schema_defaults_are_valid_values():
    schema = load_schema()
    minimal = {key: _load(SHIPPED_CONFIGS[0])[key] for key in schema["required"]}
    filled = validate_config(minimal)
    assert set(filled) == set(schema["properties"])


def test_readme_documents_every_key():
    readme = (REPO / "config" / "README.md").read_text()
    schema = load_schema()
    for key, subschema in schema["properties"].items():
        assert f"`{key}`" in readme, key
        for nested in subschema.get("properties", {}):
            assert f"`{key}.{nested}`" in readme, f"{key}.{nested}"


def test_shipped_configs_set_only_known_keys_and_all_of_them():
    keys = set(load_schema()["properties"])
    for path in SHIPPED_CONFIGS:
        assert set(_load(path)) == keys, path


# --- shipped configs ------------------------------------------------------------


@pytest.mark.parametrize("path", SHIPPED_CONFIGS, ids=lambda p: p.name)
def test_shipped_config_validates_unchanged(path):
    config = _load(path)
    assert validate_config(copy.deepcopy(config)) == config


def test_schema_works_with_snakemakes_own_validate(test_config):
    snakemake_utils = pytest.importorskip("snakemake.utils")
    del test_config["mitsuba_variant"]
    snakemake_utils.validate(test_config, str(SCHEMA_PATH))
    assert test_config["mitsuba_variant"] == "auto"


# --- unknown keys ----------------------------------------------------------------


def test_unknown_top_level_key_is_named_with_the_allowed_keys(test_config):
    test_config["foo"] = 1
    message = _error(test_config)
    assert message.startswith("unknown config key(s): 'foo'")
    assert "allowed: 'albedos'," in message and "'view_latitude_deg'" in message


def test_misspelt_key_gets_a_suggestion(test_config):
    test_config["albdeos"] = test_config.pop("albedos")
    message = _error(test_config)
    assert "'albdeos'" in message and "did you mean 'albedos'" in message
    assert "missing required config key(s): 'albedos'" in message


def test_unknown_nested_key_is_named_by_its_path(test_config):
    test_config["observations"]["min_cos_incidense"] = 0.2
    message = _error(test_config)
    assert "unknown config key(s): 'observations.min_cos_incidense'" in message
    assert "'observations.min_cos_incidence'" in message


# --- wrong types and ranges --------------------------------------------------------


@pytest.mark.parametrize(
    "key, value, expected",
    [
        ("albedos", [], "config key 'albedos': [] should be non-empty"),
        ("albedos", [0.5, 0.5], "config key 'albedos': [0.5, 0.5] has non-unique elements"),
        ("albedos", [0.5, 0.0], "config key 'albedos[1]': 0.0 is less than or equal to the minimum of 0"),
        ("albedos", [1.2], "config key 'albedos[0]': 1.2 is greater than the maximum of 1"),
        ("albedos", 0.5, "config key 'albedos': 0.5 is not of type 'array'"),
        ("minnaert_k", [1.6], "config key 'minnaert_k[0]': 1.6 is greater than the maximum of 1.5"),
        ("minnaert_k", [0], "config key 'minnaert_k[0]'"),
        ("light_angles_deg", [-1], "config key 'light_angles_deg[0]': -1 is less than the minimum of 0"),
        ("light_angles_deg", [90], "config key 'light_angles_deg[0]'"),
        ("light_angles_deg", [10, 10], "config key 'light_angles_deg'"),
        ("n_images", 2, "config key 'n_images': 2 is less than the minimum of 3"),
        ("n_images", 12.5, "config key 'n_images': 12.5 is not of type 'integer'"),
        ("n_images", True, "config key 'n_images': True is not of type 'integer'"),
        ("image_size", 16, "config key 'image_size'"),
        ("image_size", 10000, "config key 'image_size'"),
        ("samples_per_pixel", 0, "config key 'samples_per_pixel'"),
        ("camera_distance_km", 1, "config key 'camera_distance_km'"),
        ("view_latitude_deg", 85, "config key 'view_latitude_deg'"),
        ("shape_model", "eros", "config key 'shape_model': 'eros' is not one of"),
        ("shape_model_path", 3, "config key 'shape_model_path'"),
        ("observations", None, "config key 'observations': None is not of type 'object'"),
        ("estimators", [], "config key 'estimators'"),
        ("estimators", ["koizumi_lm", "koizumi_lm"], "config key 'estimators'"),
        ("estimators", ["least_squares"], "config key 'estimators[0]': 'least_squares' is not one of"),
        ("mitsuba_variant", "cuda", "config key 'mitsuba_variant'"),
    ],
)
def test_wrong_value_is_rejected_naming_the_key(test_config, key, value, expected):
    test_config[key] = value
    assert expected in _error(test_config)


@pytest.mark.parametrize(
    "nested, value",
    [
        ("min_cos_incidence", 1.5),
        ("min_cos_incidence", 0),
        ("min_cos_emission", 1),
        ("min_cos_emission", "high"),
        ("min_observations_per_point", 1),
        ("min_observations_per_point", 2.5),
    ],
)
def test_wrong_nested_value_is_rejected_naming_the_path(test_config, nested, value):
    test_config["observations"][nested] = value
    assert f"config key 'observations.{nested}': {value!r}" in _error(test_config)


def test_every_problem_is_reported_at_once(test_config):
    test_config.update(n_images=1, foo=2)
    test_config["observations"]["min_cos_emission"] = 2
    message = _error(test_config)
    assert message.startswith("3 config problems:")
    for key in ["'n_images'", "'foo'", "'observations.min_cos_emission'"]:
        assert key in message


# --- imaging conditions of their own views, Sun and relief -----------------------------


def _with_condition(config, **keys):
    config["imaging_conditions"] = [{"name": "other", **keys}]
    return config


RELIEF = {"subdivisions": 1, "rms_slope_deg": 3, "seed": 0}


def test_conditions_of_their_own_views_sun_and_relief_validate(test_config):
    config = validate_config(_with_condition(test_config, view_latitude_deg=20, light_out_of_plane_deg=-20, relief=dict(RELIEF)))
    entry = config["imaging_conditions"][0]
    assert (entry["view_latitude_deg"], entry["light_out_of_plane_deg"]) == (20, -20)
    assert entry["relief"] == RELIEF
    assert validate_config(_with_condition(test_config))["imaging_conditions"][0]["relief"] is None


@pytest.mark.parametrize(
    "keys, expected",
    [
        (dict(view_latitude_deg=85), "config key 'imaging_conditions[0].view_latitude_deg': 85 is greater than the maximum of 80"),
        (dict(light_out_of_plane_deg="up"), "config key 'imaging_conditions[0].light_out_of_plane_deg': 'up' is not of type 'number'"),
        (dict(relief={**RELIEF, "rms_slope_deg": 50}), "config key 'imaging_conditions[0].relief.rms_slope_deg': 50 is greater than or equal to the maximum of 45"),
        (dict(relief={**RELIEF, "rms_slope_deg": 0}), "config key 'imaging_conditions[0].relief.rms_slope_deg': 0 is less than or equal to the minimum of 0"),
        (dict(relief={**RELIEF, "subdivisions": 4}), "config key 'imaging_conditions[0].relief.subdivisions': 4 is greater than the maximum of 3"),
        (dict(relief={"subdivisions": 1, "seed": 0}), "missing required config key(s): 'imaging_conditions[0].relief.rms_slope_deg'"),
        (dict(relief={**RELIEF, "levels": 1}), "unknown config key(s): 'imaging_conditions[0].relief.levels'"),
        (dict(relief=3.0), "config key 'imaging_conditions[0].relief': 3.0 is not of type 'object', 'null'"),
    ],
)
def test_a_wrong_condition_geometry_or_relief_is_rejected_naming_the_key(test_config, keys, expected):
    assert expected in _error(_with_condition(test_config, **keys))


def test_a_conditions_sets_are_a_non_empty_list_of_set_ids_or_null(test_config):
    assert validate_config(_with_condition(test_config))["imaging_conditions"][0]["sets"] is None
    assert validate_config(_with_condition(test_config, sets=["light0_albedo0.5_k0.8"]))["imaging_conditions"][0]["sets"] == ["light0_albedo0.5_k0.8"]
    assert "config key 'imaging_conditions[0].sets': [] should be non-empty" in _error(_with_condition(test_config, sets=[]))
    assert "config key 'imaging_conditions[0].sets': 'light0' is not of type 'array', 'null'" in _error(_with_condition(test_config, sets="light0"))


def test_the_views_latitude_is_the_configs_plus_the_conditions_and_must_stay_in_range(test_config):
    test_config["view_latitude_deg"] = 70.0
    message = _error(_with_condition(test_config, view_latitude_deg=20))
    assert message.startswith("config key 'imaging_conditions[0]' (other): view_latitude_deg 20 puts the views at latitude 90")
    assert "config key 'view_latitude_deg'" in message and "[-80, 80]" in message
    test_config["view_latitude_deg"] = 50.0
    assert validate_config(_with_condition(test_config, view_latitude_deg=20))["imaging_conditions"][0]["view_latitude_deg"] == 20


def test_the_sun_out_of_plane_keeps_the_phase_angle_within_the_light_angles_range(test_config):
    test_config["light_angles_deg"] = [0, 75]
    message = _error(_with_condition(test_config, light_out_of_plane_deg=-50))
    assert message.startswith("config key 'imaging_conditions[0]' (other): light_out_of_plane_deg -50 with the light angles [0, 75] gives a phase angle of 80.4")
    assert validate_config(_with_condition(test_config, light_out_of_plane_deg=-40))


def test_the_pairs_turn_must_reach_the_next_image(test_config):
    test_config["n_images"] = 20
    test_config["reconstruction"]["match_max_turn_deg"] = 15
    message = _error(test_config)
    assert message.startswith("config key 'reconstruction.match_max_turn_deg': 15 deg pairs no image with another")
    assert "turns 18 deg between images at n_images 20" in message
    test_config["reconstruction"]["match_max_turn_deg"] = 54
    assert validate_config(test_config)["reconstruction"]["match_max_turn_deg"] == 54


def test_non_mapping_config_is_rejected():
    with pytest.raises(ConfigError, match="mapping"):
        validate_config(None)


def test_config_error_is_a_value_error():
    assert issubclass(ConfigError, ValueError)


# --- defaults and command-line values ------------------------------------------------


def test_defaults_are_filled_in_the_returned_and_the_given_config():
    config = {"albedos": [0.5], "minnaert_k": [0.9], "light_angles_deg": [0], "observations": {"min_cos_emission": 0.3}}
    filled = validate_config(config)
    assert filled["n_images"] == 36
    assert filled["image_size"] == 512
    assert filled["shape_model"] == "gaskell_ver64q"
    assert filled["shape_model_path"] is None
    assert filled["estimators"] == ["varpro", "koizumi_lm", "iwano_linear"]
    assert filled["mitsuba_variant"] == "auto"
    assert filled["observations"] == {
        "min_cos_incidence": 0.1,
        "min_cos_emission": 0.3,
        "min_observations_per_point": 4,
        "pixel_selection": "pure",
    }
    assert config == filled  # updated in place, like snakemake.utils.validate


def test_filled_defaults_do_not_alias_the_schema():
    first = validate_config({"albedos": [0.5], "minnaert_k": [0.9], "light_angles_deg": [0]})
    first["observations"]["min_cos_incidence"] = 0.9
    first["estimators"].append("x")
    second = validate_config({"albedos": [0.5], "minnaert_k": [0.9], "light_angles_deg": [0]})
    assert second["observations"]["min_cos_incidence"] == 0.1
    assert second["estimators"] == ["varpro", "koizumi_lm", "iwano_linear"]


def test_invalid_config_is_left_unchanged(test_config):
    del test_config["n_images"]
    test_config["foo"] = 1
    before = copy.deepcopy(test_config)
    _error(test_config)
    assert test_config == before


def test_command_line_strings_are_read_as_the_schema_asks():
    # What `snakemake --config 'albedos=[0.6, 0.7]' 'observations={min_cos_incidence: 0.2}'
    # shape_model_path=null` hands the Snakefile (lists and mappings parsed as strings).
    from snakemake.cli import parse_config

    overrides = parse_config(
        ["albedos=[0.6, 0.7]", "minnaert_k=[1]", "light_angles_deg=[0, 10]",
         "observations={min_observations_per_point: 3}", "shape_model_path=null"]
    )
    assert overrides["albedos"] == ["0.6", "0.7"]
    filled = validate_config(overrides)
    assert filled["albedos"] == [0.6, 0.7]
    assert filled["minnaert_k"] == [1]
    assert filled["light_angles_deg"] == [0, 10]
    assert filled["observations"]["min_observations_per_point"] == 3
    assert filled["shape_model_path"] is None


@pytest.mark.parametrize("spelling, expected", [("false", False), ("False", False), ("true", True), ("TRUE", True)])
def test_command_line_booleans_are_read_as_booleans(spelling, expected):
    from snakemake.cli import parse_config

    overrides = parse_config(
        ["albedos=[0.6]", "minnaert_k=[1]", "light_angles_deg=[0]", f"reconstruction={{enabled: {spelling}, priors: [{spelling}]}}"]
    )
    assert overrides["reconstruction"]["enabled"] == spelling  # Snakemake hands it over as a string
    filled = validate_config(overrides)
    assert filled["reconstruction"]["enabled"] is expected and filled["reconstruction"]["priors"] == [expected]


def test_a_word_is_not_a_boolean(test_config):
    test_config["reconstruction"] = {"enabled": "yes please"}
    assert "config key 'reconstruction.enabled': 'yes please' is not of type 'boolean'" in _error(test_config)


def test_strings_that_are_not_numbers_still_fail(test_config):
    test_config["albedos"] = ["half"]
    assert "config key 'albedos[0]': 'half' is not of type 'number'" in _error(test_config)
    test_config["albedos"] = ["nan"]
    assert "config key 'albedos[0]'" in _error(test_config)


def test_whole_floats_become_ints_where_an_integer_is_asked(test_config):
    test_config["n_images"] = 12.0
    assert validate_config(test_config)["n_images"] == 12
    assert isinstance(test_config["n_images"], int)


def test_strings_stay_strings_where_a_string_is_allowed(test_config):
    test_config["shape_model_path"] = "12"
    assert validate_config(test_config)["shape_model_path"] == "12"


def test_monte_carlo_level_must_name_a_noise_level(test_config):
    test_config["noise_monte_carlo"] = {"level": "amica-12", "realisations": 4}
    message = _error(test_config)
    assert "config key 'noise_monte_carlo.level': 'amica-12'" in message and "amica12" in message


def test_monte_carlo_off_needs_no_noise_level(test_config):
    test_config["noise_levels"] = []
    test_config["noise_monte_carlo"] = {"level": "amica12", "realisations": 4}  # no noise at all: nothing to repeat
    assert validate_config(test_config)["noise_monte_carlo"]["realisations"] == 4
    test_config["noise_monte_carlo"] = {"level": "amica12", "realisations": 0}
    assert validate_config(test_config)["noise_monte_carlo"]["realisations"] == 0
    del test_config["noise_monte_carlo"]
    assert validate_config(test_config)["noise_monte_carlo"] == {"level": "amica12", "realisations": 0}


# --- the tuning grids -------------------------------------------------------------


def _sets(config):
    return {(a, k, light) for a in config["albedos"] for k in config["minnaert_k"] for light in config["light_angles_deg"]}


@pytest.mark.parametrize("name", ["tuning.yaml", "tuning_mid.yaml"])
def test_tuning_grids_share_no_set_or_seed_with_the_papers(name):
    """Table 2's defaults are chosen on sets the reported tables do not run: no (albedo, k, light) set and none of
    the noise, prior or surface-map seeds in common with config.yaml."""
    paper, tuning = _load(REPO / "config" / "config.yaml"), _load(REPO / "config" / name)
    assert not _sets(paper) & _sets(tuning)
    assert tuning["noise_seed"] != paper["noise_seed"]
    assert tuning["reconstruction"]["prior_seed"] != paper["reconstruction"]["prior_seed"]
    paper_map_seeds = {m["seed"] for m in paper["surface_maps"]}
    assert not paper_map_seeds & {m["seed"] for m in tuning["surface_maps"]}
