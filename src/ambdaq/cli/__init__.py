"""The ``ambdaq`` command line: thin click wrappers over the library."""
