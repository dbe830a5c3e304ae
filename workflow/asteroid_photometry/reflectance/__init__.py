"""The photometric laws: the brightness of a surface point from its incidence, emission and phase angles.

Rendering (:mod:`asteroid_photometry.world`) and estimation
(:mod:`asteroid_photometry.estimation`) both evaluate these laws; each is
written once, in :mod:`.laws`.
"""
