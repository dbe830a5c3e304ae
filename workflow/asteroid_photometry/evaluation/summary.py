"""The headline numbers of a run, in one Markdown page (``results/summary.md``).

Reads the result tables the workflow wrote (Table 1 is required, every other
one optional: a part of the experiment that was not configured has no table)
and writes, per table, the few numbers a reader looks for first, then the
provenance of the run: the commit, the config file's sha256 and the effective
config. One line per table, the "headline", is gathered at the top; the
README quotes those lines, and a test checks that every number it quotes is
in the committed copy (``docs/results/summary.md``).

Numbers are written with two significant digits (:func:`number`): a headline
changes when a result does, not with its last digits. Only the runtime section
changes from run to run (it is wall-clock time).
"""

from __future__ import annotations

import hashlib
import json
import math
import subprocess
from pathlib import Path
from typing import Mapping

import pandas as pd
import yaml

from asteroid_photometry.core.files import write_text
from asteroid_photometry.evaluation.metrics import TABLE2_BOUNDS, table2_bounds

#: The tables a summary reads, in the order of the page: name -> file name under results/tables/.
TABLES = {
    "table1": "table1.csv",
    "table2": "table2.csv",
    "noise": "noise.csv",
    "noise_monte_carlo": "noise_monte_carlo.csv",
    "surface_maps": "surface_maps.csv",
    "geometry_sensitivity": "geometry_sensitivity.csv",
    "model_mismatch": "model_mismatch.csv",
    "runtime": "runtime.csv",
}

#: The estimator the headlines quote: the paper's, when it was run.
HEADLINE_METHOD = "koizumi_lm"

OK = "ok"


class SummaryError(ValueError):
    """A table the summary needs is missing or lacks a column it reads."""


def number(value, digits: int = 2) -> str:
    """``value`` to ``digits`` significant digits, trailing zeros dropped: plain from 1e-4 up, ``6e-6`` below, whole from 10**digits."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "n/a"
    value = float(value)
    if not math.isfinite(value):
        return str(value)
    if value == 0:
        return "0"
    rounded = float(f"{value:.{digits - 1}e}")
    exponent = math.floor(math.log10(abs(rounded)))
    if exponent >= digits:
        return f"{round(rounded):d}"
    if exponent >= -4:
        text = f"{rounded:.{max(digits - 1 - exponent, 0)}f}"
        return text.rstrip("0").rstrip(".") if "." in text else text
    mantissa = f"{rounded / 10**exponent:.{digits - 1}f}".rstrip("0").rstrip(".")
    return f"{mantissa}e{exponent}"


def value_range(values, digits: int = 2) -> str:
    """``min to max`` of the finite values (one number when they round alike)."""
    values = pd.Series(values, dtype=float).dropna()
    if values.empty:
        return "n/a"
    low, high = number(values.min(), digits), number(values.max(), digits)
    return low if low == high else f"{low} to {high}"


def tables_in(directory) -> dict[str, Path]:
    """The tables of :data:`TABLES` that exist under ``directory`` (results/tables/)."""
    directory = Path(directory)
    return {name: directory / file for name, file in TABLES.items() if (directory / file).is_file()}


def git_commit(directory) -> str:
    """The commit checked out at ``directory``, "unknown" when it is not a git checkout (or git is missing).

    Tracked files changed since that commit add " (with uncommitted changes)": the numbers then came from code
    the commit alone does not hold.
    """
    def git(*args):
        return subprocess.run(["git", "-C", str(directory), *args], capture_output=True, text=True, timeout=30, check=False)

    try:
        head = git("rev-parse", "HEAD")
        commit = head.stdout.strip()
        if head.returncode != 0 or not commit:
            return "unknown"
        status = git("status", "--porcelain", "--untracked-files=no")
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return commit + (" (with uncommitted changes)" if status.returncode == 0 and status.stdout.strip() else "")


def sha256_of(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _read(tables: Mapping[str, Path], name: str) -> pd.DataFrame | None:
    path = tables.get(name)
    if path is None or not Path(path).is_file():
        return None
    return pd.read_csv(path)


def _require(table: pd.DataFrame, columns, name: str) -> None:
    missing = [column for column in columns if column not in table]
    if missing:
        raise SummaryError(f"{name}: missing column(s) {', '.join(missing)}")


def _ok(table: pd.DataFrame) -> pd.DataFrame:
    return table[table["status"].astype(str) == OK] if "status" in table else table


def _sets_line(table: pd.DataFrame, keys=("set_id",)) -> str:
    sets = table.drop_duplicates(list(keys))
    ok = int((sets["status"].astype(str) == OK).sum()) if "status" in sets else len(sets)
    return f"{ok} of {len(sets)} sets ok"


def _headline_method(table: pd.DataFrame) -> str:
    methods = list(dict.fromkeys(table["method"]))
    return HEADLINE_METHOD if HEADLINE_METHOD in methods else methods[0]


def _markdown_table(header: list[str], rows: list[list[str]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(cell) for cell in row) + " |" for row in rows]
    return lines + [""]


# Each section returns (headline, lines): the headline is one sentence for the table at the top.


def _table1(table: pd.DataFrame, paper: pd.DataFrame | None) -> tuple[str, list[str]]:
    _require(table, ["set_id", "method", "status", "light_deg_err", "light_dir_err_deg", "albedo_err", "k_err"], "table1.csv")
    quantities = [
        ("light angle error (deg)", "light_deg_err", "light_deg"),
        ("light direction error, full angle (deg)", "light_dir_err_deg", None),
        ("mean albedo error", "albedo_err", "albedo"),
        ("mean k error", "k_err", "k"),
        ("per-point albedo RMSE", "albedo_rmse", None),
        ("per-point k RMSE", "k_rmse", None),
    ]
    methods = list(dict.fromkeys(table["method"]))
    ok = _ok(table)
    worst = {method: {key: ok.loc[ok.method == method, key].abs().max() for _, key, _ in quantities if key in ok} for method in methods}
    paper_worst = {}
    if paper is not None:
        paper_worst = {stem: (paper[f"{stem}_est"] - paper[f"{stem}_true"]).abs().max() for stem in ("light_deg", "albedo", "k")}
    rows = [
        [title, *(number(worst[method].get(key)) for method in methods), number(paper_worst[stem]) if stem in paper_worst else "not reported"]
        for title, key, stem in quantities
        if key in table
    ]
    lines = [
        "## Table 1: estimates on the true geometry (`table1.csv`)", "",
        f"{_sets_line(table)}. Worst over the sets of the absolute error; the paper's worst beside.", "",
        *_markdown_table(["quantity", *methods, "paper"], rows),
    ]
    method = _headline_method(table)
    headline = f"{method}: worst light error {number(worst[method]['light_deg_err'])} deg"
    if "light_deg" in paper_worst:
        headline += f" (paper {number(paper_worst['light_deg'])} deg)"
    return headline, lines


def _table2(table: pd.DataFrame) -> tuple[str, list[str]]:
    keys = ["light_dir_err_deg_final", "albedo_err_final", "k_err_final"]
    _require(table, ["set_id", "imaging", "priors", "method", "status", *keys], "table2.csv")
    rows, within_of, bound_lines = [], {}, []
    for (imaging, priors, method), group in table.groupby(["imaging", "priors", "method"], sort=True):
        bounds = table2_bounds(imaging)
        ok = _ok(group)
        # The light within its bound: the fixed one, or three Cramer-Rao deviations where the noise allows less (table2.csv's over-bound column).
        light_within = ok["light_err_over_bound_final"] <= 1.0 if "light_err_over_bound_final" in ok else ok[keys[0]].abs() <= bounds["light_dir_err_deg"]
        within = light_within & (ok[keys[1]].abs() <= bounds["albedo_err"]) & (ok[keys[2]].abs() <= bounds["k_err"])
        within_of[(imaging, priors, method)] = (int(within.sum()), len(group))
        registered = int(ok["registration_ok"].fillna(False).astype(bool).sum()) if "registration_ok" in ok else len(ok)
        rows.append([
            imaging, priors, method, f"{len(ok)} / {len(group)}", f"{registered} / {len(group)}",
            value_range(ok[keys[0]]), value_range(ok[keys[1]]), value_range(ok[keys[2]]),
            f"{int(within.sum())} / {len(group)}",
        ])
    for imaging in sorted(table.imaging.unique()):
        bounds = table2_bounds(imaging)
        bound_lines.append(f"{imaging}: light {number(bounds['light_dir_err_deg'])} deg, albedo {number(bounds['albedo_err'])}, k {number(bounds['k_err'])}")
    lines = [
        "## Table 2: from images alone (`table2.csv`)", "",
        "The final estimate (after every stage, the photometric refinement included): range over the sets of the light "
        "direction error (deg) and the mean albedo and k errors, per imaging condition; bounds: " + "; ".join(bound_lines) + " "
        "(the light's raised to three Cramér-Rao deviations for the observations used where the noise alone allows less: "
        "`light_err_over_bound_final`).", "",
        *_markdown_table(["imaging", "priors", "method", "sets ok", "registered", "light err", "albedo err", "k err", "within all bounds"], rows),
    ]
    method = _headline_method(table)
    parts = [f"{imaging}, priors {priors}: {within} / {total}" for (imaging, priors, m), (within, total) in within_of.items() if m == method]
    headline = f"{method}, final estimate, sets within all three bounds: " + ", ".join(parts)
    return headline, lines


def _noise(table: pd.DataFrame) -> tuple[str, list[str]]:
    _require(table, ["set_id", "method", "status", "noise_level"], "noise.csv")
    if "efficiency_albedo" not in table:
        return "", ["## Noise sweep (`noise.csv`)", "", f"{_sets_line(table)}; no Cramér-Rao bound in the table.", ""]
    scored = table.dropna(subset=["efficiency_albedo"])
    rows = []
    for (level, method), group in scored.groupby(["noise_level", "method"], sort=False):
        ok = _ok(group)
        sigma = ok["light_err_sigma"].abs() if "light_err_sigma" in ok else pd.Series(dtype=float)
        rows.append([
            level, method, value_range(ok["efficiency_albedo"]), value_range(ok["efficiency_k"]),
            f"{int((sigma <= 2).sum())} / {len(group)}",
        ])
    lines = [
        "## Noise sweep against the Cramér-Rao bound (`noise.csv`)", "",
        f"{_sets_line(table)}. One noise draw per set; efficiency is 1 for an efficient estimator; range over the sets.", "",
        *_markdown_table(["noise level", "method", "efficiency albedo", "efficiency k", "light within 2 sigma"], rows),
    ]
    method = "varpro" if "varpro" in set(scored["method"]) else _headline_method(scored)
    ok = _ok(scored[scored.method == method])
    headline = f"{method} per-point efficiency, all levels: {value_range(pd.concat([ok.efficiency_albedo, ok.efficiency_k]))}"
    return headline, lines


def _monte_carlo(table: pd.DataFrame) -> tuple[str, list[str]]:
    _require(table, ["set_id", "status", "draws", "light_rms_over_bound", "efficiency_albedo", "efficiency_k"], "noise_monte_carlo.csv")
    pooled = table[table.set_id == "all"]
    per_set = _ok(table[table.set_id != "all"])
    lines = ["## Noise Monte Carlo (`noise_monte_carlo.csv`)", "", f"{_sets_line(table[table.set_id != 'all'])}.", ""]
    headline = ""
    if not pooled.empty:
        row = pooled.iloc[0]
        lines += _markdown_table(
            ["", "draws", "light RMS / bound", "mean squared Mahalanobis (2 if efficient)", "light within 2 sigma", "efficiency albedo", "efficiency k"],
            [[
                "pooled", f"{int(row.draws)}", number(row.light_rms_over_bound), number(row.get("light_mahalanobis2_mean")),
                f"{number(100 * row.get('light_within_2sigma', float('nan')))} %", number(row.efficiency_albedo), number(row.efficiency_k),
            ], [
                "per set, range", value_range(per_set.draws), value_range(per_set.light_rms_over_bound),
                value_range(per_set.get("light_mahalanobis2_mean")), "", value_range(per_set.efficiency_albedo), value_range(per_set.efficiency_k),
            ]],
        )
        headline = f"light RMS error {number(row.light_rms_over_bound)} x the Cramér-Rao bound over {int(row.draws)} draws"
    return headline, lines


def _surface_maps(table: pd.DataFrame) -> tuple[str, list[str]]:
    _require(table, ["set_id", "method", "status", "light_dir_err_deg", "albedo_rmse", "k_rmse"], "surface_maps.csv")
    ok = _ok(table)
    rows = [
        [method, number(group.light_dir_err_deg.abs().max()), number(group.albedo_rmse.max()), number(group.k_rmse.max())]
        for method, group in ok.groupby("method", sort=True)
    ]
    lines = [
        "## Spatially varying albedo and k (`surface_maps.csv`)", "",
        f"{_sets_line(table)}. Worst over the sets, scored point by point against the maps.", "",
        *_markdown_table(["method", "light direction error (deg)", "per-point albedo RMSE", "per-point k RMSE"], rows),
    ]
    method = _headline_method(table)
    headline = f"{method}: per-point k RMSE at most {number(ok.loc[ok.method == method, 'k_rmse'].max())}"
    return headline, lines


def _geometry_sensitivity(table: pd.DataFrame, bounds: Mapping[str, float]) -> tuple[str, list[str]]:
    _require(table, ["set_id", "status", "variant", "normal_error_deg", "light_dir_err_deg", "albedo_err", "k_err"], "geometry_sensitivity.csv")
    ok = _ok(table)
    rows, within_of = [], {}
    for (variant, tilt), group in ok.groupby(["variant", "normal_error_deg"], sort=False):
        light, albedo, k = group.light_dir_err_deg.abs(), group.albedo_err.abs(), group.k_err.abs()
        within = int(((light <= bounds["light_dir_err_deg"]) & (albedo <= bounds["albedo_err"]) & (k <= bounds["k_err"])).sum())
        within_of[(variant, tilt)] = (within, len(group))
        rows.append([variant, number(tilt), f"{number(light.median())} / {number(light.max())}", f"{number(k.median())} / {number(k.max())}", f"{within} / {len(group)}"])
    lines = [
        "## What the estimator needs from the geometry (`geometry_sensitivity.csv`)", "",
        f"{_sets_line(table)}. Per variant and asked median normal tilt: median / worst over the sets of the absolute errors.", "",
        *_markdown_table(["variant", "tilt (deg)", "light err (deg)", "k err", "sets within all bounds"], rows),
    ]
    parts = [f"{label} {within_of[key][0]} / {within_of[key][1]}" for key, label in (
        (("bilinear", 0.0), "sampled bilinearly"), (("image_purity", 0.0), "pure samples only"),
    ) if key in within_of]
    headline = "true geometry, sets within all bounds: " + ", ".join(parts) if parts else ""
    return headline, lines


def _model_mismatch(table: pd.DataFrame) -> tuple[str, list[str]]:
    _require(table, ["render_model", "light_angle_deg", "experiment", "fit_model", "light_err_deg"], "model_mismatch.csv")
    lines = ["## The photometric model family (`model_mismatch.csv`)", ""]
    identity = table[table.experiment == "identity"]
    if not identity.empty:
        lines += [
            f"Identity fits (each law fitted to its own images): worst light error {number(identity.light_err_deg.abs().max())} deg, "
            f"worst parameter error {number(identity.get('max_param_err', pd.Series(dtype=float)).abs().max())}.", "",
        ]
    cross = table[table.experiment == "cross_fit"].dropna(subset=["bic"]) if "bic" in table else table.iloc[0:0]
    if not cross.empty:
        cells = cross.groupby(["render_model", "light_angle_deg", "noise"], sort=False)
        picked = sum(int(group.loc[group.bic.idxmin(), "fit_model"] == render) for (render, _, _), group in cells)
        lines += [f"Cross-fits: BIC picks the rendering law in {picked} of {cells.ngroups} rendered sets (each law, light angle and noise).", ""]
    sweep = table[table.experiment == "phase_sweep"]
    headline = ""
    if not sweep.empty:
        # The configured phase angle is the light's angle from the camera (light_angle_deg).
        sweep = sweep.sort_values("light_angle_deg")
        rows = [
            [number(row.light_angle_deg), number(row.get("phase_mean_deg")), number(row.get("k_images")), number(row.light_err_deg)]
            for _, row in sweep.iterrows()
        ]
        lines += [
            "Hapke surface fitted with the paper's Minnaert estimator, over the phase sweep:", "",
            *_markdown_table(["phase (deg)", "mean phase of the observations (deg)", "Minnaert k (median)", "light error (deg)"], rows),
        ]
        headline = (
            f"Minnaert fit of a Hapke surface: light {value_range(sweep.light_err_deg)} deg off "
            f"at phase {value_range(sweep.light_angle_deg)} deg"
        )
    return headline, lines


def _runtime(table: pd.DataFrame) -> tuple[str, list[str]]:
    _require(table, ["stage", "job", "seconds"], "runtime.csv")
    totals = table[table.job == "TOTAL"]
    jobs = table[table.job != "TOTAL"]
    if totals.empty:
        totals = jobs.groupby("stage", as_index=False)["seconds"].sum()
    counts = jobs.groupby("stage").size()
    rows = [[row.stage, f"{int(counts.get(row.stage, 0))}", f"{row.seconds:.0f}"] for row in totals.itertuples()]
    total = float(totals.seconds.sum())
    peak = number(jobs.max_rss_mb.max()) if "max_rss_mb" in jobs and not jobs.empty else "n/a"
    lines = [
        "## Runtime (`runtime.csv`)", "",
        f"Job-seconds from Snakemake's benchmarks (wall time of each job, summed per stage); largest peak memory of a job {peak} MB.", "",
        *_markdown_table(["stage", "jobs", "seconds"], rows + [["all", f"{len(jobs)}", f"{total:.0f}"]]),
    ]
    headline = f"{total:.0f} job-seconds in {len(jobs)} jobs"
    return headline, lines


def summary_markdown(
    tables: Mapping[str, Path],
    *,
    config: Mapping | None,
    bounds: Mapping[str, float] = TABLE2_BOUNDS,
    commit: str = "unknown",
    config_files: Mapping[str, str] | None = None,
    paper_table1=None,
) -> str:
    """The summary page of the tables in ``tables`` (name of :data:`TABLES` -> path; missing ones skipped).

    ``bounds``: Table 2's bounds (``light_dir_err_deg``, ``albedo_err``, ``k_err``);
    ``config_files``: config file path -> sha256; ``paper_table1``: the paper's Table 1 (CSV), put beside ours.
    """
    table1 = _read(tables, "table1")
    if table1 is None:
        raise SummaryError(f"Table 1 is required for the summary and was not found: {tables.get('table1', 'results/tables/table1.csv')}")
    paper = pd.read_csv(paper_table1) if paper_table1 is not None else None
    sections = [("Table 1", _table1(table1, paper))]
    for name, title, section in (
        ("table2", "Table 2", _table2),
        ("noise", "Noise sweep", _noise),
        ("noise_monte_carlo", "Noise Monte Carlo", _monte_carlo),
        ("surface_maps", "Surface maps", _surface_maps),
        ("geometry_sensitivity", "Geometry sensitivity", lambda t: _geometry_sensitivity(t, bounds)),
        ("model_mismatch", "Model mismatch", _model_mismatch),
        ("runtime", "Runtime", _runtime),
    ):
        table = _read(tables, name)
        if table is not None:
            sections.append((title, section(table)))
    lines = [
        "# Summary of the results", "",
        "The headline numbers of every result table of the run (`results/tables/`), then the run's provenance. "
        "Written by the workflow (rule `summary`); numbers to two significant digits.", "",
        "## Headlines", "",
        *_markdown_table(["output", "headline"], [[title, headline] for title, (headline, _) in sections if headline]),
    ]
    for _, (_, section_lines) in sections:
        lines += section_lines
    lines += ["## Provenance", "", f"Commit: `{commit}`", ""]
    for path, digest in (config_files or {}).items():
        lines += [f"Config file `{path}`: sha256 `{digest}`", ""]
    if config is not None:
        lines += [
            "Effective config (the files and any `--config` overrides, after validation):", "", "```yaml",
            yaml.safe_dump(json.loads(json.dumps(config)), default_flow_style=None, sort_keys=False, width=110).rstrip(), "```", "",
        ]
    return "\n".join(lines)


def write_summary(tables: Mapping[str, Path], out_path, **kwargs) -> str:
    """Write :func:`summary_markdown` to ``out_path`` (whole or not at all) and return it."""
    text = summary_markdown(tables, **kwargs)
    write_text(out_path, text)
    return text
