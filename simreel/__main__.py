"""`python -m simreel` runs the CLI."""

from simreel.cli.main import run

run()
