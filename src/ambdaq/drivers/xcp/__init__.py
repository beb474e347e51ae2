"""ASAM XCP: a controller's measurement and calibration door.  ambdaq is the master itself
(:mod:`.master`, :mod:`.transport`, :mod:`.daq`) and reads the A2L file itself (:mod:`.a2l`):
docs/hardware.md, "XCP", says why."""
