"""The robots: one package per robot (its home: ``spec``, ``factory``, ``HOME``), found by the registry."""
