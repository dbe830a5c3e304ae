"""docs/architecture.md against the code: every package it names exists, and imports go one way."""

import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
LIBRARY = REPO / "workflow" / "asteroid_photometry"
ARCHITECTURE = REPO / "docs" / "architecture.md"


def documented_layers() -> list[str]:
    """The packages of the numbered list under "## The packages", in order (top first)."""
    text = ARCHITECTURE.read_text()
    section = text.split("## The packages", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"^\d+\. `([a-z_]+)`", section, flags=re.M)


def package_of(path: Path) -> str | None:
    parts = path.relative_to(LIBRARY).parts
    return parts[0] if len(parts) > 1 else None


def imported_packages(path: Path) -> set[tuple[int, str]]:
    """(line, package) of every asteroid_photometry package this file imports, at any depth (lazy imports too)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        names = []
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module + "." + alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level:
            raise AssertionError(f"{path}:{node.lineno}: relative import; the library imports absolutely")
        elif isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        for name in names:
            parts = name.split(".")
            if parts[0] == "asteroid_photometry" and len(parts) > 1:
                found.add((node.lineno, parts[1]))
    return found


def test_documented_packages_are_the_library_packages():
    layers = documented_layers()
    assert len(layers) == len(set(layers)) >= 5
    on_disk = sorted(p.name for p in LIBRARY.iterdir() if p.is_dir() and (p / "__init__.py").exists())
    assert sorted(layers) == on_disk
    # Every module the page names as `package.module` exists.
    for package, module in re.findall(r"`([a-z_]+)\.([a-z_0-9]+)`", ARCHITECTURE.read_text()):
        if package in layers and not module[0].isupper():
            assert (LIBRARY / package / f"{module}.py").exists() or hasattr_in_package(package, module), f"{package}.{module}"


def hasattr_in_package(package: str, name: str) -> bool:
    """A documented ``package.name`` that is a function or constant of one of the package's modules."""
    for path in (LIBRARY / package).glob("*.py"):
        tree = ast.parse(path.read_text())
        for node in tree.body:
            if isinstance(node, (ast.FunctionDef, ast.ClassDef)) and node.name == name:
                return True
            if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == name for t in node.targets):
                return True
    return False


def test_imports_go_one_way():
    rank = {package: position for position, package in enumerate(documented_layers())}
    violations = []
    for path in sorted(LIBRARY.rglob("*.py")):
        own = package_of(path)
        if own is None:
            continue
        for line, imported in sorted(imported_packages(path)):
            if imported not in rank:
                violations.append(f"{path.relative_to(REPO)}:{line}: imports unknown package {imported}")
            elif rank[imported] > rank[own]:
                violations.append(f"{path.relative_to(REPO)}:{line}: {own} imports {imported}, which sits below it")
    assert not violations, "\n".join(violations)


@pytest.mark.parametrize("package", ["world", "estimation"])
def test_world_and_estimation_never_import_evaluation(package):
    for path in (LIBRARY / package).rglob("*.py"):
        assert all(imported != "evaluation" for _, imported in imported_packages(path)), path


def test_only_evaluation_truth_reads_the_true_light_and_surface():
    """The set's true light (frames.json's light_dir_cam) and surface maps are read in evaluation/truth.py only."""
    readers = []
    for path in LIBRARY.rglob("*.py"):
        text = path.read_text()
        if re.search(r"""frames\[["']light_dir_cam["']\]|load_facet_maps\(|frames\[["'](albedo|minnaert_k)["']\]""", text):
            readers.append(str(path.relative_to(LIBRARY)))
    assert sorted(readers) == ["evaluation/truth.py", "world/surface_maps.py"]


def test_layering_check_catches_an_upward_import(tmp_path):
    """The checker itself: a world module importing evaluation is reported."""
    fake = tmp_path / "asteroid_photometry"
    (fake / "world").mkdir(parents=True)
    (fake / "world" / "__init__.py").write_text("")
    bad = fake / "world" / "bad.py"
    bad.write_text("def f():\n    from asteroid_photometry.evaluation import truth\n")
    assert (2, "evaluation") in imported_packages(bad)


#: The modules a stage's job imports (through its rule script); none of them builds a table.
STAGE_MODULES = ["table1", "table2", "table2_scoring", "mission", "monte_carlo", "sensitivity", "mismatch"]
#: The modules that read the truth: the one that reads the true light, poses, albedo and k, and the mission stage's (it
#: writes and reads the mission set's truth file).
TRUTH_MODULES = ["asteroid_photometry.evaluation.truth", "asteroid_photometry.experiments.mission"]


def modules_loaded_by(module: str, of: list[str]) -> list[str]:
    """Which of ``of`` importing ``module`` (in a fresh interpreter) loads."""
    code = f"import sys, {module}; print(' '.join(m for m in {of!r} if m in sys.modules))"
    run = subprocess.run([sys.executable, "-c", code], cwd=LIBRARY.parent, capture_output=True, text=True, check=True)
    return run.stdout.split()


def imported_modules(path: Path) -> set[str]:
    """Every module (``from m import name``: ``m`` and ``m.name``) this file imports, at any depth (lazy imports too)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module:
            found |= {node.module} | {f"{node.module}.{alias.name}" for alias in node.names}
        elif isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
    return found


#: The rules of Table 2 from the mission set to the estimates (tests/test_truth_dag.py walks their inputs).
IMAGE_ONLY_SCRIPTS = ["match_features", "reconstruct", "register_cloud", "refine_cloud", "mesh_light", "final_cloud", "estimate_cloud"]


def test_the_image_only_stages_import_nothing_that_reads_the_truth():
    """Table 2's stages from the mission set to the estimates cannot call what reads the truth: their rule scripts
    import the library's ``experiments.table2`` only (and the logging), which imports neither truth module, at any
    depth, nor loads one. Their scoring (``experiments.table2_scoring``) loads both."""
    for script in IMAGE_ONLY_SCRIPTS:
        library = {m for m in imported_modules(REPO / "workflow" / "scripts" / f"{script}.py") if m.startswith("asteroid_photometry.")}
        allowed = {"asteroid_photometry.core.logs", "asteroid_photometry.experiments.table2"}
        assert [m for m in library if m not in allowed and m.rsplit(".", 1)[0] not in allowed] == [], script
    stages = imported_modules(LIBRARY / "experiments" / "table2.py")
    assert not [m for m in stages if any(m == t or m.startswith(t + ".") for t in TRUTH_MODULES)]
    assert modules_loaded_by("asteroid_photometry.experiments.table2", TRUTH_MODULES) == []
    assert modules_loaded_by("asteroid_photometry.experiments.table2_scoring", TRUTH_MODULES) == TRUTH_MODULES


@pytest.mark.parametrize("module", STAGE_MODULES)
def test_stage_modules_import_without_pandas_or_scipy_stats(module):
    """pandas is imported where a table is built, not when a stage's module is: it takes about 0.45 s, and some
    800 jobs of a full run import these modules without building one. scipy.stats (about 0.4 s, also loaded by
    scipy.signal) likewise: a chi-square quantile comes from scipy.special, and the PSF's convolution imports
    scipy.signal where it blurs."""
    heavy = ["pandas", "scipy.stats", "scipy.signal"]
    loaded = modules_loaded_by(f"asteroid_photometry.experiments.{module}", heavy)
    assert loaded == [], f"importing experiments.{module} imports {loaded}"
