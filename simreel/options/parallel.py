"""The options of a command that spreads its episodes over processes or a Ray cluster (`simreel replay`,
`simreel export`): `WORKERS` and `RAY`, declared once here and used by each command's options class as
``option(..., spec=WORKERS)``, so their flags, help and checks read the same everywhere."""

from __future__ import annotations

from simreel.errors import UsageError
from simreel.options.checks import text, whole
from simreel.options.declare import Option

__all__ = ["WORKERS", "RAY", "check_workers"]

WORKERS = Option(help="parallel processes, or Ray workers with --ray (default 1)", metavar="N", parse=int,
                 check=whole("the number of processes (Ray workers with ray) working on the episodes, an int >= 1"))
RAY = Option(help="run on a Ray cluster (pip install 'simreel[ray]'): alone, a cluster started on this machine; "
                  "'auto', the cluster this machine belongs to; or its address (host:6379, ray://host:10001)",
             nargs="?", const="local", metavar="ADDRESS",
             check=text('"local", "auto" or a cluster address ("ray://host:10001", "host:6379") as a string, or None '
                        "(no Ray)", optional=True))


def check_workers(workers: int) -> None:
    """`UsageError` for fewer than one worker."""
    if workers < 1:
        raise UsageError(f"--workers must be >= 1, got {workers}")
