"""Before a run: the disk it will fill and the memory its largest job needs, against what the machine has.

Every per-set output grows with the pixels of the set (``n_images *
image_size**2``): the rendered images, the pure-pixel observations, the
reconstruction's 8-bit images and features, the clouds. The rates below are
bytes (and megabytes of peak memory) per such pixel, measured on the small
config (one set of 36 images of 512 px, ``make test``); the estimate scales
them to the configured sets. It is printed when the workflow starts
(``snakemake -n`` shows it, ``make footprint`` prints only it), with a
warning when the disk or the memory of this machine falls short.
"""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass

from asteroid_photometry.core.config import renders_own_sets

#: The pixels of the set the rates were measured on: 36 images of 512 x 512.
MEASURED_PIXELS = 36 * 512**2

#: Bytes written per pixel of a set (results/, measured: 7.3 MB of EXR per clean set, 16.4 MB per noisy one, ...).
BYTES_PER_PIXEL = {
    "render": 0.78,  # linear float EXR, the black sky compresses
    "render_noisy": 1.74,  # noise leaves little to compress
    "observations": 0.17,
    "fits": 0.011,  # per estimator
    "observation_geometry": 0.15,  # once: the candidate observations need no light
    # Table 2's reconstructions, 0.57 for a whole one (8-bit images, COLMAP database, model), shared out as measured
    # on one full-config mission set: 78 % the features (once per set and condition), 22 % each prior setting's.
    "features": 0.44,  # 8-bit images, COLMAP database of features and verified matches
    "reconstruction": 0.13,  # per prior setting: the model and the mapper's
    "cloud": 0.046,  # per prior setting: registration, refined cloud, cloud fits
}
#: Peak memory (resident set, MB) of each heavy job on the measured set (benchmarks/, runtime.csv). estimate_cloud's and
#: score_cloud's: one job of each, every estimator of a cloud in it, on a set of the full config (of the same size).
#: match_features and reconstruct (the mapper alone) were measured on a full-config mission set of the same size.
PEAK_MB_MEASURED = {
    "refine_cloud": 786, "score_cloud": 560, "estimate_cloud": 545, "match_features": 466, "reconstruct": 388, "register_cloud": 378,
    "observation_geometry": 339, "render": 270, "observe": 187, "fit": 128,
}
#: Of that, what any job needs whatever the set's size (Python and the libraries).
BASE_MB = 150
#: Shape model, logs, benchmarks and Snakemake's metadata.
FIXED_BYTES = 10e6


@dataclass
class Footprint:
    disk_bytes: dict  # what -> bytes
    peak_mb: dict  # job -> MB
    n_sets: int

    @property
    def total_disk_bytes(self) -> float:
        return float(sum(self.disk_bytes.values()))

    @property
    def largest_job(self) -> tuple[str, float]:
        job = max(self.peak_mb, key=self.peak_mb.get)
        return job, self.peak_mb[job]

    def summary(self) -> str:
        parts = ", ".join(f"{what} {_size(size)}" for what, size in self.disk_bytes.items() if size >= 0.5e6)
        job, peak = self.largest_job
        return (
            f"estimated footprint of this run: {_size(self.total_disk_bytes)} on disk for {self.n_sets} image sets ({parts}); "
            f"largest job {job}, about {_size(peak * 1e6)} of memory"
        )


def _size(n_bytes: float) -> str:
    return f"{n_bytes / 1e9:.1f} GB" if n_bytes >= 1e9 else f"{n_bytes / 1e6:.0f} MB"


def estimate_footprint(config: dict, sets: dict, n_prior_settings: int, n_estimators: int, n_model_sets: int = 0, conditions: dict | None = None, condition_sets: dict | None = None) -> Footprint:
    """The disk and memory of the run that ``config`` asks for (``sets``: ``experiment.image_sets(config)``;
    ``n_model_sets``: the model-mismatch experiment's rendered sets, noise-free images as the others;
    ``conditions``: Table 2's imaging conditions by name, one mission set of each base set it runs on
    (``condition_sets``, by name; None: every base set); None: one, noise-free)."""
    pixels = config["n_images"] * config["image_size"] ** 2
    noisy = sum(1 for s in sets.values() if s.noise_level)
    base = sum(1 for s in sets.values() if s.is_base)
    conditions = {"ideal": {}} if conditions is None else conditions
    runs_of = {name: len(condition_sets[name]) if condition_sets else base for name in conditions}  # base sets per condition
    noisy_missions = sum(runs_of[name] for name, entry in conditions.items() if entry.get("sensor_level"))
    missions = sum(runs_of.values())
    # A condition of its own views, Sun or relief renders its own copy of every base set it runs on (noise-free, as the others).
    own_renders = sum(runs_of[name] for name, entry in conditions.items() if renders_own_sets(entry)) if n_prior_settings else 0
    runs = missions * n_prior_settings  # reconstructions of Table 2
    matched = missions if n_prior_settings else 0  # their features, one set for every prior setting
    per_set = {
        "rendered images": BYTES_PER_PIXEL["render"] * (len(sets) - noisy + n_model_sets + own_renders) + BYTES_PER_PIXEL["render_noisy"] * noisy,
        "observations and fits": BYTES_PER_PIXEL["observations"] * len(sets) + BYTES_PER_PIXEL["fits"] * len(sets) * n_estimators
        + BYTES_PER_PIXEL["observation_geometry"],
        "mission sets": BYTES_PER_PIXEL["render"] * (missions - noisy_missions) + BYTES_PER_PIXEL["render_noisy"] * noisy_missions
        if n_prior_settings else 0.0,
        "reconstructions": BYTES_PER_PIXEL["features"] * matched + BYTES_PER_PIXEL["reconstruction"] * runs,
        "clouds": BYTES_PER_PIXEL["cloud"] * runs,
    }
    disk = {what: rate * pixels for what, rate in per_set.items()}
    disk["shape, logs, metadata"] = FIXED_BYTES
    scale = pixels / MEASURED_PIXELS
    jobs = PEAK_MB_MEASURED if n_prior_settings else {job: mb for job, mb in PEAK_MB_MEASURED.items() if job not in ("refine_cloud", "estimate_cloud", "score_cloud", "match_features", "reconstruct", "register_cloud")}
    peak = {job: BASE_MB + (mb - BASE_MB) * scale for job, mb in jobs.items()}
    return Footprint(disk, peak, len(sets) + n_model_sets + own_renders)


def machine_memory_mb() -> float | None:
    """This machine's physical memory in MB (None where the system does not say)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 1e6
    except (ValueError, OSError, AttributeError):
        return None


def footprint_warnings(footprint: Footprint, workdir, parallel_jobs: int = 1, memory_mb: float | None = None) -> list[str]:
    """What this machine lacks for the run: disk where ``workdir`` lies, memory for ``parallel_jobs`` of the largest job at once."""
    warnings = []
    free = shutil.disk_usage(workdir).free
    if footprint.total_disk_bytes > free:
        warnings.append(
            f"the run needs about {_size(footprint.total_disk_bytes)} of disk but {workdir} has {_size(free)} free: "
            "free some, or run fewer sets (config keys albedos, minnaert_k, light_angles_deg, noise_levels, surface_maps) or smaller images (image_size)"
        )
    memory_mb = machine_memory_mb() if memory_mb is None else memory_mb
    job, peak = footprint.largest_job
    if memory_mb is not None:
        if peak > memory_mb:
            warnings.append(f"the largest job ({job}) needs about {peak:.0f} MB of memory but this machine has {memory_mb:.0f} MB: lower image_size or n_images")
        elif parallel_jobs * peak > memory_mb:
            warnings.append(
                f"{parallel_jobs} jobs at once may need about {parallel_jobs * peak:.0f} MB of memory ({job}: {peak:.0f} MB each) "
                f"but this machine has {memory_mb:.0f} MB: run with fewer cores"
            )
    return warnings
