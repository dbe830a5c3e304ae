"""The noise Monte Carlo: one set, one sensor level, many seeded draws, scored against the Cramer-Rao bound."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # imported where a table is built: a stage's job has none to build, and pandas takes 0.45 s to import
    import pandas as pd

from asteroid_photometry.core import files
from asteroid_photometry.core.failures import DataFailure, record, table_status
from asteroid_photometry.estimation.registry import observations_from_arrays, require_observations, run_estimator
from asteroid_photometry.evaluation import metrics
from asteroid_photometry.evaluation.truth import truth_from_arrays
from asteroid_photometry.experiments.table1 import cramer_rao_summary, load_lit_test, observation_arrays, selection_columns
from asteroid_photometry.world import noise, observe
from asteroid_photometry.world.image_sets import ImageSet
from asteroid_photometry.world.images import read_rendered_images

log = logging.getLogger(__name__)


def noise_monte_carlo_set(geometry_npz, shape_npz, cameras_json, thresholds: dict, clean_dir, sensor_entry: dict, base_seed: int, realisations: int, image_set: ImageSet, set_id: str, out_csv) -> None:
    """The noise of ``sensor_entry`` drawn ``realisations`` times on one clean set, each draw fitted by varpro.

    Draw ``r`` (1, 2, ...) uses the generator seeded with ``(base_seed, r)``:
    independent of each other and of the noisy set the sweep made from
    ``base_seed`` alone. Each draw's observations are selected as Table 1's
    are, with the light estimated from that draw (``observation_arrays``;
    ``thresholds``: the config's ``observations``). One row per draw: the
    Table 1 columns, the selection's, and the Cramer-Rao comparison of
    :func:`cramer_rao_summary`.
    """
    import pandas as pd
    candidates = observe.ObservationGeometry.load(geometry_npz)
    lit = load_lit_test(shape_npz, cameras_json, candidates, thresholds)
    sensor = noise.sensor_from_config(sensor_entry)
    try:
        frames, clean = read_rendered_images(clean_dir)
    except DataFailure as failure:
        files.write_csv(pd.DataFrame([{"set_id": set_id, "noise_level": sensor.name, "status": table_status(record("noise_monte_carlo", failure))}]), out_csv)
        return
    frames = dict(frames, sensor=sensor.to_dict())
    rows = []
    for draw in range(1, realisations + 1):
        rng = np.random.default_rng([int(base_seed), draw])
        noisy = [noise.apply_sensor_noise(image, sensor, rng) for image in clean]
        try:
            arrays = observation_arrays(candidates, frames, noisy, clean_dir, lit, thresholds["min_observations_per_point"])
            obs = observations_from_arrays(arrays)
            require_observations(obs)
            result = run_estimator(obs, "varpro", variance=arrays["variance"])
            row = metrics.summary_row(set_id, result, truth_from_arrays(arrays))
        except DataFailure as failure:
            rows.append({"set_id": set_id, "noise_level": sensor.name, "draw": draw, "status": table_status(record("noise_monte_carlo", failure))})
            continue
        row.update(status=table_status(), noise_level=sensor.name, draw=draw, **selection_columns(arrays), **cramer_rao_summary(obs, arrays, result))
        log.info("draw %d: light %.3f deg (%.2f sigma), efficiency albedo %.2f, k %.2f", draw, row["light_dir_err_deg"], row["light_err_sigma"], row["efficiency_albedo"], row["efficiency_k"])
        rows.append(row)
    files.write_csv(metrics.without_timings(pd.DataFrame(rows)), out_csv)



def write_monte_carlo_table(draw_csvs, out_csv, out_markdown) -> None:
    import pandas as pd
    table = metrics.monte_carlo_summary(pd.concat([pd.read_csv(path) for path in draw_csvs], ignore_index=True))
    files.write_csv(table, out_csv)
    files.write_text(out_markdown, metrics.monte_carlo_markdown(table))
    log.info("noise Monte Carlo: %d sets", len(table) - 1)
