"""How close the estimates come to the truth, and the tables that say so.

Per set and estimator one summary row (the columns of ``table1.csv``):
``light_deg_*`` is the angle between the light and the direction towards
the camera, as in the paper; ``light_dir_err_deg`` the full angle between
the estimated and the true light vectors; ``*_est`` the mean of the
per-point estimates, as in the paper; ``*_rmse`` their root-mean-square
error over points, which the paper did not report. With a spatially varying
surface the truth is per point: ``*_true`` is then its mean over the fitted
points and ``*_rmse`` compares each point with its own truth.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # imported where a table is built: a stage's job has none to build, and pandas takes 0.45 s to import
    import pandas as pd

from asteroid_photometry.core.failures import DataFailure, OK, status_counts_line
from asteroid_photometry.estimation import angle_between_deg, FitResult, light_angle_deg

TABLE1_COLUMNS = [
    "set_id", "method", "status", "light_deg_true", "light_deg_est", "light_deg_err", "light_dir_err_deg",
    "albedo_true", "albedo_est", "albedo_err", "albedo_rmse", "k_true", "k_est", "k_err", "k_rmse",
    "n_points", "n_obs", "converged", "selection_passes", "selection_converged", "selection_equals_true", "selection_differences",
]

#: Wall-clock columns (``fit_seconds``, ``refit_seconds``, ...) of the per-fit summaries: they change from
#: run to run, so they stay out of the science tables and go to ``fit_timing.csv`` (:func:`fit_timing_table`).
TIMING_SUFFIX = "_seconds"


def without_timings(table: pd.DataFrame) -> pd.DataFrame:
    """``table`` without its wall-clock columns: the same inputs give the same table."""
    return table[[c for c in table if not str(c).endswith(TIMING_SUFFIX)]]


@dataclass(frozen=True)
class Truth:
    """The true light, and the true albedo and k: scalars (uniform) or one value per point."""

    light_dir_cam: np.ndarray
    albedo: float | np.ndarray
    minnaert_k: float | np.ndarray


def summary_row(set_id: str, result: FitResult, truth: Truth) -> dict:
    fitted = np.isfinite(result.albedo) & np.isfinite(result.minnaert_k)
    if not fitted.any():
        raise DataFailure(f"{result.method} fitted no point ({result.n_obs} observations)")
    albedo, minnaert_k = result.albedo[fitted], result.minnaert_k[fitted]
    albedo_true = np.broadcast_to(truth.albedo, result.albedo.shape)[fitted]
    k_true = np.broadcast_to(truth.minnaert_k, result.minnaert_k.shape)[fitted]
    light_true = float(light_angle_deg(truth.light_dir_cam))
    light_est = float(light_angle_deg(result.light_dir_cam))
    row = {
        "set_id": set_id,
        "method": result.method,
        "light_deg_true": light_true,
        "light_deg_est": light_est,
        "light_deg_err": light_est - light_true,
        "light_dir_err_deg": float(angle_between_deg(result.light_dir_cam, truth.light_dir_cam)),
        "albedo_true": float(albedo_true.mean()),
        "albedo_est": float(albedo.mean()),
        "albedo_err": float(albedo.mean() - albedo_true.mean()),
        "albedo_rmse": float(np.sqrt(np.mean((albedo - albedo_true) ** 2))),
        "k_true": float(k_true.mean()),
        "k_est": float(minnaert_k.mean()),
        "k_err": float(minnaert_k.mean() - k_true.mean()),
        "k_rmse": float(np.sqrt(np.mean((minnaert_k - k_true) ** 2))),
        "n_points": int(fitted.sum()),
        "n_obs": int(result.n_obs),
        "fit_seconds": float(result.fit_seconds),
        "converged": bool(result.success),
    }
    return row


def selection_agreement(selected: np.ndarray, selected_by_true_light: np.ndarray) -> dict:
    """Scoring of a selection made with an estimated light: is it the one the true light makes?

    Both are boolean masks over the same candidate observations.
    ``selection_differences`` counts the observations only one of them keeps.
    """
    differences = int(np.count_nonzero(np.asarray(selected, bool) != np.asarray(selected_by_true_light, bool)))
    return {"selection_equals_true": differences == 0, "selection_differences": differences}


def _rows_with_status(summary_paths) -> pd.DataFrame:
    """The summary rows; a row without ``status`` (written before there was one) is ``ok``."""
    import pandas as pd
    rows = [json.loads(Path(path).read_text()) for path in summary_paths]
    return pd.DataFrame([{"status": OK, **row} for row in rows])


def collect_table1(summary_paths) -> pd.DataFrame:
    """Table 1: one row per set and estimator; a failed set's row has its ``status`` (the reason) and no numbers."""
    table = _rows_with_status(summary_paths).reindex(columns=TABLE1_COLUMNS)
    return table.sort_values(["method", "light_deg_true", "k_true", "albedo_true"], kind="stable", key=_rounded).reset_index(drop=True)


def _rounded(column: pd.Series) -> pd.Series:
    """A sort key: the truth rounded (a failed set's row has the config's values, a fitted set's their means over points)."""
    return column.round(6) if column.dtype.kind == "f" else column


def with_paper(table: pd.DataFrame, paper: pd.DataFrame) -> pd.DataFrame:
    """Our rows joined with the paper's Table 1 values of the same set (NaN where the paper has none)."""
    paper = paper.rename(columns={c: f"paper_{c}" for c in ("light_deg_est", "albedo_est", "k_est")})
    keys = ["light_deg_true", "albedo_true", "k_true"]
    merged = table.copy()
    for key in keys:
        merged[key] = merged[key].round(6)
        paper[key] = paper[key].round(6)
    return merged.merge(paper, on=keys, how="left")


def _fmt(value, digits):
    import pandas as pd
    return "" if pd.isna(value) else f"{value:.{digits}f}"


def text_cell(value) -> str:
    """A table cell as text: empty for a missing value, whole numbers without a decimal point."""
    import pandas as pd
    if pd.isna(value):
        return ""
    return f"{value:.0f}" if isinstance(value, float) and value.is_integer() else str(value)


def table1_markdown(table: pd.DataFrame, paper: pd.DataFrame) -> str:
    """The readable Table 1: ours beside the paper's, one section per estimator."""
    merged = with_paper(table, paper)
    lines = ["# Table 1: estimates on the true geometry, ours beside the paper's", ""]
    lines += [
        "Estimates are means over the points (as in the paper); RMSE is per point. "
        "Light angles in degrees; `dir err` is the full angle between the estimated and true light vectors.",
        "",
    ]
    for method, group in merged.groupby("method", sort=False):
        lines += [f"## {method}", "", status_counts_line(group, keys=("set_id",)), ""]
        lines += [
            "| light | albedo | k | light est (paper) | light est (ours) | dir err (ours) | albedo est (paper) | albedo est (ours) "
            "| albedo RMSE | k est (paper) | k est (ours) | k RMSE | points | obs |",
            "|" + "---|" * 14,
        ]
        for _, r in group.iterrows():
            if r.status != OK:
                lines.append(f"| {r.light_deg_true:g} | {r.albedo_true:g} | {r.k_true:g} | {_fmt(r.paper_light_deg_est, 4)} | {r.status} |" + " |" * 9)
                continue
            lines.append(
                f"| {r.light_deg_true:g} | {r.albedo_true:g} | {r.k_true:g} | {_fmt(r.paper_light_deg_est, 4)} | {_fmt(r.light_deg_est, 5)} "
                f"| {_fmt(r.light_dir_err_deg, 5)} | {_fmt(r.paper_albedo_est, 3)} | {_fmt(r.albedo_est, 5)} | {_fmt(r.albedo_rmse, 5)} "
                f"| {_fmt(r.paper_k_est, 3)} | {_fmt(r.k_est, 5)} | {_fmt(r.k_rmse, 5)} | {r.n_points:.0f} | {r.n_obs:.0f} |"
            )
        worst = group.loc[:, ["light_deg_err", "light_dir_err_deg", "albedo_err", "k_err", "albedo_rmse", "k_rmse"]].abs().max()
        lines += ["", "Worst over the sets (absolute): " + ", ".join(f"{name} {value:.2g}" for name, value in worst.items()), ""]
        lines += _selection_lines(group)
    paper_worst = (paper["light_deg_est"] - paper["light_deg_true"]).abs().max()
    lines += [
        f"The paper's worst: light {paper_worst:.3f} deg, albedo {(paper['albedo_est'] - paper['albedo_true']).abs().max():.3f}, "
        f"k {(paper['k_est'] - paper['k_true']).abs().max():.3f}.",
        "",
    ]
    return "\n".join(lines)


def _selection_lines(group: pd.DataFrame) -> list[str]:
    """How the sets' observations were selected (with the estimated light), and whether the true light selects the same."""
    selected = group[(group.status == OK) & group.selection_passes.notna()] if "selection_passes" in group else group.iloc[:0]
    if not len(selected):
        return []
    passes = selected.selection_passes
    same = selected.selection_equals_true.astype(bool)
    return [
        f"Observations selected with the light estimated from the images in {passes.min():.0f} to {passes.max():.0f} passes "
        f"({int(selected.selection_converged.astype(bool).sum())} of {len(selected)} sets settled); the true light selects the same "
        f"observations in {int(same.sum())} of {len(selected)} sets"
        + (f" (at most {selected.selection_differences.max():.0f} differ)." if not same.all() else "."),
        "",
    ]


def collect_sweep(summary_paths) -> pd.DataFrame:
    """The summary rows of a sweep, with every column they have (Table 1's first)."""
    table = without_timings(_rows_with_status(summary_paths))
    ordered = [c for c in TABLE1_COLUMNS if c in table] + [c for c in table if c not in TABLE1_COLUMNS]
    return table[ordered].sort_values(["method", "set_id"], kind="stable").reset_index(drop=True)


SWEEP_MARKDOWN_COLUMNS = {
    "set_id": ("set", None), "status": ("status", None), "light_dir_err_deg": ("light dir err (deg)", 5), "albedo_err": ("albedo err", 5),
    "albedo_rmse": ("albedo RMSE", 5), "k_err": ("k err", 5), "k_rmse": ("k RMSE", 5), "n_points": ("points", None),
    "efficiency_albedo": ("efficiency albedo", 3), "efficiency_k": ("efficiency k", 3),
    "light_std_deg_bound": ("light std bound (deg)", 4), "light_err_sigma": ("light err / bound std", 2),
}


def sweep_markdown(table: pd.DataFrame, sweep: str) -> str:
    titles = {"noise": "Noise sweep: the sets with sensor noise", "surface_maps": "Spatially varying albedo and k"}
    lines = [f"# {titles.get(sweep, sweep)}", ""]
    columns = [c for c in SWEEP_MARKDOWN_COLUMNS if c in table]
    for method, group in table.groupby("method", sort=False):
        lines += [f"## {method}", "", status_counts_line(group, keys=("set_id",)), ""]
        lines += ["| " + " | ".join(SWEEP_MARKDOWN_COLUMNS[c][0] for c in columns) + " |", "|" + "---|" * len(columns)]
        for _, row in group.iterrows():
            cells = [text_cell(row[c]) if SWEEP_MARKDOWN_COLUMNS[c][1] is None else _fmt(row[c], SWEEP_MARKDOWN_COLUMNS[c][1]) for c in columns]
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


def runtime_table(benchmark_paths) -> pd.DataFrame:
    """One row per benchmarked job: stage, job (wildcards), seconds, peak memory."""
    import pandas as pd
    rows = []
    for path in benchmark_paths:
        path = Path(path)
        parts = path.parts[path.parts.index("benchmarks") + 1 :] if "benchmarks" in path.parts else path.parts[-2:]
        bench = pd.read_csv(path, sep="\t")
        rows.append({
            # A job with no wildcards may sit directly under benchmarks/: its stage is the file's name.
            "stage": parts[0].removesuffix(".tsv"),
            "job": "/".join(parts[1:]).removesuffix(".tsv") or "all",
            "seconds": float(bench["s"].iloc[-1]),
            "max_rss_mb": float(bench["max_rss"].iloc[-1]) if "max_rss" in bench else np.nan,
        })
    table = pd.DataFrame(rows, columns=["stage", "job", "seconds", "max_rss_mb"])
    totals = table.groupby("stage", as_index=False).agg(seconds=("seconds", "sum"), max_rss_mb=("max_rss_mb", "max"))
    totals["job"] = "TOTAL"
    return pd.concat([table, totals[["stage", "job", "seconds", "max_rss_mb"]]], ignore_index=True)


def fit_timing_table(summary_paths) -> pd.DataFrame:
    """The wall-clock columns of per-fit summaries (``results/fits*/.../<method>.json``), one row per fit.

    ``stage`` and ``job`` name the fit as ``runtime_table`` names its job
    (``fit``, ``<set_id>/<method>``; ``fit_cloud``, ``<set_id>/priors-<on|off>/<method>``).
    """
    import pandas as pd
    rows = []
    for path in summary_paths:
        path = Path(path)
        parts = path.parts[path.parts.index("results") + 1 :] if "results" in path.parts else path.parts[-3:]
        summary = json.loads(path.read_text())
        stage = {"fits": "fit", "fits_cloud": "estimate_cloud"}.get(parts[0], parts[0])
        rows.append({"stage": stage, "job": "/".join(parts[1:]).removesuffix(".json"), **{k: v for k, v in summary.items() if k.endswith(TIMING_SUFFIX)}})
    return pd.DataFrame(rows)


def light_error_components_deg(light_est, light_true, spin_axis_cam) -> tuple[float, float]:
    """The light's error split into (azimuth, elevation) about the body's spin axis, signed, degrees.

    Elevation: the angle out of the plane normal to ``spin_axis_cam`` (the
    plane of the views and the Sun in the default geometry); azimuth: the
    turn about the axis, between the two lights' projections on that plane.
    """
    axis = np.asarray(spin_axis_cam, float) / np.linalg.norm(spin_axis_cam)
    est, true = (np.asarray(v, float) / np.linalg.norm(v) for v in (light_est, light_true))
    elevation = np.degrees(np.arcsin(np.clip(est @ axis, -1, 1)) - np.arcsin(np.clip(true @ axis, -1, 1)))
    flat_est, flat_true = est - (est @ axis) * axis, true - (true @ axis) * axis
    azimuth = np.degrees(np.arctan2(np.cross(flat_true, flat_est) @ axis, flat_true @ flat_est))
    return float(azimuth), float(elevation)


#: What the project asks of the paper's estimator on the reconstructed cloud after refinement, on the paper's
#: noise-free renders (imaging condition ``ideal``) ...
TABLE2_BOUNDS = {"light_dir_err_deg": 0.5, "albedo_err": 0.01, "k_err": 0.01}
#: ... and under every realistic imaging condition (sensor noise, PSF, calibration error, 10 m navigation).
REALISTIC_TABLE2_BOUNDS = {"light_dir_err_deg": 1.0, "albedo_err": 0.01, "k_err": 0.02}
IDEAL_CONDITION = "ideal"


def table2_bounds(imaging: str) -> dict:
    """Table 2's bounds for an imaging condition: ``TABLE2_BOUNDS`` for ``ideal``, ``REALISTIC_TABLE2_BOUNDS`` for any other."""
    return TABLE2_BOUNDS if imaging == IDEAL_CONDITION else REALISTIC_TABLE2_BOUNDS

#: Table 2's stages, from the reconstructed cloud to the truth put in part by part:
#: (column suffix, label). ``light_dir_err_deg{suffix}`` and the like are table2.csv's columns.
TABLE2_STAGES = (
    ("", "cloud"), ("_refined", "refined"), ("_true_normals", "true normals"),
    ("_true_surface", "+ true surface"), ("_true_cameras", "+ true cameras"),
)


def _monte_carlo_row(draws: pd.DataFrame) -> dict:
    """What many noise draws say about an estimator against its Cramer-Rao bound.

    ``light_rms_over_bound``: RMS over draws of (light error / the bound's RMS
    angle); 1 for an efficient estimator. ``light_mahalanobis2_mean``: the
    mean squared Mahalanobis distance of the light error under the bound's
    covariance; 2 (two angles) for an efficient estimator. ``light_within_2sigma``:
    the fraction of draws whose error is within twice the bound's RMS angle,
    0.95 (one dominant direction) to 0.98 (isotropic) for an efficient
    estimator. ``efficiency_*``: pooled over draws, ``1 / mean(1 / e)``;
    ``efficiency_*_min``: the worst single draw.
    """
    ratio = draws["light_err_sigma"].to_numpy(float)
    return {
        "draws": len(draws),
        "light_std_deg_bound": float(draws["light_std_deg_bound"].mean()),
        "light_rms_deg": float(np.sqrt(np.mean(draws["light_dir_err_deg"].to_numpy(float) ** 2))),
        "light_rms_over_bound": float(np.sqrt(np.mean(ratio**2))),
        "light_mahalanobis2_mean": float(np.mean(draws["light_mahalanobis"].to_numpy(float) ** 2)),
        "light_within_2sigma": float(np.mean(ratio <= 2.0)),
        "efficiency_albedo": float(1.0 / np.mean(1.0 / draws["efficiency_albedo"].to_numpy(float))),
        "efficiency_k": float(1.0 / np.mean(1.0 / draws["efficiency_k"].to_numpy(float))),
        "efficiency_albedo_min": float(draws["efficiency_albedo"].min()),
        "efficiency_k_min": float(draws["efficiency_k"].min()),
    }


def monte_carlo_summary(draws: pd.DataFrame) -> pd.DataFrame:
    """One row per set from the per-draw rows of ``noise_monte_carlo``, then one row ``all`` pooling every draw.

    Only the draws whose ``status`` is ok count; a set with none has its
    first failure's reason as its status and no numbers.
    """
    import pandas as pd
    draws = draws.assign(status=draws["status"].fillna(OK)) if "status" in draws else draws.assign(status=OK)
    ok = draws[draws.status == OK]

    def summary(group, name):
        good = group[group.status == OK]
        if good.empty:
            return {"set_id": name, "noise_level": group["noise_level"].iloc[0], "status": group.status.iloc[0], "draws": 0}
        failed = len(group) - len(good)
        return {"set_id": name, "noise_level": group["noise_level"].iloc[0], "status": OK if not failed else f"{OK} ({failed} draws failed)", **_monte_carlo_row(good)}

    rows = [summary(group, set_id) for set_id, group in draws.groupby("set_id", sort=True)]
    rows.append(summary(ok if not ok.empty else draws, "all"))
    table = pd.DataFrame(rows)
    table["light_std_deg_bound"] = table["light_std_deg_bound"].where(table["set_id"] != "all")  # a mean over sets means nothing
    return table


def monte_carlo_markdown(table: pd.DataFrame) -> str:
    level = table["noise_level"].iloc[0]
    lines = [
        f"# Noise Monte Carlo: varpro on independent draws of the {level} noise",
        "",
        "For an efficient estimator: light RMS / bound 1, mean squared Mahalanobis distance 2, "
        "0.95-0.98 of the draws within 2 sigma, efficiencies 1.",
        "",
        status_counts_line(table[table.set_id != "all"].assign(status=table.status.str.replace(r" \(.*", "", regex=True)), "sets"),
        "",
        "| set | draws | light std bound (deg) | light RMS (deg) | RMS / bound | mean Mahalanobis^2 | within 2 sigma "
        "| efficiency albedo | efficiency k | worst draw albedo | worst draw k |",
        "|" + "---|" * 11,
    ]
    for _, r in table.iterrows():
        if r.draws == 0:
            lines.append(f"| {r.set_id} | 0 | {r.status} |" + " |" * 8)
            continue
        lines.append(
            f"| {r.set_id} | {r.draws} | {_fmt(r.light_std_deg_bound, 4)} | {_fmt(r.light_rms_deg, 4)} | {_fmt(r.light_rms_over_bound, 2)} "
            f"| {_fmt(r.light_mahalanobis2_mean, 2)} | {_fmt(r.light_within_2sigma, 2)} | {_fmt(r.efficiency_albedo, 3)} | {_fmt(r.efficiency_k, 3)} "
            f"| {_fmt(r.efficiency_albedo_min, 3)} | {_fmt(r.efficiency_k_min, 3)} |"
        )
    return "\n".join(lines) + "\n"
