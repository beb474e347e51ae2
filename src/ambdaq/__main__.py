"""``python -m ambdaq`` runs the command line."""

from .cli.main import main

main()
