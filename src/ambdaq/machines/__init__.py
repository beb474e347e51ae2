"""The machines ambdaq knows, described once: axes, rates, bearings, rotors and their
controllers' tables.  The simulator, the analysis defaults and the command line read them here."""
