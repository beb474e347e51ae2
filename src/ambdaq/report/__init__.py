"""The commissioning report: its HTML page (:mod:`.page`) and its PDF (:mod:`.pdf`), rendered from
the commissioning workflow's result; ``ambdaq report`` is the command that gathers and writes it."""
