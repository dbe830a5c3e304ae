#!/usr/bin/env python3
"""Benchmark the estimators of the light direction, albedo and Minnaert k on the same observations.

For every size (points) it makes one set of synthetic observations
(``estimate.synthetic_observations``: a body turning about the camera's y
axis, 36 views by default, the light 10 deg from the camera, albedo uniform
in [0.3, 0.8] and k in [0.6, 1.0] per point, noiseless unless ``--noise``)
and fits it, in this one process, with

(a) ``naive``: what a newcomer would write, an outer Nelder-Mead search
    (``scipy.optimize.minimize``) over the light's two tangent coordinates
    whose objective loops in Python over the points, fitting each point's
    albedo and k with ``scipy.optimize.least_squares``. It is far too slow
    for the full sets, so it runs on ``--naive-points`` points (evenly
    spaced) and its time is extrapolated linearly in the number of points
    (the number of Nelder-Mead evaluations does not grow with it); the
    output says so.
(b) the paper's joint Levenberg-Marquardt (``estimate.fit_koizumi_lm``),
    twice: ``least_squares`` (scipy's generic sparse trust-region LM) and
    ``block_lm`` (the block-Schur LM written for this problem). Above
    ``--generic-max-points`` the generic one is not run (its sparse
    Jacobian and LSMR work arrays need too much memory); its time and
    memory are then extrapolated from the largest size it ran at, flagged.
(c) ``varpro``: ``varpro.fit_varpro``, variable projection plus a joint polish.

It prints a table per size: seconds (the best of ``--repeats``), the ratio
to varpro, the peak memory the fit added (resident set size, Linux's
``VmHWM`` reset before every fit), and whether each method reaches the
joint LM's answer (``block_lm``): light within 1e-4 deg, every point's
albedo and k within 1e-5. Then the speed targets at 100,000 points and
1,000,000 points, and an efficiency check on noisy data: the estimators'
errors against the Cramer-Rao bound (``fisher``).

Writes to ``--out`` (default results/bench/): ``timings.csv``,
``efficiency.csv``, ``timings.png`` (seconds against points, log-log) and
``summary.txt`` (the printed tables).

    .venv/bin/python bench/bench_estimators.py --quick          # < 30 s
    .venv/bin/python bench/bench_estimators.py                  # 1e3 .. 1e6 points, ~30 min

BLAS runs single-threaded (``blas_threads``) so that all methods use
one core alike.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import gc
import os
import platform
import sys
import threading
import time
from pathlib import Path

for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")

REPO = Path(__file__).resolve().parents[1]
if str(REPO / "workflow") not in sys.path:
    sys.path.insert(0, str(REPO / "workflow"))

import numpy as np  # noqa: E402
import scipy  # noqa: E402
import scipy.optimize  # noqa: E402
from asteroid_photometry.estimation import (  # noqa: E402
    Observations,
    angle_between_deg,
    fit_koizumi_lm,
    light_from_tangent,
    synthetic_observations,
)
from asteroid_photometry.reflectance.laws import minnaert_brightness
from asteroid_photometry.estimation.fisher import cramer_rao_bounds, efficiency  # noqa: E402
from asteroid_photometry.estimation.varpro import fit_varpro  # noqa: E402

LIGHT_ANGLE_DEG, LIGHT_AZIMUTH_DEG = 10.0, 30.0
ALBEDO_RANGE, K_RANGE = (0.3, 0.8), (0.6, 1.0)
LIGHT_TOLERANCE_DEG, PARAMETER_TOLERANCE = 1e-4, 1e-5
METHODS = ("naive", "koizumi_lm[least_squares]", "koizumi_lm[block_lm]", "varpro")
REFERENCE = "koizumi_lm[block_lm]"
FULL = dict(sizes=[1_000, 10_000, 100_000, 1_000_000], naive_points=100, repeats=1, efficiency_points=100_000)
QUICK = dict(sizes=[1_000, 3_000], naive_points=8, repeats=1, efficiency_points=3_000)


def true_light():
    theta, phi = np.radians(LIGHT_ANGLE_DEG), np.radians(LIGHT_AZIMUTH_DEG)
    return np.array([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), -np.cos(theta)])


@contextlib.contextmanager
def blas_threads(n_threads=1):
    """Run with every loaded OpenBLAS (numpy's and scipy's copies) at ``n_threads``, as threadpoolctl would.

    The environment variables above only act if numpy is imported after
    them; under pytest it already is. On a busy 2-core machine OpenBLAS's
    threads make the many small BLAS calls of ``fit_koizumi_lm``'s light
    search up to 10x slower. Yields the names of the libraries changed;
    their thread counts are restored on exit.
    """
    import ctypes

    restore = []
    try:
        with open("/proc/self/maps") as maps:
            paths = sorted({line.split()[-1] for line in maps if "openblas" in line.lower() and line.split()[-1].startswith("/")})
    except OSError:
        paths = []
    for path in paths:
        library = ctypes.CDLL(path)
        for prefix, suffix in (("openblas", ""), ("openblas", "64_"), ("scipy_openblas", ""), ("scipy_openblas", "64_")):
            setter = getattr(library, f"{prefix}_set_num_threads{suffix}", None)
            getter = getattr(library, f"{prefix}_get_num_threads{suffix}", None)
            if setter is not None and getter is not None:
                restore.append((Path(path).name, setter, int(getter())))
                setter(int(n_threads))
                break
    try:
        yield [name for name, _, _ in restore]
    finally:
        for _, setter, previous in restore:
            setter(previous)


# --------------------------------------------------------------------------
# Data
# --------------------------------------------------------------------------


def make_observations(n_points, n_views, seed, noise_sigma=0.0, chunk_points=100_000):
    """Synthetic observations and their truth, generated in chunks of points to bound memory."""
    rng = np.random.default_rng(seed)
    albedo = rng.uniform(*ALBEDO_RANGE, n_points)
    minnaert_k = rng.uniform(*K_RANGE, n_points)
    fields = {"point_index": [], "normal_cam": [], "view_cam": [], "brightness": []}
    for start in range(0, n_points, chunk_points):
        stop = min(n_points, start + chunk_points)
        part = synthetic_observations(
            stop - start, n_views, true_light(), albedo[start:stop], minnaert_k[start:stop],
            np.random.default_rng([seed, start]), noise_sigma,
        )
        fields["point_index"].append(part.point_index + start)
        for name in ("normal_cam", "view_cam", "brightness"):
            fields[name].append(getattr(part, name))
        del part
    arrays = {}
    for name in list(fields):
        arrays[name] = np.concatenate(fields.pop(name))
    obs = Observations(n_points=n_points, **arrays)
    del arrays
    return obs, albedo, minnaert_k


def subset(obs: Observations, point_ids):
    """The observations of some points only (renumbered 0 .. len(point_ids) - 1)."""
    renumber = np.full(obs.n_points, -1)
    renumber[point_ids] = np.arange(len(point_ids))
    rows = renumber[obs.point_index] >= 0
    return Observations(
        renumber[obs.point_index[rows]], obs.normal_cam[rows], obs.view_cam[rows], obs.brightness[rows], len(point_ids)
    )


# --------------------------------------------------------------------------
# The naive solver (a)
# --------------------------------------------------------------------------


def fit_naive(obs: Observations, light_init_tangent=(0.0, 0.0)):
    """Nelder-Mead over the light's tangent coordinates around a Python loop of per-point least_squares.

    Written as a newcomer would, but with tolerances tight enough to reach
    the joint LM's answer on noiseless data. Returns (light, albedo, k, n_evaluations).
    """
    starts = np.flatnonzero(np.diff(obs.point_index, prepend=-1))
    normals = np.split(obs.normal_cam, starts[1:])
    cos_o = np.split(obs.cos_emission, starts[1:])
    brightness = np.split(obs.brightness, starts[1:])
    n_evaluations = 0

    def per_point_fits(tangent):
        light = light_from_tangent(tangent)
        fits = []
        for normal_p, cos_o_p, brightness_p in zip(normals, cos_o, brightness):
            cos_i_p = normal_p @ light

            def residual(params, cos_i_p=cos_i_p, cos_o_p=cos_o_p, brightness_p=brightness_p):
                return minnaert_brightness(params[0], params[1], cos_i_p, cos_o_p) - brightness_p

            fits.append(scipy.optimize.least_squares(residual, [0.5, 0.8], ftol=1e-12, xtol=1e-12, gtol=1e-12))
        return fits

    def objective(tangent):
        nonlocal n_evaluations
        n_evaluations += 1
        return sum(fit.cost for fit in per_point_fits(tangent))

    start = np.asarray(light_init_tangent, dtype=float)
    result = scipy.optimize.minimize(
        objective,
        start,
        method="Nelder-Mead",
        options=dict(xatol=1e-10, fatol=1e-20, maxfev=2000, initial_simplex=[start, start + [0.1, 0.0], start + [0.0, 0.1]]),
    )
    fits = per_point_fits(result.x)
    albedo = np.full(obs.n_points, np.nan)
    minnaert_k = np.full(obs.n_points, np.nan)
    points = obs.point_index[starts]
    albedo[points] = [fit.x[0] for fit in fits]
    minnaert_k[points] = [fit.x[1] for fit in fits]
    return light_from_tangent(result.x), albedo, minnaert_k, n_evaluations


# --------------------------------------------------------------------------
# Measuring
# --------------------------------------------------------------------------


def _status_kib(key):
    with open("/proc/self/status") as status:
        for line in status:
            if line.startswith(key):
                return int(line.split()[1])
    raise KeyError(key)


class PeakMemory:
    """Peak resident set size while a block runs, and what it added to the size at the start.

    Linux: ``VmHWM`` after resetting it through ``/proc/self/clear_refs``.
    Elsewhere: a thread sampling ``psutil``'s RSS every 5 ms.
    """

    def __enter__(self):
        gc.collect()
        self.method = "VmHWM"
        try:
            with open("/proc/self/clear_refs", "w") as clear:
                clear.write("5")
            self.start = _status_kib("VmRSS") * 1024
        except OSError:
            import psutil

            self.method = "sampled"
            process = psutil.Process()
            self.start = self._sampled_peak = process.memory_info().rss
            self._stop = threading.Event()

            def sample():
                while not self._stop.wait(0.005):
                    self._sampled_peak = max(self._sampled_peak, process.memory_info().rss)

            self._thread = threading.Thread(target=sample, daemon=True)
            self._thread.start()
        return self

    def __exit__(self, *exc):
        if self.method == "VmHWM":
            self.peak = _status_kib("VmHWM") * 1024
        else:
            self._stop.set()
            self._thread.join()
            self.peak = self._sampled_peak
        self.added = max(self.peak - self.start, 0)
        return False


def fresh_large_allocations(threshold_bytes=1 << 20):
    """Make glibc map every allocation of ``threshold_bytes`` or more afresh and unmap it when freed.

    By default glibc raises its mmap threshold (up to 32 MiB) after large
    frees and keeps freed memory in its heap, so a fit can reuse memory an
    earlier fit freed and its peak reads too low. A fixed threshold (which
    also stops the adjustment) and trim threshold make the peak resident
    size count every large array. Chunk temporaries (512 KiB) stay below
    it. Returns False where there is no glibc.
    """
    import ctypes
    import ctypes.util

    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        m_trim_threshold, m_mmap_threshold = -1, -3
        return bool(libc.mallopt(m_mmap_threshold, int(threshold_bytes)) and libc.mallopt(m_trim_threshold, int(threshold_bytes)))
    except (OSError, AttributeError):
        return False


def timed(function, repeats):
    """(best seconds, peak bytes added, result of the last run)."""
    best, added, result = np.inf, 0, None
    for _ in range(repeats):
        with PeakMemory() as memory:
            start = time.perf_counter()
            result = function()
            seconds = time.perf_counter() - start
        best, added = min(best, seconds), max(added, memory.added)
    return best, added, result


def compare(light, albedo, minnaert_k, reference, points=None):
    """Light angle and worst per-point differences against the reference fit (over ``points`` if given)."""
    ref_albedo, ref_k = reference.albedo, reference.minnaert_k
    if points is not None:
        ref_albedo, ref_k = ref_albedo[points], ref_k[points]
    both = np.isfinite(albedo) & np.isfinite(ref_albedo)
    light_diff = float(angle_between_deg(light, reference.light_dir_cam))
    albedo_diff = float(np.max(np.abs(albedo[both] - ref_albedo[both]))) if np.any(both) else np.inf
    k_diff = float(np.max(np.abs(minnaert_k[both] - ref_k[both]))) if np.any(both) else np.inf
    missing = int(np.count_nonzero(np.isfinite(ref_albedo) != np.isfinite(albedo)))
    agree = light_diff < LIGHT_TOLERANCE_DEG and albedo_diff < PARAMETER_TOLERANCE and k_diff < PARAMETER_TOLERANCE and missing == 0
    return dict(light_diff_deg=light_diff, albedo_max_diff=albedo_diff, k_max_diff=k_diff, agree=bool(agree))


def run_size(n_points, n_views, *, naive_points, repeats, generic_max_points, noise, seed, generic_history, log=print):
    """Fit one synthetic set with every method; one row (dict) per method."""
    start = time.perf_counter()
    obs, albedo_true, k_true = make_observations(n_points, n_views, seed, noise)
    log(f"\n{n_points:,} points x {n_views} views: {obs.n_obs:,} observations (made in {time.perf_counter() - start:.1f} s)")
    rows = {}
    base = dict(n_points=n_points, n_views=n_views, n_obs=obs.n_obs, noise=noise)

    seconds, added, block = timed(lambda: fit_koizumi_lm(obs, solver="block_lm"), repeats)
    rows[REFERENCE] = dict(base, method=REFERENCE, seconds=seconds, peak_mib=added / 2**20, note="", light_err_truth_deg=angle_between_deg(block.light_dir_cam, true_light()))

    if n_points <= generic_max_points:
        seconds, added, generic = timed(lambda: fit_koizumi_lm(obs, solver="least_squares"), repeats)
        rows["koizumi_lm[least_squares]"] = dict(
            base, method="koizumi_lm[least_squares]", seconds=seconds, peak_mib=added / 2**20, note="",
            light_err_truth_deg=angle_between_deg(generic.light_dir_cam, true_light()),
            **compare(generic.light_dir_cam, generic.albedo, generic.minnaert_k, block),
        )
        generic_history.append((obs.n_obs, seconds, added))
    elif generic_history:
        ran_obs, ran_seconds, ran_added = generic_history[-1]
        factor = obs.n_obs / ran_obs
        rows["koizumi_lm[least_squares]"] = dict(
            base, method="koizumi_lm[least_squares]", seconds=ran_seconds * factor, peak_mib=ran_added * factor / 2**20,
            note=f"NOT RUN (> --generic-max-points): time and memory extrapolated x{factor:.1f} from {ran_obs:,} observations",
            light_err_truth_deg=np.nan, light_diff_deg=np.nan, albedo_max_diff=np.nan, k_max_diff=np.nan, agree=None,
        )

    seconds, added, result = timed(lambda: fit_varpro(obs), repeats)
    rows["varpro"] = dict(
        base, method="varpro", seconds=seconds, peak_mib=added / 2**20,
        note=f"passes {result.nfev}, stages " + ", ".join(f"{k} {v:.2f}s" for k, v in result.stage_seconds.items()),
        light_err_truth_deg=angle_between_deg(result.light_dir_cam, true_light()),
        **compare(result.light_dir_cam, result.albedo, result.minnaert_k, block),
    )

    fitted = np.flatnonzero(np.isfinite(block.albedo))
    chosen = fitted[np.linspace(0, fitted.size - 1, min(naive_points, fitted.size)).astype(np.int64)]
    small = subset(obs, chosen)
    seconds, added, (light, albedo, minnaert_k, n_evaluations) = timed(lambda: fit_naive(small), 1)
    factor = fitted.size / chosen.size
    rows["naive"] = dict(
        base, method="naive", seconds=seconds * factor, peak_mib=added / 2**20,
        note=(f"EXTRAPOLATED x{factor:.0f} from {chosen.size} points ({seconds:.1f} s, {n_evaluations} Nelder-Mead evaluations); "
              "memory of the subsample run") if factor > 1 else f"{n_evaluations} Nelder-Mead evaluations",
        light_err_truth_deg=angle_between_deg(light, true_light()),
        **compare(light, albedo, minnaert_k, block, points=chosen),
    )
    rows[REFERENCE].update(light_diff_deg=0.0, albedo_max_diff=0.0, k_max_diff=0.0, agree=True)
    del obs, block
    gc.collect()
    varpro_seconds = rows["varpro"]["seconds"]
    out = [rows[name] for name in METHODS if name in rows]
    for row in out:
        row["x_varpro"] = row["seconds"] / varpro_seconds
    return out


def run_efficiency(n_points, n_views, noise, seed, log=print):
    """Noisy data: errors of the estimators against the Cramer-Rao bound."""
    obs, albedo, minnaert_k = make_observations(n_points, n_views, seed + 1, noise)
    truth = (true_light(), albedo, minnaert_k)
    bounds = cramer_rao_bounds(obs, true_light(), albedo, minnaert_k, noise**2)
    rows = []
    fits = (
        ("varpro (sigma given)", lambda: fit_varpro(obs, sigma=noise)),
        ("varpro (sigma estimated)", lambda: fit_varpro(obs)),
        (REFERENCE, lambda: fit_koizumi_lm(obs, solver="block_lm")),
    )
    for name, fit in fits:
        start = time.perf_counter()
        result = fit()
        seconds = time.perf_counter() - start
        scores = efficiency(result, truth, bounds)
        row = dict(method=name, n_views=n_views, n_obs=obs.n_obs, noise=noise, seconds=seconds) | scores  # n_points: scored
        if hasattr(result, "albedo_std"):
            row["predicted_over_bound_light_std"] = result.light_std_deg / bounds["light_std_deg"]
            row["predicted_over_bound_k_var_median"] = float(np.nanmedian(result.minnaert_k_std**2 / bounds["k_var"]))
            row["estimated_sigma"] = result.noise_sigma
        rows.append(row)
    return rows


# --------------------------------------------------------------------------
# Output
# --------------------------------------------------------------------------


def format_timing_table(rows):
    header = f"{'points':>9} {'method':<26} {'seconds':>10} {'x varpro':>9} {'peak MiB':>9} {'light d deg':>11} {'max|d alb|':>10} {'max|d k|':>9} {'agree':>5}  note"
    lines = [header, "-" * len(header)]
    for row in rows:
        agree = "n/a" if row.get("agree") is None else ("yes" if row["agree"] else "NO")
        lines.append(
            f"{row['n_points']:>9,} {row['method']:<26} {row['seconds']:>10.3g} {row['x_varpro']:>9.3g} {row['peak_mib']:>9.0f} "
            f"{row['light_diff_deg']:>11.1e} {row['albedo_max_diff']:>10.1e} {row['k_max_diff']:>9.1e} {agree:>5}  {row['note']}"
        )
    return "\n".join(lines)


def format_efficiency_table(rows):
    header = f"{'method':<26} {'points':>8} {'noise':>6} {'seconds':>8} {'eff albedo':>10} {'eff k':>7} {'light err deg':>13} {'CRB std deg':>11} {'err/std':>7} {'Mahal.':>6}"
    lines = [header, "-" * len(header)]
    for row in rows:
        lines.append(
            f"{row['method']:<26} {row['n_points']:>8,} {row['noise']:>6.3g} {row['seconds']:>8.3g} {row['albedo_efficiency']:>10.3f} {row['k_efficiency']:>7.3f} "
            f"{row['light_error_deg']:>13.2e} {row['light_std_deg']:>11.2e} {row['light_error_sigma']:>7.2f} {row['light_mahalanobis']:>6.2f}"
        )
    return "\n".join(lines)


def targets(rows):
    """The issue's speed and memory targets, as lines of text."""
    lines = []
    by = {(row["n_points"], row["method"]): row for row in rows}
    if (100_000, "varpro") in by:
        varpro = by[(100_000, "varpro")]["seconds"]
        for method, goal in (("naive", 50.0), ("koizumi_lm[least_squares]", 5.0), ("koizumi_lm[block_lm]", 5.0)):
            if (100_000, method) in by:
                ratio = by[(100_000, method)]["seconds"] / varpro
                lines.append(f"100,000 points: {method} / varpro = {ratio:,.1f} (target >= {goal:g}): {'met' if ratio >= goal else 'NOT met'}")
    if (1_000_000, "varpro") in by:
        row = by[(1_000_000, "varpro")]
        lines.append(
            f"1,000,000 points: varpro {row['seconds']:.1f} s (target < 60 s): {'met' if row['seconds'] < 60 else 'NOT met'}; "
            f"peak memory added {row['peak_mib'] / 1024:.2f} GiB (target < 8 GiB): {'met' if row['peak_mib'] < 8 * 1024 else 'NOT met'}"
        )
    return lines


def write_csv(path, rows):
    names = []
    for row in rows:
        names += [name for name in row if name not in names]
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=names)
        writer.writeheader()
        writer.writerows(rows)


def plot(path, rows):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(figsize=(7, 5))
    for method, marker in zip(METHODS, "osD^"):
        measured = [r for r in rows if r["method"] == method]
        if not measured:
            continue
        points = [r["n_points"] for r in measured]
        seconds = [r["seconds"] for r in measured]
        extrapolated = [("EXTRAPOLATED" in r["note"]) or ("NOT RUN" in r["note"]) for r in measured]
        style = "--" if all(extrapolated) else "-"
        (line,) = axes.plot(points, seconds, style, marker=marker, label=method + (" (extrapolated)" if all(extrapolated) else ""))
        for x, y, flag in zip(points, seconds, extrapolated):
            if flag:
                axes.plot(x, y, marker=marker, markerfacecolor="white", color=line.get_color())
    axes.set_xscale("log")
    axes.set_yscale("log")
    axes.set_xlabel("points (x observations per point)")
    axes.set_ylabel("fit time [s]")
    axes.set_title("Estimators on the same synthetic observations (open: extrapolated)")
    axes.grid(True, which="both", alpha=0.3)
    axes.legend()
    figure.tight_layout()
    figure.savefig(path, dpi=120)
    plt.close(figure)


def run_benchmark(
    sizes,
    *,
    n_views=36,
    naive_points=100,
    repeats=1,
    generic_max_points=100_000,
    noise=0.0,
    seed=0,
    efficiency_points=0,
    efficiency_noise=0.01,
    out_dir=None,
    log=print,
):
    """The whole benchmark; returns (timing rows, efficiency rows) and writes the files if ``out_dir``."""
    with blas_threads(1) as blas:
        return _run_benchmark(
            sizes, n_views, naive_points, repeats, generic_max_points, noise, seed, efficiency_points, efficiency_noise, out_dir, log, blas
        )


def _run_benchmark(sizes, n_views, naive_points, repeats, generic_max_points, noise, seed, efficiency_points, efficiency_noise, out_dir, log, blas):
    timing_rows, generic_history = [], []
    for n_points in sizes:
        rows = run_size(
            n_points, n_views, naive_points=naive_points, repeats=repeats, generic_max_points=generic_max_points,
            noise=noise, seed=seed, generic_history=generic_history, log=log,
        )
        log(format_timing_table(rows))
        timing_rows += rows
    efficiency_rows = run_efficiency(efficiency_points, n_views, efficiency_noise, seed, log) if efficiency_points else []
    summary = [
        f"bench_estimators: {platform.node()}, {os.cpu_count()} cores, Python {platform.python_version()}, numpy {np.__version__}, "
        f"scipy {scipy.__version__}, BLAS threads limited to 1 in {', '.join(blas) or 'no library found'}",
        f"light {LIGHT_ANGLE_DEG:g} deg from the camera, albedo U{ALBEDO_RANGE}, k U{K_RANGE}, {n_views} views, noise {noise:g}",
        f"agree: light within {LIGHT_TOLERANCE_DEG:g} deg and every albedo and k within {PARAMETER_TOLERANCE:g} of {REFERENCE}",
        "",
        format_timing_table(timing_rows),
        "",
        *targets(timing_rows),
    ]
    if efficiency_rows:
        summary += [
            "",
            f"Efficiency against the Cramer-Rao bound ({efficiency_points:,} points, noise sigma {efficiency_noise:g}): "
            "eff = 1 / mean(err^2 / bound) per point parameter; err/std = light error over the bound's RMS angle; "
            "Mahal. = sqrt(d^T C^-1 d), a chi with 2 dof",
            format_efficiency_table(efficiency_rows),
        ]
    text = "\n".join(summary)
    log("\n" + text)
    if out_dir is not None:
        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        write_csv(out_dir / "timings.csv", timing_rows)
        if efficiency_rows:
            write_csv(out_dir / "efficiency.csv", efficiency_rows)
        plot(out_dir / "timings.png", timing_rows)
        (out_dir / "summary.txt").write_text(text + "\n")
        log(f"\nwrote {out_dir}/timings.csv, timings.png, summary.txt" + (", efficiency.csv" if efficiency_rows else ""))
    return timing_rows, efficiency_rows


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", type=int, nargs="+", help=f"numbers of points (default {FULL['sizes']}; quick {QUICK['sizes']})")
    parser.add_argument("--views", type=int, default=36, help="observations (views) per point (default 36)")
    parser.add_argument("--repeats", type=int, help="timed runs per method and size, best kept (default 1)")
    parser.add_argument("--naive-points", type=int, help=f"points the naive solver runs on (default {FULL['naive_points']}; quick {QUICK['naive_points']})")
    parser.add_argument("--generic-max-points", type=int, default=100_000, help="largest size for the generic least_squares LM (default 100000)")
    parser.add_argument("--noise", type=float, default=0.0, help="brightness noise sigma of the timing sets (default 0: noiseless)")
    parser.add_argument("--efficiency-points", type=int, help=f"points of the noisy efficiency set, 0 to skip (default {FULL['efficiency_points']:,}; quick {QUICK['efficiency_points']:,})")
    parser.add_argument("--efficiency-noise", type=float, default=0.01, help="noise sigma of the efficiency set (default 0.01)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--quick", action="store_true", help="small sizes, < 30 s")
    parser.add_argument("--out", type=Path, default=REPO / "results" / "bench", help="output directory (default results/bench/)")
    args = parser.parse_args(argv)
    defaults = QUICK if args.quick else FULL
    fresh_large_allocations()  # process-wide, so only here and not in run_benchmark (which tests call)
    run_benchmark(
        args.sizes or defaults["sizes"],
        n_views=args.views,
        naive_points=args.naive_points or defaults["naive_points"],
        repeats=args.repeats or defaults["repeats"],
        generic_max_points=args.generic_max_points,
        noise=args.noise,
        seed=args.seed,
        efficiency_points=defaults["efficiency_points"] if args.efficiency_points is None else args.efficiency_points,
        efficiency_noise=args.efficiency_noise,
        out_dir=args.out,
    )


if __name__ == "__main__":
    main()
