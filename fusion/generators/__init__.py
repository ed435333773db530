"""Contact hypotheses generators (thesis §4.3-4.5): one generator per file, pure core + Module shell."""
