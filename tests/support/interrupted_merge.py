"""Child process of tests of `simreel merge` that need it paused in the middle of the copy (Ctrl-C, a second merge).

Usage: python interrupted_merge.py IN... -o OUT. Runs `simreel merge` on the arguments; when the copy opens its
third episode it prints `copying` (the first two are written by then) and waits for a line on its standard input
(the parent sends SIGINT meanwhile, or a line to go on). Exits with the command's status.
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
    return simreel(["merge", *argv, "-q"])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
