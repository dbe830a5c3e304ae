"""The file-level stages the rule scripts call: each reads its inputs, runs the library and writes its declared outputs.

- :mod:`.table1`: render, observe and fit the paper's sets; Table 1, the sweeps, the plots.
- :mod:`.monte_carlo`: the noise Monte Carlo.
- :mod:`.table2`: Table 2 from images alone.
- :mod:`.sensitivity`: what the estimator needs from the geometry.
- :mod:`.mismatch`: the photometric model family and model mismatch.
"""
