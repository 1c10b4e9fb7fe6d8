"""Child process of tests that need `simreel merge`, `filter`, `convert` or `recover` paused in the middle of its copy
(Ctrl-C, kill -9, another command writing the same output meanwhile).

Usage: python paused_copy.py COMMAND ARGS... Runs `simreel COMMAND ARGS -q` (`recover` has no -q); when the copy opens its third episode
it prints `copying` (the first two are written by then) and waits for a line on its standard input (the parent
sends SIGINT meanwhile, or a line to go on). Exits with the command's status.
"""

from __future__ import annotations

import sys


def main(argv: list[str]) -> int:
    from simreel.cli.main import main as simreel
    from simreel.formats.hdf5.reader import Hdf5Reader

    open_episode = Hdf5Reader.open_episode
    calls = []

    def paused(self, index):
        calls.append(index)
        if len(calls) == 3:
            print("copying", flush=True)
            sys.stdin.readline()  # interrupted here, or told to go on
        return open_episode(self, index)

    Hdf5Reader.open_episode = paused
    return simreel([*argv] if argv[0] == "recover" else [*argv, "-q"])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
