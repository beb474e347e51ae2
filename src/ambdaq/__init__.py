"""ambdaq: hardware bridge and data acquisition for active magnetic bearing machines."""

__version__ = "0.3.0"
