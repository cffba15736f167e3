"""Analyses of a finished run: how well its CAVs could have done (the SUMO-checked optimum)."""
