"""Child process of the Ctrl-C test of `simreel merge`: runs the real command, paused in the middle of the copy.

Usage: python interrupted_merge.py IN... -o OUT. Runs `simreel merge` on the arguments; when the copy opens its
third episode it prints `copying` (the first two are written by then) and sleeps, for the parent to send SIGINT.
Exits with the command's status.
"""

from __future__ import annotations

import sys
import time


def main(argv: list[str]) -> int:
    from simreel.cli.main import main as simreel
    from simreel.formats.hdf5.reader import Hdf5Reader

    open_episode = Hdf5Reader.open_episode
    calls = []

    def paused(self, index):
        calls.append(index)
        if len(calls) == 3:
            print("copying", flush=True)
            time.sleep(300)  # interrupted here
        return open_episode(self, index)

    Hdf5Reader.open_episode = paused
    return simreel(["merge", *argv, "-q"])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
