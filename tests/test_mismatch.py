"""The model-mismatch experiment's design and tables, without rendering."""

import json

import pandas as pd

from asteroid_photometry.experiments import mismatch

SETTINGS = {"models": ["lambert", "minnaert", "hapke"], "phase_angles_deg": [0, 20]}


def test_model_sets_cross_every_law_with_table1_angles_and_sweep_hapke():
    sets = mismatch.model_sets(SETTINGS, [0, 10])
    assert sets["lambert_light10"] == ("lambert", 10.0)
    assert sets["hapke_light20"] == ("hapke", 20.0)
    assert len(sets) == 3 * 2 + 1  # hapke_light0 is both
    assert "minnaert_light20" not in sets
    assert "hapke_light20" not in mismatch.model_sets({**SETTINGS, "models": ["lambert"]}, [0, 10])


def _cell(render, fit, noise, rms, bic, noise_rms=0.0):
    return {"experiment": "cross_fit", "render_model": render, "light_angle_deg": 10.0, "fit_model": fit, "noise": noise,
            "residual_rms": rms, "bic": bic, "noise_rms": noise_rms, "light_err_deg": 0.0}


def test_model_selection_counts_only_cells_that_differ_beyond_the_noise():
    rows = [
        _cell("lambert", "lambert", "none", 1e-7, -10), _cell("lambert", "minnaert", "none", 1e-7, -9),  # nested: not counted
        _cell("lambert", "hapke", "none", 0.02, 5),
        _cell("lambert", "lambert", "amica12", 0.002, 100, 0.002), _cell("lambert", "minnaert", "amica12", 0.002, 120, 0.002),
        _cell("lambert", "hapke", "amica12", 0.02, 90, 0.002),  # a wrong pick where it counts
    ]
    selection = mismatch.model_selection(pd.DataFrame(rows)).set_index("fit_model")
    assert not selection.loc["minnaert", "differs_beyond_noise"] and selection.loc["hapke", "differs_beyond_noise"]
    assert selection.loc["minnaert", "rendering_law_preferred"] and not selection.loc["hapke", "rendering_law_preferred"]
    markdown = mismatch.markdown(pd.DataFrame(rows), selection.reset_index())
    assert "in 0 of them (0.0 %" in markdown


def test_tables_and_plots_from_rows(tmp_path):
    rows = [
        _cell("lambert", "lambert", "none", 1e-7, -10), _cell("lambert", "hapke", "none", 0.02, 5),
        {"experiment": "phase_sweep", "render_model": "hapke", "fit_model": "minnaert", "noise": "none", "light_angle_deg": 10.0,
         "phase_mean_deg": 10.1, "k_images": 0.56, "k_law": 0.5601, "k_images_minus_law": -1e-4, "k_law_true_light": 0.53,
         "light_err_deg": 9.6, "light_err_deg_law": 9.6, "residual_rms": 0.003},
    ]
    path = tmp_path / "rows.json"
    path.write_text(json.dumps(rows))
    out = {name: tmp_path / name for name in ("t.csv", "t.md", "phase.png", "residuals.png")}
    mismatch.write_tables([path], out["t.csv"], out["t.md"], out["phase.png"], out["residuals.png"])
    assert len(pd.read_csv(out["t.csv"])) == 3
    assert "Largest |k_images - k_law|: 0.0001" in out["t.md"].read_text()
    assert out["phase.png"].stat().st_size > 0 and out["residuals.png"].stat().st_size > 0
