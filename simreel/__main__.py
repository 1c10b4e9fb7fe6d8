"""`python -m simreel` runs the CLI."""

import sys

from simreel.cli.main import main

sys.exit(main())
