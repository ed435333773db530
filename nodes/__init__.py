"""Runtime: node process, module layers, wire messages, key space and task engine."""
