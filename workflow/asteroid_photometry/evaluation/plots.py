"""Figures of Table 1: our errors beside the paper's, per set, and per-point error distributions."""

from __future__ import annotations

import textwrap

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from asteroid_photometry.core import files  # noqa: E402
from asteroid_photometry.evaluation.metrics import IDEAL_CONDITION, TABLE2_BOUNDS, table2_bounds, TABLE2_STAGES, with_paper  # noqa: E402

QUANTITIES = {
    "light": ("light_deg_est", "light_deg_true", "light angle error (deg)"),
    "albedo": ("albedo_est", "albedo_true", "albedo error (mean over points)"),
    "minnaert_k": ("k_est", "k_true", "Minnaert k error (mean over points)"),
}


def _set_labels(group: pd.DataFrame) -> list[str]:
    return [f"{r.light_deg_true:g}/{r.albedo_true:g}/{r.k_true:g}" for r in group.itertuples()]


def plot_errors_against_paper(table: pd.DataFrame, paper: pd.DataFrame, quantity: str, out_path) -> None:
    """|error| per set on a log scale: each of our estimators and the paper's."""
    estimate, truth, label = QUANTITIES[quantity]
    merged = with_paper(table, paper)
    fig, ax = plt.subplots(figsize=(10, 4.5))
    markers = iter("os^Dv")
    reference = None
    for method, group in merged.groupby("method", sort=False):
        x = np.arange(len(group))
        error = (group[estimate] - group[truth]).abs().clip(lower=1e-9)
        ax.semilogy(x, error, marker=next(markers), linestyle="none", label=f"ours: {method}")
        if reference is None:
            reference = group
    if reference is not None:
        x = np.arange(len(reference))
        paper_error = (reference[f"paper_{estimate}"] - reference[truth]).abs().clip(lower=1e-9)
        ax.semilogy(x, paper_error, marker="x", color="k", linestyle="none", label="paper (Koizumi et al.)")
        ax.set_xticks(x, _set_labels(reference), rotation=60, ha="right", fontsize=8)
    ax.set_xlabel("set: light angle (deg) / albedo / k")
    ax.set_ylabel(f"|{label}|")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    files.save_figure(fig, out_path, dpi=120)
    plt.close(fig)


def plot_per_point_errors(estimates: dict[str, dict], out_path, method: str = "koizumi_lm") -> None:
    """Box plots of per-point albedo and k errors, one box per set, for ``method``."""
    chosen = {key: value for key, value in estimates.items() if key[1] == method}
    labels = [set_id for set_id, _ in chosen]
    fig, axes = plt.subplots(2, 1, figsize=(10, 7), sharex=True)
    for ax, (field, truth_field, name) in zip(axes, [("albedo", "albedo_true", "albedo"), ("minnaert_k", "minnaert_k_true", "k")]):
        data = []
        for value in chosen.values():
            error = value[field] - value[truth_field]
            data.append(error[np.isfinite(error)])
        ax.boxplot(data, showfliers=True, flierprops={"markersize": 2})
        ax.axhline(0.0, color="k", linewidth=0.5)
        ax.set_ylabel(f"per-point {name} error")
        ax.grid(True, alpha=0.3)
    axes[-1].set_xticks(np.arange(1, len(labels) + 1), labels, rotation=60, ha="right", fontsize=7)
    axes[0].set_title(f"Per-point errors of {method}")
    fig.tight_layout()
    files.save_figure(fig, out_path, dpi=120)
    plt.close(fig)


def plot_error_maps_on_body(centroids_m: np.ndarray, estimates: dict, title: str, out_path) -> None:
    """Per-point albedo and k errors coloured on the body, seen from +z (pole) and from -y (side)."""
    fitted = np.isfinite(estimates["albedo"]) & np.isfinite(estimates["minnaert_k"])
    values = {
        "albedo error": (estimates["albedo"] - estimates["albedo_true"])[fitted],
        "k error": (estimates["minnaert_k"] - estimates["minnaert_k_true"])[fitted],
        "true albedo": estimates["albedo_true"][fitted],
    }
    plot_values_on_body({name: (centroids_m[fitted], value) for name, value in values.items()}, title, out_path)


def plot_message(text: str, out_path) -> None:
    """A figure that says why there is nothing to draw (a failed set)."""
    fig, ax = plt.subplots(figsize=(8, 3))
    ax.axis("off")
    ax.text(0.5, 0.5, "\n".join(textwrap.fill(line, 90) for line in text.splitlines()), ha="center", va="center", fontsize=10, transform=ax.transAxes)
    files.save_figure(fig, out_path, dpi=110)
    plt.close(fig)


def _scale_limit(values) -> float:
    values = np.abs(np.concatenate([np.ravel(v) for v in values]))
    return max(float(np.percentile(values[np.isfinite(values)], 99)), 1e-12)


def plot_values_on_body(values: dict, title: str, out_path) -> None:
    """Per-point values coloured on the body, one row each, seen from +z (pole) and from -y (side).

    ``values``: name -> (points (n, 3) in the body frame in m, values (n,)).

    Names ending in "error" get a diverging scale symmetric about 0, names
    ending in "error (deg)" a sequential one from 0; a row named "refined X"
    shares the scale of "X" (the 99th percentile of both magnitudes) so that
    the two compare. Other names get viridis.
    """
    def quantity(name):
        return name.removeprefix("refined ")

    limits = {quantity(name): _scale_limit([v for other, (_, v) in values.items() if quantity(other) == quantity(name)]) for name in values}
    fig, axes = plt.subplots(len(values), 2, figsize=(11, 3.2 * len(values)), squeeze=False)
    for row, (name, (points, value)) in enumerate(values.items()):
        finite = np.isfinite(value)
        limit = limits[quantity(name)]
        if name.endswith("error"):
            style = {"cmap": "coolwarm", "vmin": -limit, "vmax": limit}
        elif name.endswith("error (deg)"):
            style = {"cmap": "magma_r", "vmin": 0.0, "vmax": limit}
        else:
            style = {"cmap": "viridis"}
        for col, (i, j, view) in enumerate([(0, 1, "from the pole (+z)"), (0, 2, "from the side (-y)")]):
            ax = axes[row, col]
            order = np.argsort(points[finite, 3 - i - j])  # draw the far side first
            if col == 1:
                order = order[::-1]
            shown, colours = points[finite][order], value[finite][order]
            scatter = ax.scatter(shown[:, i], shown[:, j], c=colours, s=2 if len(shown) > 3000 else 6, **style)
            ax.set_aspect("equal")
            ax.set_title(f"{name}, {view}", fontsize=9)
            ax.set_xlabel("x (m)", fontsize=8)
            ax.set_ylabel("yz"[j - 1] + " (m)", fontsize=8)
            fig.colorbar(scatter, ax=ax, shrink=0.8)
    fig.suptitle(title)
    fig.tight_layout()
    files.save_figure(fig, out_path, dpi=110)
    plt.close(fig)


def plot_table2_stages(table: pd.DataFrame, method: str, out_path) -> None:
    """The absolute errors of ``method`` on every registered set, from the cloud through refinement to the truth put in part by part.

    One row of panels per imaging condition, one line per set and prior setting; dashed: the condition's bounds.
    """
    ok = table["status"] == "ok" if "status" in table else pd.Series(True, index=table.index)
    imagings = sorted(table["imaging"].unique()) if "imaging" in table else [IDEAL_CONDITION]
    fig, axes = plt.subplots(len(imagings), 3, figsize=(14, 4.2 * len(imagings)), squeeze=False)
    for row_axes, imaging in zip(axes, imagings):
        in_condition = table["imaging"] == imaging if "imaging" in table else True
        rows = table[(table.method == method) & table.registration_ok.fillna(False).astype(bool) & ok & in_condition]
        bounds = table2_bounds(imaging)
        for ax, key, label in zip(row_axes, ("light_dir_err_deg", "albedo_err", "k_err"), ("light direction error (deg)", "|albedo error|", "|k error|")):
            stages = [(suffix, title) for suffix, title in TABLE2_STAGES if f"{key}{suffix}" in rows]
            for _, row in rows.iterrows():
                values = [abs(row[f"{key}{suffix}"]) for suffix, _ in stages]
                ax.plot(range(len(stages)), np.maximum(values, 1e-5), marker="o", lw=0.8, alpha=0.6, color="tab:blue" if row.priors == "on" else "tab:orange")
            ax.axhline(bounds[key], color="k", ls="--", lw=0.8)
            ax.set_xticks(range(len(stages)), [textwrap.fill(title, 8) for _, title in stages], fontsize=8)
            ax.set_yscale("log")
            ax.set_ylabel(f"{imaging}: {label}")
    axes[0, 0].plot([], [], color="tab:blue", label="priors on")
    axes[0, 0].plot([], [], color="tab:orange", label="priors off")
    axes[0, 0].plot([], [], color="k", ls="--", label="bound after refinement")
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(f"Table 2, {method}: errors per set, from the reconstructed cloud to the truth put in part by part")
    fig.tight_layout()
    files.save_figure(fig, out_path, dpi=110)
    plt.close(fig)


def plot_table2_conditions(table: pd.DataFrame, method: str, paper: dict, out_path) -> None:
    """``method``'s final errors (after every stage) per imaging condition and set, beside the paper's real-image Table 2.

    One column of points per condition and prior setting (a point per set; a
    cross at the bottom for a set that failed); dashed: the condition's
    bounds; dotted: the paper's errors on real Hayabusa images.
    """
    rows = table[table.method == method]
    groups = sorted(rows.groupby(["imaging", "priors"]).groups)
    paper_errors = {
        "light_dir_err_deg_final": abs(paper["light_deg_est"] - paper["light_deg_true"]),
        "albedo_err_final": abs(paper["albedo_est"] - paper["albedo_true"]),
        "k_err_final": abs(paper["k_est"] - paper["k_true"]),
    }
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.4))
    for ax, key, label in zip(axes, paper_errors, ("light direction error (deg)", "|albedo error|", "|k error|")):
        floor = 1e-5
        for position, (imaging, priors) in enumerate(groups):
            group = rows[(rows.imaging == imaging) & (rows.priors == priors)]
            ok = group["status"] == "ok"
            values = group.loc[ok, key].abs().clip(lower=floor)
            jitter = np.linspace(-0.15, 0.15, len(values)) if len(values) > 1 else np.zeros(len(values))
            ax.scatter(position + jitter, values, s=14, color="tab:blue" if priors == "on" else "tab:orange", alpha=0.8)
            if (~ok).any():
                ax.scatter([position] * int((~ok).sum()), [floor] * int((~ok).sum()), marker="x", color="tab:red")
            bound = table2_bounds(imaging)[key.removesuffix("_final")]
            ax.hlines(bound, position - 0.35, position + 0.35, color="k", ls="--", lw=0.8)
        ax.axhline(paper_errors[key], color="tab:green", ls=":", lw=1.2)
        ax.set_xticks(range(len(groups)), [f"{imaging}\npriors {priors}" for imaging, priors in groups], fontsize=8)
        ax.set_yscale("log")
        ax.set_ylabel(label)
    axes[0].scatter([], [], color="tab:blue", label="priors on")
    axes[0].scatter([], [], color="tab:orange", label="priors off")
    axes[0].scatter([], [], marker="x", color="tab:red", label="failed")
    axes[0].plot([], [], color="k", ls="--", label="bound")
    axes[0].plot([], [], color="tab:green", ls=":", label="paper, real images")
    axes[0].legend(fontsize=8)
    fig.suptitle(f"Table 2, {method}, final estimate: per imaging condition and set, against the paper's real-image errors")
    fig.tight_layout()
    files.save_figure(fig, out_path, dpi=110)
    plt.close(fig)


def plot_geometry_sensitivity(table: pd.DataFrame, out_path) -> None:
    """The estimator's errors against the median error of the normals it is given, one line per set.

    Markers: the normals tilted along their meridian or their parallel only,
    and, at zero normal error, the true surface sampled as the cloud is
    (bilinear) and with the image-only purity test. Dashed: Table 2's bounds.
    """
    tilted = table[table.variant == "pure_pixels"]
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2))
    for ax, key, label in zip(axes, ("light_dir_err_deg", "albedo_err", "k_err"), ("light direction error (deg)", "|albedo error|", "|k error|")):
        for _, group in tilted.groupby("set_id", sort=False):
            group = group.sort_values("normal_error_deg")
            ax.plot(group["normal_error_deg_median"], group[key].abs().clip(lower=1e-6), lw=0.8, alpha=0.5, color="tab:blue")
        median = tilted.groupby("normal_error_deg")[["normal_error_deg_median", key]].agg(lambda v: np.median(np.abs(v)))
        ax.plot(median["normal_error_deg_median"], median[key].clip(lower=1e-6), lw=2.0, color="tab:blue", marker="o", label="pure pixels, normals tilted (median of sets)")
        for variant, marker, color, legend in (
            ("pure_pixels_latitude", "v", "tab:purple", "pure pixels, normals tilted along the meridian only"),
            ("pure_pixels_longitude", "D", "tab:orange", "pure pixels, normals tilted along the parallel only"),
            ("bilinear", "s", "tab:red", "true surface, bilinear samples"),
            ("image_purity", "^", "tab:green", "true surface, image purity samples"),
        ):
            rows = table[table.variant == variant]
            ax.plot(rows["normal_error_deg_median"], rows[key].abs().clip(lower=1e-6), marker=marker, linestyle="none", color=color, alpha=0.6, label=legend)
        ax.axhline(TABLE2_BOUNDS[key], color="k", ls="--", lw=0.8, label="Table 2 bound")
        ax.set_yscale("log")
        ax.set_xlabel("median normal error (deg)")
        ax.set_ylabel(label)
    axes[0].legend(fontsize=7)
    fig.suptitle("What the estimator needs from the geometry: errors against the normals' error, and against how the true surface is sampled")
    fig.tight_layout()
    files.save_figure(fig, out_path, dpi=110)
    plt.close(fig)


def plot_errors_against_bound(noise_table: pd.DataFrame, out_path) -> None:
    """Observed errors of the noisy sets against their Cramer-Rao bounds, one point per set and level.

    Per-point albedo and k: the observed RMSE over points against the RMS of
    the bound's standard deviations over the same points (what an efficient
    estimator's RMSE would be); light: the angular error against the bound's RMS angle.
    """
    rows = noise_table.dropna(subset=["light_std_deg_bound"])
    panels = [
        ("albedo_std_bound_rms", "albedo_rmse", "albedo: bound std (RMS over points)", "observed per-point RMSE"),
        ("k_std_bound_rms", "k_rmse", "k: bound std (RMS over points)", "observed per-point RMSE"),
        ("light_std_deg_bound", "light_dir_err_deg", "light: bound RMS angle (deg)", "observed error (deg)"),
    ]
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.5))
    markers = dict(zip(sorted(rows["method"].unique()), "os^D"))
    for ax, (x_key, y_key, x_label, y_label) in zip(axes, panels):
        for (method, level), group in rows.groupby(["method", "noise_level"]):
            ax.loglog(group[x_key], group[y_key].clip(lower=1e-9), marker=markers[method], linestyle="none", alpha=0.7, label=f"{method}, {level}")
        low = min(rows[x_key].min(), rows[y_key].clip(lower=1e-9).min())
        high = max(rows[x_key].max(), rows[y_key].max())
        ax.loglog([low, high], [low, high], "k-", linewidth=0.8, label="= bound")
        if y_key == "light_dir_err_deg":
            ax.loglog([low, high], [2 * low, 2 * high], "k--", linewidth=0.8, label="2 x bound")
        ax.set_xlabel(x_label)
        ax.set_ylabel(y_label)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=6)
    fig.suptitle("Noise sweep: observed errors against the Cramér-Rao bound")
    fig.tight_layout()
    files.save_figure(fig, out_path, dpi=110)
    plt.close(fig)
