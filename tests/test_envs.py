"""The pip route (requirements.txt) and the conda route (envs/*.yaml) pin the same packages.

Every package pinned in one file must be pinned, to the same exact version, in
the other; names are compared after PEP 503 normalisation (case, '-', '_', '.').
The comparison is a plain function so that it can be shown to fail on a
mismatched pair of files (the negative tests below).
"""

import re
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
REQUIREMENTS = REPO / "requirements.txt"
CONDA_ENVS = sorted((REPO / "envs").glob("*.yaml"))

# Entries of a conda env that are not Python packages pinned by requirements.txt:
# the interpreter (pinned to a minor series) and pip itself.
CONDA_ONLY = {"python", "pip"}
PYTHON_SERIES = "3.11"

_SPEC = re.compile(r"^\s*(?P<name>[A-Za-z0-9][A-Za-z0-9._-]*)\s*(?P<op>==|=|>=|<=|~=|!=|>|<)?\s*(?P<version>\S*)\s*$")


def normalise_name(name):
    """PEP 503 name normalisation: 'PyYAML' == 'pyyaml', 'a_b' == 'a-b'."""
    return re.sub(r"[-_.]+", "-", name).lower()


def _parse_spec(spec, source):
    """Split 'name==1.2.3' into (normalised name, operator, version)."""
    match = _SPEC.match(spec.split(";")[0].split("#")[0])
    if not match:
        raise ValueError(f"{source}: cannot parse requirement {spec!r}")
    return normalise_name(match["name"]), match["op"] or "", match["version"]


def read_requirements(path):
    """Return {normalised name: (operator, version)} from a pip requirements file."""
    pins = {}
    for line in Path(path).read_text().splitlines():
        line = line.split("#")[0].strip()
        if not line:
            continue
        name, op, version = _parse_spec(line, path)
        if name in pins:
            raise ValueError(f"{path}: {name} is listed twice")
        pins[name] = (op, version)
    return pins


def read_conda_env(path):
    """Return ({name: (op, version)} for conda packages, {name: (op, version)} for the pip section)."""
    env = yaml.safe_load(Path(path).read_text())
    conda, pip = {}, {}
    for entry in env.get("dependencies") or []:
        if isinstance(entry, dict):
            for spec in entry.get("pip") or []:
                name, op, version = _parse_spec(spec, path)
                pip[name] = (op, version)
        else:
            name, op, version = _parse_spec(str(entry), path)
            conda[name] = (op, version)
    return conda, pip


def compare_pins(requirements_path, env_path):
    """List every disagreement between a requirements file and a conda env file.

    An empty list means: every pin is exact (``==``), each package pinned in
    one file is pinned to the same version in the other, the conda env pins
    ``python=3.11`` (PYTHON_SERIES) and no package appears in both its conda and
    pip sections.
    """
    problems = []
    requirements = read_requirements(requirements_path)
    conda, pip = read_conda_env(env_path)

    for name in sorted(set(conda) & set(pip)):
        problems.append(f"{env_path}: {name} is in both the conda and the pip section")

    python = conda.get("python")
    if python != ("=", PYTHON_SERIES):
        problems.append(f"{env_path}: expected python={PYTHON_SERIES}, found {python}")

    env_pins = {name: pin for name, pin in {**conda, **pip}.items() if name not in CONDA_ONLY}
    for source, pins in ((requirements_path, requirements), (env_path, env_pins)):
        for name, (op, version) in sorted(pins.items()):
            if op != "==" or not version or "*" in version:
                problems.append(f"{source}: {name} is not pinned exactly ('{op}{version}'); use ==")

    for name in sorted(set(requirements) - set(env_pins)):
        problems.append(f"{name} is pinned in {requirements_path} but missing from {env_path}")
    for name in sorted(set(env_pins) - set(requirements)):
        problems.append(f"{name} is pinned in {env_path} but missing from {requirements_path}")
    for name in sorted(set(requirements) & set(env_pins)):
        if requirements[name][1] != env_pins[name][1]:
            problems.append(
                f"{name}: {requirements_path} pins {requirements[name][1]}, {env_path} pins {env_pins[name][1]}"
            )
    return problems


def test_there_is_a_conda_env():
    assert CONDA_ENVS, "envs/ holds no conda env file"


@pytest.mark.parametrize("env_path", CONDA_ENVS, ids=lambda p: p.name)
def test_conda_env_matches_requirements(env_path):
    assert compare_pins(REQUIREMENTS, env_path) == []


def test_requirements_pin_the_workflow_stack():
    pinned = set(read_requirements(REQUIREMENTS))
    for needed in ["snakemake", "mitsuba", "drjit", "numpy", "scipy", "jsonschema", "pyyaml", "pytest"]:
        assert needed in pinned


# --- the comparison can fail -------------------------------------------------


def _write_pair(tmp_path, requirements, env):
    requirements_path = tmp_path / "requirements.txt"
    env_path = tmp_path / "env.yaml"
    requirements_path.write_text(requirements)
    env_path.write_text(env)
    return requirements_path, env_path


GOOD_ENV = """\
channels: [conda-forge]
dependencies:
  - python=3.11
  - pip
  - numpy==2.4.6
  - pyyaml==6.0.3
  - pip:
      - snakemake_executor_plugin_slurm==2.8.0
"""
GOOD_REQUIREMENTS = "numpy==2.4.6\nPyYAML==6.0.3  # comment\nsnakemake-executor-plugin-slurm==2.8.0\n"


def test_matching_pair_passes_with_normalised_names(tmp_path):
    assert compare_pins(*_write_pair(tmp_path, GOOD_REQUIREMENTS, GOOD_ENV)) == []


def test_version_mismatch_is_reported(tmp_path):
    requirements = GOOD_REQUIREMENTS.replace("numpy==2.4.6", "numpy==2.4.5")
    problems = compare_pins(*_write_pair(tmp_path, requirements, GOOD_ENV))
    assert len(problems) == 1 and "numpy" in problems[0] and "2.4.5" in problems[0]


def test_package_missing_on_either_side_is_reported(tmp_path):
    requirements = GOOD_REQUIREMENTS + "scipy==1.17.1\n"
    env = GOOD_ENV.replace("  - numpy==2.4.6\n", "")
    problems = compare_pins(*_write_pair(tmp_path, requirements, env))
    assert any("numpy" in p and "missing from" in p for p in problems)
    assert any("scipy" in p and "missing from" in p for p in problems)


@pytest.mark.parametrize("loose", ["numpy>=2.4.6", "numpy", "numpy=2.4.6", "numpy==2.4.*"])
def test_loose_pins_are_reported(tmp_path, loose):
    env = GOOD_ENV.replace("numpy==2.4.6", loose)
    problems = compare_pins(*_write_pair(tmp_path, GOOD_REQUIREMENTS, env))
    assert any("numpy" in p and "not pinned exactly" in p for p in problems)


def test_wrong_python_series_is_reported(tmp_path):
    env = GOOD_ENV.replace("python=3.11", "python=3.12")
    problems = compare_pins(*_write_pair(tmp_path, GOOD_REQUIREMENTS, env))
    assert any("python" in p for p in problems)
