"""Changing what a controller runs: verified coefficient downloads (``ambdaq push``)."""
