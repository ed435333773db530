"""Contact fusion (thesis ch. 4): hypotheses, generators, integrator, condensation, contact events."""
