"""``python -m uiest`` runs the command line."""

from uiest.cli import main

main()
