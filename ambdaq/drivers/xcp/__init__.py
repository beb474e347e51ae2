"""ASAM XCP: a controller's measurement and calibration door, with pyxcp as the master
(the ``xcp`` extra) and its A2L file read by pya2ldb (docs/hardware.md, "XCP")."""
