"""Studies on the simulated machines: commands whose answer is a run of the simulator itself (a
schedule compared on the simulated spindle's run-up, a simulated fleet to scan), not a recording
of a machine.  The one floor above ``workflows`` that imports ``sim``."""
