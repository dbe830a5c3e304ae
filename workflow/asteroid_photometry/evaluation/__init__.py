"""Scoring: the truth (read in one place, :mod:`.truth`), the error metrics, the reconstruction's quality, tables, plots and the summary."""
